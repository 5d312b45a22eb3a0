//! Residuals, Jacobians and costs of a bundle-adjustment problem (parallel over observations).

use super::*;

/// Residuals and Jacobians at one point of the parameter space (weighted by the loss, fixed
/// parameters' columns zeroed).
#[derive(Clone)]
pub(super) struct Evaluation<const M: usize> {
    pub(super) residuals: Vec<Vector2<f64>>,
    pub(super) j_pose: Vec<Mat26>,
    /// Empty when every intrinsic parameter is fixed (all zeros: [`Evaluation::ji`]); a
    /// survey-scale model with a calibrated camera would otherwise keep 208 bytes of zeros per
    /// observation, twice.
    pub(super) j_intr: Vec<SMatrix<f64, 2, M>>,
    pub(super) j_point: Vec<Mat23>,
    pub(super) cost: f64,
}

impl<const M: usize> Evaluation<M> {
    /// Observation `k`'s Jacobian by its camera's intrinsics.
    #[inline]
    pub(super) fn ji(&self, k: usize) -> SMatrix<f64, 2, M> {
        self.j_intr.get(k).copied().unwrap_or_else(SMatrix::zeros)
    }
}

/// Whether any intrinsic parameter is estimated: else the intrinsics' Jacobians and couplings
/// (all zeros) are not stored.
pub(super) fn intrinsics_free<const M: usize>(p: &Problem<M>) -> bool {
    p.fixed_intrinsics
        .iter()
        .any(|f| f.iter().any(|fixed| !fixed))
}

#[inline]
pub(super) fn robust(loss: RobustLoss, r: Vector2<f64>) -> (f64, f64) {
    let s = r.norm_squared();
    (0.5 * loss.rho(s), loss.weight(s).max(0.0).sqrt())
}

/// Where an image's camera sees a point, minus the measurement (pixels); `rotations` per image.
pub(super) fn residual<const M: usize>(
    p: &Problem<M>,
    model: &impl Projection<M>,
    o: &Observation,
    rotations: &[Matrix3<f64>],
) -> Option<Vector2<f64>> {
    let q = &p.poses[o.camera];
    let p_cam =
        rotations[o.camera] * Vector3::from(p.points[o.point]) + Vector3::new(q[3], q[4], q[5]);
    let u = model.project(&p.intrinsics[p.intrinsics_of[o.camera]], &p_cam)?;
    Some(u - Vector2::from(o.xy))
}

/// `1/σ` of observation `k`: its residual and Jacobians are divided by its σ.
#[inline]
pub(super) fn whitening<const M: usize>(p: &Problem<M>, k: usize) -> f64 {
    p.sigma_px.get(k).map_or(1.0, |s| 1.0 / s)
}

/// A matrix with the fixed parameters' columns zeroed.
pub(super) fn mask_columns<const R: usize, const N: usize>(
    mut j: SMatrix<f64, R, N>,
    fixed: &[bool; N],
) -> SMatrix<f64, R, N> {
    zero_columns(&mut j, fixed);
    j
}

/// Zeroes the fixed parameters' columns in place.
#[inline]
pub(super) fn zero_columns<const R: usize, const N: usize>(
    j: &mut SMatrix<f64, R, N>,
    fixed: &[bool; N],
) {
    for (k, _) in fixed.iter().enumerate().filter(|f| *f.1) {
        j.column_mut(k).fill(0.0);
    }
}

/// A matrix with its columns scaled.
pub(super) fn scale_columns<const R: usize, const N: usize>(
    mut j: SMatrix<f64, R, N>,
    s: &SVector<f64, N>,
) -> SMatrix<f64, R, N> {
    for (mut c, v) in j.column_iter_mut().zip(s.iter()) {
        c *= *v;
    }
    j
}

pub(super) fn prior_residual<const M: usize>(p: &Problem<M>, q: &PointPrior) -> Vector3<f64> {
    q.sqrt_information * (Vector3::from(p.points[q.point]) - Vector3::from(q.position))
}

/// A camera-centre prior's residual and its Jacobian with respect to the image's pose (fixed
/// columns zeroed): `C = −R(w)ᵀ t`, `∂C/∂t = −Rᵀ`, `∂C/∂w = [C]ₓ J(−w)` (J the left Jacobian).
pub(super) fn centre_residual<const M: usize>(
    p: &Problem<M>,
    q: &CentrePrior,
) -> (Vector3<f64>, Mat36) {
    let pose = &p.poses[q.camera];
    let w = Vector3::new(pose[0], pose[1], pose[2]);
    let rt = rotation(&w).transpose();
    let c = -rt * Vector3::new(pose[3], pose[4], pose[5]);
    let inv = Matrix3::from_diagonal(&Vector3::from(q.sigma).map(|v| 1.0 / v));
    let mut j = Mat36::zeros();
    j.fixed_view_mut::<3, 3>(0, 0)
        .copy_from(&(inv * c.cross_matrix() * left_jacobian(&(-w))));
    j.fixed_view_mut::<3, 3>(0, 3).copy_from(&(inv * -rt));
    (
        inv * (c - Vector3::from(q.position)),
        mask_columns(j, &p.fixed_poses[q.camera]),
    )
}

pub(super) fn prior_cost<const M: usize>(p: &Problem<M>, priors: &Priors) -> f64 {
    priors
        .points
        .iter()
        .map(|q| 0.5 * prior_residual(p, q).norm_squared())
        .sum::<f64>()
        + priors
            .centres
            .iter()
            .map(|q| 0.5 * centre_residual(p, q).0.norm_squared())
            .sum::<f64>()
}

/// The cost at the problem's parameters (infinite where an observation cannot be projected);
/// summed in observation order, as [`evaluate`] does, so that the two agree to the last bit.
pub(super) fn cost_of<const M: usize>(
    p: &Problem<M>,
    model: &impl Projection<M>,
    priors: &Priors,
    loss: RobustLoss,
) -> f64 {
    let rotations: Vec<Matrix3<f64>> = p
        .poses
        .iter()
        .map(|q| rotation(&Vector3::new(q[0], q[1], q[2])))
        .collect();
    let each: Vec<f64> = p
        .observations
        .par_iter()
        .with_min_len(GRAIN)
        .enumerate()
        .map(|(k, o)| {
            residual(p, model, o, &rotations)
                .map_or(f64::INFINITY, |r| robust(loss, r * whitening(p, k)).0)
        })
        .collect();
    let cost = each.iter().sum::<f64>() + prior_cost(p, priors);
    if cost.is_finite() {
        cost
    } else {
        f64::INFINITY
    }
}

/// Residuals and Jacobians; `Err(k)` names the first observation that cannot be projected.
pub(super) fn evaluate<const M: usize>(
    p: &Problem<M>,
    model: &impl Projection<M>,
    priors: &Priors,
    loss: RobustLoss,
) -> Result<Evaluation<M>, usize> {
    let n = p.observations.len();
    let mut e = Evaluation {
        residuals: vec![Vector2::zeros(); n],
        j_pose: vec![Mat26::zeros(); n],
        j_intr: vec![SMatrix::<f64, 2, M>::zeros(); if intrinsics_free(p) { n } else { 0 }],
        j_point: vec![Mat23::zeros(); n],
        cost: 0.0,
    };
    evaluate_into(p, model, priors, loss, &mut e)?;
    Ok(e)
}

/// [`evaluate`] into the buffers of an earlier evaluation of the same problem's structure (the
/// trust-region loop keeps two and swaps them, rather than allocating each step's).
pub(super) fn evaluate_into<const M: usize>(
    p: &Problem<M>,
    model: &impl Projection<M>,
    priors: &Priors,
    loss: RobustLoss,
    e: &mut Evaluation<M>,
) -> Result<(), usize> {
    let frames = PoseFrame::all(p);
    e.cost = 0.0;
    // Observation k's cost, whitened residual and Jacobians (the intrinsics' `None` when not
    // stored).
    let one = |k: usize| {
        let o = &p.observations[k];
        let (r, jc, ji, jp) = linearise_at(p, model, o, &frames[o.camera])?;
        // Whitened by the observation's σ, then weighted by the loss.
        let white = whitening(p, k);
        let (c, robust_weight) = robust(loss, r * white);
        let w = robust_weight * white;
        let mut jc = jc * w;
        zero_columns(&mut jc, &p.fixed_poses[o.camera]);
        let mut ji = ji * w;
        zero_columns(&mut ji, &p.fixed_intrinsics[p.intrinsics_of[o.camera]]);
        let jp = if p.fixed_points[o.point] {
            Mat23::zeros()
        } else {
            jp * w
        };
        Some((c, r * w, jc, ji, jp))
    };
    let costs: Vec<Option<f64>> = if e.j_intr.is_empty() {
        (
            e.residuals.par_iter_mut(),
            e.j_pose.par_iter_mut(),
            e.j_point.par_iter_mut(),
        )
            .into_par_iter()
            .with_min_len(GRAIN)
            .enumerate()
            .map(|(k, (r_out, jc_out, jp_out))| {
                let (c, r, jc, _, jp) = one(k)?;
                (*r_out, *jc_out, *jp_out) = (r, jc, jp);
                Some(c)
            })
            .collect()
    } else {
        (
            e.residuals.par_iter_mut(),
            e.j_pose.par_iter_mut(),
            e.j_intr.par_iter_mut(),
            e.j_point.par_iter_mut(),
        )
            .into_par_iter()
            .with_min_len(GRAIN)
            .enumerate()
            .map(|(k, (r_out, jc_out, ji_out, jp_out))| {
                let (c, r, jc, ji, jp) = one(k)?;
                (*r_out, *jc_out, *ji_out, *jp_out) = (r, jc, ji, jp);
                Some(c)
            })
            .collect()
    };
    for (k, c) in costs.into_iter().enumerate() {
        e.cost += c.ok_or(k)?;
    }
    e.cost += prior_cost(p, priors);
    Ok(())
}
