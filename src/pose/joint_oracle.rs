//! The former hand-written solver of the joint refinement, kept as the test oracle of its
//! bundle-adjuster configuration until the two agree.
//!
//! Joint refinement of several poses of one camera and the GCP positions they see, the GCPs
//! held to their survey by priors (a small bundle adjustment with known intrinsics).
//!
//! Levenberg–Marquardt on the normal equations, with the poses eliminated (each pose touches
//! only its own observations): the reduced system is over the GCPs, which are few.

use nalgebra::{DMatrix, DVector, Matrix2, Matrix3, Matrix6, Matrix6x3, Vector3, Vector6};

use super::PoseError;
use super::joint::{JointObs, JointResult};
use super::refine::{project_pose, whitener};
use crate::camera::Camera;
use crate::geom::Rigid3;
use crate::optim::{Damping, LmSettings, RobustLoss, Termination};

/// Increments of the poses and of the points.
type Steps = (Vec<Vector6<f64>>, Vec<Vector3<f64>>);

struct System {
    cost: f64,
    chi2: f64,
    u: Vec<Matrix6<f64>>,
    w: Vec<Vec<(usize, Matrix6x3<f64>)>>,
    v: Vec<Matrix3<f64>>,
    bp: Vec<Vector6<f64>>,
    bx: Vec<Vector3<f64>>,
}

struct Problem<'a> {
    camera: &'a Camera,
    prior: &'a [Vector3<f64>],
    prior_white: Vec<Matrix3<f64>>,
    obs: &'a [JointObs],
    loss: RobustLoss,
    n_poses: usize,
}

impl Problem<'_> {
    fn build(&self, poses: &[Rigid3], points: &[Vector3<f64>]) -> Option<System> {
        let np = points.len();
        let mut s = System {
            cost: 0.0,
            chi2: 0.0,
            u: vec![Matrix6::zeros(); self.n_poses],
            w: vec![Vec::new(); self.n_poses],
            v: vec![Matrix3::zeros(); np],
            bp: vec![Vector6::zeros(); self.n_poses],
            bx: vec![Vector3::zeros(); np],
        };
        for o in self.obs {
            let (uv, jp, jx) = project_pose(self.camera, &poses[o.pose], &points[o.point])?;
            let white = whitener(&(Matrix2::identity() / (o.sigma_px * o.sigma_px)));
            let r = white * (uv - o.uv);
            let (jp, jx) = (white * jp, white * jx);
            let sq = r.norm_squared();
            let wt = self.loss.weight(sq);
            s.cost += self.loss.rho(sq);
            s.chi2 += sq;
            s.u[o.pose] += jp.transpose() * jp * wt;
            s.v[o.point] += jx.transpose() * jx * wt;
            s.bp[o.pose] += jp.transpose() * r * wt;
            s.bx[o.point] += jx.transpose() * r * wt;
            let wkj = jp.transpose() * jx * wt;
            match s.w[o.pose].iter_mut().find(|(j, _)| *j == o.point) {
                Some((_, m)) => *m += wkj,
                None => s.w[o.pose].push((o.point, wkj)),
            }
        }
        // Priors: the surveyed positions with their covariance.
        for (j, (x, (x0, white))) in points
            .iter()
            .zip(self.prior.iter().zip(&self.prior_white))
            .enumerate()
        {
            let r = white * (x - x0);
            s.cost += r.norm_squared();
            s.chi2 += r.norm_squared();
            s.v[j] += white.transpose() * white;
            s.bx[j] += white.transpose() * r;
        }
        Some(s)
    }

    /// Solves the damped system; returns pose and point increments.
    fn solve(&self, s: &System, damping: &Damping, lm: &LmSettings) -> Option<Steps> {
        let np = s.v.len();
        let mut u_inv = Vec::with_capacity(self.n_poses);
        for u in &s.u {
            let mut a = *u;
            for k in 0..6 {
                a[(k, k)] += damping.regularizer(u[(k, k)], lm);
            }
            u_inv.push(a.try_inverse()?);
        }
        // Reduced system over the points: S = V − Σ Wᵀ U⁻¹ W, rhs = −bx + Σ Wᵀ U⁻¹ bp.
        let mut sm = DMatrix::<f64>::zeros(3 * np, 3 * np);
        let mut rhs = DVector::<f64>::zeros(3 * np);
        for j in 0..np {
            let mut v = s.v[j];
            for k in 0..3 {
                v[(k, k)] += damping.regularizer(s.v[j][(k, k)], lm);
            }
            sm.fixed_view_mut::<3, 3>(3 * j, 3 * j).copy_from(&v);
            rhs.fixed_rows_mut::<3>(3 * j).copy_from(&(-s.bx[j]));
        }
        for ((ui, wk), bp) in u_inv.iter().zip(&s.w).zip(&s.bp) {
            for &(a, wa) in wk {
                let wt_ui = wa.transpose() * ui;
                let mut r = rhs.fixed_rows_mut::<3>(3 * a);
                r += wt_ui * bp;
                for &(b, wb) in wk {
                    let mut blk = sm.fixed_view_mut::<3, 3>(3 * a, 3 * b);
                    blk -= wt_ui * wb;
                }
            }
        }
        let dx = sm.cholesky()?.solve(&rhs);
        let dxs: Vec<Vector3<f64>> = (0..np).map(|j| dx.fixed_rows::<3>(3 * j).into()).collect();
        let dps = (0..self.n_poses)
            .map(|k| {
                let mut b = -s.bp[k];
                for &(j, w) in &s.w[k] {
                    b -= w * dxs[j];
                }
                u_inv[k] * b
            })
            .collect();
        Some((dps, dxs))
    }
}

/// Refines `poses` and `points` on `obs`, with `points` held to `prior` by `prior_cov`.
pub fn refine_jointly(
    camera: &Camera,
    poses: &[Rigid3],
    prior: &[Vector3<f64>],
    prior_cov: &[Matrix3<f64>],
    obs: &[JointObs],
    loss: RobustLoss,
    lm: &LmSettings,
) -> Result<JointResult, PoseError> {
    let mut prior_white = Vec::with_capacity(prior.len());
    for (j, c) in prior_cov.iter().enumerate() {
        // A point with a zero σ is held fast by a stiff prior (1 µm).
        let c = c + Matrix3::identity() * 1e-12;
        let info = c
            .try_inverse()
            .ok_or_else(|| PoseError::Degenerate(format!("GCP {j}: singular survey covariance")))?;
        prior_white.push(
            info.cholesky()
                .map(|ch| ch.l().transpose())
                .ok_or_else(|| {
                    PoseError::Degenerate(format!("GCP {j}: survey covariance not positive"))
                })?,
        );
    }
    let problem = Problem {
        camera,
        prior,
        prior_white,
        obs,
        loss,
        n_poses: poses.len(),
    };
    let mut poses = poses.to_vec();
    let mut points = prior.to_vec();
    let behind = || PoseError::Degenerate("a GCP is behind the camera in a key frame".into());
    let mut sys = problem.build(&poses, &points).ok_or_else(behind)?;
    let mut damping = Damping::new(lm);
    let mut termination = Termination::MaxIterations;
    let mut iterations = 0;
    while iterations < lm.max_iterations {
        iterations += 1;
        let Some((dp, dx)) = problem.solve(&sys, &damping, lm) else {
            damping.update(f64::NAN, lm);
            if damping.exhausted() {
                termination = Termination::NoFurtherProgress;
                break;
            }
            continue;
        };
        // Predicted decrease of the Gauss–Newton model, −(2δᵀb + δᵀHδ).
        let mut predicted = 0.0;
        for (((d, b), u), wk) in dp.iter().zip(&sys.bp).zip(&sys.u).zip(&sys.w) {
            predicted -= 2.0 * d.dot(b) + d.dot(&(u * d));
            for &(j, w) in wk {
                predicted -= 2.0 * d.dot(&(w * dx[j]));
            }
        }
        for ((d, b), v) in dx.iter().zip(&sys.bx).zip(&sys.v) {
            predicted -= 2.0 * d.dot(b) + d.dot(&(v * d));
        }
        let cand_poses: Vec<Rigid3> = poses.iter().zip(&dp).map(|(p, d)| p.plus(d)).collect();
        let cand_points: Vec<Vector3<f64>> = points.iter().zip(&dx).map(|(p, d)| p + d).collect();
        let next = problem.build(&cand_poses, &cand_points);
        let rho = match &next {
            Some(n) if predicted > 0.0 => (sys.cost - n.cost) / predicted,
            _ => f64::NAN,
        };
        if damping.update(rho, lm) {
            let next = next.expect("accepted step was evaluated");
            let rel = (sys.cost - next.cost).abs() / sys.cost.max(1e-300);
            let step = dp.iter().map(|d| d.norm_squared()).sum::<f64>()
                + dx.iter().map(|d| d.norm_squared()).sum::<f64>();
            poses = cand_poses;
            points = cand_points;
            sys = next;
            if rel <= lm.function_tolerance {
                termination = Termination::FunctionTolerance;
                break;
            }
            if step.sqrt() <= lm.parameter_tolerance {
                termination = Termination::ParameterTolerance;
                break;
            }
        } else if damping.exhausted() {
            termination = Termination::NoFurtherProgress;
            break;
        }
    }
    // Covariances from the undamped system: points from the inverse of the reduced matrix,
    // poses from U⁻¹ + U⁻¹ W S⁻¹ Wᵀ U⁻¹.
    let np = points.len();
    let u_inv: Vec<Matrix6<f64>> = sys
        .u
        .iter()
        .map(|u| u.try_inverse())
        .collect::<Option<_>>()
        .ok_or_else(|| {
            PoseError::Degenerate("a key frame's pose is not determined by its picks".into())
        })?;
    let mut sm = DMatrix::<f64>::zeros(3 * np, 3 * np);
    for (j, v) in sys.v.iter().enumerate() {
        sm.fixed_view_mut::<3, 3>(3 * j, 3 * j).copy_from(v);
    }
    for (ui, wk) in u_inv.iter().zip(&sys.w) {
        for &(a, wa) in wk {
            for &(b, wb) in wk {
                let mut blk = sm.fixed_view_mut::<3, 3>(3 * a, 3 * b);
                blk -= wa.transpose() * ui * wb;
            }
        }
    }
    let s_inv = sm
        .try_inverse()
        .ok_or_else(|| PoseError::Degenerate("the GCPs are not determined".into()))?;
    let point_cov = (0..np)
        .map(|j| s_inv.fixed_view::<3, 3>(3 * j, 3 * j).into())
        .collect();
    let pose_cov = (0..poses.len())
        .map(|k| {
            let mut c = u_inv[k];
            for &(a, wa) in &sys.w[k] {
                for &(b, wb) in &sys.w[k] {
                    let sab: Matrix3<f64> = s_inv.fixed_view::<3, 3>(3 * a, 3 * b).into();
                    c += u_inv[k] * wa * sab * wb.transpose() * u_inv[k];
                }
            }
            c
        })
        .collect();
    Ok(JointResult {
        poses,
        points,
        pose_cov,
        point_cov,
        chi2: sys.chi2,
        iterations,
        termination,
    })
}
