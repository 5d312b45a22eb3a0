//! `geostride detect`: the bundled YOLOv3-tiny through ONNX Runtime on real video (PETS 2009's
//! `vtest`), its boxes tracked by `geostride track`, the same boxes through OpenCV's dnn, and
//! the errors for a missing library, a file that is not ONNX, a layout and classes that do not
//! fit the model.

#![cfg(all(feature = "opencv", feature = "gdal", feature = "onnx"))]

mod common;

use std::path::{Path, PathBuf};

use common::geostride;
use geostride::detect::neural::{NeuralDetector, NeuralSettings};

/// The bundled model; outside CI its absence skips (with a message), in CI it fails.
fn bundled() -> Option<PathBuf> {
    match geostride::detect::onnx::bundled_model() {
        Some(p) => Some(p),
        None => {
            let in_ci = std::env::var("CI").is_ok_and(|v| v == "true" || v == "1");
            assert!(
                !in_ci,
                "the bundled model is missing in CI: scripts/fetch-models.sh (make test runs it)"
            );
            eprintln!("SKIPPED: no bundled model; run ./scripts/fetch-models.sh");
            None
        }
    }
}

fn vtest() -> Option<PathBuf> {
    common::data_dir("video").map(|d| d.join("vtest_480x360_h264.avi"))
}

fn s(p: &Path) -> String {
    p.to_str().unwrap().to_string()
}

#[test]
fn the_bundled_model_finds_the_walkers_of_a_real_video_and_they_are_tracked() {
    let (Some(_), Some(video)) = (bundled(), vtest()) else {
        return;
    };
    let tmp = tempfile::tempdir().unwrap();
    let boxes = tmp.path().join("boxes.txt");
    let preview = tmp.path().join("preview.png");
    let run = |out: &Path, preview: Option<&Path>| {
        let mut args = vec![
            "detect".to_string(),
            s(&video),
            "--model".into(),
            "yolov3-tiny".into(),
            "--out".into(),
            s(out),
            "--max-frames".into(),
            "200".into(),
            "--json".into(),
        ];
        if let Some(p) = preview {
            args.extend([
                "--preview".into(),
                s(p),
                "--preview-frame".into(),
                "100".into(),
            ]);
        }
        let o = geostride().args(&args).output().unwrap();
        common::assert_success(&o);
        serde_json::from_slice::<serde_json::Value>(&o.stdout).unwrap()
    };
    let r = run(&boxes, Some(&preview));
    let mean = r["mean_per_frame"].as_f64().unwrap();
    eprintln!("vtest: {r}");
    // PETS 2009's walkers: typically 5 to 8 in view, the farthest small.
    assert_eq!(r["frames"], 200);
    assert!((4.0..=9.0).contains(&mean), "{mean} a frame");
    assert!(preview.is_file());
    // The same boxes on a second run.
    let again = tmp.path().join("again.txt");
    run(&again, None);
    assert_eq!(
        std::fs::read(&boxes).unwrap(),
        std::fs::read(&again).unwrap()
    );
    // Tracked from those boxes with KLT.
    let o = geostride()
        .args([
            "track",
            &s(&video),
            "--detect",
            "boxes",
            "--boxes",
            &s(&boxes),
            "--px-per-m",
            "40",
            "--no-split",
            "--max-frames",
            "200",
            "--out",
            &s(&tmp.path().join("tracks")),
            "--json",
        ])
        .output()
        .unwrap();
    common::assert_success(&o);
    let t: serde_json::Value = serde_json::from_slice(&o.stdout).unwrap();
    eprintln!("track: {t}");
    let tracks = common::read_csv(&tmp.path().join("tracks/tracks.csv"));
    let ids: std::collections::BTreeSet<&str> = tracks.iter().map(|r| r["id"].as_str()).collect();
    assert!(ids.len() >= 4, "{} tracks", ids.len());
}

#[test]
fn onnx_runtime_and_opencv_dnn_give_the_same_boxes() {
    let (Some(model), Some(video)) = (bundled(), vtest()) else {
        return;
    };
    for tile in [0, 240] {
        let settings = NeuralSettings {
            tile,
            ..NeuralSettings::default()
        };
        let mut ort = NeuralDetector::load(&model, &settings).unwrap();
        let mut cv = ort.on_opencv().unwrap();
        let mut reader = geostride::video::source::FrameReader::open(&video).unwrap();
        let (mut n, mut worst_px, mut worst_score): (usize, f64, f64) = (0, 0.0, 0.0);
        while let Some((i, bgr, w, h)) = reader.next_bgr_bytes().unwrap() {
            if i >= 60 {
                break;
            }
            if i % 10 != 0 {
                continue;
            }
            let a = ort.detect(&bgr, [w, h]).unwrap();
            let b = cv.detect(&bgr, [w, h]).unwrap();
            assert_eq!(a.len(), b.len(), "frame {i}: {a:?} vs {b:?}");
            for (x, y) in a.iter().zip(&b) {
                for k in 0..4 {
                    worst_px = worst_px.max((x.xywh[k] - y.xywh[k]).abs());
                }
                worst_score = worst_score.max((x.score - y.score).abs());
            }
            n += a.len();
        }
        eprintln!("tile {tile}: {n} boxes, worst {worst_px:.2e} px, score {worst_score:.2e}");
        assert!(n > 20);
        assert!(
            worst_px <= 1.0 && worst_score <= 1e-3,
            "{worst_px} px, {worst_score}"
        );
    }
}

#[test]
fn a_model_that_cannot_be_used_is_an_input_error() {
    let (Some(_), Some(video)) = (bundled(), vtest()) else {
        return;
    };
    let tmp = tempfile::tempdir().unwrap();
    let not_onnx = tmp.path().join("model.onnx");
    std::fs::write(&not_onnx, "not a model").unwrap();
    let out = s(&tmp.path().join("b.txt"));
    let cases: [(&[&str], Option<&str>, &str); 4] = [
        (&["--model", &s(&not_onnx)], None, "not an ONNX model"),
        (&["--classes", "pedestrian"], None, "no class 'pedestrian'"),
        (
            &["--model", "yolov3-tiny", "--layout", "yolov8"],
            None,
            "do not fit the yolov8 layout",
        ),
        (
            &[],
            Some("/nowhere/libonnxruntime.so"),
            "cannot load ONNX Runtime",
        ),
    ];
    for (extra, lib, expect) in cases {
        let mut c = geostride();
        c.args([
            "detect",
            &s(&video),
            "--out",
            &out,
            "--max-frames",
            "2",
            "-q",
        ])
        .args(extra);
        if let Some(l) = lib {
            c.env("GEOSTRIDE_ONNXRUNTIME", l);
        }
        let o = c.output().unwrap();
        let err = String::from_utf8_lossy(&o.stderr);
        assert_eq!(o.status.code(), Some(2), "{extra:?}: {err}");
        assert!(err.contains(expect), "{extra:?}: {err}");
        assert!(!Path::new(&out).exists(), "{extra:?} left an output");
    }
}

#[test]
fn the_crowd_demo_runs_with_the_onnx_detector_and_reports_what_it_gets() {
    if bundled().is_none() {
        return;
    }
    let tmp = tempfile::tempdir().unwrap();
    let o = geostride()
        .current_dir(env!("CARGO_MANIFEST_DIR"))
        .args([
            "demo",
            "--crowd",
            "--detector",
            "onnx",
            "--duration",
            "1",
            "--out",
            &s(tmp.path()),
            "--json",
            "-q",
        ])
        .output()
        .unwrap();
    common::assert_success(&o);
    let r: serde_json::Value = serde_json::from_slice(&o.stdout).unwrap();
    eprintln!("{}", r["evaluation"]);
    // Whatever it finds is reported: the evaluation is there, and the project ran the model.
    assert!(r["evaluation"]["truth_tracks"].as_u64().unwrap() > 0);
    let project =
        std::fs::read_to_string(tmp.path().join("marathon-stream/project-onnx.toml")).unwrap();
    assert!(project.contains("kind = \"onnx\""));
}
