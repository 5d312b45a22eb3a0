//! The drone's telemetry beside a run (`[video] telemetry`): the simulator's `video.SRT` (a
//! consumer GNSS's common offset and wander, `docs/simulate.md`) against the poses of the
//! drifting hover: every posed frame checked, heights too, none flagged (nor with the heights
//! said to be above EGM96: the geoid's height goes into the common offset); one block moved
//! 11 m north and one 15 m up are flagged, and a malformed file or an unknown datum stops the
//! run with its line (exit 2).

#![cfg(all(feature = "opencv", feature = "gdal", feature = "onnx"))]

mod common;

use std::path::{Path, PathBuf};

use common::assert_success;

/// The drifting hover simulated into `dir` and a project reading `srt`, its `abs_alt` above
/// `height` (the simulator writes ellipsoidal heights): its path.
fn project(dir: &Path, srt: &str, height: &str) -> PathBuf {
    let video = common::simulated_video(dir);
    let text = common::hover_project(
        "telemetry test",
        video,
        "kind = \"plane\"",
        "formats = [\"csv\"]",
    )
    .replace(
        &format!("path = \"{video}\"\n"),
        &format!("path = \"{video}\"\ntelemetry = \"{srt}\"\ntelemetry_height = \"{height}\"\n"),
    ) + "[output]\nplots = false\nsite_image = false\n";
    let path = dir.join(format!("{srt}-{height}.toml"));
    std::fs::write(&path, text).unwrap();
    path
}

fn telemetry_stage(out: &Path) -> serde_json::Value {
    let report: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(out.join("report.json")).unwrap()).unwrap();
    report["stages"]
        .as_array()
        .unwrap()
        .iter()
        .find(|s| s["name"] == "telemetry")
        .cloned()
        .unwrap_or_else(|| panic!("no telemetry stage: {report}"))
}

#[test]
fn the_simulated_telemetry_agrees_with_the_poses_and_a_frame_11_m_off_is_flagged() {
    let tmp = tempfile::tempdir().unwrap();
    let dir = tmp.path();
    common::simulate_scene("hover-drift", dir);
    let srt = std::fs::read_to_string(dir.join("video.SRT")).unwrap();

    let out = dir.join("a");
    assert_success(&common::run_project(
        &project(dir, "video.SRT", "ellipsoidal"),
        &out,
    ));
    let stage = telemetry_stage(&out);
    let counts = &stage["counts"];
    let poses = common::read_csv(&out.join("pose/poses.csv"));
    assert_eq!(
        counts["frames_checked"].as_f64().unwrap() as usize,
        poses.len()
    );
    assert_eq!(counts["frames_flagged"], 0.0, "{stage}");
    let rms = counts["residual_rms_m"].as_f64().unwrap();
    assert!(rms < 1.5, "residual RMS {rms} m");
    // The heights too: the simulator's ellipsoidal abs_alt against the survey's ellipsoidal
    // heights, their common offset the receiver's (σ 3 m).
    assert_eq!(counts["heights_compared"], 1.0, "{stage}");
    let rms_u = counts["residual_rms_u_m"].as_f64().unwrap();
    assert!(rms_u < 2.0, "vertical residual RMS {rms_u} m");
    assert!(
        counts["offset_u_m"].as_f64().unwrap().abs() < 12.0,
        "{stage}"
    );
    for chart in ["telemetry_track.png", "telemetry_residual.png"] {
        assert!(out.join("pose").join(chart).is_file(), "{chart}");
    }
    eprintln!("telemetry: {stage}");

    // Said to be above the EGM96 geoid instead, the heights move by the geoid's height there
    // (about 46 m at the scene's 51°N 4.4°E), all of it in the common offset: nothing flagged.
    let out_egm = dir.join("egm");
    assert_success(&common::run_project(
        &project(dir, "video.SRT", "egm96"),
        &out_egm,
    ));
    let egm = telemetry_stage(&out_egm);
    assert_eq!(egm["counts"]["frames_flagged"], 0.0, "{egm}");
    let shift =
        egm["counts"]["offset_u_m"].as_f64().unwrap() - counts["offset_u_m"].as_f64().unwrap();
    assert!(
        (40.0..50.0).contains(&shift),
        "EGM96 moved the heights {shift} m"
    );

    // Block 21 (frame 20) 0.0001° north: 11.1 m.
    let lat = srt
        .split("\n\n")
        .nth(20)
        .and_then(|b| b.split("[latitude: ").nth(1))
        .and_then(|r| r.split(']').next())
        .unwrap()
        .to_string();
    let moved = format!("{:.7}", lat.parse::<f64>().unwrap() + 1e-4);
    // Block 41 (frame 40) 15 m up: beyond 4 σ of the heights (3 m).
    let blocks: Vec<String> = srt
        .split("\n\n")
        .enumerate()
        .map(|(k, b)| match k {
            20 => b.replace(
                &format!("[latitude: {lat}]"),
                &format!("[latitude: {moved}]"),
            ),
            40 => {
                let alt = b
                    .split("abs_alt: ")
                    .nth(1)
                    .and_then(|r| r.split(']').next())
                    .unwrap();
                let up = format!("{:.3}", alt.parse::<f64>().unwrap() + 15.0);
                b.replace(&format!("abs_alt: {alt}]"), &format!("abs_alt: {up}]"))
            }
            _ => b.to_string(),
        })
        .collect();
    std::fs::write(dir.join("moved.SRT"), blocks.join("\n\n")).unwrap();
    let out = dir.join("b");
    let o = common::run_project(&project(dir, "moved.SRT", "ellipsoidal"), &out);
    assert_success(&o);
    let stage = telemetry_stage(&out);
    assert_eq!(stage["counts"]["frames_flagged"], 2.0, "{stage}");
    let rows = common::read_csv(&out.join("pose/telemetry.csv"));
    let flagged: Vec<_> = rows.iter().filter(|r| r["flagged"] == "1").collect();
    assert_eq!(flagged.len(), 2);
    assert_eq!(flagged[0]["frame"], "20");
    let r = common::num(flagged[0], "residual_m");
    assert!((r - 11.1).abs() < 2.0, "residual {r} m");
    assert_eq!(flagged[1]["frame"], "40");
    let up = common::num(flagged[1], "residual_u_m");
    assert!((up - 15.0).abs() < 4.0, "residual up {up} m");
    assert!(common::num(flagged[1], "residual_m") < 6.0);
    let report = std::fs::read_to_string(out.join("report.json")).unwrap();
    assert!(report.contains("2 frame(s) whose camera centre is more than"));

    // A datum geostride does not know: refused with the project's line, exit 2.
    let msl = project(dir, "video.SRT", "msl");
    let o = common::run_project(&msl, &dir.join("msl"));
    assert_eq!(o.status.code(), Some(2));
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(
        err.contains("telemetry_height") && err.contains("egm96"),
        "{err}"
    );

    // A malformed block: the run stops before any work, naming the line.
    std::fs::write(
        dir.join("bad.SRT"),
        srt.replacen("[latitude: ", "[latitude: 9", 1),
    )
    .unwrap();
    let o = common::run_project(&project(dir, "bad.SRT", "ellipsoidal"), &dir.join("c"));
    assert_eq!(o.status.code(), Some(2));
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(
        err.contains("bad.SRT:5") && err.contains("latitude"),
        "{err}"
    );
}
