//! A real Slurm cluster: the test starts a one-node cluster on localhost (Debian's munged,
//! slurmctld and slurmd, by the test itself, no systemd), submits a split run with
//! `geostride slurm --submit` (a job array and a merge after it), waits, and checks the outputs
//! against `geostride run`'s, byte for byte. Where the packages are missing (they come with
//! scripts/bootstrap.sh) or the test is not root (slurmd must be), it says so and skips; under
//! CI (`CI` set) that is a failure instead.

#![cfg(all(feature = "opencv", feature = "gdal", feature = "onnx"))]

mod common;

use std::path::{Path, PathBuf};
use std::process::Command;
use std::time::{Duration, Instant};

use common::{assert_success, geostride};

/// The daemons of a one-node cluster in a temporary folder; stopped when dropped.
struct Cluster {
    dir: tempfile::TempDir,
    pid_files: Vec<PathBuf>,
}

impl Drop for Cluster {
    fn drop(&mut self) {
        for p in &self.pid_files {
            if let Ok(pid) = std::fs::read_to_string(p) {
                let _ = Command::new("kill").arg(pid.trim()).status();
            }
        }
    }
}

impl Cluster {
    fn conf(&self) -> PathBuf {
        self.dir.path().join("slurm.conf")
    }

    /// A Slurm command against this cluster.
    fn cmd(&self, program: &str) -> Command {
        let mut c = Command::new(program);
        c.env("SLURM_CONF", self.conf());
        c
    }
}

fn free_port() -> u16 {
    std::net::TcpListener::bind("127.0.0.1:0")
        .unwrap()
        .local_addr()
        .unwrap()
        .port()
}

fn found(program: &str) -> bool {
    std::env::var_os("PATH").is_some_and(|paths| {
        std::env::split_paths(&paths)
            .chain([PathBuf::from("/usr/sbin"), PathBuf::from("/sbin")])
            .any(|d| d.join(program).is_file())
    })
}

fn program(name: &str) -> PathBuf {
    for d in ["/usr/sbin", "/usr/bin", "/sbin", "/bin"] {
        let p = Path::new(d).join(name);
        if p.is_file() {
            return p;
        }
    }
    PathBuf::from(name)
}

/// Why the cluster cannot be started here, if it cannot.
fn missing() -> Option<String> {
    let lacking: Vec<&str> = [
        "munged",
        "slurmctld",
        "slurmd",
        "sbatch",
        "scontrol",
        "sinfo",
    ]
    .into_iter()
    .filter(|p| !found(p))
    .collect();
    if !lacking.is_empty() {
        return Some(format!(
            "{} not installed (scripts/bootstrap.sh installs slurmctld, slurmd, slurm-client and munge)",
            lacking.join(", ")
        ));
    }
    let uid = Command::new("id").arg("-u").output().ok()?;
    if String::from_utf8_lossy(&uid.stdout).trim() != "0" {
        return Some("not root: slurmd must run as root".into());
    }
    None
}

/// Starts munged, slurmctld and slurmd, and waits for the node to be idle.
fn start() -> Cluster {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path().to_path_buf();
    let d = d.as_path();
    for sub in ["state", "spool", "munge", "log"] {
        std::fs::create_dir_all(d.join(sub)).unwrap();
    }
    let host = String::from_utf8(Command::new("hostname").arg("-s").output().unwrap().stdout)
        .unwrap()
        .trim()
        .to_string();
    // A fresh munge key: 1 KiB of random bytes, readable by its owner only.
    let mut bytes = vec![0u8; 1024];
    {
        use std::io::Read as _;
        std::fs::File::open("/dev/urandom")
            .unwrap()
            .read_exact(&mut bytes)
            .unwrap();
    }
    let key_file = d.join("munge/munge.key");
    std::fs::write(&key_file, bytes).unwrap();
    {
        use std::os::unix::fs::PermissionsExt as _;
        std::fs::set_permissions(&key_file, std::fs::Permissions::from_mode(0o600)).unwrap();
    }
    let socket = d.join("munge/munge.socket");
    let p = |s: &str| d.join(s).display().to_string();
    let conf = format!(
        "ClusterName=geostridetest\nSlurmctldHost={host}(127.0.0.1)\nSlurmctldPort={}\nSlurmdPort={}\nSlurmUser=root\nSlurmdUser=root\nAuthType=auth/munge\nCredType=cred/munge\nAuthInfo=socket={}\nStateSaveLocation={}\nSlurmdSpoolDir={}\nSlurmctldPidFile={}\nSlurmdPidFile={}\nSlurmctldLogFile={}\nSlurmdLogFile={}\nProctrackType=proctrack/linuxproc\nTaskPlugin=task/none\nSelectType=select/cons_tres\nSelectTypeParameters=CR_Core\nMpiDefault=none\nReturnToService=2\nJobCompType=jobcomp/none\nJobAcctGatherType=jobacct_gather/none\nAccountingStorageType=accounting_storage/none\nMailProg=/bin/true\nPlugStackConfig=/dev/null\nNodeName={host} NodeAddr=127.0.0.1 CPUs=2 RealMemory=2000 State=UNKNOWN\nPartitionName=test Nodes=ALL Default=YES MaxTime=INFINITE State=UP\n",
        free_port(),
        free_port(),
        socket.display(),
        p("state"),
        p("spool"),
        p("slurmctld.pid"),
        p("slurmd.pid"),
        p("log/slurmctld.log"),
        p("log/slurmd.log"),
    );
    std::fs::write(d.join("slurm.conf"), conf).unwrap();
    let cluster = Cluster {
        pid_files: vec![
            d.join("slurmd.pid"),
            d.join("slurmctld.pid"),
            d.join("munge/munged.pid"),
        ],
        dir,
    };
    let started = Instant::now();
    let st = Command::new(program("munged"))
        .arg("--force")
        .arg(format!("--socket={}", socket.display()))
        .arg(format!("--key-file={}", key_file.display()))
        .arg(format!("--pid-file={}", p("munge/munged.pid")))
        .arg(format!("--log-file={}", p("munge/munged.log")))
        .arg(format!("--seed-file={}", p("munge/seed")))
        .status()
        .unwrap();
    assert!(st.success(), "munged did not start");
    let st = cluster
        .cmd(program("slurmctld").to_str().unwrap())
        .args(["-c", "-i"])
        .status()
        .unwrap();
    assert!(st.success(), "slurmctld did not start");
    let st = cluster
        .cmd(program("slurmd").to_str().unwrap())
        .arg("-c")
        .status()
        .unwrap();
    assert!(st.success(), "slurmd did not start");
    loop {
        let o = cluster
            .cmd("sinfo")
            .args(["-h", "-o", "%t"])
            .output()
            .unwrap();
        if String::from_utf8_lossy(&o.stdout).trim() == "idle" {
            break;
        }
        assert!(
            started.elapsed() < Duration::from_secs(30),
            "the node is not idle after 30 s: {}",
            std::fs::read_to_string(d.join("log/slurmctld.log")).unwrap_or_default()
        );
        std::thread::sleep(Duration::from_millis(100));
    }
    eprintln!(
        "slurm: one-node cluster up in {:.2} s",
        started.elapsed().as_secs_f64()
    );
    cluster
}

#[test]
fn a_split_run_on_a_slurm_cluster_gives_the_bytes_of_run() {
    if let Some(why) = missing() {
        if std::env::var_os("CI").is_some() {
            panic!("the Slurm test cannot run under CI: {why}");
        }
        eprintln!("skipped: {why}");
        return;
    }
    let tmp = tempfile::tempdir().unwrap();
    let dir = tmp.path();
    common::simulate_scene("hover-drift", dir);
    let project = common::chunked_deck_project(
        dir,
        "project.toml",
        "slurm test",
        "[\"csv\", \"petrack\", \"mot\"]",
        "[detect]\nkind = \"colour\"\ncolour = [255, 0, 255]\n",
    );
    let one = dir.join("run");
    assert_success(&common::run_project(&project, &one));

    let cluster = start();
    let split = dir.join("split");
    let o = geostride()
        .env("SLURM_CONF", cluster.conf())
        .arg("slurm")
        .arg(&project)
        .args([
            "--segments",
            "3",
            "--submit",
            "--partition",
            "test",
            "--time",
            "0:10:00",
            "--merge-time",
            "0:10:00",
            "--mem",
            "500M",
            "--merge-mem",
            "500M",
            "--cpus",
            "1",
            "-q",
            "--out",
        ])
        .arg(&split)
        .output()
        .unwrap();
    assert_success(&o);
    let said = String::from_utf8_lossy(&o.stdout).into_owned();
    let merge_job = said
        .split("merge as job ")
        .nth(1)
        .and_then(|s| s.split_whitespace().next())
        .unwrap_or_else(|| panic!("no merge job in: {said}"))
        .to_string();
    // Wait for the merge (it runs after every task of the array).
    let t0 = Instant::now();
    let state = loop {
        let o = cluster
            .cmd("scontrol")
            .args(["show", "job", &merge_job])
            .output()
            .unwrap();
        let text = String::from_utf8_lossy(&o.stdout).into_owned();
        let state = text
            .split("JobState=")
            .nth(1)
            .and_then(|s| s.split_whitespace().next())
            .unwrap_or("")
            .to_string();
        if [
            "COMPLETED",
            "FAILED",
            "CANCELLED",
            "TIMEOUT",
            "NODE_FAIL",
            "OUT_OF_MEMORY",
        ]
        .contains(&state.as_str())
        {
            break state;
        }
        assert!(
            t0.elapsed() < Duration::from_secs(300),
            "the merge job is {state} after 300 s"
        );
        std::thread::sleep(Duration::from_millis(200));
    };
    let log =
        |name: &str| std::fs::read_to_string(split.join("slurm").join(name)).unwrap_or_default();
    assert_eq!(
        state,
        "COMPLETED",
        "merge job: {state}\nmerge log:\n{}\nsegment 0 log:\n{}",
        log("merge.log"),
        log("segment-0.log")
    );
    eprintln!(
        "slurm: array of 3 segments and the merge done in {:.1} s",
        t0.elapsed().as_secs_f64()
    );
    for f in [
        "trajectories.csv",
        "tracks_mot.txt",
        "trajectories.txt",
        "pose/poses.csv",
    ] {
        assert!(
            std::fs::read(one.join(f)).unwrap() == std::fs::read(split.join(f)).unwrap(),
            "{f} differs between run and the Slurm run"
        );
    }
    assert!(log("merge.log").contains("Merged 3 segment(s)"));
    drop(cluster);
}
