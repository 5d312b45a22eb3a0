//! Plane-to-image homographies: normalised DLT (Hartley) and geometric-error refinement.

use levenberg_marquardt::{LeastSquaresProblem, LevenbergMarquardt};
use nalgebra::{DMatrix, Dyn, Matrix3, OMatrix, OVector, Owned, U8, Vector2, Vector3};

use super::EstimateError;
use super::ransac::{Estimator, RansacResult, RansacSettings, msac};

/// A similarity that moves the centroid to the origin and the mean distance to √2.
fn normalizer(pts: &[Vector2<f64>]) -> Result<Matrix3<f64>, EstimateError> {
    let n = pts.len() as f64;
    let c = pts.iter().fold(Vector2::zeros(), |a, p| a + p) / n;
    let mean_dist = pts.iter().map(|p| (p - c).norm()).sum::<f64>() / n;
    if !(mean_dist > 0.0) || !mean_dist.is_finite() {
        return Err(EstimateError::Degenerate("all points coincide".into()));
    }
    let s = std::f64::consts::SQRT_2 / mean_dist;
    Ok(Matrix3::new(
        s,
        0.0,
        -s * c.x,
        0.0,
        s,
        -s * c.y,
        0.0,
        0.0,
        1.0,
    ))
}

fn apply(h: &Matrix3<f64>, p: &Vector2<f64>) -> Vector2<f64> {
    let q = h * Vector3::new(p.x, p.y, 1.0);
    Vector2::new(q.x / q.z, q.y / q.z)
}

/// Homography `dst ~ H · src` by the normalised direct linear transform (n ≥ 4). Scaled so that
/// `H[(2, 2)] = 1` when possible, otherwise to unit Frobenius norm.
pub fn homography_dlt(
    src: &[Vector2<f64>],
    dst: &[Vector2<f64>],
) -> Result<Matrix3<f64>, EstimateError> {
    assert_eq!(src.len(), dst.len(), "src and dst must pair up");
    if src.len() < 4 {
        return Err(EstimateError::TooFewPoints {
            needed: 4,
            got: src.len(),
        });
    }
    let (ts, td) = (normalizer(src)?, normalizer(dst)?);
    let mut a = DMatrix::<f64>::zeros(2 * src.len(), 9);
    for (i, (s, d)) in src.iter().zip(dst).enumerate() {
        let s = apply(&ts, s);
        let d = apply(&td, d);
        let (x, y, u, v) = (s.x, s.y, d.x, d.y);
        a.row_mut(2 * i)
            .copy_from_slice(&[-x, -y, -1.0, 0.0, 0.0, 0.0, u * x, u * y, u]);
        a.row_mut(2 * i + 1)
            .copy_from_slice(&[0.0, 0.0, 0.0, -x, -y, -1.0, v * x, v * y, v]);
    }
    // The null vector of A is the eigenvector of AᵀA with the smallest eigenvalue.
    let ata = a.transpose() * &a;
    let eig = ata.symmetric_eigen();
    let mut order: Vec<usize> = (0..9).collect();
    order.sort_by(|&i, &j| eig.eigenvalues[i].total_cmp(&eig.eigenvalues[j]));
    // A second (near-)null vector means the points do not pin the homography down.
    if eig.eigenvalues[order[1]] <= 1e-12 * eig.eigenvalues[order[8]] {
        return Err(EstimateError::Degenerate(
            "the points do not determine a homography (collinear?)".into(),
        ));
    }
    let h = eig.eigenvectors.column(order[0]);
    let hn = Matrix3::new(h[0], h[1], h[2], h[3], h[4], h[5], h[6], h[7], h[8]);
    let td_inv = td
        .try_inverse()
        .ok_or_else(|| EstimateError::Degenerate("normaliser".into()))?;
    let mut hm = td_inv * hn * ts;
    if hm[(2, 2)].abs() > 1e-12 * hm.norm() {
        hm /= hm[(2, 2)];
    } else {
        hm /= hm.norm();
    }
    Ok(hm)
}

/// Geometric reprojection error problem for the levenberg-marquardt crate, with `H[(2,2)] = 1`.
struct HomographyProblem<'a> {
    h: [f64; 8],
    src: &'a [Vector2<f64>],
    dst: &'a [Vector2<f64>],
}

impl HomographyProblem<'_> {
    fn matrix(&self) -> Matrix3<f64> {
        let h = &self.h;
        Matrix3::new(h[0], h[1], h[2], h[3], h[4], h[5], h[6], h[7], 1.0)
    }
}

impl LeastSquaresProblem<f64, Dyn, U8> for HomographyProblem<'_> {
    type ResidualStorage = Owned<f64, Dyn>;
    type JacobianStorage = Owned<f64, Dyn, U8>;
    type ParameterStorage = Owned<f64, U8>;

    fn set_params(&mut self, x: &OVector<f64, U8>) {
        self.h.copy_from_slice(x.as_slice());
    }

    fn params(&self) -> OVector<f64, U8> {
        OVector::<f64, U8>::from_row_slice(&self.h)
    }

    fn residuals(&self) -> Option<OVector<f64, Dyn>> {
        let h = self.matrix();
        let mut r = OVector::<f64, Dyn>::zeros(2 * self.src.len());
        for (i, (s, d)) in self.src.iter().zip(self.dst).enumerate() {
            let p = apply(&h, s);
            r[2 * i] = p.x - d.x;
            r[2 * i + 1] = p.y - d.y;
        }
        Some(r)
    }

    fn jacobian(&self) -> Option<OMatrix<f64, Dyn, U8>> {
        let h = self.matrix();
        let mut j = OMatrix::<f64, Dyn, U8>::zeros(2 * self.src.len());
        for (i, s) in self.src.iter().enumerate() {
            let q = h * Vector3::new(s.x, s.y, 1.0);
            let (u, v, w) = (q.x / q.z, q.y / q.z, q.z);
            j.row_mut(2 * i).copy_from_slice(&[
                s.x / w,
                s.y / w,
                1.0 / w,
                0.0,
                0.0,
                0.0,
                -u * s.x / w,
                -u * s.y / w,
            ]);
            j.row_mut(2 * i + 1).copy_from_slice(&[
                0.0,
                0.0,
                0.0,
                s.x / w,
                s.y / w,
                1.0 / w,
                -v * s.x / w,
                -v * s.y / w,
            ]);
        }
        Some(j)
    }
}

/// Homography by DLT, then refined by Levenberg–Marquardt on the reprojection error in `dst`.
pub fn homography_refined(
    src: &[Vector2<f64>],
    dst: &[Vector2<f64>],
) -> Result<Matrix3<f64>, EstimateError> {
    let h0 = homography_dlt(src, dst)?;
    if h0[(2, 2)] != 1.0 {
        return Ok(h0);
    }
    let problem = HomographyProblem {
        h: [
            h0[(0, 0)],
            h0[(0, 1)],
            h0[(0, 2)],
            h0[(1, 0)],
            h0[(1, 1)],
            h0[(1, 2)],
            h0[(2, 0)],
            h0[(2, 1)],
        ],
        src,
        dst,
    };
    // 1e-10 relative on the cost and the entries: far below a pixel's thousandth, and fewer
    // iterations than the crate's default of 30 machine epsilons.
    let (solved, report) = LevenbergMarquardt::new().with_tol(1e-10).minimize(problem);
    if !report.termination.was_successful() || !report.objective_function.is_finite() {
        return Ok(h0);
    }
    Ok(solved.matrix())
}

/// Applies a homography to a point; `None` at or beyond the line at infinity.
pub fn transfer(h: &Matrix3<f64>, p: &Vector2<f64>) -> Option<Vector2<f64>> {
    let q = h * Vector3::new(p.x, p.y, 1.0);
    (q.z.abs() > 1e-12 * (q.x.abs() + q.y.abs() + 1e-300))
        .then(|| Vector2::new(q.x / q.z, q.y / q.z))
}

/// Whether three points are (nearly) collinear relative to their spread.
fn collinear2(a: &Vector2<f64>, b: &Vector2<f64>, c: &Vector2<f64>) -> bool {
    let (ab, ac) = (b - a, c - a);
    let scale = ab
        .norm_squared()
        .max(ac.norm_squared())
        .max((c - b).norm_squared());
    let cross = ab.x * ac.y - ab.y * ac.x;
    scale == 0.0 || cross * cross < 1e-8 * scale * scale
}

/// Homography as an MSAC problem; residuals are transfer errors in `dst` (pixels).
pub struct HomographyEstimator<'a> {
    pub src: &'a [Vector2<f64>],
    pub dst: &'a [Vector2<f64>],
}

impl Estimator for HomographyEstimator<'_> {
    type Model = Matrix3<f64>;

    fn sample_size(&self) -> usize {
        4
    }

    fn len(&self) -> usize {
        self.src.len()
    }

    fn is_degenerate(&self, s: &[usize]) -> bool {
        [[0, 1, 2], [0, 1, 3], [0, 2, 3], [1, 2, 3]]
            .iter()
            .any(|t| {
                collinear2(&self.src[s[t[0]]], &self.src[s[t[1]]], &self.src[s[t[2]]])
                    || collinear2(&self.dst[s[t[0]]], &self.dst[s[t[1]]], &self.dst[s[t[2]]])
            })
    }

    fn fit_minimal(&self, s: &[usize]) -> Vec<Matrix3<f64>> {
        let src: Vec<_> = s.iter().map(|&i| self.src[i]).collect();
        let dst: Vec<_> = s.iter().map(|&i| self.dst[i]).collect();
        homography_dlt(&src, &dst).into_iter().collect()
    }

    fn fit_nonminimal(&self, data: &[usize], _start: &Matrix3<f64>) -> Option<Matrix3<f64>> {
        let src: Vec<_> = data.iter().map(|&i| self.src[i]).collect();
        let dst: Vec<_> = data.iter().map(|&i| self.dst[i]).collect();
        homography_dlt(&src, &dst).ok()
    }

    fn residual_sq(&self, h: &Matrix3<f64>, i: usize) -> f64 {
        transfer(h, &self.src[i]).map_or(f64::INFINITY, |p| (p - self.dst[i]).norm_squared())
    }
}

/// Robust homography: MSAC over 4-point samples, then least squares on the geometric error of
/// the inliers. The inliers are those of the refined homography.
pub fn homography_robust(
    src: &[Vector2<f64>],
    dst: &[Vector2<f64>],
    settings: &RansacSettings,
) -> Result<RansacResult<Matrix3<f64>>, EstimateError> {
    assert_eq!(src.len(), dst.len(), "src and dst must pair up");
    let est = HomographyEstimator { src, dst };
    let mut result = msac(&est, settings)?;
    let idx: Vec<usize> = (0..src.len()).filter(|&i| result.inliers[i]).collect();
    let (s, d): (Vec<_>, Vec<_>) = idx.iter().map(|&i| (src[i], dst[i])).unzip();
    if let Ok(h) = homography_refined(&s, &d) {
        let t2 = settings.threshold * settings.threshold;
        result.inliers = (0..src.len())
            .map(|i| est.residual_sq(&h, i) < t2)
            .collect();
        result.inlier_count = result.inliers.iter().filter(|&&b| b).count();
        result.model = h;
    }
    Ok(result)
}

/// The motions `cam2_from_cam1` (unit translation) a calibrated homography `x₂ ~ H x₁` of a
/// plane can come from: `H ∝ R + t nᵀ / d` for the plane `nᵀX = d` of camera 1. Up to eight
/// (Faugeras' decomposition of `H = U diag(d₁, d₂, d₃) Vᵀ`: two signs of `d₂`, four of the
/// normal's two components); the points in front of both cameras choose among them. One pure
/// rotation (no translation) when the three singular values agree.
pub fn poses_of_homography(h: &Matrix3<f64>) -> Vec<crate::geom::Rigid3> {
    use crate::geom::Rigid3;
    use nalgebra::{Rotation3, Vector3 as V3};
    let svd = h.svd(true, true);
    let (Some(u), Some(vt)) = (svd.u, svd.v_t) else {
        return Vec::new();
    };
    // In decreasing order.
    let mut order = [0, 1, 2];
    order.sort_by(|&a, &b| svd.singular_values[b].total_cmp(&svd.singular_values[a]));
    let u = Matrix3::from_columns(&order.map(|k| u.column(k).into_owned()));
    let vt = Matrix3::from_rows(&order.map(|k| vt.row(k).into_owned()));
    let [d1, d2, d3] = order.map(|k| svd.singular_values[k]);
    if !(d3 > 0.0 && d1.is_finite()) {
        return Vec::new();
    }
    let s = u.determinant() * vt.determinant();
    let proper = |m: Matrix3<f64>| Rotation3::from_matrix(&(s * u * m * vt));
    if d1 - d3 < 1e-9 * d2 {
        return vec![Rigid3 {
            rotation: proper(Matrix3::identity()),
            translation: V3::zeros(),
        }];
    }
    let (a, c) = (d1 * d1 - d2 * d2, d2 * d2 - d3 * d3);
    let x1 = (a / (a + c)).sqrt();
    let x3 = (c / (a + c)).sqrt();
    let root = (a * c).sqrt();
    let mut out = Vec::with_capacity(8);
    for (e1, e3) in [(1.0, 1.0), (1.0, -1.0), (-1.0, 1.0), (-1.0, -1.0)] {
        // d' = +d₂: a rotation about the second axis, the translation in the first and third.
        let (st, ct) = (
            e1 * e3 * root / ((d1 + d3) * d2),
            (d2 * d2 + d1 * d3) / ((d1 + d3) * d2),
        );
        let r = Matrix3::new(ct, 0.0, -st, 0.0, 1.0, 0.0, st, 0.0, ct);
        let t = u * V3::new(e1 * x1, 0.0, -e3 * x3) * (d1 - d3);
        out.push((r, t));
        // d' = −d₂: a reflection through the second axis composed with a rotation.
        let (sp, cp) = (
            e1 * e3 * root / ((d1 - d3) * d2),
            (d1 * d3 - d2 * d2) / ((d1 - d3) * d2),
        );
        let r = Matrix3::new(cp, 0.0, sp, 0.0, -1.0, 0.0, sp, 0.0, -cp);
        let t = u * V3::new(e1 * x1, 0.0, e3 * x3) * (d1 + d3);
        out.push((r, t));
    }
    out.into_iter()
        .filter_map(|(r, t)| {
            let t = t.try_normalize(1e-12)?;
            Some(Rigid3 {
                rotation: proper(r),
                translation: t,
            })
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    fn grid() -> Vec<Vector2<f64>> {
        (0..6)
            .flat_map(|r| (0..9).map(move |c| Vector2::new(c as f64 * 0.025, r as f64 * 0.025)))
            .collect()
    }

    #[test]
    fn recovers_an_exact_homography() {
        let h = Matrix3::new(900.0, 40.0, 120.0, -30.0, 870.0, 200.0, 0.2, -0.1, 1.0);
        let src = grid();
        let dst: Vec<_> = src.iter().map(|p| apply(&h, p)).collect();
        for est in [
            homography_dlt(&src, &dst).unwrap(),
            homography_refined(&src, &dst).unwrap(),
        ] {
            assert!((est - h).norm() < 1e-6 * h.norm(), "{est}");
        }
    }

    #[test]
    fn refinement_lowers_the_geometric_error() {
        let h = Matrix3::new(900.0, 40.0, 120.0, -30.0, 870.0, 200.0, 0.9, -0.6, 1.0);
        let src = grid();
        // Deterministic pseudo-noise of about a pixel.
        let dst: Vec<_> = src
            .iter()
            .enumerate()
            .map(|(i, p)| {
                apply(&h, p)
                    + Vector2::new(
                        ((i * 37) % 11) as f64 / 5.0 - 1.0,
                        ((i * 53) % 7) as f64 / 3.0 - 1.0,
                    )
            })
            .collect();
        let err = |m: &Matrix3<f64>| -> f64 {
            src.iter()
                .zip(&dst)
                .map(|(s, d)| (apply(m, s) - d).norm_squared())
                .sum()
        };
        let a = homography_dlt(&src, &dst).unwrap();
        let b = homography_refined(&src, &dst).unwrap();
        assert!(err(&b) <= err(&a) + 1e-9, "{} > {}", err(&b), err(&a));
    }

    #[test]
    fn refinement_jacobian_matches_finite_differences() {
        let src = grid();
        let dst = src.clone();
        let h = [900.0, 40.0, 120.0, -30.0, 870.0, 200.0, 0.9, -0.6];
        let mut p = HomographyProblem {
            h,
            src: &src,
            dst: &dst,
        };
        let j = p.jacobian().unwrap();
        for k in 0..8 {
            let step = 1e-6 * (1.0 + h[k].abs());
            let mut hp = h;
            hp[k] += step;
            p.set_params(&OVector::<f64, U8>::from_row_slice(&hp));
            let rp = p.residuals().unwrap();
            hp[k] -= 2.0 * step;
            p.set_params(&OVector::<f64, U8>::from_row_slice(&hp));
            let rm = p.residuals().unwrap();
            let fd = (rp - rm) / (2.0 * step);
            let err = (&fd - j.column(k)).amax();
            assert!(err < 1e-6 * (1.0 + fd.amax()), "column {k}: {err}");
        }
    }

    #[test]
    fn robust_fit_ignores_outliers() {
        let h = Matrix3::new(1.01, 0.02, 12.0, -0.015, 0.99, -7.0, 1e-6, -2e-6, 1.0);
        let src: Vec<_> = (0..200)
            .map(|i| Vector2::new(((i * 97) % 1900) as f64, ((i * 61) % 1070) as f64))
            .collect();
        let mut dst: Vec<_> = src.iter().map(|p| apply(&h, p)).collect();
        for (i, d) in dst.iter_mut().enumerate().take(60) {
            *d += Vector2::new(20.0 + i as f64, -15.0);
        }
        let r = homography_robust(
            &src,
            &dst,
            &RansacSettings {
                threshold: 1.0,
                ..RansacSettings::default()
            },
        )
        .unwrap();
        assert_eq!(r.inlier_count, 140);
        assert!(r.inliers[60..].iter().all(|&b| b));
        for p in &src {
            assert!((transfer(&r.model, p).unwrap() - apply(&h, p)).norm() < 1e-6);
        }
    }

    #[test]
    fn rejects_too_few_and_collinear_points() {
        let src = vec![Vector2::new(0.0, 0.0); 3];
        assert!(matches!(
            homography_dlt(&src, &src),
            Err(EstimateError::TooFewPoints { .. })
        ));
        let line: Vec<_> = (0..6)
            .map(|i| Vector2::new(i as f64, 2.0 * i as f64))
            .collect();
        assert!(homography_dlt(&line, &line).is_err());
    }

    /// A plane seen from two cameras: its homography's decompositions include the motion, and
    /// the points in front of both cameras choose it; a pure rotation gives no translation.
    #[test]
    fn a_plane_s_homography_gives_back_the_motion() {
        use crate::estimate::essential::best_in_front;
        use crate::geom::Rigid3;
        use nalgebra::{Rotation3, Vector3 as V3};
        let n = V3::new(0.1, -0.2, 1.0).normalize();
        let d = 5.0;
        let truth = Rigid3 {
            rotation: Rotation3::from_scaled_axis(V3::new(0.05, -0.1, 0.08)),
            translation: V3::new(0.8, 0.1, -0.2).normalize(),
        };
        let project = |p: V3<f64>| Vector2::new(p.x / p.z, p.y / p.z);
        let mut x1 = Vec::new();
        let mut x2 = Vec::new();
        for i in 0..7 {
            for j in 0..5 {
                let ray = V3::new(-0.3 + 0.1 * f64::from(i), -0.2 + 0.1 * f64::from(j), 1.0);
                let point = ray * (d / n.dot(&ray));
                x1.push(project(point));
                x2.push(project(truth.apply(&point)));
            }
        }
        let h = homography_dlt(&x1, &x2).unwrap();
        let poses = poses_of_homography(&h);
        assert!(poses.len() >= 4, "{}", poses.len());
        let (best, count) = best_in_front(poses, &x1, &x2);
        assert_eq!(count, x1.len());
        // (Compared as matrices: `angle_to` of two equal rotations can be NaN.)
        let off = |a: &Rotation3<f64>, b: &Rotation3<f64>| (a.matrix() - b.matrix()).norm();
        assert!(off(&best.rotation, &truth.rotation) < 1e-8, "{best:?}");
        assert!(
            (best.translation - truth.translation).norm() < 1e-8,
            "{best:?}"
        );
        // The same seen again with the camera only turned.
        let turned: Vec<_> = x1
            .iter()
            .map(|p| project(truth.rotation * V3::new(p.x, p.y, 1.0)))
            .collect();
        let r = poses_of_homography(&homography_dlt(&x1, &turned).unwrap());
        assert_eq!(r.len(), 1);
        assert!(r[0].translation.norm() == 0.0);
        assert!(off(&r[0].rotation, &truth.rotation) < 1e-8);
    }
}
