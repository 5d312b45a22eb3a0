//! `geostride sfm` as a library call: images in, a reconstruction, its report and its files out.
//! Features, exhaustive pair matching, the incremental reconstruction; COLMAP text model, PLY,
//! `report.json` and `report.md`.

use std::path::{Path, PathBuf};
use std::time::Instant;

use nalgebra::Vector2;
use serde::Serialize;

use super::colmap::{cameras_txt, images_txt, ply, points3d_txt};
use super::matching::{MatchSettings, match_features};
use super::reconstruct::{Reconstruction, SfmError, SfmSettings, reconstruct};
use super::sift::read_features;
use super::tracks::PairMatches;
use super::{FeatureSettings, Features};
use crate::camera::Camera;
use crate::imageio::ImageError;
use crate::progress::Progress;

/// What to reconstruct, and how.
#[derive(Clone, Debug)]
pub struct SfmJob {
    pub images: Vec<PathBuf>,
    /// The camera of every image (its size is scaled to the images' when the aspect agrees).
    pub camera: Camera,
    pub features: FeatureSettings,
    pub matching: MatchSettings,
    pub sfm: SfmSettings,
}

/// Why a job could not run.
#[derive(Debug, thiserror::Error)]
pub enum SfmJobError {
    #[error(transparent)]
    Image(#[from] ImageError),
    #[error(
        "{}: {width}x{height}, but {} is {first_w}x{first_h}: one camera is used for every image, so \
         every image must have its size (give the images of one camera)",
        path.display(),
        first.display()
    )]
    MixedSizes {
        path: PathBuf,
        width: u32,
        height: u32,
        first: PathBuf,
        first_w: u32,
        first_h: u32,
    },
    #[error(
        "the camera is for {cw}x{ch} images, the images are {width}x{height}: another aspect \
         ratio (give the calibration of this camera at this resolution)"
    )]
    CameraSize {
        cw: u32,
        ch: u32,
        width: u32,
        height: u32,
    },
    #[error(transparent)]
    Sfm(#[from] SfmError),
}

impl SfmJobError {
    /// Whether the inputs are at fault (exit code 2) rather than the run.
    pub fn is_input(&self) -> bool {
        match self {
            SfmJobError::Image(ImageError::File { .. }) => true,
            SfmJobError::Image(_) => false,
            SfmJobError::Sfm(SfmError::Adjustment(_)) => false,
            _ => true,
        }
    }
}

/// One image's part of the report.
#[derive(Clone, Debug, Serialize)]
pub struct ImageReport {
    pub name: String,
    pub registered: bool,
    pub features: usize,
    /// Features that observe a point of the model.
    pub observations: usize,
    /// Why it is not registered.
    pub reason: Option<String>,
}

/// What a run found (`report.json`).
#[derive(Clone, Debug, Serialize)]
pub struct SfmReport {
    pub images: usize,
    pub registered: usize,
    pub points: usize,
    pub observations: usize,
    pub mean_track_length: f64,
    pub mean_reprojection_px: f64,
    /// The camera at the end: `[fx, fy, cx, cy, skew, k1, k2, p1, p2, k3, k4, k5, k6]`, pixel
    /// centres at integers.
    pub camera: Vec<f64>,
    pub pairs_matched: usize,
    pub initial_pair: (String, String),
    pub per_image: Vec<ImageReport>,
    pub seconds_features: f64,
    pub seconds_matching: f64,
    pub seconds_reconstruction: f64,
}

/// A finished run: the model, the images' names and keypoints, the report.
pub struct SfmRun {
    pub reconstruction: Reconstruction,
    pub names: Vec<String>,
    pub keypoints: Vec<Vec<Vector2<f64>>>,
    pub width: u32,
    pub height: u32,
    pub report: SfmReport,
}

fn file_name(p: &Path) -> String {
    p.file_name().map_or_else(
        || p.display().to_string(),
        |n| n.to_string_lossy().into_owned(),
    )
}

/// Runs the job; `features` and `matching` show the progress of those two stages.
pub fn run_sfm(
    job: &SfmJob,
    features: &dyn Progress,
    matching: &dyn Progress,
) -> Result<SfmRun, SfmJobError> {
    if job.images.len() < 2 {
        return Err(SfmError::TooFewImages(job.images.len()).into());
    }
    let t = Instant::now();
    features.set_length(job.images.len() as u64);
    let mut found: Vec<Features> = Vec::with_capacity(job.images.len());
    for path in &job.images {
        let f = read_features(path, &job.features)?;
        if let Some(first) = found.first()
            && (f.width, f.height) != (first.width, first.height)
        {
            return Err(SfmJobError::MixedSizes {
                path: path.clone(),
                width: f.width,
                height: f.height,
                first: job.images[0].clone(),
                first_w: first.width,
                first_h: first.height,
            });
        }
        found.push(f);
        features.inc(1);
    }
    let seconds_features = t.elapsed().as_secs_f64();
    let (width, height) = (found[0].width, found[0].height);
    let camera = match job.camera.image_size {
        Some(s) if (s.width, s.height) == (width, height) => job.camera.clone(),
        Some(s) => job
            .camera
            .scaled_to(width, height)
            .ok_or(SfmJobError::CameraSize {
                cw: s.width,
                ch: s.height,
                width,
                height,
            })?,
        None => job.camera.clone().with_image_size(width, height),
    };
    let t = Instant::now();
    let n = found.len();
    matching.set_length((n * (n - 1) / 2) as u64);
    let mut pairs = Vec::new();
    for i in 0..n {
        for j in i + 1..n {
            let m = match_features(&found[i], &found[j], &job.matching);
            pairs.push(PairMatches {
                i,
                j,
                matches: m.iter().map(|m| (m.a, m.b)).collect(),
            });
            matching.inc(1);
        }
    }
    let seconds_matching = t.elapsed().as_secs_f64();
    let keypoints: Vec<Vec<Vector2<f64>>> = found
        .iter()
        .map(|f| f.keypoints.iter().map(|k| Vector2::new(k.x, k.y)).collect())
        .collect();
    let t = Instant::now();
    let r = reconstruct(&camera, &keypoints, &pairs, &job.sfm)?;
    let seconds_reconstruction = t.elapsed().as_secs_f64();
    let names: Vec<String> = job.images.iter().map(|p| file_name(p)).collect();
    let mut seen = vec![0usize; n];
    for p in &r.points {
        for &(i, _) in &p.observations {
            seen[i] += 1;
        }
    }
    let observations: usize = seen.iter().sum();
    let per_image = (0..n)
        .map(|i| ImageReport {
            name: names[i].clone(),
            registered: r.poses[i].is_some(),
            features: found[i].len(),
            observations: seen[i],
            reason: r.poses[i].is_none().then(|| {
                format!(
                    "fewer than {} of its features agree on a pose with the model's points \
                     (too little overlap with the registered images, or too little texture)",
                    job.sfm.min_pnp_inliers
                )
            }),
        })
        .collect();
    let report = SfmReport {
        images: n,
        registered: r.poses.iter().filter(|p| p.is_some()).count(),
        points: r.points.len(),
        observations,
        mean_track_length: observations as f64 / r.points.len().max(1) as f64,
        mean_reprojection_px: r.mean_reprojection_px,
        camera: r.camera.params().to_vec(),
        pairs_matched: pairs.len(),
        initial_pair: (
            names[r.initial_pair.0].clone(),
            names[r.initial_pair.1].clone(),
        ),
        per_image,
        seconds_features,
        seconds_matching,
        seconds_reconstruction,
    };
    Ok(SfmRun {
        reconstruction: r,
        names,
        keypoints,
        width,
        height,
        report,
    })
}

/// `report.md`: the summary and a line per image.
pub fn report_md(r: &SfmReport) -> String {
    let mut s = format!(
        "# Structure from motion\n\n\
         - images registered: {} of {}\n\
         - points: {}, observations: {} (mean track length {:.2})\n\
         - mean reprojection error: {:.3} px\n\
         - camera: fx {:.2}, fy {:.2}, cx {:.2}, cy {:.2}, k1 {:.4}, k2 {:.4}\n\
         - started from: {} and {}\n\
         - time: features {:.1} s, matching {:.1} s ({} pairs), reconstruction {:.1} s\n\n\
         | image | registered | features | observations | why not |\n\
         | --- | --- | --- | --- | --- |\n",
        r.registered,
        r.images,
        r.points,
        r.observations,
        r.mean_track_length,
        r.mean_reprojection_px,
        r.camera[0],
        r.camera[1],
        r.camera[2],
        r.camera[3],
        r.camera[5],
        r.camera[6],
        r.initial_pair.0,
        r.initial_pair.1,
        r.seconds_features,
        r.seconds_matching,
        r.pairs_matched,
        r.seconds_reconstruction
    );
    for i in &r.per_image {
        s.push_str(&format!(
            "| {} | {} | {} | {} | {} |\n",
            i.name,
            if i.registered { "yes" } else { "no" },
            i.features,
            i.observations,
            i.reason.as_deref().unwrap_or("")
        ));
    }
    s
}

/// Writes the run's files into `out` (which exists): the COLMAP text model, `points.ply`,
/// `report.json`, `report.md`. Returns their names.
pub fn write_outputs(out: &Path, run: &SfmRun) -> std::io::Result<Vec<String>> {
    let r = &run.reconstruction;
    let files = [
        ("cameras.txt", cameras_txt(&r.camera, run.width, run.height)),
        ("images.txt", images_txt(r, &run.names, &run.keypoints)),
        ("points3D.txt", points3d_txt(r, &run.keypoints)),
        ("points.ply", ply(r)),
        (
            "report.json",
            serde_json::to_string_pretty(&run.report).map_err(std::io::Error::other)?,
        ),
        ("report.md", report_md(&run.report)),
    ];
    let mut written = Vec::new();
    for (name, text) in files {
        crate::io::write_atomic(&out.join(name), text.as_bytes())?;
        written.push(name.to_string());
    }
    Ok(written)
}
