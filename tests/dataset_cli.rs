//! `geostride dataset`: training tiles for the overhead person detector. A dataset is the same
//! from its seed alone, in any number of parts; its files say what they hold.

#![cfg(all(feature = "opencv", feature = "gdal", feature = "onnx"))]

mod common;

use std::path::Path;

fn dataset(out: &Path, extra: &[&str]) {
    let o = common::geostride()
        .arg("dataset")
        .arg("--out")
        .arg(out)
        .args(["--size", "96", "--seed", "5", "-q"])
        .args(extra)
        .output()
        .unwrap();
    common::assert_success(&o);
}

#[test]
fn a_dataset_is_its_seed_in_any_parts_with_labels_for_every_tile() {
    let tmp = tempfile::tempdir().unwrap();
    let whole = tmp.path().join("whole");
    let (a, b) = (tmp.path().join("a"), tmp.path().join("b"));
    dataset(&whole, &["--tiles", "6"]);
    dataset(&a, &["--tiles", "3"]);
    dataset(&b, &["--tiles", "3", "--first", "3"]);
    for i in 0..6 {
        let name = format!("images/{i:07}.jpg");
        let part = if i < 3 { &a } else { &b };
        assert_eq!(
            std::fs::read(whole.join(&name)).unwrap(),
            std::fs::read(part.join(&name)).unwrap(),
            "{name}"
        );
    }
    let tiles = common::read_csv(&whole.join("tiles.csv"));
    assert_eq!(tiles.len(), 6);
    let labels = common::read_csv(&whole.join("labels.csv"));
    for l in &labels {
        let t = common::num(l, "tile") as usize;
        assert!(t < 6);
        for k in [
            "x",
            "y",
            "w",
            "h",
            "head_x",
            "head_y",
            "shoulder_px",
            "inside",
        ] {
            assert!(common::num(l, k).is_finite(), "{k}");
        }
    }
    // Every tile's people are labelled, cut ones included (none are lost).
    let people: f64 = tiles.iter().map(|t| common::num(t, "people")).sum();
    assert!(labels.len() as f64 <= people + 1e-9);
    let meta: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(whole.join("dataset.json")).unwrap())
            .unwrap();
    assert_eq!(meta["spec"]["seed"], 5);
    assert_eq!(meta["tiles"], 6);
    assert_eq!(meta["sha256"].as_str().unwrap().len(), 64);
    // No unfinished folder is left behind.
    assert!(!tmp.path().join("whole.partial").exists());
}

#[test]
fn backdrop_photos_lie_under_the_share_of_tiles_asked_and_are_recorded() {
    let tmp = tempfile::tempdir().unwrap();
    let plain = tmp.path().join("plain");
    dataset(&plain, &["--tiles", "1"]);
    // A rendered tile stands in for a photo: any image OpenCV reads will do.
    let photo = plain.join("images/0000000.jpg");
    let photo_arg = photo.to_str().unwrap();
    let on = tmp.path().join("on");
    dataset(
        &on,
        &[
            "--tiles",
            "4",
            "--backdrops",
            photo_arg,
            "--backdrop-gsd-cm",
            "1.5",
            "--backdrop-share",
            "1",
        ],
    );
    for t in common::read_csv(&on.join("tiles.csv")) {
        assert_eq!(t["ground"], "backdrop");
        assert_eq!(t["backdrop"], "0000000.jpg");
    }
    let meta: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(on.join("dataset.json")).unwrap()).unwrap();
    let b = &meta["backdrops"][0];
    assert_eq!(b["file"], "0000000.jpg");
    assert!((b["gsd_m"].as_f64().unwrap() - 0.015).abs() < 1e-12);
    assert_eq!(b["sha256"].as_str().unwrap().len(), 64);
    // Photos without their scale are refused before anything is written.
    let refused = tmp.path().join("refused");
    let o = common::geostride()
        .args(["dataset", "--tiles", "2", "--backdrops", photo_arg, "--out"])
        .arg(&refused)
        .output()
        .unwrap();
    assert_eq!(o.status.code(), Some(2));
    assert!(String::from_utf8_lossy(&o.stderr).contains("--backdrop-gsd-cm"));
    assert!(!refused.exists());
}
