//! Closed-form initialisation (Zhang, "A flexible new technique for camera calibration", 2000).
//!
//! Each board homography `H = K [r1 r2 t]` gives two linear constraints on the image of the
//! absolute conic `B = K⁻ᵀK⁻¹`. Fixed quantities (zero skew, an aspect ratio, the principal
//! point) are further linear constraints on `B`, imposed exactly by solving in their null space.
//! Pixels are centred and scaled first, which keeps the system well conditioned.

use nalgebra::{DMatrix, Matrix3, Vector2, Vector3, Vector6};

use super::{CalibrationError, Options};
use crate::camera::{Camera, ImageSize};
use crate::estimate::homography::homography_refined;
use crate::geom::{Rigid3, nearest_rotation};

/// Initial intrinsics (no distortion) and board poses.
pub struct Initial {
    pub camera: Camera,
    pub cam_from_board: Vec<Rigid3>,
}

/// `v_ij` of Zhang's paper, so that `h_iᵀ B h_j = v_ijᵀ b` with
/// `b = (B11, B12, B22, B13, B23, B33)`.
fn v_ij(h: &Matrix3<f64>, i: usize, j: usize) -> Vector6<f64> {
    let (hi, hj) = (h.column(i), h.column(j));
    Vector6::new(
        hi[0] * hj[0],
        hi[0] * hj[1] + hi[1] * hj[0],
        hi[1] * hj[1],
        hi[2] * hj[0] + hi[0] * hj[2],
        hi[2] * hj[1] + hi[1] * hj[2],
        hi[2] * hj[2],
    )
}

/// Unit vector `b` minimising `‖V b‖` subject to `C b = 0`.
fn constrained_null_vector(v: &DMatrix<f64>, c: &[Vector6<f64>]) -> Option<Vector6<f64>> {
    // Basis of the null space of C (6 x k).
    let basis: DMatrix<f64> = if c.is_empty() {
        DMatrix::identity(6, 6)
    } else {
        let cm = DMatrix::from_fn(c.len(), 6, |r, k| c[r][k]);
        let ctc = cm.transpose() * &cm;
        let eig = ctc.symmetric_eigen();
        let cols: Vec<usize> = (0..6)
            .filter(|&i| eig.eigenvalues[i].abs() < 1e-12 * eig.eigenvalues.amax().max(1e-300))
            .collect();
        if cols.is_empty() {
            return None;
        }
        DMatrix::from_fn(6, cols.len(), |r, k| eig.eigenvectors[(r, cols[k])])
    };
    let a = v * &basis;
    let ata = a.transpose() * &a;
    let eig = ata.symmetric_eigen();
    let imin = eig.eigenvalues.imin();
    let b = &basis * eig.eigenvectors.column(imin);
    Some(Vector6::from_iterator(b.iter().copied()))
}

/// Intrinsics from `b`, or why they are not a camera.
fn intrinsics_from_b(b: &Vector6<f64>) -> Result<(f64, f64, f64, f64, f64), String> {
    let b = if b[0] < 0.0 { -b } else { *b };
    let (b11, b12, b22, b13, b23, b33) = (b[0], b[1], b[2], b[3], b[4], b[5]);
    let den = b11 * b22 - b12 * b12;
    if !(b11 > 0.0 && den > 0.0) {
        return Err("the conic is not positive definite".into());
    }
    let v0 = (b12 * b13 - b11 * b23) / den;
    let lambda = b33 - (b13 * b13 + v0 * (b12 * b13 - b11 * b23)) / b11;
    if !(lambda / b11 > 0.0) {
        return Err("negative focal length squared".into());
    }
    let alpha = (lambda / b11).sqrt();
    let beta = (lambda * b11 / den).sqrt();
    let gamma = -b12 * alpha * alpha * beta / lambda;
    let u0 = gamma * v0 / beta - b13 * alpha * alpha / lambda;
    Ok((alpha, beta, gamma, u0, v0))
}

/// Closed-form intrinsics and poses from homographies; the principal point is held at the image
/// centre when `fix_pp`.
fn solve(
    hs: &[Matrix3<f64>],
    image_size: ImageSize,
    fix_aspect: Option<f64>,
    fix_pp: bool,
) -> Result<Camera, String> {
    // Normalised pixels: p' = (p − centre) / scale.
    let (w, h) = (f64::from(image_size.width), f64::from(image_size.height));
    let (c_x, c_y) = ((w - 1.0) / 2.0, (h - 1.0) / 2.0);
    let scale = w.max(h);
    let t = Matrix3::new(
        1.0 / scale,
        0.0,
        -c_x / scale,
        0.0,
        1.0 / scale,
        -c_y / scale,
        0.0,
        0.0,
        1.0,
    );
    let mut v = DMatrix::<f64>::zeros(2 * hs.len(), 6);
    for (k, hm) in hs.iter().enumerate() {
        let hn = t * hm;
        let hn = hn / hn.norm();
        v.row_mut(2 * k).copy_from(&v_ij(&hn, 0, 1).transpose());
        v.row_mut(2 * k + 1)
            .copy_from(&(v_ij(&hn, 0, 0) - v_ij(&hn, 1, 1)).transpose());
    }
    // Zero skew always; OpenCV's model estimates none.
    let mut constraints = vec![Vector6::new(0.0, 1.0, 0.0, 0.0, 0.0, 0.0)];
    if let Some(a) = fix_aspect {
        // With zero skew B11 ∝ 1/fx², B22 ∝ 1/fy², so a²·B11 − B22 = 0.
        constraints.push(Vector6::new(a * a, 0.0, -1.0, 0.0, 0.0, 0.0));
    }
    if fix_pp {
        // Principal point at the origin of the normalised frame: B13 = B23 = 0.
        constraints.push(Vector6::new(0.0, 0.0, 0.0, 1.0, 0.0, 0.0));
        constraints.push(Vector6::new(0.0, 0.0, 0.0, 0.0, 1.0, 0.0));
    }
    let b = constrained_null_vector(&v, &constraints).ok_or("over-constrained")?;
    let (alpha, beta, _gamma, u0, v0) = intrinsics_from_b(&b)?;
    let fx = alpha * scale;
    let mut fy = beta * scale;
    if let Some(a) = fix_aspect {
        fy = fx / a;
    }
    let (cx, cy) = if fix_pp {
        (c_x, c_y)
    } else {
        (u0 * scale + c_x, v0 * scale + c_y)
    };
    let plausible = fx.is_finite()
        && fy.is_finite()
        && (0.2..5.0).contains(&(fx / fy))
        && (-0.5..w).contains(&cx)
        && (-0.5..h).contains(&cy);
    if !plausible {
        return Err(format!(
            "implausible closed-form intrinsics (fx {fx:.1}, fy {fy:.1}, cx {cx:.1}, cy {cy:.1})"
        ));
    }
    Ok(Camera::pinhole(fx, fy, cx, cy).with_image_size(image_size.width, image_size.height))
}

/// The board pose from its homography and `K` (Zhang, section 3.1), with the rotation projected
/// onto SO(3) and the board in front of the camera.
pub fn pose_from_homography(k: &Matrix3<f64>, h: &Matrix3<f64>) -> Option<Rigid3> {
    let kinv = k.try_inverse()?;
    let a = kinv * h;
    let (a1, a2, a3) = (a.column(0), a.column(1), a.column(2));
    let mut lambda = 2.0 / (a1.norm() + a2.norm());
    if a3[2] * lambda < 0.0 {
        lambda = -lambda;
    }
    let r1 = a1 * lambda;
    let r2 = a2 * lambda;
    let r3 = r1.cross(&r2);
    let r = nearest_rotation(&Matrix3::from_columns(&[r1, r2, r3]));
    let tvec: Vector3<f64> = a3 * lambda;
    Some(Rigid3::new(r, tvec))
}

/// Initial camera and board poses for the views.
pub fn initialise(
    object: &[Vector3<f64>],
    views: &[&[Vector2<f64>]],
    image_size: ImageSize,
    opts: &Options,
) -> Result<Initial, CalibrationError> {
    let plane: Vec<Vector2<f64>> = object.iter().map(|p| p.xy()).collect();
    let hs = views
        .iter()
        .map(|c| homography_refined(&plane, c))
        .collect::<Result<Vec<_>, _>>()
        .map_err(|e| CalibrationError::Initialisation(format!("board homography: {e}")))?;

    // Zhang's full closed form first; the principal point at the centre (what OpenCV's
    // initialisation always assumes) when the full form is implausible.
    let camera = solve(&hs, image_size, opts.fix_aspect, opts.fix_principal_point)
        .or_else(|first| {
            solve(&hs, image_size, opts.fix_aspect, true).map_err(|second| {
                format!("{first}; with the principal point at the centre: {second}")
            })
        })
        .map_err(CalibrationError::Initialisation)?;

    let k = camera.k_matrix();
    let cam_from_board = hs
        .iter()
        .map(|h| pose_from_homography(&k, h))
        .collect::<Option<Vec<_>>>()
        .ok_or_else(|| CalibrationError::Initialisation("singular camera matrix".into()))?;
    Ok(Initial {
        camera,
        cam_from_board,
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::calibration::board_points;
    use crate::camera::BoardSpec;

    #[test]
    fn recovers_exact_intrinsics_and_poses_without_noise() {
        let truth = Camera::pinhole(1000.0, 990.0, 650.0, 470.0).with_image_size(1280, 960);
        let board = BoardSpec {
            cols: 9,
            rows: 6,
            square_m: 0.03,
        };
        let object = board_points(&board);
        let poses = [
            Rigid3::from_rvec_tvec(
                &Vector3::new(0.3, 0.1, 0.05),
                &Vector3::new(-0.1, -0.05, 0.6),
            ),
            Rigid3::from_rvec_tvec(
                &Vector3::new(-0.2, 0.35, -0.1),
                &Vector3::new(-0.15, -0.1, 0.7),
            ),
            Rigid3::from_rvec_tvec(
                &Vector3::new(0.1, -0.3, 0.4),
                &Vector3::new(-0.05, -0.08, 0.55),
            ),
            Rigid3::from_rvec_tvec(
                &Vector3::new(0.4, 0.3, -0.2),
                &Vector3::new(-0.12, -0.02, 0.8),
            ),
        ];
        let views: Vec<Vec<Vector2<f64>>> = poses
            .iter()
            .map(|p| {
                object
                    .iter()
                    .map(|x| truth.project(&p.apply(x)).unwrap())
                    .collect()
            })
            .collect();
        let refs: Vec<&[Vector2<f64>]> = views.iter().map(|v| v.as_slice()).collect();
        let init = initialise(
            &object,
            &refs,
            truth.image_size.unwrap(),
            &Options::default(),
        )
        .unwrap();
        let c = &init.camera;
        for (a, b) in [(c.fx, 1000.0), (c.fy, 990.0), (c.cx, 650.0), (c.cy, 470.0)] {
            assert!((a - b).abs() < 1e-6, "{a} vs {b}");
        }
        for (est, p) in init.cam_from_board.iter().zip(&poses) {
            assert!((est.translation - p.translation).norm() < 1e-9);
            assert!((est.rotation.matrix() - p.rotation.matrix()).norm() < 1e-9);
        }
        let fixed = Options {
            fix_aspect: Some(1.0),
            fix_principal_point: true,
            ..Options::default()
        };
        let init = initialise(&object, &refs, truth.image_size.unwrap(), &fixed).unwrap();
        assert_eq!(init.camera.fx, init.camera.fy);
        assert_eq!(init.camera.cx, 639.5);
        assert!((init.camera.fx - 995.0).abs() < 20.0, "{}", init.camera.fx);
    }
}
