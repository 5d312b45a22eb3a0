use std::collections::HashMap;
use std::path::Path;

use super::emlid::{COLUMNS_27, COLUMNS_42_EXTRA};
use super::*;
use crate::survey::model::SolutionStatus;

fn write(dir: &Path, name: &str, text: &str) -> std::path::PathBuf {
    let p = dir.join(name);
    std::fs::write(&p, text).unwrap();
    p
}

/// An Emlid CSV with the given columns (in that order) and rows of named values.
fn emlid_csv(columns: &[&str], rows: &[HashMap<&str, String>]) -> String {
    let mut s = columns.join(",") + "\n";
    for r in rows {
        let cells: Vec<String> = columns
            .iter()
            .map(|c| r.get(c).cloned().unwrap_or_default())
            .map(|v| {
                if v.contains(',') {
                    format!("\"{v}\"")
                } else {
                    v
                }
            })
            .collect();
        s += &(cells.join(",") + "\n");
    }
    s
}

fn emlid_rows() -> Vec<HashMap<&'static str, String>> {
    let mk = |name: &str, e: f64, n: f64, el: f64, h: f64, rms: f64, status: &str| {
        let mut m = HashMap::new();
        m.insert("Name", name.to_string());
        m.insert("Easting", format!("{e}"));
        m.insert("Northing", format!("{n}"));
        m.insert("Elevation", format!("{el}"));
        m.insert("Ellipsoidal height", format!("{h}"));
        // Where these eastings and northings lie in EPSG:3812 (the reader checks).
        m.insert("Longitude", "4.35598".into());
        m.insert("Latitude", "50.79726".into());
        m.insert("Easting RMS", format!("{rms}"));
        m.insert("Northing RMS", format!("{}", rms * 1.5));
        m.insert("Elevation RMS", format!("{}", rms * 2.0));
        m.insert("Solution status", status.to_string());
        m.insert("CS name", "ETRS89 / Belgian Lambert 2008".into());
        m.insert("Description", "nail, painted".into());
        m.insert("Antenna height", "1.8".into());
        m.insert("Antenna height units", "m".into());
        m
    };
    vec![
        mk("GCP1", 649_100.123, 665_200.456, 45.10, 88.61, 0.008, "FIX"),
        mk("GCP2", 649_150.5, 665_260.25, 45.42, 88.93, 0.009, "FIX"),
        mk("CHK-1", 649_130.0, 665_230.0, 45.3, 88.81, 0.012, "FLOAT"),
        mk("GCP3", 649_190.75, 665_210.5, 45.8, 89.31, 0.007, "FIX"),
    ]
}

#[test]
fn emlid_both_generations_and_any_column_order_read_the_same() {
    let dir = tempfile::tempdir().unwrap();
    let rows = emlid_rows();
    let mut all42: Vec<&str> = COLUMNS_27.to_vec();
    all42.extend(COLUMNS_42_EXTRA);
    let mut shuffled = all42.clone();
    shuffled.reverse();
    shuffled.swap(3, 17);
    let mut results = Vec::new();
    for (name, cols) in [
        ("e27.csv", COLUMNS_27.to_vec()),
        ("e42.csv", all42),
        ("shuffled.csv", shuffled),
    ] {
        let path = write(dir.path(), name, &emlid_csv(&cols, &rows));
        let text = std::fs::read_to_string(&path).unwrap();
        assert_eq!(detect(&text), Some(SurveyFormat::Emlid), "{name}");
        let s = read(&path, &ReadOptions::default()).unwrap();
        assert_eq!(s.points.len(), 4, "{name}");
        let g = &s.points[0];
        assert_eq!(g.name, "GCP1");
        assert_eq!(
            g.position,
            nalgebra::Vector3::new(649_100.123, 665_200.456, 45.10)
        );
        assert_eq!(
            g.sigma_m,
            Some(nalgebra::Vector3::new(0.008, 0.008 * 1.5, 0.016))
        );
        assert_eq!(g.code.as_deref(), Some("nail, painted"));
        assert_eq!(s.points[2].status, Some(SolutionStatus::Float));
        assert!(
            s.warnings
                .iter()
                .any(|w| w.contains("CHK-1") && w.contains("FLOAT")),
            "{:?}",
            s.warnings
        );
        assert_eq!(s.crs.as_deref(), Some("ETRS89 / Belgian Lambert 2008"));
        assert_eq!(s.height, HeightKind::Orthometric(None));
        results.push(s.points);
    }
    assert_eq!(results[0], results[1]);
    assert_eq!(results[0], results[2]);

    // --height ellipsoidal takes the other column; --fix-only drops the FLOAT point, listed.
    let path = dir.path().join("e27.csv");
    let opts = ReadOptions {
        height: Some(HeightChoice::Ellipsoidal),
        fix_only: true,
        ..ReadOptions::default()
    };
    let s = read(&path, &opts).unwrap();
    assert_eq!(s.height, HeightKind::Ellipsoidal);
    assert_eq!(s.points[0].position.z, 88.61);
    assert_eq!(s.points.len(), 3);
    assert_eq!(s.dropped.len(), 1);
    assert!(s.dropped[0].reason.contains("CHK-1"));
}

#[test]
fn emlid_without_vertical_datum_has_ellipsoidal_elevations() {
    let dir = tempfile::tempdir().unwrap();
    let mut rows = emlid_rows();
    for r in &mut rows {
        let h = r["Ellipsoidal height"].clone();
        r.insert("Elevation", h);
        r.insert("CS name", "WGS 84 / UTM zone 31N".into());
        r.insert("Longitude", "4.34717".into());
        r.insert("Latitude", "6.01639".into());
    }
    let s = read(
        &write(dir.path(), "e.csv", &emlid_csv(&COLUMNS_27, &rows)),
        &ReadOptions::default(),
    )
    .unwrap();
    assert_eq!(s.height, HeightKind::Ellipsoidal);
}

#[test]
fn emlid_errors_name_the_line_and_column() {
    let dir = tempfile::tempdir().unwrap();
    let rows = emlid_rows();
    // Missing column.
    let cols: Vec<&str> = COLUMNS_27
        .iter()
        .copied()
        .filter(|c| *c != "Northing")
        .collect();
    let e = read(
        &write(dir.path(), "a.csv", &emlid_csv(&cols, &rows)),
        &ReadOptions::default(),
    )
    .unwrap_err();
    assert_eq!(e.field.as_deref(), Some("Northing"), "{e}");
    // Duplicate column.
    let mut cols = COLUMNS_27.to_vec();
    cols.push("Easting");
    let e = read(
        &write(dir.path(), "b.csv", &emlid_csv(&cols, &rows)),
        &ReadOptions::default(),
    )
    .unwrap_err();
    assert!(e.message.contains("twice"), "{e}");
    // Unparsable number, on data line 3 (file line 4).
    let mut bad = rows.clone();
    bad[2].insert("Easting", "649x130".into());
    let e = read(
        &write(dir.path(), "c.csv", &emlid_csv(&COLUMNS_27, &bad)),
        &ReadOptions::default(),
    )
    .unwrap_err();
    assert_eq!(
        (e.line, e.field.as_deref()),
        (Some(4), Some("Easting")),
        "{e}"
    );
    // Unknown CRS name.
    let mut bad = rows.clone();
    for r in &mut bad {
        r.insert("CS name", "Nowhere Grid 1999".into());
    }
    let e = read(
        &write(dir.path(), "d.csv", &emlid_csv(&COLUMNS_27, &bad)),
        &ReadOptions::default(),
    )
    .unwrap_err();
    assert!(e.message.contains("--crs"), "{e}");
    // Mixed CRSs.
    let mut bad = rows.clone();
    bad[1].insert("CS name", "WGS 84 / UTM zone 31N".into());
    let e = read(
        &write(dir.path(), "m.csv", &emlid_csv(&COLUMNS_27, &bad)),
        &ReadOptions::default(),
    )
    .unwrap_err();
    assert!(e.message.contains("mixed CRSs"), "{e}");
    // Duplicate point names.
    let mut bad = rows.clone();
    bad[3].insert("Name", "GCP1".into());
    let e = read(
        &write(dir.path(), "n.csv", &emlid_csv(&COLUMNS_27, &bad)),
        &ReadOptions::default(),
    )
    .unwrap_err();
    assert!(
        e.message.contains("duplicate point name 'GCP1'") && e.line == Some(5),
        "{e}"
    );
}

#[test]
fn odm_lists_with_comments_tabs_nan_and_unnamed_points() {
    let dir = tempfile::tempdir().unwrap();
    let text = "# survey of 2024\nEPSG:32631\n500000.1\t5600000.2\t45.5\t100\t200\tIMG_1.JPG\tA\n\
                500000.1 5600000.2 45.5 110 210 IMG_2.JPG A extra1 extra2\n\
                500010 5600020 NaN 300.5 400.25 IMG_1.JPG  # no height\n\n";
    let p = write(dir.path(), "gcp_list.txt", text);
    assert_eq!(detect(text), Some(SurveyFormat::Odm));
    let s = read(&p, &ReadOptions::default()).unwrap();
    assert_eq!(s.points.len(), 2);
    assert_eq!(s.observation_count(), 3);
    assert_eq!(s.points[0].observations[1].image, "IMG_2.JPG");
    assert_eq!(s.points[1].name, "500010.000,5600020.000,NaN");
    assert!(s.points[1].position.z.is_nan());
    assert!(s.warnings.iter().any(|w| w.contains("NaN z")));
    // The same name at other coordinates is an error naming both lines.
    let p = write(
        dir.path(),
        "bad.txt",
        "EPSG:32631\n1 2 3 4 5 a.jpg P\n1 2 4 4 5 b.jpg P\n",
    );
    let e = read(&p, &ReadOptions::default()).unwrap_err();
    assert!(e.line == Some(3) && e.message.contains("line 2"), "{e}");
    let p = write(dir.path(), "short.txt", "EPSG:32631\n1 2 3 4 5\n");
    assert_eq!(read(&p, &ReadOptions::default()).unwrap_err().line, Some(2));
    let p = write(dir.path(), "nocrs.txt", "EPSG:99999999\n1 2 3 4 5 a.jpg\n");
    assert_eq!(
        read(
            &p,
            &ReadOptions {
                format: Some(SurveyFormat::Odm),
                ..ReadOptions::default()
            }
        )
        .unwrap_err()
        .line,
        Some(1)
    );
    // A point picked twice in one image (a published list has one): the same pixel is kept
    // once; two places drop both, each line listed with the reason.
    let p = write(
        dir.path(),
        "twice.txt",
        "EPSG:32631\n1 2 3 4 5 a.jpg P\n1 2 3 4 5 a.jpg P\n1 2 3 40 50 b.jpg P\n\
         1 2 3 41 52 b.jpg P\n1 2 3 7 8 c.jpg P\n",
    );
    let s = read(&p, &ReadOptions::default()).unwrap();
    let images: Vec<&str> = s.points[0]
        .observations
        .iter()
        .map(|o| o.image.as_str())
        .collect();
    assert_eq!(images, ["a.jpg", "c.jpg"]);
    let lines: Vec<usize> = s.dropped.iter().map(|d| d.line).collect();
    assert_eq!(lines, [3, 4, 5]);
    assert!(
        s.dropped[0].reason.contains("same pixel"),
        "{:?}",
        s.dropped
    );
    assert!(
        s.dropped[2].reason.contains("lines 4 and 5"),
        "{:?}",
        s.dropped
    );
}

#[test]
fn petrack_3dc_in_centimetres() {
    let dir = tempfile::tempdir().unwrap();
    let text = "3\n0 0 0 10.5 20.5\n1000 0 0 110.5 20.5\n0 500 25 10.5 70.5\n";
    assert_eq!(detect(text), Some(SurveyFormat::Petrack));
    let s = read(&write(dir.path(), "a.3dc", text), &ReadOptions::default()).unwrap();
    assert_eq!(s.crs, None);
    assert_eq!(s.points[1].position, nalgebra::Vector3::new(10.0, 0.0, 0.0));
    assert_eq!(s.points[2].name, "P3");
    assert_eq!(
        s.points[2].observations[0].uv,
        nalgebra::Vector2::new(10.5, 70.5)
    );
    let e = read(
        &write(dir.path(), "b.3dc", "4\n0 0 0\n1 1 1\n"),
        &ReadOptions::default(),
    )
    .unwrap_err();
    assert!(e.message.contains("says 4"), "{e}");
    let e = read(
        &write(dir.path(), "c.3dc", "2\n0 0 0\n1 1\n"),
        &ReadOptions {
            format: Some(SurveyFormat::Petrack),
            ..ReadOptions::default()
        },
    )
    .unwrap_err();
    assert_eq!(e.line, Some(3));
}

#[test]
fn opensfm_json_with_normalised_observations() {
    let dir = tempfile::tempdir().unwrap();
    let text = r#"{"points": [
      {"id": "g1", "position": {"latitude": 50.8, "longitude": 4.35, "altitude": 101.5},
       "observations": [{"shot_id": "a.jpg", "projection": [0.0, 0.0]}, {"shot_id": "b.jpg", "projection": [0.25, -0.1]}]},
      {"id": "g2", "position": {"latitude": 50.81, "longitude": 4.36, "altitude": 102.0}, "observations": []}
    ]}"#;
    let p = write(dir.path(), "ground_control_points.json", text);
    let e = read(&p, &ReadOptions::default()).unwrap_err();
    assert!(e.message.contains("--image-size"), "{e}");
    let s = read(
        &p,
        &ReadOptions {
            image_size: Some((4000, 3000)),
            ..ReadOptions::default()
        },
    )
    .unwrap();
    assert_eq!(s.format, SurveyFormat::OpenSfm);
    assert_eq!(
        s.points[0].position,
        nalgebra::Vector3::new(4.35, 50.8, 101.5)
    );
    assert_eq!(
        s.points[0].observations[0].uv,
        nalgebra::Vector2::new(1999.5, 1499.5)
    );
    assert_eq!(
        s.points[0].observations[1].uv,
        nalgebra::Vector2::new(2999.5, 1099.5)
    );
    assert_eq!(s.height, HeightKind::Ellipsoidal);
}

#[test]
fn metashape_reference_csv_with_crs_comment_and_generic_csv() {
    let dir = tempfile::tempdir().unwrap();
    let text = "#CoordinateSystem: WGS 84 / UTM zone 31N (EPSG::32631)\n#Label,X/Easting,Y/Northing,Z/Altitude,X_accuracy,Y_accuracy,Z_accuracy\n\
                point 1,500000.5,5600000.25,45.1,0.01,0.01,0.02\npoint 2,500010,5600010,46,0.01,0.01,0.02\n";
    assert_eq!(detect(text), Some(SurveyFormat::Metashape));
    let s = read(&write(dir.path(), "ref.csv", text), &ReadOptions::default()).unwrap();
    assert_eq!(s.crs.as_deref(), Some("EPSG:32631"));
    assert_eq!(s.points[0].name, "point 1");
    assert_eq!(
        s.points[1].sigma_m,
        Some(nalgebra::Vector3::new(0.01, 0.01, 0.02))
    );

    // Semicolons, another column order, given by --columns.
    let text = "E;N;H;Label;type\n500000;5600000;45;A;control\n500010;5600010;46;B;check\n500020;5600000;44;C;0\n";
    let opts = ReadOptions {
        format: Some(SurveyFormat::Csv),
        columns: Some("name=Label,x=E,y=N,z=H,role=type".parse().unwrap()),
        crs: Some("EPSG:32631".into()),
        ..ReadOptions::default()
    };
    let s = read(&write(dir.path(), "g.csv", text), &opts).unwrap();
    let roles: Vec<Role> = s.points.iter().map(|p| p.role).collect();
    assert_eq!(roles, vec![Role::Control, Role::Check, Role::Disabled]);
    // Without --columns a generic CSV is refused with an example.
    let e = read(
        &write(dir.path(), "g2.csv", text),
        &ReadOptions {
            format: Some(SurveyFormat::Csv),
            ..ReadOptions::default()
        },
    )
    .unwrap_err();
    assert!(e.message.contains("--columns"), "{e}");
    // A column map naming a column the header lacks.
    let bad = ReadOptions {
        columns: Some("name=Label,x=East,y=N".parse().unwrap()),
        ..opts.clone()
    };
    let e = read(&write(dir.path(), "g3.csv", text), &bad).unwrap_err();
    assert_eq!((e.line, e.field.as_deref()), (Some(1), Some("East")), "{e}");
    // Without a CRS anywhere.
    let e = read(
        &write(dir.path(), "g4.csv", "a,1,2,3\n"),
        &ReadOptions::default(),
    )
    .unwrap_err();
    assert!(e.message.contains("--crs"), "{e}");
}

#[test]
fn roles_picks_and_height_conflicts() {
    let dir = tempfile::tempdir().unwrap();
    let p = write(
        dir.path(),
        "r.csv",
        "#CoordinateSystem: x (EPSG::32631)\nA,500000,5600000,45\nCHK-B,500010,5600010,46\nC,500020,5600000,44\nD,500020,5600030,44\n",
    );
    let mut s = read(&p, &ReadOptions::default()).unwrap();
    assert_eq!(s.height, HeightKind::Unknown);
    assert!(s.warnings.iter().any(|w| w.contains("--height")));
    assign_roles(&mut s, Some("chk-"), &["C".into()], &["D".into()]).unwrap();
    let roles: Vec<Role> = s.points.iter().map(|p| p.role).collect();
    assert_eq!(
        roles,
        vec![Role::Control, Role::Check, Role::Check, Role::Disabled]
    );
    assert!(assign_roles(&mut s, None, &["Z".into()], &[]).is_err());

    let picks = write(
        dir.path(),
        "picks.csv",
        "name,image,u,v,sigma\nA,img1.jpg,10.5,20.5,0.5\nX,img1.jpg,1,2\n",
    );
    assert_eq!(read_picks(&picks, &mut s).unwrap(), 1);
    assert_eq!(s.points[0].observations[0].sigma_px, Some(0.5));
    assert_eq!(s.dropped.len(), 1);
    assert!(s.dropped[0].reason.contains("'X'"));

    // Coordinates that are not in the CRS given (UTM 31N as Belgian Lambert 72: the Arctic).
    let opts = ReadOptions {
        crs: Some("EPSG:6190".into()),
        ..ReadOptions::default()
    };
    let e = read(&p, &opts).unwrap_err();
    assert!(e.message.contains("outside where"), "{e}");
    assert_eq!(e.line, Some(2));

    // A compound CRS says orthometric; --height ellipsoidal contradicts it.
    let p = write(
        dir.path(),
        "r72.csv",
        "#CoordinateSystem: x (EPSG::31370)\nA,150000,170000,45\nB,150010,170010,46\n",
    );
    let opts = ReadOptions {
        crs: Some("EPSG:6190".into()),
        height: Some(HeightChoice::Ellipsoidal),
        ..ReadOptions::default()
    };
    let e = read(&p, &opts).unwrap_err();
    assert!(e.message.contains("never mixed"), "{e}");
    let opts = ReadOptions {
        crs: Some("EPSG:6190".into()),
        ..ReadOptions::default()
    };
    assert!(matches!(
        read(&p, &opts).unwrap().height,
        HeightKind::Orthometric(Some(_))
    ));
}

#[test]
fn rows_after_comment_lines_keep_their_line_numbers() {
    // The csv crate does not count comment lines: a Metashape file's header comments shifted
    // every row's line in messages.
    let dir = tempfile::tempdir().unwrap();
    let p = write(
        dir.path(),
        "m.csv",
        "#CoordinateSystem: x (EPSG::31370)\n#Label,X,Y,Z\nA,150000,170000,45\n# note\nB,150010,abc,46\n",
    );
    let e = read(&p, &ReadOptions::default()).unwrap_err();
    assert_eq!(e.line, Some(5), "{e}");
    // A decimal comma shifts the columns: more fields than the header names.
    let p = write(
        dir.path(),
        "m2.csv",
        "#CoordinateSystem: x (EPSG::31370)\n#Label,X,Y,Z\nA,150000,5,170000,2,45,1\n",
    );
    let e = read(&p, &ReadOptions::default()).unwrap_err();
    assert_eq!(e.line, Some(3), "{e}");
    assert!(e.message.contains("decimal commas"), "{e}");
}
