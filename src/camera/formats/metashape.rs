//! Agisoft Metashape calibration XML (frame cameras, Metashape 1.5 and later).
//!
//! Metashape's model (user manual, appendix "Camera models"), with `x = X/Z`, `y = Y/Z`:
//!
//! ```text
//! x' = x (1 + K1 r² + K2 r⁴ + K3 r⁶ + K4 r⁸) + P1 (r² + 2x²) + 2 P2 x y
//! y' = y (1 + K1 r² + K2 r⁴ + K3 r⁶ + K4 r⁸) + P2 (r² + 2y²) + 2 P1 x y
//! u  = w/2 + cx + x' (f + B1) + y' B2
//! v  = h/2 + cy + y' f
//! ```
//!
//! with the pixel origin at the top-left corner of the image (the centre of the top-left pixel at
//! (0.5, 0.5)). Hence, in OpenCV terms: `fx = f + B1`, `fy = f`, `skew = B2`,
//! `cx = w/2 + cx_ms − 0.5`, `cy = h/2 + cy_ms − 0.5`, `p1 = P2`, `p2 = P1` (the tangential
//! coefficients are swapped), `k1..k3 = K1..K3`. OpenCV has no r⁸ term: a non-zero K4 is
//! refitted into k1..k3 over the image and the largest resulting pixel difference is reported.

use nalgebra::{DMatrix, SMatrix};

use super::{Ctx, FormatError};
use crate::camera::{Calibration, Camera, ImageSize, N_PARAMS, ParamCovariance, param};

/// Metashape's parameters, in the order used for the linear maps below.
const MS_NAMES: [&str; 11] = [
    "f", "cx", "cy", "b1", "b2", "k1", "k2", "k3", "k4", "p1", "p2",
];
const MS_F: usize = 0;
const MS_CX: usize = 1;
const MS_CY: usize = 2;
const MS_B1: usize = 3;
const MS_B2: usize = 4;
const MS_K1: usize = 5;
const MS_K2: usize = 6;
const MS_K3: usize = 7;
const MS_K4: usize = 8;
const MS_P1: usize = 9;
const MS_P2: usize = 10;

/// Largest pixel difference accepted when folding K4 into k1..k3.
const K4_REFIT_TOLERANCE_PX: f64 = 0.05;

/// d(OpenCV parameters) / d(Metashape parameters); the map is affine, this is its linear part.
fn opencv_from_metashape() -> SMatrix<f64, N_PARAMS, 11> {
    let mut a = SMatrix::<f64, N_PARAMS, 11>::zeros();
    a[(param::FX, MS_F)] = 1.0;
    a[(param::FX, MS_B1)] = 1.0;
    a[(param::FY, MS_F)] = 1.0;
    a[(param::CX, MS_CX)] = 1.0;
    a[(param::CY, MS_CY)] = 1.0;
    a[(param::SKEW, MS_B2)] = 1.0;
    a[(param::K1, MS_K1)] = 1.0;
    a[(param::K2, MS_K2)] = 1.0;
    a[(param::K3, MS_K3)] = 1.0;
    a[(param::P1, MS_P2)] = 1.0;
    a[(param::P2, MS_P1)] = 1.0;
    a
}

/// d(Metashape parameters) / d(OpenCV parameters), for cameras without rational terms.
fn metashape_from_opencv() -> SMatrix<f64, 11, N_PARAMS> {
    let mut b = SMatrix::<f64, 11, N_PARAMS>::zeros();
    b[(MS_F, param::FY)] = 1.0;
    b[(MS_B1, param::FX)] = 1.0;
    b[(MS_B1, param::FY)] = -1.0;
    b[(MS_B2, param::SKEW)] = 1.0;
    b[(MS_CX, param::CX)] = 1.0;
    b[(MS_CY, param::CY)] = 1.0;
    b[(MS_K1, param::K1)] = 1.0;
    b[(MS_K2, param::K2)] = 1.0;
    b[(MS_K3, param::K3)] = 1.0;
    b[(MS_P1, param::P2)] = 1.0;
    b[(MS_P2, param::P1)] = 1.0;
    b
}

fn line_of(doc: &roxmltree::Document, node: roxmltree::Node) -> usize {
    doc.text_pos_at(node.range().start).row as usize
}

/// A Metashape 1.5+ frame calibration's root: not OpenCV's XML, not PhotoScan 1.4's, a pinhole.
fn check_root(ctx: &Ctx, doc: &roxmltree::Document) -> Result<(), FormatError> {
    let root = doc.root_element();
    if root.tag_name().name() == "opencv_storage" {
        return Err(ctx.err(
            Some(1),
            None,
            "this is OpenCV FileStorage XML; geostride reads OpenCV calibrations as YAML: \
             convert it with OpenCV (cv::FileStorage) or write the YAML form",
        ));
    }
    if root.tag_name().name() != "calibration" {
        return Err(ctx.err(
            Some(line_of(doc, root)),
            None,
            format!(
                "expected a Metashape <calibration> root element, found <{}>",
                root.tag_name().name()
            ),
        ));
    }
    let child = |name: &str| root.children().find(|n| n.has_tag_name(name));
    if let Some(p) = child("projection") {
        let kind = p.text().unwrap_or("").trim();
        if kind != "frame" {
            return Err(ctx.err(
                Some(line_of(doc, p)),
                Some("projection"),
                format!(
                    "only frame (pinhole) cameras are supported, found '{}'",
                    crate::io::clip(kind, 40)
                ),
            ));
        }
    }
    if child("fx").is_some() && child("f").is_none() {
        return Err(ctx.err(
            child("fx").map(|n| line_of(doc, n)),
            Some("fx"),
            "this is a PhotoScan 1.4-or-older calibration (fx/fy elements), whose conventions \
             differ; export the calibration again from Metashape 1.5 or later",
        ));
    }
    Ok(())
}

pub(super) fn parse(ctx: &Ctx, text: &str) -> Result<Calibration, FormatError> {
    let doc = super::parse_xml(ctx, text)?;
    check_root(ctx, &doc)?;
    let root = doc.root_element();
    let child = |name: &str| root.children().find(|n| n.has_tag_name(name));
    let number = |name: &str, required: bool| -> Result<Option<f64>, FormatError> {
        match child(name) {
            None if required => Err(ctx.err(
                None,
                Some(name),
                format!("missing <{name}> element: a Metashape frame calibration has f, width, height, cx, cy"),
            )),
            None => Ok(None),
            Some(n) => {
                let t = n.text().unwrap_or("").trim();
                ctx.number(t, line_of(&doc, n), name).map(Some)
            }
        }
    };
    let width = number("width", true)?.unwrap_or(0.0);
    let height = number("height", true)?.unwrap_or(0.0);
    let side = 1.0..=f64::from(crate::camera::MAX_IMAGE_SIDE);
    if !side.contains(&width)
        || !side.contains(&height)
        || width.fract() != 0.0
        || height.fract() != 0.0
    {
        return Err(ctx.err(
            None,
            Some("width"),
            format!(
                "width and height must be whole numbers of pixels from 1 to {}",
                crate::camera::MAX_IMAGE_SIDE
            ),
        ));
    }
    let mut ms = [0.0; 11];
    for (i, name) in MS_NAMES.iter().enumerate() {
        ms[i] = number(name, *name == "f")?.unwrap_or(0.0);
    }
    if !(1.0..=crate::camera::MAX_FOCAL_PX).contains(&ms[MS_F]) {
        return Err(ctx.err(
            None,
            Some("f"),
            format!(
                "a focal length f of {} px is not plausible (expected 1 to 1e7 px)",
                ms[MS_F]
            ),
        ));
    }
    for name in ["p3", "p4"] {
        if number(name, false)?.is_some_and(|v| v != 0.0) {
            return Err(ctx.err(
                None,
                Some(name),
                "higher-order tangential terms p3, p4 have no OpenCV equivalent; fix them at zero in Metashape",
            ));
        }
    }

    let (w, h) = (width, height);
    let mut camera = Camera {
        skew: ms[MS_B2],
        ..Camera::pinhole(
            ms[MS_F] + ms[MS_B1],
            ms[MS_F],
            w / 2.0 + ms[MS_CX] - 0.5,
            h / 2.0 + ms[MS_CY] - 0.5,
        )
        .with_distortion(&[ms[MS_K1], ms[MS_K2], ms[MS_P2], ms[MS_P1], ms[MS_K3]])
        .with_image_size(w as u32, h as u32)
    };
    let mut notes = Vec::new();
    if ms[MS_K4] != 0.0 {
        let (k, max_err_px) = refit_k4(&camera, ms[MS_K1], ms[MS_K2], ms[MS_K3], ms[MS_K4]);
        if max_err_px > K4_REFIT_TOLERANCE_PX {
            return Err(ctx.err(
                None,
                Some("k4"),
                format!(
                    "K4 = {} cannot be represented in OpenCV's model: folding it into k1..k3 \
                     changes pixels by up to {max_err_px:.3} px; recalibrate with K4 fixed at zero",
                    ms[MS_K4]
                ),
            ));
        }
        camera.dist[0] = k[0];
        camera.dist[1] = k[1];
        camera.dist[4] = k[2];
        notes.push(format!(
            "Metashape K4 = {} folded into k1..k3 (largest pixel difference {max_err_px:.4} px)",
            ms[MS_K4]
        ));
    }

    let covariance = match child("covariance") {
        None => None,
        Some(cov) => Some(read_covariance(
            ctx,
            &doc,
            cov,
            ms[MS_K4] != 0.0,
            &mut notes,
        )?),
    };
    Ok(Calibration {
        camera,
        covariance,
        summary: None,
        notes,
        extrinsics: None,
    })
}

fn read_covariance(
    ctx: &Ctx,
    doc: &roxmltree::Document,
    cov: roxmltree::Node,
    k4_refitted: bool,
    notes: &mut Vec<String>,
) -> Result<ParamCovariance, FormatError> {
    let line = Some(line_of(doc, cov));
    let params: Vec<&str> = cov
        .children()
        .find(|n| n.has_tag_name("params"))
        .and_then(|n| n.text())
        .unwrap_or("")
        .split_whitespace()
        .collect();
    let coeffs: Vec<f64> = cov
        .children()
        .find(|n| n.has_tag_name("coeffs"))
        .and_then(|n| n.text())
        .unwrap_or("")
        .split_whitespace()
        .map(str::parse)
        .collect::<Result<_, _>>()
        .map_err(|_| ctx.err(line, Some("covariance/coeffs"), "expected numbers"))?;
    let n = params.len();
    if n > MS_NAMES.len() || n == 0 || coeffs.len() != n * n {
        return Err(ctx.err(
            line,
            Some("covariance"),
            format!(
                "expected <params> names and n x n <coeffs>, found {n} names and {} values",
                coeffs.len()
            ),
        ));
    }
    let mut ms_cov = SMatrix::<f64, 11, 11>::zeros();
    let mut idx = Vec::with_capacity(n);
    for p in &params {
        match MS_NAMES.iter().position(|m| m == p) {
            Some(i) if idx.contains(&i) => {
                return Err(ctx.err(
                    line,
                    Some("covariance/params"),
                    format!("'{p}' is named twice"),
                ));
            }
            Some(i) => idx.push(i),
            None => {
                return Err(ctx.err(
                    line,
                    Some("covariance/params"),
                    format!(
                        "unknown parameter '{}' (expected some of {})",
                        crate::io::clip(p, 20),
                        MS_NAMES.join(" ")
                    ),
                ));
            }
        }
    }
    for (a, &ia) in idx.iter().enumerate() {
        for (b, &ib) in idx.iter().enumerate() {
            ms_cov[(ia, ib)] = coeffs[a * n + b];
        }
    }
    if k4_refitted {
        notes.push("the covariance omits K4, which has no OpenCV equivalent".into());
    }
    let a = opencv_from_metashape();
    Ok(a * ms_cov * a.transpose())
}

/// Least-squares k1..k3 that best reproduce `1 + K1 r² + K2 r⁴ + K3 r⁶ + K4 r⁸` out to the image
/// corners; returns them with the largest pixel difference.
fn refit_k4(cam: &Camera, k1: f64, k2: f64, k3: f64, k4: f64) -> ([f64; 3], f64) {
    let size = cam
        .image_size
        .expect("Metashape calibrations carry the image size");
    let corners = [
        (-0.5, -0.5),
        (size.width as f64 - 0.5, -0.5),
        (-0.5, size.height as f64 - 0.5),
        (size.width as f64 - 0.5, size.height as f64 - 0.5),
    ];
    let r_max = corners
        .iter()
        .map(|&(u, v)| ((u - cam.cx) / cam.fx).hypot((v - cam.cy) / cam.fy))
        .fold(0.0, f64::max);
    let n = 200;
    let mut a = DMatrix::<f64>::zeros(n, 3);
    let mut rhs = nalgebra::DVector::<f64>::zeros(n);
    for i in 0..n {
        let r = r_max * (i + 1) as f64 / n as f64;
        let r2 = r * r;
        // Fit the displacement r·(radial − 1), which is what pixels see.
        a[(i, 0)] = r * r2;
        a[(i, 1)] = r * r2 * r2;
        a[(i, 2)] = r * r2 * r2 * r2;
        rhs[i] = r * (k1 * r2 + k2 * r2 * r2 + k3 * r2 * r2 * r2 + k4 * r2 * r2 * r2 * r2);
    }
    // Out of range numbers (a principal point far outside the image) make no fit.
    if !(a.iter().chain(rhs.iter()).all(|v| v.is_finite())) {
        return ([k1, k2, k3], f64::INFINITY);
    }
    let Ok(sol) = a.clone().svd(true, true).solve(&rhs, 1e-15) else {
        return ([k1, k2, k3], f64::INFINITY);
    };
    let residual = a * &sol - rhs;
    let max_err = residual.amax() * cam.fx.max(cam.fy);
    ([sol[0], sol[1], sol[2]], max_err)
}

fn fmt(v: f64) -> String {
    // Shortest representation that reads back to the same double.
    format!("{v:?}")
}

pub(super) fn render(ctx: &Ctx, cal: &Calibration) -> Result<String, FormatError> {
    let cam = &cal.camera;
    let Some(ImageSize { width, height }) = cam.image_size else {
        return Err(ctx.err(
            None,
            Some("image size"),
            "Metashape stores the principal point relative to the image centre, so the image size \
             must be known; the input calibration has none",
        ));
    };
    if cam.is_rational() {
        return Err(ctx.err(
            None,
            Some("k4..k6"),
            "Metashape has no rational distortion terms; calibrate without --rational to export to Metashape",
        ));
    }
    let (w, h) = (f64::from(width), f64::from(height));
    let d = &cam.dist;
    let values: [(&str, f64); 11] = [
        ("f", cam.fy),
        ("cx", cam.cx + 0.5 - w / 2.0),
        ("cy", cam.cy + 0.5 - h / 2.0),
        ("b1", cam.fx - cam.fy),
        ("b2", cam.skew),
        ("k1", d[0]),
        ("k2", d[1]),
        ("k3", d[4]),
        ("k4", 0.0),
        ("p1", d[3]),
        ("p2", d[2]),
    ];
    let mut out = String::from("<?xml version=\"1.0\" encoding=\"UTF-8\"?>\n<calibration>\n");
    out.push_str("  <projection>frame</projection>\n");
    out.push_str(&format!(
        "  <width>{width}</width>\n  <height>{height}</height>\n"
    ));
    for (name, v) in values {
        out.push_str(&format!("  <{name}>{}</{name}>\n", fmt(v)));
    }
    if let Some(cov) = &cal.covariance {
        let b = metashape_from_opencv();
        let ms_cov = b * cov * b.transpose();
        let keep: Vec<usize> = (0..11).filter(|&i| ms_cov[(i, i)] > 0.0).collect();
        if !keep.is_empty() {
            let names: Vec<&str> = keep.iter().map(|&i| MS_NAMES[i]).collect();
            let coeffs: Vec<String> = keep
                .iter()
                .flat_map(|&i| keep.iter().map(move |&j| (i, j)))
                .map(|(i, j)| fmt(ms_cov[(i, j)]))
                .collect();
            out.push_str(&format!(
                "  <covariance>\n    <params>{}</params>\n    <coeffs>{}</coeffs>\n  </covariance>\n",
                names.join(" "),
                coeffs.join(" ")
            ));
        }
    }
    out.push_str(&format!(
        "  <date>{}</date>\n</calibration>\n",
        cal.summary
            .as_ref()
            .and_then(|s| s.created_utc.clone())
            .unwrap_or_else(crate::io::utc_now_iso8601)
    ));
    Ok(out)
}
