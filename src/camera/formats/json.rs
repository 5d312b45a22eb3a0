//! geostride's own calibration JSON (schema in `docs/formats.md`). It is the only format that
//! carries the full parameter covariance next to the summary of the views.

use serde::{Deserialize, Serialize};

use super::{Ctx, FormatError};
use crate::camera::{
    BoardSpec, Calibration, CalibrationSummary, Camera, Extrinsics, ImageSize, N_PARAMS,
    PARAM_NAMES, ParamCovariance, ViewSummary, std_devs,
};

pub const FORMAT_TAG: &str = "geostride.camera";
pub const VERSION: u32 = 1;

#[derive(Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
struct FileJson {
    format: String,
    version: u32,
    model: String,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    image_size: Option<SizeJson>,
    intrinsics: IntrinsicsJson,
    distortion: DistortionJson,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    uncertainty: Option<UncertaintyJson>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    calibration: Option<SummaryJson>,
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    notes: Vec<String>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    extrinsics: Option<ExtrinsicsJson>,
}

/// A fixed camera's pose: `cam_from_world` as a Rodrigues vector (radians) and a translation
/// (metres), and which world.
#[derive(Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
struct ExtrinsicsJson {
    rvec: [f64; 3],
    tvec_m: [f64; 3],
    world: String,
}

#[derive(Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
struct SizeJson {
    width: u32,
    height: u32,
}

#[derive(Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
struct IntrinsicsJson {
    fx: f64,
    fy: f64,
    cx: f64,
    cy: f64,
    #[serde(default)]
    skew: f64,
}

#[derive(Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
struct DistortionJson {
    k1: f64,
    k2: f64,
    p1: f64,
    p2: f64,
    k3: f64,
    #[serde(default)]
    k4: f64,
    #[serde(default)]
    k5: f64,
    #[serde(default)]
    k6: f64,
}

#[derive(Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
struct UncertaintyJson {
    parameters: Vec<String>,
    std_dev: Vec<f64>,
    covariance: Vec<Vec<f64>>,
}

#[derive(Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
struct SummaryJson {
    rms_px: f64,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    board: Option<BoardJson>,
    free_parameters: Vec<String>,
    views: Vec<ViewJson>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    created_utc: Option<String>,
}

#[derive(Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
struct BoardJson {
    cols: u32,
    rows: u32,
    square_m: f64,
}

#[derive(Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
struct ViewJson {
    name: String,
    rms_px: f64,
    rvec: [f64; 3],
    tvec_m: [f64; 3],
    outlier: bool,
}

pub(super) fn render(cal: &Calibration) -> Result<String, serde_json::Error> {
    let c = &cal.camera;
    let d = &c.dist;
    let file = FileJson {
        format: FORMAT_TAG.into(),
        version: VERSION,
        model: "brown-conrady".into(),
        image_size: c.image_size.map(|s| SizeJson {
            width: s.width,
            height: s.height,
        }),
        intrinsics: IntrinsicsJson {
            fx: c.fx,
            fy: c.fy,
            cx: c.cx,
            cy: c.cy,
            skew: c.skew,
        },
        distortion: DistortionJson {
            k1: d[0],
            k2: d[1],
            p1: d[2],
            p2: d[3],
            k3: d[4],
            k4: d[5],
            k5: d[6],
            k6: d[7],
        },
        uncertainty: cal.covariance.as_ref().map(|cov| UncertaintyJson {
            parameters: PARAM_NAMES.iter().map(|s| s.to_string()).collect(),
            std_dev: std_devs(cov).to_vec(),
            covariance: (0..N_PARAMS)
                .map(|i| (0..N_PARAMS).map(|j| cov[(i, j)]).collect())
                .collect(),
        }),
        calibration: cal.summary.as_ref().map(|s| SummaryJson {
            rms_px: s.rms_px,
            board: s.board.map(|b| BoardJson {
                cols: b.cols,
                rows: b.rows,
                square_m: b.square_m,
            }),
            free_parameters: s.free_parameters.clone(),
            views: s
                .views
                .iter()
                .map(|v| ViewJson {
                    name: v.name.clone(),
                    rms_px: v.rms_px,
                    rvec: v.rvec,
                    tvec_m: v.tvec,
                    outlier: v.outlier,
                })
                .collect(),
            created_utc: s.created_utc.clone(),
        }),
        notes: cal.notes.clone(),
        extrinsics: cal.extrinsics.as_ref().map(|e| ExtrinsicsJson {
            rvec: e.cam_from_world.rvec().into(),
            tvec_m: e.cam_from_world.translation.into(),
            world: e.world.clone(),
        }),
    };
    let mut s = serde_json::to_string_pretty(&file)?;
    s.push('\n');
    Ok(s)
}

pub(super) fn parse(ctx: &Ctx, text: &str) -> Result<Calibration, FormatError> {
    let file: FileJson = serde_json::from_str(text).map_err(|e| {
        ctx.err(
            Some(e.line()),
            None,
            format!("not a geostride camera JSON: {e} (schema: docs/formats.md)"),
        )
    })?;
    if file.format != FORMAT_TAG {
        return Err(ctx.err(
            None,
            Some("format"),
            format!("expected \"{FORMAT_TAG}\", found \"{}\"", file.format),
        ));
    }
    if file.version != VERSION {
        return Err(ctx.err(
            None,
            Some("version"),
            format!(
                "version {} is not supported by this geostride (reads version {VERSION})",
                file.version
            ),
        ));
    }
    if file.model != "brown-conrady" {
        return Err(ctx.err(
            None,
            Some("model"),
            format!("expected \"brown-conrady\", found \"{}\"", file.model),
        ));
    }
    let i = &file.intrinsics;
    if !(i.fx > 0.0 && i.fy > 0.0) {
        return Err(ctx.err(
            None,
            Some("intrinsics.fx"),
            "focal lengths must be positive",
        ));
    }
    let d = &file.distortion;
    let camera = Camera {
        image_size: file.image_size.map(|s| ImageSize {
            width: s.width,
            height: s.height,
        }),
        fx: i.fx,
        fy: i.fy,
        cx: i.cx,
        cy: i.cy,
        skew: i.skew,
        dist: [d.k1, d.k2, d.p1, d.p2, d.k3, d.k4, d.k5, d.k6],
    };
    let covariance = match file.uncertainty {
        None => None,
        Some(u) => {
            if u.parameters != PARAM_NAMES
                || u.covariance.len() != N_PARAMS
                || u.covariance.iter().any(|r| r.len() != N_PARAMS)
            {
                return Err(ctx.err(
                    None,
                    Some("uncertainty.covariance"),
                    format!(
                        "expected a {N_PARAMS}x{N_PARAMS} matrix over parameters [{}]",
                        PARAM_NAMES.join(", ")
                    ),
                ));
            }
            Some(ParamCovariance::from_fn(|r, c| u.covariance[r][c]))
        }
    };
    let summary = file.calibration.map(|s| CalibrationSummary {
        rms_px: s.rms_px,
        board: s.board.map(|b| BoardSpec {
            cols: b.cols,
            rows: b.rows,
            square_m: b.square_m,
        }),
        free_parameters: s.free_parameters,
        views: s
            .views
            .into_iter()
            .map(|v| ViewSummary {
                name: v.name,
                rms_px: v.rms_px,
                rvec: v.rvec,
                tvec: v.tvec_m,
                outlier: v.outlier,
            })
            .collect(),
        created_utc: s.created_utc,
    });
    let extrinsics = match file.extrinsics {
        None => None,
        Some(e) => {
            let finite = e.rvec.iter().chain(&e.tvec_m).all(|v| v.is_finite());
            if !finite || nalgebra::Vector3::from(e.rvec).norm() > 4.0 * std::f64::consts::PI {
                return Err(ctx.err(
                    None,
                    Some("extrinsics"),
                    "rvec (radians, a rotation of at most 4π) and tvec_m (metres) must be finite",
                ));
            }
            Some(Extrinsics {
                cam_from_world: crate::geom::Rigid3::from_rvec_tvec(
                    &e.rvec.into(),
                    &e.tvec_m.into(),
                ),
                world: e.world,
            })
        }
    };
    Ok(Calibration {
        camera,
        covariance,
        summary,
        notes: file.notes,
        extrinsics,
    })
}
