//! Camera motion over a scene (pure): hovering with drift and jitter, along waypoints, or
//! following a group.

use nalgebra::{Matrix3, Rotation3, Vector3};

use super::noise::{gaussian, hash};
use super::render::CameraPose;
use super::scene::Motion;

/// World from camera for a nadir camera whose image top points to `heading_deg` (from north):
/// camera x right, y down (towards the image bottom), z down.
pub fn nadir(heading_deg: f64) -> Matrix3<f64> {
    let a = heading_deg.to_radians();
    let up = Vector3::new(a.sin(), a.cos(), 0.0);
    let right = Vector3::new(a.cos(), -a.sin(), 0.0);
    Matrix3::from_columns(&[right, -up, Vector3::new(0.0, 0.0, -1.0)])
}

/// Camera from a nadir camera turned about its x axis so that its optical axis points
/// `below_horizon_deg` below the horizon, towards the nadir image's top.
fn looking_down(below_horizon_deg: f64) -> Matrix3<f64> {
    let t = (90.0 - below_horizon_deg).to_radians();
    // Columns: the new axes in the nadir camera's frame (x kept, z towards the image top).
    Matrix3::from_columns(&[
        Vector3::x(),
        Vector3::new(0.0, t.cos(), t.sin()),
        Vector3::new(0.0, -t.sin(), t.cos()),
    ])
}

/// Small rotation jitter for frame `index`: independent per frame, σ `deg` about each axis.
fn jitter(seed: u64, index: usize, deg: f64) -> Matrix3<f64> {
    if deg <= 0.0 {
        return Matrix3::identity();
    }
    let s = deg.to_radians();
    let v = Vector3::new(
        gaussian(hash(&[seed, index as u64, 1])) * s,
        gaussian(hash(&[seed, index as u64, 2])) * s,
        gaussian(hash(&[seed, index as u64, 3])) * s,
    );
    *Rotation3::from_scaled_axis(v).matrix()
}

/// The camera pose at frame `index` (time `t`); `group_centre` is the centroid of the people
/// present, for `follow`.
pub fn camera_pose(
    motion: &Motion,
    seed: u64,
    index: usize,
    t: f64,
    group_centre: Option<Vector3<f64>>,
) -> CameraPose {
    match motion {
        Motion::Hover {
            position,
            heading_deg,
            drift_m,
            drift_period_s,
            jitter_deg,
            below_horizon_deg,
        } => {
            let w = std::f64::consts::TAU * t / drift_period_s.max(1e-3);
            let drift = Vector3::new(
                (w).sin(),
                (0.7 * w + 1.0).sin(),
                0.3 * (1.3 * w + 2.0).sin(),
            ) * *drift_m;
            // A slow tilt of a tenth of a degree, as a gimbal settles (a camera that does not
            // drift, on a pole, does not tilt either).
            let settle = if *drift_m > 0.0 {
                0.1f64.to_radians()
            } else {
                0.0
            };
            let tilt = Rotation3::from_scaled_axis(Vector3::new(
                settle * (0.5 * w).sin(),
                settle * (0.4 * w).cos(),
                0.0,
            ));
            CameraPose {
                centre: Vector3::new(position[0], position[1], position[2]) + drift,
                world_from_cam: tilt.matrix()
                    * nadir(*heading_deg)
                    * looking_down(*below_horizon_deg)
                    * jitter(seed, index, *jitter_deg),
            }
        }
        Motion::Path {
            waypoints,
            speed_m_s,
            heading_deg,
            jitter_deg,
        } => {
            let mut remaining = speed_m_s * t;
            let mut pos = Vector3::new(waypoints[0][0], waypoints[0][1], waypoints[0][2]);
            for w in waypoints.windows(2) {
                let (a, b) = (Vector3::from(w[0]), Vector3::from(w[1]));
                let len = (b - a).norm();
                if remaining <= len {
                    pos = a + (b - a) * (remaining / len.max(1e-12));
                    break;
                }
                remaining -= len;
                pos = b;
            }
            CameraPose {
                centre: pos,
                world_from_cam: nadir(*heading_deg) * jitter(seed, index, *jitter_deg),
            }
        }
        Motion::Follow {
            altitude_m,
            heading_deg,
            jitter_deg,
        } => {
            let c = group_centre.unwrap_or_else(Vector3::zeros);
            CameraPose {
                centre: Vector3::new(c.x, c.y, c.z + altitude_m),
                world_from_cam: nadir(*heading_deg) * jitter(seed, index, *jitter_deg),
            }
        }
    }
}

/// The photos of a survey flight: the nadir grid (flight lines running east, image top north,
/// lines alternating in direction), then the obliques. `fx`, `fy`, `width`, `height`: the photo
/// camera's focal lengths and size, pixels.
pub fn survey_poses(
    spec: &super::scene::SurveyFlightSpec,
    fx: f64,
    fy: f64,
    width: u32,
    height: u32,
    seed: u64,
) -> Vec<CameraPose> {
    let h = spec.altitude_m;
    let foot_e = h * f64::from(width) / fx;
    let foot_n = h * f64::from(height) / fy;
    let step_e = (foot_e * (1.0 - spec.forward_overlap)).max(0.5);
    let step_n = (foot_n * (1.0 - spec.side_overlap)).max(0.5);
    let [[e0, n0], [e1, n1]] = spec.area;
    let count = |span: f64, step: f64| (span / step).ceil() as usize + 1;
    let (ne, nn) = (count(e1 - e0, step_e), count(n1 - n0, step_n));
    let mut poses = Vec::new();
    for row in 0..nn {
        let n = n0 + (n1 - n0) * row as f64 / (nn - 1).max(1) as f64;
        for k in 0..ne {
            let col = if row % 2 == 0 { k } else { ne - 1 - k };
            let e = e0 + (e1 - e0) * col as f64 / (ne - 1).max(1) as f64;
            let index = poses.len();
            poses.push(CameraPose {
                centre: Vector3::new(e, n, h),
                world_from_cam: nadir(0.0) * jitter(seed ^ 0x05EE_DF11, index, spec.jitter_deg),
            });
        }
    }
    let target = Vector3::new((e0 + e1) / 2.0, (n0 + n1) / 2.0, 0.0);
    let reach = h * spec.oblique_deg.to_radians().tan();
    for k in 0..spec.obliques {
        let a = std::f64::consts::TAU * f64::from(k) / f64::from(spec.obliques);
        let forward = Vector3::new(a.sin(), a.cos(), 0.0);
        let centre = target - forward * reach + Vector3::new(0.0, 0.0, h);
        let z = (target - centre).normalize();
        // The image top away from the camera, level.
        let y0 = -forward;
        let y = (y0 - z * y0.dot(&z)).normalize();
        let x = y.cross(&z);
        poses.push(CameraPose {
            centre,
            world_from_cam: Matrix3::from_columns(&[x, y, z]),
        });
    }
    poses
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn nadir_looks_down_with_the_image_top_to_the_heading() {
        let r = nadir(0.0);
        assert_eq!(r * Vector3::z(), Vector3::new(0.0, 0.0, -1.0));
        // Image up (−y) is north.
        assert!((r * -Vector3::y() - Vector3::new(0.0, 1.0, 0.0)).norm() < 1e-12);
        assert!((r * Vector3::x() - Vector3::new(1.0, 0.0, 0.0)).norm() < 1e-12);
        let r90 = nadir(90.0);
        assert!((r90 * -Vector3::y() - Vector3::new(1.0, 0.0, 0.0)).norm() < 1e-12);
        assert!((r.determinant() - 1.0).abs() < 1e-12);
    }

    #[test]
    fn paths_are_followed_at_speed_and_hover_drifts_slowly() {
        let m = Motion::Path {
            waypoints: vec![[0.0, 0.0, 30.0], [10.0, 0.0, 30.0], [10.0, 10.0, 30.0]],
            speed_m_s: 2.0,
            heading_deg: 0.0,
            jitter_deg: 0.0,
        };
        assert!(
            (camera_pose(&m, 1, 0, 7.5, None).centre - Vector3::new(10.0, 5.0, 30.0)).norm()
                < 1e-12
        );
        assert!(
            (camera_pose(&m, 1, 0, 100.0, None).centre - Vector3::new(10.0, 10.0, 30.0)).norm()
                < 1e-12
        );
        let h = Motion::Hover {
            position: [0.0, 0.0, 30.0],
            heading_deg: 0.0,
            drift_m: 0.3,
            drift_period_s: 40.0,
            jitter_deg: 0.02,
            below_horizon_deg: 90.0,
        };
        let a = camera_pose(&h, 1, 0, 0.0, None);
        let b = camera_pose(&h, 1, 1, 0.04, None);
        assert!((a.centre - b.centre).norm() < 0.01);
        assert_eq!(camera_pose(&h, 1, 1, 0.04, None), b, "deterministic");
    }

    #[test]
    fn a_pole_camera_looks_below_the_horizon_towards_its_heading() {
        let pole = Motion::Hover {
            position: [0.0, -20.0, 12.0],
            heading_deg: 90.0,
            drift_m: 0.0,
            drift_period_s: 40.0,
            jitter_deg: 0.0,
            below_horizon_deg: 30.0,
        };
        let r = camera_pose(&pole, 1, 0, 0.0, None).world_from_cam;
        let (s, c) = (30f64.to_radians().sin(), 30f64.to_radians().cos());
        // The optical axis east and 30° down, the image's x to the south (right of east), its y
        // down and away.
        assert!((r * Vector3::z() - Vector3::new(c, 0.0, -s)).norm() < 1e-9);
        assert!((r * Vector3::x() - Vector3::new(0.0, -1.0, 0.0)).norm() < 1e-9);
        assert!((r * Vector3::y() - Vector3::new(-s, 0.0, -c)).norm() < 1e-9);
        assert!((r.determinant() - 1.0).abs() < 1e-12);
    }
}
