//! Robust PnP: P3P (Lambda Twist) samples scored by MSAC, with Gauss–Newton local optimisation.
//!
//! The estimator works on undistorted normalised image coordinates, so that the camera model
//! (distortion included) is applied once per point rather than once per hypothesis; residuals are
//! scaled by the focal length to read in pixels. Final refinement on the full camera model
//! belongs to `pose`.

use nalgebra::{Matrix6, Vector2, Vector3, Vector6};

use super::p3p::p3p;
use super::ransac::Estimator;
use crate::geom::Rigid3;
use crate::geom::skew;

/// Gauss–Newton on `Σ wᵢ |π(R Xᵢ + t) − xyᵢ|²` in normalised coordinates, with left increments
/// of the rotation. Stops early when the step is negligible; points behind the camera are
/// skipped.
pub fn gauss_newton_pose(
    world: &[Vector3<f64>],
    xy: &[Vector2<f64>],
    subset: &[usize],
    start: &Rigid3,
    iterations: usize,
) -> Rigid3 {
    let mut pose = *start;
    for _ in 0..iterations {
        let mut jtj = Matrix6::<f64>::zeros();
        let mut jtr = Vector6::<f64>::zeros();
        for &i in subset {
            let p = pose.apply(&world[i]);
            if p.z <= 0.0 {
                continue;
            }
            let iz = 1.0 / p.z;
            let r = Vector2::new(p.x * iz - xy[i].x, p.y * iz - xy[i].y);
            // d(x/z, y/z)/dp, then dp/d(δθ, δt) = [−[p]×, I].
            let dn = nalgebra::Matrix2x3::new(iz, 0.0, -p.x * iz * iz, 0.0, iz, -p.y * iz * iz);
            let mut j = nalgebra::Matrix2x6::<f64>::zeros();
            j.fixed_view_mut::<2, 3>(0, 0).copy_from(&(dn * -skew(&p)));
            j.fixed_view_mut::<2, 3>(0, 3).copy_from(&dn);
            jtj += j.transpose() * j;
            jtr += j.transpose() * r;
        }
        let Some(chol) = jtj.cholesky() else { break };
        let delta = -chol.solve(&jtr);
        let dr = Vector3::new(delta[0], delta[1], delta[2]);
        let rot = nalgebra::Rotation3::from_scaled_axis(dr);
        pose = Rigid3 {
            rotation: rot * pose.rotation,
            translation: rot * pose.translation + Vector3::new(delta[3], delta[4], delta[5]),
        };
        if delta.norm() < 1e-12 * (1.0 + pose.translation.norm()) {
            break;
        }
    }
    pose
}

/// PnP as an MSAC problem over 3D–2D correspondences.
pub struct PnpEstimator<'a> {
    world: &'a [Vector3<f64>],
    xy: &'a [Vector2<f64>],
    bearings: Vec<Vector3<f64>>,
    /// Pixels per normalised unit (the focal length), to read residuals in pixels.
    scale: f64,
}

impl<'a> PnpEstimator<'a> {
    /// `xy` are undistorted normalised image coordinates; `focal_px` scales residuals to pixels.
    pub fn new(world: &'a [Vector3<f64>], xy: &'a [Vector2<f64>], focal_px: f64) -> Self {
        assert_eq!(world.len(), xy.len(), "world and image points must pair up");
        let bearings = xy
            .iter()
            .map(|m| Vector3::new(m.x, m.y, 1.0).normalize())
            .collect();
        PnpEstimator {
            world,
            xy,
            bearings,
            scale: focal_px,
        }
    }
}

/// Whether three points are (nearly) collinear or coincident, relative to their spread.
pub fn collinear(a: &Vector3<f64>, b: &Vector3<f64>, c: &Vector3<f64>) -> bool {
    let (ab, ac) = (b - a, c - a);
    let scale = ab
        .norm_squared()
        .max(ac.norm_squared())
        .max((c - b).norm_squared());
    scale == 0.0 || ab.cross(&ac).norm_squared() < 1e-10 * scale * scale
}

impl Estimator for PnpEstimator<'_> {
    type Model = Rigid3;

    fn sample_size(&self) -> usize {
        3
    }

    fn len(&self) -> usize {
        self.world.len()
    }

    fn is_degenerate(&self, s: &[usize]) -> bool {
        let w = |i: usize| self.world[s[i]];
        let y = |i: usize| self.bearings[s[i]];
        collinear(&w(0), &w(1), &w(2))
            || (y(0) - y(1)).norm() < 1e-9
            || (y(0) - y(2)).norm() < 1e-9
            || (y(1) - y(2)).norm() < 1e-9
    }

    fn fit_minimal(&self, s: &[usize]) -> Vec<Rigid3> {
        p3p(
            &[self.world[s[0]], self.world[s[1]], self.world[s[2]]],
            &[
                self.bearings[s[0]],
                self.bearings[s[1]],
                self.bearings[s[2]],
            ],
        )
    }

    fn fit_nonminimal(&self, data: &[usize], start: &Rigid3) -> Option<Rigid3> {
        (data.len() >= 4).then(|| gauss_newton_pose(self.world, self.xy, data, start, 5))
    }

    fn residual_sq(&self, pose: &Rigid3, i: usize) -> f64 {
        let p = pose.apply(&self.world[i]);
        if p.z <= 0.0 {
            return f64::INFINITY;
        }
        let d = Vector2::new(p.x / p.z - self.xy[i].x, p.y / p.z - self.xy[i].y);
        d.norm_squared() * self.scale * self.scale
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::estimate::ransac::{RansacSettings, msac};
    use nalgebra::Rotation3;
    use rand::{RngExt, SeedableRng};

    #[test]
    fn msac_finds_the_pose_and_the_outliers() {
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(3);
        let f = 1500.0;
        for _ in 0..20 {
            let truth = Rigid3 {
                rotation: Rotation3::from_scaled_axis(Vector3::new(
                    3.1,
                    0.02,
                    rng.random_range(-3.0..3.0),
                )),
                translation: Vector3::new(0.5, -0.3, 30.0),
            };
            let world: Vec<Vector3<f64>> = (0..20)
                .map(|_| {
                    Vector3::new(
                        rng.random_range(-15.0..15.0),
                        rng.random_range(-10.0..10.0),
                        rng.random_range(-0.5..0.5),
                    )
                })
                .collect();
            let mut xy: Vec<Vector2<f64>> = world
                .iter()
                .map(|w| {
                    let p = truth.apply(w);
                    Vector2::new(p.x / p.z, p.y / p.z)
                        + Vector2::new(rng.random_range(-1.0..1.0), rng.random_range(-1.0..1.0)) / f
                })
                .collect();
            for m in xy.iter_mut().take(6) {
                *m += Vector2::new(
                    rng.random_range(30.0..200.0),
                    rng.random_range(-200.0..-30.0),
                ) / f;
            }
            let est = PnpEstimator::new(&world, &xy, f);
            let r = msac(
                &est,
                &RansacSettings {
                    threshold: 4.0,
                    seed: 1,
                    ..RansacSettings::default()
                },
            )
            .unwrap();
            assert!(
                r.inliers[..6].iter().all(|&b| !b) && r.inliers[6..].iter().all(|&b| b),
                "{:?}",
                r.inliers
            );
            // Tilt and sideways shift trade off over a near-planar scene: decimetres at 30 m.
            assert!((r.model.centre() - truth.centre()).norm() < 1.0);
        }
    }

    #[test]
    fn gauss_newton_converges_from_a_nearby_pose() {
        let truth = Rigid3 {
            rotation: Rotation3::from_scaled_axis(Vector3::new(3.0, 0.1, 0.4)),
            translation: Vector3::new(1.0, 2.0, 25.0),
        };
        let world: Vec<Vector3<f64>> = (0..10)
            .map(|i| {
                Vector3::new(
                    (i % 4) as f64 * 5.0,
                    (i / 4) as f64 * 4.0,
                    (i % 3) as f64 * 0.3,
                )
            })
            .collect();
        let xy: Vec<Vector2<f64>> = world
            .iter()
            .map(|w| truth.apply(w))
            .map(|p| Vector2::new(p.x / p.z, p.y / p.z))
            .collect();
        let start = Rigid3 {
            rotation: Rotation3::from_scaled_axis(Vector3::new(0.02, -0.03, 0.05)) * truth.rotation,
            translation: truth.translation + Vector3::new(0.5, -0.4, 1.0),
        };
        let all: Vec<usize> = (0..10).collect();
        let est = gauss_newton_pose(&world, &xy, &all, &start, 20);
        assert!((est.translation - truth.translation).norm() < 1e-8);
    }
}
