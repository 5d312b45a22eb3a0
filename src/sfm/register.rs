//! New images placed in an existing model (pure): the model read back from its COLMAP text files
//! (`cameras.txt`, `images.txt` with every keypoint and the point it observes, `points3D.txt`),
//! each new image's features matched with the model images', the matches that land on a model
//! point turned into 2D–3D correspondences, then P3P + MSAC and Gauss–Newton on the inliers. The
//! model is held as it is: a registered image gets a pose in the model's frame and nothing else
//! moves.

use std::collections::HashMap;
use std::path::{Path, PathBuf};

use nalgebra::{Quaternion, Rotation3, UnitQuaternion, Vector2, Vector3};
use serde::Serialize;

use crate::camera::Camera;
use crate::estimate::pnp::{PnpEstimator, gauss_newton_pose};
use crate::estimate::ransac::{RansacSettings, msac};
use crate::geom::Rigid3;

/// A model as `geostride sfm` (or COLMAP, with one camera) wrote it.
#[derive(Clone, Debug)]
pub struct Model {
    pub camera: Camera,
    pub width: u32,
    pub height: u32,
    /// Per registered image: its name, `cam_from_world`, and per keypoint (in the order of its
    /// features) the index into `points` of the point it observes.
    pub images: Vec<ModelImage>,
    pub points: Vec<Vector3<f64>>,
}

#[derive(Clone, Debug)]
pub struct ModelImage {
    pub name: String,
    pub pose: Rigid3,
    /// Keypoints, full-resolution pixels (geostride's convention).
    pub keypoints: Vec<Vector2<f64>>,
    pub point_of: Vec<Option<usize>>,
}

#[derive(Debug, thiserror::Error)]
#[error("{}{}: {message}", path.display(), line.map(|l| format!(":{l}")).unwrap_or_default())]
pub struct ModelError {
    pub path: PathBuf,
    pub line: Option<usize>,
    pub message: String,
}

/// The largest coordinate of a model's point or camera, metres (or model units): an
/// Earth-centred frame is 6.4e6; beyond this a number is a mistake.
pub const MAX_MODEL_COORDINATE: f64 = 1e8;

/// Reads the COLMAP text model in `dir` (its files no larger than the input limit).
pub fn read_model(dir: &Path) -> Result<Model, ModelError> {
    let read = |name: &str| -> Result<(PathBuf, String), ModelError> {
        let path = dir.join(name);
        let text = crate::io::FileCtx { path: &path }
            .read_text("a COLMAP text model file")
            .map_err(|e| ModelError {
                path: path.clone(),
                line: None,
                message: format!(
                    "{} (a model folder holds cameras.txt, images.txt and points3D.txt, as `geostride sfm` writes them)",
                    e.message
                ),
            })?;
        Ok((path, text))
    };
    let cameras = read("cameras.txt")?;
    let points = read("points3D.txt")?;
    let images = read("images.txt")?;
    parse_model(
        (&cameras.0, &cameras.1),
        (&images.0, &images.1),
        (&points.0, &points.1),
    )
}

/// Whitespace-separated finite numbers.
fn finite_numbers(line: &str) -> Option<Vec<f64>> {
    line.split_whitespace()
        .map(|v| v.parse::<f64>().ok().filter(|x| x.is_finite()))
        .collect()
}

/// A whole number in a field (an id, a size).
fn whole(t: &str) -> Option<i64> {
    t.parse::<i64>().ok()
}

/// A model file's error at `line`.
fn bad(path: &Path, line: usize, message: String) -> ModelError {
    ModelError {
        path: path.to_path_buf(),
        line: Some(line),
        message,
    }
}

/// A line that is neither a comment nor blank.
fn content((_, l): &(usize, &str)) -> bool {
    !l.starts_with('#') && !l.trim().is_empty()
}

/// cameras.txt: its one camera, with its image size and id.
fn parse_camera(path: &Path, text: &str) -> Result<(Camera, u32, u32, i64), ModelError> {
    let mut camera = None;
    for (k, l) in text.lines().enumerate().filter(content) {
        if camera.is_some() {
            return Err(bad(
                path,
                k + 1,
                "more than one camera: registration uses one".into(),
            ));
        }
        let f: Vec<&str> = l.split_whitespace().collect();
        let id = f.first().and_then(|t| whole(t));
        let v = f.get(2..).and_then(|r| finite_numbers(&r.join(" ")));
        let (Some(id), Some(model), Some(v)) = (id, f.get(1), v) else {
            return Err(bad(
                path,
                k + 1,
                "expected CAMERA_ID MODEL WIDTH HEIGHT PARAMS, whole ids and finite numbers".into(),
            ));
        };
        let want = match *model {
            "PINHOLE" => 6,
            "OPENCV" => 10,
            "FULL_OPENCV" => 14,
            other => {
                return Err(bad(
                    path,
                    k + 1,
                    format!(
                        "camera model {}: PINHOLE, OPENCV or FULL_OPENCV expected",
                        crate::io::clip(other, 40)
                    ),
                ));
            }
        };
        if v.len() != want {
            return Err(bad(
                path,
                k + 1,
                format!("{model} needs {} parameters", want - 2),
            ));
        }
        let side = 1.0..=f64::from(crate::camera::MAX_IMAGE_SIDE);
        if !(side.contains(&v[0])
            && side.contains(&v[1])
            && v[0].fract() == 0.0
            && v[1].fract() == 0.0)
        {
            return Err(bad(
                path,
                k + 1,
                format!(
                    "an image of {}x{} pixels: expected whole numbers from 1 to {}",
                    v[0],
                    v[1],
                    crate::camera::MAX_IMAGE_SIDE
                ),
            ));
        }
        let (w, h) = (v[0] as u32, v[1] as u32);
        let (fx, fy, cx, cy) = (v[2], v[3], v[4] - 0.5, v[5] - 0.5);
        let mut c = Camera::pinhole(fx, fy, cx, cy).with_image_size(w, h);
        for (d, x) in c.dist.iter_mut().zip(v[6..].iter()) {
            *d = *x;
        }
        crate::camera::Calibration::from_camera(c.clone())
            .validate()
            .map_err(|(field, message)| bad(path, k + 1, format!("{field}: {message}")))?;
        camera = Some((c, w, h, id));
    }
    camera.ok_or_else(|| bad(path, 1, "no camera in the file".into()))
}

/// points3D.txt: the points, and their ids to indices.
fn parse_points(
    path: &Path,
    text: &str,
) -> Result<(Vec<Vector3<f64>>, HashMap<i64, usize>), ModelError> {
    let mut points = Vec::new();
    let mut index_of: HashMap<i64, usize> = HashMap::new();
    for (k, l) in text.lines().enumerate().filter(content) {
        let f: Vec<&str> = l.split_whitespace().take(4).collect();
        let parsed = (f.len() == 4)
            .then(|| Some((whole(f[0])?, finite_numbers(&f[1..].join(" "))?)))
            .flatten();
        let Some((id, xyz)) = parsed else {
            return Err(bad(
                path,
                k + 1,
                "expected POINT3D_ID X Y Z ..., a whole id and finite coordinates".into(),
            ));
        };
        if id < 0 {
            return Err(bad(
                path,
                k + 1,
                format!("point id {id}: ids are 0 or more"),
            ));
        }
        if xyz.iter().any(|x| x.abs() > MAX_MODEL_COORDINATE) {
            return Err(bad(
                path,
                k + 1,
                format!("a coordinate beyond {MAX_MODEL_COORDINATE:e}: not a model's point"),
            ));
        }
        if index_of.insert(id, points.len()).is_some() {
            return Err(bad(path, k + 1, format!("point {id} is listed twice")));
        }
        points.push(Vector3::new(xyz[0], xyz[1], xyz[2]));
    }
    Ok((points, index_of))
}

/// images.txt: a head line, then its points' line (empty for an image without points).
fn parse_images(
    path: &Path,
    text: &str,
    camera_id: i64,
    (width, height): (u32, u32),
    index_of: &HashMap<i64, usize>,
) -> Result<Vec<ModelImage>, ModelError> {
    let mut lines = text.lines().enumerate();
    let mut images = Vec::new();
    let mut ids = std::collections::HashSet::new();
    let mut names = std::collections::HashSet::new();
    while let Some((k, head)) = lines.next() {
        if head.starts_with('#') || head.trim().is_empty() {
            continue;
        }
        let f: Vec<&str> = head.split_whitespace().collect();
        let parsed = (f.len() == 10)
            .then(|| {
                Some((
                    whole(f[0])?,
                    finite_numbers(&f[1..8].join(" "))?,
                    whole(f[8])?,
                ))
            })
            .flatten();
        let Some((id, v, cam)) = parsed else {
            return Err(bad(
                path,
                k + 1,
                "expected IMAGE_ID QW QX QY QZ TX TY TZ CAMERA_ID NAME: whole ids, finite numbers, a name without spaces".into(),
            ));
        };
        if !ids.insert(id) {
            return Err(bad(path, k + 1, format!("image {id} is listed twice")));
        }
        if cam != camera_id {
            return Err(bad(
                path,
                k + 1,
                format!("camera {cam} is not the camera of cameras.txt ({camera_id})"),
            ));
        }
        let norm = (v[0] * v[0] + v[1] * v[1] + v[2] * v[2] + v[3] * v[3]).sqrt();
        if !((norm - 1.0).abs() <= 1e-3) {
            return Err(bad(
                path,
                k + 1,
                format!("the rotation's quaternion has norm {norm}: expected a unit quaternion"),
            ));
        }
        if v[4..7].iter().any(|x| x.abs() > MAX_MODEL_COORDINATE) {
            return Err(bad(
                path,
                k + 1,
                format!("a translation beyond {MAX_MODEL_COORDINATE:e}: not a model's camera"),
            ));
        }
        let name = f[9].to_string();
        let escapes = Path::new(&name).is_absolute()
            || Path::new(&name)
                .components()
                .any(|c| matches!(c, std::path::Component::ParentDir));
        if escapes || name.chars().any(|c| c.is_control() || c == ',' || c == '"') {
            return Err(bad(
                path,
                k + 1,
                format!(
                    "image name {}: expected a name inside the images' folder (no '..', not absolute, no commas or quotes)",
                    crate::io::clip(&name, 60)
                ),
            ));
        }
        if !names.insert(name.clone()) {
            return Err(bad(path, k + 1, format!("image {name} is listed twice")));
        }
        let q = UnitQuaternion::from_quaternion(Quaternion::new(v[0], v[1], v[2], v[3]));
        let pose = Rigid3::new(Rotation3::from(q), Vector3::new(v[4], v[5], v[6]));
        let (k2, row) = lines.next().unwrap_or((k + 1, ""));
        let v = finite_numbers(row)
            .filter(|v| v.len() % 3 == 0)
            .ok_or_else(|| {
                bad(
                    path,
                    k2 + 1,
                    "expected X Y POINT3D_ID triples of finite numbers".into(),
                )
            })?;
        let mut keypoints = Vec::with_capacity(v.len() / 3);
        let mut point_of = Vec::with_capacity(v.len() / 3);
        let (w, h) = (f64::from(width), f64::from(height));
        for t in v.chunks(3) {
            if !(t[0] >= -1.0 && t[0] <= w + 1.0 && t[1] >= -1.0 && t[1] <= h + 1.0) {
                return Err(bad(
                    path,
                    k2 + 1,
                    format!(
                        "the keypoint ({}, {}) lies outside the {width}x{height} image",
                        t[0], t[1]
                    ),
                ));
            }
            keypoints.push(Vector2::new(t[0] - 0.5, t[1] - 0.5));
            if t[2].fract() != 0.0 {
                return Err(bad(
                    path,
                    k2 + 1,
                    format!("point id {}: expected a whole number (-1: none)", t[2]),
                ));
            }
            let id = t[2] as i64;
            point_of.push(if id < 0 {
                None
            } else {
                Some(*index_of.get(&id).ok_or_else(|| {
                    bad(path, k2 + 1, format!("point {id} is not in points3D.txt"))
                })?)
            });
        }
        images.push(ModelImage {
            name,
            pose,
            keypoints,
            point_of,
        });
    }
    Ok(images)
}

/// A COLMAP text model from its three files' texts (`(path, text)`, the paths for messages):
/// one camera, finite numbers in range, ids whole and unique, every point an image observes
/// in points3D.txt, names that stay inside the images' folder.
pub fn parse_model(
    cameras: (&Path, &str),
    images: (&Path, &str),
    points: (&Path, &str),
) -> Result<Model, ModelError> {
    let (camera, width, height, camera_id) = parse_camera(cameras.0, cameras.1)?;
    let (points, index_of) = parse_points(points.0, points.1)?;
    let (path, text) = images;
    let images = parse_images(path, text, camera_id, (width, height), &index_of)?;
    if images.is_empty() {
        return Err(bad(path, 1, "no registered image in the model".into()));
    }
    Ok(Model {
        camera,
        width,
        height,
        images,
        points,
    })
}

/// One new image's registration.
#[derive(Clone, Debug, Serialize)]
pub struct Registration {
    pub name: String,
    #[serde(skip)]
    pub pose: Option<Rigid3>,
    /// 2D–3D correspondences found, and those the pose agrees with.
    pub correspondences: usize,
    pub inliers: usize,
    /// RMS reprojection error of the inliers, pixels.
    pub rms_px: Option<f64>,
    pub reason: Option<String>,
    /// The pose is not measured but interpolated between the nearest registered frames before
    /// and after (a video frame whose features failed: blur, water, sky).
    pub interpolated: bool,
    /// The inliers: each keypoint's pixel and its model point (what a tracker carries on).
    #[serde(skip)]
    pub matched: Vec<(Vector2<f64>, Vector3<f64>)>,
}

/// Gives each unregistered frame between two registered ones a pose interpolated by frame
/// number (centres linearly, rotations along the shortest arc) and flags it; `frames` are the
/// registrations' frame numbers, increasing. Frames before the first or after the last
/// registered one stay without a pose.
pub fn interpolate_failed(regs: &mut [Registration], frames: &[usize]) {
    let known: Vec<usize> = (0..regs.len())
        .filter(|&k| regs[k].pose.is_some())
        .collect();
    for pair in known.windows(2) {
        let (a, b) = (pair[0], pair[1]);
        let (pa, pb) = (regs[a].pose.expect("known"), regs[b].pose.expect("known"));
        for k in a + 1..b {
            let t = (frames[k] - frames[a]) as f64 / (frames[b] - frames[a]) as f64;
            regs[k].pose = Some(pa.interpolate(&pb, t));
            regs[k].interpolated = true;
        }
    }
}

#[derive(Clone, Debug)]
pub struct RegisterSettings {
    pub inlier_px: f64,
    pub min_inliers: usize,
    pub seed: u64,
}

impl Default for RegisterSettings {
    fn default() -> Self {
        RegisterSettings {
            inlier_px: 4.0,
            min_inliers: 30,
            seed: 0,
        }
    }
}

/// Registers one image taken with `camera` from its keypoints (`pixels`) and its matches with
/// model images (`matches`: model image index, then `(new keypoint, model keypoint)` pairs).
pub fn register_image(
    model: &Model,
    camera: &Camera,
    name: &str,
    pixels: &[Vector2<f64>],
    matches: &[(usize, Vec<(usize, usize)>)],
    s: &RegisterSettings,
) -> Registration {
    // Each new keypoint's model point, by votes over the model images it matched.
    let mut votes: HashMap<(usize, usize), usize> = HashMap::new();
    for (m, pairs) in matches {
        let img = &model.images[*m];
        for &(a, b) in pairs {
            if let Some(Some(p)) = img.point_of.get(b) {
                *votes.entry((a, *p)).or_insert(0) += 1;
            }
        }
    }
    let mut best: HashMap<usize, (usize, usize)> = HashMap::new();
    for (&(a, p), &n) in &votes {
        let e = best.entry(a).or_insert((p, n));
        if n > e.1 || (n == e.1 && p < e.0) {
            *e = (p, n);
        }
    }
    // In keypoint order: the sampler's draws must not depend on a hash map's order.
    let mut chosen: Vec<(usize, usize)> = best.into_iter().map(|(a, (p, _))| (a, p)).collect();
    chosen.sort_unstable();
    let mut world = Vec::new();
    let mut xy = Vec::new();
    let mut uv = Vec::new();
    for &(a, p) in &chosen {
        let Ok(ray) = camera.unproject(&pixels[a]) else {
            continue;
        };
        if ray.z <= 1e-9 {
            continue;
        }
        world.push(model.points[p]);
        xy.push(Vector2::new(ray.x / ray.z, ray.y / ray.z));
        uv.push(pixels[a]);
    }
    let fail = |reason: String, inliers: usize| Registration {
        name: name.to_string(),
        pose: None,
        correspondences: world.len(),
        inliers,
        rms_px: None,
        reason: Some(reason),
        interpolated: false,
        matched: Vec::new(),
    };
    if world.len() < s.min_inliers {
        return fail(
            format!(
                "{} of its features match model points, {} needed (too little overlap with the model's images, or too little texture)",
                world.len(),
                s.min_inliers
            ),
            0,
        );
    }
    let est = PnpEstimator::new(&world, &xy, camera.fx);
    let Ok(r) = msac(
        &est,
        &RansacSettings {
            threshold: s.inlier_px,
            seed: s.seed,
            ..RansacSettings::default()
        },
    ) else {
        return fail("no pose agrees with enough of its matches".into(), 0);
    };
    if r.inlier_count < s.min_inliers {
        return fail(
            format!(
                "only {} matches agree on a pose, {} needed",
                r.inlier_count, s.min_inliers
            ),
            r.inlier_count,
        );
    }
    let mut inliers: Vec<usize> = (0..world.len()).filter(|&k| r.inliers[k]).collect();
    let mut pose = gauss_newton_pose(&world, &xy, &inliers, &r.model, 10);
    // Once more with the inliers of the refined pose.
    let err = |pose: &Rigid3, k: usize| -> f64 {
        camera
            .project(&pose.apply(&world[k]))
            .map_or(f64::INFINITY, |p| (p - uv[k]).norm())
    };
    let again: Vec<usize> = (0..world.len())
        .filter(|&k| err(&pose, k) <= s.inlier_px)
        .collect();
    if again.len() >= s.min_inliers {
        inliers = again;
        pose = gauss_newton_pose(&world, &xy, &inliers, &pose, 10);
    }
    let rms =
        (inliers.iter().map(|&k| err(&pose, k).powi(2)).sum::<f64>() / inliers.len() as f64).sqrt();
    Registration {
        name: name.to_string(),
        pose: Some(pose),
        correspondences: world.len(),
        inliers: inliers.len(),
        rms_px: Some(rms),
        reason: None,
        interpolated: false,
        matched: inliers.iter().map(|&k| (uv[k], world[k])).collect(),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn reg(pose: Option<Rigid3>) -> Registration {
        Registration {
            name: String::new(),
            pose,
            correspondences: 0,
            inliers: 0,
            rms_px: None,
            reason: pose.is_none().then(|| "failed".into()),
            interpolated: false,
            matched: Vec::new(),
        }
    }

    #[test]
    fn failed_frames_between_registered_ones_are_interpolated_and_flagged() {
        let pose = |e: f64, yaw_deg: f64| {
            let r = Rotation3::from_euler_angles(std::f64::consts::PI, 0.0, yaw_deg.to_radians());
            Rigid3::new(r, -(r * Vector3::new(e, 0.0, 30.0)))
        };
        let mut regs = vec![
            reg(None),
            reg(Some(pose(0.0, 0.0))),
            reg(None),
            reg(None),
            reg(Some(pose(3.0, 3.0))),
            reg(None),
        ];
        interpolate_failed(&mut regs, &[0, 10, 11, 12, 13, 14]);
        assert!(regs[0].pose.is_none() && regs[5].pose.is_none());
        assert!(!regs[1].interpolated && regs[2].interpolated && regs[3].interpolated);
        let p = regs[3].pose.unwrap();
        // Frame 12 of 10..13: two thirds of the way.
        assert!((p.centre() - Vector3::new(2.0, 0.0, 30.0)).norm() < 1e-9);
        let angle = (p.rotation * pose(2.0, 2.0).rotation.inverse()).angle();
        assert!(angle < 1e-6, "{angle}");
    }
}
