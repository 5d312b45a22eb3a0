//! Bundle adjustment against Ceres Solver on the same BAL problem in the same run:
//! `$GEOSTRIDE_DATA/bal/problem-49-7776-pre.txt` (49 cameras, 7776 points, 31843 observations).
//! The peer is our own small program (`benches/ceres/ba_ceres.cc`) built against Debian's
//! libceres-dev: SPARSE_SCHUR, points eliminated first, 2 threads, Ceres's default tolerances,
//! as geostride's. Prints both final costs and the time ratio (target: geostride/Ceres ≤ 1.0).

use std::path::{Path, PathBuf};
use std::process::Command;

use geostride::optim::ba::BaSettings;
use geostride::optim::bal::bundle_adjust;
use geostride::optim::bal::read_bal;

const RUNS: usize = 3;

fn median(mut v: Vec<f64>) -> f64 {
    v.sort_by(f64::total_cmp);
    v[v.len() / 2]
}

/// Builds the Ceres program into target/ceres when its source is newer.
fn ceres_program(root: &Path) -> PathBuf {
    let src = root.join("benches/ceres/ba_ceres.cc");
    let exe = root.join("target/ceres/ba_ceres");
    let stale = match (std::fs::metadata(&src), std::fs::metadata(&exe)) {
        (Ok(s), Ok(e)) => s.modified().unwrap() > e.modified().unwrap(),
        _ => true,
    };
    if stale {
        std::fs::create_dir_all(exe.parent().unwrap()).unwrap();
        let status = Command::new("g++")
            .args(["-O2", "-std=c++17"])
            .arg(&src)
            .args([
                "-I/usr/include/eigen3",
                "-lceres",
                "-lglog",
                "-lgflags",
                "-lpthread",
                "-o",
            ])
            .arg(&exe)
            .status()
            .expect("g++ (scripts/bootstrap.sh --bench installs it with libceres-dev)");
        assert!(status.success(), "building {} failed", src.display());
    }
    exe
}

fn main() {
    let root = Path::new(env!("CARGO_MANIFEST_DIR"));
    let Some(data) = std::env::var_os("GEOSTRIDE_DATA") else {
        eprintln!("ba_vs_ceres: GEOSTRIDE_DATA is not set (make bench sets it to ../shared/data)");
        std::process::exit(1);
    };
    let file = PathBuf::from(data).join("bal/problem-49-7776-pre.txt");
    let problem = read_bal(&file).unwrap_or_else(|e| panic!("{e}"));
    let exe = ceres_program(root);
    let threads = std::thread::available_parallelism()
        .map_or(1, |n| n.get())
        .min(2);

    let (mut ours, mut theirs) = (Vec::new(), Vec::new());
    let (mut our_summary, mut their_json) = (None, serde_json::Value::Null);
    for _ in 0..RUNS {
        let mut p = problem.clone();
        let s = bundle_adjust(&mut p, &BaSettings::default()).unwrap_or_else(|e| panic!("{e}"));
        ours.push(s.seconds);
        our_summary = Some(s);
        let out = Command::new(&exe)
            .arg(&file)
            .arg(threads.to_string())
            .output()
            .expect("ba_ceres");
        assert!(
            out.status.success(),
            "{}",
            String::from_utf8_lossy(&out.stderr)
        );
        their_json = serde_json::from_slice(&out.stdout).expect("ba_ceres JSON");
        theirs.push(their_json["seconds"].as_f64().unwrap());
    }
    let s = our_summary.unwrap();
    let ceres_final = their_json["final_cost"].as_f64().unwrap();
    let (t_ours, t_theirs) = (median(ours.clone()), median(theirs.clone()));
    println!(
        "ba_vs_ceres: {} ({} cameras, {} points, {} observations; {threads} threads each)",
        file.display(),
        s.cameras,
        s.points,
        s.observations
    );
    println!(
        "  geostride  initial {:.7e}  final {:.10e}  {} iterations ({} accepted)  {:.3} s median of {:?}  {}",
        s.initial_cost,
        s.final_cost,
        s.iterations.len(),
        s.accepted_steps,
        t_ours,
        ours.iter().map(|t| format!("{t:.3}")).collect::<Vec<_>>(),
        s.termination
    );
    println!(
        "  Ceres      initial {:.7e}  final {:.10e}  {} iterations ({} successful steps)  {:.3} s median of {:?}  {} ({})",
        their_json["initial_cost"].as_f64().unwrap(),
        ceres_final,
        their_json["iterations"],
        their_json["successful_steps"],
        t_theirs,
        theirs.iter().map(|t| format!("{t:.3}")).collect::<Vec<_>>(),
        their_json["termination"].as_str().unwrap_or("?"),
        their_json["linear_solver"].as_str().unwrap_or("?")
    );
    let rel = (s.final_cost - ceres_final) / ceres_final;
    println!(
        "  final cost: geostride − Ceres = {:+.3e} relative (target: within 0.1 % or lower): {}",
        rel,
        if rel <= 1e-3 { "met" } else { "NOT met" }
    );
    let ratio = t_ours / t_theirs;
    println!(
        "  time: geostride / Ceres = {ratio:.2} (target ≤ 1.0): {}",
        if ratio <= 1.0 { "met" } else { "NOT met" }
    );
}
