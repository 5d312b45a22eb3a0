//! `geostride run` end to end on a simulated hovering video: the outputs open in GDAL with the
//! right CRS, a re-run reuses its stages, an interrupted run finishes with the same outputs as
//! an uninterrupted one, and a bad project file names the key and the line.

#![cfg(all(feature = "opencv", feature = "gdal", feature = "onnx"))]

mod common;

use std::path::{Path, PathBuf};
use std::process::Command;

use common::geostride;

/// Simulates the test scene and writes a project file beside it.
fn setup(dir: &Path) -> PathBuf {
    common::simulate_scene("hover-drift", dir);
    let video = common::simulated_video(dir);
    let project = common::hover_project(
        "pipeline test",
        video,
        "kind = \"deck\"\ncentre_line = [[654460.0, 696000.0], [654540.0, 696000.0]]\nwidth_m = 5.0",
        "crs = \"EPSG:32631\"\nformats = [\"csv\", \"geojson\", \"gpkg\", \"petrack\", \"mot\", \"detections\", \"hdf5\", \"sqlite\"]",
    );
    // The simulator names the picks' image after its video.
    let picks = std::fs::read_to_string(dir.join("picks.csv")).unwrap();
    assert!(picks.contains(&format!("{video}#0")));
    let path = dir.join("project.toml");
    std::fs::write(&path, project).unwrap();
    path
}

fn run(project: &Path, out: &Path) -> std::process::Output {
    common::run_project(project, out)
}

fn report(out: &Path) -> serde_json::Value {
    serde_json::from_str(&std::fs::read_to_string(out.join("report.json")).unwrap()).unwrap()
}

/// The outputs that must not depend on how the run went: byte for byte, the GeoPackage too
/// (its time stamps are fixed), and the HDF5 (it keeps none).
const SAME: [&str; 11] = [
    "trajectories.h5",
    "trajectories.sqlite",
    "walkable_area.wkt",
    "trajectories.csv",
    "detections.csv",
    "trajectories.txt",
    "tracks_mot.txt",
    "trajectories.geojson",
    "positions.geojson",
    "trajectories.gpkg",
    "pose/poses.csv",
];

#[test]
fn runs_reuses_resumes_and_writes_gis_files() {
    let tmp = tempfile::tempdir().unwrap();
    let project = setup(tmp.path());

    // An uninterrupted run.
    let a = tmp.path().join("a");
    let o = run(&project, &a);
    assert!(
        o.status.success(),
        "{}\n{}",
        String::from_utf8_lossy(&o.stdout),
        String::from_utf8_lossy(&o.stderr)
    );
    let r = report(&a);
    let stages: Vec<&str> = r["stages"]
        .as_array()
        .unwrap()
        .iter()
        .map(|s| s["name"].as_str().unwrap())
        .collect();
    assert_eq!(
        stages,
        [
            "scan", "pose", "track", "project", "smooth", "export", "views"
        ]
    );
    assert!(
        r["stages"][2]["counts"]["tracks"].as_f64().unwrap() >= 5.0,
        "{}",
        r["stages"]
    );
    assert_eq!(
        r["inputs"]
            .as_array()
            .unwrap()
            .iter()
            .filter(|i| i["sha256"].as_str().unwrap().len() == 64)
            .count(),
        3
    );
    assert!(
        std::fs::read_to_string(a.join("report.md"))
            .unwrap()
            .contains("## Stages")
    );

    // A re-run reuses every stage and writes the same outputs.
    let o = run(&project, &a);
    assert!(o.status.success());
    let r = report(&a);
    for s in r["stages"].as_array().unwrap().iter().take(5) {
        assert_eq!(s["status"], "reused", "{s}");
    }

    // Another tracker setting, into a copy of that output: the scan (where the image tracker
    // runs) is computed again, not its old tracks reused.
    let a2 = tmp.path().join("a2");
    std::fs::create_dir_all(a2.join(".stages/chunks")).unwrap();
    for sub in [".stages", ".stages/chunks"] {
        for e in std::fs::read_dir(a.join(sub)).unwrap().flatten() {
            if e.path().is_file() {
                std::fs::copy(e.path(), a2.join(sub).join(e.file_name())).unwrap();
            }
        }
    }
    let retracked = tmp.path().join("retracked.toml");
    std::fs::write(
        &retracked,
        std::fs::read_to_string(&project).unwrap() + "[track]\nmax_gap_s = 0.3\n",
    )
    .unwrap();
    common::assert_success(&run(&retracked, &a2));
    assert_eq!(report(&a2)["stages"][0]["status"], "computed");

    // Killed right after the scan, then started again: the same outputs.
    let b = tmp.path().join("b");
    let killed = geostride()
        .env("GEOSTRIDE_TEST_KILL_AFTER", "scan")
        .arg("run")
        .arg(&project)
        .arg("--out")
        .arg(&b)
        .arg("-q")
        .output()
        .unwrap();
    assert!(!killed.status.success(), "the run was meant to die");
    assert!(b.join(".stages/chunks/00000.bin").is_file() && !b.join("trajectories.csv").exists());
    let o = run(&project, &b);
    common::assert_success(&o);
    assert_eq!(report(&b)["stages"][0]["status"], "reused");
    for f in SAME {
        assert_eq!(
            std::fs::read(a.join(f)).unwrap(),
            std::fs::read(b.join(f)).unwrap(),
            "{f} differs after a resumed run"
        );
    }

    // Killed by a signal in the middle of the scan: nothing half-written, and the same outputs.
    let c = tmp.path().join("c");
    let mut child = geostride()
        .arg("run")
        .arg(&project)
        .arg("--out")
        .arg(&c)
        .arg("-q")
        .spawn()
        .unwrap();
    std::thread::sleep(std::time::Duration::from_millis(1500));
    let _ = child.kill();
    let _ = child.wait();
    for entry in std::fs::read_dir(c.join(".stages"))
        .into_iter()
        .flatten()
        .chain(
            std::fs::read_dir(c.join(".stages/chunks"))
                .into_iter()
                .flatten(),
        )
        .flatten()
        // A temporary (`.NAME.tmp-PID`) may be cut short: the next run removes it.
        .filter(|e| e.path().is_file() && !e.file_name().to_string_lossy().starts_with('.'))
    {
        assert!(
            geostride::cache::cache_file_whole(&entry.path()),
            "{} is half-written",
            entry.path().display()
        );
    }
    let o = run(&project, &c);
    common::assert_success(&o);
    for f in SAME {
        assert_eq!(
            std::fs::read(a.join(f)).unwrap(),
            std::fs::read(c.join(f)).unwrap(),
            "{f} differs after a killed run"
        );
    }

    // Every GIS output opens in GDAL with the right CRS.
    let gpkg = gdal::Dataset::open(a.join("trajectories.gpkg")).unwrap();
    use gdal::vector::LayerAccess;
    let layer = gpkg.layer_by_name("trajectories").unwrap();
    assert!(layer.feature_count() >= 5);
    let srs = layer.spatial_ref().unwrap();
    assert_eq!(srs.auth_code().unwrap(), 32631, "the output CRS");
    assert!(gpkg.layer_by_name("positions").unwrap().feature_count() > 100);
    for f in ["trajectories.geojson", "positions.geojson"] {
        let ds = gdal::Dataset::open(a.join(f)).unwrap();
        let l = ds.layer(0).unwrap();
        // WGS 84 (RFC 7946), 3D with ellipsoidal heights.
        let code = l.spatial_ref().unwrap().auth_code().unwrap();
        assert!(code == 4326 || code == 4979, "{f}: EPSG:{code}");
        assert!(l.feature_count() >= 5);
    }
    if let Ok(o) = Command::new("ogrinfo")
        .arg("-so")
        .arg("-al")
        .arg(a.join("trajectories.gpkg"))
        .output()
    {
        let text = String::from_utf8_lossy(&o.stdout);
        assert!(
            o.status.success() && text.contains("UTM zone 31N"),
            "{text}"
        );
    }
    // PeTrack text and MOT rows.
    let pt = std::fs::read_to_string(a.join("trajectories.txt")).unwrap();
    assert!(
        pt.lines()
            .any(|l| !l.starts_with('#') && l.split('\t').count() == 5)
    );
    let mot = std::fs::read_to_string(a.join("tracks_mot.txt")).unwrap();
    assert!(mot.lines().all(|l| l.split(',').count() == 10));

    // The detector's error model from the truth's heads as annotations, the image width from
    // the run's report.
    let o = geostride()
        .args(["fit-error", "--json", "--annotation-columns", "frame,px,py"])
        .arg("--detections")
        .arg(a.join("detections.csv"))
        .arg("--annotations")
        .arg(tmp.path().join("truth/heads.csv"))
        .output()
        .unwrap();
    common::assert_success(&o);
    let fit: serde_json::Value = serde_json::from_slice(&o.stdout).unwrap();
    println!("{fit}");
    assert!(fit["pairs_used"].as_f64().unwrap() > 100.0, "{fit}");
    assert!(fit["width_px"].as_f64().unwrap() > 100.0, "{fit}");
    // Hats found to within a few pixels.
    for knot in fit["model"]["knots"].as_array().unwrap() {
        for k in ["vertical_px2", "horizontal_px2"] {
            let v = knot[k].as_f64().unwrap();
            assert!(v > 0.0 && v < 30.0, "{k} {v}");
        }
    }
}

/// Writes a minimal valid project with dummy inputs, then `edit`s it.
fn bad_project(edit: impl Fn(&str) -> String) -> (tempfile::TempDir, PathBuf) {
    let tmp = tempfile::tempdir().unwrap();
    for f in ["gcps.csv", "picks.csv", "video.mp4"] {
        std::fs::write(tmp.path().join(f), "x").unwrap();
    }
    let text = "name = \"x\"\n[camera]\ncalibration = \"mini3pro\"\n[survey]\ngcps = \"gcps.csv\"\npicks = [\"picks.csv\"]\n[video]\npath = \"video.mp4\"\n[ground]\nkind = \"plane\"\nheight_m = 0.0\n[detect]\nclusters = 15\n";
    let path = tmp.path().join("project.toml");
    std::fs::write(&path, edit(text)).unwrap();
    (tmp, path)
}

#[test]
fn a_bad_project_file_names_the_key_and_its_line() {
    type Edit<'a> = &'a dyn Fn(&str) -> String;
    let cases: [(Edit, &str, &str); 6] = [
        (
            &|t| t.replace("clusters = 15", "clusters = 1"),
            "detect.clusters",
            "project.toml:13:",
        ),
        (
            &|t| t.replace("clusters = 15", "clusterz = 15"),
            "unknown field `clusterz`",
            "project.toml:13:",
        ),
        (
            &|t| t.replace("video.mp4\"", "missing.mp4\""),
            "video.path",
            "project.toml:8:",
        ),
        (
            &|t| format!("{t}[track]\nkind = \"greedy\"\n"),
            "unknown variant `greedy`",
            "project.toml:15:",
        ),
        (
            &|t| t.replace("kind = \"plane\"", "kind = \"meadow\""),
            "unknown variant `meadow`",
            "project.toml:10:",
        ),
        (
            &|t| format!("{t}[export]\nformats = [\"csv\", \"shp\"]\n"),
            "export.formats",
            "project.toml:15:",
        ),
    ];
    for (edit, what, line) in cases {
        let (_tmp, path) = bad_project(edit);
        let o = run(&path, &path.with_file_name("out"));
        let err = String::from_utf8_lossy(&o.stderr);
        assert_eq!(o.status.code(), Some(2), "{what}: {err}");
        assert!(
            err.contains(what) && err.contains(line),
            "expected '{what}' at '{line}' in: {err}"
        );
        assert!(
            !path.with_file_name("out").exists(),
            "no output for a bad project"
        );
    }
}
