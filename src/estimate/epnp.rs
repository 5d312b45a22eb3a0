//! EPnP (Lepetit, Moreno-Noguer & Fua, IJCV 2009), written from the paper: a non-iterative PnP
//! for n ≥ 4 points, used to initialise refinement.
//!
//! Every world point is a barycentric combination of four control points (three when the points
//! are coplanar); the projection equations are linear in the control points' camera
//! coordinates, which therefore lie in the null space of a 2n × 3k matrix M. The null-space
//! combination is found for 1, 2 and 3 null vectors from the preserved distances between control
//! points, polished by Gauss–Newton, and the candidate with the smallest reprojection error wins.

use nalgebra::{DMatrix, DVector, Matrix3, SymmetricEigen, Vector2, Vector3};

use super::EstimateError;
use crate::geom::Rigid3;
use crate::geom::nearest_rotation;

/// Relative size of the smallest principal axis below which the points count as coplanar.
const PLANAR_RATIO: f64 = 1e-6;

/// The rigid transform `p_cam = R p_world + t` that best maps `world` onto `cam` (Kabsch).
pub fn absolute_orientation(world: &[Vector3<f64>], cam: &[Vector3<f64>]) -> Rigid3 {
    let n = world.len() as f64;
    let cw = world.iter().sum::<Vector3<f64>>() / n;
    let cc = cam.iter().sum::<Vector3<f64>>() / n;
    let h = world.iter().zip(cam).fold(Matrix3::zeros(), |h, (w, c)| {
        h + (c - cc) * (w - cw).transpose()
    });
    let rotation = nearest_rotation(&h);
    Rigid3 {
        rotation,
        translation: cc - rotation * cw,
    }
}

/// Squared reprojection error in normalised coordinates, summed; infinite with a point behind.
fn reprojection_sq(pose: &Rigid3, world: &[Vector3<f64>], xy: &[Vector2<f64>]) -> f64 {
    let mut sum = 0.0;
    for (w, m) in world.iter().zip(xy) {
        let p = pose.apply(w);
        if p.z <= 0.0 {
            return f64::INFINITY;
        }
        sum += (Vector2::new(p.x / p.z, p.y / p.z) - m).norm_squared();
    }
    sum
}

/// The `k` null vectors of `MᵀM` (3k unknowns: the control points in the camera frame), the
/// eigenvectors of its `k` smallest eigenvalues.
fn null_vectors(alphas: &[Vec<f64>], xy: &[Vector2<f64>], k: usize) -> Vec<DVector<f64>> {
    let d = 3 * k;
    let mut mtm = DMatrix::<f64>::zeros(d, d);
    let mut row_u = vec![0.0; d];
    let mut row_v = vec![0.0; d];
    for (a, m) in alphas.iter().zip(xy) {
        for j in 0..k {
            row_u[3 * j] = a[j];
            row_u[3 * j + 1] = 0.0;
            row_u[3 * j + 2] = -a[j] * m.x;
            row_v[3 * j] = 0.0;
            row_v[3 * j + 1] = a[j];
            row_v[3 * j + 2] = -a[j] * m.y;
        }
        for r in 0..d {
            for c in r..d {
                mtm[(r, c)] += row_u[r] * row_u[c] + row_v[r] * row_v[c];
            }
        }
    }
    for r in 0..d {
        for c in 0..r {
            mtm[(r, c)] = mtm[(c, r)];
        }
    }
    let eig = SymmetricEigen::new(mtm);
    let mut order: Vec<usize> = (0..d).collect();
    order.sort_by(|&a, &b| eig.eigenvalues[a].total_cmp(&eig.eigenvalues[b]));
    order
        .iter()
        .take(k)
        .map(|&i| eig.eigenvectors.column(i).into())
        .collect()
}

/// Candidate weights β of the null vectors: one vector scaled by the distances, two and three
/// linearised in the products βᵢβⱼ.
fn beta_candidates(
    null: &[DVector<f64>],
    pairs: &[(usize, usize)],
    rho: &[f64],
    diff: impl Fn(&DVector<f64>, usize, usize) -> Vector3<f64>,
) -> Vec<Vec<f64>> {
    let mut candidates: Vec<Vec<f64>> = Vec::new();
    // One null vector: the scale from the distances.
    {
        let (mut num, mut den) = (0.0, 0.0);
        for (p, &(a, b)) in pairs.iter().enumerate() {
            let dv = diff(&null[0], a, b).norm();
            num += dv * rho[p].sqrt();
            den += dv * dv;
        }
        if den > 0.0 {
            candidates.push(vec![num / den]);
        }
    }
    // Two and three null vectors: linearised in the products βᵢβⱼ.
    for nv in 2..=3usize {
        let prods: Vec<(usize, usize)> =
            (0..nv).flat_map(|i| (i..nv).map(move |j| (i, j))).collect();
        if prods.len() > pairs.len() {
            continue;
        }
        let mut l = DMatrix::<f64>::zeros(pairs.len(), prods.len());
        for (p, &(a, b)) in pairs.iter().enumerate() {
            for (q, &(i, j)) in prods.iter().enumerate() {
                let dot = diff(&null[i], a, b).dot(&diff(&null[j], a, b));
                l[(p, q)] = if i == j { dot } else { 2.0 * dot };
            }
        }
        let svd = l.svd(true, true);
        let Ok(bb) = svd.solve(&DVector::from_column_slice(&rho), 1e-12) else {
            continue;
        };
        // βᵢ from the diagonal products, signs from the cross products with β₀.
        let b0 = bb[0].abs().sqrt();
        if b0 == 0.0 {
            continue;
        }
        let mut betas = vec![b0];
        for i in 1..nv {
            let q = prods
                .iter()
                .position(|&pq| pq == (0, i))
                .expect("product (0, i)");
            betas.push(bb[q] / b0);
        }
        candidates.push(betas);
    }
    candidates
}

/// Pose from n ≥ 4 world points and their undistorted normalised image coordinates `(x/z, y/z)`.
pub fn epnp(world: &[Vector3<f64>], xy: &[Vector2<f64>]) -> Result<Rigid3, EstimateError> {
    assert_eq!(world.len(), xy.len(), "world and image points must pair up");
    let n = world.len();
    if n < 4 {
        return Err(EstimateError::TooFewPoints { needed: 4, got: n });
    }
    // Control points: the centroid and the principal axes scaled by their spread.
    let centroid = world.iter().sum::<Vector3<f64>>() / n as f64;
    let cov = world.iter().fold(Matrix3::zeros(), |c, p| {
        c + (p - centroid) * (p - centroid).transpose()
    }) / n as f64;
    let eig = SymmetricEigen::new(cov);
    let mut order = [0, 1, 2];
    order.sort_by(|&a, &b| eig.eigenvalues[b].total_cmp(&eig.eigenvalues[a]));
    let largest = eig.eigenvalues[order[0]];
    if !(largest > 0.0) || eig.eigenvalues[order[1]] <= PLANAR_RATIO * largest {
        return Err(EstimateError::Degenerate(
            "the world points are coincident or collinear".into(),
        ));
    }
    let planar = eig.eigenvalues[order[2]] <= PLANAR_RATIO * largest;
    if !planar && n == 4 {
        // M is 8 x 12 with a four-dimensional null space: P3P on the triples is exact instead.
        return four_point_p3p(world, xy);
    }
    let k = if planar { 3 } else { 4 };
    let mut ctrl = vec![centroid];
    for &axis in order.iter().take(k - 1) {
        let v: Vector3<f64> = eig.eigenvectors.column(axis).into();
        ctrl.push(centroid + v * eig.eigenvalues[axis].max(0.0).sqrt());
    }
    // Barycentric coordinates in the control-point basis.
    let basis = Matrix3::from_fn(|r, c| {
        if c + 1 < k {
            ctrl[c + 1][r] - centroid[r]
        } else {
            0.0
        }
    });
    let alphas: Vec<Vec<f64>> = world
        .iter()
        .map(|p| {
            let d = p - centroid;
            let a: Vec<f64> = (0..k - 1)
                .map(|c| {
                    let axis: Vector3<f64> = basis.column(c).into();
                    axis.dot(&d) / axis.norm_squared()
                })
                .collect();
            let mut out = vec![1.0 - a.iter().sum::<f64>()];
            out.extend(a);
            out
        })
        .collect();
    let d = 3 * k;
    let null = null_vectors(&alphas, xy, k);

    let pairs: Vec<(usize, usize)> = (0..k)
        .flat_map(|a| (a + 1..k).map(move |b| (a, b)))
        .collect();
    let rho: Vec<f64> = pairs
        .iter()
        .map(|&(a, b)| (ctrl[a] - ctrl[b]).norm_squared())
        .collect();
    // Differences of the null vectors between control points a and b.
    let diff = |v: &DVector<f64>, a: usize, b: usize| -> Vector3<f64> {
        Vector3::new(
            v[3 * a] - v[3 * b],
            v[3 * a + 1] - v[3 * b + 1],
            v[3 * a + 2] - v[3 * b + 2],
        )
    };

    let candidates = beta_candidates(&null, &pairs, &rho, diff);

    let mut best: Option<(f64, Rigid3)> = None;
    for betas in candidates {
        let mut b = vec![0.0; k];
        b[..betas.len()].copy_from_slice(&betas);
        gauss_newton(&null, &pairs, &rho, &mut b, diff);
        let x = null
            .iter()
            .zip(&b)
            .fold(DVector::zeros(d), |x, (v, &bi)| x + v * bi);
        let mut cam_ctrl: Vec<Vector3<f64>> = (0..k)
            .map(|j| Vector3::new(x[3 * j], x[3 * j + 1], x[3 * j + 2]))
            .collect();
        let mut cam: Vec<Vector3<f64>> = alphas
            .iter()
            .map(|a| (0..k).fold(Vector3::zeros(), |s, j| s + cam_ctrl[j] * a[j]))
            .collect();
        // The null space has no sign: put the points in front of the camera.
        if cam.iter().map(|p| p.z).sum::<f64>() < 0.0 {
            cam_ctrl.iter_mut().for_each(|p| *p = -*p);
            cam.iter_mut().for_each(|p| *p = -*p);
        }
        let pose = absolute_orientation(world, &cam);
        let err = reprojection_sq(&pose, world, xy);
        if err.is_finite() && best.as_ref().is_none_or(|(e, _)| err < *e) {
            best = Some((err, pose));
        }
    }
    // Nearly coplanar points solved as coplanar are slightly off: polish on all points.
    let all: Vec<usize> = (0..n).collect();
    best.map(|(_, p)| super::pnp::gauss_newton_pose(world, xy, &all, &p, 5))
        .ok_or_else(|| {
            EstimateError::Degenerate("no pose puts the points in front of the camera".into())
        })
}

/// The P3P solution of any triple that best reprojects all four points.
fn four_point_p3p(world: &[Vector3<f64>], xy: &[Vector2<f64>]) -> Result<Rigid3, EstimateError> {
    let mut best: Option<(f64, Rigid3)> = None;
    for skip in 0..4 {
        let idx: Vec<usize> = (0..4).filter(|&i| i != skip).collect();
        let w = [world[idx[0]], world[idx[1]], world[idx[2]]];
        let b = [0, 1, 2].map(|j| Vector3::new(xy[idx[j]].x, xy[idx[j]].y, 1.0).normalize());
        for pose in super::p3p::p3p(&w, &b) {
            // A triple near P3P's unstable configurations is inexact: polish on all four.
            let pose = super::pnp::gauss_newton_pose(world, xy, &[0, 1, 2, 3], &pose, 10);
            let err = reprojection_sq(&pose, world, xy);
            if err.is_finite() && best.as_ref().is_none_or(|(e, _)| err < *e) {
                best = Some((err, pose));
            }
        }
    }
    best.map(|(_, p)| p).ok_or_else(|| {
        EstimateError::Degenerate("no pose puts the points in front of the camera".into())
    })
}

/// Gauss–Newton on the null-space weights β, matching the control-point distances.
fn gauss_newton(
    null: &[DVector<f64>],
    pairs: &[(usize, usize)],
    rho: &[f64],
    b: &mut [f64],
    diff: impl Fn(&DVector<f64>, usize, usize) -> Vector3<f64>,
) {
    let k = b.len();
    let diffs: Vec<Vec<Vector3<f64>>> = pairs
        .iter()
        .map(|&(a, c)| null.iter().map(|v| diff(v, a, c)).collect())
        .collect();
    for _ in 0..10 {
        let mut jtj = DMatrix::<f64>::zeros(k, k);
        let mut jtr = DVector::<f64>::zeros(k);
        let mut cost = 0.0;
        for (p, dv) in diffs.iter().enumerate() {
            let s: Vector3<f64> = (0..k).fold(Vector3::zeros(), |s, i| s + dv[i] * b[i]);
            let r = s.norm_squared() - rho[p];
            cost += r * r;
            let j: Vec<f64> = (0..k).map(|i| 2.0 * s.dot(&dv[i])).collect();
            for i in 0..k {
                jtr[i] += j[i] * r;
                for m in 0..k {
                    jtj[(i, m)] += j[i] * j[m];
                }
            }
        }
        let Some(step) = jtj
            .clone()
            .cholesky()
            .map(|c| c.solve(&jtr))
            .or_else(|| jtj.svd(true, true).solve(&jtr, 1e-12).ok())
        else {
            return;
        };
        for i in 0..k {
            b[i] -= step[i];
        }
        if step.norm() <= 1e-12 * (1.0 + b.iter().map(|x| x * x).sum::<f64>().sqrt()) || cost == 0.0
        {
            return;
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::Rotation3;
    use rand::{RngExt, SeedableRng};

    fn case(
        rng: &mut impl rand::Rng,
        n: usize,
        planar: bool,
    ) -> (Vec<Vector3<f64>>, Vec<Vector2<f64>>, Rigid3) {
        let rotation = Rotation3::from_scaled_axis(Vector3::new(
            rng.random_range(-0.5..0.5),
            rng.random_range(-0.5..0.5),
            rng.random_range(-3.0..3.0),
        ));
        let pose = Rigid3 {
            rotation,
            translation: Vector3::new(
                rng.random_range(-1.0..1.0),
                rng.random_range(-1.0..1.0),
                rng.random_range(6.0..12.0),
            ),
        };
        let world: Vec<Vector3<f64>> = (0..n)
            .map(|_| {
                let z = if planar {
                    0.0
                } else {
                    rng.random_range(-1.0..1.0)
                };
                Vector3::new(rng.random_range(-3.0..3.0), rng.random_range(-3.0..3.0), z)
            })
            .collect();
        let xy = world
            .iter()
            .map(|w| {
                let p = pose.apply(w);
                Vector2::new(p.x / p.z, p.y / p.z)
            })
            .collect();
        (world, xy, pose)
    }

    #[test]
    fn exact_for_general_and_planar_points() {
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(7);
        for planar in [false, true] {
            for n in [4, 5, 6, 10, 50] {
                for _ in 0..50 {
                    let (world, xy, truth) = case(&mut rng, n, planar);
                    let est = epnp(&world, &xy).unwrap();
                    let err = (est.rotation.matrix() - truth.rotation.matrix()).norm()
                        + (est.translation - truth.translation).norm();
                    assert!(err < 1e-6, "planar {planar}, n {n}: error {err}");
                }
            }
        }
    }

    #[test]
    fn degenerate_inputs_are_errors() {
        let line: Vec<_> = (0..6)
            .map(|i| Vector3::new(i as f64, 2.0 * i as f64, 0.0))
            .collect();
        let xy: Vec<_> = (0..6).map(|i| Vector2::new(0.01 * i as f64, 0.0)).collect();
        assert!(matches!(
            epnp(&line, &xy),
            Err(EstimateError::Degenerate(_))
        ));
        assert!(matches!(
            epnp(&line[..3], &xy[..3]),
            Err(EstimateError::TooFewPoints { .. })
        ));
        let same = vec![Vector3::new(1.0, 1.0, 1.0); 5];
        assert!(epnp(&same, &xy[..5]).is_err());
    }
}
