//! A nadir camera over ground control points, with pick noise and gross outliers (pure): the
//! known-truth scenario that the pose tests and benchmarks share.

use nalgebra::{Matrix3, Rotation3, Vector2, Vector3};
use rand::{RngExt, SeedableRng};
use rand_distr::{Distribution, Normal};

use crate::camera::Camera;
use crate::geom::Rigid3;
use crate::pose::{Attitude, GcpObservation};

/// What to simulate.
#[derive(Clone, Debug)]
pub struct GcpViewSpec {
    pub points: usize,
    /// σ of the pick noise per axis, pixels.
    pub noise_px: f64,
    /// The first `round(fraction · points)` picks are displaced by a gross error.
    pub outlier_fraction: f64,
    /// Gross errors are `gross_px` to `10 · gross_px` in a random direction.
    pub gross_px: f64,
    pub altitude_m: f64,
    /// Ground heights drawn from this range, metres.
    pub relief_m: (f64, f64),
    /// Pitch and roll drawn from ±this, degrees; the yaw is any.
    pub tilt_deg: f64,
}

impl Default for GcpViewSpec {
    fn default() -> Self {
        GcpViewSpec {
            points: 20,
            noise_px: 1.0,
            outlier_fraction: 0.3,
            gross_px: 15.0,
            altitude_m: 30.0,
            relief_m: (-1.0, 1.5),
            tilt_deg: 3.0,
        }
    }
}

/// A simulated view with its truth.
#[derive(Clone, Debug)]
pub struct GcpView {
    pub camera: Camera,
    pub cam_from_world: Rigid3,
    pub observations: Vec<GcpObservation>,
    pub outlier: Vec<bool>,
}

/// A DJI-like 4K camera (3840 × 2160, 2756 px focal length) with mild distortion.
pub fn drone_camera_4k() -> Camera {
    Camera::pinhole(2756.0, 2756.0, 1919.5, 1079.5)
        .with_image_size(3840, 2160)
        .with_distortion(&[-0.08, 0.05, 0.0004, -0.0003, -0.01])
}

/// GCPs spread over the image of a nadir camera; exact survey positions (zero covariance).
pub fn gcp_view(camera: &Camera, spec: &GcpViewSpec, seed: u64) -> GcpView {
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(seed);
    let att = Attitude {
        yaw_deg: rng.random_range(0.0..360.0),
        pitch_deg: rng.random_range(-spec.tilt_deg..=spec.tilt_deg),
        roll_deg: rng.random_range(-spec.tilt_deg..=spec.tilt_deg),
        off_nadir_deg: 0.0,
    };
    let rotation = Rotation3::from_matrix_unchecked(att.world_from_cam()).inverse();
    let centre = Vector3::new(
        rng.random_range(-2.0..2.0),
        rng.random_range(-2.0..2.0),
        spec.altitude_m,
    );
    let truth = Rigid3 {
        rotation,
        translation: -(rotation * centre),
    };
    let (w, h) = camera
        .image_size
        .map_or((2.0 * camera.cx + 1.0, 2.0 * camera.cy + 1.0), |s| {
            (f64::from(s.width), f64::from(s.height))
        });
    let noise = Normal::new(0.0, spec.noise_px.max(0.0)).expect("σ ≥ 0");
    let gross_count = (spec.outlier_fraction * spec.points as f64).round() as usize;
    let mut observations = Vec::with_capacity(spec.points);
    let mut outlier = Vec::with_capacity(spec.points);
    while observations.len() < spec.points {
        let uv = Vector2::new(
            rng.random_range(0.03 * w..0.97 * w),
            rng.random_range(0.05 * h..0.95 * h),
        );
        let Ok(ray) = camera.unproject(&uv) else {
            continue;
        };
        let d = rotation.inverse() * ray.into_inner();
        let world =
            centre + d * ((rng.random_range(spec.relief_m.0..=spec.relief_m.1) - centre.z) / d.z);
        let Ok(exact) = camera.project(&truth.apply(&world)) else {
            continue;
        };
        let mut pick = exact + Vector2::new(noise.sample(&mut rng), noise.sample(&mut rng));
        let gross = observations.len() < gross_count;
        if gross {
            let a: f64 = rng.random_range(0.0..std::f64::consts::TAU);
            pick += Vector2::new(a.cos(), a.sin())
                * rng.random_range(spec.gross_px..=10.0 * spec.gross_px);
        }
        observations.push(GcpObservation {
            name: format!("P{}", observations.len() + 1),
            world,
            world_cov: Matrix3::zeros(),
            uv: pick,
            sigma_px: spec.noise_px,
        });
        outlier.push(gross);
    }
    GcpView {
        camera: camera.clone(),
        cam_from_world: truth,
        observations,
        outlier,
    }
}
