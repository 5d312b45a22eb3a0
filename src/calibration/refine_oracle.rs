//! The former hand-written calibration solver, kept as the test oracle of its bundle-adjuster
//! configuration until the two agree.
//!
//! Levenberg–Marquardt over the intrinsics, the distortion and every board pose.
//!
//! The normal equations have an arrow structure: a small dense block for the free intrinsics
//! (`U`), a 6x6 block per view (`V_i`) and their coupling (`W_i`). Each step eliminates the poses
//! with a Schur complement, `S = U − Σ W_i V_i⁻¹ W_iᵀ`, solves the small intrinsic system and
//! back-substitutes, so a step costs O(views) instead of O(views³). The covariance of the
//! intrinsics at the optimum is `σ² S⁻¹` with `σ²` the residual variance.

use nalgebra::{DMatrix, DVector, Matrix6, SMatrix, Vector2, Vector3, Vector6};

use super::{CalibrationError, Parametrization};
use crate::camera::{Camera, ParamCovariance};
use crate::geom::{Rigid3, skew};
use crate::optim::{Damping, LmSettings, Termination};

use super::refine::Solved;

/// Normal-equation blocks at one linearisation point.
struct Normal {
    u: DMatrix<f64>,
    g_theta: DVector<f64>,
    w: Vec<DMatrix<f64>>,
    v: Vec<Matrix6<f64>>,
    g_pose: Vec<Vector6<f64>>,
}

fn residuals_and_cost(
    cam: &Camera,
    object: &[Vector3<f64>],
    views: &[&[Vector2<f64>]],
    poses: &[Rigid3],
) -> Option<(Vec<Vec<Vector2<f64>>>, f64)> {
    let mut cost = 0.0;
    let mut all = Vec::with_capacity(views.len());
    for (obs, pose) in views.iter().zip(poses) {
        let mut res = Vec::with_capacity(obs.len());
        for (x, o) in object.iter().zip(obs.iter()) {
            let p = pose.apply(x);
            let r = cam.project(&p).ok()? - o;
            cost += 0.5 * r.norm_squared();
            res.push(r);
        }
        all.push(res);
    }
    Some((all, cost))
}

/// Residuals (2 per corner) of one view with their Jacobians with respect to the free intrinsics
/// and to the pose increment `(δθ, δt)` of [`Rigid3::plus`].
fn view_jacobians(
    cam: &Camera,
    pm: &DMatrix<f64>,
    object: &[Vector3<f64>],
    obs: &[Vector2<f64>],
    pose: &Rigid3,
) -> Option<(DVector<f64>, DMatrix<f64>, DMatrix<f64>)> {
    let m = 2 * obs.len();
    let mut jt = DMatrix::<f64>::zeros(m, pm.ncols());
    let mut jp = DMatrix::<f64>::zeros(m, 6);
    let mut r = DVector::<f64>::zeros(m);
    for (k, (x, o)) in object.iter().zip(obs.iter()).enumerate() {
        let p = pose.apply(x);
        let (uv, j_point, j_params) = cam.project_with_jacobians(&p).ok()?;
        let res = uv - o;
        r[2 * k] = res.x;
        r[2 * k + 1] = res.y;
        // Rigid3::plus: d(R x + t)/dδθ = −[R x + t]×.
        let j_rot = j_point * (-skew(&p));
        let mut j_pose = SMatrix::<f64, 2, 6>::zeros();
        j_pose.fixed_view_mut::<2, 3>(0, 0).copy_from(&j_rot);
        j_pose.fixed_view_mut::<2, 3>(0, 3).copy_from(&j_point);
        jp.fixed_view_mut::<2, 6>(2 * k, 0).copy_from(&j_pose);
        jt.rows_mut(2 * k, 2).copy_from(&(j_params * pm));
    }
    Some((r, jt, jp))
}

fn linearise(
    cam: &Camera,
    param: &Parametrization,
    object: &[Vector3<f64>],
    views: &[&[Vector2<f64>]],
    poses: &[Rigid3],
) -> Option<Normal> {
    let n = param.len();
    let pm = param.matrix();
    let mut normal = Normal {
        u: DMatrix::zeros(n, n),
        g_theta: DVector::zeros(n),
        w: Vec::with_capacity(views.len()),
        v: Vec::with_capacity(views.len()),
        g_pose: Vec::with_capacity(views.len()),
    };
    for (obs, pose) in views.iter().zip(poses) {
        let (r, jt, jp) = view_jacobians(cam, &pm, object, obs, pose)?;
        normal.u.gemm_tr(1.0, &jt, &jt, 1.0);
        normal.g_theta.gemv_tr(1.0, &jt, &r, 1.0);
        normal.w.push(jt.transpose() * &jp);
        let v = jp.transpose() * &jp;
        normal.v.push(Matrix6::from_iterator(v.iter().copied()));
        let g = jp.transpose() * &r;
        normal
            .g_pose
            .push(Vector6::from_iterator(g.iter().copied()));
    }
    Some(normal)
}

/// Solves the damped system by eliminating the poses; returns the intrinsic and pose steps.
fn solve_step(
    nm: &Normal,
    damping: &Damping,
    settings: &LmSettings,
) -> Option<(DVector<f64>, Vec<Vector6<f64>>, f64)> {
    let n = nm.u.nrows();
    let mut s = nm.u.clone();
    let mut dtheta_diag = DVector::zeros(n);
    for i in 0..n {
        let reg = damping.regularizer(nm.u[(i, i)], settings);
        s[(i, i)] += reg;
        dtheta_diag[i] = reg;
    }
    let mut rhs = -nm.g_theta.clone();
    let mut vinv = Vec::with_capacity(nm.v.len());
    let mut pose_diag = Vec::with_capacity(nm.v.len());
    for (i, v) in nm.v.iter().enumerate() {
        let mut vd = *v;
        let mut d = Vector6::zeros();
        for k in 0..6 {
            d[k] = damping.regularizer(v[(k, k)], settings);
            vd[(k, k)] += d[k];
        }
        let inv = vd.cholesky()?.inverse();
        let wv = &nm.w[i] * DMatrix::from_iterator(6, 6, inv.iter().copied());
        s -= &wv * nm.w[i].transpose();
        rhs += &wv * DVector::from_iterator(6, nm.g_pose[i].iter().copied());
        vinv.push(inv);
        pose_diag.push(d);
    }
    let dtheta = match s.clone().cholesky() {
        Some(ch) => ch.solve(&rhs),
        None => s.lu().solve(&rhs)?,
    };
    let mut dposes = Vec::with_capacity(nm.v.len());
    // Model decrease ½(μ δᵀDδ − gᵀδ), accumulated over all blocks.
    let mut pred = dtheta.dot(&dtheta_diag.component_mul(&dtheta)) - nm.g_theta.dot(&dtheta);
    for i in 0..nm.v.len() {
        let wt_dtheta = nm.w[i].transpose() * &dtheta;
        let b = -nm.g_pose[i] - Vector6::from_iterator(wt_dtheta.iter().copied());
        let dp = vinv[i] * b;
        pred += dp.dot(&pose_diag[i].component_mul(&dp)) - nm.g_pose[i].dot(&dp);
        dposes.push(dp);
    }
    Some((dtheta, dposes, 0.5 * pred))
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
    let mut cam = camera;
    let mut theta = param.get(&cam);
    param.set(&mut cam, &theta);
    let mut poses = poses;
    let (_, mut cost) = residuals_and_cost(&cam, object, views, &poses).ok_or_else(|| {
        CalibrationError::Optimisation(
            "a board corner projects behind the camera at the start".into(),
        )
    })?;
    let mut damping = Damping::new(settings);
    let mut termination = Termination::MaxIterations;
    let mut iterations = 0;
    let mut normal = linearise(&cam, param, object, views, &poses)
        .ok_or_else(|| CalibrationError::Optimisation("cannot linearise at the start".into()))?;

    while iterations < settings.max_iterations {
        let gmax = normal
            .g_theta
            .amax()
            .max(normal.g_pose.iter().map(|g| g.amax()).fold(0.0, f64::max));
        if gmax <= settings.gradient_tolerance {
            termination = Termination::GradientTolerance;
            break;
        }
        if damping.exhausted() {
            termination = Termination::NoFurtherProgress;
            break;
        }
        iterations += 1;
        let Some((dtheta, dposes, pred)) = solve_step(&normal, &damping, settings) else {
            damping.update(f64::NAN, settings);
            continue;
        };
        let step_norm =
            (dtheta.norm_squared() + dposes.iter().map(|d| d.norm_squared()).sum::<f64>()).sqrt();
        let x_norm = (theta.iter().map(|t| t * t).sum::<f64>()
            + poses
                .iter()
                .map(|p| p.translation.norm_squared() + p.rotation.scaled_axis().norm_squared())
                .sum::<f64>())
        .sqrt();
        if step_norm <= settings.parameter_tolerance * (x_norm + settings.parameter_tolerance) {
            termination = Termination::ParameterTolerance;
            break;
        }
        let new_theta: Vec<f64> = theta
            .iter()
            .zip(dtheta.iter())
            .map(|(t, d)| t + d)
            .collect();
        let mut new_cam = cam.clone();
        param.set(&mut new_cam, &new_theta);
        let new_poses: Vec<Rigid3> = poses
            .iter()
            .zip(&dposes)
            .map(|(p, d)| p.plus(&Vector6::from_column_slice(d.as_slice())))
            .collect();
        let new_cost = residuals_and_cost(&new_cam, object, views, &new_poses).map(|(_, c)| c);
        let rho = match new_cost {
            Some(c) if pred > 0.0 => (cost - c) / pred,
            _ => f64::NAN,
        };
        if damping.update(rho, settings) {
            let new_cost = new_cost.expect("accepted steps have a cost");
            let decrease = cost - new_cost;
            theta = new_theta;
            cam = new_cam;
            poses = new_poses;
            cost = new_cost;
            normal = linearise(&cam, param, object, views, &poses)
                .ok_or_else(|| CalibrationError::Optimisation("cannot linearise".into()))?;
            if decrease <= settings.function_tolerance * cost {
                termination = Termination::FunctionTolerance;
                break;
            }
        }
    }

    let (residuals, cost) = residuals_and_cost(&cam, object, views, &poses).ok_or_else(|| {
        CalibrationError::Optimisation("a board corner ends behind the camera".into())
    })?;
    let (covariance, sigma_px) = covariance(&normal, param, cost, views)?;
    Ok(Solved {
        camera: cam,
        cam_from_board: poses,
        residuals,
        cost,
        covariance,
        sigma_px,
        iterations,
        termination,
    })
}

/// `σ² (U − Σ W V⁻¹ Wᵀ)⁻¹`, mapped onto the 13 parameters.
fn covariance(
    nm: &Normal,
    param: &Parametrization,
    cost: f64,
    views: &[&[Vector2<f64>]],
) -> Result<(ParamCovariance, f64), CalibrationError> {
    let n_obs: usize = 2 * views.iter().map(|v| v.len()).sum::<usize>();
    let n_unknowns = param.len() + 6 * views.len();
    if n_obs <= n_unknowns {
        return Err(CalibrationError::TooFewViews { got: views.len() });
    }
    let sigma2 = 2.0 * cost / (n_obs - n_unknowns) as f64;
    let mut s = nm.u.clone();
    for (i, v) in nm.v.iter().enumerate() {
        let inv = v
            .cholesky()
            .ok_or_else(|| {
                CalibrationError::Optimisation(format!("the pose of view {i} is undetermined"))
            })?
            .inverse();
        let inv = DMatrix::from_iterator(6, 6, inv.iter().copied());
        s -= &nm.w[i] * inv * nm.w[i].transpose();
    }
    let s_inv = s
        .clone()
        .cholesky()
        .map(|c| c.inverse())
        .or_else(|| s.try_inverse())
        .ok_or_else(|| {
            CalibrationError::Optimisation(
                "the intrinsics are not determined by these views (singular normal matrix); \
                 add views with the board tilted in different directions"
                    .into(),
            )
        })?;
    let p = param.matrix();
    let full = &p * (s_inv * sigma2) * p.transpose();
    Ok((
        ParamCovariance::from_iterator(full.iter().copied()),
        sigma2.sqrt(),
    ))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::calibration::{Options, board_points};
    use crate::camera::BoardSpec;

    /// The calibration Jacobians (intrinsics through the parametrization, and the pose
    /// increment) agree with central differences of the residuals.
    #[test]
    fn view_jacobians_match_finite_differences() {
        let board = BoardSpec {
            cols: 4,
            rows: 3,
            square_m: 0.05,
        };
        let object = board_points(&board);
        let cam = Camera::pinhole(800.0, 790.0, 330.0, 250.0)
            .with_distortion(&[-0.2, 0.05, 0.001, -0.002, 0.01, 0.02, -0.01, 0.003])
            .with_image_size(640, 480);
        let pose = Rigid3::from_rvec_tvec(
            &Vector3::new(0.3, -0.2, 0.1),
            &Vector3::new(-0.1, -0.05, 0.6),
        );
        let obs: Vec<Vector2<f64>> = object.iter().map(|_| Vector2::new(300.0, 200.0)).collect();
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
            let pm = param.matrix();
            let mut base = cam.clone();
            let theta = param.get(&base);
            param.set(&mut base, &theta);
            let (_, jt, jp) = view_jacobians(&base, &pm, &object, &obs, &pose).unwrap();
            let resid =
                |c: &Camera, p: &Rigid3| view_jacobians(c, &pm, &object, &obs, p).unwrap().0;
            for k in 0..theta.len() {
                let h = 1e-6 * (1.0 + theta[k].abs());
                let (mut a, mut b) = (base.clone(), base.clone());
                let (mut ta, mut tb) = (theta.clone(), theta.clone());
                ta[k] += h;
                tb[k] -= h;
                param.set(&mut a, &ta);
                param.set(&mut b, &tb);
                let fd = (resid(&a, &pose) - resid(&b, &pose)) / (2.0 * h);
                let err = (&fd - jt.column(k)).amax();
                assert!(
                    err < 1e-5 * (1.0 + fd.amax()),
                    "{}: {err}",
                    param.names()[k]
                );
            }
            for k in 0..6 {
                let h = 1e-7;
                let mut d = Vector6::zeros();
                d[k] = h;
                let step = |d: &Vector6<f64>| pose.plus(d);
                let fd = (resid(&base, &step(&d)) - resid(&base, &step(&-d))) / (2.0 * h);
                let err = (&fd - jp.column(k)).amax();
                assert!(err < 1e-4 * (1.0 + fd.amax()), "pose {k}: {err}");
            }
        }
    }
}
