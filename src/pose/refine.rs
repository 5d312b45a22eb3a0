//! Levenberg–Marquardt refinement of one camera pose on the full camera model (distortion
//! included), with per-point 2×2 weights and an optional robust loss, and the pose covariance.
//!
//! The increment is `p_cam ← exp(δθ) p_cam + δt`: a rotation about the camera centre, then a
//! shift in the camera frame, so `∂C/∂δθ = 0` and `∂C/∂δt = −Rᵀ` for the centre `C = −Rᵀt`.

use nalgebra::{Matrix2, Matrix2x3, Matrix2x6, Matrix3, Matrix6, Vector2, Vector3, Vector6};

use super::PoseError;
use crate::camera::Camera;
use levenberg_marquardt::{LeastSquaresProblem, LevenbergMarquardt, TerminationReason};
use nalgebra::{DVector, Dyn, OMatrix, Owned, U6};

use crate::geom::rigid::so3_left_jacobian;
use crate::geom::{Rigid3, skew};
use crate::optim::{LmSettings, RobustLoss, Termination};

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

/// The pose problem for the `levenberg-marquardt` crate. The parameters are the increment
/// `x = (δθ, δt)` of [`Rigid3::plus`] from `base`; the residuals are the whitened pixel errors
/// `r` scaled by `√(ρ(s)/s)`, `s = |r|²`, so that their squares are the robust loss and the
/// crate minimises `½Σρ(sᵢ)` itself (it has no robust loss of its own).
struct PoseProblem<'a> {
    camera: &'a Camera,
    base: Rigid3,
    x: Vector6<f64>,
    obs: &'a [PointObs],
    white: &'a [Matrix2<f64>],
    loss: RobustLoss,
}

/// A pixel error so large that any step reaching it is refused: what a point behind the camera
/// gives (the crate would otherwise stop at that trial step).
const REFUSED: f64 = 1e30;

impl PoseProblem<'_> {
    fn pose(&self) -> Rigid3 {
        self.base.plus(&self.x)
    }
}

/// `g(s) = √(ρ(s)/s)` and `g'(s)`: the scaling that turns a residual of squared norm `s` into
/// one whose square is `ρ(s)`.
fn loss_scale(loss: RobustLoss, s: f64) -> (f64, f64) {
    if s <= f64::MIN_POSITIVE {
        return (1.0, 0.0);
    }
    let rho = loss.rho(s);
    let g = (rho / s).sqrt();
    (g, (loss.weight(s) * s - rho) / (2.0 * s * s * g))
}

impl LeastSquaresProblem<f64, Dyn, U6> for PoseProblem<'_> {
    type ResidualStorage = Owned<f64, Dyn>;
    type JacobianStorage = Owned<f64, Dyn, U6>;
    type ParameterStorage = Owned<f64, U6>;

    fn set_params(&mut self, x: &Vector6<f64>) {
        self.x = *x;
    }

    fn params(&self) -> Vector6<f64> {
        self.x
    }

    fn residuals(&self) -> Option<DVector<f64>> {
        let pose = self.pose();
        let mut out = DVector::zeros(2 * self.obs.len());
        for (i, (o, u)) in self.obs.iter().zip(self.white).enumerate() {
            let r = match self.camera.project(&pose.apply(&o.world)) {
                Ok(uv) => {
                    let r = u * (uv - o.uv);
                    r * loss_scale(self.loss, r.norm_squared()).0
                }
                Err(_) => Vector2::repeat(REFUSED),
            };
            out.fixed_rows_mut::<2>(2 * i).copy_from(&r);
        }
        Some(out)
    }

    fn jacobian(&self) -> Option<OMatrix<f64, Dyn, U6>> {
        let pose = self.pose();
        let dt = Vector3::new(self.x[3], self.x[4], self.x[5]);
        // p = exp(θ)·p₀ + δt, and exp(θ + ε) ≈ exp(J_l(θ)·ε)·exp(θ): ∂p/∂θ = −[p − δt]×·J_l(θ).
        let jl = so3_left_jacobian(&Vector3::new(self.x[0], self.x[1], self.x[2]));
        let mut out = OMatrix::<f64, Dyn, U6>::zeros(2 * self.obs.len());
        for (i, (o, u)) in self.obs.iter().zip(self.white).enumerate() {
            let p = pose.apply(&o.world);
            let (uv, j_point, _) = self.camera.project_with_jacobians(&p).ok()?;
            let mut j = Matrix2x6::zeros();
            j.fixed_view_mut::<2, 3>(0, 0)
                .copy_from(&(j_point * -skew(&(p - dt)) * jl));
            j.fixed_view_mut::<2, 3>(0, 3).copy_from(&j_point);
            let r = u * (uv - o.uv);
            let jr = u * j;
            let (g, dg) = loss_scale(self.loss, r.norm_squared());
            let jw = jr * g + r * (r.transpose() * jr) * (2.0 * dg);
            out.fixed_rows_mut::<2>(2 * i).copy_from(&jw);
        }
        Some(out)
    }
}

/// Refines `start` on `obs` with the `levenberg-marquardt` crate (a small dense problem). Fails
/// when a point is behind the camera at the start, or the normal equations are singular (fewer
/// than three well-spread points).
pub fn refine_pose(
    camera: &Camera,
    start: &Rigid3,
    obs: &[PointObs],
    loss: RobustLoss,
    settings: &LmSettings,
) -> Result<RefinedPose, PoseError> {
    let white: Vec<Matrix2<f64>> = obs.iter().map(|o| whitener(&o.info)).collect();
    evaluate(camera, start, obs, &white, loss)
        .map_err(|i| PoseError::BehindCamera { points: vec![i] })?;
    let problem = PoseProblem {
        camera,
        base: *start,
        x: Vector6::zeros(),
        obs,
        white: &white,
        loss,
    };
    // The crate counts evaluations, `patience · (parameters + 1)` at most.
    let (solved, report) = LevenbergMarquardt::new()
        .with_ftol(settings.function_tolerance.max(1e-10))
        .with_xtol(settings.parameter_tolerance.max(1e-10))
        .with_gtol(0.0)
        .with_patience(settings.max_iterations.div_ceil(7).max(1))
        .minimize(problem);
    let termination = match report.termination {
        TerminationReason::Converged { ftol: true, .. } | TerminationReason::ResidualsZero => {
            Termination::FunctionTolerance
        }
        TerminationReason::Converged { .. } => Termination::ParameterTolerance,
        TerminationReason::Orthogonal => Termination::GradientTolerance,
        TerminationReason::NoImprovementPossible(_) => Termination::NoFurtherProgress,
        TerminationReason::LostPatience => Termination::MaxIterations,
        other => {
            return Err(PoseError::Degenerate(format!(
                "the pose refinement failed: {other:?}"
            )));
        }
    };
    let pose = solved.pose();
    // The covariance and χ² at the solution, from the reweighted normal equations.
    let cur = evaluate(camera, &pose, obs, &white, loss).map_err(|_| {
        PoseError::Degenerate("a point went behind the camera during refinement".into())
    })?;
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
        iterations: report.number_of_evaluations,
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
    use crate::optim::Damping;
    use nalgebra::Rotation3;

/// The former hand-written solver, kept as the test oracle until the crate's agrees.
    /// Refines `start` on `obs`. Fails when a point is behind the camera at the start, or the
    /// normal equations are singular (fewer than three well-spread points).
    pub fn refine_pose_former(
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

    /// The crate's solution is the former solver's: the same optimum, covariance and χ², with
    /// every loss, outliers, anisotropic weights and a distorted camera.
    #[test]
    fn agrees_with_the_former_solver() {
        let camera = Camera::pinhole(1400.0, 1390.0, 960.0, 540.0)
            .with_distortion(&[-0.1, 0.05, 0.001, -0.002, 0.01]);
        let mut state = 7u64;
        let mut rand = move || {
            state = state
                .wrapping_mul(6_364_136_223_846_793_005)
                .wrapping_add(1_442_695_040_888_963_407);
            ((state >> 11) as f64 / (1u64 << 53) as f64) * 2.0 - 1.0
        };
        for case in 0..12 {
            let truth = Rigid3 {
                rotation: nalgebra::Rotation3::from_scaled_axis(Vector3::new(
                    3.1 + 0.05 * rand(),
                    0.1 * rand(),
                    0.5 * rand(),
                )),
                translation: Vector3::new(rand(), rand(), 30.0 + 3.0 * rand()),
            };
            let mut obs = Vec::new();
            for k in 0..(6 + case) {
                let world = Vector3::new(15.0 * rand(), 8.0 * rand(), 0.5 * rand());
                let Ok(uv) = camera.project(&truth.apply(&world)) else {
                    continue;
                };
                let a = 0.5 + rand().abs();
                let info = Matrix2::new(1.0 / a, 0.2 * rand(), 0.0, 1.0 / (a * 1.5));
                let info = (info + info.transpose()) * 0.5 + Matrix2::identity() * 0.5;
                let outlier = k == 2 && case % 3 == 0;
                let noise = if outlier { 25.0 } else { 0.7 };
                obs.push(PointObs {
                    world,
                    uv: uv + Vector2::new(rand(), rand()) * noise,
                    info,
                });
            }
            let start = truth.plus(&Vector6::new(
                0.01 * rand(),
                0.01 * rand(),
                0.01 * rand(),
                0.3 * rand(),
                0.3 * rand(),
                0.5 * rand(),
            ));
            let loss = [
                RobustLoss::Squared,
                RobustLoss::Huber(2.0),
                RobustLoss::Cauchy(2.0),
            ][case % 3];
            let lm = LmSettings::default();
            let new = refine_pose(&camera, &start, &obs, loss, &lm).unwrap();
            let old = refine_pose_former(&camera, &start, &obs, loss, &lm).unwrap();
            // The difference as an increment of the former solution, in its standard
            // deviations: both stop where the cost no longer falls by 1e-12 of itself.
            let (a, b) = (&old.cam_from_world, &new.cam_from_world);
            let d_rot = (b.rotation * a.rotation.inverse()).scaled_axis();
            let d_t = b.translation - Rotation3::from_scaled_axis(d_rot) * a.translation;
            let d = Vector6::new(d_rot.x, d_rot.y, d_rot.z, d_t.x, d_t.y, d_t.z);
            let sigmas = (d.transpose() * old.covariance.try_inverse().unwrap() * d)[0]
                .max(0.0)
                .sqrt();
            let d_cov = (new.covariance - old.covariance).norm() / old.covariance.norm();
            let d_chi2 = (new.chi2 - old.chi2).abs() / old.chi2;
            assert!(
                sigmas < 1e-3 && d_cov < 1e-4 && d_chi2 < 1e-6,
                "case {case} ({loss:?}): {sigmas:e} σ apart, covariance {d_cov:e}, \
                 chi2 {d_chi2:e}; {} vs {} evaluations",
                new.iterations,
                old.iterations
            );
            assert!(new.termination.converged(), "{:?}", new.termination);
            eprintln!("case {case} ({loss:?}): {sigmas:.1e} σ, covariance {d_cov:.1e}, chi2 {d_chi2:.1e}; {} vs {} evaluations", new.iterations, old.iterations);
        }
    }
}
