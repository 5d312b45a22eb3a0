//! Pinhole camera with Brown–Conrady distortion, in OpenCV's formulation.
//!
//! Normalised coordinates `(x, y) = (X/Z, Y/Z)`, `r² = x² + y²`:
//!
//! ```text
//! radial = (1 + k1 r² + k2 r⁴ + k3 r⁶) / (1 + k4 r² + k5 r⁴ + k6 r⁶)
//! xd = x·radial + 2 p1 x y + p2 (r² + 2 x²)
//! yd = y·radial + p1 (r² + 2 y²) + 2 p2 x y
//! u  = fx·xd + skew·yd + cx
//! v  = fy·yd + cy
//! ```
//!
//! Pixel (0, 0) is the centre of the top-left pixel (OpenCV). With `k4 = k5 = k6 = 0` this is
//! the plain polynomial model (`k1 k2 p1 p2 k3`), with them the rational model.

use nalgebra::{Matrix2, Matrix2x3, SMatrix, Unit, Vector2, Vector3};
use thiserror::Error;

/// Number of camera parameters, in the order of [`PARAM_NAMES`].
pub const N_PARAMS: usize = 13;

/// Parameter order used by [`Camera::params`] and every Jacobian: the pinhole part, then the
/// distortion in OpenCV order.
pub const PARAM_NAMES: [&str; N_PARAMS] = [
    "fx", "fy", "cx", "cy", "skew", "k1", "k2", "p1", "p2", "k3", "k4", "k5", "k6",
];

/// Index of each parameter in [`Camera::params`].
pub mod param {
    pub const FX: usize = 0;
    pub const FY: usize = 1;
    pub const CX: usize = 2;
    pub const CY: usize = 3;
    pub const SKEW: usize = 4;
    pub const K1: usize = 5;
    pub const K2: usize = 6;
    pub const P1: usize = 7;
    pub const P2: usize = 8;
    pub const K3: usize = 9;
    pub const K4: usize = 10;
    pub const K5: usize = 11;
    pub const K6: usize = 12;
    /// Index of the first distortion coefficient; distortion `i` (OpenCV order) is `DIST0 + i`.
    pub const DIST0: usize = 5;
}

/// Jacobian of a pixel with respect to every camera parameter.
pub type ParamJacobian = SMatrix<f64, 2, N_PARAMS>;

/// Image size in pixels.
#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Serialize)]
pub struct ImageSize {
    pub width: u32,
    pub height: u32,
}

/// A pinhole camera with Brown–Conrady distortion (OpenCV's model, with optional skew).
/// Serialises as its fields (reports); calibration files go through [`super::formats`].
#[derive(Clone, Debug, PartialEq, serde::Serialize)]
pub struct Camera {
    /// The image size the intrinsics refer to, when known.
    pub image_size: Option<ImageSize>,
    /// Focal lengths in pixels.
    pub fx: f64,
    pub fy: f64,
    /// Principal point in pixels (pixel centres at integers).
    pub cx: f64,
    pub cy: f64,
    /// Skew in pixels (`K[0][1]`); zero for every modern sensor.
    pub skew: f64,
    /// Distortion in OpenCV order: `k1 k2 p1 p2 k3 k4 k5 k6`.
    pub dist: [f64; 8],
}

#[derive(Debug, Error, Clone, PartialEq)]
pub enum CameraError {
    #[error(
        "undistortion did not converge for normalised point ({x:.6}, {y:.6}) after {iterations} iterations \
         (residual {residual:.3e}); the point lies outside the region where the distortion model is invertible"
    )]
    UndistortNotConverged {
        x: f64,
        y: f64,
        iterations: usize,
        residual: f64,
    },
    #[error("point is behind the camera (z = {z})")]
    BehindCamera { z: f64 },
    #[error("the rational distortion denominator is not positive at r² = {r2:.4}")]
    DenominatorNotPositive { r2: f64 },
}

/// Distortion of one normalised point with its derivatives.
struct DistortEval {
    xd: Vector2<f64>,
    /// d(xd, yd) / d(x, y)
    d_xy: Matrix2<f64>,
    /// d(xd, yd) / d(k1 k2 p1 p2 k3 k4 k5 k6)
    d_dist: SMatrix<f64, 2, 8>,
}

impl Camera {
    /// A distortion-free camera.
    pub fn pinhole(fx: f64, fy: f64, cx: f64, cy: f64) -> Self {
        Camera {
            image_size: None,
            fx,
            fy,
            cx,
            cy,
            skew: 0.0,
            dist: [0.0; 8],
        }
    }

    pub fn with_image_size(mut self, width: u32, height: u32) -> Self {
        self.image_size = Some(ImageSize { width, height });
        self
    }

    pub fn with_distortion(mut self, dist: &[f64]) -> Self {
        self.dist = [0.0; 8];
        self.dist[..dist.len().min(8)].copy_from_slice(&dist[..dist.len().min(8)]);
        self
    }

    /// The same camera at another resolution of the same aspect ratio (a video mode, say), or
    /// `None` when the aspect ratio differs (the sensor crop would be unknown). Pixel centres stay
    /// at integers: `c' = (c + 0.5)·s − 0.5`.
    pub fn scaled_to(&self, width: u32, height: u32) -> Option<Camera> {
        let size = self.image_size?;
        let sx = f64::from(width) / f64::from(size.width);
        let sy = f64::from(height) / f64::from(size.height);
        if (sx - sy).abs() > 1e-3 * sx {
            return None;
        }
        Some(Camera {
            image_size: Some(ImageSize { width, height }),
            fx: self.fx * sx,
            fy: self.fy * sy,
            cx: (self.cx + 0.5) * sx - 0.5,
            cy: (self.cy + 0.5) * sy - 0.5,
            skew: self.skew * sx,
            dist: self.dist,
        })
    }

    /// All parameters in [`PARAM_NAMES`] order.
    pub fn params(&self) -> [f64; N_PARAMS] {
        let d = &self.dist;
        [
            self.fx, self.fy, self.cx, self.cy, self.skew, d[0], d[1], d[2], d[3], d[4], d[5],
            d[6], d[7],
        ]
    }

    /// Sets all parameters from [`PARAM_NAMES`] order; the image size is kept.
    pub fn set_params(&mut self, p: &[f64; N_PARAMS]) {
        self.fx = p[0];
        self.fy = p[1];
        self.cx = p[2];
        self.cy = p[3];
        self.skew = p[4];
        self.dist.copy_from_slice(&p[5..13]);
    }

    /// True when the rational terms k4..k6 are in use.
    pub fn is_rational(&self) -> bool {
        self.dist[5..8].iter().any(|&k| k != 0.0)
    }

    /// The 3x3 camera matrix `K`.
    pub fn k_matrix(&self) -> nalgebra::Matrix3<f64> {
        nalgebra::Matrix3::new(
            self.fx, self.skew, self.cx, 0.0, self.fy, self.cy, 0.0, 0.0, 1.0,
        )
    }

    /// The distorted point, and what its derivatives need: `r², r⁴, r⁶, a, b`, the rational
    /// radial factor being `a / b`.
    #[inline]
    fn distorted(&self, xy: &Vector2<f64>) -> Result<(Vector2<f64>, [f64; 5]), CameraError> {
        let [k1, k2, p1, p2, k3, k4, k5, k6] = self.dist;
        let (x, y) = (xy.x, xy.y);
        let r2 = x * x + y * y;
        let r4 = r2 * r2;
        let r6 = r4 * r2;
        let a = 1.0 + k1 * r2 + k2 * r4 + k3 * r6;
        let b = 1.0 + k4 * r2 + k5 * r4 + k6 * r6;
        if b <= 0.0 {
            return Err(CameraError::DenominatorNotPositive { r2 });
        }
        let radial = a / b;
        let xd = x * radial + 2.0 * p1 * x * y + p2 * (r2 + 2.0 * x * x);
        let yd = y * radial + p1 * (r2 + 2.0 * y * y) + 2.0 * p2 * x * y;
        Ok((Vector2::new(xd, yd), [r2, r4, r6, a, b]))
    }

    fn distort_eval(&self, xy: &Vector2<f64>) -> Result<DistortEval, CameraError> {
        let [k1, k2, p1, p2, k3, k4, k5, k6] = self.dist;
        let (x, y) = (xy.x, xy.y);
        let (xd, [r2, r4, r6, a, b]) = self.distorted(xy)?;
        let radial = a / b;
        // d radial / d r²
        let da = k1 + 2.0 * k2 * r2 + 3.0 * k3 * r4;
        let db = k4 + 2.0 * k5 * r2 + 3.0 * k6 * r4;
        let dradial = (da * b - a * db) / (b * b);

        let d_xy = Matrix2::new(
            radial + 2.0 * x * x * dradial + 2.0 * p1 * y + 6.0 * p2 * x,
            2.0 * x * y * dradial + 2.0 * p1 * x + 2.0 * p2 * y,
            2.0 * x * y * dradial + 2.0 * p1 * x + 2.0 * p2 * y,
            radial + 2.0 * y * y * dradial + 6.0 * p1 * y + 2.0 * p2 * x,
        );

        let inv_b = 1.0 / b;
        let num = [r2 * inv_b, r4 * inv_b, r6 * inv_b];
        let den = [
            -radial * r2 * inv_b,
            -radial * r4 * inv_b,
            -radial * r6 * inv_b,
        ];
        #[rustfmt::skip]
        let d_dist = SMatrix::<f64, 2, 8>::from_row_slice(&[
            x * num[0], x * num[1], 2.0 * x * y,         r2 + 2.0 * x * x, x * num[2], x * den[0], x * den[1], x * den[2],
            y * num[0], y * num[1], r2 + 2.0 * y * y,    2.0 * x * y,      y * num[2], y * den[0], y * den[1], y * den[2],
        ]);
        Ok(DistortEval { xd, d_xy, d_dist })
    }

    /// Applies the distortion to undistorted normalised coordinates (without the derivatives:
    /// every projection goes through here).
    pub fn distort(&self, xy: &Vector2<f64>) -> Result<Vector2<f64>, CameraError> {
        Ok(self.distorted(xy)?.0)
    }

    /// Maps distorted normalised coordinates to pixels.
    pub fn normalized_distorted_to_pixel(&self, xd: &Vector2<f64>) -> Vector2<f64> {
        Vector2::new(
            self.fx * xd.x + self.skew * xd.y + self.cx,
            self.fy * xd.y + self.cy,
        )
    }

    /// Maps pixels to distorted normalised coordinates (the inverse of `K`).
    pub fn pixel_to_normalized_distorted(&self, uv: &Vector2<f64>) -> Vector2<f64> {
        let yd = (uv.y - self.cy) / self.fy;
        let xd = (uv.x - self.cx - self.skew * yd) / self.fx;
        Vector2::new(xd, yd)
    }

    /// Undistorted normalised coordinates to pixels.
    pub fn normalized_to_pixel(&self, xy: &Vector2<f64>) -> Result<Vector2<f64>, CameraError> {
        Ok(self.normalized_distorted_to_pixel(&self.distort(xy)?))
    }

    /// Projects a point in the camera frame (metres) to pixels.
    pub fn project(&self, p_cam: &Vector3<f64>) -> Result<Vector2<f64>, CameraError> {
        if p_cam.z <= 0.0 {
            return Err(CameraError::BehindCamera { z: p_cam.z });
        }
        self.normalized_to_pixel(&Vector2::new(p_cam.x / p_cam.z, p_cam.y / p_cam.z))
    }

    /// Projects a point and returns the pixel with its Jacobians with respect to the point
    /// (2x3) and to every parameter (2x13, [`PARAM_NAMES`] order).
    pub fn project_with_jacobians(
        &self,
        p_cam: &Vector3<f64>,
    ) -> Result<(Vector2<f64>, Matrix2x3<f64>, ParamJacobian), CameraError> {
        if p_cam.z <= 0.0 {
            return Err(CameraError::BehindCamera { z: p_cam.z });
        }
        let inv_z = 1.0 / p_cam.z;
        let xy = Vector2::new(p_cam.x * inv_z, p_cam.y * inv_z);
        let e = self.distort_eval(&xy)?;
        let (xd, yd) = (e.xd.x, e.xd.y);
        let uv = self.normalized_distorted_to_pixel(&e.xd);

        // d(u, v) / d(xd, yd)
        let a = Matrix2::new(self.fx, self.skew, 0.0, self.fy);
        // d(x, y) / d(X, Y, Z)
        let d_norm = Matrix2x3::new(inv_z, 0.0, -xy.x * inv_z, 0.0, inv_z, -xy.y * inv_z);
        let j_point = a * e.d_xy * d_norm;

        let mut j_params = ParamJacobian::zeros();
        j_params[(0, param::FX)] = xd;
        j_params[(1, param::FY)] = yd;
        j_params[(0, param::CX)] = 1.0;
        j_params[(1, param::CY)] = 1.0;
        j_params[(0, param::SKEW)] = yd;
        let j_dist = a * e.d_dist;
        j_params
            .fixed_view_mut::<2, 8>(0, param::DIST0)
            .copy_from(&j_dist);
        Ok((uv, j_point, j_params))
    }

    /// Inverts the distortion: distorted normalised coordinates to undistorted ones, by Newton's
    /// method with backtracking. Fails, rather than returning a wrong point, where the model is not
    /// invertible (beyond the fold of a strongly negative radial term, say).
    pub fn undistort(&self, xd: &Vector2<f64>) -> Result<Vector2<f64>, CameraError> {
        const MAX_ITER: usize = 50;
        const TOL: f64 = 1e-13;
        if self.dist.iter().all(|&k| k == 0.0) {
            return Ok(*xd);
        }
        let mut xy = *xd;
        let fail = |iterations, residual| CameraError::UndistortNotConverged {
            x: xd.x,
            y: xd.y,
            iterations,
            residual,
        };
        let mut e = self.distort_eval(&xy).map_err(|_| fail(0, f64::INFINITY))?;
        let mut res = e.xd - xd;
        for it in 0..MAX_ITER {
            let rn = res.norm();
            if rn <= TOL * (1.0 + xd.norm()) {
                // Converged; the Jacobian must be orientation-preserving, or we found a point on
                // the far side of the fold, which maps to the same pixel but is not the true ray.
                if e.d_xy.determinant() <= 0.0 {
                    return Err(fail(it, rn));
                }
                return Ok(xy);
            }
            let step = match e.d_xy.try_inverse() {
                Some(inv) => -(inv * res),
                None => return Err(fail(it, rn)),
            };
            let mut t = 1.0;
            loop {
                let cand = xy + step * t;
                if let Ok(ce) = self.distort_eval(&cand) {
                    let cres = ce.xd - xd;
                    if cres.norm() < rn {
                        xy = cand;
                        e = ce;
                        res = cres;
                        break;
                    }
                }
                t *= 0.5;
                if t < 1e-6 {
                    return Err(fail(it, rn));
                }
            }
        }
        Err(fail(MAX_ITER, res.norm()))
    }

    /// Pixel to undistorted normalised coordinates.
    pub fn pixel_to_normalized(&self, uv: &Vector2<f64>) -> Result<Vector2<f64>, CameraError> {
        self.undistort(&self.pixel_to_normalized_distorted(uv))
    }

    /// Pixel to the unit ray in the camera frame (x right, y down, z forward).
    pub fn unproject(&self, uv: &Vector2<f64>) -> Result<Unit<Vector3<f64>>, CameraError> {
        let xy = self.pixel_to_normalized(uv)?;
        Ok(Unit::new_normalize(Vector3::new(xy.x, xy.y, 1.0)))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    pub(crate) fn test_cameras() -> Vec<Camera> {
        vec![
            Camera::pinhole(800.0, 790.0, 320.5, 240.25),
            Camera::pinhole(535.9, 535.9, 342.3, 235.6)
                .with_distortion(&[-0.266, -0.0386, 0.00178, -0.00028, 0.238]),
            Camera {
                skew: 1.5,
                ..Camera::pinhole(1200.0, 1210.0, 640.0, 480.0)
                    .with_distortion(&[0.12, -0.3, 0.002, -0.001, 0.05, 0.09, -0.2, 0.04])
            },
        ]
    }

    fn points() -> Vec<Vector3<f64>> {
        vec![
            Vector3::new(0.1, -0.2, 2.0),
            Vector3::new(-0.5, 0.3, 1.5),
            Vector3::new(0.6, 0.4, 3.0),
            Vector3::new(0.0, 0.0, 1.0),
        ]
    }

    /// The derivative-free distortion is `distort_eval`'s, bit for bit.
    #[test]
    fn distort_is_the_evaluations_point() {
        for cam in test_cameras() {
            for i in 0..200 {
                let t = f64::from(i) * 0.37;
                let xy = Vector2::new(0.6 * t.sin(), 0.45 * (1.3 * t).cos());
                assert_eq!(cam.distort(&xy).unwrap(), cam.distort_eval(&xy).unwrap().xd);
            }
        }
    }

    #[test]
    fn point_jacobian_matches_finite_differences() {
        for cam in test_cameras() {
            for p in points() {
                let (_, jp, _) = cam.project_with_jacobians(&p).unwrap();
                for k in 0..3 {
                    let h = 1e-6;
                    let mut a = p;
                    let mut b = p;
                    a[k] += h;
                    b[k] -= h;
                    let fd = (cam.project(&a).unwrap() - cam.project(&b).unwrap()) / (2.0 * h);
                    let err = (fd - jp.column(k)).norm();
                    assert!(err < 1e-5 * (1.0 + fd.norm()), "point column {k}: {err}");
                }
            }
        }
    }

    #[test]
    fn parameter_jacobian_matches_finite_differences() {
        for cam in test_cameras() {
            for p in points() {
                let (_, _, jk) = cam.project_with_jacobians(&p).unwrap();
                for k in 0..N_PARAMS {
                    let h = 1e-6 * (1.0 + cam.params()[k].abs());
                    let mut a = cam.clone();
                    let mut b = cam.clone();
                    let mut pa = cam.params();
                    let mut pb = cam.params();
                    pa[k] += h;
                    pb[k] -= h;
                    a.set_params(&pa);
                    b.set_params(&pb);
                    let fd = (a.project(&p).unwrap() - b.project(&p).unwrap()) / (2.0 * h);
                    let err = (fd - jk.column(k)).norm();
                    assert!(
                        err < 1e-6 * (1.0 + fd.norm()),
                        "{}: analytic {:?} fd {:?}",
                        PARAM_NAMES[k],
                        jk.column(k),
                        fd
                    );
                }
            }
        }
    }

    #[test]
    fn undistort_inverts_distort() {
        for cam in test_cameras() {
            for p in points() {
                let uv = cam.project(&p).unwrap();
                let ray = cam.unproject(&uv).unwrap();
                let expected = p.normalize();
                assert!(
                    (ray.into_inner() - expected).norm() < 1e-12,
                    "{cam:?} {p:?}"
                );
            }
        }
    }

    #[test]
    fn undistort_fails_beyond_the_fold() {
        // k1 < 0 alone: xd = x (1 + k1 r²) peaks at r² = -1/(3 k1); beyond that no inverse.
        let cam =
            Camera::pinhole(500.0, 500.0, 0.0, 0.0).with_distortion(&[-0.3, 0.0, 0.0, 0.0, 0.0]);
        let r_max = (1.0f64 / 0.9).sqrt();
        let rd_max = r_max * (1.0 - 0.3 * r_max * r_max);
        assert!(cam.undistort(&Vector2::new(rd_max * 0.9, 0.0)).is_ok());
        let err = cam
            .undistort(&Vector2::new(rd_max * 1.05, 0.0))
            .unwrap_err();
        assert!(matches!(err, CameraError::UndistortNotConverged { .. }));
    }

    #[test]
    fn behind_camera_is_an_error() {
        let cam = Camera::pinhole(500.0, 500.0, 0.0, 0.0);
        assert!(cam.project(&Vector3::new(0.0, 0.0, -1.0)).is_err());
    }
}
