//! Perspective-three-point by Lambda Twist (Persson & Nordberg, ECCV 2018), written from the
//! paper's derivation.
//!
//! The depths λ of three bearing vectors yᵢ satisfy `|λᵢyᵢ − λⱼyⱼ|² = aᵢⱼ` (the squared world
//! distances). Two homogeneous combinations D1, D2 of these quadrics define a pencil
//! `D1 + γ D2`; a root γ of `det(D1 + γD2) = 0` makes it a degenerate conic, a pair of planes
//! through the origin of λ-space, each giving λ₁ linearly in λ₂, λ₃. Substituting into one
//! quadric gives a quadratic in τ = λ₂/λ₃, and λ₃ follows from a third. The depths are polished
//! by Gauss–Newton; the pose comes from the three camera-frame points.

use nalgebra::{Matrix3, Vector3};

use crate::geom::{Rigid3, nearest_rotation};

/// Real roots of `a x² + b x + c`, stable against cancellation.
fn quadratic_roots(a: f64, b: f64, c: f64) -> Vec<f64> {
    if a.abs() < 1e-300 {
        return if b.abs() > 1e-300 {
            vec![-c / b]
        } else {
            vec![]
        };
    }
    let disc = b * b - 4.0 * a * c;
    if disc < 0.0 {
        return vec![];
    }
    let q = -0.5 * (b + b.signum() * disc.sqrt());
    let mut r = vec![q / a];
    if q.abs() > 1e-300 {
        r.push(c / q);
    }
    r
}

/// Real roots of `x³ + a x² + b x + c`, each polished by Newton's method.
fn cubic_roots(a: f64, b: f64, c: f64) -> Vec<f64> {
    // Depressed cubic t³ + p t + q with x = t − a/3.
    let p = b - a * a / 3.0;
    let q = 2.0 * a * a * a / 27.0 - a * b / 3.0 + c;
    let disc = q * q / 4.0 + p * p * p / 27.0;
    let mut roots = if disc > 0.0 {
        let s = disc.sqrt();
        vec![(-q / 2.0 + s).cbrt() + (-q / 2.0 - s).cbrt()]
    } else {
        let r = (-p / 3.0).max(0.0).sqrt();
        if r == 0.0 {
            vec![0.0]
        } else {
            let phi = (-q / (2.0 * r * r * r)).clamp(-1.0, 1.0).acos();
            (0..3)
                .map(|k| 2.0 * r * ((phi + 2.0 * std::f64::consts::PI * f64::from(k)) / 3.0).cos())
                .collect()
        }
    };
    for t in &mut roots {
        *t -= a / 3.0;
        for _ in 0..4 {
            let f = ((*t + a) * *t + b) * *t + c;
            let df = (3.0 * *t + 2.0 * a) * *t + b;
            if df.abs() < 1e-300 {
                break;
            }
            *t -= f / df;
        }
    }
    roots
}

fn adjugate(m: &Matrix3<f64>) -> Matrix3<f64> {
    let c = |r0: usize, r1: usize, c0: usize, c1: usize| {
        m[(r0, c0)] * m[(r1, c1)] - m[(r0, c1)] * m[(r1, c0)]
    };
    Matrix3::new(
        c(1, 2, 1, 2),
        -c(0, 2, 1, 2),
        c(0, 1, 1, 2),
        -c(1, 2, 0, 2),
        c(0, 2, 0, 2),
        -c(0, 1, 0, 2),
        c(1, 2, 0, 1),
        -c(0, 2, 0, 1),
        c(0, 1, 0, 1),
    )
}

/// Polishes depths on the three distance equations by Gauss–Newton.
fn refine_depths(l: &mut Vector3<f64>, b12: f64, b13: f64, b23: f64, a12: f64, a13: f64, a23: f64) {
    for _ in 0..5 {
        let (l1, l2, l3) = (l.x, l.y, l.z);
        let r = Vector3::new(
            l1 * l1 + l2 * l2 - 2.0 * b12 * l1 * l2 - a12,
            l1 * l1 + l3 * l3 - 2.0 * b13 * l1 * l3 - a13,
            l2 * l2 + l3 * l3 - 2.0 * b23 * l2 * l3 - a23,
        );
        if r.amax() < 1e-15 * (a12 + a13 + a23) {
            return;
        }
        #[rustfmt::skip]
        let j = Matrix3::new(
            2.0 * (l1 - b12 * l2), 2.0 * (l2 - b12 * l1), 0.0,
            2.0 * (l1 - b13 * l3), 0.0, 2.0 * (l3 - b13 * l1),
            0.0, 2.0 * (l2 - b23 * l3), 2.0 * (l3 - b23 * l2),
        );
        match j.try_inverse() {
            Some(ji) => *l -= ji * r,
            None => return,
        }
    }
}

/// Up to four poses from three world points and their unit bearing vectors in the camera frame.
pub fn p3p(world: &[Vector3<f64>; 3], bearings: &[Vector3<f64>; 3]) -> Vec<Rigid3> {
    let (x1, x2, x3) = (world[0], world[1], world[2]);
    let (y1, y2, y3) = (
        bearings[0].normalize(),
        bearings[1].normalize(),
        bearings[2].normalize(),
    );
    let (a12, a13, a23) = (
        (x1 - x2).norm_squared(),
        (x1 - x3).norm_squared(),
        (x2 - x3).norm_squared(),
    );
    if a12 <= 0.0
        || a13 <= 0.0
        || a23 <= 0.0
        || (x2 - x1).cross(&(x3 - x1)).norm_squared() < 1e-20 * a12 * a13
    {
        return Vec::new();
    }
    let (b12, b13, b23) = (y1.dot(&y2), y1.dot(&y3), y2.dot(&y3));
    #[rustfmt::skip]
    let m12 = Matrix3::new(1.0, -b12, 0.0, -b12, 1.0, 0.0, 0.0, 0.0, 0.0);
    #[rustfmt::skip]
    let m13 = Matrix3::new(1.0, 0.0, -b13, 0.0, 0.0, 0.0, -b13, 0.0, 1.0);
    #[rustfmt::skip]
    let m23 = Matrix3::new(0.0, 0.0, 0.0, 0.0, 1.0, -b23, 0.0, -b23, 1.0);
    let d1 = m12 * a23 - m23 * a12;
    let d2 = m13 * a23 - m23 * a13;
    // det(D1 + γD2) = det D1 + γ tr(adj(D1) D2) + γ² tr(D1 adj(D2)) + γ³ det D2.
    let (c0, c1, c2, c3) = (
        d1.determinant(),
        (adjugate(&d1) * d2).trace(),
        (d1 * adjugate(&d2)).trace(),
        d2.determinant(),
    );
    let gammas = if c3.abs() > 1e-14 * (c0.abs() + c1.abs() + c2.abs() + c3.abs()) {
        cubic_roots(c2 / c3, c1 / c3, c0 / c3)
    } else {
        quadratic_roots(c2, c1, c0)
    };
    // The best-conditioned real root: a clearly indefinite rank-2 D0.
    // (quality, s, e1, e2): the planes are (e1 ± s e2)·λ = 0.
    let mut best: Option<(f64, f64, Vector3<f64>, Vector3<f64>)> = None;
    for g in gammas {
        let d0 = d1 + d2 * g;
        let eig = d0.symmetric_eigen();
        let mut idx = [0, 1, 2];
        idx.sort_by(|&i, &j| {
            eig.eigenvalues[j]
                .abs()
                .total_cmp(&eig.eigenvalues[i].abs())
        });
        let (s1, s2) = (eig.eigenvalues[idx[0]], eig.eigenvalues[idx[1]]);
        if s1 * s2 >= 0.0 {
            continue;
        }
        let quality = s2.abs() / s1.abs();
        if best.as_ref().is_none_or(|b| quality > b.0) {
            let e1: Vector3<f64> = eig.eigenvectors.column(idx[0]).into();
            let e2: Vector3<f64> = eig.eigenvectors.column(idx[1]).into();
            best = Some((quality, (-s2 / s1).sqrt(), e1, e2));
        }
    }
    let Some((_, s, e1, e2)) = best else {
        return Vec::new();
    };
    let mut poses = Vec::new();
    let wx = Matrix3::from_columns(&[x1 - x2, x1 - x3, (x1 - x2).cross(&(x1 - x3))]);
    let Some(wx_inv) = wx.try_inverse() else {
        return Vec::new();
    };
    for sign in [1.0, -1.0] {
        // The plane (e1 − sign·s·e2)·λ = 0 of the degenerate conic.
        let w = e1 - e2 * (sign * s);
        if w.x.abs() < 1e-12 * w.norm() {
            continue;
        }
        let (p, q) = (-w.y / w.x, -w.z / w.x);
        // λ₁ = p λ₂ + q λ₃, λ₂ = τ λ₃ into λᵀ D1 λ = 0 (homogeneous in λ₃).
        let v = |tau: f64| Vector3::new(p * tau + q, tau, 1.0);
        let f = |tau: f64| v(tau).dot(&(d1 * v(tau)));
        // f is quadratic in τ: recover its coefficients from three values.
        let (f0, f1, fm1) = (f(0.0), f(1.0), f(-1.0));
        let (qa, qb, qc) = ((f1 + fm1) / 2.0 - f0, (f1 - fm1) / 2.0, f0);
        for tau in quadratic_roots(qa, qb, qc) {
            if tau <= 0.0 {
                continue;
            }
            let den = tau * tau - 2.0 * b23 * tau + 1.0;
            if den <= 0.0 {
                continue;
            }
            let l3 = (a23 / den).sqrt();
            let mut l = Vector3::new((p * tau + q) * l3, tau * l3, l3);
            if l.x <= 0.0 {
                continue;
            }
            refine_depths(&mut l, b12, b13, b23, a12, a13, a23);
            if l.iter().any(|&x| !(x > 0.0)) {
                continue;
            }
            let (p1, p2, p3) = (y1 * l.x, y2 * l.y, y3 * l.z);
            let yc = Matrix3::from_columns(&[p1 - p2, p1 - p3, (p1 - p2).cross(&(p1 - p3))]);
            let r = nearest_rotation(&(yc * wx_inv));
            let t = p1 - r * x1;
            let pose = Rigid3 {
                rotation: r,
                translation: t,
            };
            if !poses.iter().any(|o: &Rigid3| {
                (o.rotation.matrix() - r.matrix()).norm() < 1e-9
                    && (o.translation - t).norm() < 1e-9 * (1.0 + t.norm())
            }) {
                poses.push(pose);
            }
        }
    }
    poses
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::{RngExt, SeedableRng};

    fn random_case(rng: &mut impl rand::Rng) -> ([Vector3<f64>; 3], Rigid3) {
        let rotation = nalgebra::Rotation3::from_scaled_axis(Vector3::new(
            rng.random_range(-1.0..1.0),
            rng.random_range(-1.0..1.0),
            rng.random_range(-3.0..3.0),
        ));
        let translation = Vector3::new(
            rng.random_range(-2.0..2.0),
            rng.random_range(-2.0..2.0),
            rng.random_range(4.0..12.0),
        );
        let pose = Rigid3 {
            rotation,
            translation,
        };
        let world = std::array::from_fn(|_| {
            // Points in front of the camera: choose in the camera frame, map back.
            let pc = Vector3::new(
                rng.random_range(-3.0..3.0),
                rng.random_range(-2.0..2.0),
                rng.random_range(3.0..10.0),
            );
            rotation.inverse() * (pc - translation)
        });
        (world, pose)
    }

    #[test]
    fn recovers_the_true_pose_among_its_solutions() {
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(1);
        let mut worst: f64 = 0.0;
        for _ in 0..2000 {
            let (world, truth) = random_case(&mut rng);
            let bearings = world.map(|x| truth.apply(&x).normalize());
            let sols = p3p(&world, &bearings);
            assert!(!sols.is_empty() && sols.len() <= 4);
            let err = sols
                .iter()
                .map(|s| {
                    (s.rotation.matrix() - truth.rotation.matrix()).norm()
                        + (s.translation - truth.translation).norm()
                })
                .fold(f64::INFINITY, f64::min);
            worst = worst.max(err);
            // Every solution reprojects the three points exactly.
            for s in &sols {
                for (x, y) in world.iter().zip(&bearings) {
                    assert!((s.apply(x).normalize() - y).norm() < 1e-6);
                }
            }
        }
        assert!(worst < 1e-6, "worst pose error {worst}");
    }

    #[test]
    fn degenerate_triples_give_no_pose() {
        let line = [
            Vector3::new(0.0, 0.0, 5.0),
            Vector3::new(1.0, 0.0, 5.0),
            Vector3::new(2.0, 0.0, 5.0),
        ];
        assert!(p3p(&line, &line.map(|x| x.normalize())).is_empty());
        let same = [Vector3::new(1.0, 0.0, 5.0); 3];
        assert!(p3p(&same, &same.map(|x| x.normalize())).is_empty());
        assert_eq!(cubic_roots(-6.0, 11.0, -6.0).len(), 3);
    }
}
