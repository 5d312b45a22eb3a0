//! Residuals, Jacobians and costs of a bundle-adjustment problem (parallel over observations).

use super::*;

/// Residuals and Jacobians at one point of the parameter space (weighted by the loss, fixed
/// parameters' columns zeroed).
pub(super) struct Evaluation<const M: usize> {
    pub(super) residuals: Vec<Vector2<f64>>,
    pub(super) j_pose: Vec<Mat26>,
    pub(super) j_intr: Vec<SMatrix<f64, 2, M>>,
    pub(super) j_point: Vec<Mat23>,
    pub(super) cost: f64,
}

#[inline]
pub(super) fn robust(loss: RobustLoss, r: Vector2<f64>) -> (f64, f64) {
    let s = r.norm_squared();
    (0.5 * loss.rho(s), loss.weight(s).max(0.0).sqrt())
}

/// Where an image's camera sees a point, minus the measurement (pixels).
pub(super) fn residual<const M: usize>(
    p: &Problem<M>,
    model: &impl Projection<M>,
    o: &Observation,
) -> Option<Vector2<f64>> {
    let q = &p.poses[o.camera];
    let w = Vector3::new(q[0], q[1], q[2]);
    let p_cam = rotation(&w) * Vector3::from(p.points[o.point]) + Vector3::new(q[3], q[4], q[5]);
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
    for (k, _) in fixed.iter().enumerate().filter(|f| *f.1) {
        j.column_mut(k).fill(0.0);
    }
    j
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
    let each: Vec<f64> = p
        .observations
        .par_iter()
        .enumerate()
        .map(|(k, o)| {
            residual(p, model, o).map_or(f64::INFINITY, |r| robust(loss, r * whitening(p, k)).0)
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
    let per: Vec<Option<(Linearised<M>, f64)>> = p
        .observations
        .par_iter()
        .enumerate()
        .map(|(k, o)| {
            let (r, jc, ji, jp) = linearise(p, model, o)?;
            // Whitened by the observation's σ, then weighted by the loss.
            let white = whitening(p, k);
            let (c, robust_weight) = robust(loss, r * white);
            let w = robust_weight * white;
            let ji = mask_columns(ji * w, &p.fixed_intrinsics[p.intrinsics_of[o.camera]]);
            let jp = if p.fixed_points[o.point] {
                Mat23::zeros()
            } else {
                jp * w
            };
            Some((
                (
                    r * w,
                    mask_columns(jc * w, &p.fixed_poses[o.camera]),
                    ji,
                    jp,
                ),
                c,
            ))
        })
        .collect();
    let n = per.len();
    let mut e = Evaluation {
        residuals: Vec::with_capacity(n),
        j_pose: Vec::with_capacity(n),
        j_intr: Vec::with_capacity(n),
        j_point: Vec::with_capacity(n),
        cost: 0.0,
    };
    for (k, item) in per.into_iter().enumerate() {
        let ((r, jc, ji, jp), c) = item.ok_or(k)?;
        e.residuals.push(r);
        e.j_pose.push(jc);
        e.j_intr.push(ji);
        e.j_point.push(jp);
        e.cost += c;
    }
    e.cost += prior_cost(p, priors);
    Ok(e)
}
