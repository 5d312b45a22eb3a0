//! From image to world (pure): a detection's ray meets the head surface — the ground plus the
//! person's height, straight up — and its uncertainty follows, split by source.
//!
//! The paper's homography plane (section 3.3.4) is this surface when the ground is a plane; a
//! deck profile or a DEM makes it curved, and the intersection is then found by fixed-point
//! iteration along the ray. Covariances are propagated through the numerical Jacobian of the
//! whole projection (distortion included): the pick's pixel covariance (random from frame to
//! frame), the height's σ (the same for a person in every frame: systematic) and the pose's
//! covariance (shared by everyone in a frame).

pub mod body;

use nalgebra::{Matrix2, Matrix6, Vector2, Vector3, Vector6};

use crate::camera::Camera;
use crate::geom::Rigid3;
use crate::terrain::HeightSurface;

/// A projected detection.
#[derive(Clone, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct WorldPoint {
    /// East, north, up in the site frame, metres.
    pub position: Vector3<f64>,
    /// Horizontal covariance from the pixel noise, m².
    pub cov_pixel: Matrix2<f64>,
    /// Horizontal covariance from the height's uncertainty and the ground's, m² (systematic for
    /// a person).
    pub cov_height: Matrix2<f64>,
    /// Horizontal covariance from the pose's uncertainty, m² (shared within a frame).
    pub cov_pose: Matrix2<f64>,
}

impl WorldPoint {
    /// All sources together.
    pub fn cov_total(&self) -> Matrix2<f64> {
        self.cov_pixel + self.cov_height + self.cov_pose
    }
}

/// The point where the ray through `uv` meets `surface` raised by `height_m`; `None` when the ray
/// points up, misses the surface, or the pixel cannot be undistorted.
pub fn intersect(
    camera: &Camera,
    cam_from_world: &Rigid3,
    surface: &dyn HeightSurface,
    height_m: f64,
    uv: &Vector2<f64>,
) -> Option<Vector3<f64>> {
    let ray = camera.unproject(uv).ok()?.into_inner();
    let world_from_cam = cam_from_world.rotation.inverse();
    let d = world_from_cam * ray;
    if d.z >= -1e-9 {
        return None;
    }
    let c = cam_from_world.centre();
    // Start on the surface below the camera; iterate: height at the current point, then the ray
    // at that height (converges quickly for a near-vertical ray over walkable ground).
    let mut z = surface.height(&c.xy())? + height_m;
    for _ in 0..50 {
        let s = (z - c.z) / d.z;
        if !(s > 0.0) {
            return None;
        }
        let p = c + d * s;
        let z_next = surface.height(&p.xy())? + height_m;
        if (z_next - z).abs() < 1e-7 {
            return Some(Vector3::new(p.x, p.y, z_next));
        }
        z = z_next;
    }
    None
}

/// Projects a detection with its covariances. `pose_cov` is the covariance of the pose's
/// increment (`pose::refine` convention), when known.
#[allow(clippy::too_many_arguments)]
pub fn project(
    camera: &Camera,
    cam_from_world: &Rigid3,
    pose_cov: Option<&Matrix6<f64>>,
    surface: &dyn HeightSurface,
    uv: &Vector2<f64>,
    uv_cov: &Matrix2<f64>,
    height_m: f64,
    height_sd_m: f64,
) -> Option<WorldPoint> {
    let position = intersect(camera, cam_from_world, surface, height_m, uv)?;
    let at = |pose: &Rigid3, h: f64, p: &Vector2<f64>| {
        intersect(camera, pose, surface, h, p).map(|x| x.xy())
    };
    // d(e, n)/d(u, v) by central differences of half a pixel.
    let mut j_uv = Matrix2::zeros();
    for k in 0..2 {
        let mut step = Vector2::zeros();
        step[k] = 0.5;
        let (a, b) = (
            at(cam_from_world, height_m, &(uv + step))?,
            at(cam_from_world, height_m, &(uv - step))?,
        );
        j_uv.set_column(k, &(a - b));
    }
    let cov_pixel = j_uv * uv_cov * j_uv.transpose();
    // The ground's own σ (a plane fitted to points) shifts the head as the height's does.
    let ground_sd_m = surface.height_sigma(&position.xy()).unwrap_or(0.0);
    let sd_m = height_sd_m.hypot(ground_sd_m);
    let cov_height = if sd_m > 0.0 {
        let dh = 0.05;
        let g = (at(cam_from_world, height_m + dh, uv)? - at(cam_from_world, height_m - dh, uv)?)
            / (2.0 * dh);
        g * g.transpose() * (sd_m * sd_m)
    } else {
        Matrix2::zeros()
    };
    let cov_pose = match pose_cov {
        Some(pc) => {
            let mut j = nalgebra::Matrix2x6::zeros();
            for k in 0..6 {
                let mut d = Vector6::zeros();
                d[k] = if k < 3 { 1e-6 } else { 1e-4 };
                let a = at(&cam_from_world.plus(&d), height_m, uv)?;
                let b = at(&cam_from_world.plus(&-d), height_m, uv)?;
                j.set_column(k, &((a - b) / (2.0 * d[k])));
            }
            j * pc * j.transpose()
        }
        None => Matrix2::zeros(),
    };
    Some(WorldPoint {
        position,
        cov_pixel,
        cov_height,
        cov_pose,
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::terrain::Plane;
    use nalgebra::Rotation3;

    fn nadir(centre: Vector3<f64>) -> Rigid3 {
        let rotation = Rotation3::from_matrix_unchecked(nalgebra::Matrix3::new(
            1.0, 0.0, 0.0, 0.0, -1.0, 0.0, 0.0, 0.0, -1.0,
        ));
        Rigid3 {
            rotation,
            translation: -(rotation * centre),
        }
    }

    struct Ramp;
    impl HeightSurface for Ramp {
        fn height(&self, en: &Vector2<f64>) -> Option<f64> {
            Some(0.05 * en.x + 0.01 * en.y * en.y)
        }
    }

    #[test]
    fn a_head_projects_back_where_it_was_and_height_errors_grow_outward() {
        let camera = Camera::pinhole(1400.0, 1400.0, 960.0, 540.0).with_distortion(&[-0.1, 0.03]);
        let pose = nadir(Vector3::new(1.0, 2.0, 30.0));
        for (surface, name) in [
            (&Ramp as &dyn HeightSurface, "ramp"),
            (
                &Plane::from_gradient(0.0, 0.0, 0.5) as &dyn HeightSurface,
                "plane",
            ),
        ] {
            for p in [Vector2::new(3.0, 4.0), Vector2::new(-12.0, 7.0)] {
                let head = Vector3::new(p.x, p.y, surface.height(&p).unwrap() + 1.75);
                let uv = camera.project(&pose.apply(&head)).unwrap();
                let w = project(
                    &camera,
                    &pose,
                    None,
                    surface,
                    &uv,
                    &Matrix2::identity(),
                    1.75,
                    0.1,
                )
                .unwrap();
                assert!(
                    (w.position - head).norm() < 1e-6,
                    "{name}: {} vs {head}",
                    w.position
                );
                // A 0.1 m height σ displaces radially by 0.1·r/(H − h).
                let r = (p - Vector2::new(1.0, 2.0)).norm();
                let expect = 0.1 * r / (30.0 - head.z);
                let got = w.cov_height.trace().sqrt();
                assert!(
                    (got - expect).abs() < 0.05 * expect + 1e-3,
                    "{name}: {got} vs {expect}"
                );
                // One pixel at 28 m with f = 1400 is 2 cm.
                assert!((w.cov_pixel[(0, 0)].sqrt() - (30.0 - head.z) / 1400.0).abs() < 3e-3);
            }
        }
        // Upward rays miss.
        let up = Rigid3 {
            rotation: Rotation3::identity(),
            translation: Vector3::zeros(),
        };
        assert!(
            intersect(
                &camera,
                &up,
                &Plane::from_gradient(0.0, 0.0, 0.0),
                1.7,
                &Vector2::new(960.0, 540.0)
            )
            .is_none()
        );
    }

    /// The stated covariances against a Monte Carlo of the projection: the pose drawn from its
    /// covariance (correlated rotation and translation, through the `Rigid3::plus` increment), the
    /// pixel from its covariance and the height from its σ; 20 000 draws.
    #[test]
    fn covariances_agree_with_a_monte_carlo_of_pose_pixel_and_height() {
        use rand::SeedableRng;
        use rand_distr::{Distribution, Normal};
        let camera = Camera::pinhole(1400.0, 1400.0, 960.0, 540.0).with_distortion(&[-0.1, 0.03]);
        let pose = nadir(Vector3::new(1.0, 2.0, 30.0))
            .plus(&Vector6::new(0.05, -0.03, 0.2, 0.0, 0.0, 0.0));
        // A pose covariance as a GCP solve gives it: tilt and position correlated.
        let sd = Vector6::new(4e-4, 6e-4, 3e-4, 0.01, 0.02, 0.008);
        let mut corr = Matrix6::identity();
        for (a, b, r) in [(0, 4, 0.8), (1, 3, -0.7), (2, 5, 0.3)] {
            corr[(a, b)] = r;
            corr[(b, a)] = r;
        }
        let pose_cov = Matrix6::from_diagonal(&sd) * corr * Matrix6::from_diagonal(&sd);
        let chol = pose_cov.cholesky().expect("SPD").l();
        let surface = Ramp;
        let uv_cov = nalgebra::Matrix2::new(0.09, 0.03, 0.03, 0.05);
        let uv_chol = uv_cov.cholesky().unwrap().l();
        let (height, height_sd) = (1.75, 0.03);
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(7);
        let normal = Normal::new(0.0, 1.0).unwrap();
        for uv in [Vector2::new(960.0, 540.0), Vector2::new(1700.0, 200.0)] {
            let w = project(
                &camera,
                &pose,
                Some(&pose_cov),
                &surface,
                &uv,
                &uv_cov,
                height,
                height_sd,
            )
            .unwrap();
            let n = 20_000;
            let mut draws = Vec::with_capacity(n);
            for _ in 0..n {
                let z6 = Vector6::from_fn(|_, _| normal.sample(&mut rng));
                let z2 = Vector2::from_fn(|_, _| normal.sample(&mut rng));
                let p = pose.plus(&(chol * z6));
                let h = height + height_sd * normal.sample(&mut rng);
                let x = intersect(&camera, &p, &surface, h, &(uv + uv_chol * z2)).unwrap();
                draws.push(x.xy() - w.position.xy());
            }
            let mean = draws.iter().sum::<Vector2<f64>>() / n as f64;
            let mc = draws
                .iter()
                .map(|d| (d - mean) * (d - mean).transpose())
                .sum::<nalgebra::Matrix2<f64>>()
                / (n - 1) as f64;
            let stated = w.cov_total();
            // The pose's part is a sizeable share, so a wrong increment convention shows.
            assert!(w.cov_pose.trace() > 0.3 * stated.trace(), "{}", w.cov_pose);
            let scale = stated.trace();
            assert!(
                (mc - stated).abs().max() < 0.05 * scale,
                "at {uv}: Monte Carlo {mc} vs stated {stated}"
            );
            // And the 95 % ellipse holds 95 % of the draws.
            let inv = stated.try_inverse().unwrap();
            let inside = draws
                .iter()
                .filter(|d| (d.transpose() * inv * *d)[(0, 0)] <= 5.991)
                .count() as f64
                / n as f64;
            assert!((inside - 0.95).abs() < 0.01, "at {uv}: {inside}");
        }
    }
}
