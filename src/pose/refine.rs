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

use crate::geom::so3::left_jacobian;
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
        let jl = left_jacobian(&Vector3::new(self.x[0], self.x[1], self.x[2]));
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

    /// The crate's problem: its Jacobian is the derivative of its scaled residuals away from
    /// the base pose, in and beyond the robust loss's quadratic part.
    #[test]
    fn scaled_residual_jacobian_matches_finite_differences() {
        let camera = Camera::pinhole(1400.0, 1390.0, 960.0, 540.0)
            .with_distortion(&[-0.1, 0.05, 0.001, -0.002, 0.01]);
        let base = Rigid3 {
            rotation: nalgebra::Rotation3::from_scaled_axis(Vector3::new(3.1, 0.05, 0.3)),
            translation: Vector3::new(0.4, -0.2, 30.0),
        };
        let obs: Vec<PointObs> = (0..6)
            .map(|k| {
                let world = Vector3::new(f64::from(k) * 2.0 - 5.0, f64::from(k % 3) - 1.0, 0.2);
                let uv = camera.project(&base.apply(&world)).unwrap();
                PointObs {
                    world,
                    // Residuals from a fraction of a pixel to far beyond the loss's scale.
                    uv: uv + Vector2::new(0.3, -0.2) * f64::from(k * k),
                    info: Matrix2::new(1.2, 0.3, 0.3, 0.8),
                }
            })
            .collect();
        let white: Vec<Matrix2<f64>> = obs.iter().map(|o| whitener(&o.info)).collect();
        for loss in [
            RobustLoss::Squared,
            RobustLoss::Huber(2.0),
            RobustLoss::Cauchy(2.0),
        ] {
            let mut p = PoseProblem {
                camera: &camera,
                base,
                x: Vector6::new(0.02, -0.01, 0.03, 0.1, -0.2, 0.3),
                obs: &obs,
                white: &white,
                loss,
            };
            let j = p.jacobian().unwrap();
            let x0 = p.x;
            for k in 0..6 {
                let h = 1e-6;
                p.x = x0;
                p.x[k] += h;
                let up = p.residuals().unwrap();
                p.x[k] -= 2.0 * h;
                let down = p.residuals().unwrap();
                let fd = (up - down) / (2.0 * h);
                assert!(
                    (&fd - j.column(k)).norm() < 1e-5 * (1.0 + fd.norm()),
                    "{loss:?}, column {k}: {fd} vs {}",
                    j.column(k)
                );
            }
        }
    }
}
