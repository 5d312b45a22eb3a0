//! Levenberg–Marquardt refinement of one camera pose on the full camera model (distortion
//! included), with per-point 2×2 weights and an optional robust loss, and the pose covariance.
//!
//! The increment is `p_cam ← exp(δθ) p_cam + δt`: a rotation about the camera centre, then a
//! shift in the camera frame, so `∂C/∂δθ = 0` and `∂C/∂δt = −Rᵀ` for the centre `C = −Rᵀt`.

use nalgebra::{Matrix2, Matrix2x3, Matrix2x6, Matrix3, Matrix6, Vector2, Vector3, Vector6};

use super::PoseError;
use crate::camera::Camera;
use crate::geom::Rigid3;
use crate::geom::skew;
use crate::optim::{Damping, LmSettings, RobustLoss, Termination};

/// One 3D–2D correspondence with the inverse covariance (information) of its pixel residual.
#[derive(Clone, Debug)]
pub struct PointObs {
    pub world: Vector3<f64>,
    pub uv: Vector2<f64>,
    pub info: Matrix2<f64>,
}

/// A refined pose.
#[derive(Clone, Debug)]
pub struct RefinedPose {
    pub cam_from_world: Rigid3,
    /// Covariance of the increment `(δθ, δt)` of [`Rigid3::plus`] (radians, metres).
    pub covariance: Matrix6<f64>,
    /// `Σ |rᵢ|²` of the whitened residuals (χ² when the weights are right).
    pub chi2: f64,
    pub iterations: usize,
    pub termination: Termination,
}

/// Pixel and its Jacobian with respect to [`Rigid3::plus`]'s `(δθ, δt)`; also `∂uv/∂X_world`.
pub fn project_pose(
    camera: &Camera,
    pose: &Rigid3,
    world: &Vector3<f64>,
) -> Option<(Vector2<f64>, Matrix2x6<f64>, Matrix2x3<f64>)> {
    let p = pose.apply(world);
    let (uv, j_point, _) = camera.project_with_jacobians(&p).ok()?;
    let mut j = Matrix2x6::zeros();
    j.fixed_view_mut::<2, 3>(0, 0)
        .copy_from(&(j_point * -skew(&p)));
    j.fixed_view_mut::<2, 3>(0, 3).copy_from(&j_point);
    Some((uv, j, j_point * pose.rotation.matrix()))
}

/// The upper Cholesky-like factor `U` with `UᵀU = info`, to whiten residuals.
pub fn whitener(info: &Matrix2<f64>) -> Matrix2<f64> {
    match info.cholesky() {
        Some(c) => c.l().transpose(),
        None => Matrix2::zeros(),
    }
}

struct Eval {
    cost: f64,
    chi2: f64,
    jtj: Matrix6<f64>,
    jtr: Vector6<f64>,
}

fn evaluate(
    camera: &Camera,
    pose: &Rigid3,
    obs: &[PointObs],
    white: &[Matrix2<f64>],
    loss: RobustLoss,
) -> Result<Eval, usize> {
    let mut e = Eval {
        cost: 0.0,
        chi2: 0.0,
        jtj: Matrix6::zeros(),
        jtr: Vector6::zeros(),
    };
    for (i, (o, u)) in obs.iter().zip(white).enumerate() {
        let (uv, j, _) = project_pose(camera, pose, &o.world).ok_or(i)?;
        let r = u * (uv - o.uv);
        let jw = u * j;
        let s = r.norm_squared();
        let w = loss.weight(s);
        e.cost += loss.rho(s);
        e.chi2 += s;
        e.jtj += jw.transpose() * jw * w;
        e.jtr += jw.transpose() * r * w;
    }
    Ok(e)
}

/// Refines `start` on `obs`. Fails when a point is behind the camera at the start, or the
/// normal equations are singular (fewer than three well-spread points).
pub fn refine_pose(
    camera: &Camera,
    start: &Rigid3,
    obs: &[PointObs],
    loss: RobustLoss,
    settings: &LmSettings,
) -> Result<RefinedPose, PoseError> {
    let white: Vec<Matrix2<f64>> = obs.iter().map(|o| whitener(&o.info)).collect();
    let mut pose = *start;
    let mut cur = evaluate(camera, &pose, obs, &white, loss)
        .map_err(|i| PoseError::BehindCamera { points: vec![i] })?;
    let mut damping = Damping::new(settings);
    let mut termination = Termination::MaxIterations;
    let mut iterations = 0;
    while iterations < settings.max_iterations {
        iterations += 1;
        if cur.jtr.amax() <= settings.gradient_tolerance {
            termination = Termination::GradientTolerance;
            break;
        }
        let mut a = cur.jtj;
        for k in 0..6 {
            a[(k, k)] += damping.regularizer(cur.jtj[(k, k)], settings);
        }
        let Some(chol) = a.cholesky() else {
            damping.update(f64::NAN, settings);
            if damping.exhausted() {
                termination = Termination::NoFurtherProgress;
                break;
            }
            continue;
        };
        let delta = -chol.solve(&cur.jtr);
        let predicted = -(delta.dot(&cur.jtr) * 2.0 + delta.dot(&(cur.jtj * delta)));
        let cand = pose.plus(&delta);
        let next = evaluate(camera, &cand, obs, &white, loss);
        let rho = match &next {
            Ok(n) if predicted > 0.0 => (cur.cost - n.cost) / predicted,
            _ => f64::NAN,
        };
        if damping.update(rho, settings) {
            let next = next.expect("accepted step was evaluated");
            let rel = (cur.cost - next.cost).abs() / cur.cost.max(1e-300);
            pose = cand;
            cur = next;
            if rel <= settings.function_tolerance {
                termination = Termination::FunctionTolerance;
                break;
            }
            if delta.norm()
                <= settings.parameter_tolerance
                    * (pose.translation.norm() + settings.parameter_tolerance)
            {
                termination = Termination::ParameterTolerance;
                break;
            }
        } else if damping.exhausted() {
            termination = Termination::NoFurtherProgress;
            break;
        }
    }
    let covariance = cur
        .jtj
        .try_inverse()
        .filter(|c| c.iter().all(|x| x.is_finite()))
        .ok_or_else(|| {
            PoseError::Degenerate(
                "the points do not determine the pose (the normal matrix is singular)".into(),
            )
        })?;
    Ok(RefinedPose {
        cam_from_world: pose,
        covariance,
        chi2: cur.chi2,
        iterations,
        termination,
    })
}

/// Covariance of `(δφ_world, C)`: the rotation error about the world axes (radians) and the
/// camera centre (metres), from the covariance of the increment `(δθ, δt)`.
pub fn world_covariance(pose: &Rigid3, cov: &Matrix6<f64>) -> Matrix6<f64> {
    // R' = exp(δθ) R, so Rᵀ' = exp(−Rᵀδθ) Rᵀ: δφ_world = −Rᵀ δθ; C' = C − Rᵀ δt.
    let rt: Matrix3<f64> = pose.rotation.matrix().transpose();
    let mut j = Matrix6::zeros();
    j.fixed_view_mut::<3, 3>(0, 0).copy_from(&(-rt));
    j.fixed_view_mut::<3, 3>(3, 3).copy_from(&(-rt));
    j * cov * j.transpose()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn pose_jacobian_matches_finite_differences() {
        let camera = Camera::pinhole(1400.0, 1390.0, 960.0, 540.0)
            .with_distortion(&[-0.1, 0.05, 0.001, -0.002, 0.01]);
        let pose = Rigid3 {
            rotation: nalgebra::Rotation3::from_scaled_axis(Vector3::new(3.1, 0.05, 0.3)),
            translation: Vector3::new(0.4, -0.2, 30.0),
        };
        let x = Vector3::new(5.0, -3.0, 0.4);
        let (_, j, jx) = project_pose(&camera, &pose, &x).unwrap();
        for k in 0..6 {
            let mut d = Vector6::zeros();
            d[k] = 1e-6;
            let up = project_pose(&camera, &pose.plus(&d), &x).unwrap().0;
            d[k] = -1e-6;
            let um = project_pose(&camera, &pose.plus(&d), &x).unwrap().0;
            let fd = (up - um) / 2e-6;
            assert!(
                (fd - j.column(k)).norm() < 1e-4 * (1.0 + fd.norm()),
                "column {k}: {fd} vs {}",
                j.column(k)
            );
        }
        for k in 0..3 {
            let mut dx = Vector3::zeros();
            dx[k] = 1e-5;
            let fd = (project_pose(&camera, &pose, &(x + dx)).unwrap().0
                - project_pose(&camera, &pose, &(x - dx)).unwrap().0)
                / 2e-5;
            assert!((fd - jx.column(k)).norm() < 1e-5 * (1.0 + fd.norm()));
        }
        // The centre does not move under δθ, and moves by −Rᵀδt.
        let d = Vector6::new(0.01, -0.02, 0.03, 0.0, 0.0, 0.0);
        assert!((pose.plus(&d).centre() - pose.centre()).norm() < 1e-12);
        let dt = Vector6::new(0.0, 0.0, 0.0, 1e-3, 2e-3, -1e-3);
        let expect = pose.centre() - pose.rotation.inverse() * Vector3::new(1e-3, 2e-3, -1e-3);
        assert!((pose.plus(&dt).centre() - expect).norm() < 1e-9);
    }
}
