//! A reference model that new images and video frames are placed in: the model read back, its
//! images' features (from the model's cache where it holds them), and the registration of one
//! image against the model images nearest where it is expected. The model is never changed: its
//! points are the fixed 3D side of every 2D–3D correspondence.

use std::path::{Path, PathBuf};

use nalgebra::{Matrix3, Vector2, Vector3};

use super::FeatureSettings;
use super::Features;
use super::cache::SfmCache;
use super::job::SfmJobError;
use super::job::extract_features;
use super::matching::{MatchSettings, match_features};
use super::register::ModelError;
use super::register::{Model, RegisterSettings, Registration, read_model, register_image};
use super::video_pose::{ModelFloor, PlacedKey, SIGMA_PX, VideoPoseSettings, pose_from_carried};
use crate::camera::Camera;
use crate::geom::Rigid3;
use crate::geom::similarity::Similarity;
use crate::progress::Progress;

/// A model and its images' features, ready to register images against.
pub struct Reference {
    pub model: Model,
    /// The model images' features, in the model's image order.
    pub features: Vec<Features>,
    /// The model's frame as its report says (`site`, `enu`, `model`).
    pub frame: String,
}

impl Reference {
    /// Reads the model in `model_dir` (COLMAP text, `geostride sfm`'s output) and its images'
    /// features from `model_images`: the model's own cache serves those it holds, read only (the
    /// model is an input), and `cache` those found since. The settings must be the model's, or
    /// the keypoints would not be the model's.
    pub fn load(
        model_dir: &Path,
        model_images: &Path,
        settings: &FeatureSettings,
        cache: &SfmCache,
        progress: &dyn Progress,
    ) -> Result<Reference, RegisterError> {
        Self::of_model(
            read_model(model_dir)?,
            model_dir,
            model_images,
            settings,
            cache,
            progress,
        )
    }

    /// [`Reference::load`] of a model read already (from `model_dir`).
    pub fn of_model(
        model: Model,
        model_dir: &Path,
        model_images: &Path,
        settings: &FeatureSettings,
        cache: &SfmCache,
        progress: &dyn Progress,
    ) -> Result<Reference, RegisterError> {
        let paths: Vec<PathBuf> = model
            .images
            .iter()
            .map(|m| model_images.join(&m.name))
            .collect();
        let frame = std::fs::read_to_string(model_dir.join("report.json"))
            .ok()
            .and_then(|t| serde_json::from_str::<serde_json::Value>(&t).ok())
            .and_then(|v| v["frame"].as_str().map(str::to_string))
            .unwrap_or_else(|| "model".into());
        // Every model photo present before the long work.
        if let Some(missing) = paths.iter().find(|p| !p.is_file()) {
            return Err(RegisterError::MissingImage {
                path: missing.clone(),
            });
        }
        let cache = cache.clone().reading_also(&model_dir.join("cache"));
        let (features, _, _) = extract_features(&paths, settings, &cache, progress)?;
        for (k, (f, m)) in features.iter().zip(&model.images).enumerate() {
            // The same count and the same places: another photo of the same name, or other
            // settings, would attach the model's points to the wrong features.
            let moved = f
                .keypoints
                .iter()
                .zip(&m.keypoints)
                .any(|(a, b)| (a.x - b.x).abs() > 0.01 || (a.y - b.y).abs() > 0.01);
            if f.len() != m.keypoints.len() || moved {
                return Err(RegisterError::FeaturesDiffer {
                    path: paths[k].clone(),
                    found: f.len(),
                    listed: m.keypoints.len(),
                });
            }
        }
        Ok(Reference {
            model,
            features,
            frame,
        })
    }

    /// Moves the model into another frame (`dst = s·R·src + t`, a site frame, say): its points
    /// and its cameras.
    pub fn transform(&mut self, dst_from_model: &Similarity) {
        for p in &mut self.model.points {
            *p = dst_from_model.apply(p);
        }
        let r_dst_from_model = dst_from_model.rotation.to_rotation_matrix();
        for im in &mut self.model.images {
            let centre = dst_from_model.apply(&im.pose.centre());
            let rotation = im.pose.rotation * r_dst_from_model.inverse();
            im.pose = Rigid3::new(rotation, -(rotation * centre));
        }
    }

    /// The model images whose centres are horizontally nearest `near`, `k` of them (all when
    /// `near` is `None` or `k` is 0 or the model's size).
    pub fn nearest_images(&self, near: Option<&Vector3<f64>>, k: usize) -> Vec<usize> {
        let m = self.model.images.len();
        let Some(here) = near.filter(|_| k > 0 && k < m) else {
            return (0..m).collect();
        };
        let mut by: Vec<(f64, usize)> = self
            .model
            .images
            .iter()
            .enumerate()
            .map(|(i, im)| ((im.pose.centre() - here).xy().norm(), i))
            .collect();
        by.sort_by(|a, b| a.0.total_cmp(&b.0).then(a.1.cmp(&b.1)));
        by.into_iter().take(k).map(|(_, i)| i).collect()
    }

    /// Registers one image from its features, matched with the model images `with`.
    pub fn register(
        &self,
        camera: &Camera,
        name: &str,
        features: &Features,
        with: &[usize],
        matching: &MatchSettings,
        settings: &RegisterSettings,
    ) -> Registration {
        let matches: Vec<(usize, Vec<(usize, usize)>)> = with
            .iter()
            .map(|&k| {
                let found = match_features(features, &self.features[k], matching);
                (k, found.iter().map(|x| (x.a, x.b)).collect())
            })
            .collect();
        let pixels: Vec<Vector2<f64>> = features
            .keypoints
            .iter()
            .map(|k| Vector2::new(k.x, k.y))
            .collect();
        register_image(&self.model, camera, name, &pixels, &matches, settings)
    }

    /// Registers a video frame against the model photos nearest `near` (all when it fails
    /// there); gives the photos it was last matched with too.
    pub fn place_frame(
        &self,
        camera: &Camera,
        name: &str,
        features: &Features,
        near: Option<&Vector3<f64>>,
        s: &VideoPoseSettings,
    ) -> (Registration, Vec<usize>) {
        let settings = RegisterSettings {
            min_inliers: s.min_inliers,
            ..RegisterSettings::default()
        };
        let with = self.nearest_images(near, s.neighbours);
        let all = self.model.images.len();
        let r = self.register(
            camera,
            name,
            features,
            &with,
            &MatchSettings::default(),
            &settings,
        );
        if r.pose.is_some() || with.len() == all {
            return (r, with);
        }
        let every: Vec<usize> = (0..all).collect();
        let r = self.register(
            camera,
            name,
            features,
            &every,
            &MatchSettings::default(),
            &settings,
        );
        (r, every)
    }

    /// A key frame placed in the model ([`Reference::place_frame`]), its pose refined from the
    /// inliers with the model points held ([`pose_from_carried`] with no motion) and its σ
    /// floored by the model's; the registration (its reason set when the inliers do not refine)
    /// and the photos matched with.
    pub fn place_key_frame(
        &self,
        camera: &Camera,
        name: &str,
        features: &Features,
        near: Option<&Vector3<f64>>,
        (floor, s): (&ModelFloor, &VideoPoseSettings),
    ) -> (Registration, Vec<usize>, Option<PlacedKey>) {
        let (mut r, with) = self.place_frame(camera, name, features, near, s);
        let mut key = None;
        if let Some(start) = r.pose {
            let refined = pose_from_carried(
                camera,
                &start,
                &r.matched,
                &Matrix3::identity(),
                SIGMA_PX,
                s.min_inliers,
            );
            match refined {
                Some((p, rms, _)) => {
                    key = Some(PlacedKey {
                        placed: floor.placed(&p, rms),
                        matched: r.matched.clone(),
                    })
                }
                None => r.reason = Some("its inliers did not refine to a pose".into()),
            }
        }
        (r, with, key)
    }
}

/// One camera of a georeferenced model's `cameras.csv`.
#[derive(Clone, Debug)]
pub struct GeoCamera {
    pub image: String,
    /// Centre in the model's frame, metres.
    pub centre: Vector3<f64>,
    /// Centre in the survey's CRS (`crs_x, crs_y, crs_h`).
    pub crs: Vector3<f64>,
    /// σ of the centre east, north, up (metres) and of the attitude (degrees).
    pub sigma_enu_m: Vector3<f64>,
    pub sigma_rotation_deg: f64,
}

/// The registered, georeferenced cameras of a model's `cameras.csv` (as `geostride sfm --gcps`
/// writes it). An error names the file and line, or says the model is not georeferenced.
pub fn read_geo_cameras(model_dir: &Path) -> Result<Vec<GeoCamera>, crate::io::FileError> {
    let path = model_dir.join("cameras.csv");
    let ctx = crate::io::FileCtx { path: &path };
    let text = ctx.read_text("a model's cameras.csv")?;
    let mut lines = text.lines();
    let header: Vec<&str> = lines
        .next()
        .unwrap_or("")
        .split(',')
        .map(str::trim)
        .collect();
    let need = [
        "image",
        "registered",
        "x",
        "y",
        "z",
        "crs_x",
        "crs_y",
        "crs_h",
        "sigma_e_m",
        "sigma_n_m",
        "sigma_u_m",
        "sigma_rotation_deg",
    ];
    let mut col = [0usize; 12];
    for (k, n) in need.iter().enumerate() {
        col[k] = header.iter().position(|h| h == n).ok_or_else(|| {
            ctx.at(
                1,
                format!(
                    "no column '{n}': the model is not georeferenced (build it with geostride sfm ... --gcps GCPS)"
                ),
            )
        })?;
    }
    let mut out = Vec::new();
    for (i, l) in lines.enumerate() {
        let line = i + 2;
        let f: Vec<&str> = l.split(',').map(str::trim).collect();
        if l.trim().is_empty() || f.get(col[1]) != Some(&"yes") {
            continue;
        }
        let num = |k: usize| -> Result<f64, crate::io::FileError> {
            ctx.number(f.get(col[k]).copied().unwrap_or(""), line, need[k])
        };
        out.push(GeoCamera {
            image: f[col[0]].to_string(),
            centre: Vector3::new(num(2)?, num(3)?, num(4)?),
            crs: Vector3::new(num(5)?, num(6)?, num(7)?),
            sigma_enu_m: Vector3::new(num(8)?, num(9)?, num(10)?),
            sigma_rotation_deg: num(11)?,
        });
    }
    if out.len() < 3 {
        return Err(ctx.at(
            1,
            format!(
                "{} georeferenced camera(s); at least 3 are needed to place the model",
                out.len()
            ),
        ));
    }
    Ok(out)
}

/// The features' cap a model was built with (its report.json), else the default.
pub fn model_max_features(model_dir: &Path) -> usize {
    std::fs::read_to_string(model_dir.join("report.json"))
        .ok()
        .and_then(|t| serde_json::from_str::<serde_json::Value>(&t).ok())
        .and_then(|v| v["max_features"].as_u64())
        .map_or(FeatureSettings::default().max_features, |v| v as usize)
}

/// Keeps the features outside every `[x, y, width, height]` box (people, who move, and their
/// shadows); gives how many were dropped.
pub fn mask_features(features: &mut Features, boxes: &[[f64; 4]]) -> usize {
    if boxes.is_empty() {
        return 0;
    }
    let n = features.keypoints.len();
    let len = super::DESCRIPTOR_LEN;
    let mut keypoints = Vec::with_capacity(n);
    let mut descriptors = Vec::with_capacity(features.descriptors.len());
    for (i, k) in features.keypoints.iter().enumerate() {
        let inside = boxes
            .iter()
            .any(|b| k.x >= b[0] && k.x <= b[0] + b[2] && k.y >= b[1] && k.y <= b[1] + b[3]);
        if !inside {
            keypoints.push(k.clone());
            descriptors.extend_from_slice(&features.descriptors[i * len..(i + 1) * len]);
        }
    }
    let dropped = n - keypoints.len();
    features.keypoints = keypoints;
    features.descriptors = descriptors;
    dropped
}

#[derive(Debug, thiserror::Error)]
pub enum RegisterError {
    #[error(transparent)]
    Model(#[from] ModelError),
    #[error(transparent)]
    Job(#[from] SfmJobError),
    #[error(
        "{}: {found} features, but the model lists {listed} keypoints for it, or not in the same places: the model was built from other features (another photo of that name, another version or --max-features); build it again or give its images as they were",
        path.display()
    )]
    FeaturesDiffer {
        path: PathBuf,
        found: usize,
        listed: usize,
    },
    #[error(
        "{}: a photo of the model is not here: give the folder of the model's photos (--model-images)",
        path.display()
    )]
    MissingImage { path: PathBuf },
    #[error("{0}")]
    Video(String),
    #[error("{}: the new images are {width}x{height}, their camera {mw}x{mh}: give the camera of these images (--camera)", path.display())]
    Size {
        path: PathBuf,
        width: u32,
        height: u32,
        mw: u32,
        mh: u32,
    },
}

impl RegisterError {
    pub fn is_input(&self) -> bool {
        match self {
            RegisterError::Job(e) => e.is_input(),
            _ => true,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn masked_features_inside_boxes_are_dropped_with_their_descriptors() {
        let kp = |x: f64, y: f64| super::super::Keypoint {
            x,
            y,
            size: 1.0,
            angle_deg: 0.0,
            response: 1.0,
        };
        let len = super::super::DESCRIPTOR_LEN;
        let mut f = Features {
            width: 100,
            height: 100,
            keypoints: vec![kp(5.0, 5.0), kp(50.0, 50.0), kp(90.0, 10.0)],
            descriptors: (0..3 * len).map(|i| (i / len) as f32).collect(),
        };
        assert_eq!(mask_features(&mut f, &[[40.0, 40.0, 20.0, 20.0]]), 1);
        assert_eq!(f.keypoints.len(), 2);
        assert_eq!(f.descriptor(1)[0], 2.0);
    }
}
