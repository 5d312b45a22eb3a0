//! What a run shows (issue 21) on a simulated drifting hover over a footbridge: the rectified
//! site image lies where the survey says (each GCP target found in it within 2 ground-sample
//! distances of its surveyed position), the plots and annotated video are there, `render`
//! makes them again, and PedPy (installed from PyPI in a throwaway environment) reads the PeTrack
//! file unchanged and gives geostride's densities and speeds within 2 %.

#![cfg(all(feature = "opencv", feature = "gdal", feature = "onnx"))]

mod common;

use std::path::{Path, PathBuf};
use std::sync::OnceLock;

use common::{assert_success, geostride};

/// The walkable area (the deck) and the measurement area, site frame.
const WALKABLE: &str = "[[-40.0, -2.5], [40.0, -2.5], [40.0, 2.5], [-40.0, 2.5]]";
const MEASUREMENT: &str = "[[-6.0, -2.5], [6.0, -2.5], [6.0, 2.5], [-6.0, 2.5]]";
/// Two lines across the deck, for PedPy's flow.
const LINES: &str = "[[[0.0, -2.5], [0.0, 2.5]], [[-10.0, -2.5], [-10.0, 2.5]]]";

/// One simulated run shared by the tests: (folder, run folder).
fn fixture() -> &'static (tempfile::TempDir, PathBuf) {
    static RUN: OnceLock<(tempfile::TempDir, PathBuf)> = OnceLock::new();
    RUN.get_or_init(|| {
        let dir = tempfile::tempdir().unwrap();
        common::simulate_scene("hover-drift", dir.path());
        let video = common::simulated_video(dir.path());
        let text = common::hover_project(
            "views test",
            video,
            "kind = \"deck\"\ncentre_line = [[654460.0, 696000.0], [654540.0, 696000.0]]\nwidth_m = 5.0",
            // UTM: a grid turned about 1.1° from the site frame's north.
            "crs = \"EPSG:32631\"\nformats = [\"csv\", \"geojson\", \"petrack\", \"gpkg\", \"hdf5\", \"sqlite\"]",
        ) + &format!(
            "[output]\nvideo = true\nvideo_width = 960\n[analysis]\nmeasurement_area = {MEASUREMENT}\nwalkable_area = {WALKABLE}\nmeasurement_lines = {LINES}\n"
        );
        let project = dir.path().join("project.toml");
        std::fs::write(&project, text).unwrap();
        let out = dir.path().join("run");
        assert_success(&common::run_project(&project, &out));
        (dir, out)
    })
}

/// The site image's gray pixels, size and geotransform.
fn site_image(path: &Path) -> (Vec<f64>, usize, usize, [f64; 6]) {
    let ds = gdal::Dataset::open(path).unwrap();
    let (w, h) = ds.raster_size();
    let gt = ds.geo_transform().unwrap();
    assert!(
        ds.spatial_ref()
            .unwrap()
            .to_wkt()
            .unwrap()
            .contains("UTM zone 31N")
    );
    assert_eq!(ds.raster_count(), 4, "RGB and alpha");
    let mut gray = vec![0.0; w * h];
    for b in 1..=3 {
        let band = ds.rasterband(b).unwrap();
        let buf = band.read_as::<u8>((0, 0), (w, h), (w, h), None).unwrap();
        for (g, v) in gray.iter_mut().zip(buf.data()) {
            *g += f64::from(*v) / 3.0;
        }
    }
    (gray, w, h, gt)
}

/// The centre of a 2 × 2 checker target (quadrants of `q` pixels) within `r` pixels of
/// `(x, y)`: where opposite quadrants differ most; sub-pixel by a parabola through the peak.
fn checker_centre(
    img: &[f64],
    w: usize,
    h: usize,
    (x, y): (f64, f64),
    r: i64,
    q: i64,
) -> Option<(f64, f64)> {
    let at = |c: i64, r: i64| -> Option<f64> {
        (c >= 0 && r >= 0 && (c as usize) < w && (r as usize) < h)
            .then(|| img[r as usize * w + c as usize])
    };
    let block = |c0: i64, r0: i64| -> Option<f64> {
        let mut s = 0.0;
        for r in r0..r0 + q {
            for c in c0..c0 + q {
                s += at(c, r)?;
            }
        }
        Some(s / (q * q) as f64)
    };
    // The centre lies between pixels c − 1 and c (a corner of four quadrants).
    let score = |c: i64, r: i64| -> Option<f64> {
        let (tl, tr) = (block(c - q, r - q)?, block(c, r - q)?);
        let (bl, br) = (block(c - q, r)?, block(c, r)?);
        Some((tl + br - tr - bl).abs())
    };
    let (cx, cy) = (x.round() as i64, y.round() as i64);
    let mut best = (f64::MIN, 0, 0);
    for r0 in cy - r..=cy + r {
        for c0 in cx - r..=cx + r {
            if let Some(s) = score(c0, r0)
                && s > best.0
            {
                best = (s, c0, r0);
            }
        }
    }
    let (s, c, r0) = best;
    if s < 60.0 {
        return None;
    }
    let peak = |m: f64, z: f64, p: f64| {
        let d = m - 2.0 * z + p;
        if d.abs() > 1e-9 {
            0.5 * (m - p) / d
        } else {
            0.0
        }
    };
    let dx = peak(score(c - 1, r0)?, s, score(c + 1, r0)?).clamp(-0.5, 0.5);
    let dy = peak(score(c, r0 - 1)?, s, score(c, r0 + 1)?).clamp(-0.5, 0.5);
    // Between pixels c − 1 and c: pixel-centre coordinates c − 0.5.
    Some((c as f64 - 0.5 + dx, r0 as f64 - 0.5 + dy))
}

#[test]
fn every_gcp_target_lies_within_two_ground_sample_distances_of_its_survey() {
    let (dir, out) = fixture();
    let (img, w, h, gt) = site_image(&out.join("site.tif"));
    let gsd = gt[1];
    assert!(
        (gt[5] + gsd).abs() < 1e-12 && gt[2] == 0.0 && gt[4] == 0.0,
        "{gt:?}"
    );
    // The surveyed positions, through PROJ's command line (the GCP file is in Belgian Lambert
    // 2008; the image in UTM 31N).
    let gcps = common::read_csv(&dir.path().join("gcps.csv"));
    let input: String = gcps
        .iter()
        .map(|g| {
            format!(
                "{} {}\n",
                common::num(g, "Easting"),
                common::num(g, "Northing")
            )
        })
        .collect();
    let mut child = std::process::Command::new("cs2cs")
        .args(["-f", "%.4f", "EPSG:3812", "EPSG:32631"])
        .stdin(std::process::Stdio::piped())
        .stdout(std::process::Stdio::piped())
        .spawn()
        .expect("cs2cs (proj-bin, installed by scripts/bootstrap.sh)");
    use std::io::Write as _;
    child
        .stdin
        .take()
        .unwrap()
        .write_all(input.as_bytes())
        .unwrap();
    let converted = String::from_utf8(child.wait_with_output().unwrap().stdout).unwrap();
    let mut worst = 0.0f64;
    let mut found = 0;
    for (g, line) in gcps.iter().zip(converted.lines()) {
        let v: Vec<f64> = line
            .split_whitespace()
            .take(2)
            .map(|t| t.parse().unwrap())
            .collect();
        let expected = ((v[0] - gt[0]) / gsd - 0.5, (gt[3] - v[1]) / gsd - 0.5);
        let name = &g["Name"];
        if !(expected.0 > 0.0 && expected.1 > 0.0 && expected.0 < w as f64 && expected.1 < h as f64)
        {
            continue;
        }
        // Targets of 0.6 m: quadrants of 0.3 m, searched within 1 m.
        let q = (0.3 / gsd).round() as i64;
        let r = (1.0 / gsd).round() as i64;
        let c = checker_centre(&img, w, h, expected, r, q)
            .unwrap_or_else(|| panic!("{name}: no target found near pixel {expected:?}"));
        let off = ((c.0 - expected.0).powi(2) + (c.1 - expected.1).powi(2)).sqrt();
        eprintln!(
            "{name}: target at ({:.1}, {:.1}), surveyed at ({:.1}, {:.1}): {off:.2} px = {:.3} m",
            c.0,
            c.1,
            expected.0,
            expected.1,
            off * gsd
        );
        assert!(
            off <= 2.0,
            "{name}: {off:.2} px from its surveyed position (GSD {gsd} m)"
        );
        worst = worst.max(off);
        found += 1;
    }
    eprintln!(
        "{found} targets, worst {worst:.2} px ({:.3} m) at GSD {gsd} m",
        worst * gsd
    );
    assert!(found >= 6, "only {found} GCP targets in the site image");
}

#[test]
fn plots_site_images_and_the_annotated_video_are_written_and_linked() {
    let (_, out) = fixture();
    let report = std::fs::read_to_string(out.join("report.md")).unwrap();
    for f in [
        "plots/speed.png",
        "plots/people.png",
        "plots/sigma_image.png",
        "plots/fundamental.png",
        "site.png",
        "site_speed.png",
    ] {
        let bytes = std::fs::read(out.join(f)).unwrap();
        assert!(bytes.starts_with(b"\x89PNG"), "{f}");
        assert!(
            report.contains(&format!("]({f})")),
            "report.md does not link {f}"
        );
    }
    assert!(report.contains("(site.tif)") && report.contains("(annotated.mp4)"));
    // The annotated video has every frame (4 s at 15 frames/s), at the width asked for.
    let cap = opencv::videoio::VideoCapture::from_file(
        out.join("annotated.mp4").to_str().unwrap(),
        opencv::videoio::CAP_ANY,
    )
    .unwrap();
    use opencv::prelude::*;
    assert_eq!(
        cap.get(opencv::videoio::CAP_PROP_FRAME_COUNT).unwrap(),
        60.0
    );
    assert_eq!(
        cap.get(opencv::videoio::CAP_PROP_FRAME_WIDTH).unwrap(),
        960.0
    );
    // QGIS's default styles inside the GeoPackage: lines by identity, points by time.
    let gpkg = gdal::Dataset::open(out.join("trajectories.gpkg")).unwrap();
    let rs = gpkg
        .execute_sql(
            "SELECT f_table_name, styleQML, useAsDefault FROM layer_styles ORDER BY f_table_name",
            None,
            gdal::vector::sql::Dialect::DEFAULT,
        )
        .unwrap()
        .unwrap();
    use gdal::vector::LayerAccess;
    let mut rs = rs;
    let styles: Vec<(String, String, i64)> = rs
        .features()
        .map(|f| {
            (
                f.field_as_string(0).unwrap().unwrap(),
                f.field_as_string(1).unwrap().unwrap(),
                f.field_as_integer64(2).unwrap().unwrap(),
            )
        })
        .collect();
    assert_eq!(styles.len(), 2, "{styles:?}");
    assert_eq!((styles[0].0.as_str(), styles[0].2), ("positions", 1));
    assert!(styles[0].1.contains("time_s") && styles[0].1.contains("<qgis"));
    assert_eq!((styles[1].0.as_str(), styles[1].2), ("trajectories", 1));
    assert!(styles[1].1.contains("&quot;id&quot;"));
    // Frames with people in the measurement area.
    let rows = common::read_csv(&out.join("measures.csv"));
    assert_eq!(rows.len(), 60);
    assert!(rows.iter().any(|r| common::num(r, "inside") > 0.0));
}

#[test]
fn render_makes_the_views_again_from_the_stages_and_refuses_a_folder_without_a_run() {
    let (dir, out) = fixture();
    // A copy of the run folder, so that the other tests' files stay as they are.
    let copy = dir.path().join("render-copy");
    let status = std::process::Command::new("cp")
        .arg("-r")
        .arg(out)
        .arg(&copy)
        .status()
        .unwrap();
    assert!(status.success());
    std::fs::remove_file(copy.join("site.tif")).unwrap();
    let o = geostride()
        .args(["render", "--no-video", "-q"])
        .arg(&copy)
        .output()
        .unwrap();
    assert_success(&o);
    assert!(copy.join("site.tif").is_file());
    let report: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(copy.join("report.json")).unwrap()).unwrap();
    assert!(report["views"].as_array().unwrap().len() >= 7);
    // A run given its project file by a relative path records it absolute: render may run
    // from any folder.
    let o = geostride()
        .current_dir(dir.path())
        .args(["run", "project.toml", "--out", "relative", "-q"])
        .output()
        .unwrap();
    assert_success(&o);
    let report: serde_json::Value = serde_json::from_str(
        &std::fs::read_to_string(dir.path().join("relative/report.json")).unwrap(),
    )
    .unwrap();
    assert_eq!(
        Path::new(report["project_file"].as_str().unwrap()),
        dir.path().join("project.toml").canonicalize().unwrap()
    );
    // A folder without a run: exit status 2 and what to give.
    let o = geostride()
        .args(["render"])
        .arg(dir.path())
        .output()
        .unwrap();
    assert_eq!(o.status.code(), Some(2));
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(
        err.contains("report.json") && err.contains("output folder"),
        "{err}"
    );
}

/// PedPy and JuPedSim from PyPI (pinned) in a throwaway environment, made once for the tests
/// that use it: `None` (the test skipped, and says why) when they cannot be installed outside
/// CI; in CI a failure.
fn pedpy_python() -> Option<PathBuf> {
    static PYTHON: OnceLock<Option<(tempfile::TempDir, PathBuf)>> = OnceLock::new();
    PYTHON
        .get_or_init(|| {
            let in_ci = std::env::var("CI").is_ok_and(|v| v == "true" || v == "1");
            let dir = tempfile::tempdir().unwrap();
            let venv = dir.path().join("pedpy-venv");
            let ok = std::process::Command::new("python3")
                .args(["-m", "venv"])
                .arg(&venv)
                .status()
                .is_ok_and(|s| s.success())
                && std::process::Command::new(venv.join("bin/pip"))
                    .args(["install", "-q", "--disable-pip-version-check"])
                    .args(["pedpy==1.5.1", "jupedsim==1.4.2"])
                    .status()
                    .is_ok_and(|s| s.success());
            if ok {
                let python = venv.join("bin/python");
                return Some((dir, python));
            }
            let why = "python3 -m venv and pip install pedpy jupedsim failed (no python3-venv, or PyPI unreachable)";
            if in_ci {
                panic!("the PedPy test cannot run in CI: {why}");
            }
            eprintln!("SKIPPED: {why}");
            None
        })
        .as_ref()
        .map(|(_, p)| p.clone())
}

/// Loads the run's trajectories in PedPy as argv[1] says (`txt`: the PeTrack text with the
/// project's walkable area; `hdf5`, `sqlite`: the archive with the walkable area it holds,
/// which must be the one `walkable_area.wkt` gives) and prints its measures frame by frame.
const PEDPY_SCRIPT: &str = r#"
import json, pathlib, sys
import pedpy, shapely
kind, path = sys.argv[1], pathlib.Path(sys.argv[2])
if kind == "txt":
    traj = pedpy.load_trajectory(trajectory_file=path)
    walk = pedpy.WalkableArea(json.loads(sys.argv[3]))
elif kind == "hdf5":
    traj = pedpy.load_trajectory_from_ped_data_archive_hdf5(trajectory_file=path)
    walk = pedpy.load_walkable_area_from_ped_data_archive_hdf5(trajectory_file=path)
else:
    traj = pedpy.load_trajectory_from_jupedsim_sqlite(trajectory_file=path)
    walk = pedpy.load_walkable_area_from_jupedsim_sqlite(trajectory_file=path)
if kind != "txt":
    written = shapely.from_wkt(open(path.parent / "walkable_area.wkt").read())
    assert walk.polygon.equals(written), (walk.polygon.wkt, written.wkt)
    given = shapely.Polygon(json.loads(sys.argv[3]))
    assert walk.polygon.symmetric_difference(given).area < 1e-6, (walk.polygon.wkt, given.wkt)
ma = pedpy.MeasurementArea(json.loads(sys.argv[4]))
print("frame_rate", traj.frame_rate, "points", len(traj.data))
cells = pedpy.compute_individual_voronoi_polygons(traj_data=traj, walkable_area=walk)
vdens, inter = pedpy.compute_voronoi_density(individual_voronoi_data=cells, measurement_area=ma)
cdens = pedpy.compute_classic_density(traj_data=traj, measurement_area=ma)
speed = pedpy.compute_individual_speed(traj_data=traj, frame_step=int(sys.argv[5]),
    speed_calculation=pedpy.SpeedCalculation.BORDER_SINGLE_SIDED)
vspeed = pedpy.compute_voronoi_speed(traj_data=traj, individual_speed=speed,
    individual_voronoi_intersection=inter, measurement_area=ma)
mspeed = pedpy.compute_mean_speed_per_frame(traj_data=traj, individual_speed=speed, measurement_area=ma)
for f in vdens.index:
    print(f, vdens.loc[f, "density"], cdens.loc[f, "density"], vspeed.loc[f, "speed"],
          mspeed.loc[f, "speed"] if f in mspeed.index else 0.0)
"#;

/// `script` written as `dir/name` and run by `python` with `args`: its standard output (the
/// test fails on a non-zero exit, with the script's errors).
fn run_python(
    python: &Path,
    dir: &Path,
    (name, script): (&str, &str),
    args: &[&std::ffi::OsStr],
) -> String {
    let path = dir.join(name);
    std::fs::write(&path, script).unwrap();
    let o = std::process::Command::new(python)
        .arg(&path)
        .args(args)
        .output()
        .unwrap();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    String::from_utf8(o.stdout).unwrap()
}

/// PedPy's measures from the run's file `file` read as `kind` against geostride's
/// `measures.csv`: every frame's Voronoi density and the means of the four measures within
/// `tolerance` (relative).
fn pedpy_agrees(kind: &str, file: &str, tolerance: f64) {
    let (dir, out) = fixture();
    let Some(python) = pedpy_python() else {
        return;
    };
    // PedPy differences positions 2 frames either side (0.27 s at 15 frames/s).
    let path = out.join(file);
    let text = run_python(
        &python,
        dir.path(),
        (&format!("pedpy_check_{kind}.py"), PEDPY_SCRIPT),
        &[
            kind.as_ref(),
            path.as_os_str(),
            WALKABLE.as_ref(),
            MEASUREMENT.as_ref(),
            "2".as_ref(),
        ],
    );
    let mut lines = text.lines();
    let head: Vec<&str> = lines.next().unwrap().split_whitespace().collect();
    assert_eq!(head[1].parse::<f64>().unwrap(), 15.0, "frame rate: {text}");
    let ours: Vec<_> = common::read_csv(&out.join("measures.csv"));
    let by_frame: std::collections::HashMap<usize, &std::collections::HashMap<String, String>> =
        ours.iter()
            .map(|r| (common::num(r, "frame") as usize, r))
            .collect();
    let (mut sums, mut worst_density) = ([0.0f64; 8], 0.0f64);
    let mut frames = 0;
    for line in lines {
        let v: Vec<f64> = line
            .split_whitespace()
            .map(|t| t.parse().unwrap())
            .collect();
        let g = by_frame[&(v[0] as usize)];
        let (vd, cd, vs, ms) = (
            common::num(g, "voronoi_density_1_m2"),
            common::num(g, "classic_density_1_m2"),
            common::num(g, "voronoi_speed_m_s"),
            g["mean_speed_m_s"].parse::<f64>().unwrap_or(0.0),
        );
        if vd > 0.0 {
            worst_density = worst_density.max((v[1] - vd).abs() / vd);
        }
        for (k, x) in [v[1], vd, v[2], cd, v[3], vs, v[4], ms]
            .into_iter()
            .enumerate()
        {
            sums[k] += x;
        }
        frames += 1;
    }
    assert_eq!(frames, 60, "PedPy's frames: {text}");
    let rel = |a: f64, b: f64| (a - b).abs() / b.abs().max(1e-12);
    eprintln!(
        "PedPy ({kind}) / geostride over {frames} frames: Voronoi density {:.4} / {:.4} (worst frame {:.2e}), classic {:.4} / {:.4}, Voronoi speed {:.4} / {:.4} m/s, mean speed {:.4} / {:.4} m/s",
        sums[0] / 60.0,
        sums[1] / 60.0,
        worst_density,
        sums[2] / 60.0,
        sums[3] / 60.0,
        sums[4] / 60.0,
        sums[5] / 60.0,
        sums[6] / 60.0,
        sums[7] / 60.0
    );
    assert!(
        worst_density < tolerance,
        "Voronoi density differs by {worst_density:.4} in a frame"
    );
    for (k, what) in [
        (0, "Voronoi density"),
        (2, "classic density"),
        (4, "Voronoi speed"),
        (6, "mean speed"),
    ] {
        let d = rel(sums[k], sums[k + 1]);
        assert!(
            d < tolerance,
            "{what}: PedPy {} against geostride {} ({:.2} %)",
            sums[k],
            sums[k + 1],
            100.0 * d
        );
    }
}

#[test]
fn pedpy_reads_the_petrack_file_and_agrees_with_geostride_within_two_percent() {
    // The text's positions are rounded to 0.1 mm.
    pedpy_agrees("txt", "trajectories.txt", 0.02);
}

#[test]
fn pedpy_reads_the_hdf5_archive_and_its_walkable_area_and_agrees_within_one_percent() {
    pedpy_agrees("hdf5", "trajectories.h5", 0.01);
}

#[test]
fn pedpy_reads_the_jupedsim_sqlite_and_its_walkable_area_and_agrees_within_one_percent() {
    pedpy_agrees("sqlite", "trajectories.sqlite", 0.01);
}

/// Whether segment `a`–`b` crosses segment `c`–`d` (their ends strictly on either side).
fn crosses(a: [f64; 2], b: [f64; 2], c: [f64; 2], d: [f64; 2]) -> bool {
    let side = |p: [f64; 2], q: [f64; 2], r: [f64; 2]| {
        ((q[0] - p[0]) * (r[1] - p[1]) - (q[1] - p[1]) * (r[0] - p[0])).signum()
    };
    side(a, b, c) * side(a, b, d) < 0.0 && side(c, d, a) * side(c, d, b) < 0.0
}

/// The measurement lines geostride writes (`measurement_lines.wkt`, `areas.geojson`) read by
/// PedPy as its `MeasurementLine`s: its N(t) counts as many people across each as the
/// trajectories say.
#[test]
fn pedpy_counts_the_people_across_geostrides_measurement_lines() {
    let (dir, out) = fixture();
    let wkt = std::fs::read_to_string(out.join("measurement_lines.wkt")).unwrap();
    assert_eq!(
        wkt,
        "LINESTRING (0.0000 -2.5000, 0.0000 2.5000)\nLINESTRING (-10.0000 -2.5000, -10.0000 2.5000)\n"
    );
    let areas: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(out.join("areas.geojson")).unwrap()).unwrap();
    let lines: Vec<_> = areas["features"]
        .as_array()
        .unwrap()
        .iter()
        .filter(|f| f["properties"]["role"] == "measurement_line")
        .collect();
    assert_eq!(lines.len(), 2, "{areas}");
    for l in &lines {
        assert_eq!(l["geometry"]["type"], "LineString");
        assert_eq!(l["geometry"]["coordinates"].as_array().unwrap().len(), 2);
        assert!((l["properties"]["length_m"].as_f64().unwrap() - 5.0).abs() < 1e-9);
    }
    // Who crosses each line, from the trajectories.
    let rows = common::read_csv(&out.join("trajectories.csv"));
    let mut by_id: std::collections::BTreeMap<String, Vec<(f64, [f64; 2])>> = Default::default();
    for r in &rows {
        by_id.entry(r["id"].clone()).or_default().push((
            common::num(r, "frame"),
            [common::num(r, "e_m"), common::num(r, "n_m")],
        ));
    }
    let ends = [([0.0, -2.5], [0.0, 2.5]), ([-10.0, -2.5], [-10.0, 2.5])];
    for t in by_id.values_mut() {
        t.sort_by(|a, b| a.0.total_cmp(&b.0));
    }
    let ours: Vec<usize> = ends
        .iter()
        .map(|&(c, d)| {
            by_id
                .values()
                .filter(|t| {
                    t.windows(2)
                        .any(|w| w[1].0 == w[0].0 + 1.0 && crosses(w[0].1, w[1].1, c, d))
                })
                .count()
        })
        .collect();
    assert!(ours.iter().all(|&n| n > 0), "nobody crosses: {ours:?}");
    // A line of one point: refused before any work, with its key and line, exit 2.
    let text = std::fs::read_to_string(dir.path().join("project.toml")).unwrap();
    let bad = dir.path().join("bad-line.toml");
    std::fs::write(&bad, text.replace(LINES, "[[[1.0, 2.0], [1.0, 2.0]]]")).unwrap();
    let o = common::run_project(&bad, &dir.path().join("bad-line"));
    assert_eq!(o.status.code(), Some(2));
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(
        err.contains("analysis.measurement_lines") && err.contains("bad-line.toml:"),
        "{err}"
    );
    let Some(python) = pedpy_python() else {
        return;
    };
    let (h5, wkt) = (
        out.join("trajectories.h5"),
        out.join("measurement_lines.wkt"),
    );
    let text = run_python(
        &python,
        dir.path(),
        (
            "pedpy_lines.py",
            r#"
import pathlib, sys, pedpy, shapely
traj = pedpy.load_trajectory_from_ped_data_archive_hdf5(trajectory_file=pathlib.Path(sys.argv[1]))
for line in open(sys.argv[2]).read().splitlines():
    ml = pedpy.MeasurementLine(shapely.from_wkt(line))
    nt, crossing = pedpy.compute_n_t(traj_data=traj, measurement_line=ml)
    print(crossing["id"].nunique())
"#,
        ),
        &[h5.as_os_str(), wkt.as_os_str()],
    );
    let pedpy: Vec<usize> = text.lines().map(|l| l.trim().parse().unwrap()).collect();
    eprintln!("people across the lines: PedPy {pedpy:?}, the trajectories {ours:?}");
    assert_eq!(pedpy, ours);
}

/// JuPedSim's own reader (`jupedsim.Recording`) opens the SQLite: its frame count, frame rate,
/// bounds, geometry and a frame's agents are those of the run's trajectories.
#[test]
fn jupedsim_opens_the_sqlite() {
    let (dir, out) = fixture();
    let Some(python) = pedpy_python() else {
        return;
    };
    let sqlite = out.join("trajectories.sqlite");
    let text = run_python(
        &python,
        dir.path(),
        (
            "jupedsim_check.py",
            r#"
import sys, jupedsim
rec = jupedsim.Recording(sys.argv[1])
frame = rec.frame(30)
print(rec.num_frames, rec.fps, rec.geometry().area, len(frame.agents))
for a in frame.agents:
    print(a.id, a.position[0], a.position[1], a.orientation[0], a.orientation[1])
"#,
        ),
        &[sqlite.as_os_str()],
    );
    let mut lines = text.lines();
    let head: Vec<f64> = lines
        .next()
        .unwrap()
        .split_whitespace()
        .map(|t| t.parse().unwrap())
        .collect();
    let rows = common::read_csv(&out.join("trajectories.csv"));
    let last = rows
        .iter()
        .map(|r| common::num(r, "frame"))
        .fold(0.0, f64::max);
    assert_eq!(head[0], last + 1.0, "frames from 0 to the last: {text}");
    assert_eq!(head[1], 15.0, "fps: {text}");
    assert!(
        (head[2] - 80.0 * 5.0).abs() < 1e-6,
        "the deck's 80 × 5 m: {text}"
    );
    let at30: Vec<_> = rows
        .iter()
        .filter(|r| common::num(r, "frame") == 30.0)
        .collect();
    assert_eq!(head[3] as usize, at30.len(), "{text}");
    assert!(!at30.is_empty());
    for line in lines {
        let v: Vec<f64> = line
            .split_whitespace()
            .map(|t| t.parse().unwrap())
            .collect();
        let r = at30
            .iter()
            .find(|r| common::num(r, "id") == v[0])
            .unwrap_or_else(|| panic!("agent {} is not in trajectories.csv: {text}", v[0]));
        assert!((v[1] - common::num(r, "e_m")).abs() < 1e-3, "{line}");
        assert!((v[2] - common::num(r, "n_m")).abs() < 1e-3, "{line}");
        assert!(
            (v[3].hypot(v[4]) - 1.0).abs() < 1e-9,
            "orientation a unit vector: {line}"
        );
    }
}

/// `areas.geojson` holds the walkable and measurement areas in WGS 84 where the site frame puts
/// them: each polygon's area on the ground (from its longitudes and latitudes) is the site
/// frame's, the measurement area lies inside the walkable one, and the WKT files say the same.
#[test]
fn the_areas_are_written_as_wkt_and_as_geojson_in_wgs84() {
    let (_, out) = fixture();
    let j: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(out.join("areas.geojson")).unwrap()).unwrap();
    let f = j["features"].as_array().unwrap();
    // The two areas, then the two measurement lines (`pedpy_counts_the_people_across_...`).
    assert_eq!(f.len(), 4);
    let ring = |k: usize| -> Vec<(f64, f64)> {
        f[k]["geometry"]["coordinates"][0]
            .as_array()
            .unwrap()
            .iter()
            .map(|c| (c[0].as_f64().unwrap(), c[1].as_f64().unwrap()))
            .collect()
    };
    // The shoelace area on a local equirectangular projection (exact enough over 80 m).
    let ground_area = |r: &[(f64, f64)]| {
        let (lon0, lat0) = r[0];
        let m = 6_371_000.0f64.to_radians();
        let xy: Vec<(f64, f64)> = r
            .iter()
            .map(|(lon, lat)| ((lon - lon0) * m * lat0.to_radians().cos(), (lat - lat0) * m))
            .collect();
        0.5 * xy
            .windows(2)
            .map(|w| w[0].0 * w[1].1 - w[1].0 * w[0].1)
            .sum::<f64>()
            .abs()
    };
    for (k, role, area, file) in [
        (0, "walkable", 400.0, "walkable_area.wkt"),
        (1, "measurement", 60.0, "measurement_area.wkt"),
    ] {
        let p = &f[k]["properties"];
        assert_eq!(p["role"], role);
        assert_eq!(p["area_m2"].as_f64(), Some(area));
        let wkt = std::fs::read_to_string(out.join(file)).unwrap();
        assert_eq!(p["site_frame_wkt"].as_str().unwrap(), wkt.trim());
        let r = ring(k);
        assert_eq!(r.first(), r.last());
        let a = ground_area(&r);
        assert!(
            (a - area).abs() < 0.005 * area,
            "{role}: {a} m² on the ground, {area} in the site frame"
        );
    }
    assert_eq!(f[0]["properties"]["source"], "[analysis] walkable_area");
    let (walk, meas) = (ring(0), ring(1));
    let (lo, hi) = walk.iter().fold(
        ((f64::MAX, f64::MAX), (f64::MIN, f64::MIN)),
        |(lo, hi), &(x, y)| ((lo.0.min(x), lo.1.min(y)), (hi.0.max(x), hi.1.max(y))),
    );
    // The two share the deck's edges: inside within 3e-9° (0.3 mm; 9 decimals are written).
    let e = 3e-9;
    assert!(
        meas.iter()
            .all(|&(x, y)| x > lo.0 - e && x < hi.0 + e && y > lo.1 - e && y < hi.1 + e)
    );
}
