//! `geostride gcp find` on simulated video frames with exact truth: checker targets (0.6 m, about
//! 27 px from 30 m) found, identified from their layout alone, and placed against the truth
//! (the simulator's picks with no pick noise); a symmetric layout refused unless the heading
//! tells it apart.

#![cfg(all(feature = "opencv", feature = "gdal"))]

mod common;

use std::path::Path;

fn find(dir: &Path, extra: &[&str]) -> std::process::Output {
    common::geostride()
        .current_dir(dir)
        .args([
            "gcp",
            "find",
            "sim/video.mp4",
            "--gcps",
            "sim/gcps.csv",
            "--out",
            "found.csv",
        ])
        .args(extra)
        .output()
        .unwrap()
}

#[test]
fn targets_are_found_identified_by_layout_and_placed_within_a_fifth_of_a_pixel() {
    let tmp = tempfile::tempdir().unwrap();
    let dir = tmp.path();
    common::targets::simulate(dir, &common::target_scene(20.0, &common::IRREGULAR_GCPS));
    let out = find(dir, &[]);
    common::assert_success(&out);
    let truth = common::picks(&dir.join("sim/picks.csv"));
    let found = common::picks(&dir.join("found.csv"));
    assert_eq!(truth.len(), 7, "all seven in view");
    let mut sq = 0.0;
    for (name, (u, v, _)) in &truth {
        let (fu, fv, sigma) = found.get(name).unwrap_or_else(|| {
            panic!(
                "{name} not picked: {}",
                String::from_utf8_lossy(&out.stdout)
            )
        });
        let e2 = (fu - u).powi(2) + (fv - v).powi(2);
        assert!(e2.sqrt() < 0.5, "{name}: {} px from the truth", e2.sqrt());
        assert!(*sigma > 0.0 && *sigma < 0.5, "{name}: σ {sigma}");
        sq += e2;
    }
    assert_eq!(found.len(), truth.len(), "no pick beyond the truth's");
    // Issue 39's 0.2 px. Measured 0.17 px, most of it the simulator's: it draws targets from
    // its ground texture, whose texels move their edges by up to half a texel (drawn exactly,
    // 0.04 px; docs/survey.md).
    let rms = (sq / (2.0 * truth.len() as f64)).sqrt();
    assert!(rms <= 0.2, "centre RMS {rms} px");
    // `pose` reads the picks as written.
    let pose = common::geostride()
        .current_dir(dir)
        .args([
            "pose",
            "--camera",
            "sim/camera.json",
            "--gcps",
            "sim/gcps.csv",
            "--picks",
            "found.csv",
        ])
        .args(["--image-size", "1920x1080", "--picks-image", "video.mp4#0"])
        .output()
        .unwrap();
    common::assert_success(&pose);
}

#[test]
fn a_symmetric_layout_is_refused_without_a_heading_and_identified_with_one() {
    let tmp = tempfile::tempdir().unwrap();
    let dir = tmp.path();
    // Two rows of four, 6 m apart: a half turn maps the grid onto itself.
    let gcps: Vec<(String, f64, f64)> = (0..8)
        .map(|k| {
            (
                format!("P{}", k + 1),
                -13.5 + 9.0 * (k % 4) as f64,
                if k < 4 { -3.0 } else { 3.0 },
            )
        })
        .collect();
    let named: Vec<(&str, f64, f64)> = gcps
        .iter()
        .map(|(n, e, nn)| (n.as_str(), *e, *nn))
        .collect();
    common::targets::simulate(dir, &common::target_scene(0.0, &named));
    let out = find(dir, &[]);
    assert_eq!(
        out.status.code(),
        Some(1),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    assert!(String::from_utf8_lossy(&out.stdout).contains("ambiguous"));
    assert!(!dir.join("found.csv").exists(), "nothing written");
    // The drone's heading, roughly: the image's top is north.
    let out = find(dir, &["--heading", "10:45"]);
    common::assert_success(&out);
    let truth = common::picks(&dir.join("sim/picks.csv"));
    let found = common::picks(&dir.join("found.csv"));
    assert!(
        found.len() + 1 >= truth.len(),
        "{} of {}",
        found.len(),
        truth.len()
    );
    for (name, (u, v, _)) in &found {
        let (tu, tv, _) = truth[name];
        assert!((u - tu).hypot(v - tv) < 1.0, "{name} is another target");
    }
    // The same frame as a drone's photo, its DJI XMP saying where the gimbal points: looking
    // down, its yaw is the heading, with no --heading given; looking 30° down, it is not used.
    let (bgr, w, h) =
        geostride::video::source::FrameReader::frame_bgr_bytes(&dir.join("sim/video.mp4"), 0)
            .unwrap();
    let rgb: Vec<u8> = bgr
        .chunks_exact(3)
        .flat_map(|p| [p[2], p[1], p[0]])
        .collect();
    let jpeg = geostride::imageio::encode_rgb_jpeg(w as u32, h as u32, &rgb, 95).unwrap();
    for (pitch, named) in [(-89.9, true), (-30.0, false)] {
        std::fs::write(dir.join("photo.jpg"), with_dji_xmp(&jpeg, 8.0, pitch)).unwrap();
        let _ = std::fs::remove_file(dir.join("found.csv"));
        let out = common::geostride()
            .current_dir(dir)
            .args([
                "gcp",
                "find",
                "photo.jpg",
                "--gcps",
                "sim/gcps.csv",
                "--out",
                "found.csv",
            ])
            .output()
            .unwrap();
        let report = String::from_utf8_lossy(&out.stdout);
        if !named {
            assert_eq!(out.status.code(), Some(1), "{report}");
            assert!(report.contains("ambiguous"), "{report}");
            continue;
        }
        common::assert_success(&out);
        assert!(
            report.contains("heading 8.0° from the photo's XMP gimbal yaw"),
            "{report}"
        );
        let found = common::picks(&dir.join("found.csv"));
        assert!(found.len() + 1 >= truth.len(), "{report}");
        for (name, (u, v, _)) in &found {
            let (tu, tv, _) = truth[name];
            assert!((u - tu).hypot(v - tv) < 1.0, "{name} is another target");
        }
    }
}

/// `jpeg` with an XMP segment after its start, as DJI drones write one: the gimbal's yaw (from
/// north through east), pitch (-90 straight down) and roll, degrees.
fn with_dji_xmp(jpeg: &[u8], yaw: f64, pitch: f64) -> Vec<u8> {
    let xml = format!(
        "<x:xmpmeta xmlns:x=\"adobe:ns:meta/\"><rdf:RDF xmlns:rdf=\"http://www.w3.org/1999/02/22-rdf-syntax-ns#\">\
         <rdf:Description xmlns:drone-dji=\"http://www.dji.com/drone-dji/1.0/\" \
         drone-dji:GimbalYawDegree=\"{yaw:+.2}\" drone-dji:GimbalPitchDegree=\"{pitch:+.2}\" \
         drone-dji:GimbalRollDegree=\"+0.00\"/></rdf:RDF></x:xmpmeta>"
    );
    let mut body = b"http://ns.adobe.com/xap/1.0/\0".to_vec();
    body.extend(xml.as_bytes());
    let len = (body.len() + 2) as u16;
    let mut out = jpeg[..2].to_vec();
    out.extend([0xFF, 0xE1]);
    out.extend(len.to_be_bytes());
    out.extend(body);
    out.extend(&jpeg[2..]);
    out
}

/// The camera centre of every frame in a run's `pose/poses.csv`.
fn centres(out: &Path) -> Vec<[f64; 3]> {
    common::read_csv(&out.join("pose/poses.csv"))
        .iter()
        .map(|r| ["centre_e_m", "centre_n_m", "centre_u_m"].map(|k| common::num(r, k)))
        .collect()
}

#[test]
fn a_run_with_automatic_picks_poses_the_camera_as_the_true_picks_do() {
    let tmp = tempfile::tempdir().unwrap();
    // Hats, for the project's colour detector.
    let scene =
        common::target_scene(20.0, &common::IRREGULAR_GCPS).replace("hats = false", "hats = true");
    std::fs::write(tmp.path().join("scene.toml"), scene).unwrap();
    let dir = &tmp.path().join("sim");
    common::simulate(&tmp.path().join("scene.toml"), dir);
    // The true picks (no noise: their σ is written as 0, which a run refuses) at 0.2 px.
    let true_picks = std::fs::read_to_string(dir.join("picks.csv")).unwrap();
    let true_picks: String = true_picks
        .lines()
        .map(|l| match l.rsplit_once(',') {
            Some((head, "0")) => format!("{head},0.2\n"),
            _ => format!("{l}\n"),
        })
        .collect();
    std::fs::write(dir.join("picks.csv"), true_picks).unwrap();
    let truth_picks = common::hover_project(
        "picks",
        "video.mp4",
        "kind = \"plane\"",
        "formats = [\"csv\"]",
    );
    let auto = truth_picks.replace("picks = [\"picks.csv\"]\n", "") + "[picks]\nauto = true\n";
    std::fs::write(dir.join("truth.toml"), &truth_picks).unwrap();
    std::fs::write(dir.join("auto.toml"), &auto).unwrap();
    for name in ["truth", "auto"] {
        let out = common::run_project(&dir.join(format!("{name}.toml")), &dir.join(name));
        common::assert_success(&out);
    }
    let found = common::picks(&dir.join("auto/picks-auto.csv"));
    assert_eq!(found.len(), 7, "{found:?}");
    let (a, t) = (centres(&dir.join("auto")), centres(&dir.join("truth")));
    assert_eq!(a.len(), t.len());
    for (a, t) in a.iter().zip(&t) {
        // The found picks are about 0.2 px from the true ones (0.5 cm at this scale).
        let d = ((a[0] - t[0]).powi(2) + (a[1] - t[1]).powi(2) + (a[2] - t[2]).powi(2)).sqrt();
        assert!(d < 0.05, "camera centres {d} m apart: {a:?} vs {t:?}");
        assert!((a[2] - 30.0).abs() < 0.05, "height {} m, flown at 30", a[2]);
    }
    // Both picks and auto: refused, naming the key.
    let both = truth_picks + "[picks]\nauto = true\n";
    std::fs::write(dir.join("both.toml"), both).unwrap();
    let out = common::run_project(&dir.join("both.toml"), &dir.join("both"));
    assert_eq!(out.status.code(), Some(2));
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(
        err.contains("picks.auto") || err.contains("'auto'"),
        "{err}"
    );
}

/// Coded markers (ArUco 4x4_50, ids 11-17, 0.6 m: about 27 px from 30 m) named through a code
/// table, by `gcp find` and by a run's `[picks] auto = true`; a point a marker names that the
/// survey lacks is refused with the table's line.
#[test]
fn coded_markers_are_named_through_a_code_table_in_find_and_in_a_run() {
    let tmp = tempfile::tempdir().unwrap();
    let mut scene =
        common::target_scene(20.0, &common::IRREGULAR_GCPS).replace("hats = false", "hats = true");
    let mut table = String::from("id,name\n");
    for (k, (name, _, _)) in common::IRREGULAR_GCPS.iter().enumerate() {
        let line = format!("name = \"{name}\"\n");
        scene = scene.replace(
            &line,
            &format!("{line}design = \"coded\"\ncode = {}\n", 11 + k),
        );
        table += &format!("{},{name}\n", 11 + k);
    }
    std::fs::write(tmp.path().join("scene.toml"), scene).unwrap();
    let dir = &tmp.path().join("sim");
    common::simulate(&tmp.path().join("scene.toml"), dir);
    std::fs::write(dir.join("codes.csv"), &table).unwrap();
    let out = find(
        tmp.path(),
        &["--design", "coded", "--codes", "sim/codes.csv"],
    );
    common::assert_success(&out);
    let truth = common::picks(&dir.join("picks.csv"));
    let found = common::picks(&tmp.path().join("found.csv"));
    assert_eq!(found.len(), truth.len(), "{found:?}");
    let mut sq = 0.0;
    for (name, (u, v, sigma)) in &found {
        let (tu, tv, _) = truth[name];
        sq += (u - tu).powi(2) + (v - tv).powi(2);
        assert!((0.05..0.5).contains(sigma), "{name}: σ {sigma}");
    }
    let rms = (sq / (2.0 * found.len() as f64)).sqrt();
    assert!(rms <= 0.2, "centre RMS {rms:.3} px");
    // A run finds and names them itself, and poses the camera as the found picks do.
    let picked = common::hover_project(
        "coded",
        "video.mp4",
        "kind = \"plane\"",
        "formats = [\"csv\"]",
    )
    .replace("picks.csv", "../found.csv");
    let project = picked.replace("picks = [\"../found.csv\"]\n", "")
        + "[picks]\nauto = true\ndesigns = [\"coded\"]\ncodes = \"codes.csv\"\n";
    std::fs::write(dir.join("picked.toml"), &picked).unwrap();
    std::fs::write(dir.join("coded.toml"), &project).unwrap();
    for name in ["picked", "coded"] {
        let out = common::run_project(&dir.join(format!("{name}.toml")), &dir.join(name));
        common::assert_success(&out);
    }
    assert_eq!(common::picks(&dir.join("coded/picks-auto.csv")).len(), 7);
    let (a, t) = (centres(&dir.join("coded")), centres(&dir.join("picked")));
    assert_eq!(a.len(), t.len());
    for (a, t) in a.iter().zip(&t) {
        let d = ((a[0] - t[0]).powi(2) + (a[1] - t[1]).powi(2) + (a[2] - t[2]).powi(2)).sqrt();
        assert!(d < 0.01, "camera centres {d} m apart: {a:?} vs {t:?}");
        assert!((a[2] - 30.0).abs() < 0.05, "height {} m, flown at 30", a[2]);
    }
    // A table naming a point the survey lacks: refused, with its line.
    std::fs::write(dir.join("codes.csv"), table.replace("13,G3", "13,G33")).unwrap();
    let out = common::run_project(&dir.join("coded.toml"), &dir.join("refused"));
    assert_eq!(out.status.code(), Some(2));
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(err.contains("line 4") && err.contains("'G33'"), "{err}");
}

/// A real drone photo (brighton-drone, its EXIF GPS in Minnesota) searched with a real survey
/// of another area (odm-gcp-lists, Brazil): refused as bad input, the distance said, nothing
/// written; by `gcp find` and by the picking page alike.
#[test]
fn a_survey_of_another_area_than_the_photo_is_refused() {
    let (Some(photos), Some(lists)) = (
        common::data_dir("brighton-drone/images"),
        common::data_dir("odm-gcp-lists/yjmenezes_odm_br"),
    ) else {
        return;
    };
    let tmp = tempfile::tempdir().unwrap();
    let photo = photos.join("DJI_0018.JPG");
    let gcps = lists.join("gcp_list.txt");
    let out_csv = tmp.path().join("found.csv");
    for command in ["find", "pick"] {
        let out = common::geostride()
            .args(["gcp", command])
            .arg(&photo)
            .arg("--gcps")
            .arg(&gcps)
            .arg("--out")
            .arg(&out_csv)
            .output()
            .unwrap();
        assert_eq!(out.status.code(), Some(2), "{command}");
        let err = String::from_utf8_lossy(&out.stderr);
        assert!(
            err.contains("DJI_0018.JPG")
                && err.contains("km from the nearest point")
                && err.contains("another area"),
            "{command}: {err}"
        );
        assert!(!out_csv.exists());
    }
}

/// Every design in random views (tests/common/targets.rs; `make bench` runs 45 images a
/// design): four images of each, eight targets 20–60 px across, from straight down to 50°
/// below the horizon, identified from their layout alone (coded markers by their ids).
#[test]
fn every_design_is_found_and_named_from_its_layout_in_random_views() {
    let tmp = tempfile::tempdir().unwrap();
    for design in ["checker", "x", "cross", "coded"] {
        let (mut visible, mut right, mut wrong, mut sq) = (0, 0, 0, 0.0);
        for seed in 1000..1004 {
            let s =
                common::targets::run(&tmp.path().join(format!("{design}-{seed}")), seed, design);
            visible += s.visible;
            right += s.right;
            wrong += s.wrong;
            sq += s.errors.iter().map(|(e, _)| e).sum::<f64>();
        }
        let rms = (sq / (2 * right.max(1)) as f64).sqrt();
        assert_eq!(wrong, 0, "{design}: a target given another's name");
        assert!(visible >= 30, "{design}: {visible} targets in view");
        assert!(
            right + 1 >= visible,
            "{design}: {right} of {visible} found and named"
        );
        // Issue 39's 0.2 px holds over the bench's 45 images (checker 0.199 px, most of it the
        // simulator's texture-drawn targets); four images scatter more.
        assert!(rms <= 0.22, "{design}: centre RMS {rms:.3} px");
    }
}
