//! The drone's telemetry beside a run (`[video] telemetry`): the simulator's `video.SRT` (a
//! consumer GNSS's common offset and wander, `docs/simulate.md`) against the poses of the
//! drifting hover: every posed frame checked, none flagged; one block moved 11 m north is
//! flagged, and a malformed file stops the run with its line (exit 2).

#![cfg(all(feature = "opencv", feature = "gdal", feature = "onnx"))]

mod common;

use std::path::{Path, PathBuf};

use common::assert_success;

/// The drifting hover simulated into `dir` and a project reading `srt`: its path.
fn project(dir: &Path, srt: &str) -> PathBuf {
    let video = common::simulated_video(dir);
    let text = common::hover_project(
        "telemetry test",
        video,
        "kind = \"plane\"",
        "formats = [\"csv\"]",
    )
    .replace(
        &format!("path = \"{video}\"\n"),
        &format!("path = \"{video}\"\ntelemetry = \"{srt}\"\n"),
    ) + "[output]\nplots = false\nsite_image = false\n";
    let path = dir.join(format!("{srt}.toml"));
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
    assert_success(&common::run_project(&project(dir, "video.SRT"), &out));
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
    eprintln!("telemetry: {stage}");

    // Block 21 (frame 20) 0.0001° north: 11.1 m.
    let lat = srt
        .split("\n\n")
        .nth(20)
        .and_then(|b| b.split("[latitude: ").nth(1))
        .and_then(|r| r.split(']').next())
        .unwrap()
        .to_string();
    let moved = format!("{:.7}", lat.parse::<f64>().unwrap() + 1e-4);
    let blocks: Vec<String> = srt
        .split("\n\n")
        .enumerate()
        .map(|(k, b)| {
            if k == 20 {
                b.replace(
                    &format!("[latitude: {lat}]"),
                    &format!("[latitude: {moved}]"),
                )
            } else {
                b.to_string()
            }
        })
        .collect();
    std::fs::write(dir.join("moved.SRT"), blocks.join("\n\n")).unwrap();
    let out = dir.join("b");
    let o = common::run_project(&project(dir, "moved.SRT"), &out);
    assert_success(&o);
    let stage = telemetry_stage(&out);
    assert_eq!(stage["counts"]["frames_flagged"], 1.0, "{stage}");
    let rows = common::read_csv(&out.join("pose/telemetry.csv"));
    let flagged: Vec<_> = rows.iter().filter(|r| r["flagged"] == "1").collect();
    assert_eq!(flagged.len(), 1);
    assert_eq!(flagged[0]["frame"], "20");
    let r = common::num(flagged[0], "residual_m");
    assert!((r - 11.1).abs() < 2.0, "residual {r} m");
    let report = std::fs::read_to_string(out.join("report.json")).unwrap();
    assert!(report.contains("1 frame(s) whose camera centre is more than"));

    // A malformed block: the run stops before any work, naming the line.
    std::fs::write(
        dir.join("bad.SRT"),
        srt.replacen("[latitude: ", "[latitude: 9", 1),
    )
    .unwrap();
    let o = common::run_project(&project(dir, "bad.SRT"), &dir.join("c"));
    assert_eq!(o.status.code(), Some(2));
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(
        err.contains("bad.SRT:5") && err.contains("latitude"),
        "{err}"
    );
}
