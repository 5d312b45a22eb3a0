//! Checkerboard calibration.
//!
//! The solver is pure: [`zhang`] initialises the intrinsics in closed form from the board
//! homographies (Zhang 2000), [`refine`] runs Levenberg–Marquardt over the intrinsics, the
//! distortion and every board pose with a Schur complement on the poses, and reports the
//! parameter covariance. [`detect`] (OpenCV) finds the corners and [`inputs`] (OpenCV) turns
//! images, folders and videos into frames.

pub mod coverage;
#[cfg(feature = "opencv")]
pub mod detect;
#[cfg(feature = "opencv")]
pub mod inputs;
#[cfg(feature = "opencv")]
pub mod oracle;
pub mod refine;
pub mod zhang;

use nalgebra::{Vector2, Vector3};
use serde::Serialize;
use thiserror::Error;

use crate::camera::{
    BoardSpec, Calibration, CalibrationSummary, Camera, ImageSize, N_PARAMS, PARAM_NAMES,
    ParamCovariance, ViewSummary, param,
};
use crate::geom::Rigid3;
use crate::optim::{LmSettings, Termination};

pub use coverage::Coverage;

/// The board's inner corners in its own frame (metres, z = 0), in OpenCV's order: row by row,
/// `cols` corners per row.
pub fn board_points(board: &BoardSpec) -> Vec<Vector3<f64>> {
    (0..board.rows)
        .flat_map(|r| {
            (0..board.cols).map(move |c| {
                Vector3::new(
                    f64::from(c) * board.square_m,
                    f64::from(r) * board.square_m,
                    0.0,
                )
            })
        })
        .collect()
}

/// One view of the board: its detected corners, in [`board_points`] order.
#[derive(Clone, Debug)]
pub struct View {
    pub name: String,
    pub corners: Vec<Vector2<f64>>,
}

/// What the solver estimates and what it holds fixed (OpenCV's `CALIB_*` flags, by name).
#[derive(Clone, Debug)]
pub struct Options {
    /// Hold `fx / fy` at this ratio (`CALIB_FIX_ASPECT_RATIO`).
    pub fix_aspect: Option<f64>,
    /// Hold the principal point at the image centre (`CALIB_FIX_PRINCIPAL_POINT`).
    pub fix_principal_point: bool,
    /// Hold p1 = p2 = 0 (`CALIB_ZERO_TANGENT_DIST`).
    pub zero_tangential: bool,
    /// Number of estimated polynomial radial terms k1..k3 (0 to 3).
    pub radial_terms: usize,
    /// Also estimate the rational terms k4, k5, k6 (`CALIB_RATIONAL_MODEL`).
    pub rational: bool,
    /// Views whose RMS exceeds this multiple of the median view RMS are flagged as outliers.
    pub outlier_factor: f64,
    pub lm: LmSettings,
}

impl Default for Options {
    fn default() -> Self {
        Options {
            fix_aspect: None,
            fix_principal_point: false,
            zero_tangential: false,
            radial_terms: 3,
            rational: false,
            outlier_factor: 3.0,
            lm: LmSettings::default(),
        }
    }
}

#[derive(Debug, Error)]
pub enum CalibrationError {
    #[error("{got} usable view(s) of the board; at least 3 are needed, from different angles")]
    TooFewViews { got: usize },
    #[error("view '{view}' has {got} corners, but the {cols}x{rows} board has {expected}")]
    CornerCount {
        view: String,
        got: usize,
        expected: usize,
        cols: u32,
        rows: u32,
    },
    #[error("--radial-terms must be 0 to 3, got {0}")]
    RadialTerms(usize),
    #[error("the aspect ratio fx/fy must be positive, got {0}")]
    Aspect(f64),
    #[error(
        "cannot initialise the intrinsics: {0}. The views may be degenerate (boards all parallel \
         to the image, or all at the same tilt); add views with the board tilted in different directions"
    )]
    Initialisation(String),
    #[error("the optimisation failed: {0}")]
    Optimisation(String),
}

/// The full result of a calibration, with everything the report shows.
#[derive(Clone, Debug)]
pub struct CalibrationResult {
    pub camera: Camera,
    /// Parameter covariance, [`PARAM_NAMES`] order; zero for fixed parameters.
    pub covariance: ParamCovariance,
    pub free_parameters: Vec<&'static str>,
    /// RMS reprojection error over all corners, pixels (OpenCV's definition).
    pub rms_px: f64,
    /// Estimated standard deviation of one corner coordinate, pixels.
    pub sigma_px: f64,
    pub views: Vec<ViewResult>,
    pub iterations: usize,
    pub termination: Termination,
    pub coverage: Coverage,
    pub board: BoardSpec,
    pub image_size: ImageSize,
    /// Names of views dropped as outliers before the final solve (`--drop-outliers`).
    pub dropped: Vec<String>,
}

#[derive(Clone, Debug)]
pub struct ViewResult {
    pub name: String,
    pub cam_from_board: Rigid3,
    pub rms_px: f64,
    pub max_px: f64,
    pub outlier: bool,
}

impl CalibrationResult {
    pub fn std_devs(&self) -> [f64; N_PARAMS] {
        crate::camera::std_devs(&self.covariance)
    }

    /// The calibration as files carry it.
    pub fn to_calibration(&self) -> Calibration {
        Calibration {
            camera: self.camera.clone(),
            covariance: Some(self.covariance),
            summary: Some(CalibrationSummary {
                rms_px: self.rms_px,
                board: Some(self.board),
                free_parameters: self.free_parameters.iter().map(|s| s.to_string()).collect(),
                views: self
                    .views
                    .iter()
                    .map(|v| ViewSummary {
                        name: v.name.clone(),
                        rms_px: v.rms_px,
                        rvec: v.cam_from_board.rvec().into(),
                        tvec: v.cam_from_board.translation.into(),
                        outlier: v.outlier,
                    })
                    .collect(),
                created_utc: Some(crate::io::utc_now_iso8601()),
            }),
            notes: Vec::new(),
            extrinsics: None,
        }
    }
}

/// How each estimated quantity maps onto the 13 camera parameters.
#[derive(Clone, Debug)]
pub struct Parametrization {
    /// Per free quantity: its name and `(parameter index, coefficient)` pairs.
    pub slots: Vec<(&'static str, Vec<(usize, f64)>)>,
}

impl Parametrization {
    pub fn new(opts: &Options) -> Result<Self, CalibrationError> {
        if opts.radial_terms > 3 {
            return Err(CalibrationError::RadialTerms(opts.radial_terms));
        }
        let mut slots: Vec<(&'static str, Vec<(usize, f64)>)> = Vec::new();
        match opts.fix_aspect {
            Some(a) if !(a > 0.0 && a.is_finite()) => return Err(CalibrationError::Aspect(a)),
            // fx = a·f, fy = f: one focal length.
            Some(a) => slots.push(("f", vec![(param::FX, a), (param::FY, 1.0)])),
            None => {
                slots.push(("fx", vec![(param::FX, 1.0)]));
                slots.push(("fy", vec![(param::FY, 1.0)]));
            }
        }
        if !opts.fix_principal_point {
            slots.push(("cx", vec![(param::CX, 1.0)]));
            slots.push(("cy", vec![(param::CY, 1.0)]));
        }
        let radial = [param::K1, param::K2, param::K3];
        for &k in &radial[..opts.radial_terms] {
            slots.push((PARAM_NAMES[k], vec![(k, 1.0)]));
        }
        if !opts.zero_tangential {
            slots.push(("p1", vec![(param::P1, 1.0)]));
            slots.push(("p2", vec![(param::P2, 1.0)]));
        }
        if opts.rational {
            for k in [param::K4, param::K5, param::K6] {
                slots.push((PARAM_NAMES[k], vec![(k, 1.0)]));
            }
        }
        Ok(Parametrization { slots })
    }

    pub fn len(&self) -> usize {
        self.slots.len()
    }

    pub fn is_empty(&self) -> bool {
        self.slots.is_empty()
    }

    /// The free values of a camera (each slot's first parameter divided by its coefficient).
    pub fn get(&self, cam: &Camera) -> Vec<f64> {
        let p = cam.params();
        self.slots
            .iter()
            .map(|(_, c)| p[c.last().expect("slot").0] / c.last().expect("slot").1)
            .collect()
    }

    /// Writes free values into a camera; parameters outside every slot keep their values.
    pub fn set(&self, cam: &mut Camera, theta: &[f64]) {
        let mut p = cam.params();
        for ((_, coeffs), &t) in self.slots.iter().zip(theta) {
            for &(i, c) in coeffs {
                p[i] = c * t;
            }
        }
        cam.set_params(&p);
    }

    /// The linear map from free values to the 13 parameters (13 x n).
    pub fn matrix(&self) -> nalgebra::DMatrix<f64> {
        let mut m = nalgebra::DMatrix::zeros(N_PARAMS, self.len());
        for (s, (_, coeffs)) in self.slots.iter().enumerate() {
            for &(i, c) in coeffs {
                m[(i, s)] = c;
            }
        }
        m
    }

    pub fn names(&self) -> Vec<&'static str> {
        self.slots.iter().map(|(n, _)| *n).collect()
    }
}

/// Names of the 13 parameters that a parametrization estimates (`f` expands to fx and fy).
fn free_parameter_names(p: &Parametrization) -> Vec<&'static str> {
    let m = p.matrix();
    (0..N_PARAMS)
        .filter(|&i| m.row(i).iter().any(|&c| c != 0.0))
        .map(|i| PARAM_NAMES[i])
        .collect()
}

/// Calibrates a camera from views of a board: closed-form initialisation, then
/// Levenberg–Marquardt, then outlier flags; with `drop_outliers`, recalibrates once without the
/// flagged views (keeping at least 3).
pub fn calibrate(
    views: &[View],
    board: &BoardSpec,
    image_size: ImageSize,
    opts: &Options,
    drop_outliers: bool,
) -> Result<CalibrationResult, CalibrationError> {
    let first = calibrate_once(views, board, image_size, opts)?;
    if !drop_outliers || !first.views.iter().any(|v| v.outlier) {
        return Ok(first);
    }
    let kept: Vec<View> = views
        .iter()
        .zip(&first.views)
        .filter(|(_, r)| !r.outlier)
        .map(|(v, _)| v.clone())
        .collect();
    if kept.len() < 3 {
        return Ok(first);
    }
    let mut second = calibrate_once(&kept, board, image_size, opts)?;
    second.dropped = first
        .views
        .iter()
        .filter(|v| v.outlier)
        .map(|v| v.name.clone())
        .collect();
    Ok(second)
}

fn calibrate_once(
    views: &[View],
    board: &BoardSpec,
    image_size: ImageSize,
    opts: &Options,
) -> Result<CalibrationResult, CalibrationError> {
    let object = board_points(board);
    for v in views {
        if v.corners.len() != object.len() {
            return Err(CalibrationError::CornerCount {
                view: v.name.clone(),
                got: v.corners.len(),
                expected: object.len(),
                cols: board.cols,
                rows: board.rows,
            });
        }
    }
    if views.len() < 3 {
        return Err(CalibrationError::TooFewViews { got: views.len() });
    }
    let parametrization = Parametrization::new(opts)?;
    let corners: Vec<&[Vector2<f64>]> = views.iter().map(|v| v.corners.as_slice()).collect();
    let init = zhang::initialise(&object, &corners, image_size, opts)?;
    let solved = refine::refine(
        &object,
        &corners,
        init.camera,
        init.cam_from_board,
        &parametrization,
        &opts.lm,
    )?;

    let n_points: usize = corners.iter().map(|c| c.len()).sum();
    let rms_px = (2.0 * solved.cost / n_points as f64).sqrt();
    let mut view_results: Vec<ViewResult> = views
        .iter()
        .zip(&solved.cam_from_board)
        .zip(&solved.residuals)
        .map(|((v, pose), res)| {
            let sq: f64 = res.iter().map(|r| r.norm_squared()).sum();
            ViewResult {
                name: v.name.clone(),
                cam_from_board: *pose,
                rms_px: (sq / res.len() as f64).sqrt(),
                max_px: res.iter().map(|r| r.norm()).fold(0.0, f64::max),
                outlier: false,
            }
        })
        .collect();
    flag_outliers(&mut view_results, opts.outlier_factor);

    Ok(CalibrationResult {
        camera: solved.camera,
        covariance: solved.covariance,
        free_parameters: free_parameter_names(&parametrization),
        rms_px,
        sigma_px: solved.sigma_px,
        views: view_results,
        iterations: solved.iterations,
        termination: solved.termination,
        coverage: Coverage::of(&corners, image_size),
        board: *board,
        image_size,
        dropped: Vec::new(),
    })
}

/// Flags views whose RMS exceeds `factor` times the median view RMS.
fn flag_outliers(views: &mut [ViewResult], factor: f64) {
    let mut rms: Vec<f64> = views.iter().map(|v| v.rms_px).collect();
    rms.sort_by(f64::total_cmp);
    let median = if rms.len() % 2 == 1 {
        rms[rms.len() / 2]
    } else {
        0.5 * (rms[rms.len() / 2 - 1] + rms[rms.len() / 2])
    };
    for v in views {
        v.outlier = v.rms_px > factor * median;
    }
}

/// A serialisable report for `--json`.
#[derive(Serialize)]
pub struct JsonReport {
    pub board: [u32; 2],
    pub square_m: f64,
    pub camera: Camera,
    pub std_dev: std::collections::BTreeMap<&'static str, f64>,
    pub free_parameters: Vec<&'static str>,
    pub rms_px: f64,
    pub sigma_px: f64,
    pub iterations: usize,
    pub termination: Termination,
    pub views: Vec<JsonView>,
    pub dropped_views: Vec<String>,
    pub coverage_percent: f64,
}

#[derive(Serialize)]
pub struct JsonView {
    pub name: String,
    pub rms_px: f64,
    pub max_px: f64,
    pub outlier: bool,
    pub rvec: [f64; 3],
    pub tvec_m: [f64; 3],
}

impl CalibrationResult {
    pub fn json_report(&self) -> JsonReport {
        let sd = self.std_devs();
        JsonReport {
            board: [self.board.cols, self.board.rows],
            square_m: self.board.square_m,
            camera: self.camera.clone(),
            std_dev: PARAM_NAMES.iter().copied().zip(sd).collect(),
            free_parameters: self.free_parameters.clone(),
            rms_px: self.rms_px,
            sigma_px: self.sigma_px,
            iterations: self.iterations,
            termination: self.termination,
            views: self
                .views
                .iter()
                .map(|v| JsonView {
                    name: v.name.clone(),
                    rms_px: v.rms_px,
                    max_px: v.max_px,
                    outlier: v.outlier,
                    rvec: v.cam_from_board.rvec().into(),
                    tvec_m: v.cam_from_board.translation.into(),
                })
                .collect(),
            dropped_views: self.dropped.clone(),
            coverage_percent: self.coverage.percent(),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::simulate::board::{add_noise, project_corners, random_board_poses};
    use rand::SeedableRng;

    fn truth() -> Camera {
        Camera::pinhole(1000.0, 1004.0, 642.0, 478.0)
            .with_distortion(&[-0.21, 0.12, 0.0011, -0.0006, -0.03])
            .with_image_size(1280, 960)
    }

    const BOARD: BoardSpec = BoardSpec {
        cols: 9,
        rows: 6,
        square_m: 0.03,
    };

    fn views(cam: &Camera, n: usize, sigma: f64, seed: u64) -> Vec<View> {
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(seed);
        random_board_poses(cam, &BOARD, n, &mut rng)
            .iter()
            .enumerate()
            .map(|(i, p)| {
                let mut corners = project_corners(cam, &BOARD, p);
                add_noise(&mut corners, sigma, &mut rng);
                View {
                    name: format!("v{i}"),
                    corners,
                }
            })
            .collect()
    }

    #[test]
    fn noise_free_views_give_the_exact_camera() {
        let cam = truth();
        let v = views(&cam, 10, 0.0, 1);
        let r = calibrate(
            &v,
            &BOARD,
            cam.image_size.unwrap(),
            &Options::default(),
            false,
        )
        .unwrap();
        let (a, b) = (r.camera.params(), cam.params());
        for i in 0..N_PARAMS {
            assert!(
                (a[i] - b[i]).abs() < 1e-6 * (1.0 + b[i].abs()),
                "{}: {} vs {}",
                PARAM_NAMES[i],
                a[i],
                b[i]
            );
        }
        assert!(r.rms_px < 1e-6, "{}", r.rms_px);
        assert!(r.termination.converged(), "{:?}", r.termination);
    }

    #[test]
    fn fixed_quantities_stay_fixed() {
        let cam = Camera {
            fy: 1000.0,
            cx: 639.5,
            cy: 479.5,
            dist: [-0.2, 0.1, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0],
            ..truth()
        };
        let v = views(&cam, 8, 0.1, 2);
        let opts = Options {
            fix_aspect: Some(1.0),
            fix_principal_point: true,
            zero_tangential: true,
            radial_terms: 2,
            ..Options::default()
        };
        let r = calibrate(&v, &BOARD, cam.image_size.unwrap(), &opts, false).unwrap();
        assert_eq!(r.camera.fx, r.camera.fy);
        assert_eq!((r.camera.cx, r.camera.cy), (639.5, 479.5));
        assert_eq!(r.camera.dist[2..], [0.0; 6]);
        assert_eq!(r.free_parameters, vec!["fx", "fy", "k1", "k2"]);
        let sd = r.std_devs();
        assert_eq!(sd[param::CX], 0.0);
        assert!(sd[param::FX] > 0.0 && (sd[param::FX] - sd[param::FY]).abs() < 1e-12);
        assert!((r.camera.fx - 1000.0).abs() < 6.0 * sd[param::FX]);
    }

    #[test]
    fn a_bad_view_is_flagged_and_dropped() {
        let cam = truth();
        let mut v = views(&cam, 10, 0.2, 3);
        add_noise(
            &mut v[4].corners,
            2.0,
            &mut rand_chacha::ChaCha8Rng::seed_from_u64(9),
        );
        let r = calibrate(
            &v,
            &BOARD,
            cam.image_size.unwrap(),
            &Options::default(),
            false,
        )
        .unwrap();
        let flagged: Vec<&str> = r
            .views
            .iter()
            .filter(|v| v.outlier)
            .map(|v| v.name.as_str())
            .collect();
        assert_eq!(flagged, vec!["v4"]);
        let r2 = calibrate(
            &v,
            &BOARD,
            cam.image_size.unwrap(),
            &Options::default(),
            true,
        )
        .unwrap();
        assert_eq!(r2.dropped, vec!["v4".to_string()]);
        assert_eq!(r2.views.len(), 9);
        assert!(r2.rms_px < r.rms_px);
    }

    #[test]
    fn fronto_parallel_boards_are_refused_not_guessed() {
        // Boards parallel to the image plane do not determine the focal length.
        let cam = truth();
        let object = board_points(&BOARD);
        let v: Vec<View> = [(-0.1, -0.05), (0.0, 0.0), (-0.05, 0.02), (-0.12, 0.03)]
            .iter()
            .enumerate()
            .map(|(i, &(x, y))| View {
                name: format!("v{i}"),
                corners: object
                    .iter()
                    .map(|p| {
                        cam.project(&(p + nalgebra::Vector3::new(x, y, 0.6)))
                            .unwrap()
                    })
                    .collect(),
            })
            .collect();
        let err = calibrate(
            &v,
            &BOARD,
            cam.image_size.unwrap(),
            &Options::default(),
            false,
        )
        .unwrap_err();
        println!("{err}");
        assert!(
            matches!(
                err,
                CalibrationError::Initialisation(_) | CalibrationError::Optimisation(_)
            ),
            "{err}"
        );
    }

    #[test]
    fn too_few_views_and_wrong_corner_counts_are_errors() {
        let cam = truth();
        let v = views(&cam, 2, 0.1, 4);
        assert!(matches!(
            calibrate(
                &v,
                &BOARD,
                cam.image_size.unwrap(),
                &Options::default(),
                false
            ),
            Err(CalibrationError::TooFewViews { got: 2 })
        ));
        let mut v = views(&cam, 4, 0.1, 5);
        v[1].corners.pop();
        assert!(matches!(
            calibrate(
                &v,
                &BOARD,
                cam.image_size.unwrap(),
                &Options::default(),
                false
            ),
            Err(CalibrationError::CornerCount { .. })
        ));
    }
}
