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
    /// Per observation: `Jposeᵀ Jpoint` and `Jintrᵀ Jpoint`.
    pub(super) w_pose: Vec<Mat63>,
    pub(super) w_intr: Vec<SMatrix<f64, M, 3>>,
    /// The camera side's gradient, in [`Layout`] order.
    pub(super) g_cam: DVector<f64>,
    pub(super) g_point: Vec<Vector3<f64>>,
}

/// Per group of observations (an image's, a point's): `Σ JᵀJ` and `Σ Jᵀr`, `jac(k)` the
/// observation's Jacobian with respect to the group's parameters.
pub(super) fn normal_blocks<const N: usize>(
    groups: &[Vec<usize>],
    jac: impl Fn(usize) -> SMatrix<f64, 2, N> + Sync,
    residuals: &[Vector2<f64>],
) -> (Vec<SMatrix<f64, N, N>>, Vec<SVector<f64, N>>) {
    groups
        .par_iter()
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
}

impl Structure {
    pub(super) fn new<const M: usize>(p: &Problem<M>) -> Structure {
        let mut st = Structure {
            by_image: vec![Vec::new(); p.poses.len()],
            by_camera: vec![Vec::new(); p.intrinsics.len()],
            by_point: vec![Vec::new(); p.points.len()],
        };
        for (k, o) in p.observations.iter().enumerate() {
            st.by_image[o.camera].push(k);
            st.by_camera[p.intrinsics_of[o.camera]].push(k);
            st.by_point[o.point].push(k);
        }
        st
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
    let jc = |k: usize| {
        let s = s_cam.fixed_rows::<6>(lay.pose[obs[k].camera]).into_owned();
        scale_columns(e.j_pose[k], &s)
    };
    let ji = |k: usize| {
        let s = s_cam
            .fixed_rows::<M>(lay.of(p, obs[k].camera).1)
            .into_owned();
        scale_columns(e.j_intr[k], &s)
    };
    let jp = |k: usize| scale_columns(e.j_point[k], &s_point[obs[k].point]);
    let per_image: Vec<(Mat6, SMatrix<f64, 6, M>, Vec6)> = st
        .by_image
        .par_iter()
        .map(|ks| {
            let mut u = Mat6::zeros();
            let mut ui = SMatrix::<f64, 6, M>::zeros();
            let mut g = Vec6::zeros();
            for &k in ks {
                let (a, b) = (jc(k), ji(k));
                u += a.transpose() * a;
                ui += a.transpose() * b;
                g += a.transpose() * e.residuals[k];
            }
            (u, ui, g)
        })
        .collect();
    let mut u_pose: Vec<Mat6> = per_image.iter().map(|x| x.0).collect();
    let u_pose_intr = per_image.iter().map(|x| x.1).collect();
    let mut g_pose: Vec<Vec6> = per_image.iter().map(|x| x.2).collect();
    let (u_intr, g_intr) = normal_blocks(&st.by_camera, ji, &e.residuals);
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
    let (w_pose, w_intr) = (0..obs.len())
        .into_par_iter()
        .map(|k| {
            let b = jp(k);
            (jc(k).transpose() * b, ji(k).transpose() * b)
        })
        .unzip();
    Normal {
        u_pose,
        u_pose_intr,
        u_intr,
        v,
        w_pose,
        w_intr,
        g_cam: flat(lay, &g_pose, &g_intr),
        g_point,
    }
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
    let (s_minus, b_plus) = st
        .by_point
        .par_iter()
        .enumerate()
        .fold(
            || (DMatrix::<f64>::zeros(dim, dim), DVector::<f64>::zeros(dim)),
            |(mut s, mut b), (j, ks)| {
                let vi = &v_inv[j];
                let wv: Vec<(Mat63, SMatrix<f64, M, 3>)> = ks
                    .iter()
                    .map(|&k| (n.w_pose[k] * vi, n.w_intr[k] * vi))
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
                        let (wp, wi) = (n.w_pose[kb].transpose(), n.w_intr[kb].transpose());
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
        )
        .reduce(
            || (DMatrix::<f64>::zeros(dim, dim), DVector::<f64>::zeros(dim)),
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
        let (wpa, wia) = (n.w_pose[ka] * vi, n.w_intr[ka] * vi);
        for (&kb, &((upb, lpb), (ugb, lgb))) in ks.iter().zip(&at) {
            let (wpb, wib) = (n.w_pose[kb].transpose(), n.w_intr[kb].transpose());
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
        let y = s.cholesky()?.solve(&b);
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
        .by_point
        .par_iter()
        .enumerate()
        .map(|(j, ks)| {
            let mut r = -n.g_point[j];
            for &k in ks {
                let (pk, ik) = lay.of(p, obs[k].camera);
                r -= n.w_pose[k].transpose() * y_cam.fixed_rows::<6>(pk)
                    + n.w_intr[k].transpose() * y_cam.fixed_rows::<M>(ik);
            }
            v_inv[j] * r
        })
        .collect();
    Some((y_cam, y_point))
}
