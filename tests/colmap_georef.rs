//! COLMAP models in and out, against COLMAP 3.8 itself (Debian's `colmap`, installed by
//! scripts/bootstrap.sh): a model COLMAP reconstructed from the simulated survey flight is
//! converted text ↔ binary byte for byte as `colmap model_converter` converts it, and
//! georeferenced by `geostride sfm georef` with the flight's GCPs and picks; COLMAP's model of
//! the real Herz-Jesu-P8 photos is placed in its laser scan's frame; bad models are refused with
//! their file and place, exit 2.

#![cfg(all(feature = "opencv", feature = "gdal", feature = "onnx"))]

use std::path::{Path, PathBuf};
use std::process::Command;
use std::sync::OnceLock;

mod common;

fn geostride(args: &[&str]) -> std::process::Output {
    Command::new(env!("CARGO_BIN_EXE_geostride"))
        .args(args)
        .output()
        .expect("geostride runs")
}

fn s(p: &Path) -> &str {
    p.to_str().unwrap()
}

/// `colmap ARGS` (headless), which must succeed.
fn colmap(args: &[&str]) {
    let o = Command::new("colmap")
        .args(args)
        .env("QT_QPA_PLATFORM", "offscreen")
        .output()
        .expect("COLMAP is installed (scripts/bootstrap.sh installs Debian's colmap)");
    assert!(
        o.status.success(),
        "colmap {args:?}: {}{}",
        String::from_utf8_lossy(&o.stdout),
        String::from_utf8_lossy(&o.stderr)
    );
}

/// The simulated survey flight (tests/scenes/survey-flight.toml: 19 photos 2400x1350, 10 GCPs
/// and 3 check points with 1/2 cm survey noise, picks with 0.5 px noise) reconstructed by COLMAP
/// on the CPU with the camera it was simulated with (the mini3pro preset at 2400x1350, held):
/// the folder (kept for every test), the simulation and COLMAP's binary model.
fn colmap_model() -> &'static (tempfile::TempDir, PathBuf, PathBuf) {
    static MODEL: OnceLock<(tempfile::TempDir, PathBuf, PathBuf)> = OnceLock::new();
    MODEL.get_or_init(|| {
        let tmp = tempfile::tempdir().unwrap();
        let sim = tmp.path().join("sim");
        common::simulate_scene("survey-flight", &sim);
        let db = tmp.path().join("db.db");
        let photos = sim.join("survey/photos");
        let sparse = tmp.path().join("sparse");
        std::fs::create_dir_all(&sparse).unwrap();
        colmap(&[
            "feature_extractor",
            "--database_path",
            s(&db),
            "--image_path",
            s(&photos),
            "--ImageReader.single_camera",
            "1",
            "--ImageReader.camera_model",
            "PINHOLE",
            // The preset (fx 2756.023 at 3840x2160) at 2400x1350, COLMAP's pixel convention.
            "--ImageReader.camera_params",
            "1722.514375,1722.514375,1200,675",
            "--SiftExtraction.use_gpu",
            "0",
            "--SiftExtraction.max_image_size",
            "1600",
            "--SiftExtraction.max_num_features",
            "3000",
            "--SiftExtraction.num_threads",
            "2",
        ]);
        colmap(&[
            "exhaustive_matcher",
            "--database_path",
            s(&db),
            "--SiftMatching.use_gpu",
            "0",
            "--SiftMatching.num_threads",
            "2",
        ]);
        colmap(&[
            "mapper",
            "--database_path",
            s(&db),
            "--image_path",
            s(&photos),
            "--output_path",
            s(&sparse),
            "--Mapper.num_threads",
            "2",
            "--Mapper.ba_refine_focal_length",
            "0",
            "--Mapper.ba_refine_extra_params",
            "0",
        ]);
        let model = sparse.join("0");
        assert!(model.join("images.bin").is_file(), "COLMAP made no model");
        (tmp, sim, model)
    })
}

/// `colmap model_converter` of `from` into `to` (created) as `kind` (TXT or BIN).
fn convert(from: &Path, to: &Path, kind: &str) {
    std::fs::create_dir_all(to).unwrap();
    colmap(&[
        "model_converter",
        "--input_path",
        s(from),
        "--output_path",
        s(to),
        "--output_type",
        kind,
    ]);
}

fn bytes(p: &Path) -> Vec<u8> {
    std::fs::read(p).unwrap_or_else(|e| panic!("{}: {e}", p.display()))
}

#[test]
fn text_and_binary_conversions_are_byte_identical_to_colmaps() {
    let (tmp, _, model) = colmap_model();
    let dir = |n: &str| tmp.path().join(n);
    // COLMAP's own conversions: binary → text, and that text → binary.
    convert(model, &dir("c_txt"), "TXT");
    convert(&dir("c_txt"), &dir("c_bin"), "BIN");
    for (from, to, kind) in [
        (model.clone(), "g_txt", "txt"),
        (dir("c_txt"), "g_bin", "bin"),
    ] {
        let o = geostride(&[
            "sfm",
            "convert",
            s(&from),
            "--output-type",
            kind,
            "--out",
            s(&dir(to)),
        ]);
        common::assert_success(&o);
    }
    for f in ["cameras", "images", "points3D"] {
        let (ours, theirs) = (
            dir("g_txt").join(format!("{f}.txt")),
            dir("c_txt").join(format!("{f}.txt")),
        );
        assert!(
            bytes(&ours) == bytes(&theirs),
            "{f}.txt differs from COLMAP's"
        );
        let (ours, theirs) = (
            dir("g_bin").join(format!("{f}.bin")),
            dir("c_bin").join(format!("{f}.bin")),
        );
        assert!(
            bytes(&ours) == bytes(&theirs),
            "{f}.bin differs from COLMAP's"
        );
    }
    let points = std::fs::read_to_string(dir("c_txt").join("points3D.txt")).unwrap();
    let n = points.lines().filter(|l| !l.starts_with('#')).count();
    eprintln!(
        "COLMAP 3.8's model of the survey flight: {n} points, text and binary byte-identical to model_converter's"
    );
    assert!(n > 3000, "{n} points");
}

/// Model minus survey of each check point, and its σ, from a report.
fn check_points(report: &serde_json::Value) -> Vec<(String, [f64; 3], [f64; 3])> {
    let arr = |v: &serde_json::Value| -> [f64; 3] { [0, 1, 2].map(|k| v[k].as_f64().unwrap()) };
    report["georef"]["points"]
        .as_array()
        .unwrap()
        .iter()
        .filter(|p| p["role"] == "check")
        .map(|p| {
            (
                p["name"].as_str().unwrap().to_string(),
                arr(&p["residual_m"]),
                arr(&p["sigma_m"]),
            )
        })
        .collect()
}

#[test]
fn a_colmap_model_is_georeferenced_with_its_check_points_within_twice_their_sigma() {
    let (tmp, sim, model) = colmap_model();
    let out = tmp.path().join("georef");
    let o = geostride(&[
        "sfm",
        "georef",
        s(model),
        "--gcps",
        s(&sim.join("gcps.csv")),
        "--picks",
        s(&sim.join("survey/picks.csv")),
        "--out",
        s(&out),
        "--json",
    ]);
    common::assert_success(&o);
    let report: serde_json::Value = serde_json::from_slice(&o.stdout).unwrap();
    assert_eq!(report["images"], 19);
    assert_eq!(report["format"], "binary");
    let g = &report["georef"];
    assert_eq!(g["placed_by"], "control points");
    assert_eq!(g["control_rms"]["points"], 10, "{g}");
    let checks = check_points(&report);
    assert_eq!(checks.len(), 3);
    for (name, r, sigma) in &checks {
        let horizontal = r[0].hypot(r[1]);
        let sigma_h = sigma[0].hypot(sigma[1]);
        eprintln!(
            "{name}: {horizontal:.4} m horizontally (2σ {:.4}), {:.4} m vertically (2σ {:.4})",
            2.0 * sigma_h,
            r[2].abs(),
            2.0 * sigma[2]
        );
        assert!(
            horizontal <= 2.0 * sigma_h && r[2].abs() <= 2.0 * sigma[2],
            "{name}: {r:?} σ {sigma:?}"
        );
    }
    // Every camera where the simulator put it.
    let truth = common::read_csv(&sim.join("truth/survey_cameras.csv"));
    let got = common::read_csv(&out.join("cameras.csv"));
    let mut worst = 0.0f64;
    for t in &truth {
        let c = got
            .iter()
            .find(|g| g["image"] == t["image"])
            .expect("every image in cameras.csv");
        let d = nalgebra::Vector3::new(
            common::num(c, "crs_x") - common::num(t, "x"),
            common::num(c, "crs_y") - common::num(t, "y"),
            common::num(c, "crs_h") - common::num(t, "ellipsoidal_height_m"),
        );
        worst = worst.max(d.norm());
    }
    eprintln!("COLMAP model georeferenced: 19 cameras within {worst:.4} m of the truth");
    assert!(worst <= 0.05, "{worst} m");
    for f in [
        "cameras.bin",
        "images.bin",
        "points3D.bin",
        "points.ply",
        "cameras.gpkg",
        "report.md",
    ] {
        assert!(out.join(f).is_file(), "{f}");
    }
    // COLMAP reads the model written, in metres of the site frame: a camera centre −Rᵀt
    // agrees with cameras.csv.
    let txt = tmp.path().join("georef_txt");
    convert(&out, &txt, "TXT");
    let images = std::fs::read_to_string(txt.join("images.txt")).unwrap();
    let head: Vec<f64> = images
        .lines()
        .find(|l| !l.starts_with('#'))
        .unwrap()
        .split_whitespace()
        .take(8)
        .map(|v| v.parse().unwrap())
        .collect();
    let name = images
        .lines()
        .find(|l| !l.starts_with('#'))
        .unwrap()
        .split_whitespace()
        .nth(9)
        .unwrap();
    let q = nalgebra::UnitQuaternion::from_quaternion(nalgebra::Quaternion::new(
        head[1], head[2], head[3], head[4],
    ));
    let centre = -(q.inverse() * nalgebra::Vector3::new(head[5], head[6], head[7]));
    let row = got.iter().find(|g| g["image"] == name).unwrap();
    let csv = nalgebra::Vector3::new(
        common::num(row, "x"),
        common::num(row, "y"),
        common::num(row, "z"),
    );
    assert!((centre - csv).norm() < 1e-3, "{centre} vs {csv}");

    // The same model as text, written as text: the same georeferencing.
    let c_txt = tmp.path().join("in_txt");
    convert(model, &c_txt, "TXT");
    let out2 = tmp.path().join("georef2");
    let o = geostride(&[
        "sfm",
        "georef",
        s(&c_txt),
        "--gcps",
        s(&sim.join("gcps.csv")),
        "--picks",
        s(&sim.join("survey/picks.csv")),
        "--out",
        s(&out2),
        "--json",
    ]);
    common::assert_success(&o);
    let again: serde_json::Value = serde_json::from_slice(&o.stdout).unwrap();
    assert_eq!(again["format"], "text");
    assert!(out2.join("images.txt").is_file());
    let h = |r: &serde_json::Value| r["georef"]["check_rms"]["horizontal_m"].as_f64().unwrap();
    assert!(
        (h(&again) - h(&report)).abs() < 1e-6,
        "{} vs {}",
        h(&again),
        h(&report)
    );
}

#[test]
fn bad_models_are_refused_with_file_and_place() {
    let (tmp, sim, model) = colmap_model();
    let bad = |name: &str| {
        let d = tmp.path().join(name);
        std::fs::create_dir_all(&d).unwrap();
        d
    };
    let georef = |dir: &Path| {
        let out = dir.with_extension("out");
        let o = geostride(&[
            "sfm",
            "georef",
            s(dir),
            "--gcps",
            s(&sim.join("gcps.csv")),
            "--picks",
            s(&sim.join("survey/picks.csv")),
            "--out",
            s(&out),
        ]);
        assert_eq!(
            o.status.code(),
            Some(2),
            "{}",
            String::from_utf8_lossy(&o.stderr)
        );
        assert!(!out.exists());
        String::from_utf8_lossy(&o.stderr).to_string()
    };
    // A cut images.bin.
    let d = bad("cut");
    for f in ["cameras.bin", "points3D.bin"] {
        std::fs::copy(model.join(f), d.join(f)).unwrap();
    }
    let images = bytes(&model.join("images.bin"));
    std::fs::write(d.join("images.bin"), &images[..images.len() / 2]).unwrap();
    let e = georef(&d);
    assert!(e.contains("images.bin:byte") && e.contains("cut"), "{e}");
    // A fisheye camera, named.
    let d = bad("fisheye");
    let text = tmp.path().join("fisheye_src");
    convert(model, &text, "TXT");
    for f in ["images.txt", "points3D.txt"] {
        std::fs::copy(text.join(f), d.join(f)).unwrap();
    }
    let cameras = std::fs::read_to_string(text.join("cameras.txt")).unwrap();
    let cameras = cameras.replace(
        "PINHOLE 2400 1350 1722.514375 1722.514375 1200 675",
        "OPENCV_FISHEYE 2400 1350 1722.5 1722.5 1200 675 0 0 0 0",
    );
    std::fs::write(d.join("cameras.txt"), cameras).unwrap();
    let e = georef(&d);
    assert!(e.contains("OPENCV_FISHEYE"), "{e}");
    // A malformed keypoint, by line.
    let d = bad("text");
    std::fs::copy(text.join("cameras.txt"), d.join("cameras.txt")).unwrap();
    std::fs::copy(text.join("points3D.txt"), d.join("points3D.txt")).unwrap();
    let images = std::fs::read_to_string(text.join("images.txt")).unwrap();
    let mut lines: Vec<String> = images.lines().map(String::from).collect();
    lines[5] = lines[5].replacen(' ', " x", 1);
    std::fs::write(d.join("images.txt"), lines.join("\n") + "\n").unwrap();
    let e = georef(&d);
    assert!(e.contains("images.txt:6:"), "{e}");
    // No model at all.
    let e = georef(&bad("empty"));
    assert!(e.contains("no COLMAP model here"), "{e}");
}

/// A ground-truth camera of Herz-Jesu-P8: `K`, and `R` mapping camera to world with centre `C`.
fn herzjesu_camera(
    path: &Path,
) -> (
    nalgebra::Matrix3<f64>,
    nalgebra::Matrix3<f64>,
    nalgebra::Vector3<f64>,
) {
    let v: Vec<f64> = std::fs::read_to_string(path)
        .unwrap()
        .split_whitespace()
        .map(|t| t.parse().unwrap())
        .collect();
    let k = nalgebra::Matrix3::from_row_slice(&v[0..9]);
    let r = nalgebra::Matrix3::from_row_slice(&v[12..21]);
    (k, r, nalgebra::Vector3::new(v[21], v[22], v[23]))
}

/// Real photos with a surveyed frame: COLMAP 3.8's model of Herz-Jesu-P8 (8 photos of a church
/// facade) georeferenced into the laser scan's frame. Its "GCPs" are eight model points, well
/// spread, whose positions in that frame are triangulated from their keypoints with the
/// benchmark's ground-truth cameras (each camera registered to the scan): five control
/// points, three check points. The cameras must come out where the scan placed them, the check
/// points within twice their σ.
#[test]
fn a_real_colmap_model_is_georeferenced_into_the_laser_scans_frame() {
    let Some(data) = common::data_dir("strecha-herzjesu-p8") else {
        return;
    };
    let tmp = tempfile::tempdir().unwrap();
    let db = tmp.path().join("db.db");
    let sparse = tmp.path().join("sparse");
    std::fs::create_dir_all(&sparse).unwrap();
    let images = data.join("images");
    let (k, _, _) = herzjesu_camera(&data.join("gt_dense_cameras/0000.jpg.camera"));
    let params = format!(
        "{},{},{},{}",
        k[(0, 0)],
        k[(1, 1)],
        k[(0, 2)] + 0.5,
        k[(1, 2)] + 0.5
    );
    colmap(&[
        "feature_extractor",
        "--database_path",
        s(&db),
        "--image_path",
        s(&images),
        "--ImageReader.single_camera",
        "1",
        "--ImageReader.camera_model",
        "PINHOLE",
        "--ImageReader.camera_params",
        &params,
        "--SiftExtraction.use_gpu",
        "0",
        "--SiftExtraction.max_image_size",
        "1600",
        "--SiftExtraction.max_num_features",
        "4000",
        "--SiftExtraction.num_threads",
        "2",
    ]);
    colmap(&[
        "exhaustive_matcher",
        "--database_path",
        s(&db),
        "--SiftMatching.use_gpu",
        "0",
        "--SiftMatching.num_threads",
        "2",
    ]);
    colmap(&[
        "mapper",
        "--database_path",
        s(&db),
        "--image_path",
        s(&images),
        "--output_path",
        s(&sparse),
        "--Mapper.num_threads",
        "2",
        "--Mapper.ba_refine_focal_length",
        "0",
        "--Mapper.ba_refine_extra_params",
        "0",
    ]);
    let model_dir = sparse.join("0");
    let (model, _) = geostride::sfm::colmap_model::read_model_dir(&model_dir).unwrap();
    assert_eq!(
        model.images.len(),
        8,
        "COLMAP registered {} of 8",
        model.images.len()
    );
    // The ground-truth projection of each image: x ~ K Rᵀ (X − C).
    let gt: std::collections::HashMap<u32, nalgebra::Matrix3x4<f64>> = model
        .images
        .iter()
        .map(|i| {
            let (k, r, c) =
                herzjesu_camera(&data.join(format!("gt_dense_cameras/{}.camera", i.name)));
            let mut rt = nalgebra::Matrix3x4::zeros();
            rt.fixed_view_mut::<3, 3>(0, 0).copy_from(&r.transpose());
            rt.set_column(3, &(-r.transpose() * c));
            (i.id, k * rt)
        })
        .collect();
    let image = |id: u32| model.images.iter().find(|i| i.id == id).unwrap();
    // Points seen in 4 images or more, triangulated (DLT) with the ground-truth cameras; those
    // they reproject within 1.5 px RMS.
    let mut candidates = Vec::new();
    for p in model.points.iter().filter(|p| p.track.len() >= 4) {
        // COLMAP's multithreaded mapper can merge a track that holds one image twice; a
        // surveyor picks a target once per photo, so such points are no candidates.
        let mut images: Vec<u32> = p.track.iter().map(|&(i, _)| i).collect();
        images.sort_unstable();
        images.dedup();
        if images.len() != p.track.len() {
            continue;
        }
        let obs: Vec<(u32, [f64; 2])> = p
            .track
            .iter()
            .map(|&(i, k)| (i, image(i).points2d[k as usize].xy))
            .collect();
        let mut a = nalgebra::DMatrix::<f64>::zeros(2 * obs.len(), 4);
        for (row, (i, xy)) in obs.iter().enumerate() {
            let m = &gt[i];
            for c in 0..4 {
                a[(2 * row, c)] = xy[0] * m[(2, c)] - m[(0, c)];
                a[(2 * row + 1, c)] = xy[1] * m[(2, c)] - m[(1, c)];
            }
        }
        let v = a.svd(false, true).v_t.unwrap();
        let h = v.row(v.nrows() - 1);
        let x = nalgebra::Vector3::new(h[0] / h[3], h[1] / h[3], h[2] / h[3]);
        let rms = (obs
            .iter()
            .map(|(i, xy)| {
                let q = gt[i] * x.push(1.0);
                (q[0] / q[2] - xy[0]).powi(2) + (q[1] / q[2] - xy[1]).powi(2)
            })
            .sum::<f64>()
            / obs.len() as f64)
            .sqrt();
        if rms < 1.5 {
            candidates.push((x, obs));
        }
    }
    assert!(
        candidates.len() > 100,
        "{} points agree with the ground-truth cameras",
        candidates.len()
    );
    // Eight spread points: farthest-point sampling from the first.
    let mut chosen = vec![0usize];
    while chosen.len() < 8 {
        let next = (0..candidates.len())
            .max_by(|&a, &b| {
                let d = |k: usize| {
                    chosen
                        .iter()
                        .map(|&c| (candidates[k].0 - candidates[c].0).norm())
                        .fold(f64::MAX, f64::min)
                };
                d(a).total_cmp(&d(b))
            })
            .unwrap();
        chosen.push(next);
    }
    let sigma = 0.01;
    let mut gcps = String::from("name,x,y,z,sx,sy,sz\n");
    let mut picks = String::from("name,image,u,v,sigma\n");
    for (n, &c) in chosen.iter().enumerate() {
        let name = if n < 5 {
            format!("GCP{n}")
        } else {
            format!("CHK-{n}")
        };
        let x = candidates[c].0;
        gcps.push_str(&format!(
            "{name},{},{},{},{sigma},{sigma},{sigma}\n",
            x.x, x.y, x.z
        ));
        for (i, xy) in &candidates[c].1 {
            picks.push_str(&format!(
                "{name},{},{},{},1.0\n",
                image(*i).name,
                xy[0] - 0.5,
                xy[1] - 0.5
            ));
        }
    }
    std::fs::write(tmp.path().join("gcps.csv"), gcps).unwrap();
    std::fs::write(tmp.path().join("picks.csv"), picks).unwrap();
    let out = tmp.path().join("georef");
    let o = geostride(&[
        "sfm",
        "georef",
        s(&model_dir),
        "--gcps",
        s(&tmp.path().join("gcps.csv")),
        "--format",
        "csv",
        "--columns",
        "name,x,y,z,sx,sy,sz",
        "--crs",
        "local",
        "--picks",
        s(&tmp.path().join("picks.csv")),
        "--out",
        s(&out),
        "--json",
    ]);
    common::assert_success(&o);
    let report: serde_json::Value = serde_json::from_slice(&o.stdout).unwrap();
    for (name, r, sigma) in check_points(&report) {
        let d = nalgebra::Vector3::from(r).norm();
        eprintln!("Herz-Jesu {name}: {d:.4} m from its position in the scan's frame");
        assert!(
            r[0].hypot(r[1]) <= 2.0 * sigma[0].hypot(sigma[1]) && r[2].abs() <= 2.0 * sigma[2],
            "{name}: {r:?}"
        );
    }
    let got = common::read_csv(&out.join("cameras.csv"));
    let mut worst = 0.0f64;
    for row in &got {
        let (_, _, c) =
            herzjesu_camera(&data.join(format!("gt_dense_cameras/{}.camera", row["image"])));
        let e = nalgebra::Vector3::new(
            common::num(row, "crs_x"),
            common::num(row, "crs_y"),
            common::num(row, "crs_h"),
        ) - c;
        worst = worst.max(e.norm());
    }
    eprintln!(
        "Herz-Jesu: COLMAP's 8 cameras georeferenced within {worst:.4} m of the laser scan's"
    );
    assert_eq!(got.len(), 8);
    assert!(worst < 0.03, "{worst} m");
}
