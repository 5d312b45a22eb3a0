//! Camera models and calibration files (pure: nalgebra and std only).
//!
//! [`Camera`] is a pinhole camera with Brown–Conrady distortion in OpenCV's order and
//! conventions. [`Calibration`] is a camera together with what a calibration knows about it: the
//! parameter covariance and a summary of the views it came from. [`formats`] reads and writes it
//! as OpenCV YAML, Agisoft Metashape XML and geostride JSON.

pub mod formats;
mod model;
pub mod presets;

pub use model::{Camera, CameraError, ImageSize, N_PARAMS, PARAM_NAMES, ParamJacobian, param};

use nalgebra::SMatrix;

/// Covariance of the 13 camera parameters, [`PARAM_NAMES`] order. Rows and columns of parameters
/// that were held fixed are zero.
pub type ParamCovariance = SMatrix<f64, N_PARAMS, N_PARAMS>;

/// The widest or tallest image geostride accepts, pixels: the largest sensors are about 15 000
/// pixels wide; a bigger number is a mistake, and buffers grow with it.
pub const MAX_IMAGE_SIDE: u32 = 32_768;

/// The largest focal length accepted, pixels.
pub const MAX_FOCAL_PX: f64 = 1e7;

/// Standard deviations from a covariance's diagonal ([`PARAM_NAMES`] order).
pub fn std_devs(cov: &ParamCovariance) -> [f64; N_PARAMS] {
    std::array::from_fn(|i| cov[(i, i)].max(0.0).sqrt())
}

/// A camera with its uncertainty and the record of how it was calibrated.
#[derive(Clone, Debug, PartialEq)]
pub struct Calibration {
    pub camera: Camera,
    pub covariance: Option<ParamCovariance>,
    pub summary: Option<CalibrationSummary>,
    /// Remarks made while reading or converting (e.g. an approximated coefficient).
    pub notes: Vec<String>,
    /// A fixed camera's pose, when the file gives one (a Tsai calibration, geostride JSON).
    pub extrinsics: Option<Extrinsics>,
}

/// Where a fixed camera stands: `cam_from_world` with the world in metres, and which world.
#[derive(Clone, Debug, PartialEq)]
pub struct Extrinsics {
    pub cam_from_world: crate::geom::Rigid3,
    /// The world frame, in words (the file's own frame, a site frame, ...).
    pub world: String,
}

/// What a checkerboard calibration reports and calibration files carry.
#[derive(Clone, Debug, PartialEq)]
pub struct CalibrationSummary {
    /// Root mean square of the reprojection error length over all corners, pixels (OpenCV's
    /// definition: `sqrt(Σ‖r‖² / n_points)`).
    pub rms_px: f64,
    pub board: Option<BoardSpec>,
    /// Names of the parameters that were estimated (the rest were held fixed).
    pub free_parameters: Vec<String>,
    pub views: Vec<ViewSummary>,
    /// ISO 8601 UTC time of the calibration.
    pub created_utc: Option<String>,
}

/// A planar chessboard: inner corners per row and column, and the square size in metres.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct BoardSpec {
    pub cols: u32,
    pub rows: u32,
    pub square_m: f64,
}

/// One view of a calibration.
#[derive(Clone, Debug, PartialEq)]
pub struct ViewSummary {
    pub name: String,
    pub rms_px: f64,
    /// Board pose `cam_from_board`: Rodrigues vector (radians) and translation (metres).
    pub rvec: [f64; 3],
    pub tvec: [f64; 3],
    pub outlier: bool,
}

impl Calibration {
    /// Checks that the numbers can describe a camera: every parameter finite, focal lengths from
    /// 1 to [`MAX_FOCAL_PX`] pixels, an image size up to [`MAX_IMAGE_SIDE`], and a covariance
    /// that is finite, symmetric and positive semi-definite. On failure: the field and why.
    pub fn validate(&self) -> Result<(), (&'static str, String)> {
        let c = &self.camera;
        let params = c.params();
        if let Some(i) = params.iter().position(|v| !v.is_finite()) {
            return Err((
                PARAM_NAMES[i],
                format!("{} is not a finite number", params[i]),
            ));
        }
        for (name, f) in [("fx", c.fx), ("fy", c.fy)] {
            if !(1.0..=MAX_FOCAL_PX).contains(&f) {
                return Err((
                    name,
                    format!(
                        "a focal length of {f} px is not plausible (expected 1 to {MAX_FOCAL_PX:e} px)"
                    ),
                ));
            }
        }
        if let Some(s) = c.image_size
            && !((1..=MAX_IMAGE_SIDE).contains(&s.width)
                && (1..=MAX_IMAGE_SIDE).contains(&s.height))
        {
            return Err((
                "image_size",
                format!(
                    "{}x{} pixels: expected 1 to {MAX_IMAGE_SIDE} on each side",
                    s.width, s.height
                ),
            ));
        }
        if let Some(cov) = &self.covariance {
            if cov.iter().any(|v| !v.is_finite()) {
                return Err(("covariance", "has numbers that are not finite".into()));
            }
            let scale = cov.diagonal().amax().max(f64::MIN_POSITIVE);
            if (cov - cov.transpose()).amax() > 1e-9 * scale {
                return Err(("covariance", "is not symmetric".into()));
            }
            let min_eigen = cov.symmetric_eigenvalues().min();
            if min_eigen < -1e-9 * scale {
                return Err((
                    "covariance",
                    format!(
                        "is not positive semi-definite (an eigenvalue of {min_eigen:e}): variances cannot be negative"
                    ),
                ));
            }
        }
        Ok(())
    }

    pub fn from_camera(camera: Camera) -> Self {
        Calibration {
            camera,
            covariance: None,
            summary: None,
            notes: Vec::new(),
            extrinsics: None,
        }
    }

    /// Standard deviation of every parameter ([`PARAM_NAMES`] order), when the covariance is known.
    pub fn std_devs(&self) -> Option<[f64; N_PARAMS]> {
        self.covariance.as_ref().map(std_devs)
    }
}
