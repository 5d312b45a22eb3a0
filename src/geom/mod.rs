//! Pure geometry: rotations and rigid transforms (nalgebra and std only).
//!
//! Transforms are named `dst_from_src`: `p_cam = cam_from_world * p_world`.

pub mod geodesy;
pub mod similarity;

use nalgebra::{Isometry3, Matrix3, Rotation3, Translation3, UnitQuaternion, Vector3};

/// A rigid transform. Named by its frames at the use site, e.g. `cam_from_board: Pose`.
pub type Pose = Isometry3<f64>;

/// The cross-product matrix: `skew(a) * b == a.cross(&b)`.
pub fn skew(a: &Vector3<f64>) -> Matrix3<f64> {
    Matrix3::new(0.0, -a.z, a.y, a.z, 0.0, -a.x, -a.y, a.x, 0.0)
}

/// A pose from an OpenCV-style Rodrigues rotation vector (radians) and translation.
pub fn pose_from_rvec_tvec(rvec: &Vector3<f64>, tvec: &Vector3<f64>) -> Pose {
    Isometry3::from_parts(
        Translation3::from(*tvec),
        UnitQuaternion::from_scaled_axis(*rvec),
    )
}

/// The Rodrigues rotation vector (axis times angle, radians) of a pose's rotation.
pub fn rvec_of(pose: &Pose) -> Vector3<f64> {
    pose.rotation.scaled_axis()
}

/// Applies a local increment: rotation `exp(delta_rot) * R` (left, in the destination frame),
/// translation `t + delta_t`. This is the manifold update used by every pose optimiser here, so
/// the Jacobian of `R X + t` with respect to `delta_rot` is `-skew(R X)`.
pub fn pose_plus(pose: &Pose, delta_rot: &Vector3<f64>, delta_t: &Vector3<f64>) -> Pose {
    let rot = UnitQuaternion::from_scaled_axis(*delta_rot) * pose.rotation;
    Isometry3::from_parts(Translation3::from(pose.translation.vector + delta_t), rot)
}

/// Projects a 3x3 matrix onto the nearest rotation (Frobenius norm), via SVD.
pub fn nearest_rotation(m: &Matrix3<f64>) -> Rotation3<f64> {
    let svd = m.svd(true, true);
    let u = svd.u.expect("svd u");
    let v_t = svd.v_t.expect("svd v_t");
    let mut r = u * v_t;
    if r.determinant() < 0.0 {
        let mut u2 = u;
        u2.column_mut(2).neg_mut();
        r = u2 * v_t;
    }
    Rotation3::from_matrix_unchecked(r)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn pose_plus_jacobian_matches_finite_differences() {
        let pose = pose_from_rvec_tvec(&Vector3::new(0.3, -0.2, 0.9), &Vector3::new(0.1, 0.2, 3.0));
        let x = Vector3::new(0.4, -0.7, 0.2);
        let analytic = -skew(&(pose.rotation * x));
        let h = 1e-7;
        for k in 0..3 {
            let mut d = Vector3::zeros();
            d[k] = h;
            let plus = pose_plus(&pose, &d, &Vector3::zeros()) * nalgebra::Point3::from(x);
            let minus = pose_plus(&pose, &(-d), &Vector3::zeros()) * nalgebra::Point3::from(x);
            let fd = (plus - minus) / (2.0 * h);
            assert!((fd - analytic.column(k)).norm() < 1e-8, "column {k}");
        }
    }

    #[test]
    fn rvec_round_trip() {
        let r = Vector3::new(0.5, -1.2, 2.0);
        let p = pose_from_rvec_tvec(&r, &Vector3::zeros());
        assert!((rvec_of(&p) - r).norm() < 1e-12);
    }

    #[test]
    fn nearest_rotation_of_a_rotation_is_itself() {
        let r = Rotation3::from_scaled_axis(Vector3::new(0.1, 0.2, -0.3));
        let n = nearest_rotation(r.matrix());
        assert!((n.matrix() - r.matrix()).norm() < 1e-12);
        let noisy = r.matrix() * 1.1 + Matrix3::from_element(0.01);
        let n = nearest_rotation(&noisy);
        assert!((n.matrix() * n.matrix().transpose() - Matrix3::identity()).norm() < 1e-12);
    }
}
