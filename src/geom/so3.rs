//! Rotations as angle-axis vectors (SO(3)): the rotation matrix and the left Jacobian, what the
//! bundle adjuster's and the pose refinement's parameters and Jacobians are made of.

use nalgebra::{Matrix3, Rotation3, UnitQuaternion, Vector3};

/// The angle-axis vector of a rotation (the inverse of [`rotation`]), finite and precise for any
/// rotation matrix that is orthonormal to rounding. nalgebra's `Rotation3::scaled_axis` takes
/// the angle as `acos((trace − 1) / 2)`: a trace a few ulps over 3 (a near-identity rotation
/// from an SVD or a decomposition) gives NaN, and near zero it loses half the digits.
pub fn log(r: &Rotation3<f64>) -> Vector3<f64> {
    UnitQuaternion::from_rotation_matrix(r).scaled_axis()
}

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

/// A rotation matrix that is the identity to rounding but whose trace is a few ulps over 3,
/// as the homography start of two near-identical photos gave: nalgebra's `scaled_axis` makes
/// it NaN (the tests of [`log`] and of the bundle adjuster's pose parameters).
#[cfg(test)]
pub(crate) fn near_identity_over_trace() -> Matrix3<f64> {
    Matrix3::new(
        1.0000000000000004,
        -1.09e-14,
        3.83e-14,
        1.15e-14,
        1.0000000000000002,
        9.0e-16,
        -3.84e-14,
        -7.9e-16,
        1.0000000000000002,
    )
}

#[cfg(test)]
mod log_tests {
    use super::*;

    /// Near-identity matrices a few ulps off orthonormal (trace over 3: nalgebra's
    /// `scaled_axis` gives NaN) and small and large angles: `log` inverts `rotation`.
    #[test]
    fn log_is_finite_and_inverts_rotation() {
        let over = Rotation3::<f64>::from_matrix_unchecked(near_identity_over_trace());
        assert!(
            over.scaled_axis().x.is_nan(),
            "nalgebra's NaN is the case this guards"
        );
        let w = log(&over);
        assert!(w.iter().all(|v| v.is_finite()) && w.norm() < 1e-13, "{w:?}");
        for w in [
            Vector3::new(1e-9, -2e-9, 3e-9),
            Vector3::new(0.3, -0.2, 0.1),
            Vector3::new(0.0, 3.0, 0.0),
        ] {
            let back = log(&Rotation3::from_matrix_unchecked(rotation(&w)));
            assert!(
                (back - w).norm() < 1e-12 * w.norm().max(1.0),
                "{w:?} → {back:?}"
            );
        }
    }
}
