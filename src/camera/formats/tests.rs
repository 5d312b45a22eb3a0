// Literals copied digit for digit from OpenCV files.
#![allow(clippy::excessive_precision)]

use std::path::Path;

use nalgebra::Vector3;

use super::*;
use crate::camera::{BoardSpec, CalibrationSummary, Camera, ParamCovariance, ViewSummary};

fn full_calibration(rational: bool) -> Calibration {
    let dist: &[f64] = if rational {
        &[0.11, -0.25, 0.0012, -0.0007, 0.031, 0.05, -0.02, 0.004]
    } else {
        &[
            -0.2663726090966068,
            -0.03858889892230465,
            0.0017831947042852964,
            -0.00028122100441115472,
            0.23839153080878486,
        ]
    };
    let camera = Camera {
        skew: 0.0,
        ..Camera::pinhole(
            535.915_733_961_632,
            535.0000001,
            342.283_154_733_083_73,
            235.570_829_097_881_73,
        )
        .with_distortion(dist)
        .with_image_size(640, 480)
    };
    // A symmetric positive semi-definite covariance with zero rows for fixed skew and k4..k6.
    let mut l = ParamCovariance::zeros();
    for i in 0..13 {
        for j in 0..=i {
            l[(i, j)] = 1e-3 * ((i * 7 + j * 3) % 5) as f64 + if i == j { 0.01 } else { 0.0 };
        }
    }
    let mut cov = l * l.transpose();
    let fixed: &[usize] = if rational { &[4] } else { &[4, 10, 11, 12] };
    for &f in fixed {
        for k in 0..13 {
            cov[(f, k)] = 0.0;
            cov[(k, f)] = 0.0;
        }
    }
    Calibration {
        camera,
        covariance: Some(cov),
        summary: Some(CalibrationSummary {
            rms_px: 0.3925909897558136,
            board: Some(BoardSpec {
                cols: 9,
                rows: 6,
                square_m: 0.025,
            }),
            free_parameters: vec![
                "fx".into(),
                "fy".into(),
                "cx".into(),
                "cy".into(),
                "k1".into(),
            ],
            views: vec![
                ViewSummary {
                    name: "left01.jpg".into(),
                    rms_px: 0.192965463,
                    rvec: [0.168, 0.2756, 0.01346],
                    tvec: [-0.0752, -0.1089, 0.3997],
                    outlier: false,
                },
                ViewSummary {
                    name: "left 02.jpg".into(),
                    rms_px: 1.18204820,
                    rvec: [0.413, 0.649, -1.337],
                    tvec: [-0.0585, 0.0829, 0.3538],
                    outlier: true,
                },
            ],
            created_utc: Some("2026-11-21T10:00:00Z".into()),
        }),
        notes: vec![],
        extrinsics: None,
    }
}

fn round_trip(cal: &Calibration, format: Format) -> Calibration {
    let text = render(cal, format, Path::new("mem")).unwrap();
    parse(Path::new("mem"), &text, None).unwrap_or_else(|e| panic!("{e}\n{text}"))
}

#[test]
fn opencv_yaml_round_trips_exactly() {
    for rational in [false, true] {
        let cal = full_calibration(rational);
        assert_eq!(round_trip(&cal, Format::OpenCvYaml), cal);
    }
}

#[test]
fn json_round_trips_exactly() {
    for rational in [false, true] {
        let mut cal = full_calibration(rational);
        cal.notes.push("a note".into());
        assert_eq!(round_trip(&cal, Format::Json), cal);
    }
}

#[test]
fn metashape_round_trips_camera_and_covariance() {
    let mut cal = full_calibration(false);
    cal.camera.skew = 0.25;
    let back = round_trip(&cal, Format::Metashape);
    let (a, b) = (cal.camera.params(), back.camera.params());
    for i in 0..13 {
        assert!(
            (a[i] - b[i]).abs() <= 1e-12 * (1.0 + a[i].abs()),
            "param {i}: {} vs {}",
            a[i],
            b[i]
        );
    }
    assert_eq!(back.camera.image_size, cal.camera.image_size);
    let (ca, cb) = (cal.covariance.unwrap(), back.covariance.unwrap());
    assert!(
        (ca - cb).amax() < 1e-15,
        "covariance differs by {}",
        (ca - cb).amax()
    );
}

/// Metashape's published projection, written out independently of the converter.
fn metashape_project(ms: &[(&str, f64)], w: f64, h: f64, p: &Vector3<f64>) -> (f64, f64) {
    let g = |n: &str| {
        ms.iter()
            .find(|(k, _)| *k == n)
            .map(|(_, v)| *v)
            .unwrap_or(0.0)
    };
    let (x, y) = (p.x / p.z, p.y / p.z);
    let r2 = x * x + y * y;
    let rad = 1.0 + g("k1") * r2 + g("k2") * r2 * r2 + g("k3") * r2.powi(3) + g("k4") * r2.powi(4);
    let xp = x * rad + g("p1") * (r2 + 2.0 * x * x) + 2.0 * g("p2") * x * y;
    let yp = y * rad + g("p2") * (r2 + 2.0 * y * y) + 2.0 * g("p1") * x * y;
    let u = w * 0.5 + g("cx") + xp * g("f") + xp * g("b1") + yp * g("b2");
    let v = h * 0.5 + g("cy") + yp * g("f");
    (u, v)
}

#[test]
fn metashape_conversion_reproduces_metashape_projection() {
    let ms = [
        ("f", 2905.5),
        ("cx", 12.25),
        ("cy", -7.5),
        ("b1", 1.5),
        ("b2", -0.3),
        ("k1", -0.11),
        ("k2", 0.09),
        ("k3", -0.02),
        ("p1", 0.0011),
        ("p2", -0.0007),
    ];
    let mut xml = String::from(
        "<?xml version=\"1.0\"?>\n<calibration>\n<projection>frame</projection>\n<width>2832</width>\n<height>2128</height>\n",
    );
    for (k, v) in ms {
        xml.push_str(&format!("<{k}>{v}</{k}>\n"));
    }
    xml.push_str("</calibration>\n");
    let cal = parse(Path::new("ms.xml"), &xml, None).unwrap();
    for p in [
        Vector3::new(0.1, 0.2, 1.0),
        Vector3::new(-0.4, 0.3, 1.2),
        Vector3::new(0.45, -0.33, 1.0),
    ] {
        let (u_ms, v_ms) = metashape_project(&ms, 2832.0, 2128.0, &p);
        let uv = cal.camera.project(&p).unwrap();
        // Metashape's pixel origin is the image corner, OpenCV's the first pixel's centre.
        assert!(
            (uv.x + 0.5 - u_ms).abs() < 1e-9,
            "u {} vs {}",
            uv.x + 0.5,
            u_ms
        );
        assert!(
            (uv.y + 0.5 - v_ms).abs() < 1e-9,
            "v {} vs {}",
            uv.y + 0.5,
            v_ms
        );
    }
}

#[test]
fn metashape_k4_is_refitted_within_tolerance_or_refused() {
    let base = "<calibration><projection>frame</projection><width>4000</width><height>3000</height>\
                <f>3000</f><cx>0</cx><cy>0</cy><k1>-0.1</k1><k2>0.05</k2><k3>0.0</k3>";
    let small = format!("{base}<k4>0.00001</k4></calibration>");
    let cal = parse(Path::new("ms.xml"), &small, None).unwrap();
    assert_eq!(cal.notes.len(), 1, "{:?}", cal.notes);
    // The refitted camera agrees with Metashape within the stated tolerance at the corner.
    let ms = [("f", 3000.0), ("k1", -0.1), ("k2", 0.05), ("k4", 0.00001)];
    let p = Vector3::new(0.6, 0.45, 1.0);
    let (u_ms, v_ms) = metashape_project(&ms, 4000.0, 3000.0, &p);
    let uv = cal.camera.project(&p).unwrap();
    assert!((uv.x + 0.5 - u_ms).hypot(uv.y + 0.5 - v_ms) < 0.05);

    let large = format!("{base}<k4>0.5</k4></calibration>");
    let err = parse(Path::new("ms.xml"), &large, None).unwrap_err();
    assert_eq!(err.field.as_deref(), Some("k4"), "{err}");
}

#[test]
fn metashape_refuses_what_it_cannot_represent() {
    let mut cal = full_calibration(true);
    let err = render(&cal, Format::Metashape, Path::new("out.xml")).unwrap_err();
    assert!(err.to_string().contains("rational"), "{err}");
    cal = full_calibration(false);
    cal.camera.image_size = None;
    let err = render(&cal, Format::Metashape, Path::new("out.xml")).unwrap_err();
    assert!(err.to_string().contains("image size"), "{err}");
}

#[test]
fn reads_the_older_opencv_spelling_and_four_coefficients() {
    let text = "%YAML:1.0\nimage_Width: 640\nimage_Height: 480\nCamera_Matrix: !!opencv-matrix\n   rows: 3\n   cols: 3\n   dt: d\n   \
                data: [ 500., 0., 320., 0., 510., 240., 0., 0., 1. ]\nDistortion_Coefficients: !!opencv-matrix\n   rows: 4\n   cols: 1\n   dt: d\n   \
                data: [ -0.1, 0.01, 0.001, 0.002 ]\nAvg_Reprojection_Error: 0.25\n";
    let cal = parse(Path::new("old.yml"), text, None).unwrap();
    assert_eq!(cal.camera.fx, 500.0);
    assert_eq!(cal.camera.fy, 510.0);
    assert_eq!(
        cal.camera.dist,
        [-0.1, 0.01, 0.001, 0.002, 0.0, 0.0, 0.0, 0.0]
    );
    assert_eq!(cal.camera.image_size.unwrap().width, 640);
    assert_eq!(cal.summary.unwrap().rms_px, 0.25);
}

#[test]
fn reads_eight_rational_coefficients_as_a_row() {
    let text = "%YAML:1.0\ncamera_matrix: !!opencv-matrix\n   rows: 3\n   cols: 3\n   dt: d\n   data: [ 500., 0., 320., 0., 500., 240., 0., 0., 1. ]\n\
                distortion_coefficients: !!opencv-matrix\n   rows: 1\n   cols: 8\n   dt: d\n   data: [ 1, 2, 3, 4, 5, 6, 7, 8 ]\n";
    let cal = parse(Path::new("r.yml"), text, None).unwrap();
    assert_eq!(cal.camera.dist, [1.0, 2.0, 3.0, 4.0, 5.0, 6.0, 7.0, 8.0]);
    assert!(cal.camera.image_size.is_none());
    assert!(cal.summary.is_none());
}

#[test]
fn bad_files_name_the_line_and_field() {
    let bad_k = "%YAML:1.0\ncamera_matrix: !!opencv-matrix\n   rows: 3\n   cols: 3\n   dt: d\n   data: [ 500., 0., 320., 0., 500., 240., 0., 0. ]\n";
    let err = parse(Path::new("bad.yml"), bad_k, None).unwrap_err();
    assert_eq!(err.line, Some(2));
    assert_eq!(err.field.as_deref(), Some("camera_matrix"));
    assert!(
        err.to_string()
            .starts_with("bad.yml:2: field 'camera_matrix'"),
        "{err}"
    );

    let bad_d = "%YAML:1.0\ncamera_matrix: !!opencv-matrix\n   rows: 3\n   cols: 3\n   dt: d\n   data: [ 500., 0., 320., 0., 500., 240., 0., 0., 1. ]\n\
                 distortion_coefficients: !!opencv-matrix\n   rows: 6\n   cols: 1\n   dt: d\n   data: [ 1, 2, 3, 4, 5, 6 ]\n";
    let err = parse(Path::new("bad.yml"), bad_d, None).unwrap_err();
    assert!(err.message.contains("4, 5 or 8"), "{err}");

    let err = parse(Path::new("x.txt"), "hello", None).unwrap_err();
    assert!(err.message.contains("--format"), "{err}");

    let err = parse(
        Path::new("x.json"),
        "{\"format\": \"geostride.camera\", \"version\": 1,\n \"model\": 3}",
        None,
    )
    .unwrap_err();
    assert_eq!(err.line, Some(2), "{err}");

    let err = parse(
        Path::new("x.xml"),
        "<calibration><width>10</width></calibration>",
        None,
    )
    .unwrap_err();
    assert_eq!(err.field.as_deref(), Some("height"), "{err}");
}

#[test]
fn write_is_atomic_and_picks_the_format_from_the_extension() {
    let dir = tempfile::tempdir().unwrap();
    let cal = full_calibration(false);
    for (name, fmt) in [
        ("a.yaml", Format::OpenCvYaml),
        ("a.xml", Format::Metashape),
        ("a.json", Format::Json),
    ] {
        let p = dir.path().join(name);
        assert_eq!(write(&cal, &p, None).unwrap(), fmt);
        assert!(read(&p, None).is_ok());
    }
    let p = dir.path().join("a.txt");
    assert!(write(&cal, &p, None).is_err());
    assert!(!p.exists());
}
