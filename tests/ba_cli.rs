//! `geostride ba` on the real BAL problems in `$GEOSTRIDE_DATA/bal` (Agarwal et al.'s Ladybug
//! sequence, 49 cameras), and its errors.

#![cfg(all(feature = "opencv", feature = "gdal", feature = "onnx"))]

mod common;

use common::{data_dir, geostride};

fn ba_json(file: &std::path::Path, extra: &[&str]) -> serde_json::Value {
    let run = geostride()
        .arg("ba")
        .arg("--bal")
        .arg(file)
        .arg("--json")
        .args(extra)
        .output()
        .unwrap();
    common::assert_success(&run);
    serde_json::from_slice(&run.stdout).unwrap()
}

#[test]
fn ladybug_49_reproduces_the_initial_cost_and_converges() {
    let Some(dir) = data_dir("bal") else {
        return;
    };
    let s = ba_json(&dir.join("problem-49-7776-pre.txt"), &[]);
    let n = |k: &str| s[k].as_f64().unwrap_or_else(|| panic!("{k} in {s}"));
    println!(
        "initial {:e} final {:e} iterations {} in {:.3} s: {}",
        n("initial_cost"),
        n("final_cost"),
        s["iterations"].as_array().unwrap().len(),
        n("seconds"),
        s["termination"]
    );
    assert_eq!(
        (n("cameras"), n("points"), n("observations")),
        (49.0, 7776.0, 31843.0)
    );
    // The published initial cost, 8.509125e+05 (to its seven digits).
    assert!(
        (n("initial_cost") / 8.509125e5 - 1.0).abs() < 1e-7,
        "{}",
        n("initial_cost")
    );
    assert_ne!(s["termination"], "max_iterations");
    assert_ne!(s["termination"], "failure");
    // Down by a factor of 60 at least (other solvers stop near 1.3e4).
    assert!(n("final_cost") < 1.4e4, "{}", n("final_cost"));
    // Every accepted iteration lowers the cost.
    let mut last = n("initial_cost");
    for it in s["iterations"].as_array().unwrap() {
        if it["accepted"].as_bool().unwrap() {
            let c = it["cost"].as_f64().unwrap();
            assert!(c < last);
            last = c;
        }
    }
    assert_eq!(last, n("final_cost"));

    let s = ba_json(
        &dir.join("bal-ladybug-problem-49-7776-pre-shrink-1800.txt"),
        &["--max-iterations", "3"],
    );
    assert!((s["initial_cost"].as_f64().unwrap() / 2.345198e5 - 1.0).abs() < 1e-6);
    assert_eq!(s["iterations"].as_array().unwrap().len(), 3);
    assert_eq!(s["termination"], "max_iterations");
}

#[test]
fn ba_refuses_bad_input_with_a_reason() {
    let dir = tempfile::tempdir().unwrap();
    let bad = dir.path().join("bad.txt");
    std::fs::write(&bad, "1 1 1\n0 0 1.0 2.0\n0 0 0 0 0 -5 500 0 zero\n1 2 3\n").unwrap();
    let out = geostride()
        .args(["ba", "--bal"])
        .arg(&bad)
        .output()
        .unwrap();
    assert_eq!(out.status.code(), Some(2));
    let msg = String::from_utf8_lossy(&out.stderr);
    assert!(msg.contains("bad.txt:3: field 'camera 0 k2'"), "{msg}");
    let out = geostride()
        .args(["ba", "--loss", "tukey", "--bal"])
        .arg(&bad)
        .output()
        .unwrap();
    assert_eq!(out.status.code(), Some(2));
    assert!(String::from_utf8_lossy(&out.stderr).contains("--loss"));
}
