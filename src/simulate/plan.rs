//! Survey planning (pure): what a camera at a given altitude sees and how accurately heads are
//! located, as in the paper's sections 3.4.1 and 4.1.2.
//!
//! The camera looks straight down from `altitude_m` above flat ground (z = 0), image top to the
//! north. A head at height `h` is located by intersecting its pixel's ray with the plane z = h:
//!
//! - a head-height error Δh moves that intersection horizontally by `r·Δh/(H − h)`, with r the
//!   horizontal distance from the nadir: zero at the image centre, largest in the corners;
//! - a pixel covariance Σ becomes the world covariance `J Σ Jᵀ`, with `J = ∂(E, N)/∂(u, v)` of the
//!   ray–plane intersection; the 95 % error is the semi-major axis of the 95 % ellipse,
//!   `√(χ²₂(0.95) λ_max)`.

use nalgebra::{Matrix2, Matrix3, Vector2, Vector3};
use serde::Serialize;

use crate::camera::Camera;

/// χ² with 2 degrees of freedom at 95 %.
pub const CHI2_2_95: f64 = 5.991_464_547_107_979;

/// The pixel noise of head detections.
#[derive(Clone, Copy, Debug, PartialEq, Serialize)]
#[serde(tag = "kind", rename_all = "snake_case")]
pub enum PixelNoise {
    /// The same variance everywhere, both axes, no correlation (the paper: 4 px²).
    Constant { var_px2: f64 },
    /// A detector whose horizontal variance grows linearly from the centre to the left and
    /// right edges (the paper's section 4.1.3: 10 px² vertical; 10 px² horizontal at the centre,
    /// 20 px² at the edges).
    Detector {
        vertical_px2: f64,
        horizontal_centre_px2: f64,
        horizontal_edge_px2: f64,
    },
}

impl PixelNoise {
    /// Covariance of a detection at pixel `uv` in an image of `width` pixels centred on `cx`.
    pub fn covariance(&self, uv: &Vector2<f64>, cx: f64, width: f64) -> Matrix2<f64> {
        match *self {
            PixelNoise::Constant { var_px2 } => Matrix2::identity() * var_px2,
            PixelNoise::Detector {
                vertical_px2,
                horizontal_centre_px2,
                horizontal_edge_px2,
            } => {
                let f = ((uv.x - cx).abs() / (width / 2.0)).min(1.0);
                Matrix2::new(
                    horizontal_centre_px2 + f * (horizontal_edge_px2 - horizontal_centre_px2),
                    0.0,
                    0.0,
                    vertical_px2,
                )
            }
        }
    }
}

/// What to plan for.
#[derive(Clone, Debug)]
pub struct PlanSettings {
    /// Camera height above the ground, metres.
    pub altitude_m: f64,
    /// Height of the heads above the ground (the homography plane), metres.
    pub head_height_m: f64,
    /// Error of the assumed head height, metres.
    pub height_error_m: f64,
    pub noise: PixelNoise,
    /// Spacing of the map samples, pixels.
    pub map_step_px: u32,
}

/// A map over the image, sampled every `step_px` pixels (the last row and column on the edge).
#[derive(Clone, Debug, Serialize)]
pub struct ErrorMap {
    pub cols: usize,
    pub rows: usize,
    pub step_px: u32,
    /// Row-major, metres; NaN where the camera model cannot be inverted.
    pub values_m: Vec<f64>,
}

impl ErrorMap {
    pub fn max(&self) -> f64 {
        self.values_m
            .iter()
            .copied()
            .filter(|v| v.is_finite())
            .fold(0.0, f64::max)
    }
}

/// The largest error over the full frame and over its central half-width by half-height region.
#[derive(Clone, Copy, Debug, Serialize)]
pub struct ErrorSummary {
    pub max_full_m: f64,
    pub max_central_m: f64,
    pub at_centre_m: f64,
}

#[derive(Clone, Debug, Serialize)]
pub struct Plan {
    pub image_size: [u32; 2],
    pub altitude_m: f64,
    pub head_height_m: f64,
    /// Ground sample distance at the image centre, on the ground and at head height (m/px).
    pub gsd_ground_m: f64,
    pub gsd_head_m: f64,
    /// Width and height of the area seen, on the ground and at head height (metres, between the
    /// outer edges of the edge pixels, along the image axes through the centre).
    pub footprint_ground_m: [f64; 2],
    pub footprint_head_m: [f64; 2],
    pub height_error_m: f64,
    pub height_error: ErrorSummary,
    pub noise: PixelNoise,
    pub noise_95: ErrorSummary,
    #[serde(skip)]
    pub height_error_map: ErrorMap,
    #[serde(skip)]
    pub noise_95_map: ErrorMap,
}

#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum PlanError {
    #[error("the camera has no image size; give one with --video-mode")]
    NoImageSize,
    #[error("the altitude ({altitude} m) must exceed the head height plus its error ({head} m)")]
    TooLow { altitude: f64, head: f64 },
    #[error(
        "the maps would have {cells} cells (more than {MAX_MAP_CELLS}): give a larger --map-step"
    )]
    MapTooLarge { cells: u64 },
    #[error("{0} must be a finite number, not negative")]
    NotFinite(&'static str),
}

/// The most samples a map may have (each costs a ray intersection and 16 bytes).
pub const MAX_MAP_CELLS: u64 = 20_000_000;

/// A nadir camera: east along image x, north along image −y.
struct Nadir {
    camera: Camera,
    centre: Vector3<f64>,
    world_from_cam: Matrix3<f64>,
}

impl Nadir {
    fn new(camera: Camera, altitude_m: f64) -> Self {
        // Camera axes in the world: x = east, y = south, z = down.
        let world_from_cam = Matrix3::new(1.0, 0.0, 0.0, 0.0, -1.0, 0.0, 0.0, 0.0, -1.0);
        Nadir {
            camera,
            centre: Vector3::new(0.0, 0.0, altitude_m),
            world_from_cam,
        }
    }

    /// Horizontal position where the ray of pixel `uv` meets the plane z = `h`.
    fn on_plane(&self, uv: &Vector2<f64>, h: f64) -> Option<Vector2<f64>> {
        let ray = self.camera.unproject(uv).ok()?;
        let d = self.world_from_cam * ray.into_inner();
        if d.z >= 0.0 {
            return None;
        }
        let t = (h - self.centre.z) / d.z;
        Some((self.centre + d * t).xy())
    }
}

/// Plans a flight: footprint, GSD and both error maps.
pub fn plan(camera: &Camera, s: &PlanSettings) -> Result<Plan, PlanError> {
    let size = camera.image_size.ok_or(PlanError::NoImageSize)?;
    for (v, name) in [
        (s.head_height_m, "the head height"),
        (s.height_error_m, "the height error"),
    ] {
        if !(v.is_finite() && v >= 0.0) {
            return Err(PlanError::NotFinite(name));
        }
    }
    let step = u64::from(s.map_step_px.max(1));
    let cells = (u64::from(size.width) / step + 2) * (u64::from(size.height) / step + 2);
    if cells > MAX_MAP_CELLS {
        return Err(PlanError::MapTooLarge { cells });
    }
    if !(s.altitude_m > s.head_height_m + s.height_error_m.max(0.0)) {
        return Err(PlanError::TooLow {
            altitude: s.altitude_m,
            head: s.head_height_m + s.height_error_m.max(0.0),
        });
    }
    let (w, h) = (f64::from(size.width), f64::from(size.height));
    let nadir = Nadir::new(camera.clone(), s.altitude_m);
    let (cx, cy) = (camera.cx, camera.cy);

    let span = |plane: f64| -> [f64; 2] {
        let edge = |a: Vector2<f64>, b: Vector2<f64>| -> f64 {
            match (nadir.on_plane(&a, plane), nadir.on_plane(&b, plane)) {
                (Some(p), Some(q)) => (p - q).norm(),
                _ => f64::NAN,
            }
        };
        [
            edge(Vector2::new(-0.5, cy), Vector2::new(w - 0.5, cy)),
            edge(Vector2::new(cx, -0.5), Vector2::new(cx, h - 0.5)),
        ]
    };
    let gsd = |plane: f64| -> f64 {
        match (
            nadir.on_plane(&Vector2::new(cx - 0.5, cy), plane),
            nadir.on_plane(&Vector2::new(cx + 0.5, cy), plane),
        ) {
            (Some(p), Some(q)) => (p - q).norm(),
            _ => f64::NAN,
        }
    };

    let step = s.map_step_px.max(1);
    let samples = |n: u32| -> Vec<f64> {
        let mut v: Vec<f64> = (0..n).step_by(step as usize).map(f64::from).collect();
        if v.last().is_some_and(|&l| l < f64::from(n - 1)) {
            v.push(f64::from(n - 1));
        }
        v
    };
    let (us, vs) = (samples(size.width), samples(size.height));
    let central = |uv: &Vector2<f64>| (uv.x - cx).abs() <= w / 4.0 && (uv.y - cy).abs() <= h / 4.0;

    let mut dh_vals = Vec::with_capacity(us.len() * vs.len());
    let mut noise_vals = Vec::with_capacity(us.len() * vs.len());
    let (mut dh_sum, mut noise_sum) = (
        ErrorSummary {
            max_full_m: 0.0,
            max_central_m: 0.0,
            at_centre_m: 0.0,
        },
        ErrorSummary {
            max_full_m: 0.0,
            max_central_m: 0.0,
            at_centre_m: 0.0,
        },
    );
    let head = s.head_height_m;
    let dh_error = |uv: &Vector2<f64>| -> f64 {
        match (
            nadir.on_plane(uv, head),
            nadir.on_plane(uv, head + s.height_error_m),
        ) {
            (Some(a), Some(b)) => (a - b).norm(),
            _ => f64::NAN,
        }
    };
    let noise_error = |uv: &Vector2<f64>| -> f64 {
        let e = 0.25;
        let d = |du: f64, dv: f64| nadir.on_plane(&(uv + Vector2::new(du, dv)), head);
        let (Some(pu), Some(mu), Some(pv), Some(mv)) =
            (d(e, 0.0), d(-e, 0.0), d(0.0, e), d(0.0, -e))
        else {
            return f64::NAN;
        };
        let j = Matrix2::from_columns(&[(pu - mu) / (2.0 * e), (pv - mv) / (2.0 * e)]);
        let cov = j * s.noise.covariance(uv, cx, w) * j.transpose();
        let lmax = cov.symmetric_eigen().eigenvalues.max();
        (CHI2_2_95 * lmax.max(0.0)).sqrt()
    };
    for &v in &vs {
        for &u in &us {
            let uv = Vector2::new(u, v);
            let (a, b) = (dh_error(&uv), noise_error(&uv));
            dh_vals.push(a);
            noise_vals.push(b);
            for (sum, val) in [(&mut dh_sum, a), (&mut noise_sum, b)] {
                if val.is_finite() {
                    sum.max_full_m = sum.max_full_m.max(val);
                    if central(&uv) {
                        sum.max_central_m = sum.max_central_m.max(val);
                    }
                }
            }
        }
    }
    // The central region's own corners, which the sample grid may miss.
    for (du, dv) in [(-1.0, -1.0), (1.0, -1.0), (-1.0, 1.0), (1.0, 1.0)] {
        let uv = Vector2::new(cx + du * w / 4.0, cy + dv * h / 4.0);
        for (sum, val) in [
            (&mut dh_sum, dh_error(&uv)),
            (&mut noise_sum, noise_error(&uv)),
        ] {
            if val.is_finite() {
                sum.max_central_m = sum.max_central_m.max(val);
            }
        }
    }
    let c = Vector2::new(cx, cy);
    dh_sum.at_centre_m = dh_error(&c);
    noise_sum.at_centre_m = noise_error(&c);
    let map = |values_m| ErrorMap {
        cols: us.len(),
        rows: vs.len(),
        step_px: step,
        values_m,
    };
    Ok(Plan {
        image_size: [size.width, size.height],
        altitude_m: s.altitude_m,
        head_height_m: head,
        gsd_ground_m: gsd(0.0),
        gsd_head_m: gsd(head),
        footprint_ground_m: span(0.0),
        footprint_head_m: span(head),
        height_error_m: s.height_error_m,
        height_error: dh_sum,
        noise: s.noise,
        noise_95: noise_sum,
        height_error_map: map(dh_vals),
        noise_95_map: map(noise_vals),
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    fn settings() -> PlanSettings {
        PlanSettings {
            altitude_m: 30.0,
            head_height_m: 1.7,
            height_error_m: 0.1,
            noise: PixelNoise::Constant { var_px2: 4.0 },
            map_step_px: 16,
        }
    }

    #[test]
    fn closed_forms_for_a_pinhole() {
        // fx = 1000 at 2000x1000: half-angles tan 1.0 and 0.5.
        let cam = Camera::pinhole(1000.0, 1000.0, 999.5, 499.5).with_image_size(2000, 1000);
        let p = plan(&cam, &settings()).unwrap();
        assert!((p.gsd_ground_m - 0.03).abs() < 1e-9);
        assert!((p.gsd_head_m - 0.0283).abs() < 1e-9);
        assert!(
            (p.footprint_ground_m[0] - 60.0).abs() < 1e-6
                && (p.footprint_ground_m[1] - 30.0).abs() < 1e-6
        );
        // Δh error at a corner pixel centre: r·Δh/(H − h) = tan(θ)·Δh.
        let corner = ((999.5f64 / 1000.0).powi(2) + (499.5f64 / 1000.0).powi(2)).sqrt() * 0.1;
        assert!(
            (p.height_error.max_full_m - corner).abs() < 1e-9,
            "{}",
            p.height_error.max_full_m
        );
        let central = ((500.0f64 / 1000.0).powi(2) + (250.0f64 / 1000.0).powi(2)).sqrt() * 0.1;
        assert!((p.height_error.max_central_m - central).abs() < 1e-9);
        assert!(p.height_error.at_centre_m.abs() < 1e-12);
        // Noise: 2 px at the centre is 2·GSD(head) per axis; 95 % semi-axis √5.99·that.
        assert!((p.noise_95.at_centre_m - CHI2_2_95.sqrt() * 2.0 * 0.0283).abs() < 1e-6);
        // A nadir pinhole maps the head plane affinely: the same error everywhere.
        assert!((p.noise_95.max_full_m - p.noise_95.at_centre_m).abs() < 1e-9);
        // With barrel distortion the edges are compressed in the image, so errors grow there.
        let distorted = cam.clone().with_distortion(&[-0.2, 0.0, 0.0, 0.0, 0.0]);
        let q = plan(&distorted, &settings()).unwrap();
        assert!(q.noise_95.max_full_m > q.noise_95.at_centre_m * 1.2);
        assert_eq!(
            p.height_error_map.values_m.len(),
            p.height_error_map.cols * p.height_error_map.rows
        );
    }

    #[test]
    fn detector_model_varies_across_the_image() {
        let n = PixelNoise::Detector {
            vertical_px2: 10.0,
            horizontal_centre_px2: 10.0,
            horizontal_edge_px2: 20.0,
        };
        let c = n.covariance(&Vector2::new(999.5, 10.0), 999.5, 2000.0);
        assert_eq!(c, Matrix2::new(10.0, 0.0, 0.0, 10.0));
        let e = n.covariance(&Vector2::new(-0.5, 10.0), 999.5, 2000.0);
        assert_eq!(e[(0, 0)], 20.0);
        let cam = Camera::pinhole(1000.0, 1000.0, 999.5, 499.5);
        assert_eq!(plan(&cam, &settings()).unwrap_err(), PlanError::NoImageSize);
        let cam = cam.with_image_size(2000, 1000);
        let low = PlanSettings {
            altitude_m: 1.75,
            ..settings()
        };
        assert!(matches!(plan(&cam, &low), Err(PlanError::TooLow { .. })));
    }
}
