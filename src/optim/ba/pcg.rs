//! The reduced camera system solved by preconditioned conjugate gradients (many images).

use super::*;

/// Solves `S y = b` by conjugate gradients without forming `S = U − W V⁻¹ Wᵀ`: each product
/// goes through the observations, point by point; the preconditioner is `S`'s diagonal blocks
/// (a pose with its own intrinsics, a pose, shared intrinsics). Stops when the residual falls
/// below `tolerance` of `b` (or after as many steps as unknowns).
pub(super) fn iterative_reduced_solve<const M: usize>(
    p: &Problem<M>,
    st: &Structure,
    lay: &Layout,
    n: &Normal<M>,
    damping: &DVector<f64>,
    v_inv: &[Matrix3<f64>],
    tolerance: f64,
) -> Option<DVector<f64>> {
    let obs = &p.observations;
    let dim = lay.dim;
    // b = −g_c + Σ W V⁻¹ g_p, and the Schur part of the preconditioner's blocks.
    let zero = || {
        (
            DVector::<f64>::zeros(dim),
            lay.units
                .iter()
                .map(|&(_, m)| DMatrix::<f64>::zeros(m, m))
                .collect::<Vec<_>>(),
        )
    };
    let (b_plus, schur) = fold_in_order(
        st.coupling(),
        point_chunk(p.points.len(), p.observations.len()),
        zero,
        |(mut b, mut blocks), (j, ks)| {
            let t = v_inv[j] * n.g_point[j];
            for &k in ks {
                let (pk, ik) = lay.of(p, obs[k].camera);
                let mut rows = b.fixed_rows_mut::<6>(pk);
                rows += n.w_pose[k] * t;
                let mut rows = b.fixed_rows_mut::<M>(ik);
                rows += n.wi(k) * t;
            }
            add_unit_blocks(p, lay, n, ks, &v_inv[j], &mut blocks);
            (b, blocks)
        },
        |(b1, mut m1), (b2, m2)| {
            for (x, y) in m1.iter_mut().zip(m2) {
                *x += y;
            }
            (b1 + b2, m1)
        },
    );
    let b = b_plus - &n.g_cam;
    // The camera blocks' own part of each unit: JᵀJ + D/Δ restricted to it.
    let mut own: Vec<DMatrix<f64>> = lay
        .units
        .iter()
        .map(|&(start, size)| DMatrix::from_diagonal(&damping.rows(start, size)))
        .collect();
    let local = |unit: usize, offset: usize| offset - lay.units[unit].0;
    for i in 0..p.poses.len() {
        let (pi, gi) = lay.of(p, i);
        let (up, ug) = (lay.pose_unit[i], lay.intr_unit[p.intrinsics_of[i]]);
        let lp = local(up, pi);
        let mut view = own[up].fixed_view_mut::<6, 6>(lp, lp);
        view += n.u_pose[i];
        if ug == up {
            let lg = local(up, gi);
            let mut view = own[up].fixed_view_mut::<6, M>(lp, lg);
            view += n.u_pose_intr[i];
            let mut view = own[up].fixed_view_mut::<M, 6>(lg, lp);
            view += n.u_pose_intr[i].transpose();
        }
    }
    for (g, &o) in lay.intr.iter().enumerate() {
        let u = lay.intr_unit[g];
        let lg = local(u, o);
        let mut view = own[u].fixed_view_mut::<M, M>(lg, lg);
        view += n.u_intr[g];
    }
    let precond: Vec<DMatrix<f64>> = own
        .into_par_iter()
        .zip(schur)
        .map(|(a, b)| (a - b).cholesky().map(|c| c.inverse()))
        .collect::<Option<_>>()?;
    let preconditioned = |r: &DVector<f64>| {
        let mut z = DVector::zeros(dim);
        for (&(start, size), m) in lay.units.iter().zip(&precond) {
            z.rows_mut(start, size)
                .copy_from(&(m * r.rows(start, size)));
        }
        z
    };
    let apply = |x: &DVector<f64>| -> DVector<f64> {
        let minus = fold_in_order(
            st.coupling(),
            point_chunk(p.points.len(), p.observations.len()),
            || DVector::<f64>::zeros(dim),
            |mut acc, (j, ks)| {
                let mut t = Vector3::zeros();
                for &k in ks {
                    let (pk, ik) = lay.of(p, obs[k].camera);
                    t += n.w_pose[k].transpose() * x.fixed_rows::<6>(pk)
                        + n.wi(k).transpose() * x.fixed_rows::<M>(ik);
                }
                let t = v_inv[j] * t;
                for &k in ks {
                    let (pk, ik) = lay.of(p, obs[k].camera);
                    let mut rows = acc.fixed_rows_mut::<6>(pk);
                    rows += n.w_pose[k] * t;
                    let mut rows = acc.fixed_rows_mut::<M>(ik);
                    rows += n.wi(k) * t;
                }
                acc
            },
            |a, b| a + b,
        );
        camera_block_product(p, lay, n, damping, x) - minus
    };
    let mut x = DVector::zeros(dim);
    let mut r = b.clone();
    let mut z = preconditioned(&r);
    let mut d = z.clone();
    let mut rz = r.dot(&z);
    let b_norm = b.norm();
    for _ in 0..dim {
        if r.norm() <= tolerance * b_norm {
            break;
        }
        let q = apply(&d);
        let dq = d.dot(&q);
        if !(dq > 0.0) {
            return None;
        }
        let alpha = rz / dq;
        x.axpy(alpha, &d, 1.0);
        r.axpy(-alpha, &q, 1.0);
        z = preconditioned(&r);
        let rz_new = r.dot(&z);
        let beta = rz_new / rz;
        rz = rz_new;
        d = &z + beta * d;
    }
    x.iter().all(|c| c.is_finite()).then_some(x)
}
