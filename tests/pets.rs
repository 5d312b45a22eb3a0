//! PETS 2009 S2L1 View_001 (`$GEOSTRIDE_DATA/pets2009-s2l1`): its Tsai calibration read as a
//! camera with its pose, checked against the ground truth's own projection (the truth's world
//! positions are the Tsai projection of a point 1.5 px above and left of each box's bottom
//! centre, 768×576 pixels).

#![cfg(all(feature = "opencv", feature = "gdal", feature = "onnx"))]

mod common;

use geostride::camera::formats::{Format, read};
use nalgebra::Vector3;

#[test]
fn the_tsai_calibration_reproduces_the_ground_truths_projection() {
    let Some(dir) = common::data_dir("pets2009-s2l1") else {
        return;
    };
    let xml = read(&dir.join("View_001.xml"), None).unwrap();
    let txt = read(&dir.join("View_001.txt"), Some(Format::Tsai)).unwrap();
    assert_eq!(xml.camera, txt.camera);
    let pose = xml.extrinsics.as_ref().unwrap().cam_from_world;
    // The README's pose in OpenCV terms and the camera centre 7.07 m up.
    let rvec = pose.rvec();
    assert!(
        (rvec - Vector3::new(1.6705, -0.9153, 0.6155)).norm() < 1e-3,
        "{rvec}"
    );
    let centre = pose.centre();
    assert!(
        (centre - Vector3::new(-28.94, -19.53, 7.07)).norm() < 0.01,
        "{centre}"
    );
    // At 480×360 (the video), the README's OpenCV intrinsics.
    let small = xml.camera.scaled_to(480, 360).unwrap();
    assert!((small.fx - 740.63).abs() < 0.01 && (small.fy - 746.63).abs() < 0.01);
    assert!(
        (small.dist[0] + 0.157683).abs() < 0.002,
        "k1 {}",
        small.dist[0]
    );

    let gt = std::fs::read_to_string(dir.join("gt_frames_0000-0399.txt")).unwrap();
    let (mut n, mut worst) = (0, 0.0f64);
    for line in gt.lines() {
        let f: Vec<f64> = line.split(',').map(|x| x.parse().unwrap()).collect();
        let (left, top, w, h) = (f[2], f[3], f[4], f[5]);
        let world = Vector3::new(f[7], f[8], 0.0);
        let uv = xml.camera.project(&pose.apply(&world)).unwrap();
        let marked = nalgebra::Vector2::new(left + w / 2.0 - 1.5, top + h - 1.5);
        worst = worst.max((uv - marked).norm());
        n += 1;
    }
    eprintln!("{n} truth rows, worst {worst:.3} px from the marked point");
    assert!(n > 2000);
    // The truth's coordinates are given to 0.1 mm and its boxes to 0.001 px: within a pixel.
    assert!(worst < 1.0, "{worst} px");
}

/// `[pose] kind = "fixed"` from the Tsai file, no GCPs: every frame gets the calibration's pose
/// and the trajectories land on the PETS plaza (the truth's x from −13 to 7.4 m, y from −15 to
/// 7.7 m). How well they match the truth is issue 37's benchmark, not this test's.
#[test]
fn a_fixed_camera_runs_from_its_tsai_calibration_without_gcps() {
    let (Some(dir), Some(video)) = (common::data_dir("pets2009-s2l1"), common::data_dir("video"))
    else {
        return;
    };
    let tmp = tempfile::tempdir().unwrap();
    let project = tmp.path().join("project.toml");
    std::fs::write(
        &project,
        format!(
            "name = \"PETS 2009 S2L1\"\n[camera]\ncalibration = \"{}\"\n[video]\npath = \"{}\"\n\
             duration_s = 10\n[pose]\nkind = \"fixed\"\n[ground]\nkind = \"plane\"\nheight_m = 0.0\n\
             [detect]\nkind = \"onnx\"\n[track]\nkind = \"klt\"\n[export]\nformats = [\"csv\"]\n",
            dir.join("View_001.xml").display(),
            video.join("vtest_480x360_h264.avi").display()
        ),
    )
    .unwrap();
    let out = tmp.path().join("out");
    let o = common::geostride()
        .args([
            "run",
            project.to_str().unwrap(),
            "--out",
            out.to_str().unwrap(),
            "-q",
        ])
        .output()
        .unwrap();
    common::assert_success(&o);
    let poses = common::read_csv(&out.join("pose/poses.csv"));
    assert_eq!(poses.len(), 1, "one pose for the fixed camera");
    assert_eq!(poses[0]["frames"], "0-99");
    let centre = Vector3::new(
        common::num(&poses[0], "centre_e_m"),
        common::num(&poses[0], "centre_n_m"),
        common::num(&poses[0], "centre_u_m"),
    );
    assert!(
        (centre - Vector3::new(-28.94, -19.53, 7.07)).norm() < 0.01,
        "{centre}"
    );
    let rows = common::read_csv(&out.join("trajectories.csv"));
    assert!(rows.len() > 200, "{} trajectory points", rows.len());
    let on_plaza = rows
        .iter()
        .filter(|r| {
            let (e, n) = (common::num(r, "e_m"), common::num(r, "n_m"));
            (-20.0..15.0).contains(&e) && (-20.0..12.0).contains(&n)
        })
        .count();
    assert!(
        on_plaza as f64 > 0.9 * rows.len() as f64,
        "{on_plaza} of {} points on the plaza",
        rows.len()
    );
}

/// Issue 37's benchmark (`scripts/pets-benchmark.sh`, also run by `make bench`): frames 0–399
/// against the world truth at the standard 1 m, with the bundled detector and with the ACF
/// boxes. The bundled detector is held to issue 37's targets; the other runs to what was
/// measured (docs/accuracy.md), a little below it.
#[test]
fn the_pets_benchmark_holds_its_measured_accuracy() {
    let (Some(_), Some(_)) = (common::data_dir("pets2009-s2l1"), common::data_dir("video")) else {
        return;
    };
    let tmp = tempfile::tempdir().unwrap();
    let out = tmp.path().join("pets");
    let o = std::process::Command::new("sh")
        .arg(concat!(
            env!("CARGO_MANIFEST_DIR"),
            "/scripts/pets-benchmark.sh"
        ))
        .arg(&out)
        .env("GEOSTRIDE", env!("CARGO_BIN_EXE_geostride"))
        .output()
        .unwrap();
    common::assert_success(&o);
    let json = |name: &str| -> serde_json::Value {
        serde_json::from_str(&std::fs::read_to_string(out.join(format!("{name}.json"))).unwrap())
            .unwrap()
    };
    let num = |v: &serde_json::Value, k: &str| v[k].as_f64().unwrap();
    let table = std::fs::read_to_string(out.join("table.md")).unwrap();
    eprintln!("{table}");

    // The bundled detector as it comes (two tiles of 360 px, chosen from the model's 416 px
    // input and the frames): issue 37's targets for the mean error (0.239 m per frame
    // measured), MOTA (0.856), IDF1 (0.825) and tracks (15 for 10 people, one of them a real
    // person walking beyond the annotated plaza, docs/accuracy.md).
    let (t, p) = (json("bundled-tracking"), json("bundled-positions"));
    assert_eq!(num(&t, "truth_tracks"), 10.0, "people in frames 0-399");
    assert!(
        num(&p, "mean_error_m") <= 0.25,
        "per frame {}",
        p["mean_error_m"]
    );
    assert!(num(&t, "mota") >= 0.80, "MOTA {}", t["mota"]);
    assert!(num(&t, "idf1") >= 0.75, "IDF1 {}", t["idf1"]);
    assert!(num(&t, "estimated_tracks") <= 15.0, "{t}");
    let inside = num(&t["uncertainty"], "inside_95");
    assert!(
        (0.92..=0.98).contains(&inside),
        "95 % ellipses hold {inside}"
    );
    let tiles = std::fs::read_to_string(out.join("bundled/report.json")).unwrap();
    assert!(tiles.contains("\"model_tile_px\": 360.0"), "{tiles}");

    // On whole frames (shrunk for the model): as measured, 0.260 m, MOTA 0.908, IDF1 0.745.
    let (t, p) = (
        json("bundled-whole-tracking"),
        json("bundled-whole-positions"),
    );
    assert!(num(&t, "mota") >= 0.85, "MOTA {}", t["mota"]);
    assert!(num(&t, "idf1") >= 0.68, "IDF1 {}", t["idf1"]);
    assert!(num(&t, "motp_m") <= 0.30, "MOTP {}", t["motp_m"]);
    assert!(num(&t, "estimated_tracks") <= 15.0, "{t}");
    assert!(
        num(&p, "mean_error_m") <= 0.28,
        "per frame {}",
        p["mean_error_m"]
    );

    // The ACF boxes through geostride: no worse than their own projection.
    let (t, p, own) = (
        json("acf-tracking"),
        json("acf-positions"),
        json("acf-own-positions"),
    );
    assert!(
        num(&p, "mean_error_m") <= num(&own, "mean_error_m"),
        "ACF through geostride {} m, their own projection {} m",
        p["mean_error_m"],
        own["mean_error_m"]
    );
    assert!(
        num(&t, "motp_m") <= num(&own, "mean_error_m"),
        "MOTP {}",
        t["motp_m"]
    );
    assert!(num(&t, "mota") >= 0.82 && num(&t, "idf1") >= 0.75, "{t}");
}
