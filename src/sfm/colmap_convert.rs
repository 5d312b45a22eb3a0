//! A COLMAP model as geostride's reconstruction and back (pure): its camera as a Brown–Conrady
//! camera, its images' poses and keypoints (COLMAP's pixels shifted by −0.5 to geostride's,
//! whose top-left pixel centre is (0, 0)), its points with their tracks. What the
//! georeferencing changes (poses, points, their errors) is written back into the model; every
//! other field (ids, names, colours, keypoints that observe nothing) stays as it was read.

use nalgebra::{Quaternion, Rotation3, UnitQuaternion, Vector2, Vector3};

use super::colmap_model::{ColmapCamera, ColmapModel};
use super::reconstruct::{ModelPoint, Reconstruction, Start};
use super::register::MAX_MODEL_COORDINATE;
use crate::camera::Camera;
use crate::geom::Rigid3;

/// A model geostride cannot take, and why (the model's fields named).
#[derive(Debug, thiserror::Error)]
#[error("{0}")]
pub struct ConvertError(pub String);

/// The model as a reconstruction: the images in the model's order.
pub struct Converted {
    pub reconstruction: Reconstruction,
    /// Per image, its name.
    pub names: Vec<String>,
    /// Per image, its keypoints in geostride's pixels.
    pub keypoints: Vec<Vec<Vector2<f64>>>,
    pub width: u32,
    pub height: u32,
}

/// The COLMAP camera models geostride's camera holds exactly.
pub const SUPPORTED_MODELS: [&str; 6] = [
    "SIMPLE_PINHOLE",
    "PINHOLE",
    "SIMPLE_RADIAL",
    "RADIAL",
    "OPENCV",
    "FULL_OPENCV",
];

/// A COLMAP camera as geostride's (pixel centres at integers).
pub fn camera_of(c: &ColmapCamera) -> Result<(Camera, u32, u32), ConvertError> {
    let p = &c.params;
    let name = c.model_name();
    // (fx, fy, cx, cy, distortion in OpenCV order)
    let (fx, fy, cx, cy, dist): (f64, f64, f64, f64, &[f64]) = match name {
        "SIMPLE_PINHOLE" => (p[0], p[0], p[1], p[2], &[]),
        "PINHOLE" => (p[0], p[1], p[2], p[3], &[]),
        "SIMPLE_RADIAL" => (p[0], p[0], p[1], p[2], &p[3..4]),
        "RADIAL" => (p[0], p[0], p[1], p[2], &p[3..5]),
        "OPENCV" | "FULL_OPENCV" => (p[0], p[1], p[2], p[3], &p[4..]),
        other => {
            return Err(ConvertError(format!(
                "camera {}: COLMAP's {other} model, which geostride's Brown–Conrady camera does not hold (it takes {}); undistort the images with `colmap image_undistorter` or reconstruct with one of those models",
                c.id,
                SUPPORTED_MODELS.join(", ")
            )));
        }
    };
    let side = 1..=u64::from(crate::camera::MAX_IMAGE_SIDE);
    if !(side.contains(&c.width) && side.contains(&c.height)) {
        return Err(ConvertError(format!(
            "camera {}: an image of {}x{} pixels: expected 1 to {} on each side",
            c.id,
            c.width,
            c.height,
            crate::camera::MAX_IMAGE_SIDE
        )));
    }
    let (w, h) = (c.width as u32, c.height as u32);
    let mut camera = Camera::pinhole(fx, fy, cx - 0.5, cy - 0.5).with_image_size(w, h);
    camera.dist[..dist.len()].copy_from_slice(dist);
    crate::camera::Calibration::from_camera(camera.clone())
        .validate()
        .map_err(|(field, message)| ConvertError(format!("camera {}: {field}: {message}", c.id)))?;
    Ok((camera, w, h))
}

/// The one camera every image uses: several cameras are taken only when they are one camera
/// (same model, size and parameters), as geostride adjusts one.
fn shared_camera(m: &ColmapModel) -> Result<&ColmapCamera, ConvertError> {
    let mut used: Vec<u32> = m.images.iter().map(|i| i.camera_id).collect();
    used.sort_unstable();
    used.dedup();
    let find = |id: u32| {
        m.cameras.iter().find(|c| c.id == id).ok_or_else(|| {
            ConvertError(format!(
                "images name camera {id}, which cameras does not hold"
            ))
        })
    };
    let Some(&first) = used.first() else {
        return Err(ConvertError("the model has no images".into()));
    };
    let camera = find(first)?;
    for &id in &used[1..] {
        let other = find(id)?;
        if (other.model_id, other.width, other.height, &other.params)
            != (camera.model_id, camera.width, camera.height, &camera.params)
        {
            return Err(ConvertError(format!(
                "the images use {} cameras with different intrinsics (cameras {} and {id}); geostride georeferences models of one camera: reconstruct with `--ImageReader.single_camera 1` (one drone, one zoom setting)",
                used.len(),
                camera.id
            )));
        }
    }
    Ok(camera)
}

/// The model as a reconstruction (every image registered, as COLMAP writes only those).
pub fn to_reconstruction(m: &ColmapModel) -> Result<Converted, ConvertError> {
    let (camera, width, height) = camera_of(shared_camera(m)?)?;
    let mut index_of_image = std::collections::HashMap::new();
    let mut names = Vec::with_capacity(m.images.len());
    let mut keypoints = Vec::with_capacity(m.images.len());
    let mut poses = Vec::with_capacity(m.images.len());
    let far = |v: &[f64]| v.iter().any(|x| x.abs() > MAX_MODEL_COORDINATE);
    for (k, i) in m.images.iter().enumerate() {
        if far(&i.tvec) {
            return Err(ConvertError(format!(
                "image {}: a translation beyond {MAX_MODEL_COORDINATE:e}: not a model's camera",
                i.id
            )));
        }
        index_of_image.insert(i.id, k);
        names.push(i.name.clone());
        keypoints.push(
            i.points2d
                .iter()
                .map(|p| Vector2::new(p.xy[0] - 0.5, p.xy[1] - 0.5))
                .collect::<Vec<_>>(),
        );
        let [w, x, y, z] = i.qvec;
        let q = UnitQuaternion::from_quaternion(Quaternion::new(w, x, y, z));
        poses.push(Some(Rigid3::new(Rotation3::from(q), Vector3::from(i.tvec))));
    }
    let mut points = Vec::with_capacity(m.points.len());
    for p in &m.points {
        if far(&p.xyz) {
            return Err(ConvertError(format!(
                "point {}: a coordinate beyond {MAX_MODEL_COORDINATE:e}: not a model's point",
                p.id
            )));
        }
        let mut observations = Vec::with_capacity(p.track.len());
        for &(image_id, idx) in &p.track {
            let Some(&i) = index_of_image.get(&image_id) else {
                return Err(ConvertError(format!(
                    "point {}'s track names image {image_id}, which images does not hold",
                    p.id
                )));
            };
            if idx as usize >= keypoints[i].len() {
                return Err(ConvertError(format!(
                    "point {}'s track names keypoint {idx} of image {image_id}, which has {}",
                    p.id,
                    keypoints[i].len()
                )));
            }
            observations.push((i, idx as usize));
        }
        points.push(ModelPoint {
            xyz: Vector3::from(p.xyz),
            observations,
        });
    }
    let mut reconstruction = Reconstruction {
        poses,
        points,
        mean_reprojection_px: 0.0,
        camera,
        initial_pair: (0, 0),
        start: Start {
            model: "colmap",
            essential_inliers: 0,
            homography_inliers: 0,
            rotations_skipped: 0,
        },
        principal_point: None,
        other_models: Vec::new(),
        adjustments: Default::default(),
    };
    reconstruction.mean_reprojection_px = reconstruction.mean_reprojection(&keypoints);
    Ok(Converted {
        reconstruction,
        names,
        keypoints,
        width,
        height,
    })
}

/// Writes the reconstruction's poses, points and their mean reprojection errors (pixels) back
/// into the model it was converted from.
pub fn apply(m: &mut ColmapModel, c: &Converted) {
    let r = &c.reconstruction;
    for (image, pose) in m.images.iter_mut().zip(&r.poses) {
        let Some(pose) = pose else { continue };
        let q = UnitQuaternion::from_rotation_matrix(&pose.rotation);
        image.qvec = [q.w, q.i, q.j, q.k];
        image.tvec = pose.translation.into();
    }
    for (k, (point, p)) in m.points.iter_mut().zip(&r.points).enumerate() {
        point.xyz = p.xyz.into();
        point.error = super::colmap::point_error_px(r, k, &c.keypoints);
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::sfm::colmap_model::{ColmapImage, ColmapPoint, Point2D};

    fn model(model_id: i32, params: Vec<f64>) -> ColmapModel {
        ColmapModel {
            cameras: vec![ColmapCamera {
                id: 3,
                model_id,
                width: 640,
                height: 480,
                params,
            }],
            images: vec![ColmapImage {
                id: 9,
                qvec: [1.0, 0.0, 0.0, 0.0],
                tvec: [0.0, 0.0, 0.0],
                camera_id: 3,
                name: "a.jpg".into(),
                points2d: vec![Point2D {
                    xy: [320.5, 240.5],
                    point3d_id: Some(4),
                }],
            }],
            points: vec![ColmapPoint {
                id: 4,
                xyz: [0.0, 0.0, 2.0],
                rgb: [0, 0, 0],
                error: 1.0,
                track: vec![(9, 0)],
            }],
        }
    }

    #[test]
    fn cameras_keep_colmaps_meaning_and_others_are_refused_by_name() {
        let c = to_reconstruction(&model(2, vec![500.0, 320.5, 240.5, -0.1])).unwrap();
        let cam = &c.reconstruction.camera;
        assert_eq!(
            (cam.fx, cam.fy, cam.cx, cam.cy, cam.dist[0]),
            (500.0, 500.0, 320.0, 240.0, -0.1)
        );
        // The point on the axis is seen at the principal point: no error.
        assert!(c.reconstruction.mean_reprojection_px < 1e-9);
        assert_eq!(c.keypoints[0][0], Vector2::new(320.0, 240.0));
        let e = to_reconstruction(&model(
            5,
            vec![500.0, 500.0, 320.0, 240.0, 0.0, 0.0, 0.0, 0.0],
        ))
        .err()
        .unwrap();
        assert!(e.0.contains("OPENCV_FISHEYE"), "{e}");
        let mut m = model(1, vec![500.0, 500.0, 320.5, 240.5]);
        m.points[0].track[0].1 = 5;
        assert!(
            to_reconstruction(&m)
                .err()
                .unwrap()
                .0
                .contains("keypoint 5")
        );
    }

    #[test]
    fn a_converted_model_written_back_unchanged_is_the_model() {
        let m = model(4, vec![500.0, 501.0, 320.5, 240.5, 0.01, 0.0, 0.0, 0.0]);
        let c = to_reconstruction(&m).unwrap();
        let mut back = m.clone();
        apply(&mut back, &c);
        assert_eq!(back.images, m.images);
        assert_eq!(back.points[0].xyz, m.points[0].xyz);
        assert!(back.points[0].error < 1e-9);
    }
}
