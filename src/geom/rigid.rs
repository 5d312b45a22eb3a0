//! The rigid transform, and the one increment every optimiser and covariance uses.
//!
//! A `Rigid3` named `b_from_a` maps points of frame a into frame b: `p_b = R·p_a + t`. Its
//! increment `δ = (δθ, δt)` (radians, then metres) moves the destination frame:
//! `b_from_a ← (exp(δθ), δt) ∘ b_from_a`, that is `p_b ← exp(δθ)·p_b + δt`. A 6×6 covariance of
//! a pose is a covariance of this δ (`docs/conventions.md`).

use std::ops::Mul;

use nalgebra::{
    Isometry3, Matrix3, Matrix6, Rotation3, Translation3, UnitQuaternion, Vector3, Vector6,
};

use super::skew;

/// A rigid transform `p_b = R·p_a + t`, named `b_from_a` where it is used.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Rigid3 {
    pub rotation: Rotation3<f64>,
    pub translation: Vector3<f64>,
}

impl Default for Rigid3 {
    fn default() -> Self {
        Rigid3::identity()
    }
}

impl Rigid3 {
    pub fn identity() -> Self {
        Rigid3 {
            rotation: Rotation3::identity(),
            translation: Vector3::zeros(),
        }
    }

    pub fn new(rotation: Rotation3<f64>, translation: Vector3<f64>) -> Self {
        Rigid3 {
            rotation,
            translation,
        }
    }

    /// From an OpenCV-style Rodrigues vector (axis × angle, radians) and translation.
    pub fn from_rvec_tvec(rvec: &Vector3<f64>, tvec: &Vector3<f64>) -> Self {
        Rigid3::new(Rotation3::from_scaled_axis(*rvec), *tvec)
    }

    /// The rotation's Rodrigues vector (axis × angle, radians).
    pub fn rvec(&self) -> Vector3<f64> {
        super::so3::log(&self.rotation)
    }

    /// `R·p + t`.
    pub fn apply(&self, p: &Vector3<f64>) -> Vector3<f64> {
        self.rotation * p + self.translation
    }

    /// The destination frame's origin in source coordinates: for `cam_from_world`, the camera
    /// centre in the world.
    pub fn centre(&self) -> Vector3<f64> {
        -(self.rotation.inverse() * self.translation)
    }

    /// The camera between this pose and `other` at fraction `t`: rotation by slerp (held at
    /// this one's where the two are opposite), centre linearly.
    pub fn interpolate(&self, other: &Rigid3, t: f64) -> Rigid3 {
        let qa = UnitQuaternion::from_rotation_matrix(&self.rotation);
        let qb = UnitQuaternion::from_rotation_matrix(&other.rotation);
        let rotation = qa
            .try_slerp(&qb, t, 1e-9)
            .unwrap_or(qa)
            .to_rotation_matrix();
        let c = self.centre() * (1.0 - t) + other.centre() * t;
        Rigid3::new(rotation, -(rotation * c))
    }

    /// `a_from_b` of this `b_from_a`.
    pub fn inverse(&self) -> Self {
        let r = self.rotation.inverse();
        Rigid3::new(r, -(r * self.translation))
    }

    /// The increment `δ = (δθ, δt)`: `p_b ← exp(δθ)·p_b + δt`.
    pub fn plus(&self, delta: &Vector6<f64>) -> Self {
        let r = Rotation3::from_scaled_axis(Vector3::new(delta[0], delta[1], delta[2]));
        Rigid3::new(
            r * self.rotation,
            r * self.translation + Vector3::new(delta[3], delta[4], delta[5]),
        )
    }

    /// `∂(R·p + t)/∂δ` at `δ = 0`: `[−[R·p + t]×, I]` (3×6 as two blocks).
    pub fn jacobian_of_apply(&self, p: &Vector3<f64>) -> (Matrix3<f64>, Matrix3<f64>) {
        (-skew(&self.apply(p)), Matrix3::identity())
    }

    /// The adjoint: for `c_from_b = self`, an increment `δ_b` of `b_from_a` is the increment
    /// `Ad·δ_b` of `c_from_a = self ∘ b_from_a` (the same motion, seen in frame c).
    pub fn adjoint(&self) -> Matrix6<f64> {
        let r = *self.rotation.matrix();
        let mut ad = Matrix6::zeros();
        ad.fixed_view_mut::<3, 3>(0, 0).copy_from(&r);
        ad.fixed_view_mut::<3, 3>(3, 0)
            .copy_from(&(skew(&self.translation) * r));
        ad.fixed_view_mut::<3, 3>(3, 3).copy_from(&r);
        ad
    }

    pub fn to_isometry(&self) -> Isometry3<f64> {
        Isometry3::from_parts(
            Translation3::from(self.translation),
            UnitQuaternion::from_rotation_matrix(&self.rotation),
        )
    }

    pub fn from_isometry(iso: &Isometry3<f64>) -> Self {
        Rigid3::new(iso.rotation.to_rotation_matrix(), iso.translation.vector)
    }
}

/// `c_from_a = c_from_b * b_from_a`.
impl Mul for Rigid3 {
    type Output = Rigid3;
    fn mul(self, rhs: Rigid3) -> Rigid3 {
        Rigid3::new(
            self.rotation * rhs.rotation,
            self.rotation * rhs.translation + self.translation,
        )
    }
}

/// The Jacobian `∂δ/∂(δw, δt')` that turns a covariance of additive increments of the
/// angle-axis vector `w` and the translation (what a bundle adjuster in Ceres's BAL
/// parameterisation estimates) into one of [`Rigid3::plus`]'s `δ` at the pose `(w, t)`.
/// `exp(w + δw) ≈ exp(J_l(w)·δw)·exp(w)` with `J_l` the left Jacobian of SO(3), and
/// `t + δt' = exp(δθ)·t + δt` gives `δt = δt' − δθ × t`.
pub fn tangent_from_angle_axis(w: &Vector3<f64>, t: &Vector3<f64>) -> Matrix6<f64> {
    let jl = super::so3::left_jacobian(w);
    let mut m = Matrix6::zeros();
    m.fixed_view_mut::<3, 3>(0, 0).copy_from(&jl);
    m.fixed_view_mut::<3, 3>(3, 0).copy_from(&(skew(t) * jl));
    m.fixed_view_mut::<3, 3>(3, 3)
        .copy_from(&Matrix3::identity());
    m
}

#[cfg(test)]
mod tests {
    use super::*;

    fn pose() -> Rigid3 {
        Rigid3::from_rvec_tvec(&Vector3::new(0.3, -0.2, 0.9), &Vector3::new(0.1, 0.2, 3.0))
    }

    #[test]
    fn compose_inverse_and_centre() {
        let a = pose();
        let b =
            Rigid3::from_rvec_tvec(&Vector3::new(-0.1, 0.5, 0.2), &Vector3::new(2.0, -1.0, 0.5));
        let p = Vector3::new(0.4, -0.7, 0.2);
        assert!(((a * b).apply(&p) - a.apply(&b.apply(&p))).norm() < 1e-12);
        assert!(((a * a.inverse()).apply(&p) - p).norm() < 1e-12);
        assert!(a.apply(&a.centre()).norm() < 1e-12);
        let iso = a.to_isometry();
        assert!(((iso * nalgebra::Point3::from(p)).coords - a.apply(&p)).norm() < 1e-12);
        assert!((Rigid3::from_isometry(&iso).apply(&p) - a.apply(&p)).norm() < 1e-12);
        assert!((a.rvec() - Vector3::new(0.3, -0.2, 0.9)).norm() < 1e-12);
    }

    #[test]
    fn the_increments_jacobian_and_adjoint_match_finite_differences() {
        let a = pose();
        let p = Vector3::new(0.4, -0.7, 0.2);
        let (jr, jt) = a.jacobian_of_apply(&p);
        let h = 1e-7;
        for k in 0..6 {
            let mut d = Vector6::zeros();
            d[k] = h;
            let fd = (a.plus(&d).apply(&p) - a.plus(&-d).apply(&p)) / (2.0 * h);
            let col = if k < 3 {
                jr.column(k)
            } else {
                jt.column(k - 3)
            };
            assert!((fd - col).norm() < 1e-7, "column {k}");
        }
        // The same motion seen through c_from_b: plus on the composition.
        let c_from_b =
            Rigid3::from_rvec_tvec(&Vector3::new(0.2, 0.1, -0.4), &Vector3::new(1.0, 2.0, -0.5));
        let d = Vector6::new(1e-6, -2e-6, 1.5e-6, 3e-6, -1e-6, 2e-6);
        let lhs = c_from_b * a.plus(&d);
        let rhs = (c_from_b * a).plus(&(c_from_b.adjoint() * d));
        assert!((lhs.apply(&p) - rhs.apply(&p)).norm() < 1e-10);
    }

    #[test]
    fn angle_axis_increments_map_to_the_tangent() {
        let w = Vector3::new(0.3, -1.2, 2.0);
        let t = Vector3::new(0.5, -0.2, 30.0);
        let m = tangent_from_angle_axis(&w, &t);
        let base = Rigid3::from_rvec_tvec(&w, &t);
        let p = Vector3::new(1.0, 2.0, -3.0);
        for k in 0..6 {
            let mut d = Vector6::zeros();
            d[k] = 1e-6;
            let moved =
                Rigid3::from_rvec_tvec(&(w + d.fixed_rows::<3>(0)), &(t + d.fixed_rows::<3>(3)));
            let via = base.plus(&(m * d));
            assert!(
                (moved.apply(&p) - via.apply(&p)).norm() < 1e-10,
                "column {k}"
            );
        }
    }
}
