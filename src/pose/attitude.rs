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

#[cfg(test)]
mod tests {
    use super::*;

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
