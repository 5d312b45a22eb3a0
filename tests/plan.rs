//! `geostride plan` reproduces the paper's planning numbers with the nominal presets.

#![cfg(all(feature = "opencv", feature = "gdal", feature = "onnx"))]

mod common;

fn plan_json(args: &[&str]) -> serde_json::Value {
    let o = common::geostride()
        .arg("plan")
        .args(args)
        .arg("--json")
        .output()
        .unwrap();
    common::assert_success(&o);
    serde_json::from_slice(&o.stdout).unwrap()
}

fn within(value: f64, target: f64, rel: f64) -> bool {
    (value / target - 1.0).abs() <= rel
}

#[test]
fn mavic_3_enterprise_at_30_m_matches_the_paper() {
    let p = plan_json(&[
        "--camera",
        "mavic3e",
        "--video-mode",
        "3840x2160",
        "--altitude",
        "30",
        "--height-error",
        "0.1",
    ]);
    let full = p["height_error"]["max_full_m"].as_f64().unwrap();
    let central = p["height_error"]["max_central_m"].as_f64().unwrap();
    println!("Mavic 3E, 30 m, dh 0.1 m: max {full:.4} m full frame, {central:.4} m central");
    // Section 4.1.2: 0.08 m over the full frame, 0.042 m in the central region.
    assert!(within(full, 0.08, 0.10), "{full}");
    assert!(within(central, 0.042, 0.10), "{central}");
    // Section 3.4.1: 4 px² of pixel noise stays under 0.1 m (95 %) everywhere.
    let noise = p["noise_95"]["max_full_m"].as_f64().unwrap();
    assert!(noise < 0.1, "{noise}");
}

#[test]
fn mini_3_pro_footprint_at_30_m() {
    let p = plan_json(&["--camera", "mini3pro", "--altitude", "30"]);
    let (w, h) = (
        p["footprint_ground_m"][0].as_f64().unwrap(),
        p["footprint_ground_m"][1].as_f64().unwrap(),
    );
    println!("Mini 3 Pro at 30 m: {w:.1} m x {h:.1} m");
    // Section 2: "a FoV of about 40 m x 22 m".
    assert!(within(w, 40.0, 0.10) && within(h, 22.0, 0.10), "{w} x {h}");
    assert!(p["noise_95"]["max_full_m"].as_f64().unwrap() < 0.1);
}

#[test]
fn maps_are_written_and_bad_input_is_refused() {
    let tmp = tempfile::tempdir().unwrap();
    let o = common::geostride()
        .args([
            "plan",
            "--camera",
            "mavic3e",
            "--altitude",
            "30",
            "--detector-model",
            "10,10,20",
            "--map-step",
            "16",
            "--out",
        ])
        .arg(tmp.path())
        .output()
        .unwrap();
    common::assert_success(&o);
    for f in ["height-error.png", "noise95.png"] {
        let bytes = std::fs::read(tmp.path().join(f)).unwrap();
        assert_eq!(&bytes[1..4], b"PNG", "{f}");
    }
    let out = String::from_utf8_lossy(&o.stdout);
    assert!(out.contains("detector noise"), "{out}");
    for bad in [
        vec!["--camera", "nosuch", "--altitude", "30"],
        vec!["--camera", "mavic3e", "--altitude", "1.5"],
        vec![
            "--camera",
            "mavic3e",
            "--altitude",
            "30",
            "--video-mode",
            "1920x1440",
        ],
    ] {
        let o = common::geostride().arg("plan").args(&bad).output().unwrap();
        assert_eq!(
            o.status.code(),
            Some(2),
            "{bad:?}: {}",
            String::from_utf8_lossy(&o.stderr)
        );
    }
    // Halving the resolution halves nothing on the ground but doubles the GSD.
    let a = plan_json(&["--camera", "mavic3e", "--altitude", "30"]);
    let b = plan_json(&[
        "--camera",
        "mavic3e",
        "--altitude",
        "30",
        "--video-mode",
        "1920x1080",
    ]);
    assert!(within(
        b["gsd_ground_m"].as_f64().unwrap(),
        2.0 * a["gsd_ground_m"].as_f64().unwrap(),
        1e-3
    ));
    assert!(within(
        b["footprint_ground_m"][0].as_f64().unwrap(),
        a["footprint_ground_m"][0].as_f64().unwrap(),
        1e-6
    ));
}
