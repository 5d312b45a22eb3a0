//! Levenberg–Marquardt over the intrinsics, the distortion and every board pose: a
//! configuration of the bundle adjuster ([`crate::optim::ba`]) with the board's corners fixed,
//! one camera shared by every view and the intrinsics restricted to the free quantities of a
//! [`Parametrization`] (a fixed aspect ratio ties `fx` to `fy` through the camera model). The
//! covariance of the intrinsics is the adjuster's, `σ² S⁻¹` with the poses eliminated and `σ²`
//! the residual variance, mapped onto the 13 parameters.

use nalgebra::{DMatrix, SMatrix, Vector2, Vector3};

use super::{CalibrationError, Parametrization};
use crate::camera::{Camera, N_PARAMS, ParamCovariance};
use crate::geom::Rigid3;
use crate::optim::ba::{
    BaError, BaSettings, Observation, Priors, Problem, Projection, adjust_with_covariance,
};
use crate::optim::ba_camera::{camera_from_params, pose_params, rigid_pose};
use crate::optim::{LmSettings, Termination};

/// The optimum and what is known about it.
pub struct Solved {
    pub camera: Camera,
    pub cam_from_board: Vec<Rigid3>,
    /// Residuals (projected − observed, pixels) per view and corner.
    pub residuals: Vec<Vec<Vector2<f64>>>,
    /// `½ Σ ‖r‖²`.
    pub cost: f64,
    pub covariance: ParamCovariance,
    /// Residual standard deviation per coordinate, pixels.
    pub sigma_px: f64,
    pub iterations: usize,
    pub termination: Termination,
}

/// The Brown–Conrady camera with its parameters tied as a [`Parametrization`] says: each
/// quantity's last parameter carries it (the engine's free parameter), the others follow by
/// their coefficients and are held fixed.
struct Tied {
    /// Per parameter following another: its index, its carrier's and its ratio to it.
    ties: Vec<(usize, usize, f64)>,
    fixed: [bool; N_PARAMS],
}

impl Tied {
    fn new(param: &Parametrization) -> Tied {
        let mut fixed = [true; N_PARAMS];
        let mut ties = Vec::new();
        for (_, coeffs) in &param.slots {
            let &(lead, c_lead) = coeffs.last().expect("slot");
            fixed[lead] = false;
            ties.extend(
                coeffs
                    .iter()
                    .filter(|(i, _)| *i != lead)
                    .map(|&(i, c)| (i, lead, c / c_lead)),
            );
        }
        Tied { ties, fixed }
    }

    /// The 13 parameters with the tied ones following their carriers.
    fn expand(&self, k: &[f64; N_PARAMS]) -> [f64; N_PARAMS] {
        let mut out = *k;
        for &(i, lead, ratio) in &self.ties {
            out[i] = ratio * k[lead];
        }
        out
    }
}

impl Projection<N_PARAMS> for Tied {
    fn project(&self, k: &[f64; N_PARAMS], p_cam: &Vector3<f64>) -> Option<Vector2<f64>> {
        camera_from_params(&self.expand(k)).project(p_cam).ok()
    }

    fn project_with_jacobians(
        &self,
        k: &[f64; N_PARAMS],
        p_cam: &Vector3<f64>,
    ) -> Option<(Vector2<f64>, SMatrix<f64, 2, 3>, SMatrix<f64, 2, N_PARAMS>)> {
        if self.ties.is_empty() {
            return camera_from_params(k).project_with_jacobians(p_cam).ok();
        }
        let mut out = camera_from_params(&self.expand(k))
            .project_with_jacobians(p_cam)
            .ok();
        if let Some((_, _, j)) = out.as_mut() {
            // A carrier's column gathers its followers' (their columns are held fixed).
            for &(i, lead, ratio) in &self.ties {
                for r in 0..2 {
                    j[(r, lead)] += ratio * j[(r, i)];
                }
            }
        }
        out
    }
}

/// Runs Levenberg–Marquardt from an initial camera and poses.
pub fn refine(
    object: &[Vector3<f64>],
    views: &[&[Vector2<f64>]],
    camera: Camera,
    poses: Vec<Rigid3>,
    param: &Parametrization,
    settings: &LmSettings,
) -> Result<Solved, CalibrationError> {
    let n_obs: usize = 2 * views.iter().map(|v| v.len()).sum::<usize>();
    if n_obs <= param.len() + 6 * views.len() {
        return Err(CalibrationError::TooFewViews { got: views.len() });
    }
    let model = Tied::new(param);
    let mut start = camera.clone();
    param.set(&mut start, &param.get(&camera));
    let observations = views
        .iter()
        .enumerate()
        .flat_map(|(i, corners)| {
            corners.iter().enumerate().map(move |(j, uv)| Observation {
                camera: i,
                point: j,
                xy: [uv.x, uv.y],
            })
        })
        .collect();
    let mut problem = Problem::new(
        poses.iter().map(pose_params).collect(),
        vec![start.params()],
        vec![0; views.len()],
        object.iter().map(|x| (*x).into()).collect(),
        observations,
    );
    problem.fixed_points = vec![true; object.len()];
    problem.fixed_intrinsics = vec![model.fixed];
    let failed = |e: BaError| match e {
        BaError::Projection { image, .. } => CalibrationError::Optimisation(format!(
            "a board corner projects behind the camera in view {image} at the start"
        )),
        BaError::Singular => CalibrationError::Optimisation(
            "the intrinsics are not determined by these views (singular normal matrix); \
             add views with the board tilted in different directions"
                .into(),
        ),
        e => CalibrationError::Optimisation(e.to_string()),
    };
    let (summary, cov) = adjust_with_covariance(
        &mut problem,
        &model,
        &Priors::default(),
        &BaSettings::from_lm(settings),
        None,
    )
    .map_err(failed)?;

    let mut cam = camera;
    cam.set_params(&model.expand(&problem.intrinsics[0]));
    let cam_from_board: Vec<Rigid3> = problem.poses.iter().map(rigid_pose).collect();
    let mut residuals = Vec::with_capacity(views.len());
    for (corners, pose) in views.iter().zip(&cam_from_board) {
        let mut res = Vec::with_capacity(corners.len());
        for (x, o) in object.iter().zip(corners.iter()) {
            let uv = cam.project(&pose.apply(x)).map_err(|_| {
                CalibrationError::Optimisation("a board corner ends behind the camera".into())
            })?;
            res.push(uv - o);
        }
        residuals.push(res);
    }
    Ok(Solved {
        camera: cam,
        cam_from_board,
        residuals,
        cost: summary.final_cost,
        covariance: parameter_covariance(param, &cov.intrinsics(0)),
        sigma_px: cov.sigma_px,
        iterations: summary.iterations.len(),
        termination: summary.termination.into(),
    })
}

/// The covariance of the free quantities (each carried by its last parameter) mapped onto the
/// 13 parameters: `P C Pᵀ`, `P` the parametrization's matrix.
fn parameter_covariance(param: &Parametrization, engine: &DMatrix<f64>) -> ParamCovariance {
    let carriers: Vec<(usize, f64)> = param
        .slots
        .iter()
        .map(|(_, c)| *c.last().expect("slot"))
        .collect();
    // The carrier's value is its coefficient times the quantity's.
    let free = DMatrix::from_fn(carriers.len(), carriers.len(), |a, b| {
        engine[(carriers[a].0, carriers[b].0)] / (carriers[a].1 * carriers[b].1)
    });
    let p = param.matrix();
    let full = &p * free * p.transpose();
    ParamCovariance::from_iterator(full.iter().copied())
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::calibration::Options;

    /// The tied camera's Jacobian with respect to the engine's parameters (a fixed aspect ties
    /// fx to fy) agrees with central differences of its projection.
    #[test]
    fn tied_jacobians_match_finite_differences() {
        let cam = Camera::pinhole(800.0, 790.0, 330.0, 250.0)
            .with_distortion(&[-0.2, 0.05, 0.001, -0.002, 0.01, 0.02, -0.01, 0.003]);
        let p_cam = Vector3::new(0.1, -0.07, 0.6);
        for opts in [
            Options {
                rational: true,
                ..Options::default()
            },
            Options {
                fix_aspect: Some(1.02),
                zero_tangential: true,
                ..Options::default()
            },
        ] {
            let param = Parametrization::new(&opts).unwrap();
            let model = Tied::new(&param);
            let k = model.expand(&cam.params());
            let (_, _, j) = model.project_with_jacobians(&k, &p_cam).unwrap();
            for c in (0..N_PARAMS).filter(|&c| !model.fixed[c]) {
                let h = 1e-6 * (1.0 + k[c].abs());
                let (mut up, mut down) = (k, k);
                up[c] += h;
                down[c] -= h;
                let fd = (model.project(&up, &p_cam).unwrap()
                    - model.project(&down, &p_cam).unwrap())
                    / (2.0 * h);
                let err = (fd - j.column(c)).amax();
                assert!(err < 1e-5 * (1.0 + fd.amax()), "parameter {c}: {err}");
            }
        }
    }
}
