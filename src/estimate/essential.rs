//! The essential matrix of two calibrated views (pure): the five-point solver, the four poses
//! of an essential matrix and the one in front of the cameras, the Sampson error, and an MSAC
//! estimator.
//!
//! Points are undistorted normalised image coordinates (`K⁻¹·x` with the distortion removed);
//! the epipolar constraint is `x₂ᵀ·E·x₁ = 0` with `E = [t]×·R` for `cam2_from_cam1 = (R, t)`.
//!
//! The five-point solver follows Stewénius, Engels and Nistér (2006), "Recent developments on
//! direct relative orientation": `E` is sought in the four-dimensional null space of the five
//! epipolar constraints, `E = x·X + y·Y + z·Z + W`; the ten cubic constraints `det E = 0` and
//! `2·E·Eᵀ·E − tr(E·Eᵀ)·E = 0` are reduced by Gauss–Jordan elimination, and the real solutions
//! are the real eigenvalues of the 10×10 matrix of multiplication by `x` on the quotient ring.

use nalgebra::{DMatrix, Matrix3, SMatrix, Vector2, Vector3};

use super::ransac::Estimator;
use crate::geom::Rigid3;

/// The monomials of degree ≤ 3 in `(x, y, z)`, graded reverse lexicographic: the ten cubic
/// ones first (eliminated), then the ten of the quotient ring's basis.
const MONOMIALS: [(u8, u8, u8); 20] = [
    (3, 0, 0),
    (2, 1, 0),
    (2, 0, 1),
    (1, 2, 0),
    (1, 1, 1),
    (1, 0, 2),
    (0, 3, 0),
    (0, 2, 1),
    (0, 1, 2),
    (0, 0, 3),
    (2, 0, 0),
    (1, 1, 0),
    (1, 0, 1),
    (0, 2, 0),
    (0, 1, 1),
    (0, 0, 2),
    (1, 0, 0),
    (0, 1, 0),
    (0, 0, 1),
    (0, 0, 0),
];

fn monomial_index(e: (u8, u8, u8)) -> usize {
    MONOMIALS
        .iter()
        .position(|&m| m == e)
        .expect("degree at most 3")
}

/// A polynomial of degree ≤ 3 in `(x, y, z)`, coefficients in [`MONOMIALS`] order.
#[derive(Clone, Copy)]
struct Poly([f64; 20]);

impl Poly {
    fn zero() -> Poly {
        Poly([0.0; 20])
    }

    /// `a·x + b·y + c·z + d`.
    fn linear(a: f64, b: f64, c: f64, d: f64) -> Poly {
        let mut p = Poly::zero();
        p.0[16] = a;
        p.0[17] = b;
        p.0[18] = c;
        p.0[19] = d;
        p
    }

    fn mul(&self, q: &Poly) -> Poly {
        let mut out = Poly::zero();
        for (i, &a) in self.0.iter().enumerate() {
            if a == 0.0 {
                continue;
            }
            let ea = MONOMIALS[i];
            for (j, &b) in q.0.iter().enumerate() {
                if b == 0.0 {
                    continue;
                }
                let eb = MONOMIALS[j];
                out.0[monomial_index((ea.0 + eb.0, ea.1 + eb.1, ea.2 + eb.2))] += a * b;
            }
        }
        out
    }

    fn add(&self, q: &Poly) -> Poly {
        let mut out = *self;
        for (o, b) in out.0.iter_mut().zip(&q.0) {
            *o += b;
        }
        out
    }

    fn scale(&self, s: f64) -> Poly {
        let mut out = *self;
        for o in &mut out.0 {
            *o *= s;
        }
        out
    }
}

/// A 3×3 matrix of polynomials.
type PolyMat = [[Poly; 3]; 3];

fn poly_mat_mul(a: &PolyMat, b: &PolyMat) -> PolyMat {
    let mut out = [[Poly::zero(); 3]; 3];
    for (i, row) in out.iter_mut().enumerate() {
        for (j, o) in row.iter_mut().enumerate() {
            for k in 0..3 {
                *o = o.add(&a[i][k].mul(&b[k][j]));
            }
        }
    }
    out
}

fn transpose(a: &PolyMat) -> PolyMat {
    let mut out = *a;
    for (i, row) in out.iter_mut().enumerate() {
        for (j, o) in row.iter_mut().enumerate() {
            *o = a[j][i];
        }
    }
    out
}

/// The epipolar constraint of one correspondence as a row on `E`'s entries, row-major.
fn epipolar_row(x1: &Vector2<f64>, x2: &Vector2<f64>) -> [f64; 9] {
    [
        x2.x * x1.x,
        x2.x * x1.y,
        x2.x,
        x2.y * x1.x,
        x2.y * x1.y,
        x2.y,
        x1.x,
        x1.y,
        1.0,
    ]
}

/// The essential matrices (unit Frobenius norm, up to ten) through five correspondences of
/// normalised coordinates `x₁ ↔ x₂`.
pub fn five_point(x1: &[Vector2<f64>; 5], x2: &[Vector2<f64>; 5]) -> Vec<Matrix3<f64>> {
    // The null space of the 5×9 constraints: the right singular vectors of the four smallest
    // singular values of the matrix padded to 9×9.
    let mut a = SMatrix::<f64, 9, 9>::zeros();
    for k in 0..5 {
        let row = epipolar_row(&x1[k], &x2[k]);
        for (j, v) in row.iter().enumerate() {
            a[(k, j)] = *v;
        }
    }
    let svd = a.svd(false, true);
    let Some(v_t) = svd.v_t else {
        return Vec::new();
    };
    let mut order: Vec<usize> = (0..9).collect();
    order.sort_by(|&i, &j| svd.singular_values[i].total_cmp(&svd.singular_values[j]));
    let basis: Vec<[f64; 9]> = order[..4]
        .iter()
        .map(|&i| {
            let mut b = [0.0; 9];
            for (j, v) in b.iter_mut().enumerate() {
                *v = v_t[(i, j)];
            }
            b
        })
        .collect();
    // E = x·X + y·Y + z·Z + W.
    let mut e: PolyMat = [[Poly::zero(); 3]; 3];
    for (i, row) in e.iter_mut().enumerate() {
        for (j, p) in row.iter_mut().enumerate() {
            let k = 3 * i + j;
            *p = Poly::linear(basis[0][k], basis[1][k], basis[2][k], basis[3][k]);
        }
    }
    let mut constraints = DMatrix::<f64>::zeros(10, 20);
    // det E.
    let det = e[0][0]
        .mul(
            &e[1][1]
                .mul(&e[2][2])
                .add(&e[1][2].mul(&e[2][1]).scale(-1.0)),
        )
        .add(
            &e[0][1].mul(
                &e[1][2]
                    .mul(&e[2][0])
                    .add(&e[1][0].mul(&e[2][2]).scale(-1.0)),
            ),
        )
        .add(
            &e[0][2].mul(
                &e[1][0]
                    .mul(&e[2][1])
                    .add(&e[1][1].mul(&e[2][0]).scale(-1.0)),
            ),
        );
    for (j, c) in det.0.iter().enumerate() {
        constraints[(0, j)] = *c;
    }
    // 2·E·Eᵀ·E − tr(E·Eᵀ)·E.
    let eet = poly_mat_mul(&e, &transpose(&e));
    let trace = eet[0][0].add(&eet[1][1]).add(&eet[2][2]);
    let eete = poly_mat_mul(&eet, &e);
    for i in 0..3 {
        for j in 0..3 {
            let p = eete[i][j].scale(2.0).add(&trace.mul(&e[i][j]).scale(-1.0));
            for (k, c) in p.0.iter().enumerate() {
                constraints[(1 + 3 * i + j, k)] = *c;
            }
        }
    }
    // Gauss–Jordan: each cubic monomial in terms of the basis, [I | G].
    let c1 = constraints.columns(0, 10).into_owned();
    let c2 = constraints.columns(10, 10).into_owned();
    let Some(g) = c1.lu().solve(&c2) else {
        return Vec::new();
    };
    if !g.iter().all(|v| v.is_finite()) {
        return Vec::new();
    }
    // Multiplication by x on the basis (x², xy, xz, y², yz, z², x, y, z, 1): the first six
    // products are cubic monomials 0..6 (x³, x²y, x²z, xy², xyz, xz²), reduced through G; the
    // others are x², xy, xz and x, basis elements 0, 1, 2 and 6.
    let mut action = SMatrix::<f64, 10, 10>::zeros();
    for r in 0..6 {
        for c in 0..10 {
            action[(r, c)] = -g[(r, c)];
        }
    }
    action[(6, 0)] = 1.0;
    action[(7, 1)] = 1.0;
    action[(8, 2)] = 1.0;
    action[(9, 6)] = 1.0;
    let Some(eigen) = action.try_schur(1e-12, 1000) else {
        return Vec::new();
    };
    let mut out: Vec<Matrix3<f64>> = Vec::new();
    for lambda in eigen.complex_eigenvalues().iter() {
        // A real root near another shows as a pair with a tiny imaginary part: its real part is
        // tried, and kept only if the matrix it gives is essential (checked below).
        if lambda.im.abs() > 1e-4 * (1.0 + lambda.re.abs()) {
            continue;
        }
        // The eigenvector: the basis monomials at the solution.
        let shifted = action - SMatrix::<f64, 10, 10>::identity() * lambda.re;
        let svd = shifted.svd(false, true);
        let Some(v_t) = svd.v_t else { continue };
        let k = svd.singular_values.imin();
        let b = v_t.row(k);
        if b[9].abs() < 1e-12 * b.norm() {
            continue;
        }
        let (x, y, z) = (b[6] / b[9], b[7] / b[9], b[8] / b[9]);
        let mut m = Matrix3::zeros();
        for i in 0..3 {
            for j in 0..3 {
                let k = 3 * i + j;
                m[(i, j)] = x * basis[0][k] + y * basis[1][k] + z * basis[2][k] + basis[3][k];
            }
        }
        let n = m.norm();
        if !(n > 0.0 && n.is_finite()) {
            continue;
        }
        let m = m / n;
        let mmt = m * m.transpose();
        let cubic = 2.0 * mmt * m - mmt.trace() * m;
        if cubic.norm() > 1e-6 || m.determinant().abs() > 1e-6 {
            continue;
        }
        // A double eigenvalue (rare) would give the same matrix twice.
        if out
            .iter()
            .any(|o| (o - m).norm() < 1e-9 || (o + m).norm() < 1e-9)
        {
            continue;
        }
        out.push(m);
    }
    out
}

/// The four `cam2_from_cam1` poses of an essential matrix (unit baseline).
pub fn poses_of_essential(e: &Matrix3<f64>) -> [Rigid3; 4] {
    let svd = e.svd(true, true);
    let (mut u, mut v_t) = (svd.u.expect("asked for U"), svd.v_t.expect("asked for Vᵀ"));
    // nalgebra does not sort the singular values: put the smallest last.
    let k = svd.singular_values.imin();
    if k != 2 {
        u.swap_columns(k, 2);
        v_t.swap_rows(k, 2);
    }
    if u.determinant() < 0.0 {
        u = -u;
    }
    if v_t.determinant() < 0.0 {
        v_t = -v_t;
    }
    let w = Matrix3::new(0.0, -1.0, 0.0, 1.0, 0.0, 0.0, 0.0, 0.0, 1.0);
    let ra = u * w * v_t;
    let rb = u * w.transpose() * v_t;
    let t: Vector3<f64> = u.column(2).into_owned();
    let rigid = |r: Matrix3<f64>, t: Vector3<f64>| {
        Rigid3::new(nalgebra::Rotation3::from_matrix_unchecked(r), t)
    };
    [rigid(ra, t), rigid(ra, -t), rigid(rb, t), rigid(rb, -t)]
}

/// The depths along both rays of the midpoint triangulation of `x₁ ↔ x₂` under
/// `cam2_from_cam1`: `(depth in camera 1, depth in camera 2)`.
pub fn triangulated_depths(
    cam2_from_cam1: &Rigid3,
    x1: &Vector2<f64>,
    x2: &Vector2<f64>,
) -> Option<(f64, f64)> {
    // X₁ = d₁·f₁ (camera 1) and R·X₁ + t = d₂·f₂: least squares in (d₁, d₂).
    let f1 = Vector3::new(x1.x, x1.y, 1.0);
    let f2 = Vector3::new(x2.x, x2.y, 1.0);
    let rf1 = cam2_from_cam1.rotation * f1;
    let t = cam2_from_cam1.translation;
    // d₁·Rf₁ − d₂·f₂ = −t.
    let a = nalgebra::Matrix3x2::from_columns(&[rf1, -f2]);
    let ata = a.transpose() * a;
    let d = ata.try_inverse()? * (a.transpose() * -t);
    Some((d[0], d[1]))
}

/// The one of the four poses of `e` that puts most correspondences in front of both cameras,
/// with that count.
pub fn pose_in_front(
    e: &Matrix3<f64>,
    x1: &[Vector2<f64>],
    x2: &[Vector2<f64>],
) -> (Rigid3, usize) {
    best_in_front(poses_of_essential(e), x1, x2)
}

/// The one of `poses` (`cam2_from_cam1`) that puts most correspondences in front of both
/// cameras, with that count (the first of those that tie).
pub fn best_in_front(
    poses: impl IntoIterator<Item = Rigid3>,
    x1: &[Vector2<f64>],
    x2: &[Vector2<f64>],
) -> (Rigid3, usize) {
    let mut best = (Rigid3::identity(), 0);
    for pose in poses {
        let n = x1
            .iter()
            .zip(x2)
            .filter(|(a, b)| {
                triangulated_depths(&pose, a, b).is_some_and(|(d1, d2)| d1 > 0.0 && d2 > 0.0)
            })
            .count();
        if n > best.1 {
            best = (pose, n);
        }
    }
    best
}

/// The essential matrix of `cam2_from_cam1`: `[t]×·R`.
pub fn essential_of(cam2_from_cam1: &Rigid3) -> Matrix3<f64> {
    crate::geom::skew(&cam2_from_cam1.translation) * cam2_from_cam1.rotation.matrix()
}

/// The squared Sampson distance of `x₁ ↔ x₂` to `e` (normalised units squared): the first-order
/// squared distance to the nearest pair that satisfies the constraint exactly.
pub fn sampson_sq(e: &Matrix3<f64>, x1: &Vector2<f64>, x2: &Vector2<f64>) -> f64 {
    let p1 = Vector3::new(x1.x, x1.y, 1.0);
    let p2 = Vector3::new(x2.x, x2.y, 1.0);
    let ex1 = e * p1;
    let etx2 = e.transpose() * p2;
    let c = p2.dot(&ex1);
    let d = ex1.x * ex1.x + ex1.y * ex1.y + etx2.x * etx2.x + etx2.y * etx2.y;
    if d > 0.0 { c * c / d } else { f64::INFINITY }
}

/// MSAC on normalised correspondences; residuals in pixels through `focal_px` (the threshold's
/// unit).
pub struct EssentialEstimator<'a> {
    pub x1: &'a [Vector2<f64>],
    pub x2: &'a [Vector2<f64>],
    pub focal_px: f64,
}

impl Estimator for EssentialEstimator<'_> {
    type Model = Matrix3<f64>;

    fn sample_size(&self) -> usize {
        5
    }

    fn len(&self) -> usize {
        self.x1.len()
    }

    fn is_degenerate(&self, sample: &[usize]) -> bool {
        // Two samples at the same place in either image say nothing more.
        sample.iter().enumerate().any(|(k, &i)| {
            sample[..k].iter().any(|&j| {
                (self.x1[i] - self.x1[j]).norm_squared() < 1e-18
                    || (self.x2[i] - self.x2[j]).norm_squared() < 1e-18
            })
        })
    }

    fn fit_minimal(&self, sample: &[usize]) -> Vec<Matrix3<f64>> {
        let a: [Vector2<f64>; 5] = std::array::from_fn(|k| self.x1[sample[k]]);
        let b: [Vector2<f64>; 5] = std::array::from_fn(|k| self.x2[sample[k]]);
        five_point(&a, &b)
    }

    fn residual_sq(&self, model: &Matrix3<f64>, i: usize) -> f64 {
        sampson_sq(model, &self.x1[i], &self.x2[i]) * self.focal_px * self.focal_px
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::testing::Uniform;
    use nalgebra::Rotation3;

    /// Two views of random points: `(cam2_from_cam1, x₁, x₂)`.
    fn scene(
        rng: &mut Uniform,
        n: usize,
        depth_spread: f64,
    ) -> (Rigid3, Vec<Vector2<f64>>, Vec<Vector2<f64>>) {
        let pose = Rigid3::new(
            Rotation3::from_scaled_axis(Vector3::new(rng.next(), rng.next(), rng.next()) * 0.3),
            Vector3::new(rng.next(), rng.next(), 0.3 * rng.next()),
        );
        let (mut a, mut b) = (Vec::new(), Vec::new());
        while a.len() < n {
            let p = Vector3::new(
                rng.next() * 2.0,
                rng.next() * 2.0,
                5.0 + depth_spread * rng.next(),
            );
            let q = pose.apply(&p);
            if q.z <= 0.1 {
                continue;
            }
            a.push(Vector2::new(p.x / p.z, p.y / p.z));
            b.push(Vector2::new(q.x / q.z, q.y / q.z));
        }
        (pose, a, b)
    }

    fn same_up_to_sign(a: &Matrix3<f64>, b: &Matrix3<f64>) -> f64 {
        let (a, b) = (a / a.norm(), b / b.norm());
        (a - b).norm().min((a + b).norm())
    }

    #[test]
    fn five_points_recover_the_true_essential_matrix() {
        let mut rng = Uniform::new(3);
        for depth_spread in [3.0, 0.01] {
            let mut worst: f64 = 0.0;
            for _ in 0..200 {
                let (pose, a, b) = scene(&mut rng, 5, depth_spread);
                let truth = essential_of(&pose);
                let sols = five_point(
                    &std::array::from_fn(|k| a[k]),
                    &std::array::from_fn(|k| b[k]),
                );
                assert!(!sols.is_empty() && sols.len() <= 10);
                for e in &sols {
                    // Every solution satisfies the five constraints and is essential.
                    for k in 0..5 {
                        assert!(sampson_sq(e, &a[k], &b[k]) < 1e-18);
                    }
                    let s = e.singular_values();
                    let mut s: Vec<f64> = s.iter().copied().collect();
                    s.sort_by(f64::total_cmp);
                    assert!(s[0] < 1e-6 && (s[2] - s[1]).abs() < 1e-6, "{s:?}");
                }
                let best = sols
                    .iter()
                    .map(|e| same_up_to_sign(e, &truth))
                    .fold(f64::INFINITY, f64::min);
                worst = worst.max(best);
            }
            assert!(worst < 1e-6, "depth spread {depth_spread}: worst {worst:e}");
        }
    }

    #[test]
    fn the_pose_in_front_is_the_true_one() {
        let mut rng = Uniform::new(11);
        for _ in 0..50 {
            let (pose, a, b) = scene(&mut rng, 20, 2.0);
            let (found, n) = pose_in_front(&essential_of(&pose), &a, &b);
            assert_eq!(n, 20);
            let dr = (found.rotation.matrix() - pose.rotation.matrix()).norm();
            let dt = (found.translation - pose.translation.normalize()).norm();
            assert!(dr < 1e-9 && dt < 1e-9, "{dr} {dt}");
        }
    }

    #[test]
    fn msac_finds_the_inliers() {
        let mut rng = Uniform::new(5);
        let (pose, mut a, b) = scene(&mut rng, 200, 3.0);
        let focal = 1000.0;
        let outliers: Vec<usize> = (0..200).filter(|i| i % 4 == 0).collect();
        for &i in &outliers {
            a[i] += Vector2::new(rng.next(), rng.next()) * 0.05;
        }
        let est = EssentialEstimator {
            x1: &a,
            x2: &b,
            focal_px: focal,
        };
        let settings = super::super::ransac::RansacSettings {
            threshold: 1.0,
            ..Default::default()
        };
        let r = super::super::ransac::msac(&est, &settings).unwrap();
        assert!(same_up_to_sign(&r.model, &essential_of(&pose)) < 1e-6);
        for i in 0..200 {
            let far = est.residual_sq(&essential_of(&pose), i) > 1.0;
            assert!(!far || !r.inliers[i]);
        }
        assert!(r.inlier_count >= 150, "{}", r.inlier_count);
    }
}
