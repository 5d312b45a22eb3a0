//! Rotations as angle-axis vectors (SO(3)): the rotation matrix and the left Jacobian, what the
//! bundle adjuster's and the pose refinement's parameters and Jacobians are made of.

use nalgebra::{Matrix3, Vector3};

/// The rotation matrix of an angle-axis vector (Rodrigues); to first order near zero.
pub fn rotation(w: &Vector3<f64>) -> Matrix3<f64> {
    let theta2 = w.norm_squared();
    let k = w.cross_matrix();
    if theta2 > f64::EPSILON {
        let theta = theta2.sqrt();
        Matrix3::identity() + k * (theta.sin() / theta) + k * k * ((1.0 - theta.cos()) / theta2)
    } else {
        Matrix3::identity() + k
    }
}

/// The left Jacobian of SO(3): `exp(w + δ) ≈ exp(J_l(w)·δ)·exp(w)`, so that
/// `∂(R(w)·X)/∂w = −[R(w)·X]ₓ · J_l(w)` (the bundle adjuster's, the pose refinement's and
/// `rigid::tangent_from_angle_axis`'s one).
pub fn left_jacobian(w: &Vector3<f64>) -> Matrix3<f64> {
    let theta2 = w.norm_squared();
    let k = w.cross_matrix();
    if theta2 > 1e-12 {
        let theta = theta2.sqrt();
        Matrix3::identity()
            + k * ((1.0 - theta.cos()) / theta2)
            + k * k * ((theta - theta.sin()) / (theta2 * theta))
    } else {
        Matrix3::identity() + k * 0.5 + k * k / 6.0
    }
}
