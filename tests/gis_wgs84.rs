//! GeoJSON longitudes and latitudes are WGS 84, datum change included: `geostride run` on a short
//! simulated hover over sites surveyed in Belgian Lambert 72 (BD72, a datum about 100 m from
//! WGS 84), Belgian Lambert 2008 (ETRS89), UTM 31N (WGS 84) and the Swiss LV95 (CH1903+), each
//! point compared with PROJ's own `cs2cs` on the CSV's coordinates in the same CRS.

#![cfg(all(feature = "opencv", feature = "gdal", feature = "onnx"))]

mod common;

use std::io::Write as _;
use std::path::Path;
use std::process::{Command, Stdio};

use common::{assert_success, geostride};

/// A short drifting hover (tests/scenes/hover-drift.toml) moved to `crs` at `origin`.
fn scene(crs: &str, origin: [f64; 3]) -> String {
    let base = std::fs::read_to_string(
        Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/scenes/hover-drift.toml"),
    )
    .unwrap();
    let base = base.replace("duration_s = 4.0", "duration_s = 1.0");
    assert!(base.contains("duration_s = 1.0"));
    // [site] must come before the first table, with the top-level keys.
    let (head, rest) = base.split_at(base.find("\n[camera]").unwrap());
    format!(
        "{head}\n\n[site]\ncrs = \"{crs}\"\norigin = [{}, {}, {}]\n{rest}",
        origin[0], origin[1], origin[2]
    )
}

fn project(video: &str) -> String {
    common::hover_project(
        "WGS 84 test",
        video,
        "kind = \"plane\"",
        "formats = [\"csv\", \"geojson\"]",
    )
}

/// `cs2cs CRS EPSG:4326` on `x y z` rows: (longitude, latitude) in degrees.
fn cs2cs(crs: &str, xyz: &[[f64; 3]]) -> Vec<(f64, f64)> {
    let mut child = Command::new("cs2cs")
        .args(["-f", "%.12f", crs, "EPSG:4326"])
        .stdin(Stdio::piped())
        .stdout(Stdio::piped())
        .spawn()
        .expect("cs2cs (Debian's proj-bin, installed by scripts/bootstrap.sh)");
    {
        let mut stdin = child.stdin.take().unwrap();
        for p in xyz {
            writeln!(stdin, "{:.6} {:.6} {:.6}", p[0], p[1], p[2]).unwrap();
        }
    }
    let out = child.wait_with_output().unwrap();
    assert!(out.status.success());
    String::from_utf8(out.stdout)
        .unwrap()
        .lines()
        .map(|l| {
            // EPSG:4326's own axis order: latitude, longitude.
            let v: Vec<f64> = l.split_whitespace().map(|t| t.parse().unwrap()).collect();
            (v[1], v[0])
        })
        .collect()
}

/// Every (id, frame) → (x, y, z) of trajectories.csv.
fn csv_points(path: &Path) -> std::collections::BTreeMap<(u64, u64), [f64; 3]> {
    let text = std::fs::read_to_string(path).unwrap();
    let mut lines = text.lines();
    let header: Vec<&str> = lines.next().unwrap().split(',').collect();
    let col = |name: &str| header.iter().position(|h| *h == name).unwrap();
    let (id, frame, x, y, z) = (col("id"), col("frame"), col("x"), col("y"), col("z"));
    lines
        .map(|l| {
            let f: Vec<&str> = l.split(',').collect();
            (
                (f[id].parse().unwrap(), f[frame].parse().unwrap()),
                [f[x], f[y], f[z]].map(|v| v.parse().unwrap()),
            )
        })
        .collect()
}

/// (worst difference from cs2cs given the CSV's x y z, the same given x y only), degrees.
fn check_site(crs: &str, origin: [f64; 3]) -> (f64, f64) {
    let tmp = tempfile::tempdir().unwrap();
    let dir = tmp.path();
    let scene_path = dir.join("scene.toml");
    std::fs::write(&scene_path, scene(crs, origin)).unwrap();
    let sim = dir.join("sim");
    assert_success(
        &geostride()
            .arg("simulate")
            .arg(&scene_path)
            .arg("--out")
            .arg(&sim)
            .arg("-q")
            .output()
            .unwrap(),
    );
    let video = common::simulated_video(&sim);
    std::fs::write(sim.join("project.toml"), project(video)).unwrap();
    let out = dir.join("run");
    assert_success(
        &geostride()
            .arg("run")
            .arg(sim.join("project.toml"))
            .arg("--out")
            .arg(&out)
            .arg("-q")
            .output()
            .unwrap(),
    );
    let points = csv_points(&out.join("trajectories.csv"));
    assert!(points.len() > 20, "{crs}: only {} points", points.len());
    let geojson: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(out.join("positions.geojson")).unwrap())
            .unwrap();
    let features = geojson["features"].as_array().unwrap();
    assert_eq!(features.len(), points.len());
    let keys: Vec<(u64, u64)> = features
        .iter()
        .map(|f| {
            let p = &f["properties"];
            (p["id"].as_u64().unwrap(), p["frame"].as_u64().unwrap())
        })
        .collect();
    let xyz: Vec<[f64; 3]> = keys.iter().map(|k| points[k]).collect();
    let worst_against = |reference: &[(f64, f64)]| {
        let mut worst: f64 = 0.0;
        for (f, (lon, lat)) in features.iter().zip(reference) {
            let c = f["geometry"]["coordinates"].as_array().unwrap();
            let (glon, glat) = (c[0].as_f64().unwrap(), c[1].as_f64().unwrap());
            worst = worst.max((glon - lon).abs()).max((glat - lat).abs());
        }
        worst
    };
    let worst = worst_against(&cs2cs(crs, &xyz));
    // The same without heights (cs2cs given x y only): a datum's rotation moves a point 60 m up
    // by a fraction of a millimetre.
    let flat: Vec<[f64; 3]> = xyz.iter().map(|p| [p[0], p[1], 0.0]).collect();
    let worst_flat = worst_against(&cs2cs(crs, &flat));
    let report: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(out.join("report.json")).unwrap()).unwrap();
    let ops = report["wgs84_transformations"].as_array().unwrap();
    assert!(!ops.is_empty(), "{crs}: the report names no transformation");
    eprintln!(
        "{crs}: {} points, worst |GeoJSON − cs2cs| {worst:.1e}° ({worst_flat:.1e}° with cs2cs given no height); {}",
        points.len(),
        ops.iter()
            .map(|o| o.as_str().unwrap())
            .collect::<Vec<_>>()
            .join("; ")
    );
    // The survey itself, converted to GeoJSON.
    let gcps_geojson = dir.join("gcps.geojson");
    assert_success(
        &geostride()
            .args(["survey", "convert"])
            .arg(sim.join("gcps.csv"))
            .args(["--to", "geojson", "-o"])
            .arg(&gcps_geojson)
            .output()
            .unwrap(),
    );
    let gcps: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(&gcps_geojson).unwrap()).unwrap();
    let text = std::fs::read_to_string(sim.join("gcps.csv")).unwrap();
    let xyz: Vec<[f64; 3]> = text
        .lines()
        .skip(1)
        .map(|l| {
            let f: Vec<&str> = l.split(',').collect();
            [f[1], f[2], f[3]].map(|v| v.parse().unwrap())
        })
        .collect();
    let reference = cs2cs(crs, &xyz);
    let features = gcps["features"].as_array().unwrap();
    assert_eq!(features.len(), xyz.len());
    for (f, (lon, lat)) in features.iter().zip(&reference) {
        let c = f["geometry"]["coordinates"].as_array().unwrap();
        let d = (c[0].as_f64().unwrap() - lon)
            .abs()
            .max((c[1].as_f64().unwrap() - lat).abs());
        // Nine decimals: 1e-9° (0.1 mm), where seven would be up to 5 mm off.
        assert!(d < 6e-10, "{crs}: survey GeoJSON {d:e}° from cs2cs");
    }
    (worst, worst_flat)
}

#[test]
fn geojson_matches_cs2cs_in_four_national_crss() {
    let sites: [(&str, [f64; 3]); 4] = [
        // Ghent in Belgian Lambert 72: BD72 is about 100 m from WGS 84 here.
        ("EPSG:31370", [154_503.446, 195_999.262, 52.0]),
        ("EPSG:3812", [654_500.0, 696_000.0, 52.0]),
        ("EPSG:32631", [600_391.449, 5_659_042.609, 52.0]),
        // Bern in the Swiss LV95.
        ("EPSG:2056", [2_600_104.109, 1_199_879.628, 560.0]),
    ];
    for (crs, origin) in sites {
        let (worst, worst_flat) = check_site(crs, origin);
        // The CSV's coordinates are rounded to 0.1 mm and GeoJSON's to 1e-9°: together ≤ 1e-9°.
        assert!(worst < 2e-9, "{crs}: GeoJSON {worst:e}° from cs2cs");
        if crs == "EPSG:31370" {
            // The check, however cs2cs is called.
            assert!(
                worst_flat < 1e-8,
                "{crs}: {worst_flat:e}° from cs2cs without heights"
            );
        }
    }
}
