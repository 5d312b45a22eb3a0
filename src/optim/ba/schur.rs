//! The normal equations in blocks, their scaling and damping, and the Schur complement on the
//! points: the reduced camera system, solved densely, and the back-substitution.

use super::*;

/// The normal equations' blocks in the scaled variables. `JᵀJ` on the camera side has a block
/// per pose, per pose and its intrinsics, and per intrinsics.
pub(super) struct Normal<const M: usize> {
    pub(super) u_pose: Vec<Mat6>,
    pub(super) u_pose_intr: Vec<SMatrix<f64, 6, M>>,
    pub(super) u_intr: Vec<SMatrix<f64, M, M>>,
    pub(super) v: Vec<Matrix3<f64>>,
    /// Per observation: `Jposeᵀ Jpoint` and `Jintrᵀ Jpoint`; empty when every point is fixed
    /// (they would be zero, and [`Structure::coupling`] names no observation to read them).
    pub(super) w_pose: Vec<Mat63>,
    /// Empty when every intrinsic parameter is fixed: see [`Normal::wi`].
    pub(super) w_intr: Vec<SMatrix<f64, M, 3>>,
    pub(super) observations: usize,
    /// The camera side's gradient, in [`Layout`] order.
    pub(super) g_cam: DVector<f64>,
    pub(super) g_point: Vec<Vector3<f64>>,
}

impl<const M: usize> Normal<M> {
    /// Observation `k`'s `Jintrᵀ Jpoint`.
    #[inline]
    pub(super) fn wi(&self, k: usize) -> SMatrix<f64, M, 3> {
        self.w_intr.get(k).copied().unwrap_or_else(SMatrix::zeros)
    }
}

/// Per group of observations (an image's, a point's): `Σ JᵀJ` and `Σ Jᵀr`, `jac(k)` the
/// observation's Jacobian with respect to the group's parameters.
pub(super) fn normal_blocks<const N: usize>(
    groups: &[Vec<usize>],
    jac: impl Fn(usize) -> SMatrix<f64, 2, N> + Sync,
    residuals: &[Vector2<f64>],
) -> (Vec<SMatrix<f64, N, N>>, Vec<SVector<f64, N>>) {
    let observations = groups.iter().map(Vec::len).sum();
    groups
        .par_iter()
        .with_min_len(grain(groups.len(), observations))
        .map(|ks| {
            let mut a = SMatrix::<f64, N, N>::zeros();
            let mut g = SVector::<f64, N>::zeros();
            for &k in ks {
                let j = jac(k);
                a += j.transpose() * j;
                g += j.transpose() * residuals[k];
            }
            (a, g)
        })
        .unzip()
}

/// Per group of observations, the squared norms of its parameters' Jacobian columns.
pub(super) fn column_norms_sq<const N: usize>(
    groups: &[Vec<usize>],
    jac: &[SMatrix<f64, 2, N>],
) -> Vec<SVector<f64, N>> {
    if jac.is_empty() {
        // Jacobians not stored: all zeros.
        return vec![SVector::<f64, N>::zeros(); groups.len()];
    }
    groups
        .iter()
        .map(|ks| {
            ks.iter().fold(SVector::<f64, N>::zeros(), |acc, &k| {
                acc + jac[k].row_iter().fold(SVector::<f64, N>::zeros(), |a, r| {
                    a + r.transpose().component_mul(&r.transpose())
                })
            })
        })
        .collect()
}

/// Ceres's Jacobi scaling of a column of squared norm `sq`: `1 / (1 + ‖column‖)`.
pub(super) fn jacobi_scales<const N: usize>(sq: &[SVector<f64, N>]) -> Vec<SVector<f64, N>> {
    sq.iter()
        .map(|v| v.map(|x| 1.0 / (1.0 + x.sqrt())))
        .collect()
}

/// Which observations each image, each camera and each point has.
pub(super) struct Structure {
    pub(super) by_image: Vec<Vec<usize>>,
    pub(super) by_camera: Vec<Vec<usize>>,
    pub(super) by_point: Vec<Vec<usize>>,
    /// `by_point` with fixed points' lists emptied, when there are fixed points.
    fixed_free: Option<Vec<Vec<usize>>>,
}

impl Structure {
    pub(super) fn new<const M: usize>(p: &Problem<M>) -> Structure {
        let mut st = Structure {
            by_image: vec![Vec::new(); p.poses.len()],
            by_camera: vec![Vec::new(); p.intrinsics.len()],
            by_point: vec![Vec::new(); p.points.len()],
            fixed_free: None,
        };
        for (k, o) in p.observations.iter().enumerate() {
            st.by_image[o.camera].push(k);
            st.by_camera[p.intrinsics_of[o.camera]].push(k);
            st.by_point[o.point].push(k);
        }
        if p.fixed_points.iter().any(|f| *f) {
            st.fixed_free = Some(
                st.by_point
                    .iter()
                    .zip(&p.fixed_points)
                    .map(|(ks, fixed)| if *fixed { Vec::new() } else { ks.clone() })
                    .collect(),
            );
        }
        st
    }

    /// Per point, the observations that couple it to the cameras in the Schur complement: none
    /// for a fixed point (its `W` blocks are zero), which spares a calibration's board corners
    /// every pair of views.
    pub(super) fn coupling(&self) -> &[Vec<usize>] {
        self.fixed_free.as_deref().unwrap_or(&self.by_point)
    }
}

/// A flat camera-side vector from per-pose and per-camera pieces.
pub(super) fn flat<const M: usize>(
    lay: &Layout,
    poses: &[Vec6],
    intr: &[SVector<f64, M>],
) -> DVector<f64> {
    let mut v = DVector::zeros(lay.dim);
    for (o, x) in lay.pose.iter().zip(poses) {
        v.fixed_rows_mut::<6>(*o).copy_from(x);
    }
    for (o, x) in lay.intr.iter().zip(intr) {
        v.fixed_rows_mut::<M>(*o).copy_from(x);
    }
    v
}

/// The Jacobi scales of every camera-side and point parameter, from the first Jacobian.
pub(super) fn scales<const M: usize>(
    p: &Problem<M>,
    priors: &Priors,
    st: &Structure,
    lay: &Layout,
    e: &Evaluation<M>,
) -> (DVector<f64>, Vec<Vector3<f64>>) {
    let mut pose_sq = column_norms_sq(&st.by_image, &e.j_pose);
    for q in &priors.centres {
        for r in centre_residual(p, q).1.row_iter() {
            pose_sq[q.camera] += r.transpose().component_mul(&r.transpose());
        }
    }
    let intr_sq = column_norms_sq(&st.by_camera, &e.j_intr);
    let mut point_sq = column_norms_sq(&st.by_point, &e.j_point);
    for q in &priors.points {
        let w = &q.sqrt_information;
        point_sq[q.point] += Vector3::from_fn(|c, _| w.column(c).norm_squared());
    }
    (
        flat(lay, &jacobi_scales(&pose_sq), &jacobi_scales(&intr_sq)),
        jacobi_scales(&point_sq),
    )
}

pub(super) fn scaled_normal<const M: usize>(
    p: &Problem<M>,
    priors: &Priors,
    st: &Structure,
    lay: &Layout,
    e: &Evaluation<M>,
    s_cam: &DVector<f64>,
    s_point: &[Vector3<f64>],
) -> Normal<M> {
    let obs = &p.observations;
    // One pass per image: its pose blocks and its share of its camera's intrinsic blocks (in
    // parallel even when every image shares one camera), each Jacobian scaled once.
    type PerImage<const M: usize> = (
        Mat6,
        SMatrix<f64, 6, M>,
        Vec6,
        SMatrix<f64, M, M>,
        SVector<f64, M>,
    );
    let per_image: Vec<PerImage<M>> = st
        .by_image
        .par_iter()
        .enumerate()
        .with_min_len(grain(p.poses.len(), obs.len()))
        .map(|(i, ks)| {
            let (pi, gi) = lay.of(p, i);
            let sc = s_cam.fixed_rows::<6>(pi).into_owned();
            let si = s_cam.fixed_rows::<M>(gi).into_owned();
            // The image's rows stacked, unscaled, so that its blocks are matrix products
            // (BLAS-like kernels) rather than a small product per observation; scaled after.
            let rows = 2 * ks.len();
            let mut a = DMatrix::<f64>::zeros(rows, 6);
            let mut b = DMatrix::<f64>::zeros(rows, M);
            let mut r = DVector::<f64>::zeros(rows);
            for (n, &k) in ks.iter().enumerate() {
                a.fixed_view_mut::<2, 6>(2 * n, 0).copy_from(&e.j_pose[k]);
                b.fixed_view_mut::<2, M>(2 * n, 0).copy_from(&e.ji(k));
                r.fixed_rows_mut::<2>(2 * n).copy_from(&e.residuals[k]);
            }
            // Column dot products over the free columns only (a fixed parameter's column is
            // zero), each symmetric block's lower triangle mirrored.
            let free_pose: Vec<usize> = (0..6).filter(|&c| !p.fixed_poses[i][c]).collect();
            let fixed_intr = &p.fixed_intrinsics[p.intrinsics_of[i]];
            let free_intr: Vec<usize> = (0..M).filter(|&c| !fixed_intr[c]).collect();
            let mut u = Mat6::zeros();
            let mut ui = SMatrix::<f64, 6, M>::zeros();
            let mut uii = SMatrix::<f64, M, M>::zeros();
            let mut g = Vec6::zeros();
            let mut g_i = SVector::<f64, M>::zeros();
            for (n, &x) in free_pose.iter().enumerate() {
                let ax = a.column(x);
                for &y in &free_pose[..=n] {
                    u[(x, y)] = ax.dot(&a.column(y));
                    u[(y, x)] = u[(x, y)];
                }
                for &y in &free_intr {
                    ui[(x, y)] = ax.dot(&b.column(y));
                }
                g[x] = ax.dot(&r);
            }
            for (n, &x) in free_intr.iter().enumerate() {
                let bx = b.column(x);
                for &y in &free_intr[..=n] {
                    uii[(x, y)] = bx.dot(&b.column(y));
                    uii[(y, x)] = uii[(x, y)];
                }
                g_i[x] = bx.dot(&r);
            }
            u.component_mul_assign(&(sc * sc.transpose()));
            ui.component_mul_assign(&(sc * si.transpose()));
            uii.component_mul_assign(&(si * si.transpose()));
            g.component_mul_assign(&sc);
            g_i.component_mul_assign(&si);
            (u, ui, g, uii, g_i)
        })
        .collect();
    let mut u_intr = vec![SMatrix::<f64, M, M>::zeros(); p.intrinsics.len()];
    let mut g_intr = vec![SVector::<f64, M>::zeros(); p.intrinsics.len()];
    let mut u_pose = Vec::with_capacity(p.poses.len());
    let mut u_pose_intr = Vec::with_capacity(p.poses.len());
    let mut g_pose = Vec::with_capacity(p.poses.len());
    for (i, (u, ui, g, uii, gi)) in per_image.into_iter().enumerate() {
        let c = p.intrinsics_of[i];
        u_intr[c] += uii;
        g_intr[c] += gi;
        u_pose.push(u);
        u_pose_intr.push(ui);
        g_pose.push(g);
    }
    let jp = |k: usize| scale_columns(e.j_point[k], &s_point[obs[k].point]);
    let (mut v, mut g_point) = normal_blocks(&st.by_point, jp, &e.residuals);
    // A point prior's Jacobian is W, scaled like the point's columns.
    for q in &priors.points {
        let j = scale_columns(q.sqrt_information, &s_point[q.point]);
        v[q.point] += j.transpose() * j;
        g_point[q.point] += j.transpose() * prior_residual(p, q);
    }
    for q in &priors.centres {
        let (r, j) = centre_residual(p, q);
        let s = s_cam.fixed_rows::<6>(lay.pose[q.camera]).into_owned();
        let j = scale_columns(j, &s);
        u_pose[q.camera] += j.transpose() * j;
        g_pose[q.camera] += j.transpose() * r;
    }
    let (w_pose, w_intr) = couplings(p, lay, e, s_cam, s_point);
    Normal {
        u_pose,
        u_pose_intr,
        u_intr,
        v,
        w_pose,
        w_intr,
        g_cam: flat(lay, &g_pose, &g_intr),
        g_point,
        observations: obs.len(),
    }
}

/// Per observation, its scaled `Jposeᵀ Jpoint` and `Jintrᵀ Jpoint` (see [`Normal`]'s fields for
/// when each is left empty).
fn couplings<const M: usize>(
    p: &Problem<M>,
    lay: &Layout,
    e: &Evaluation<M>,
    s_cam: &DVector<f64>,
    s_point: &[Vector3<f64>],
) -> (Vec<Mat63>, Vec<SMatrix<f64, M, 3>>) {
    let obs = &p.observations;
    let fixed_point = |k: usize| p.fixed_points[obs[k].point];
    let all_fixed = p.fixed_points.iter().all(|f| *f);
    let coupled = if all_fixed { 0 } else { obs.len() };
    // Unscaled products, then scaled: no 2×M temporaries moved about. A fixed point's
    // Jacobian is zero, and so are its couplings.
    let w_pose = (0..coupled)
        .into_par_iter()
        .with_min_len(GRAIN)
        .map(|k| {
            if fixed_point(k) {
                return Mat63::zeros();
            }
            let (pk, _) = lay.of(p, obs[k].camera);
            let mut wp = e.j_pose[k].tr_mul(&e.j_point[k]);
            wp.component_mul_assign(
                &(s_cam.fixed_rows::<6>(pk) * s_point[obs[k].point].transpose()),
            );
            wp
        })
        .collect();
    // Not stored where the intrinsics are all fixed (all zeros: [`Normal::wi`]).
    let w_intr = (0..if e.j_intr.is_empty() { 0 } else { coupled })
        .into_par_iter()
        .with_min_len(GRAIN)
        .map(|k| {
            if fixed_point(k) {
                return SMatrix::<f64, M, 3>::zeros();
            }
            let (_, ik) = lay.of(p, obs[k].camera);
            let mut wi = e.j_intr[k].tr_mul(&e.j_point[k]);
            wi.component_mul_assign(
                &(s_cam.fixed_rows::<M>(ik) * s_point[obs[k].point].transpose()),
            );
            wi
        })
        .collect();
    (w_pose, w_intr)
}

/// The LM diagonal: the diagonals of `JᵀJ` clamped to `[lo, hi]`.
pub(super) fn clamped_diagonals<const M: usize>(
    lay: &Layout,
    n: &Normal<M>,
    lo: f64,
    hi: f64,
) -> (DVector<f64>, Vec<Vector3<f64>>) {
    let clamp = |x: f64| x.clamp(lo, hi);
    let poses: Vec<Vec6> = n.u_pose.iter().map(|b| b.diagonal().map(clamp)).collect();
    let intr: Vec<SVector<f64, M>> = n.u_intr.iter().map(|b| b.diagonal().map(clamp)).collect();
    (
        flat(lay, &poses, &intr),
        n.v.iter().map(|b| b.diagonal().map(clamp)).collect(),
    )
}

/// `(JᵀJ)_cameras · x` plus the damping `D/Δ · x`, without the points' part.
pub(super) fn camera_block_product<const M: usize>(
    p: &Problem<M>,
    lay: &Layout,
    n: &Normal<M>,
    damping: &DVector<f64>,
    x: &DVector<f64>,
) -> DVector<f64> {
    let mut y = damping.component_mul(x);
    for i in 0..p.poses.len() {
        let (pi, gi) = lay.of(p, i);
        let (xp, xg) = (
            x.fixed_rows::<6>(pi).into_owned(),
            x.fixed_rows::<M>(gi).into_owned(),
        );
        let mut yp = y.fixed_rows_mut::<6>(pi);
        yp += n.u_pose[i] * xp + n.u_pose_intr[i] * xg;
        let mut yg = y.fixed_rows_mut::<M>(gi);
        yg += n.u_pose_intr[i].transpose() * xp;
    }
    for (g, &o) in lay.intr.iter().enumerate() {
        let xg = x.fixed_rows::<M>(o).into_owned();
        let mut yg = y.fixed_rows_mut::<M>(o);
        yg += n.u_intr[g] * xg;
    }
    y
}

/// The reduced camera system `S y = b` of the damped normal equations, the points eliminated
/// through their inverted damped blocks `v_inv`.
pub(super) fn reduced_system<const M: usize>(
    p: &Problem<M>,
    st: &Structure,
    lay: &Layout,
    n: &Normal<M>,
    d_cam: &DVector<f64>,
    v_inv: &[Matrix3<f64>],
    radius: f64,
) -> (DMatrix<f64>, DVector<f64>) {
    let obs = &p.observations;
    let dim = lay.dim;
    // Σ W V⁻¹ Wᵀ and Σ W V⁻¹ g, accumulated point by point in parallel.
    let (s_minus, b_plus) = fold_in_order(
        st.coupling(),
        point_chunk(p.points.len(), p.observations.len()),
        || (DMatrix::<f64>::zeros(dim, dim), DVector::<f64>::zeros(dim)),
        |(mut s, mut b), (j, ks)| {
            let vi = &v_inv[j];
            let wv: Vec<(Mat63, SMatrix<f64, M, 3>)> = ks
                .iter()
                .map(|&k| (n.w_pose[k] * vi, n.wi(k) * vi))
                .collect();
            for (&ka, (wpa, wia)) in ks.iter().zip(&wv) {
                let (pa, ia) = lay.of(p, obs[ka].camera);
                let mut rows = b.fixed_rows_mut::<6>(pa);
                rows += wpa * n.g_point[j];
                let mut rows = b.fixed_rows_mut::<M>(ia);
                rows += wia * n.g_point[j];
                // The lower triangle only (blocks on or below the diagonal): S is
                // symmetric, mirrored once at the end.
                for &kb in ks {
                    let (pb, ib) = lay.of(p, obs[kb].camera);
                    let (wp, wi) = (n.w_pose[kb].transpose(), n.wi(kb).transpose());
                    if pa >= pb {
                        let mut view = s.fixed_view_mut::<6, 6>(pa, pb);
                        view += wpa * wp;
                    }
                    if pa >= ib {
                        let mut view = s.fixed_view_mut::<6, M>(pa, ib);
                        view += wpa * wi;
                    }
                    if ia >= pb {
                        let mut view = s.fixed_view_mut::<M, 6>(ia, pb);
                        view += wia * wp;
                    }
                    if ia >= ib {
                        let mut view = s.fixed_view_mut::<M, M>(ia, ib);
                        view += wia * wi;
                    }
                }
            }
            (s, b)
        },
        |(s1, b1), (s2, b2)| (s1 + s2, b1 + b2),
    );
    let mut s = -s_minus;
    s.fill_upper_triangle_with_lower_triangle();
    for i in 0..p.poses.len() {
        let (pi, gi) = lay.of(p, i);
        let mut view = s.fixed_view_mut::<6, 6>(pi, pi);
        view += n.u_pose[i];
        let mut view = s.fixed_view_mut::<6, M>(pi, gi);
        view += n.u_pose_intr[i];
        let mut view = s.fixed_view_mut::<M, 6>(gi, pi);
        view += n.u_pose_intr[i].transpose();
    }
    for (g, &o) in lay.intr.iter().enumerate() {
        let mut view = s.fixed_view_mut::<M, M>(o, o);
        view += n.u_intr[g];
    }
    for (k, d) in d_cam.iter().enumerate() {
        s[(k, k)] += d / radius;
    }
    (s, b_plus - &n.g_cam)
}

/// The points' damped blocks, inverted; `None` when one is singular.
pub(super) fn point_inverses<const M: usize>(
    n: &Normal<M>,
    d_point: &[Vector3<f64>],
    radius: f64,
) -> Option<Vec<Matrix3<f64>>> {
    n.v.par_iter()
        .with_min_len(grain(n.v.len(), n.observations))
        .zip(d_point)
        .map(|(v, d)| (v + Matrix3::from_diagonal(&(d / radius))).try_inverse())
        .collect()
}

/// Adds a point's `Σ_a Σ_b W_a V⁻¹ W_bᵀ` to the preconditioner's blocks, restricted to each
/// unit: every pair of its observations whose parameter blocks share a unit (one image's pose
/// and own intrinsics; a shared camera's intrinsics seen from two images) adds its block there.
pub(super) fn add_unit_blocks<const M: usize>(
    p: &Problem<M>,
    lay: &Layout,
    n: &Normal<M>,
    ks: &[usize],
    vi: &Matrix3<f64>,
    acc: &mut [DMatrix<f64>],
) {
    // Per observation: (unit, offset in it) of its pose and of its intrinsics.
    let at: Vec<((usize, usize), (usize, usize))> = ks
        .iter()
        .map(|&k| {
            let i = p.observations[k].camera;
            let (pi, gi) = lay.of(p, i);
            let (up, ug) = (lay.pose_unit[i], lay.intr_unit[p.intrinsics_of[i]]);
            ((up, pi - lay.units[up].0), (ug, gi - lay.units[ug].0))
        })
        .collect();
    for (&ka, &((upa, lpa), (uga, lga))) in ks.iter().zip(&at) {
        let (wpa, wia) = (n.w_pose[ka] * vi, n.wi(ka) * vi);
        for (&kb, &((upb, lpb), (ugb, lgb))) in ks.iter().zip(&at) {
            let (wpb, wib) = (n.w_pose[kb].transpose(), n.wi(kb).transpose());
            if upa == upb {
                let mut view = acc[upa].fixed_view_mut::<6, 6>(lpa, lpb);
                view += wpa * wpb;
            }
            if upa == ugb {
                let mut view = acc[upa].fixed_view_mut::<6, M>(lpa, lgb);
                view += wpa * wib;
            }
            if uga == upb {
                let mut view = acc[uga].fixed_view_mut::<M, 6>(lga, lpb);
                view += wia * wpb;
            }
            if uga == ugb {
                let mut view = acc[uga].fixed_view_mut::<M, M>(lga, lgb);
                view += wia * wib;
            }
        }
    }
}

/// Solves the damped system by eliminating the points; `None` when the reduced camera system is
/// not positive definite. Returns the scaled step (camera side, points).
#[allow(clippy::too_many_arguments)]
pub(super) fn schur_step<const M: usize>(
    p: &Problem<M>,
    st: &Structure,
    lay: &Layout,
    n: &Normal<M>,
    d_cam: &DVector<f64>,
    d_point: &[Vector3<f64>],
    radius: f64,
    (solver, tolerance): (LinearSolver, f64),
) -> Option<(DVector<f64>, Vec<Vector3<f64>>)> {
    let obs = &p.observations;
    let dense = match solver {
        LinearSolver::Auto => p.poses.len() <= DENSE_MAX_IMAGES,
        LinearSolver::DenseSchur => true,
        LinearSolver::IterativeSchur => false,
    };
    let (y_cam, v_inv) = if dense {
        let v_inv = point_inverses(n, d_point, radius)?;
        let (s, b) = reduced_system(p, st, lay, n, d_cam, &v_inv, radius);
        let y = match Arrow::of(st, lay, &s) {
            Some(arrow) => arrow.solve(&b),
            None => s.cholesky()?.solve(&b),
        };
        if !y.iter().all(|v| v.is_finite()) {
            return None;
        }
        (y, v_inv)
    } else {
        let v_inv = point_inverses(n, d_point, radius)?;
        (
            iterative_reduced_solve(p, st, lay, n, &(d_cam / radius), &v_inv, tolerance)?,
            v_inv,
        )
    };
    let y_point = st
        .coupling()
        .par_iter()
        .with_min_len(grain(p.points.len(), p.observations.len()))
        .enumerate()
        .map(|(j, ks)| {
            let mut r = -n.g_point[j];
            for &k in ks {
                let (pk, ik) = lay.of(p, obs[k].camera);
                r -= n.w_pose[k].transpose() * y_cam.fixed_rows::<6>(pk)
                    + n.wi(k).transpose() * y_cam.fixed_rows::<M>(ik);
            }
            v_inv[j] * r
        })
        .collect();
    Some((y_cam, y_point))
}

/// The reduced camera system when no point couples two images (every point fixed, as a
/// calibration board's): block-diagonal over the images' units but for their rows of the
/// shared intrinsics, which come last. Each unit is eliminated in turn and the shared
/// intrinsics come from their Schur complement: the cost grows with the images, not with their
/// cube.
pub(super) struct Arrow {
    tail: usize,
    /// Per unit: its offset, `A⁻¹` and `A⁻¹ B` (`A` its block, `B` its coupling to the tail).
    units: Vec<(usize, DMatrix<f64>, DMatrix<f64>)>,
    /// `B`s, per unit, for the right-hand sides.
    couplings: Vec<DMatrix<f64>>,
    /// The Cholesky factor of the tail's Schur complement `C − Σ Bᵀ A⁻¹ B`.
    complement: nalgebra::Cholesky<f64, nalgebra::Dyn>,
}

impl Arrow {
    /// `None` where the structure does not hold (a point couples images, or nothing is shared)
    /// or a block is not positive definite (the dense path then decides).
    pub(super) fn of(st: &Structure, lay: &Layout, s: &DMatrix<f64>) -> Option<Arrow> {
        let tail = lay.shared_start;
        let m = lay.dim - tail;
        if tail == 0 || m == 0 || !st.coupling().iter().all(|ks| ks.is_empty()) {
            return None;
        }
        let mut c = s.view((tail, tail), (m, m)).into_owned();
        let mut units = Vec::new();
        let mut couplings = Vec::new();
        for &(o, n) in lay.units.iter().filter(|(o, _)| *o < tail) {
            let a_inv = s.view((o, o), (n, n)).into_owned().cholesky()?.inverse();
            let coupling = s.view((o, tail), (n, m)).into_owned();
            let x = &a_inv * &coupling;
            c.gemm_tr(-1.0, &coupling, &x, 1.0);
            units.push((o, a_inv, x));
            couplings.push(coupling);
        }
        Some(Arrow {
            tail,
            units,
            couplings,
            complement: c.cholesky()?,
        })
    }

    pub(super) fn solve(&self, b: &DVector<f64>) -> DVector<f64> {
        let m = b.len() - self.tail;
        let mut rhs = b.rows(self.tail, m).into_owned();
        for ((o, a_inv, _), coupling) in self.units.iter().zip(&self.couplings) {
            let a_inv_b = a_inv * b.rows(*o, a_inv.nrows());
            rhs.gemv_tr(-1.0, coupling, &a_inv_b, 1.0);
        }
        let y_tail = self.complement.solve(&rhs);
        let mut y = DVector::zeros(b.len());
        for (o, a_inv, x) in &self.units {
            let yu = a_inv * b.rows(*o, a_inv.nrows()) - x * &y_tail;
            y.rows_mut(*o, yu.len()).copy_from(&yu);
        }
        y.rows_mut(self.tail, m).copy_from(&y_tail);
        y
    }

    /// The whole inverse: `Σ_tt = S_c⁻¹`, `Σ_ut = −X_u Σ_tt`, `Σ_uv = δ_uv A_u⁻¹ + X_u Σ_tt X_vᵀ`
    /// with `X_u = A_u⁻¹ B_u`.
    pub(super) fn inverse(&self, dim: usize) -> DMatrix<f64> {
        let m = dim - self.tail;
        let tt = self.complement.inverse();
        let mut inv = DMatrix::zeros(dim, dim);
        let xs: Vec<DMatrix<f64>> = self.units.iter().map(|(_, _, x)| x * &tt).collect();
        for ((o, a_inv, _), x_tt) in self.units.iter().zip(&xs) {
            let n = a_inv.nrows();
            inv.view_mut((*o, self.tail), (n, m)).copy_from(&(-x_tt));
            inv.view_mut((self.tail, *o), (m, n))
                .copy_from(&(-x_tt.transpose()));
            for (o2, _, x2) in &self.units {
                let block = x_tt * x2.transpose();
                inv.view_mut((*o, *o2), (n, x2.nrows())).copy_from(&block);
            }
            let mut diag = inv.view_mut((*o, *o), (n, n));
            diag += a_inv;
        }
        inv.view_mut((self.tail, self.tail), (m, m)).copy_from(&tt);
        inv
    }
}
