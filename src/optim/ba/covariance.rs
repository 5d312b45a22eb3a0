//! Covariances of the adjusted cameras (the inverse of the reduced system at the solution) and
//! of the points (their blocks of the full inverse, from the same reduced system).

use super::*;

/// The covariance of the camera-side parameters at the optimum.
#[derive(Clone, Debug)]
pub struct CameraCovariance {
    /// Over every pose and camera parameter, in the solver's order (see [`Self::pose`] and
    /// [`Self::intrinsics`]); fixed parameters have zero rows and columns.
    pub matrix: DMatrix<f64>,
    /// The observations' σ (pixels) the covariance is scaled by: given, or estimated.
    pub sigma_px: f64,
    /// Per point, its 3×3 covariance: zero for a fixed point, `None` for one that the
    /// observations and priors do not determine (seen in one image only, not surveyed).
    pub points: Vec<Option<Matrix3<f64>>>,
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
/// points eliminated; and each point's block of the full inverse. `σ` is `sigma_px` (in units
/// of the observations' own σ where [`Problem::sigma_px`] gives them) or, when `None`,
/// estimated from the observations' residuals as `Σ r²` over the degrees of freedom (`2·observations + 3·priors − free
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
    // On this thread when small, else on a worker of the pool, as `adjust`.
    on_pool(p.observations.len(), || {
        covariance_on_pool(p, model, priors, loss, sigma_px)
    })
}

fn covariance_on_pool<const M: usize>(
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
    let freedom = Freedom::of(p, priors, &lay);
    let sigma = sigma_px.unwrap_or_else(|| freedom.sigma(&e.residuals));
    // Whiten the observations; the priors are whitened already.
    for k in 0..e.residuals.len() {
        e.residuals[k] /= sigma;
        e.j_pose[k] /= sigma;
        if let Some(j) = e.j_intr.get_mut(k) {
            *j /= sigma;
        }
        e.j_point[k] /= sigma;
    }
    // In Jacobi-scaled variables (as the solver's): focal lengths in pixels beside distortion
    // coefficients and radians would otherwise defeat the factorisation.
    let (s_cam, s_point) = scales(p, priors, &st, &lay, &e);
    let n = scaled_normal(p, priors, &st, &lay, &e, &s_cam, &s_point);
    let at = Linearisation::new((&st, &lay), &n, (&s_cam, &s_point));
    from_normal(p, &at, &freedom, sigma, 1.0)
}

/// The degrees of freedom of a problem with its priors.
pub(super) struct Freedom {
    /// Per parameter of the camera side, whether it is estimated.
    free: Vec<bool>,
    /// Per point, its observable coordinates: two per image it is seen in and three for a
    /// survey (a fixed point none).
    point_rank: Vec<usize>,
    dof: usize,
}

impl Freedom {
    pub(super) fn of<const M: usize>(p: &Problem<M>, priors: &Priors, lay: &Layout) -> Freedom {
        let free = lay.free(p);
        let mut point_rank = vec![0; p.points.len()];
        for o in p.observations.iter().filter(|o| !p.fixed_points[o.point]) {
            point_rank[o.point] += 2;
        }
        for q in &priors.points {
            point_rank[q.point] += 3;
        }
        let n_free = free.iter().filter(|f| **f).count()
            + point_rank.iter().map(|r| (*r).min(3)).sum::<usize>();
        let dof = (2 * p.observations.len() + 3 * (priors.points.len() + priors.centres.len()))
            .saturating_sub(n_free);
        Freedom {
            free,
            point_rank,
            dof,
        }
    }

    /// `σ` from the residuals: `√(Σ r² / dof)`.
    pub(super) fn sigma(&self, residuals: &[Vector2<f64>]) -> f64 {
        let sq: f64 = residuals.iter().map(|r| r.norm_squared()).sum();
        (sq / self.dof.max(1) as f64).sqrt()
    }
}

/// A problem's normal equations at one point, in the Jacobi-scaled variables.
pub(super) struct Linearisation<'a, const M: usize> {
    pub(super) st: &'a Structure,
    pub(super) lay: &'a Layout,
    pub(super) n: &'a Normal<M>,
    pub(super) s_cam: &'a DVector<f64>,
    pub(super) s_point: &'a [Vector3<f64>],
}

impl<'a, const M: usize> Linearisation<'a, M> {
    pub(super) fn new(
        (st, lay): (&'a Structure, &'a Layout),
        n: &'a Normal<M>,
        (s_cam, s_point): (&'a DVector<f64>, &'a [Vector3<f64>]),
    ) -> Self {
        Linearisation {
            st,
            lay,
            n,
            s_cam,
            s_point,
        }
    }
}

/// The covariances from the normal equations: their inverse (points eliminated) times
/// `variance_factor` (`σ²` when the equations are of residuals not divided by `σ`).
pub(super) fn from_normal<const M: usize>(
    p: &Problem<M>,
    at: &Linearisation<M>,
    freedom: &Freedom,
    sigma: f64,
    variance_factor: f64,
) -> Result<CameraCovariance, BaError> {
    let (st, lay, n) = (at.st, at.lay, at.n);
    // A point seen once (and not surveyed) is free along its ray: the pseudo-inverse of its
    // block gives it no say on the cameras, as it has none.
    let v_inv: Vec<Matrix3<f64>> =
        n.v.iter()
            .map(|v| {
                v.pseudo_inverse(1e-12 * v.norm())
                    .unwrap_or_else(|_| Matrix3::zeros())
            })
            .collect();
    let (mut s, _) = reduced_system(p, st, lay, n, &DVector::zeros(lay.dim), &v_inv, 1.0);
    let fixed: Vec<usize> = (0..lay.dim).filter(|&k| !freedom.free[k]).collect();
    for &k in &fixed {
        s[(k, k)] = 1.0;
    }
    let s_inv = match Arrow::of(st, lay, &s) {
        Some(arrow) => arrow.inverse(lay.dim),
        None => s.cholesky().ok_or(BaError::Singular)?.inverse(),
    };
    let points = point_covariances(p, st, lay, n, &v_inv, &s_inv, at.s_point)
        .into_iter()
        .enumerate()
        .map(
            |(j, c)| match (p.fixed_points[j], freedom.point_rank[j] >= 3) {
                (true, _) => Some(Matrix3::zeros()),
                (false, true) => Some(c * variance_factor),
                (false, false) => None,
            },
        )
        .collect();
    // Back to the problem's units: `diag(s) S⁻¹ diag(s)`, entry by entry.
    let mut matrix = s_inv;
    for (j, mut col) in matrix.column_iter_mut().enumerate() {
        col.component_mul_assign(at.s_cam);
        col *= at.s_cam[j] * variance_factor;
    }
    for &k in &fixed {
        matrix.row_mut(k).fill(0.0);
        matrix.column_mut(k).fill(0.0);
    }
    Ok(CameraCovariance {
        matrix,
        sigma_px: sigma,
        points,
        pose_offsets: lay.pose.clone(),
        intrinsics_offsets: lay.intr.clone(),
        intrinsics_len: M,
    })
}

/// Each point's block of the inverse of the full normal matrix,
/// `V⁻¹ + V⁻¹ Wᵀ S⁻¹ W V⁻¹` (`W` the point's column of camera couplings), in the problem's
/// own units: `s_inv` and the blocks are in the Jacobi-scaled variables.
fn point_covariances<const M: usize>(
    p: &Problem<M>,
    st: &Structure,
    lay: &Layout,
    n: &Normal<M>,
    v_inv: &[Matrix3<f64>],
    s_inv: &DMatrix<f64>,
    s_point: &[Vector3<f64>],
) -> Vec<Matrix3<f64>> {
    st.coupling()
        .par_iter()
        .with_min_len(grain(p.points.len(), p.observations.len()))
        .enumerate()
        .map(|(j, ks)| {
            let mut wsw = Matrix3::zeros();
            for &a in ks {
                let (pa, ia) = lay.of(p, p.observations[a].camera);
                let (wpa, wia) = (n.w_pose[a].transpose(), n.wi(a).transpose());
                for &b in ks {
                    let (pb, ib) = lay.of(p, p.observations[b].camera);
                    let (wpb, wib) = (&n.w_pose[b], &n.wi(b));
                    wsw += wpa * s_inv.fixed_view::<6, 6>(pa, pb) * wpb
                        + wpa * s_inv.fixed_view::<6, M>(pa, ib) * wib
                        + wia * s_inv.fixed_view::<M, 6>(ia, pb) * wpb
                        + wia * s_inv.fixed_view::<M, M>(ia, ib) * wib;
                }
            }
            let vi = &v_inv[j];
            let scaled = vi + vi * wsw * vi;
            let sp = Matrix3::from_diagonal(&s_point[j]);
            sp * scaled * sp
        })
        .collect()
}
