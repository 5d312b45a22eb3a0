//! OpenCV's `cv::calibrateCamera` on the same corners (OpenCV adapter). Not used to calibrate:
//! it is the reference that tests and `make bench` compare geostride's own solver against.

use opencv::calib3d;
use opencv::core::{CV_64F, Mat, Point2f, Point3f, Size, TermCriteria, TermCriteria_Type, Vector};
use opencv::prelude::*;

use super::{Options, View, board_points};
use crate::camera::{BoardSpec, Camera, ImageSize, N_PARAMS};
use crate::geom::Rigid3;

/// Corners and board points in OpenCV's containers, built once so timings exclude conversion.
pub struct OpenCvInput {
    object: Vector<Vector<Point3f>>,
    image: Vector<Vector<Point2f>>,
    size: Size,
}

impl OpenCvInput {
    pub fn new(views: &[View], board: &BoardSpec, size: ImageSize) -> Self {
        let pts: Vector<Point3f> = board_points(board)
            .iter()
            .map(|p| Point3f::new(p.x as f32, p.y as f32, p.z as f32))
            .collect();
        let mut object = Vector::new();
        let mut image = Vector::new();
        for v in views {
            object.push(pts.clone());
            image.push(
                v.corners
                    .iter()
                    .map(|c| Point2f::new(c.x as f32, c.y as f32))
                    .collect::<Vector<Point2f>>(),
            );
        }
        OpenCvInput {
            object,
            image,
            size: Size::new(size.width as i32, size.height as i32),
        }
    }
}

/// OpenCV's `CALIB_*` flags equivalent to geostride's options.
pub fn opencv_flags(opts: &Options) -> i32 {
    let mut flags = 0;
    if opts.fix_aspect.is_some() {
        flags |= calib3d::CALIB_FIX_ASPECT_RATIO;
    }
    if opts.fix_principal_point {
        flags |= calib3d::CALIB_FIX_PRINCIPAL_POINT;
    }
    if opts.zero_tangential {
        flags |= calib3d::CALIB_ZERO_TANGENT_DIST;
    }
    for (k, flag) in [
        calib3d::CALIB_FIX_K1,
        calib3d::CALIB_FIX_K2,
        calib3d::CALIB_FIX_K3,
    ]
    .into_iter()
    .enumerate()
    {
        if opts.radial_terms <= k {
            flags |= flag;
        }
    }
    if opts.rational {
        flags |= calib3d::CALIB_RATIONAL_MODEL;
    }
    flags
}

/// OpenCV's result: camera, RMS (px) and the standard deviations of the intrinsics in
/// geostride's parameter order (skew, which OpenCV does not estimate, is 0).
pub struct OpenCvResult {
    pub camera: Camera,
    pub cam_from_board: Vec<Rigid3>,
    pub rms_px: f64,
    pub std_devs: [f64; N_PARAMS],
}

/// Runs `cv::calibrateCamera` (with `with_std_devs`, `calibrateCameraExtended`) with OpenCV's
/// default termination (30 iterations or a relative change below DBL_EPSILON).
pub fn calibrate_camera(
    input: &OpenCvInput,
    opts: &Options,
    with_std_devs: bool,
) -> opencv::Result<OpenCvResult> {
    let mut k = Mat::eye(3, 3, CV_64F)?.to_mat()?;
    if let Some(a) = opts.fix_aspect {
        *k.at_2d_mut::<f64>(0, 0)? = a;
    }
    let mut d = Mat::default();
    let mut rvecs = Vector::<Mat>::new();
    let mut tvecs = Vector::<Mat>::new();
    let criteria = TermCriteria::new(
        TermCriteria_Type::COUNT as i32 + TermCriteria_Type::EPS as i32,
        30,
        f64::EPSILON,
    )?;
    let flags = opencv_flags(opts);
    let mut sd = [0.0; N_PARAMS];
    let rms = if with_std_devs {
        let (mut sdi, mut sde, mut per_view) = (Mat::default(), Mat::default(), Mat::default());
        let rms = calib3d::calibrate_camera_extended(
            &input.object,
            &input.image,
            input.size,
            &mut k,
            &mut d,
            &mut rvecs,
            &mut tvecs,
            &mut sdi,
            &mut sde,
            &mut per_view,
            flags,
            criteria,
        )?;
        // OpenCV order: fx fy cx cy k1 k2 p1 p2 k3 k4 k5 k6 ...; geostride inserts skew at 4.
        let cv_index = [0, 1, 2, 3, -1, 4, 5, 6, 7, 8, 9, 10, 11];
        for (s, &k) in sd.iter_mut().zip(&cv_index) {
            if k >= 0 {
                *s = *sdi.at::<f64>(k)?;
            }
        }
        rms
    } else {
        calib3d::calibrate_camera(
            &input.object,
            &input.image,
            input.size,
            &mut k,
            &mut d,
            &mut rvecs,
            &mut tvecs,
            flags,
            criteria,
        )?
    };
    let dist: Vec<f64> = (0..d.total() as i32)
        .map(|i| d.at::<f64>(i).copied())
        .collect::<opencv::Result<_>>()?;
    let camera = Camera::pinhole(
        *k.at_2d::<f64>(0, 0)?,
        *k.at_2d::<f64>(1, 1)?,
        *k.at_2d::<f64>(0, 2)?,
        *k.at_2d::<f64>(1, 2)?,
    )
    .with_distortion(&dist);
    let vec3 = |m: &Mat| -> opencv::Result<nalgebra::Vector3<f64>> {
        Ok(nalgebra::Vector3::new(
            *m.at::<f64>(0)?,
            *m.at::<f64>(1)?,
            *m.at::<f64>(2)?,
        ))
    };
    let cam_from_board = rvecs
        .iter()
        .zip(tvecs.iter())
        .map(|(r, t)| Ok(Rigid3::from_rvec_tvec(&vec3(&r)?, &vec3(&t)?)))
        .collect::<opencv::Result<Vec<_>>>()?;
    Ok(OpenCvResult {
        camera,
        cam_from_board,
        rms_px: rms,
        std_devs: sd,
    })
}
