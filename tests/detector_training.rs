//! The overhead detector's training recipe, in a few steps (`make model` runs it whole): tiles
//! from `geostride dataset`, `scripts/train_detector.py` on them, and the model it exports read
//! back by `geostride detect` through its metadata. Needs Debian's python3-torch, python3-pil
//! and python3-onnx (`scripts/bootstrap.sh` installs them); in CI their absence is a failure.

#![cfg(all(feature = "opencv", feature = "gdal", feature = "onnx"))]

mod common;

use std::path::Path;
use std::process::Command;

/// Debian's Python, where the packages are (another python3 may come first on the PATH).
const PYTHON: &str = "/usr/bin/python3";

fn has_torch() -> bool {
    let ok = Command::new(PYTHON)
        .args(["-c", "import torch, PIL, onnx"])
        .output()
        .is_ok_and(|o| o.status.success());
    if !ok {
        let in_ci = std::env::var("CI").is_ok_and(|v| v == "true" || v == "1");
        assert!(
            !in_ci,
            "python3-torch, python3-pil and python3-onnx are missing: scripts/bootstrap.sh installs them"
        );
        eprintln!(
            "SKIPPED: needs python3-torch, python3-pil, python3-onnx (make test installs them)"
        );
    }
    ok
}

fn dataset(out: &Path, seed: &str, tiles: &str) {
    let o = common::geostride()
        .args([
            "dataset", "--size", "128", "--tiles", tiles, "--seed", seed, "-q", "--out",
        ])
        .arg(out)
        .output()
        .unwrap();
    common::assert_success(&o);
}

#[test]
fn a_few_training_steps_give_a_model_geostride_reads() {
    if !has_torch() {
        return;
    }
    let tmp = tempfile::tempdir().unwrap();
    let (train, val) = (tmp.path().join("train"), tmp.path().join("val"));
    dataset(&train, "11", "16");
    dataset(&val, "12", "8");
    let model = tmp.path().join("model.onnx");
    let report = tmp.path().join("report.json");
    let root = Path::new(env!("CARGO_MANIFEST_DIR"));
    let o = Command::new(PYTHON)
        .arg(root.join("scripts/train_detector.py"))
        .args([
            "--batch",
            "4",
            "--max-steps",
            "3",
            "--threads",
            "1",
            "--train",
        ])
        .arg(&train)
        .arg("--val")
        .arg(&val)
        .arg("--val-all")
        .arg(&val)
        .arg("--out")
        .arg(&model)
        .arg("--report")
        .arg(&report)
        .output()
        .unwrap();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let r: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(&report).unwrap()).unwrap();
    assert_eq!(r["steps"], 3);
    // The same validation split as a training run's, per ground sample distance and view.
    assert_eq!(r["by"]["gsd_m"].as_array().unwrap().len(), 4);
    assert!(r["all_scales"]["recall"].is_number());
    let boxes = tmp.path().join("boxes.txt");
    let o = common::geostride()
        .arg("detect")
        .arg(val.join("images/0000000.jpg"))
        .arg("--model")
        .arg(&model)
        .arg("--out")
        .arg(&boxes)
        .args(["--input-size", "128x128", "--json", "-q"])
        .output()
        .unwrap();
    common::assert_success(&o);
    let j: serde_json::Value = serde_json::from_slice(&o.stdout).unwrap();
    assert_eq!(
        j["layout"], "centre_heatmap",
        "read from the model's metadata"
    );
    // It states the scales it was trained at: the frame is seen at its own scale.
    assert_eq!(j["frame_scale"], 1.0);
    // The suppression chosen on the validation set is the model's, and geostride uses it.
    let chosen = r["nms_contained"].as_f64().unwrap();
    assert!(chosen > 0.0 && chosen <= 1.0, "{chosen}");
    assert_eq!(j["nms_contained"].as_f64(), Some(chosen));
    // A training set and a validation set of one seed are refused.
    let o = Command::new(PYTHON)
        .arg(root.join("scripts/train_detector.py"))
        .arg("--train")
        .arg(&train)
        .arg("--val")
        .arg(&train)
        .arg("--out")
        .arg(tmp.path().join("x.onnx"))
        .output()
        .unwrap();
    assert!(!o.status.success());
    assert!(String::from_utf8_lossy(&o.stderr).contains("another seed"));
}
