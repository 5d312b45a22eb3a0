//! Planes: total least squares, RANSAC, and local planes fitted in a window around each query
//! point of a point cloud (the paper's 2 m x 2 m local ground for moving-camera events).

use nalgebra::{Matrix3, Vector2, Vector3};
use rand::{Rng, RngExt};

use super::HeightSurface;

/// A plane `n · p = d` with `n` the upward unit normal.
#[derive(Clone, Debug, PartialEq)]
pub struct Plane {
    pub normal: Vector3<f64>,
    pub d: f64,
}

#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum PlaneError {
    #[error("a plane needs at least 3 points, got {0}")]
    TooFewPoints(usize),
    #[error("the points are collinear or vertical: no height surface")]
    Degenerate,
}

impl Plane {
    /// `z = gx·E + gy·N + c`.
    pub fn from_gradient(gx: f64, gy: f64, c: f64) -> Plane {
        let n = Vector3::new(-gx, -gy, 1.0);
        let norm = n.norm();
        Plane {
            normal: n / norm,
            d: c / norm,
        }
    }

    /// Signed distance of a point from the plane (positive above).
    pub fn distance(&self, p: &Vector3<f64>) -> f64 {
        self.normal.dot(p) - self.d
    }

    /// Total least squares: the plane through the centroid whose normal is the direction of least
    /// spread. Returns it with the RMS of the orthogonal distances.
    pub fn fit(points: &[Vector3<f64>]) -> Result<(Plane, f64), PlaneError> {
        if points.len() < 3 {
            return Err(PlaneError::TooFewPoints(points.len()));
        }
        let n = points.len() as f64;
        let c = points.iter().fold(Vector3::zeros(), |a, p| a + p) / n;
        let mut cov = Matrix3::zeros();
        for p in points {
            let d = p - c;
            cov += d * d.transpose();
        }
        let eig = cov.symmetric_eigen();
        let mut idx = [0, 1, 2];
        idx.sort_by(|&a, &b| eig.eigenvalues[a].total_cmp(&eig.eigenvalues[b]));
        let (l0, l1) = (eig.eigenvalues[idx[0]], eig.eigenvalues[idx[1]]);
        let mut normal: Vector3<f64> = eig.eigenvectors.column(idx[0]).into();
        if l1 <= 1e-12 * eig.eigenvalues[idx[2]].max(1e-300) || normal.z.abs() < 1e-6 {
            return Err(PlaneError::Degenerate);
        }
        if normal.z < 0.0 {
            normal = -normal;
        }
        let plane = Plane {
            d: normal.dot(&c),
            normal,
        };
        Ok((plane, (l0.max(0.0) / n).sqrt()))
    }

    /// RANSAC on 3-point samples with an inlier distance, then a least-squares refit on the
    /// inliers. Returns the plane and the inlier mask.
    pub fn fit_ransac(
        points: &[Vector3<f64>],
        threshold_m: f64,
        iterations: usize,
        rng: &mut impl Rng,
    ) -> Result<(Plane, Vec<bool>), PlaneError> {
        let n = points.len();
        if n < 3 {
            return Err(PlaneError::TooFewPoints(n));
        }
        let mut best: Option<(usize, Plane)> = None;
        for _ in 0..iterations.max(1) {
            let i = rng.random_range(0..n);
            let j = rng.random_range(0..n);
            let k = rng.random_range(0..n);
            if i == j || j == k || i == k {
                continue;
            }
            let nrm = (points[j] - points[i]).cross(&(points[k] - points[i]));
            if nrm.norm() < 1e-12 || nrm.z.abs() < 1e-6 * nrm.norm() {
                continue;
            }
            let mut nrm = nrm.normalize();
            if nrm.z < 0.0 {
                nrm = -nrm;
            }
            let plane = Plane {
                d: nrm.dot(&points[i]),
                normal: nrm,
            };
            let count = points
                .iter()
                .filter(|p| plane.distance(p).abs() <= threshold_m)
                .count();
            if best.as_ref().is_none_or(|(c, _)| count > *c) {
                best = Some((count, plane));
            }
        }
        let (_, plane) = best.ok_or(PlaneError::Degenerate)?;
        let mask: Vec<bool> = points
            .iter()
            .map(|p| plane.distance(p).abs() <= threshold_m)
            .collect();
        let inliers: Vec<Vector3<f64>> = points
            .iter()
            .zip(&mask)
            .filter(|(_, m)| **m)
            .map(|(p, _)| *p)
            .collect();
        let (refit, _) = Plane::fit(&inliers)?;
        let mask = points
            .iter()
            .map(|p| refit.distance(p).abs() <= threshold_m)
            .collect();
        Ok((refit, mask))
    }
}

impl HeightSurface for Plane {
    fn shareable(&self) -> Option<&(dyn HeightSurface + Sync)> {
        Some(self)
    }

    fn height(&self, en: &Vector2<f64>) -> Option<f64> {
        (self.normal.z.abs() > 1e-9)
            .then(|| (self.d - self.normal.x * en.x - self.normal.y * en.y) / self.normal.z)
    }

    fn normal(&self, _: &Vector2<f64>) -> Option<Vector3<f64>> {
        Some(self.normal)
    }
}

/// Ground as a plane fitted, for each query, to the points of a cloud inside a square window
/// around it (the paper: 2 m, around each person), robustly: points further from the plane than
/// three robust σ (people, railings, a mismatched tie point) are left out and the plane fitted
/// again. With too few points the window doubles, up to `max_window_m`. Points are bucketed on a
/// grid of the window's size for lookup. As a [`HeightSurface`], fits are made at the nodes of a
/// 5 cm grid, each once (a projection asks a few dozen times around each point; the windows of
/// neighbouring nodes share nearly all their points), and blended between them.
pub struct LocalPlanes {
    points: Vec<Vector3<f64>>,
    memo: std::sync::Mutex<std::collections::HashMap<(i64, i64), Option<LocalFit>>>,
    /// The robust plane of the whole cloud, for a query where even the widest window is too
    /// sparse (its σ the cloud's RMS about it); made once, when first needed.
    whole: std::sync::OnceLock<Option<LocalFit>>,
    window_m: f64,
    cell: std::collections::HashMap<(i64, i64), Vec<usize>>,
    /// Fewest points a window needs.
    pub min_points: usize,
    /// The widest window tried when the first holds too few points.
    pub max_window_m: f64,
    /// Residuals within this are never outliers (the ground's own roughness), metres.
    pub floor_m: f64,
}

/// A local plane and how well it is known.
#[derive(Clone, Debug, PartialEq)]
pub struct LocalFit {
    pub plane: Plane,
    /// σ of the plane's height at the query position, metres (the residuals' spread over the
    /// points' number and spread).
    pub sigma_m: f64,
    /// RMS distance of the kept points from the plane, metres.
    pub rms_m: f64,
    pub points: usize,
    pub outliers: usize,
    /// The window that held enough points (wider than asked: a fallback).
    pub window_m: f64,
}

impl LocalPlanes {
    /// `window_m` is the side of the square window (the paper: 2 m).
    pub fn new(points: Vec<Vector3<f64>>, window_m: f64) -> Self {
        let mut cell: std::collections::HashMap<(i64, i64), Vec<usize>> =
            std::collections::HashMap::new();
        for (i, p) in points.iter().enumerate() {
            cell.entry(Self::key(p.x, p.y, window_m))
                .or_default()
                .push(i);
        }
        LocalPlanes {
            points,
            memo: Default::default(),
            whole: Default::default(),
            window_m,
            cell,
            min_points: 6,
            max_window_m: 4.0 * window_m,
            floor_m: 0.02,
        }
    }

    fn key(e: f64, n: f64, size: f64) -> (i64, i64) {
        ((e / size).floor() as i64, (n / size).floor() as i64)
    }

    /// The points within a square of side `side` around `en`.
    fn near(&self, en: &Vector2<f64>, side: f64) -> Vec<Vector3<f64>> {
        let half = side / 2.0;
        let (ci, cj) = Self::key(en.x, en.y, self.window_m);
        let reach = (half / self.window_m).ceil() as i64 + 1;
        let mut near = Vec::new();
        for di in -reach..=reach {
            for dj in -reach..=reach {
                if let Some(ids) = self.cell.get(&(ci + di, cj + dj)) {
                    near.extend(
                        ids.iter()
                            .map(|&i| self.points[i])
                            .filter(|p| (p.x - en.x).abs() <= half && (p.y - en.y).abs() <= half),
                    );
                }
            }
        }
        near
    }

    /// The robust plane around a position, with its σ there; `None` where even the widest
    /// window holds too few points.
    pub fn fit_at(&self, en: &Vector2<f64>) -> Option<LocalFit> {
        let mut side = self.window_m;
        loop {
            let near = self.near(en, side);
            if near.len() >= self.min_points
                && let Some(fit) = robust_fit(&near, en, self.floor_m, self.min_points)
            {
                return Some(LocalFit {
                    window_m: side,
                    ..fit
                });
            }
            if side >= self.max_window_m {
                return None;
            }
            side = (side * 2.0).min(self.max_window_m);
        }
    }

    /// The plane fitted in the window around a position.
    pub fn plane_at(&self, en: &Vector2<f64>) -> Option<Plane> {
        self.fit_at(en).map(|f| f.plane)
    }

    /// The fallback: the robust plane of every point, its σ the kept points' RMS about it (a
    /// site far from flat gets a σ to match), `window_m` 0.
    pub fn whole_cloud(&self) -> Option<LocalFit> {
        self.whole
            .get_or_init(|| {
                let n = self.points.len() as f64;
                let centre = self.points.iter().fold(Vector2::zeros(), |a, p| a + p.xy()) / n;
                let fit = robust_fit(&self.points, &centre, self.floor_m, self.min_points)?;
                Some(LocalFit {
                    sigma_m: fit.rms_m.max(fit.sigma_m),
                    window_m: 0.0,
                    ..fit
                })
            })
            .clone()
    }

    /// The fit at the 5 cm grid node nearest `en`, made once; the whole cloud's plane where
    /// the widest window is too sparse.
    pub fn fit_near(&self, en: &Vector2<f64>) -> Option<LocalFit> {
        self.fit_node(
            (en.x / NODE_STEP_M).round() as i64,
            (en.y / NODE_STEP_M).round() as i64,
        )
    }

    /// The fit at grid node `(i, j)` (at `(i, j)` × 5 cm), made once.
    fn fit_node(&self, i: i64, j: i64) -> Option<LocalFit> {
        if let Some(f) = self.memo.lock().ok().and_then(|m| m.get(&(i, j)).cloned()) {
            return f;
        }
        let node = Vector2::new(i as f64 * NODE_STEP_M, j as f64 * NODE_STEP_M);
        let fit = self.fit_at(&node).or_else(|| self.whole_cloud());
        if let Ok(mut m) = self.memo.lock() {
            m.insert((i, j), fit.clone());
        }
        fit
    }

    /// The four nodes around `en` with their bilinear weights.
    fn around(en: &Vector2<f64>) -> [((i64, i64), f64); 4] {
        let (x, y) = (en.x / NODE_STEP_M, en.y / NODE_STEP_M);
        let (i, j) = (x.floor(), y.floor());
        let (tx, ty) = (x - i, y - j);
        let (i, j) = (i as i64, j as i64);
        [
            ((i, j), (1.0 - tx) * (1.0 - ty)),
            ((i + 1, j), tx * (1.0 - ty)),
            ((i, j + 1), (1.0 - tx) * ty),
            ((i + 1, j + 1), tx * ty),
        ]
    }
}

/// RANSAC (3 `floor_m`), least squares on its inliers, then again with the points within 3
/// robust σ (1.4826 × the median absolute residual of the kept points, at least `floor_m`),
/// three times; the height σ at `en` from the fit's covariance.
fn robust_fit(
    points: &[Vector3<f64>],
    en: &Vector2<f64>,
    floor_m: f64,
    min_points: usize,
) -> Option<LocalFit> {
    // A consensus start (people and railings can be a third of a window's points), seeded by
    // the position so that a query always gives the same plane.
    let seed = en.x.to_bits() ^ en.y.to_bits().rotate_left(17);
    let mut rng = <rand_chacha::ChaCha8Rng as rand::SeedableRng>::seed_from_u64(seed);
    let (_, inliers) = Plane::fit_ransac(points, 3.0 * floor_m, 200, &mut rng).ok()?;
    let mut kept: Vec<Vector3<f64>> = points
        .iter()
        .zip(&inliers)
        .filter(|(_, k)| **k)
        .map(|(p, _)| *p)
        .collect();
    if kept.len() < min_points.max(3) {
        return None;
    }
    let (mut plane, _) = Plane::fit(&kept).ok()?;
    for _ in 0..3 {
        let mut r: Vec<f64> = points.iter().map(|p| plane.distance(p).abs()).collect();
        let mut sorted: Vec<f64> = kept.iter().map(|p| plane.distance(p).abs()).collect();
        sorted.sort_by(f64::total_cmp);
        let mad = sorted[sorted.len() / 2];
        let limit = (3.0 * 1.4826 * mad).max(floor_m);
        let next: Vec<Vector3<f64>> = points
            .iter()
            .zip(r.iter_mut())
            .filter(|(_, d)| **d <= limit)
            .map(|(p, _)| *p)
            .collect();
        if next.len() < min_points.max(3) {
            break;
        }
        let same = next.len() == kept.len();
        kept = next;
        plane = Plane::fit(&kept).ok()?.0;
        if same {
            break;
        }
    }
    // Height σ at `en`: heights z = a + b·(e − e₀) + c·(n − n₀) centred at the query, so σ(a)
    // from (AᵀA)⁻¹ and the residuals' variance.
    let n = kept.len();
    let mut ata = nalgebra::Matrix3::<f64>::zeros();
    let mut ss = 0.0;
    for p in &kept {
        let row = Vector3::new(1.0, p.x - en.x, p.y - en.y);
        ata += row * row.transpose();
        ss += plane.distance(p).powi(2);
    }
    let dof = n.saturating_sub(3).max(1) as f64;
    let var = ss / dof;
    let inv = ata.try_inverse()?;
    let tilt = plane.normal.z.abs().max(1e-9);
    Some(LocalFit {
        plane,
        sigma_m: (var * inv[(0, 0)]).max(0.0).sqrt() / tilt,
        rms_m: (ss / n as f64).sqrt(),
        points: n,
        outliers: points.len() - n,
        window_m: 0.0,
    })
}

/// The grid the fits of a [`LocalPlanes`] surface are made on, metres.
const NODE_STEP_M: f64 = 0.05;

/// As a surface, the heights of the four nodes' planes at the query, blended bilinearly: the
/// ground is then continuous (a projection's fixed-point iteration and its finite differences
/// never meet a step between two nodes' planes).
impl HeightSurface for LocalPlanes {
    fn shareable(&self) -> Option<&(dyn HeightSurface + Sync)> {
        Some(self)
    }

    fn height(&self, en: &Vector2<f64>) -> Option<f64> {
        let mut z = 0.0;
        for ((i, j), w) in Self::around(en) {
            z += w * self.fit_node(i, j)?.plane.height(en)?;
        }
        Some(z)
    }

    fn normal(&self, en: &Vector2<f64>) -> Option<Vector3<f64>> {
        let mut n = Vector3::zeros();
        for ((i, j), w) in Self::around(en) {
            n += w * self.fit_node(i, j)?.plane.normal;
        }
        Some(n.normalize())
    }

    fn height_sigma(&self, en: &Vector2<f64>) -> Option<f64> {
        let mut v = 0.0;
        for ((i, j), w) in Self::around(en) {
            v += w * self.fit_node(i, j)?.sigma_m.powi(2);
        }
        Some(v.sqrt())
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::SeedableRng;
    use rand_distr::{Distribution, Normal};

    fn noisy_plane(n: usize, seed: u64) -> Vec<Vector3<f64>> {
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(seed);
        let noise = Normal::new(0.0, 0.005).unwrap();
        (0..n)
            .map(|_| {
                let (e, nn) = (rng.random_range(-20.0..20.0), rng.random_range(-20.0..20.0));
                Vector3::new(e, nn, 0.02 * e - 0.01 * nn + 5.0 + noise.sample(&mut rng))
            })
            .collect()
    }

    #[test]
    fn least_squares_recovers_a_known_plane() {
        let pts = noisy_plane(400, 1);
        let (p, rms) = Plane::fit(&pts).unwrap();
        let truth = Plane::from_gradient(0.02, -0.01, 5.0);
        assert!((p.normal - truth.normal).norm() < 1e-3);
        assert!((p.height(&Vector2::new(3.0, 4.0)).unwrap() - (0.06 - 0.04 + 5.0)).abs() < 2e-3);
        assert!((rms - 0.005).abs() < 0.001, "{rms}");
        assert_eq!(Plane::fit(&pts[..2]), Err(PlaneError::TooFewPoints(2)));
        let line: Vec<_> = (0..5).map(|i| Vector3::new(i as f64, 0.0, 0.0)).collect();
        assert_eq!(Plane::fit(&line), Err(PlaneError::Degenerate));
    }

    #[test]
    fn local_planes_are_a_continuous_surface() {
        // Across the 5 cm nodes the blended height moves with the slope only (a step between
        // two nodes' planes stalled the projection's fixed-point iteration).
        let local = LocalPlanes::new(noisy_plane(3000, 3), 2.0);
        let mut prev: Option<f64> = None;
        for k in 0..400 {
            let en = Vector2::new(1.0 + 0.0005 * k as f64, 2.0 + 0.0003 * k as f64);
            let h = local.height(&en).unwrap();
            if let Some(p) = prev {
                assert!((h - p).abs() < 2e-5, "{k}: {p} -> {h}");
            }
            prev = Some(h);
        }
        let s = local.height_sigma(&Vector2::new(1.02, 2.01)).unwrap();
        assert!(s > 0.0 && s < 0.005, "{s}");
    }

    #[test]
    fn ransac_ignores_people_and_clutter() {
        let mut pts = noisy_plane(300, 2);
        // 30 % of points 1-2 m above the ground: people, railings.
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(9);
        for p in pts.iter_mut().take(90) {
            p.z += rng.random_range(1.0..2.0);
        }
        let (plane, inliers) = Plane::fit_ransac(&pts, 0.03, 200, &mut rng).unwrap();
        assert!(inliers.iter().take(90).all(|m| !m));
        assert!(inliers.iter().skip(90).filter(|m| **m).count() > 200);
        assert!((plane.height(&Vector2::new(0.0, 0.0)).unwrap() - 5.0).abs() < 0.005);
        let (ls, _) = Plane::fit(&pts).unwrap();
        assert!(
            (ls.height(&Vector2::zeros()).unwrap() - 5.0).abs() > 0.2,
            "plain least squares is pulled up"
        );
    }

    #[test]
    fn local_planes_follow_a_curved_ground() {
        // A gentle bowl z = 0.005 (E² + N²), sampled every 0.25 m.
        let mut pts = Vec::new();
        for i in -60..=60 {
            for j in -60..=60 {
                let (e, n) = (i as f64 * 0.25, j as f64 * 0.25);
                pts.push(Vector3::new(e, n, 0.005 * (e * e + n * n)));
            }
        }
        let local = LocalPlanes::new(pts, 2.0);
        for &(e, n) in &[(0.0, 0.0), (8.0, -3.0), (-10.0, 10.0)] {
            let z = 0.005 * (e * e + n * n);
            let h = local.height(&Vector2::new(e, n)).unwrap();
            // A plane over a 2 m window of a paraboloid errs by at most the curvature term.
            assert!((h - z).abs() < 0.005 * 1.0 + 1e-9, "{e},{n}: {h} vs {z}");
            let nrm = local.normal(&Vector2::new(e, n)).unwrap();
            let expected = Vector3::new(-0.01 * e, -0.01 * n, 1.0).normalize();
            assert!((nrm - expected).norm() < 1e-3);
        }
        // No points near there: no local plane, but the whole cloud's, its σ the cloud's
        // spread about it (this ground is curved: centimetres, not the local millimetres).
        assert!(local.fit_at(&Vector2::new(40.0, 0.0)).is_none());
        let far = local.fit_near(&Vector2::new(40.0, 0.0)).unwrap();
        assert_eq!(far.window_m, 0.0);
        assert!(far.sigma_m >= far.rms_m && far.sigma_m > 0.01, "{far:?}");
        assert_eq!(
            local.height_sigma(&Vector2::new(40.0, 0.0)),
            Some(far.sigma_m)
        );
    }

    #[test]
    fn local_planes_leave_out_people_state_their_sigma_and_widen_where_points_are_few() {
        // Tie points on a sloping deck (1 cm noise), 30 % of them on people 1–2 m up.
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(4);
        let noise = Normal::new(0.0, 0.01).unwrap();
        let ground = |e: f64, n: f64| 6.0 + 0.03 * e - 0.01 * n;
        let mut pts = Vec::new();
        for _ in 0..4000 {
            let (e, n) = (rng.random_range(-20.0..20.0), rng.random_range(-5.0..5.0));
            let mut z = ground(e, n) + noise.sample(&mut rng);
            if rng.random_range(0.0..1.0) < 0.3 {
                z += rng.random_range(1.0..2.0);
            }
            pts.push(Vector3::new(e, n, z));
        }
        // A sparse patch: only a handful of points within 1 m of (15, 0).
        pts.retain(|p| !((p.x - 15.0).abs() < 2.0 && p.y.abs() < 2.0) || p.x > 16.5);
        let local = LocalPlanes::new(pts, 2.0);
        let fit = local.fit_at(&Vector2::new(-5.0, 1.0)).unwrap();
        let h = fit.plane.height(&Vector2::new(-5.0, 1.0)).unwrap();
        assert!(
            (h - ground(-5.0, 1.0)).abs() < 3.0 * fit.sigma_m + 1e-3,
            "{h} {fit:?}"
        );
        assert!(fit.sigma_m > 0.001 && fit.sigma_m < 0.01, "{fit:?}");
        assert!(fit.outliers > 5 && fit.rms_m < 0.02, "{fit:?}");
        assert_eq!(fit.window_m, 2.0);
        // The sparse patch: a wider window, still the ground.
        let wide = local.fit_at(&Vector2::new(15.0, 0.0)).unwrap();
        assert!(wide.window_m > 2.0, "{wide:?}");
        let h = wide.plane.height(&Vector2::new(15.0, 0.0)).unwrap();
        // Points on one side only: extrapolated, and its σ says so.
        assert!(
            (h - ground(15.0, 0.0)).abs() < 3.0 * wide.sigma_m + 1e-3 && wide.sigma_m > fit.sigma_m,
            "{h} {wide:?}"
        );
    }
}
