//! `geostride pose` end to end on a temporary folder: a simulated view with outliers, its JSON
//! and annotated image, and bad inputs.

#![cfg(all(feature = "opencv", feature = "gdal", feature = "onnx"))]

mod common;

use std::path::Path;

use common::geostride;
use geostride::camera::{Calibration, formats};
use geostride::simulate::gcp_view::{GcpView, GcpViewSpec, drone_camera_4k, gcp_view};

/// Writes the camera, the GCPs (local metres) and the picks of a simulated view.
fn write_inputs(dir: &Path, view: &GcpView) {
    formats::write(
        &Calibration::from_camera(view.camera.clone()),
        &dir.join("cam.yaml"),
        None,
    )
    .unwrap();
    let mut gcps = String::from("name,x,y,z\n");
    let mut picks = String::from("name,image,u,v,sigma\n");
    for o in &view.observations {
        gcps += &format!(
            "{},{:.4},{:.4},{:.4}\n",
            o.name, o.world.x, o.world.y, o.world.z
        );
        picks += &format!("{},shot.png,{:.3},{:.3},1.0\n", o.name, o.uv.x, o.uv.y);
    }
    std::fs::write(dir.join("gcps.csv"), gcps).unwrap();
    std::fs::write(dir.join("picks.csv"), picks).unwrap();
}

fn pose_cmd(dir: &Path) -> std::process::Command {
    let mut c = geostride();
    c.current_dir(dir).args([
        "pose",
        "--camera",
        "cam.yaml",
        "--gcps",
        "gcps.csv",
        "--format",
        "csv",
        "--columns",
        "name,x,y,z",
        "--crs",
        "local",
        "--picks",
        "picks.csv",
    ]);
    c
}

#[test]
fn solves_a_view_flags_its_outliers_and_draws_them() {
    let dir = tempfile::tempdir().unwrap();
    let view = gcp_view(&drone_camera_4k(), &GcpViewSpec::default(), 3);
    write_inputs(dir.path(), &view);
    // A grey photo of the camera's size, to annotate.
    geostride::imageio::write_gray(
        &dir.path().join("shot.png"),
        &geostride::image::GrayImage {
            width: 3840,
            height: 2160,
            pixels: vec![128; 3840 * 2160],
        },
    )
    .unwrap();
    let out = pose_cmd(dir.path())
        .args([
            "--image",
            "shot.png",
            "--annotated",
            "shot-pose.png",
            "--json",
        ])
        .output()
        .unwrap();
    common::assert_success(&out);
    let j: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
    let c = view.cam_from_world.centre();
    let p = &j["camera_position"];
    let err = ((p["x"].as_f64().unwrap() - c.x).powi(2)
        + (p["y"].as_f64().unwrap() - c.y).powi(2)
        + (p["z"].as_f64().unwrap() - c.z).powi(2))
    .sqrt();
    assert!(err < 0.2, "camera position off by {err} m");
    assert!(j["rms_px"].as_f64().unwrap() < 2.0);
    let flags: Vec<bool> = j["residuals"]
        .as_array()
        .unwrap()
        .iter()
        .map(|r| r["outlier"].as_bool().unwrap())
        .collect();
    assert_eq!(flags, view.outlier);
    assert!(j["attitude"]["off_nadir_deg"].as_f64().unwrap() < 5.0);
    assert!(dir.path().join("shot-pose.png").is_file());

    // The report names the outliers.
    let out = pose_cmd(dir.path()).output().unwrap();
    assert!(out.status.success());
    let text = String::from_utf8_lossy(&out.stdout);
    assert_eq!(text.matches("OUTLIER").count(), 6, "{text}");
    assert!(text.contains("Camera position"));
}

#[test]
fn bad_inputs_are_clear_errors() {
    let dir = tempfile::tempdir().unwrap();
    let view = gcp_view(
        &drone_camera_4k(),
        &GcpViewSpec {
            outlier_fraction: 0.0,
            ..GcpViewSpec::default()
        },
        4,
    );
    write_inputs(dir.path(), &view);
    let fails = |extra: &[&str], picks: Option<&str>, expect: &str| {
        if let Some(p) = picks {
            std::fs::write(dir.path().join("picks.csv"), p).unwrap();
        }
        let out = pose_cmd(dir.path()).args(extra).output().unwrap();
        let err = String::from_utf8_lossy(&out.stderr);
        assert_eq!(out.status.code(), Some(2), "{expect}: {err}");
        assert!(err.contains(expect), "expected '{expect}' in: {err}");
    };
    let o = &view.observations;
    let pick = |i: usize, u: f64, v: f64| format!("{},shot.png,{u},{v}\n", o[i].name);
    // Three picks.
    let three: String = (0..3).map(|i| pick(i, o[i].uv.x, o[i].uv.y)).collect();
    fails(&[], Some(&three), "at least 4 GCPs");
    // A pick outside the image.
    let outside: String = (0..6)
        .map(|i| pick(i, if i == 2 { 5000.0 } else { o[i].uv.x }, o[i].uv.y))
        .collect();
    fails(&[], Some(&outside), "outside the 3840x2160 image");
    // Every pick at one pixel.
    let same: String = (0..6).map(|i| pick(i, 100.0, 100.0)).collect();
    fails(&[], Some(&same), "same pixel");
    // Unknown image name.
    let good: String = (0..8).map(|i| pick(i, o[i].uv.x, o[i].uv.y)).collect();
    fails(
        &["--picks-image", "other.png"],
        Some(&good),
        "no picks name that image",
    );
    // No picks at all.
    fails(&[], Some("name,image,u,v\n"), "no picks");
    // A video that is not there, and one that is not a video.
    std::fs::write(dir.path().join("picks.csv"), &good).unwrap();
    fails(
        &["--video", "missing.mp4", "--out", "o"],
        None,
        "no such video file",
    );
    std::fs::write(dir.path().join("junk.mp4"), "not a video").unwrap();
    fails(&["--video", "junk.mp4", "--out", "o"], None, "junk.mp4");
    assert!(
        !dir.path().join("o").exists(),
        "no output folder for a failed run"
    );
}

#[test]
fn a_gcp_list_with_picks_needs_no_picks_file() {
    // OpenDroneMap's gcp_list.txt carries the picks; coordinates in UTM 31N around a point.
    let dir = tempfile::tempdir().unwrap();
    let view = gcp_view(
        &drone_camera_4k(),
        &GcpViewSpec {
            outlier_fraction: 0.0,
            ..GcpViewSpec::default()
        },
        9,
    );
    formats::write(
        &Calibration::from_camera(view.camera.clone()),
        &dir.path().join("cam.yaml"),
        None,
    )
    .unwrap();
    let mut list = String::from("WGS84 UTM 31N\n");
    for o in &view.observations {
        list += &format!(
            "{:.4} {:.4} {:.4} {:.3} {:.3} shot.jpg {}\n",
            500000.0 + o.world.x,
            5650000.0 + o.world.y,
            50.0 + o.world.z,
            o.uv.x,
            o.uv.y,
            o.name
        );
    }
    std::fs::write(dir.path().join("gcp_list.txt"), list).unwrap();
    let out = geostride()
        .current_dir(dir.path())
        .args([
            "pose",
            "--camera",
            "cam.yaml",
            "--gcps",
            "gcp_list.txt",
            "--json",
        ])
        .output()
        .unwrap();
    common::assert_success(&out);
    let j: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
    assert_eq!(j["image"], "shot.jpg");
    assert!(
        j["camera_position"]["crs"]
            .as_str()
            .unwrap()
            .contains("UTM zone 31N")
    );
    // UTM's scale factor (0.9996) and the grid's convergence separate the CRS from the local
    // frame by centimetres over this site.
    let c = view.cam_from_world.centre();
    let p = &j["camera_position"];
    let (dx, dy, dz) = (
        p["x"].as_f64().unwrap() - 500000.0 - c.x,
        p["y"].as_f64().unwrap() - 5650000.0 - c.y,
        p["z"].as_f64().unwrap() - 50.0 - c.z,
    );
    assert!(
        (dx * dx + dy * dy + dz * dz).sqrt() < 0.3,
        "({dx}, {dy}, {dz})"
    );
    assert_eq!(j["outliers"], 0);
}
