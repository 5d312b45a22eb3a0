//! `geostride survey inspect` and `survey convert` end to end: the real OpenDroneMap lists,
//! round trips through WGS 84, GIS outputs opened by ogrinfo, Helmert fits, bad inputs.

#![cfg(all(feature = "opencv", feature = "gdal", feature = "onnx"))]

mod common;

use std::path::{Path, PathBuf};
use std::process::Output;

fn run(args: &[&str], paths: &[&Path]) -> Output {
    let mut c = common::geostride();
    c.args(args);
    for p in paths {
        c.arg(p);
    }
    c.output().unwrap()
}

fn ok(o: &Output) -> String {
    assert!(
        o.status.success(),
        "exit {:?}\nstdout: {}\nstderr: {}",
        o.status.code(),
        String::from_utf8_lossy(&o.stdout),
        String::from_utf8_lossy(&o.stderr)
    );
    String::from_utf8_lossy(&o.stdout).into_owned()
}

fn stderr(o: &Output) -> String {
    String::from_utf8_lossy(&o.stderr).into_owned()
}

fn inspect_json(file: &Path, extra: &[&str]) -> serde_json::Value {
    let mut args = vec!["survey", "inspect", "--json"];
    args.extend(extra);
    serde_json::from_str(&ok(&run(&args, &[file]))).unwrap()
}

/// Every gcp_list.txt in the shared data, with its number of points and observations (counted by
/// hand: rows, and distinct names or coordinates).
const ODM_LISTS: [(&str, u64, u64); 7] = [
    ("odm_data_bellus/gcp_list.txt", 4, 4),
    ("sekilab_OpenDroneMapExercise/gcp_list.txt", 6, 33),
    ("yjmenezes_odm_br/gcp_list.txt", 6, 25),
    ("yjmenezes_odm_br/odm_gcp_br/gcp_list.txt", 6, 25),
    // 74 rows, two of them HV11 at two places in IMG_5352.JPG (lines 47, 48): both dropped.
    ("yjmenezes_odm_br/odm_gcp_br/gcp_list_chk_raw.txt", 15, 72),
    // 82 rows, the same HV11 pair on lines 51 and 52.
    (
        "yjmenezes_odm_br/odm_gcp_br/gcp_list_floatxy_raw.txt",
        19,
        80,
    ),
    ("yjmenezes_odm_br/odm_gcp_br/gcp_list_raw.txt", 6, 25),
];

fn positions(v: &serde_json::Value) -> Vec<(String, [f64; 3])> {
    v["points"]
        .as_array()
        .unwrap()
        .iter()
        .map(|p| {
            let pos: Vec<f64> = p["position"]
                .as_array()
                .unwrap()
                .iter()
                .map(|x| x.as_f64().unwrap_or(f64::NAN))
                .collect();
            (
                p["name"].as_str().unwrap().to_string(),
                [pos[0], pos[1], pos[2]],
            )
        })
        .collect()
}

#[test]
fn every_odm_list_parses_with_the_right_counts_and_round_trips_through_wgs84() {
    let Some(dir) = common::data_dir("odm-gcp-lists") else {
        return;
    };
    let tmp = tempfile::tempdir().unwrap();
    for (i, (rel, points, observations)) in ODM_LISTS.iter().enumerate() {
        let file = dir.join(rel);
        let v = inspect_json(&file, &[]);
        assert_eq!(v["counts"]["points"], *points, "{rel}");
        assert_eq!(v["counts"]["observations"], *observations, "{rel}");
        let table = ok(&run(&["survey", "inspect"], &[&file]));
        assert!(
            table.contains(&format!("{points} point(s)"))
                && table.contains(&format!("{observations} observation(s)")),
            "{table}"
        );
        if rel.ends_with("_raw.txt") && *points > 6 {
            assert!(
                table.contains("2 row(s) dropped") && table.contains("at two places"),
                "{table}"
            );
        }

        // To WGS 84 longitude/latitude and back to the list's own CRS.
        let original_crs = v["crs"].as_str().unwrap().to_string();
        let wgs = tmp.path().join(format!("wgs{i}.txt"));
        ok(&run(
            &[
                "survey",
                "convert",
                "--to",
                "odm",
                "--to-crs",
                "EPSG:4326",
                "-o",
            ],
            &[&wgs, &file],
        ));
        assert!(
            std::fs::read_to_string(&wgs)
                .unwrap()
                .starts_with("EPSG:4326\n")
        );
        let back = tmp.path().join(format!("back{i}.txt"));
        ok(&run(
            &[
                "survey",
                "convert",
                "--to",
                "odm",
                "--to-crs",
                &original_crs,
                "-o",
            ],
            &[&back, &wgs],
        ));
        let (a, b) = (positions(&v), positions(&inspect_json(&back, &[])));
        assert_eq!(a.len(), b.len());
        for ((na, pa), (nb, pb)) in a.iter().zip(&b) {
            let d = ((pa[0] - pb[0]).powi(2) + (pa[1] - pb[1]).powi(2)).sqrt();
            assert!(d < 0.001, "{rel} {na}/{nb}: {d} m after the round trip");
            assert!(
                pa[2] == pb[2] || (pa[2].is_nan() && pb[2].is_nan()),
                "heights are carried unchanged"
            );
        }
    }
}

fn ogrinfo(path: &Path) -> String {
    let o = std::process::Command::new("ogrinfo")
        .args(["-so", "-al"])
        .arg(path)
        .output()
        .expect("ogrinfo (gdal-bin) is installed by scripts/bootstrap.sh");
    assert!(
        o.status.success(),
        "ogrinfo failed on {}: {}",
        path.display(),
        String::from_utf8_lossy(&o.stderr)
    );
    String::from_utf8_lossy(&o.stdout).into_owned()
}

#[test]
fn geopackage_and_geojson_open_in_ogrinfo_with_the_right_crs() {
    let Some(dir) = common::data_dir("odm-gcp-lists") else {
        return;
    };
    let file = dir.join("yjmenezes_odm_br/odm_gcp_br/gcp_list_chk_raw.txt");
    let tmp = tempfile::tempdir().unwrap();
    let gpkg = tmp.path().join("gcps.gpkg");
    ok(&run(
        &["survey", "convert", "--to", "gpkg", "-o"],
        &[&gpkg, &file],
    ));
    let info = ogrinfo(&gpkg);
    assert!(info.contains("Feature Count: 15"), "{info}");
    assert!(info.contains("UTM zone 22S"), "{info}");
    assert!(
        info.contains("name: String") && info.contains("e_m: Real"),
        "{info}"
    );

    let geojson = tmp.path().join("gcps.geojson");
    ok(&run(
        &["survey", "convert", "--to", "geojson", "-o"],
        &[&geojson, &file],
    ));
    let info = ogrinfo(&geojson);
    assert!(
        info.contains("Feature Count: 15") && info.contains("WGS 84"),
        "{info}"
    );
    // RFC 7946: longitude first, in degrees (this site is at 49.4° W, 25.6° S).
    let g: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(&geojson).unwrap()).unwrap();
    let c = &g["features"][0]["geometry"]["coordinates"];
    assert!(
        (c[0].as_f64().unwrap() + 49.42).abs() < 0.01
            && (c[1].as_f64().unwrap() + 25.61).abs() < 0.01,
        "{c}"
    );
    assert!(g.get("crs").is_none(), "RFC 7946 has no crs member");

    // A GeoPackage in another CRS, asked for explicitly.
    let gpkg2 = tmp.path().join("sirgas.gpkg");
    ok(&run(
        &[
            "survey",
            "convert",
            "--to",
            "gpkg",
            "--to-crs",
            "EPSG:31982",
            "-o",
        ],
        &[&gpkg2, &file],
    ));
    assert!(ogrinfo(&gpkg2).contains("SIRGAS 2000 / UTM zone 22S"));
}

/// Model coordinates of the GCPs of `odm_gcp_br/gcp_list.txt` as OpenDroneMap's georeferencing
/// log lists them, one line per observation in file order.
fn odm_model_positions(log: &str) -> Vec<[f64; 3]> {
    log.lines()
        .filter(|l| l.starts_with("Position in model for gcp"))
        .map(|l| {
            let v: Vec<f64> = l
                .split_whitespace()
                .filter_map(|t| t.split('=').nth(1))
                .map(|x| x.parse().unwrap())
                .collect();
            [v[0], v[1], v[2]]
        })
        .collect()
}

#[test]
fn helmert_fit_of_real_gcps_onto_opendronemaps_model() {
    let Some(dir) = common::data_dir("odm-gcp-lists") else {
        return;
    };
    let base = dir.join("yjmenezes_odm_br/odm_gcp_br");
    let list = std::fs::read_to_string(base.join("gcp_list.txt")).unwrap();
    let model = odm_model_positions(
        &std::fs::read_to_string(base.join("odm_georeferencing_log.txt")).unwrap(),
    );
    let rows: Vec<Vec<&str>> = list
        .lines()
        .skip(1)
        .map(|l| l.split_whitespace().collect())
        .collect();
    assert_eq!(
        rows.len(),
        model.len(),
        "one model position per observation"
    );
    // Mean model position per named GCP: a reference in ODM's local model frame.
    let mut names: Vec<&str> = Vec::new();
    for r in &rows {
        if !names.contains(&r[6]) {
            names.push(r[6]);
        }
    }
    let tmp = tempfile::tempdir().unwrap();
    let mut csv = String::from("name,x,y,z\n");
    for n in &names {
        let ps: Vec<&[f64; 3]> = rows
            .iter()
            .zip(&model)
            .filter(|(r, _)| r[6] == *n)
            .map(|(_, m)| m)
            .collect();
        let mean: Vec<f64> = (0..3)
            .map(|k| ps.iter().map(|p| p[k]).sum::<f64>() / ps.len() as f64)
            .collect();
        csv += &format!("{n},{},{},{}\n", mean[0], mean[1], mean[2]);
    }
    let model_csv = tmp.path().join("model.csv");
    std::fs::write(&model_csv, csv).unwrap();
    let v = inspect_json(
        &base.join("gcp_list.txt"),
        &[
            "--height",
            "ellipsoidal",
            "--fit-to",
            model_csv.to_str().unwrap(),
            "--fit-to-crs",
            "local",
            "--check",
            "HV07",
        ],
    );
    let fit = &v["fit"];
    let control = fit["control"]["total_m"].as_f64().unwrap();
    let check = fit["check"]["total_m"].as_f64().unwrap();
    println!(
        "ODM model: scale {} control RMSE {control:.3} m check RMSE {check:.3} m",
        fit["scale"]
    );
    // ODM reports a mean georeferencing error of 0.093 m for its best triplet; the model's scale
    // is about 1/1.027 of the ground's.
    assert!(control < 0.15, "control RMSE {control}");
    assert!(check < 0.3, "check RMSE {check}");
    assert_eq!(fit["control"]["count"], 5);
    assert_eq!(fit["check"]["count"], 1);
    let s = fit["scale"].as_f64().unwrap();
    assert!((s * 1.027 - 1.0).abs() < 0.02, "scale {s}");
}

fn write(dir: &Path, name: &str, text: &str) -> PathBuf {
    let p = dir.join(name);
    std::fs::write(&p, text).unwrap();
    p
}

#[test]
fn emlid_file_inspected_with_warnings_dropped_rows_and_a_local_fit() {
    let tmp = tempfile::tempdir().unwrap();
    let header = "Name,Easting,Northing,Elevation,Description,Longitude,Latitude,Ellipsoidal height,Easting RMS,Northing RMS,Elevation RMS,Lateral RMS,Antenna height,Antenna height units,Solution status,Averaging start,Averaging end,Samples,PDOP,Base easting,Base northing,Base elevation,Base longitude,Base latitude,Base ellipsoidal height,Baseline,CS name";
    let mut text = format!("{header}\n");
    let pts = [
        ("A", 0.0, 0.0, 10.0),
        ("B", 40.0, 0.0, 10.5),
        ("C", 40.0, 30.0, 11.0),
        ("D", 0.0, 30.0, 10.2),
        ("CHK-E", 20.0, 15.0, 10.6),
        ("F", 10.0, 25.0, 10.4),
    ];
    for (i, (n, e, nn, z)) in pts.iter().enumerate() {
        let status = if i == 5 { "FLOAT" } else { "FIX" };
        text += &format!(
            "{n},{},{},{z},,,,,0.01,0.01,0.02,,,,{status},,,,,,,,,,,,ETRS89 / Belgian Lambert 2008\n",
            649_000.0 + e,
            665_000.0 + nn
        );
    }
    let emlid = write(tmp.path(), "emlid.csv", &text);
    let table = ok(&run(&["survey", "inspect", "--fix-only"], &[&emlid]));
    assert!(table.contains("5 point(s): 4 control, 1 check"), "{table}");
    assert!(
        table.contains("dropped") && table.contains("point F has solution FLOAT"),
        "{table}"
    );
    let table = ok(&run(&["survey", "inspect"], &[&emlid]));
    assert!(
        table.contains("warning: point F (line 7) has solution FLOAT"),
        "{table}"
    );
    assert!(table.contains("ETRS89 / Belgian Lambert 2008"), "{table}");

    // A fit of a local copy (metres, named like the survey) onto the survey: residuals tiny.
    let mut local = String::from(
        "#CoordinateSystem: Local Coordinates (m)\n#Label,X/Easting,Y/Northing,Z/Altitude\n",
    );
    for (n, e, nn, z) in &pts {
        local += &format!("{n},{},{},{}\n", -nn + 5.0, e - 3.0, z - 10.0);
    }
    let local_file = write(tmp.path(), "local.csv", &local);
    let v = inspect_json(&local_file, &["--fit-to", emlid.to_str().unwrap()]);
    assert_eq!(v["crs"], serde_json::Value::Null);
    let fit = &v["fit"];
    assert!(fit["control"]["total_m"].as_f64().unwrap() < 0.01, "{fit}");
    assert_eq!(fit["check"]["count"], 1);
    // Lambert 2008 grid distances differ from ground distances by the grid scale (about -1e-4).
    assert!(fit["scale_ppm"].as_f64().unwrap().abs() < 300.0, "{fit}");
}

#[test]
fn bad_inputs_exit_2_with_the_file_and_line() {
    let tmp = tempfile::tempdir().unwrap();
    let o = run(&["survey", "inspect"], &[&tmp.path().join("missing.txt")]);
    assert_eq!(o.status.code(), Some(2));
    assert!(stderr(&o).contains("cannot read"), "{}", stderr(&o));

    let f = write(tmp.path(), "what.txt", "hello world\n");
    let o = run(&["survey", "inspect"], &[&f]);
    assert_eq!(o.status.code(), Some(2));
    assert!(
        stderr(&o).contains("cannot tell the format"),
        "{}",
        stderr(&o)
    );

    let f = write(
        tmp.path(),
        "gcp_list.txt",
        "EPSG:32631\n500000 5600000 10 1 2 a.jpg P\n500000 5600000 x 1 2 b.jpg P\n",
    );
    let o = run(&["survey", "inspect"], &[&f]);
    assert_eq!(o.status.code(), Some(2));
    assert!(
        stderr(&o).contains("gcp_list.txt:3: field 'z': expected a number, found 'x'"),
        "{}",
        stderr(&o)
    );

    let f = write(
        tmp.path(),
        "crs.txt",
        "EPSG:123456789\n500000 5600000 10 1 2 a.jpg P\n",
    );
    let o = run(&["survey", "inspect", "--format", "odm"], &[&f]);
    assert_eq!(o.status.code(), Some(2));
    assert!(stderr(&o).contains("crs.txt:1:"), "{}", stderr(&o));

    // Converting into a missing folder, or over the input, is refused before any work.
    let good = write(
        tmp.path(),
        "good.txt",
        "EPSG:32631\n500000 5600000 10 1 2 a.jpg P\n",
    );
    let o = run(
        &["survey", "convert", "--to", "csv", "-o"],
        &[&tmp.path().join("no/dir/x.csv"), &good],
    );
    assert_eq!(o.status.code(), Some(2));
    let o = run(&["survey", "convert", "--to", "odm", "-o"], &[&good, &good]);
    assert_eq!(o.status.code(), Some(2));
    assert_eq!(
        std::fs::read_to_string(&good).unwrap(),
        "EPSG:32631\n500000 5600000 10 1 2 a.jpg P\n"
    );
    // Too few points for a fit.
    let o = run(&["survey", "inspect", "--fit-to"], &[&good, &good]);
    assert_eq!(o.status.code(), Some(2));
    assert!(
        stderr(&o).contains("at least 3 control points"),
        "{}",
        stderr(&o)
    );
    // A local survey cannot become GeoJSON.
    let local = write(tmp.path(), "l.3dc", "3\n0 0 0\n100 0 0\n0 100 0\n");
    let o = run(
        &["survey", "convert", "--to", "geojson", "-o"],
        &[&tmp.path().join("l.geojson"), &local],
    );
    assert_eq!(o.status.code(), Some(2));
    assert!(!tmp.path().join("l.geojson").exists());
}

#[test]
fn help_documents_every_survey_option() {
    for sub in ["inspect", "convert"] {
        let help = ok(&run(&["survey", sub, "--help"], &[]));
        for opt in [
            "--format",
            "--crs",
            "--height",
            "--fix-only",
            "--columns",
            "--delimiter",
            "--image-size",
            "--picks",
            "--check-prefix",
            "--check",
            "--disable",
            "--origin",
            "--fit-to",
            "--robust",
            "--rigid",
        ] {
            assert!(help.contains(opt), "survey {sub} --help lacks {opt}");
        }
    }
}
