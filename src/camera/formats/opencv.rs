//! OpenCV YAML calibration files, as written by OpenCV's calibration samples
//! (`samples/cpp/calibration.cpp`, the camera-calibration tutorial), in both the current
//! (`camera_matrix`) and the older (`Camera_Matrix`) spellings.

use super::cvyaml::{self, Node};
use super::{Ctx, FormatError};
use crate::camera::{
    BoardSpec, Calibration, CalibrationSummary, Camera, ImageSize, N_PARAMS, PARAM_NAMES,
    ParamCovariance, ViewSummary, std_devs,
};

const CAMERA_MATRIX_KEYS: [&str; 4] = ["camera_matrix", "Camera_Matrix", "cameraMatrix", "K"];
const DISTORTION_KEYS: [&str; 5] = [
    "distortion_coefficients",
    "Distortion_Coefficients",
    "distCoeffs",
    "dist_coeffs",
    "D",
];

fn first<'a>(doc: &'a Node, keys: &[&'static str]) -> Option<(&'static str, &'a Node)> {
    keys.iter().find_map(|k| doc.get(k).map(|n| (*k, n)))
}

/// A matrix node's shape and data.
fn matrix(ctx: &Ctx, key: &str, node: &Node) -> Result<(usize, usize, Vec<f64>), FormatError> {
    let line = Some(node.line());
    let bad = |msg: String| ctx.err(line, Some(key), msg);
    if !matches!(node, Node::Map { .. }) {
        return Err(bad(
            "expected an '!!opencv-matrix' with rows, cols, dt and data".into(),
        ));
    }
    let dim = |name: &str| -> Result<usize, FormatError> {
        node.get(name)
            .and_then(Node::as_scalar)
            .and_then(|s| s.parse().ok())
            .ok_or_else(|| bad(format!("expected a whole number '{name}'")))
    };
    let (rows, cols) = (dim("rows")?, dim("cols")?);
    let items = match node.get("data") {
        Some(Node::Seq { items, .. }) => items,
        _ => return Err(bad("expected 'data: [ ... ]'".into())),
    };
    if items.len() != rows * cols {
        return Err(bad(format!(
            "has {} values in 'data' but rows x cols = {rows} x {cols} = {}",
            items.len(),
            rows * cols
        )));
    }
    let data = items
        .iter()
        .enumerate()
        .map(|(i, n)| {
            n.as_scalar().and_then(cvyaml::parse_f64).ok_or_else(|| {
                ctx.err(
                    Some(n.line()),
                    Some(key),
                    format!("data[{i}] is not a number"),
                )
            })
        })
        .collect::<Result<Vec<_>, _>>()?;
    Ok((rows, cols, data))
}

fn scalar_f64(ctx: &Ctx, doc: &Node, key: &str) -> Result<Option<f64>, FormatError> {
    match doc.get(key) {
        None => Ok(None),
        Some(n) => n
            .as_scalar()
            .and_then(cvyaml::parse_f64)
            .map(Some)
            .ok_or_else(|| ctx.err(Some(n.line()), Some(key), "expected a number")),
    }
}

fn strings(doc: &Node, key: &str) -> Option<Vec<String>> {
    match doc.get(key)? {
        Node::Seq { items, .. } => items
            .iter()
            .map(|n| n.as_scalar().map(str::to_string))
            .collect(),
        _ => None,
    }
}

pub(super) fn parse(ctx: &Ctx, text: &str) -> Result<Calibration, FormatError> {
    let doc = cvyaml::parse(text).map_err(|e| {
        ctx.err(
            Some(e.line),
            None,
            format!("not valid OpenCV YAML: {}", e.message),
        )
    })?;

    let Some((kkey, knode)) = first(&doc, &CAMERA_MATRIX_KEYS) else {
        let found: Vec<&str> = match &doc {
            Node::Map { entries, .. } => entries.iter().map(|(k, _)| k.as_str()).collect(),
            _ => vec![],
        };
        return Err(ctx.err(
            None,
            None,
            format!(
                "no camera matrix: expected one of {} (found keys: {})",
                CAMERA_MATRIX_KEYS.join(", "),
                crate::io::clip(&found.join(", "), 200)
            ),
        ));
    };
    let (r, c, k) = matrix(ctx, kkey, knode)?;
    if (r, c) != (3, 3) {
        return Err(ctx.err(
            Some(knode.line()),
            Some(kkey),
            format!("expected a 3x3 matrix, found {r}x{c}"),
        ));
    }
    if k[3] != 0.0 || k[6] != 0.0 || k[7] != 0.0 || k[8] != 1.0 {
        return Err(ctx.err(
            Some(knode.line()),
            Some(kkey),
            "expected [fx s cx; 0 fy cy; 0 0 1] with a last row of 0 0 1",
        ));
    }
    if !(k[0] > 0.0 && k[4] > 0.0) {
        return Err(ctx.err(
            Some(knode.line()),
            Some(kkey),
            "focal lengths fx and fy must be positive",
        ));
    }

    let Some((dkey, dnode)) = first(&doc, &DISTORTION_KEYS) else {
        return Err(ctx.err(
            None,
            None,
            format!(
                "no distortion coefficients: expected one of {} (write zeros for a distortion-free camera)",
                DISTORTION_KEYS.join(", ")
            ),
        ));
    };
    let (r, c, d) = matrix(ctx, dkey, dnode)?;
    if r != 1 && c != 1 {
        return Err(ctx.err(
            Some(dnode.line()),
            Some(dkey),
            format!("expected a 1xN or Nx1 vector, found {r}x{c}"),
        ));
    }
    match d.len() {
        4 | 5 | 8 => {}
        12 | 14 => {
            if d[8..].iter().any(|&v| v != 0.0) {
                return Err(ctx.err(
                    Some(dnode.line()),
                    Some(dkey),
                    "thin-prism (s1..s4) or tilt (tx, ty) coefficients are not supported; \
                     recalibrate without CALIB_THIN_PRISM_MODEL / CALIB_TILTED_MODEL",
                ));
            }
        }
        n => {
            return Err(ctx.err(
                Some(dnode.line()),
                Some(dkey),
                format!("expected 4, 5 or 8 coefficients (k1 k2 p1 p2 [k3 [k4 k5 k6]]), found {n}"),
            ));
        }
    }
    let mut camera = Camera {
        skew: k[1],
        ..Camera::pinhole(k[0], k[4], k[2], k[5]).with_distortion(&d[..d.len().min(8)])
    };

    let width = scalar_f64(ctx, &doc, "image_width")?.or(scalar_f64(ctx, &doc, "image_Width")?);
    let height = scalar_f64(ctx, &doc, "image_height")?.or(scalar_f64(ctx, &doc, "image_Height")?);
    if let (Some(w), Some(h)) = (width, height) {
        if w < 1.0 || h < 1.0 || w.fract() != 0.0 || h.fract() != 0.0 {
            return Err(ctx.err(
                None,
                Some("image_width"),
                "image size must be positive whole numbers",
            ));
        }
        camera.image_size = Some(ImageSize {
            width: w as u32,
            height: h as u32,
        });
    }

    let covariance = match doc.get("parameter_covariance") {
        None => None,
        Some(node) => {
            let (r, c, data) = matrix(ctx, "parameter_covariance", node)?;
            let names = strings(&doc, "parameter_names").unwrap_or_default();
            if (r, c) != (N_PARAMS, N_PARAMS) || names != PARAM_NAMES {
                return Err(ctx.err(
                    Some(node.line()),
                    Some("parameter_covariance"),
                    format!(
                        "expected a {N_PARAMS}x{N_PARAMS} matrix over parameter_names [{}]",
                        PARAM_NAMES.join(", ")
                    ),
                ));
            }
            Some(ParamCovariance::from_row_slice(&data))
        }
    };

    let summary = match scalar_f64(ctx, &doc, "avg_reprojection_error")?.or(scalar_f64(
        ctx,
        &doc,
        "Avg_Reprojection_Error",
    )?) {
        None => None,
        Some(rms_px) => Some(read_summary(ctx, &doc, rms_px)?),
    };

    Ok(Calibration {
        camera,
        covariance,
        summary,
        notes: Vec::new(),
        extrinsics: None,
    })
}

fn read_summary(ctx: &Ctx, doc: &Node, rms_px: f64) -> Result<CalibrationSummary, FormatError> {
    let get = |a: &str, b: &str| -> Result<Option<f64>, FormatError> {
        Ok(scalar_f64(ctx, doc, a)?.or(scalar_f64(ctx, doc, b)?))
    };
    let board = match (
        get("board_width", "board_Width")?,
        get("board_height", "board_Height")?,
        get("square_size", "square_Size")?,
    ) {
        (Some(c), Some(r), Some(s)) => Some(BoardSpec {
            cols: c as u32,
            rows: r as u32,
            square_m: s,
        }),
        _ => None,
    };
    let per_view = match first(
        doc,
        &[
            "per_view_reprojection_errors",
            "Per_View_Reprojection_Errors",
        ],
    ) {
        Some((key, node)) => matrix(ctx, key, node)?.2,
        None => Vec::new(),
    };
    let extrinsics = match first(doc, &["extrinsic_parameters", "Extrinsic_Parameters"]) {
        Some((key, node)) => {
            let (r, c, data) = matrix(ctx, key, node)?;
            if c != 6 || r != per_view.len() {
                return Err(ctx.err(
                    Some(node.line()),
                    Some(key),
                    format!(
                        "expected {} rows of 6 (rvec, tvec), found {r}x{c}",
                        per_view.len()
                    ),
                ));
            }
            data
        }
        None => vec![0.0; per_view.len() * 6],
    };
    let names = strings(doc, "image_names");
    let outliers = match doc.get("view_outliers") {
        Some(node) => matrix(ctx, "view_outliers", node)?.2,
        None => vec![0.0; per_view.len()],
    };
    let views = per_view
        .iter()
        .enumerate()
        .map(|(i, &rms)| ViewSummary {
            name: names
                .as_ref()
                .and_then(|n| n.get(i).cloned())
                .unwrap_or_else(|| format!("view {i}")),
            rms_px: rms,
            rvec: [
                extrinsics[6 * i],
                extrinsics[6 * i + 1],
                extrinsics[6 * i + 2],
            ],
            tvec: [
                extrinsics[6 * i + 3],
                extrinsics[6 * i + 4],
                extrinsics[6 * i + 5],
            ],
            outlier: outliers.get(i).is_some_and(|&o| o != 0.0),
        })
        .collect();
    Ok(CalibrationSummary {
        rms_px,
        board,
        free_parameters: strings(doc, "free_parameters").unwrap_or_default(),
        views,
        created_utc: doc
            .get("calibration_time")
            .and_then(Node::as_scalar)
            .map(str::to_string),
    })
}

pub(super) fn render(cal: &Calibration) -> String {
    let cam = &cal.camera;
    let mut w = cvyaml::Writer::new();
    w.comment(&format!(
        "geostride {} camera calibration (OpenCV conventions: pixel (0,0) is the centre of the top-left pixel)",
        env!("CARGO_PKG_VERSION")
    ));
    if let Some(s) = &cal.summary {
        if let Some(t) = &s.created_utc {
            w.string("calibration_time", t);
        }
        w.scalar("nframes", s.views.len());
    }
    if let Some(size) = cam.image_size {
        w.scalar("image_width", size.width);
        w.scalar("image_height", size.height);
    }
    if let Some(b) = cal.summary.as_ref().and_then(|s| s.board) {
        w.scalar("board_width", b.cols);
        w.scalar("board_height", b.rows);
        w.real("square_size", b.square_m);
    }
    w.matrix("camera_matrix", 3, 3, cam.k_matrix().transpose().as_slice());
    let n_dist = if cam.is_rational() { 8 } else { 5 };
    w.matrix("distortion_coefficients", n_dist, 1, &cam.dist[..n_dist]);
    if let Some(s) = &cal.summary {
        w.real("avg_reprojection_error", s.rms_px);
        if !s.views.is_empty() {
            let n = s.views.len();
            let per: Vec<f64> = s.views.iter().map(|v| v.rms_px).collect();
            w.matrix("per_view_reprojection_errors", n, 1, &per);
            let ext: Vec<f64> = s
                .views
                .iter()
                .flat_map(|v| v.rvec.iter().chain(v.tvec.iter()).copied())
                .collect();
            w.matrix("extrinsic_parameters", n, 6, &ext);
            let names: Vec<&str> = s.views.iter().map(|v| v.name.as_str()).collect();
            w.strings("image_names", &names);
            let out: Vec<f64> = s
                .views
                .iter()
                .map(|v| f64::from(u8::from(v.outlier)))
                .collect();
            w.matrix("view_outliers", n, 1, &out);
        }
        let free: Vec<&str> = s.free_parameters.iter().map(String::as_str).collect();
        w.strings("free_parameters", &free);
    }
    if let Some(cov) = &cal.covariance {
        w.strings("parameter_names", &PARAM_NAMES);
        w.matrix("parameter_std_dev", N_PARAMS, 1, &std_devs(cov));
        w.matrix(
            "parameter_covariance",
            N_PARAMS,
            N_PARAMS,
            cov.transpose().as_slice(),
        );
    }
    w.finish()
}
