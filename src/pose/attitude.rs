//! Yaw, pitch and roll of a (near-)nadir camera, and its deviation from nadir.
//!
//! The reference attitude is nadir with the image top to the north: camera x east, y south,
//! z down. The camera's attitude is `world_from_cam = Rz(−yaw) · Rx(pitch) · Ry(−roll) · N`,
//! with N that reference: yaw is the compass direction of the image top (clockwise from north),
//! pitch tilts the optical axis towards the image top, roll towards the image right.

use nalgebra::{Matrix3, Rotation3, Vector3};
use serde::Serialize;

/// Angles in degrees.
#[derive(Clone, Copy, Debug, PartialEq, Serialize)]
pub struct Attitude {
    pub yaw_deg: f64,
    pub pitch_deg: f64,
    pub roll_deg: f64,
    /// Angle between the optical axis and the downward vertical.
    pub off_nadir_deg: f64,
}

fn nadir() -> Matrix3<f64> {
    Matrix3::new(1.0, 0.0, 0.0, 0.0, -1.0, 0.0, 0.0, 0.0, -1.0)
}

impl Attitude {
    pub fn from_world_from_cam(r: &Matrix3<f64>) -> Attitude {
        // M = Rz(a) Rx(b) Ry(c): its last row is (−cos b sin c, sin b, cos b cos c) and its second
        // column (−sin a cos b, cos a cos b, sin b).
        let m = r * nadir().transpose();
        let b = m[(2, 1)].clamp(-1.0, 1.0).asin();
        let c = (-m[(2, 0)]).atan2(m[(2, 2)]);
        let a = (-m[(0, 1)]).atan2(m[(1, 1)]);
        let axis = r * Vector3::z();
        let yaw = (-a.to_degrees()).rem_euclid(360.0);
        Attitude {
            yaw_deg: if yaw >= 359.9999999995 { 0.0 } else { yaw },
            pitch_deg: b.to_degrees(),
            roll_deg: -c.to_degrees(),
            off_nadir_deg: (-axis.z).clamp(-1.0, 1.0).acos().to_degrees(),
        }
    }

    /// `world_from_cam` of these angles.
    pub fn world_from_cam(&self) -> Matrix3<f64> {
        let rz = Rotation3::from_axis_angle(&Vector3::z_axis(), -self.yaw_deg.to_radians());
        let rx = Rotation3::from_axis_angle(&Vector3::x_axis(), self.pitch_deg.to_radians());
        let ry = Rotation3::from_axis_angle(&Vector3::y_axis(), -self.roll_deg.to_radians());
        (rz * rx * ry).matrix() * nadir()
    }
}

/// σ of yaw, pitch and roll (degrees) from the covariance of a rotation error `δφ` about the
/// world axes (`world_from_cam' = exp(δφ) world_from_cam`), by central differences.
pub fn attitude_sigma_deg(world_from_cam: &Matrix3<f64>, cov_phi: &Matrix3<f64>) -> [f64; 3] {
    let eps = 1e-6;
    let mut j = Matrix3::zeros();
    for k in 0..3 {
        let mut d = Vector3::zeros();
        d[k] = eps;
        let a = Attitude::from_world_from_cam(&(Rotation3::new(d).matrix() * world_from_cam));
        let b = Attitude::from_world_from_cam(&(Rotation3::new(-d).matrix() * world_from_cam));
        // Yaw wraps at 0/360.
        let dyaw = (a.yaw_deg - b.yaw_deg + 540.0).rem_euclid(360.0) - 180.0;
        j.set_column(
            k,
            &(Vector3::new(dyaw, a.pitch_deg - b.pitch_deg, a.roll_deg - b.roll_deg) / (2.0 * eps)),
        );
    }
    let c = j * cov_phi * j.transpose();
    [
        c[(0, 0)].max(0.0).sqrt(),
        c[(1, 1)].max(0.0).sqrt(),
        c[(2, 2)].max(0.0).sqrt(),
    ]
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn sigmas_of_a_nadir_camera_follow_the_world_axes() {
        let r = Attitude {
            yaw_deg: 0.0,
            pitch_deg: 0.0,
            roll_deg: 0.0,
            off_nadir_deg: 0.0,
        }
        .world_from_cam();
        let cov = Matrix3::from_diagonal(&Vector3::new(1e-6, 4e-6, 9e-6));
        let s = attitude_sigma_deg(&r, &cov);
        // Yaw about up, pitch about east, roll about north.
        let deg = 1e-3f64.to_degrees();
        assert!(
            (s[0] - 3.0 * deg).abs() < 1e-6
                && (s[1] - deg).abs() < 1e-6
                && (s[2] - 2.0 * deg).abs() < 1e-6,
            "{s:?}"
        );
    }

    #[test]
    fn angles_round_trip_and_mean_what_they_say() {
        for (y, p, r) in [
            (0.0, 0.0, 0.0),
            (30.0, 2.0, -1.5),
            (271.0, -4.0, 3.0),
            (90.0, 10.0, 0.0),
        ] {
            let a = Attitude {
                yaw_deg: y,
                pitch_deg: p,
                roll_deg: r,
                off_nadir_deg: 0.0,
            };
            let b = Attitude::from_world_from_cam(&a.world_from_cam());
            assert!(
                (b.yaw_deg - y).abs() < 1e-9
                    && (b.pitch_deg - p).abs() < 1e-9
                    && (b.roll_deg - r).abs() < 1e-9,
                "{b:?}"
            );
        }
        // Yaw 90: the image top (−y of the camera) points east.
        let m = Attitude {
            yaw_deg: 90.0,
            pitch_deg: 0.0,
            roll_deg: 0.0,
            off_nadir_deg: 0.0,
        }
        .world_from_cam();
        assert!((m * -Vector3::y() - Vector3::x()).norm() < 1e-12);
        // Pitch up: the optical axis leans towards the image top (north at yaw 0).
        let m = Attitude {
            yaw_deg: 0.0,
            pitch_deg: 5.0,
            roll_deg: 0.0,
            off_nadir_deg: 0.0,
        }
        .world_from_cam();
        assert!((m * Vector3::z()).y > 0.0);
        assert!((Attitude::from_world_from_cam(&m).off_nadir_deg - 5.0).abs() < 1e-9);
        // Roll: towards the image right (east at yaw 0).
        let m = Attitude {
            yaw_deg: 0.0,
            pitch_deg: 0.0,
            roll_deg: 3.0,
            off_nadir_deg: 0.0,
        }
        .world_from_cam();
        assert!((m * Vector3::z()).x > 0.0);
    }
}
