//! `geostride simulate`: deterministic truth, and truth heads that land on the rendered hats.

#![cfg(all(feature = "opencv", feature = "gdal", feature = "onnx"))]

mod common;

use std::path::Path;

use opencv::core::Vec3b;
use opencv::imgcodecs;
use opencv::prelude::*;

fn scene() -> std::path::PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/scenes/small-stream.toml")
}

fn simulate(out: &Path, extra: &[&str]) {
    let o = common::geostride()
        .arg("simulate")
        .arg(scene())
        .arg("--out")
        .arg(out)
        .arg("-q")
        .args(extra)
        .output()
        .unwrap();
    common::assert_success(&o);
}

#[test]
fn the_same_seed_gives_byte_identical_truth() {
    let (a, b, c) = (
        tempfile::tempdir().unwrap(),
        tempfile::tempdir().unwrap(),
        tempfile::tempdir().unwrap(),
    );
    simulate(a.path(), &[]);
    simulate(b.path(), &[]);
    simulate(c.path(), &["--seed", "6"]);
    let files = [
        "truth/camera.csv",
        "truth/heads.csv",
        "truth/people.csv",
        "truth/gcps.csv",
        "truth/scene.json",
        "gcps.csv",
        "picks.csv",
        "checkerboards/board-00.png",
    ];
    for f in files {
        let (x, y) = (
            std::fs::read(a.path().join(f)).unwrap(),
            std::fs::read(b.path().join(f)).unwrap(),
        );
        assert!(!x.is_empty(), "{f} is empty");
        assert_eq!(x, y, "{f} differs between two runs with the same seed");
    }
    assert_ne!(
        std::fs::read(a.path().join("truth/heads.csv")).unwrap(),
        std::fs::read(c.path().join("truth/heads.csv")).unwrap()
    );
    // The exported GCP file reads back as a survey, with the file's heights ellipsoidal.
    let o = common::geostride()
        .args(["survey", "inspect", "--json"])
        .arg(a.path().join("gcps.csv"))
        .output()
        .unwrap();
    common::assert_success(&o);
    let v: serde_json::Value = serde_json::from_slice(&o.stdout).unwrap();
    assert_eq!(v["counts"]["points"], 2);
    assert_eq!(v["height"], "ellipsoidal");
}

/// Inverse of the renderer's gamma (1/2.2).
fn linear(v: u8) -> f64 {
    (f64::from(v) / 255.0).powf(2.2)
}

#[test]
fn truth_heads_land_on_the_rendered_hats_within_half_a_pixel() {
    let out = tempfile::tempdir().unwrap();
    simulate(out.path(), &["--frames-every", "1"]);
    let heads = std::fs::read_to_string(out.path().join("truth/heads.csv")).unwrap();
    let rows: Vec<(usize, usize, f64, f64)> = heads
        .lines()
        .skip(1)
        .map(|l| {
            let f: Vec<&str> = l.split(',').collect();
            (
                f[0].parse().unwrap(),
                f[2].parse().unwrap(),
                f[6].parse().unwrap(),
                f[7].parse().unwrap(),
            )
        })
        .collect();
    let mut checked = 0;
    let mut worst: f64 = 0.0;
    for &(frame, person, px, py) in &rows {
        // Only isolated hats well inside the image: a neighbour's head could share the window.
        let isolated = rows.iter().all(|&(f2, p2, x2, y2)| {
            f2 != frame || p2 == person || (x2 - px).hypot(y2 - py) > 40.0
        });
        if !isolated || px < 15.0 || py < 15.0 || px > 1904.0 || py > 1064.0 {
            continue;
        }
        let img = imgcodecs::imread(
            out.path()
                .join(format!("frames/frame-{frame:05}.png"))
                .to_str()
                .unwrap(),
            imgcodecs::IMREAD_COLOR,
        )
        .unwrap();
        // Magenta-ness in linear light is the hat's coverage of a pixel: grey, skin, hair and
        // the shirts of the palette have none.
        let (mut sw, mut sx, mut sy) = (0.0, 0.0, 0.0);
        let (cx, cy) = (px.round() as i32, py.round() as i32);
        for v in cy - 12..=cy + 12 {
            for u in cx - 12..=cx + 12 {
                let p = img.at_2d::<Vec3b>(v, u).unwrap();
                let (b, g, r) = (linear(p[0]), linear(p[1]), linear(p[2]));
                let m = (r.min(b) - g).max(0.0);
                if m > 0.01 {
                    sw += m;
                    sx += m * f64::from(u);
                    sy += m * f64::from(v);
                }
            }
        }
        assert!(
            sw > 0.0,
            "no hat at frame {frame} person {person} ({px}, {py})"
        );
        let err = (sx / sw - px).hypot(sy / sw - py);
        worst = worst.max(err);
        assert!(
            err < 0.5,
            "frame {frame} person {person}: hat centroid off by {err:.3} px"
        );
        checked += 1;
    }
    println!("{checked} hats measured, worst {worst:.3} px");
    assert!(checked >= 10, "only {checked} isolated hats to measure");
}

#[test]
fn bad_scenes_are_refused_with_the_line() {
    let tmp = tempfile::tempdir().unwrap();
    let bad = tmp.path().join("bad.toml");
    std::fs::write(&bad, "[camera]\ncalibration = \"mini3pro\"\n[camera.motion]\nkind = \"hover\"\nposition = [0, 0, 30]\n[ground]\nkind = \"deck\"\nwidth_m = 4\nlength_m = 60\nlenght_m = 3\n").unwrap();
    let o = common::geostride()
        .arg("simulate")
        .arg(&bad)
        .arg("--out")
        .arg(tmp.path().join("o"))
        .output()
        .unwrap();
    assert_eq!(o.status.code(), Some(2));
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(
        err.contains("bad.toml:") && err.contains("lenght_m"),
        "{err}"
    );
    let missing_cam = tmp.path().join("cam.toml");
    std::fs::write(&missing_cam, "[camera]\ncalibration = \"nothere.yaml\"\n[camera.motion]\nkind = \"hover\"\nposition = [0, 0, 30]\n[ground]\nkind = \"deck\"\nwidth_m = 4\nlength_m = 60\n").unwrap();
    let o = common::geostride()
        .arg("simulate")
        .arg(&missing_cam)
        .arg("--out")
        .arg(tmp.path().join("o"))
        .output()
        .unwrap();
    assert_eq!(
        o.status.code(),
        Some(2),
        "{}",
        String::from_utf8_lossy(&o.stderr)
    );
}
