//! `geostride track`: background subtraction and KLT on real footage (OpenCV's vtest.avi, a
//! fixed camera over a pedestrian street), and its errors.

#![cfg(all(feature = "opencv", feature = "gdal", feature = "onnx"))]

mod common;

use common::{data_dir, geostride};

#[test]
fn vtest_goes_through_background_detection_and_klt() {
    let Some(dir) = data_dir("video") else {
        return;
    };
    let video = dir.join("vtest_480x360_h264.avi");
    let out = tempfile::tempdir().unwrap();
    // People there are 25–40 px tall: about 20 px per metre.
    let run = geostride()
        .arg("track")
        .arg(&video)
        .args([
            "--px-per-m",
            "20",
            "--min-area-m2",
            "0.2",
            "--max-area-m2",
            "6",
        ])
        .arg("--out")
        .arg(out.path())
        .arg("--json")
        .output()
        .unwrap();
    common::assert_success(&run);
    let report: serde_json::Value = serde_json::from_slice(&run.stdout).unwrap();
    println!("{}", serde_json::to_string_pretty(&report).unwrap());
    let n = |k: &str| {
        report[k]
            .as_f64()
            .unwrap_or_else(|| panic!("{k} in {report}"))
    };
    assert_eq!(n("frames"), 795.0);
    assert!(n("detections") > 2000.0, "{}", n("detections"));
    // Dozens of people cross the street in 80 s; tracks of a second or more.
    assert!((30.0..300.0).contains(&n("tracks")), "{}", n("tracks"));
    assert!(n("mean_track_length_s") > 1.0);
    // The files hold what the report says.
    let mot = std::fs::read_to_string(out.path().join("tracks_mot.txt")).unwrap();
    assert_eq!(mot.lines().count() as f64, n("track_points"));
    let ids: std::collections::BTreeSet<&str> =
        mot.lines().map(|l| l.split(',').nth(1).unwrap()).collect();
    assert_eq!(ids.len() as f64, n("tracks"));
    for l in mot.lines() {
        let f: Vec<f64> = l.split(',').map(|x| x.parse().unwrap()).collect();
        assert!(
            f[0] >= 1.0 && f[0] <= 795.0 && f[4] > 0.0 && f[5] > 0.0,
            "{l}"
        );
    }
    let csv = std::fs::read_to_string(out.path().join("tracks.csv")).unwrap();
    assert_eq!(csv.lines().count() as f64, n("track_points") + 1.0);
}

#[test]
fn track_refuses_bad_input_with_a_reason() {
    let out = tempfile::tempdir().unwrap();
    let missing = geostride()
        .args(["track", "no-such-video.mp4", "--px-per-m", "20", "--out"])
        .arg(out.path())
        .output()
        .unwrap();
    assert_eq!(missing.status.code(), Some(2));
    assert!(String::from_utf8_lossy(&missing.stderr).contains("no-such-video.mp4"));
    let no_boxes = geostride()
        .args([
            "track",
            "video.mp4",
            "--px-per-m",
            "20",
            "--detect",
            "boxes",
            "--out",
        ])
        .arg(out.path())
        .output()
        .unwrap();
    assert_eq!(no_boxes.status.code(), Some(2));
    assert!(String::from_utf8_lossy(&no_boxes.stderr).contains("--boxes FILE"));
    let bad_scale = geostride()
        .args(["track", "video.mp4", "--px-per-m", "-3", "--out"])
        .arg(out.path())
        .output()
        .unwrap();
    assert_eq!(bad_scale.status.code(), Some(2));
    // Nothing was written.
    assert_eq!(std::fs::read_dir(out.path()).unwrap().count(), 0);
}
