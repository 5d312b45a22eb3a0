//! A reconstruction as COLMAP's text model (`cameras.txt`, `images.txt`, `points3D.txt`) and as a
//! PLY point cloud (pure formatting).
//!
//! COLMAP's conventions: the centre of the top-left pixel is (0.5, 0.5) (geostride's and
//! OpenCV's is (0, 0), so 0.5 is added to every pixel coordinate and to the principal point);
//! `images.txt` holds `cam_from_world` as a unit quaternion `(qw, qx, qy, qz)` and a translation;
//! the camera model is `OPENCV` (`fx fy cx cy k1 k2 p1 p2`) or `FULL_OPENCV` when `k3`..`k6` are
//! used. Ids start at 1.

use std::fmt::Write as _;

use nalgebra::{UnitQuaternion, Vector2};

use super::reconstruct::Reconstruction;
use crate::camera::Camera;

/// `cameras.txt`: the one camera.
pub fn cameras_txt(camera: &Camera, width: u32, height: u32) -> String {
    let d = &camera.dist;
    let (cx, cy) = (camera.cx + 0.5, camera.cy + 0.5);
    let params = if d[4..].iter().all(|v| *v == 0.0) {
        format!(
            "OPENCV {width} {height} {} {} {cx} {cy} {} {} {} {}",
            camera.fx, camera.fy, d[0], d[1], d[2], d[3]
        )
    } else {
        format!(
            "FULL_OPENCV {width} {height} {} {} {cx} {cy} {} {} {} {} {} {} {} {}",
            camera.fx, camera.fy, d[0], d[1], d[2], d[3], d[4], d[5], d[6], d[7]
        )
    };
    format!(
        "# Camera list with one line of data per camera:\n\
         #   CAMERA_ID, MODEL, WIDTH, HEIGHT, PARAMS[]\n\
         # Number of cameras: 1\n\
         1 {params}\n"
    )
}

/// Per image and keypoint, the index of the point it observes (`None`: none).
pub fn point_of_keypoint(
    r: &Reconstruction,
    keypoints: &[Vec<Vector2<f64>>],
) -> Vec<Vec<Option<usize>>> {
    let mut out: Vec<Vec<Option<usize>>> = keypoints.iter().map(|k| vec![None; k.len()]).collect();
    for (p, point) in r.points.iter().enumerate() {
        for &(i, kp) in &point.observations {
            out[i][kp] = Some(p);
        }
    }
    out
}

/// `images.txt`: each registered image's pose and its keypoints, with the id of the point each
/// observes (−1: none).
pub fn images_txt(r: &Reconstruction, names: &[String], keypoints: &[Vec<Vector2<f64>>]) -> String {
    let of = point_of_keypoint(r, keypoints);
    let registered: Vec<usize> = (0..names.len()).filter(|&i| r.poses[i].is_some()).collect();
    let observations: usize = r.points.iter().map(|p| p.observations.len()).sum();
    let mut s = String::new();
    let _ = writeln!(
        s,
        "# Image list with two lines of data per image:\n\
         #   IMAGE_ID, QW, QX, QY, QZ, TX, TY, TZ, CAMERA_ID, NAME\n\
         #   POINTS2D[] as (X, Y, POINT3D_ID)\n\
         # Number of images: {}, mean observations per image: {:.1}",
        registered.len(),
        observations as f64 / registered.len().max(1) as f64
    );
    for &i in &registered {
        let pose = r.poses[i].expect("registered");
        let q = UnitQuaternion::from_rotation_matrix(&pose.rotation);
        let t = pose.translation;
        let _ = writeln!(
            s,
            "{} {} {} {} {} {} {} {} 1 {}",
            i + 1,
            q.w,
            q.i,
            q.j,
            q.k,
            t.x,
            t.y,
            t.z,
            names[i]
        );
        let row: Vec<String> = keypoints[i]
            .iter()
            .zip(&of[i])
            .map(|(k, p)| {
                format!(
                    "{} {} {}",
                    k.x + 0.5,
                    k.y + 0.5,
                    p.map_or(-1, |p| p as i64 + 1)
                )
            })
            .collect();
        let _ = writeln!(s, "{}", row.join(" "));
    }
    s
}

/// `points3D.txt`: each point, its mean reprojection error (pixels) and its track as
/// (image id, keypoint index). Colour: grey (features are found in grey images).
pub fn points3d_txt(r: &Reconstruction, keypoints: &[Vec<Vector2<f64>>]) -> String {
    let mut s = String::new();
    let observations: usize = r.points.iter().map(|p| p.observations.len()).sum();
    let _ = writeln!(
        s,
        "# 3D point list with one line of data per point:\n\
         #   POINT3D_ID, X, Y, Z, R, G, B, ERROR, TRACK[] as (IMAGE_ID, POINT2D_IDX)\n\
         # Number of points: {}, mean track length: {:.2}",
        r.points.len(),
        observations as f64 / r.points.len().max(1) as f64
    );
    for (p, point) in r.points.iter().enumerate() {
        let error = point_error_px(r, p, keypoints);
        let track: Vec<String> = point
            .observations
            .iter()
            .map(|(i, kp)| format!("{} {kp}", i + 1))
            .collect();
        let x = point.xyz;
        let _ = writeln!(
            s,
            "{} {} {} {} 128 128 128 {error} {}",
            p + 1,
            x.x,
            x.y,
            x.z,
            track.join(" ")
        );
    }
    s
}

/// The mean distance of point `p`'s observations from its projections, pixels.
pub fn point_error_px(r: &Reconstruction, p: usize, keypoints: &[Vec<Vector2<f64>>]) -> f64 {
    let point = &r.points[p];
    let sum: f64 = point
        .observations
        .iter()
        .map(|&(i, kp)| {
            let pose = r.poses[i].expect("registered");
            r.camera
                .project(&pose.apply(&point.xyz))
                .map_or(f64::INFINITY, |uv| (uv - keypoints[i][kp]).norm())
        })
        .sum();
    sum / point.observations.len().max(1) as f64
}

/// The points and the camera centres as an ASCII PLY (points grey, cameras red).
pub fn ply(r: &Reconstruction) -> String {
    let centres: Vec<_> = r.poses.iter().flatten().map(|p| p.centre()).collect();
    let mut s = format!(
        "ply\nformat ascii 1.0\ncomment geostride sfm: points, then camera centres in red\n\
         element vertex {}\nproperty double x\nproperty double y\nproperty double z\n\
         property uchar red\nproperty uchar green\nproperty uchar blue\nend_header\n",
        r.points.len() + centres.len()
    );
    for p in &r.points {
        let _ = writeln!(s, "{} {} {} 128 128 128", p.xyz.x, p.xyz.y, p.xyz.z);
    }
    for c in centres {
        let _ = writeln!(s, "{} {} {} 255 0 0", c.x, c.y, c.z);
    }
    s
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::geom::Rigid3;
    use crate::sfm::reconstruct::ModelPoint;
    use nalgebra::{Rotation3, Vector3};

    fn model() -> (Reconstruction, Vec<Vec<Vector2<f64>>>) {
        let camera = Camera::pinhole(1000.0, 1000.0, 500.0, 400.0);
        let poses = vec![
            Some(Rigid3::identity()),
            None,
            Some(Rigid3::new(
                Rotation3::from_scaled_axis(Vector3::new(0.1, -0.2, 0.3)),
                Vector3::new(1.0, 0.0, 0.2),
            )),
        ];
        let xyz = Vector3::new(0.3, -0.2, 5.0);
        let kp = |pose: &Rigid3| camera.project(&pose.apply(&xyz)).unwrap();
        let keypoints = vec![
            vec![Vector2::new(1.0, 2.0), kp(&poses[0].unwrap())],
            vec![Vector2::new(3.0, 4.0)],
            vec![kp(&poses[2].unwrap())],
        ];
        let r = Reconstruction {
            poses,
            points: vec![ModelPoint {
                xyz,
                observations: vec![(0, 1), (2, 0)],
            }],
            mean_reprojection_px: 0.0,
            camera,
            initial_pair: (0, 2),
            start: Default::default(),
            principal_point: None,
            other_models: Vec::new(),
            adjustments: Default::default(),
        };
        (r, keypoints)
    }

    /// Read back as COLMAP would: the quaternion and translation reproject the point onto the
    /// keypoints written, in COLMAP's pixel convention.
    #[test]
    fn colmap_text_reprojects() {
        let (r, kps) = model();
        let names: Vec<String> = ["a.jpg", "b.jpg", "c.jpg"].map(String::from).to_vec();
        let images = images_txt(&r, &names, &kps);
        let cameras = cameras_txt(&r.camera, 1000, 800);
        assert!(
            cameras.contains("1 OPENCV 1000 800 1000 1000 500.5 400.5 0 0 0 0"),
            "{cameras}"
        );
        let lines: Vec<&str> = images.lines().filter(|l| !l.starts_with('#')).collect();
        // Two registered images, two lines each; image 2 (b.jpg) is not there.
        assert_eq!(lines.len(), 4);
        assert!(lines[2].starts_with("3 ") && lines[2].ends_with(" 1 c.jpg"));
        let v: Vec<f64> = lines[2]
            .split_whitespace()
            .skip(1)
            .take(7)
            .map(|x| x.parse().unwrap())
            .collect();
        let q = UnitQuaternion::from_quaternion(nalgebra::Quaternion::new(v[0], v[1], v[2], v[3]));
        let p = q * r.points[0].xyz + Vector3::new(v[4], v[5], v[6]);
        let uv = Vector2::new(1000.0 * p.x / p.z + 500.5, 1000.0 * p.y / p.z + 400.5);
        let pts: Vec<f64> = lines[3]
            .split_whitespace()
            .map(|x| x.parse().unwrap())
            .collect();
        assert!((uv - Vector2::new(pts[0], pts[1])).norm() < 1e-9);
        assert_eq!(pts[2], 1.0);
        // Image 1's first keypoint sees nothing.
        assert!(lines[1].starts_with("1.5 2.5 -1 "));
        let points = points3d_txt(&r, &kps);
        let last = points.lines().last().unwrap();
        assert!(
            last.starts_with("1 0.3 -0.2 5 128 128 128 ") && last.ends_with(" 1 1 3 0"),
            "{last}"
        );
        assert!(ply(&r).contains("element vertex 3\n"));
    }
}
