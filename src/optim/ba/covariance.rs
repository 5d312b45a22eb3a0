//! Covariances of the adjusted cameras (the inverse of the reduced system at the solution).

use super::*;

/// The covariance of the camera-side parameters at the optimum.
#[derive(Clone, Debug)]
pub struct CameraCovariance {
    /// Over every pose and camera parameter, in the solver's order (see [`Self::pose`] and
    /// [`Self::intrinsics`]); fixed parameters have zero rows and columns.
    pub matrix: DMatrix<f64>,
    /// The observations' σ (pixels) the covariance is scaled by: given, or estimated.
    pub sigma_px: f64,
    pub(super) pose_offsets: Vec<usize>,
    pub(super) intrinsics_offsets: Vec<usize>,
    pub(super) intrinsics_len: usize,
}

impl CameraCovariance {
    /// The 6×6 covariance of image `i`'s pose (`w` radians, then `t`).
    pub fn pose(&self, i: usize) -> DMatrix<f64> {
        let o = self.pose_offsets[i];
        self.matrix.view((o, o), (6, 6)).into_owned()
    }

    /// The covariance of camera `g`'s intrinsics.
    pub fn intrinsics(&self, g: usize) -> DMatrix<f64> {
        let (o, m) = (self.intrinsics_offsets[g], self.intrinsics_len);
        self.matrix.view((o, o), (m, m)).into_owned()
    }

    /// The standard deviation of parameter `c` of image `i`'s pose.
    pub fn pose_sigma(&self, i: usize, c: usize) -> f64 {
        let o = self.pose_offsets[i] + c;
        self.matrix[(o, o)].sqrt()
    }

    /// The standard deviation of intrinsic parameter `c` of camera `g`.
    pub fn intrinsics_sigma(&self, g: usize, c: usize) -> f64 {
        let o = self.intrinsics_offsets[g] + c;
        self.matrix[(o, o)].sqrt()
    }
}

/// The covariance of the camera-side parameters at the problem's current values: the inverse
/// of the information matrix (observations weighted by `1/σ²`, priors by their own σ) with the
/// points eliminated. `σ` is `sigma_px` or, when `None`, estimated from the observations'
/// residuals as `Σ r²` over the degrees of freedom (`2·observations + 3·priors − free
/// parameters`). With a robust loss the observations are weighted by `√ρ'` as in the solver
/// (an outlier's say shrinks). Fixed parameters get zero rows and columns. Without priors the
/// gauge (a similarity) is free and the covariance is not defined ([`BaError::Singular`]).
pub fn covariance<const M: usize>(
    p: &Problem<M>,
    model: &impl Projection<M>,
    priors: &Priors,
    loss: RobustLoss,
    sigma_px: Option<f64>,
) -> Result<CameraCovariance, BaError> {
    p.check()?;
    check_priors(p, priors)?;
    let st = Structure::new(p);
    let lay = Layout::new(p);
    let mut e = evaluate(p, model, &Priors::default(), loss).map_err(|k| projection_error(p, k))?;
    let free = lay.free(p);
    // A point's observable coordinates: two per image it is seen in and three for a survey.
    let mut point_rank = vec![0; p.points.len()];
    for o in &p.observations {
        point_rank[o.point] += 2;
    }
    for q in &priors.points {
        point_rank[q.point] += 3;
    }
    let n_free =
        free.iter().filter(|f| **f).count() + point_rank.iter().map(|r| (*r).min(3)).sum::<usize>();
    let dof = (2 * p.observations.len() + 3 * (priors.points.len() + priors.centres.len()))
        .saturating_sub(n_free);
    let sigma = match sigma_px {
        Some(v) => v,
        None => {
            let sq: f64 = e.residuals.iter().map(|r| r.norm_squared()).sum();
            (sq / dof.max(1) as f64).sqrt()
        }
    };
    // Whiten the observations; the priors are whitened already.
    for k in 0..e.residuals.len() {
        e.residuals[k] /= sigma;
        e.j_pose[k] /= sigma;
        e.j_intr[k] /= sigma;
        e.j_point[k] /= sigma;
    }
    // In Jacobi-scaled variables (as the solver's): focal lengths in pixels beside distortion
    // coefficients and radians would otherwise defeat the factorisation.
    let (s_cam, s_point) = scales(p, priors, &st, &lay, &e);
    let n = scaled_normal(p, priors, &st, &lay, &e, &s_cam, &s_point);
    // A point seen once (and not surveyed) is free along its ray: the pseudo-inverse of its
    // block gives it no say on the cameras, as it has none.
    let v_inv: Vec<Matrix3<f64>> =
        n.v.iter()
            .map(|v| {
                v.pseudo_inverse(1e-12 * v.norm())
                    .unwrap_or_else(|_| Matrix3::zeros())
            })
            .collect();
    let (mut s, _) = reduced_system(p, &st, &lay, &n, &DVector::zeros(lay.dim), &v_inv, 1.0);
    for (k, _) in free.iter().enumerate().filter(|f| !*f.1) {
        s[(k, k)] = 1.0;
    }
    let scale = DMatrix::from_diagonal(&s_cam);
    let mut matrix = &scale * s.cholesky().ok_or(BaError::Singular)?.inverse() * &scale;
    for (k, _) in free.iter().enumerate().filter(|f| !*f.1) {
        matrix.row_mut(k).fill(0.0);
        matrix.column_mut(k).fill(0.0);
    }
    Ok(CameraCovariance {
        matrix,
        sigma_px: sigma,
        pose_offsets: lay.pose,
        intrinsics_offsets: lay.intr,
        intrinsics_len: M,
    })
}
