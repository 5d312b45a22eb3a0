//! `make fuzz`: the long fuzzing run (tests/fuzzing) and the large-input memory check.
//!
//! ```text
//! cargo run --release --example fuzz -- [--inputs N] [--target NAME] [--seed S] [--jobs J]
//! cargo run --release --example fuzz -- --big [--mb 200]
//! ```
//!
//! Without `--big`: every parser gets N inputs (10⁶ by default, `crs` too) in a child
//! process of its own, two at a time, so that a crash (a stack overflow aborts) is reported with
//! the parser and the inputs' range and does not stop the others. Prints inputs tried, results,
//! the slowest input and the peak heap per parser; exits 1 on a panic, crash, slow input (> 1 s),
//! a message that does not name the file or exceeds 8 kB, or a peak heap over 2 GB.
//!
//! With `--big`: each command that reads a file is given a file of about 200 MB (valid rows in
//! bulk, one huge line, one huge token, random bytes, deep nesting) and run as a child process;
//! its peak resident memory must stay under 2 GB and it must exit 0, 1 or 2, never by a signal
//! or a panic (101).

#[path = "../tests/fuzzing/mod.rs"]
mod fuzzing;

use std::io::Write;
use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};

#[global_allocator]
static ALLOC: fuzzing::Counting = fuzzing::Counting;

const LIMIT_BYTES: u64 = 2 << 30;

fn arg(args: &[String], name: &str) -> Option<String> {
    args.iter()
        .position(|a| a == name)
        .and_then(|i| args.get(i + 1).cloned())
}

fn main() {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let seed: u64 = arg(&args, "--seed")
        .and_then(|v| v.parse().ok())
        .unwrap_or(0x6E0_5712);
    if let Some(name) = arg(&args, "--child") {
        let first: u64 = arg(&args, "--first")
            .and_then(|v| v.parse().ok())
            .unwrap_or(0);
        let count: u64 = arg(&args, "--count")
            .and_then(|v| v.parse().ok())
            .unwrap_or(1000);
        child(&name, seed, first, count);
        return;
    }
    let ok = if args.iter().any(|a| a == "--big") {
        let mb: usize = arg(&args, "--mb")
            .and_then(|v| v.parse().ok())
            .unwrap_or(200);
        big(mb, arg(&args, "--case").as_deref())
    } else {
        let inputs: u64 = arg(&args, "--inputs")
            .and_then(|v| v.parse().ok())
            .unwrap_or(1_000_000);
        let jobs: usize = arg(&args, "--jobs")
            .and_then(|v| v.parse().ok())
            .unwrap_or(2);
        parsers(inputs, seed, jobs, arg(&args, "--target").as_deref())
    };
    std::process::exit(if ok { 0 } else { 1 });
}

/// Fuzzes one target in this process and prints its report as one line of JSON.
fn child(name: &str, seed: u64, first: u64, count: u64) {
    let targets = fuzzing::targets();
    let t = targets
        .iter()
        .find(|t| t.name == name)
        .expect("a target of that name");
    // In slices, so that a crash is placed within a slice.
    let slice = 10_000;
    let mut total = fuzzing::Report::default();
    let mut done = 0;
    while done < count {
        let n = slice.min(count - done);
        eprintln!("slice {} {}", first + done, n);
        let r = fuzzing::fuzz(t, seed, first + done, n);
        total.inputs += r.inputs;
        total.ok += r.ok;
        total.errors += r.errors;
        total.panics.extend(r.panics);
        total.bad_messages.extend(r.bad_messages);
        if r.slowest.1 > total.slowest.1 {
            total.slowest = r.slowest;
        }
        total.peak_bytes = total.peak_bytes.max(r.peak_bytes);
        total.seconds += r.seconds;
        done += n;
    }
    let json = serde_json::json!({
        "target": name,
        "inputs": total.inputs,
        "ok": total.ok,
        "errors": total.errors,
        "panics": total.panics.iter().take(5).map(|(i, m)| format!("{i}: {m}")).collect::<Vec<_>>(),
        "bad_messages": total.bad_messages.iter().take(5).map(|(i, m)| format!("{i}: {m}")).collect::<Vec<_>>(),
        "slowest_s": total.slowest.1,
        "slowest_index": total.slowest.0,
        "slowest_bytes": total.slowest.2,
        "peak_bytes": total.peak_bytes,
        "seconds": total.seconds,
    });
    println!("{json}");
}

/// Runs every target (or one) in child processes, `jobs` at a time.
fn parsers(inputs: u64, seed: u64, jobs: usize, only: Option<&str>) -> bool {
    let exe = std::env::current_exe().unwrap();
    let targets: Vec<(String, u64)> = fuzzing::targets()
        .iter()
        .filter(|t| only.is_none_or(|o| o == t.name))
        .map(|t| (t.name.to_string(), inputs))
        .collect();
    println!(
        "geostride fuzz: {} parsers, {inputs} inputs each, seed {seed:#x}, {jobs} at a time",
        targets.len()
    );
    println!(
        "{:<18} {:>9} {:>9} {:>9} {:>7} {:>7} {:>10} {:>10} {:>9}",
        "parser",
        "inputs",
        "ok",
        "errors",
        "panics",
        "crashes",
        "slowest ms",
        "peak heap",
        "seconds"
    );
    let mut ok = true;
    let mut queue = targets.into_iter();
    let mut running: Vec<(String, u64, std::process::Child, PathBuf)> = Vec::new();
    let dir = std::env::temp_dir().join(format!("geostride-fuzz-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    loop {
        while running.len() < jobs {
            let Some((name, n)) = queue.next() else { break };
            let log = dir.join(format!("{name}.log"));
            let c = Command::new(&exe)
                .args([
                    "--child",
                    &name,
                    "--count",
                    &n.to_string(),
                    "--seed",
                    &seed.to_string(),
                ])
                .stdout(Stdio::piped())
                .stderr(std::fs::File::create(&log).unwrap())
                .spawn()
                .unwrap();
            running.push((name, n, c, log));
        }
        if running.is_empty() {
            break;
        }
        // Whichever child ends first (a slow parser must not hold the other slot).
        let done = loop {
            if let Some(i) = running
                .iter_mut()
                .position(|r| r.2.try_wait().ok().flatten().is_some())
            {
                break i;
            }
            std::thread::sleep(std::time::Duration::from_millis(200));
        };
        let (name, n, c, log) = running.remove(done);
        let out = c.wait_with_output().unwrap();
        let line = String::from_utf8_lossy(&out.stdout).trim().to_string();
        match serde_json::from_str::<serde_json::Value>(&line) {
            Ok(v) if out.status.success() => {
                let panics = v["panics"].as_array().map_or(0, Vec::len);
                let bad = v["bad_messages"].as_array().map_or(0, Vec::len);
                let slow = v["slowest_s"].as_f64().unwrap_or(0.0);
                let peak = v["peak_bytes"].as_u64().unwrap_or(0);
                println!(
                    "{:<18} {:>9} {:>9} {:>9} {:>7} {:>7} {:>10.1} {:>7.1} MB {:>9.0}",
                    name,
                    v["inputs"],
                    v["ok"],
                    v["errors"],
                    panics,
                    0,
                    slow * 1e3,
                    peak as f64 / 1e6,
                    v["seconds"].as_f64().unwrap_or(0.0)
                );
                if panics > 0 || bad > 0 || slow > 1.0 || peak > LIMIT_BYTES {
                    ok = false;
                    println!("  FAILED: {v}");
                }
                let _ = n;
            }
            _ => {
                ok = false;
                let log = std::fs::read_to_string(&log).unwrap_or_default();
                let last = log
                    .lines()
                    .rev()
                    .find(|l| l.starts_with("slice"))
                    .unwrap_or("");
                println!(
                    "{name:<18} CRASHED ({}) in inputs {last}: {}",
                    out.status,
                    log.lines().rev().take(3).collect::<Vec<_>>().join(" | ")
                );
            }
        }
        std::io::stdout().flush().unwrap();
    }
    let _ = std::fs::remove_dir_all(&dir);
    println!(
        "{}",
        if ok {
            "fuzz: no panic, crash, slow input, bad message or runaway heap"
        } else {
            "fuzz: FAILED"
        }
    );
    ok
}

/// Peak resident memory (bytes) and exit of a command, by `wait4`.
fn measured(cmd: &mut Command) -> (u64, Option<i32>, Option<i32>, String) {
    let err = tempfile::NamedTempFile::new().unwrap();
    let child = cmd
        .stdout(Stdio::null())
        .stderr(err.reopen().unwrap())
        .spawn()
        .unwrap();
    let mut status = 0;
    let mut usage: libc::rusage = unsafe { std::mem::zeroed() };
    let pid = child.id() as libc::pid_t;
    unsafe { libc::wait4(pid, &mut status, 0, &mut usage) };
    std::mem::forget(child);
    let code = libc::WIFEXITED(status).then(|| libc::WEXITSTATUS(status));
    let signal = libc::WIFSIGNALED(status).then(|| libc::WTERMSIG(status));
    let stderr = std::fs::read_to_string(err.path()).unwrap_or_default();
    (usage.ru_maxrss as u64 * 1024, code, signal, stderr)
}

/// Writes about `bytes` of `line` repeated (after `head`).
fn bulk(path: &Path, head: &str, line: &str, bytes: usize) {
    let mut f = std::io::BufWriter::new(std::fs::File::create(path).unwrap());
    f.write_all(head.as_bytes()).unwrap();
    let mut n = head.len();
    let mut k = 0u64;
    while n < bytes {
        let l = line.replace("{k}", &k.to_string());
        f.write_all(l.as_bytes()).unwrap();
        n += l.len();
        k += 1;
    }
}

fn big(mb: usize, only: Option<&str>) -> bool {
    let bytes = mb << 20;
    let root = Path::new(env!("CARGO_MANIFEST_DIR"));
    let exe = root.join("target/release/geostride");
    assert!(exe.is_file(), "build geostride first (make build)");
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    // A small valid project beside the big files.
    let sim = Command::new(&exe)
        .arg("simulate")
        .arg(root.join("tests/scenes/hover-drift.toml"))
        .arg("--out")
        .arg(d.join("p"))
        .args(["--duration", "1", "-q"])
        .status()
        .unwrap();
    assert!(sim.success());
    let p = d.join("p");
    let video = if p.join("video.mp4").is_file() {
        "video.mp4"
    } else {
        "video.avi"
    };
    let project = |extra: &str| {
        format!(
            "[camera]\ncalibration = \"mini3pro\"\n[survey]\ngcps = \"gcps.csv\"\npicks = [\"picks.csv\"]\nheight = \"ellipsoidal\"\n[video]\npath = \"{video}\"\n[ground]\nkind = \"plane\"\n{extra}[export]\nformats = [\"csv\"]\n"
        )
    };
    let emlid_head = std::fs::read_to_string(p.join("gcps.csv")).unwrap();
    let emlid_row = emlid_head
        .lines()
        .nth(1)
        .unwrap()
        .replacen("GCP1", "P{k}", 1)
        + "\n";
    let emlid_head = emlid_head.lines().next().unwrap().to_string() + "\n";

    // Each case: its name, the big file (name, header, row repeated with {k} its number, tail),
    // and the command's arguments: `@` is the big file, `@video` the video, `@/NAME` a path in
    // the case's folder.
    struct Big {
        name: &'static str,
        file: &'static str,
        head: String,
        row: String,
        tail: &'static str,
        args: &'static str,
    }
    let big = |name, file, head: &str, row: &str, tail, args| Big {
        name,
        file,
        head: head.to_string(),
        row: row.to_string(),
        tail,
        args,
    };
    let boxes_args = "track @video --detect boxes --boxes @ --px-per-m 30 --out @/t -q";
    let cases = [
        big(
            "survey: rows",
            "big.csv",
            &emlid_head,
            &emlid_row,
            "",
            "survey inspect @",
        ),
        big(
            "survey: one line",
            "big.csv",
            "Name,Easting\n",
            "9,",
            "",
            "survey inspect @",
        ),
        big(
            "survey: one token",
            "big.txt",
            "EPSG:32631\n1 ",
            "9",
            "",
            "survey inspect @",
        ),
        big(
            "survey: random bytes",
            "big.bin",
            "",
            "",
            "",
            "survey inspect @",
        ),
        big(
            "survey: OpenSfM JSON",
            "big.json",
            "{\"points\": [",
            "{\"id\": \"p{k}\", \"position\": {\"latitude\": 50.8, \"longitude\": 4.35, \"altitude\": 52}, \"observations\": []},",
            "{\"id\": \"last\", \"position\": {\"latitude\": 50.8, \"longitude\": 4.35}, \"observations\": []}]}",
            "survey inspect @",
        ),
        big(
            "picks: rows",
            "picks.csv",
            "name,image,u,v\n",
            "GCP1,img{k}.jpg,100.5,200.25\n",
            "",
            "survey inspect @/gcps.csv --picks @",
        ),
        big(
            "calibration: YAML",
            "cam.yaml",
            "%YAML:1.0\n---\n",
            "k{k}: 1\n",
            "",
            "camera show @",
        ),
        big(
            "calibration: nesting",
            "cam.json",
            "",
            "[",
            "",
            "camera show @",
        ),
        big(
            "project",
            "project.toml",
            "name = \"x\"\n",
            "# {k}\n",
            "",
            "run @ -q",
        ),
        big(
            "scene",
            "scene.toml",
            "name = \"x\"\n",
            "# {k}\n",
            "",
            "simulate @ --out @/sim",
        ),
        big(
            "boxes: MOT rows",
            "boxes.txt",
            "",
            "1{k},-1,100.5,100.25,40,80,0.9\n",
            "",
            boxes_args,
        ),
        big(
            "boxes: JSON Lines",
            "boxes.jsonl",
            "",
            "{\"frame\": {k}, \"bbox\": [1.5, 2.5, 30, 60], \"score\": 0.9}\n",
            "",
            boxes_args,
        ),
        big(
            "boxes: COCO",
            "boxes.json",
            "[",
            "{\"image_id\": {k}, \"category_id\": 1, \"bbox\": [1.5, 2.5, 30, 60], \"score\": 0.9},",
            "{\"image_id\": 0, \"category_id\": 1, \"bbox\": [1, 2, 3, 4], \"score\": 0.5}]",
            boxes_args,
        ),
        big(
            "BAL: a large problem",
            "big.bal",
            "",
            "",
            "",
            "ba --bal @ --max-iterations 2",
        ),
        big(
            "BAL: huge counts",
            "big.bal",
            "1000000000 1000000000 1000000000\n",
            "0 0 1.5 2.5\n",
            "",
            "ba --bal @",
        ),
        big(
            "evaluate: rows",
            "truth.csv",
            "frame,person,e_m,n_m\n",
            "{k},1,1.5,2.5\n",
            "",
            "evaluate --truth @ --tracks @ --tracks-columns frame,person,e_m,n_m",
        ),
        big(
            "fit-error: one frame",
            "heads.csv",
            "frame,x_px,y_px\n",
            "0,{k}.5,10\n",
            "",
            "fit-error --detections @ --annotations @ --annotation-columns frame,x_px,y_px --width 1920",
        ),
        big(
            "fit-error: rows",
            "heads.csv",
            "frame,u_px,v_px\n",
            "{k},1.5,2.5\n",
            "",
            "fit-error --detections @ --annotations @ --annotation-columns frame,u_px,v_px --width 1920",
        ),
        big(
            "heights: rows",
            "heights.csv",
            "id,height_m\n",
            "{k},1.75\n",
            "",
            "run @/project-heights.toml --out @/run -q",
        ),
    ];
    // Writes a case's big file into `f` and gives its arguments.
    let setup = |c: &Big, f: &Path| -> Vec<String> {
        let path = f.join(c.file);
        match (c.name, c.row.is_empty()) {
            ("BAL: a large problem", _) => big_bal(&path, bytes),
            (_, true) => {
                // Random bytes (xorshift).
                let mut v = vec![0u8; bytes];
                let mut x: u64 = 1;
                for b in v.iter_mut() {
                    x ^= x << 13;
                    x ^= x >> 7;
                    x ^= x << 17;
                    *b = x as u8;
                }
                std::fs::write(&path, v).unwrap();
            }
            _ => {
                bulk(&path, &c.head, &c.row, bytes);
                let mut t = std::fs::OpenOptions::new()
                    .append(true)
                    .open(&path)
                    .unwrap();
                t.write_all(c.tail.as_bytes()).unwrap();
            }
        }
        c.args
            .split(' ')
            .map(|a| match a {
                "@" => path.display().to_string(),
                "@video" => p_video(f),
                _ => match a.strip_prefix("@/") {
                    Some(rest) => f.join(rest).display().to_string(),
                    None => a.to_string(),
                },
            })
            .collect()
    };
    fn p_video(f: &Path) -> String {
        for v in ["video.mp4", "video.avi"] {
            if f.join(v).is_file() {
                return f.join(v).display().to_string();
            }
        }
        unreachable!("the simulated video")
    }
    println!("geostride fuzz --big: inputs of {mb} MB; peak resident memory must stay under 2 GB");
    println!(
        "{:<24} {:>10} {:>6} {:>10}  message",
        "case", "file MB", "exit", "peak MB"
    );
    let mut ok = true;
    for case in cases
        .iter()
        .filter(|c| only.is_none_or(|o| c.name.starts_with(o)))
    {
        let name = case.name;
        let f = d.join(name.replace([' ', ':'], "_"));
        std::fs::create_dir_all(&f).unwrap();
        for e in std::fs::read_dir(&p).unwrap().flatten() {
            if e.path().is_file() {
                std::fs::copy(e.path(), f.join(e.file_name())).unwrap();
            }
        }
        std::fs::write(f.join("project.toml"), project("")).unwrap();
        std::fs::write(
            f.join("project-heights.toml"),
            project("[projection]\nheights = \"heights.csv\"\n"),
        )
        .unwrap();
        let args = setup(case, &f);
        let size: u64 = std::fs::read_dir(&f)
            .unwrap()
            .flatten()
            .map(|e| e.metadata().map(|m| m.len()).unwrap_or(0))
            .max()
            .unwrap_or(0);
        let t0 = std::time::Instant::now();
        let (peak, code, signal, stderr) = measured(Command::new(&exe).args(&args).current_dir(&f));
        let first = stderr
            .lines()
            .find(|l| l.starts_with("error"))
            .unwrap_or("")
            .chars()
            .take(110)
            .collect::<String>();
        let good = signal.is_none() && matches!(code, Some(0..=2)) && peak < LIMIT_BYTES;
        println!(
            "{:<24} {:>10.0} {:>6} {:>10.0}  {:.1} s {}{}",
            name,
            size as f64 / 1e6,
            code.map_or(format!("sig{}", signal.unwrap_or(0)), |c| c.to_string()),
            peak as f64 / 1e6,
            t0.elapsed().as_secs_f64(),
            first,
            if good { "" } else { "  <-- FAILED" }
        );
        ok &= good;
        let _ = std::fs::remove_dir_all(&f);
    }
    println!(
        "{}",
        if ok {
            "fuzz --big: every command stayed under 2 GB and exited 0, 1 or 2"
        } else {
            "fuzz --big: FAILED"
        }
    );
    ok
}

/// A valid BAL problem of about `bytes`: 20 cameras around 1 point cloud, each point seen by
/// every camera.
fn big_bal(path: &Path, bytes: usize) {
    let cams = 20usize;
    // An observation line is ~30 bytes, a point ~30: 20 observations and a point per point.
    let points = bytes / (cams * 30 + 30);
    let mut f = std::io::BufWriter::new(std::fs::File::create(path).unwrap());
    writeln!(f, "{cams} {points} {}", cams * points).unwrap();
    for p in 0..points {
        for c in 0..cams {
            let (u, v) = (
                (p % 997) as f64 * 0.3 - 150.0 + c as f64,
                (p % 991) as f64 * 0.2 - 100.0,
            );
            writeln!(f, "{c} {p} {u:.3} {v:.3}").unwrap();
        }
    }
    for c in 0..cams {
        let a = c as f64 * 0.05;
        writeln!(f, "{a}\n0.01\n0.02\n{}\n0.1\n-10\n500\n0\n0", a * 2.0).unwrap();
    }
    for p in 0..points {
        writeln!(
            f,
            "{:.3}\n{:.3}\n{:.3}",
            (p % 997) as f64 * 0.006 - 3.0,
            (p % 991) as f64 * 0.004 - 2.0,
            (p % 13) as f64 * 0.01
        )
        .unwrap();
    }
}
