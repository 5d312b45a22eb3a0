//! `geostride pose --video` on a drifting hovering camera from the simulator: key frames are
//! chosen, and every frame's pose projects the GCPs within 1 px (mean) of where the true pose
//! puts them.

#![cfg(all(feature = "opencv", feature = "gdal", feature = "onnx"))]

mod common;

use std::collections::HashMap;
use std::path::Path;

use common::geostride;
use geostride::camera::Camera;
use geostride::geom::Rigid3;
use geostride::survey::crs::Crs;
use nalgebra::Vector3;

fn pose_of(row: &HashMap<String, String>) -> Rigid3 {
    Rigid3::from_rvec_tvec(
        &Vector3::new(
            common::num(row, "rvec_x"),
            common::num(row, "rvec_y"),
            common::num(row, "rvec_z"),
        ),
        &Vector3::new(
            common::num(row, "tvec_x"),
            common::num(row, "tvec_y"),
            common::num(row, "tvec_z"),
        ),
    )
}

#[test]
fn every_frame_of_a_drifting_hover_is_within_a_pixel_of_the_truth() {
    let dir = tempfile::tempdir().unwrap();
    let sim = dir.path().join("sim");
    let scene = Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/scenes/hover-drift.toml");
    let seed = std::env::var("HOVER_SEED").unwrap_or_else(|_| "21".into());
    let out = geostride()
        .args([
            "simulate",
            scene.to_str().unwrap(),
            "--out",
            sim.to_str().unwrap(),
            "--seed",
            &seed,
            "-q",
        ])
        .output()
        .unwrap();
    common::assert_success(&out);

    // The simulator's site frame is the tangent frame at its origin: use the same one.
    let scene_json: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(sim.join("truth/scene.json")).unwrap())
            .unwrap();
    let origin: Vec<f64> = scene_json["site"]["origin"]
        .as_array()
        .unwrap()
        .iter()
        .map(|v| v.as_f64().unwrap())
        .collect();
    let crs = Crs::new(scene_json["site"]["crs"].as_str().unwrap()).unwrap();
    let (lon, lat) = crs.to_lon_lat(origin[0], origin[1]).unwrap();
    let origin_arg = format!("{lat:.10},{lon:.10},{}", origin[2]);
    let video = common::simulated_video(&sim);

    let res = dir.path().join("pose");
    let out = geostride()
        .current_dir(&sim)
        .args([
            "pose",
            "--camera",
            "mini3pro",
            "--gcps",
            "gcps.csv",
            "--height",
            "ellipsoidal",
            "--picks",
            "picks.csv",
            "--video",
            video,
            "--out",
        ])
        .arg(&res)
        .args(["--origin", &origin_arg, "-q"])
        .output()
        .unwrap();
    let stdout = String::from_utf8_lossy(&out.stdout);
    assert!(
        out.status.success(),
        "{}\n{stdout}",
        String::from_utf8_lossy(&out.stderr)
    );
    println!("{stdout}");

    let camera: Camera = geostride::camera::presets::preset("mini3pro")
        .unwrap()
        .camera
        .scaled_to(1280, 720)
        .unwrap();
    let gcps: Vec<Vector3<f64>> = common::read_csv(&sim.join("truth/gcps.csv"))
        .iter()
        .map(|r| {
            Vector3::new(
                common::num(r, "e_m"),
                common::num(r, "n_m"),
                common::num(r, "u_m"),
            )
        })
        .collect();
    let truth = common::read_csv(&sim.join("truth/camera.csv"));
    let est = common::read_csv(&res.join("poses.csv"));
    assert_eq!(est.len(), truth.len(), "a pose for every frame");
    let (mut worst, mut sum, mut keys) = (0.0f64, 0.0, 0);
    for (t, e) in truth.iter().zip(&est) {
        assert_eq!(t["frame"], e["frame"]);
        let (pt, pe) = (pose_of(t), pose_of(e));
        let mean = gcps
            .iter()
            .map(|g| {
                let a = camera.project(&pt.apply(g)).unwrap();
                let b = camera.project(&pe.apply(g)).unwrap();
                (a - b).norm()
            })
            .sum::<f64>()
            / gcps.len() as f64;
        worst = worst.max(mean);
        sum += mean;
        keys += usize::from(e["key"] == "1");
        assert_eq!(
            e["interpolated"], "0",
            "frame {} was not solved",
            e["frame"]
        );
    }
    println!(
        "{} frames, {keys} key frames; mean reprojection against the truth: average {:.3} px, worst frame {worst:.3} px",
        est.len(),
        sum / est.len() as f64
    );
    assert!(keys >= 2, "key frames chosen: {keys}");
    assert!(worst < 1.0, "worst frame {worst} px from the truth");
    for f in [
        "reprojection.csv",
        "reprojection.png",
        "key_frames.csv",
        "gcps_adjusted.csv",
        "pose.json",
    ] {
        assert!(res.join(f).is_file(), "{f}");
    }
}

/// Real footage from a fixed camera (OpenCV's vtest.avi, pedestrians on a plaza): the
/// stabiliser must see no motion, keep its reference through the walkers, and drop them as
/// outliers.
#[test]
fn a_fixed_real_camera_is_registered_to_itself() {
    use geostride::pose::stabilise::{StabiliseSettings, Stabiliser};
    use geostride::video::klt::{Klt, KltSettings};
    use geostride::video::source::FrameReader;
    let Some(dir) = common::data_dir("video") else {
        return;
    };
    let path = dir.join("vtest_480x360_h264.avi");
    let mut reader = FrameReader::open(&path).unwrap();
    let klt = Klt::new(KltSettings::default());
    let (_, first) = reader.next_gray().unwrap().unwrap();
    let template = klt.frame(0, first.clone()).unwrap();
    let mut stab = Stabiliser::new(
        Klt::new(KltSettings::default()),
        StabiliseSettings::default(),
        (reader.width, reader.height),
        template,
        0,
        Vec::new(),
    );
    let mut frame = Some((0, first));
    let (mut keys, mut worst, mut frames, mut outliers) = (0, 0.0f64, 0, 0);
    while let Some((i, gray)) = frame {
        if i >= 200 {
            break;
        }
        let t = stab.push(i, klt.frame(i, gray).unwrap()).unwrap();
        keys += usize::from(t.key.is_some());
        outliers += t.features - t.inliers;
        // Where the homography moves the image's corners and centre.
        let h = t.frame_from_ref;
        for (x, y) in [
            (0.0, 0.0),
            (479.0, 0.0),
            (0.0, 359.0),
            (479.0, 359.0),
            (240.0, 180.0),
        ] {
            let p = geostride::estimate::homography::transfer(&h, &nalgebra::Vector2::new(x, y))
                .unwrap();
            worst = worst.max((p - nalgebra::Vector2::new(x, y)).norm());
        }
        frames += 1;
        frame = reader.next_gray().unwrap();
    }
    println!(
        "{frames} frames of {}: {keys} key frame(s), the image moved at most {worst:.3} px, {outliers} feature tracks rejected",
        path.display()
    );
    assert_eq!(frames, 200);
    assert!(keys <= 3, "{keys} key frames for a fixed camera");
    assert!(worst < 0.5, "a fixed camera moved {worst} px");
    assert!(outliers > 0, "the walkers' features are rejected");
}
