//! geostride's OpenCV YAML is read by OpenCV's own FileStorage, and OpenCV's is read by geostride.

#![cfg(all(feature = "opencv", feature = "gdal", feature = "onnx"))]

use std::path::Path;

use geostride::camera::formats::{self, Format};
use geostride::camera::{Calibration, Camera};
use opencv::core::{CV_64F, FileStorage, FileStorage_Mode, Mat};
use opencv::prelude::*;

fn camera() -> Camera {
    Camera::pinhole(1108.123456789012, 1106.5, 646.25, 474.875)
        .with_distortion(&[-0.182, 0.094, 0.0008, -0.0005, -0.021, 0.01, -0.002, 0.0003])
        .with_image_size(1280, 960)
}

fn mat_values(m: &Mat) -> Vec<f64> {
    let mut out = Vec::new();
    for r in 0..m.rows() {
        for c in 0..m.cols() {
            out.push(*m.at_2d::<f64>(r, c).unwrap());
        }
    }
    out
}

#[test]
fn opencv_reads_what_geostride_writes() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("cam.yaml");
    let cam = camera();
    formats::write(&Calibration::from_camera(cam.clone()), &path, None).unwrap();
    let fs = FileStorage::new_def(path.to_str().unwrap(), FileStorage_Mode::READ as i32).unwrap();
    assert!(fs.is_opened().unwrap());
    let k = fs.get("camera_matrix").unwrap().mat().unwrap();
    assert_eq!(
        mat_values(&k),
        vec![cam.fx, 0.0, cam.cx, 0.0, cam.fy, cam.cy, 0.0, 0.0, 1.0]
    );
    let d = fs.get("distortion_coefficients").unwrap().mat().unwrap();
    assert_eq!(mat_values(&d), cam.dist.to_vec());
    assert_eq!(fs.get("image_width").unwrap().to_i32().unwrap(), 1280);
}

#[test]
fn geostride_reads_what_opencv_writes() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("cv.yml");
    let cam = camera();
    {
        let mut fs =
            FileStorage::new_def(path.to_str().unwrap(), FileStorage_Mode::WRITE as i32).unwrap();
        let k = Mat::from_slice_2d(&[
            [cam.fx, 0.0, cam.cx],
            [0.0, cam.fy, cam.cy],
            [0.0, 0.0, 1.0],
        ])
        .unwrap();
        let d = Mat::from_slice(&cam.dist[..5])
            .unwrap()
            .t()
            .unwrap()
            .to_mat()
            .unwrap();
        assert_eq!(k.typ(), CV_64F);
        fs.write_i32("image_width", 1280).unwrap();
        fs.write_i32("image_height", 960).unwrap();
        fs.write_mat("camera_matrix", &k).unwrap();
        fs.write_mat("distortion_coefficients", &d).unwrap();
        fs.write_f64("avg_reprojection_error", 0.25).unwrap();
        fs.release().unwrap();
    }
    let cal = formats::read(&path, None).unwrap();
    assert_eq!(cal.camera.fx, cam.fx);
    assert_eq!(cal.camera.cy, cam.cy);
    assert_eq!(cal.camera.dist[..5], cam.dist[..5]);
    assert_eq!(cal.camera.image_size, cam.image_size);
    assert_eq!(cal.summary.unwrap().rms_px, 0.25);
    // Written again by geostride, it reads back identically.
    let again = formats::render(
        &formats::read(&path, Some(Format::OpenCvYaml)).unwrap(),
        Format::OpenCvYaml,
        Path::new("x"),
    )
    .unwrap();
    assert_eq!(
        formats::parse(Path::new("x"), &again, None)
            .unwrap()
            .camera
            .dist[..5],
        cam.dist[..5]
    );
}
