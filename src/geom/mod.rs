//! Pure geometry: rotations and rigid transforms (nalgebra and std only).
//!
//! Transforms are named `dst_from_src`: `p_cam = cam_from_world * p_world`.

pub mod geodesy;
pub mod rigid;
pub mod similarity;
pub mod so3;

pub use rigid::Rigid3;

use nalgebra::{Matrix3, Rotation3, Vector3};

/// The cross-product matrix: `skew(a) * b == a.cross(&b)`.
pub fn skew(a: &Vector3<f64>) -> Matrix3<f64> {
    Matrix3::new(0.0, -a.z, a.y, a.z, 0.0, -a.x, -a.y, a.x, 0.0)
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
    fn nearest_rotation_of_a_rotation_is_itself() {
        let r = Rotation3::from_scaled_axis(Vector3::new(0.1, 0.2, -0.3));
        let n = nearest_rotation(r.matrix());
        assert!((n.matrix() - r.matrix()).norm() < 1e-12);
        let noisy = r.matrix() * 1.1 + Matrix3::from_element(0.01);
        let n = nearest_rotation(&noisy);
        assert!((n.matrix() * n.matrix().transpose() - Matrix3::identity()).norm() < 1e-12);
    }
}
