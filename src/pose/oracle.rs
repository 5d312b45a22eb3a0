//! OpenCV's `cv::solvePnPRansac` and `cv::solvePnP` on the same correspondences (OpenCV
//! adapter). Not used to solve poses: the reference that tests and `make bench` compare
//! geostride's own solver against.

use nalgebra::{Vector2, Vector3};
use opencv::calib3d;
use opencv::core::{CV_64F, Mat, Point2d, Point3d, Vector};
use opencv::prelude::*;

use crate::camera::Camera;
use crate::geom::Rigid3;

/// Correspondences and camera in OpenCV's containers, built once so timings exclude conversion.
pub struct OpenCvPnpInput {
    object: Vector<Point3d>,
    image: Vector<Point2d>,
    k: Mat,
    dist: Mat,
}

fn vec3(m: &Mat) -> opencv::Result<Vector3<f64>> {
    Ok(Vector3::new(
        *m.at::<f64>(0)?,
        *m.at::<f64>(1)?,
        *m.at::<f64>(2)?,
    ))
}

impl OpenCvPnpInput {
    pub fn new(
        camera: &Camera,
        world: &[Vector3<f64>],
        uv: &[Vector2<f64>],
    ) -> opencv::Result<Self> {
        let k = Mat::from_slice_2d(&[
            [camera.fx, camera.skew, camera.cx],
            [0.0, camera.fy, camera.cy],
            [0.0, 0.0, 1.0],
        ])?;
        let dist = Mat::from_slice(&camera.dist)?.try_clone()?;
        Ok(OpenCvPnpInput {
            object: world.iter().map(|p| Point3d::new(p.x, p.y, p.z)).collect(),
            image: uv.iter().map(|p| Point2d::new(p.x, p.y)).collect(),
            k,
            dist,
        })
    }

    /// `cv::solvePnPRansac` with the iterative (Levenberg–Marquardt) method, which also refines
    /// the pose on the inliers. Returns the pose and the inlier flags.
    pub fn solve_ransac(
        &self,
        threshold_px: f32,
        confidence: f64,
        iterations: i32,
    ) -> opencv::Result<Option<(Rigid3, Vec<bool>)>> {
        let mut rvec = Mat::zeros(3, 1, CV_64F)?.to_mat()?;
        let mut tvec = Mat::zeros(3, 1, CV_64F)?.to_mat()?;
        let mut inliers = Mat::default();
        let ok = calib3d::solve_pnp_ransac(
            &self.object,
            &self.image,
            &self.k,
            &self.dist,
            &mut rvec,
            &mut tvec,
            false,
            iterations,
            threshold_px,
            confidence,
            &mut inliers,
            calib3d::SOLVEPNP_ITERATIVE,
        )?;
        if !ok {
            return Ok(None);
        }
        let mut flags = vec![false; self.object.len()];
        for i in 0..inliers.total() as i32 {
            flags[*inliers.at::<i32>(i)? as usize] = true;
        }
        Ok(Some((
            Rigid3::from_rvec_tvec(&vec3(&rvec)?, &vec3(&tvec)?),
            flags,
        )))
    }

    /// `cv::solvePnP` (iterative) on the points flagged in `subset`.
    pub fn solve(&self, subset: &[bool]) -> opencv::Result<Option<Rigid3>> {
        let object: Vector<Point3d> = self
            .object
            .iter()
            .zip(subset)
            .filter(|(_, s)| **s)
            .map(|(p, _)| p)
            .collect();
        let image: Vector<Point2d> = self
            .image
            .iter()
            .zip(subset)
            .filter(|(_, s)| **s)
            .map(|(p, _)| p)
            .collect();
        let mut rvec = Mat::zeros(3, 1, CV_64F)?.to_mat()?;
        let mut tvec = Mat::zeros(3, 1, CV_64F)?.to_mat()?;
        if !calib3d::solve_pnp(
            &object,
            &image,
            &self.k,
            &self.dist,
            &mut rvec,
            &mut tvec,
            false,
            calib3d::SOLVEPNP_ITERATIVE,
        )? {
            return Ok(None);
        }
        Ok(Some(Rigid3::from_rvec_tvec(&vec3(&rvec)?, &vec3(&tvec)?)))
    }
}
