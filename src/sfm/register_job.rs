//! `geostride sfm register MODEL IMAGES...` as a library call: the model read back, the model
//! images' features (from the model's cache where it holds them) and the new images', each new
//! image matched with its nearest model images (by EXIF GPS when every photo has it, else with
//! all), then registered (`sfm::register`). The model is not changed.

use std::path::{Path, PathBuf};
use std::time::Instant;

use serde::Serialize;

use super::FeatureSettings;
use super::cache::SfmCache;
use super::exif::{GpsFix, read_meta};
use super::job::{SfmJobError, enu_of, extract_features, file_name};
use super::matching::MatchSettings;
use super::reference::{Reference, RegisterError};
use super::register::{Model, RegisterSettings, Registration};
use crate::camera::Camera;
use crate::draw::{Chart, Series, Style, line_chart};
use crate::progress::Progress;
use crate::terrain::HeightSurface;

#[derive(Clone, Debug)]
pub struct RegisterJob {
    pub model_dir: PathBuf,
    /// Where the model's images are (their files, by the names in `images.txt`).
    pub model_images: PathBuf,
    pub images: Vec<PathBuf>,
    /// Or every `.1`-th frame of a video (named `VIDEO#FRAME`).
    pub video: Option<(PathBuf, usize)>,
    /// The new images' camera (a video's, say); `None`: the model's.
    pub camera: Option<Camera>,
    /// Model images each new image is matched with, nearest by GPS first; 0: all.
    pub neighbours: usize,
    pub features: FeatureSettings,
    pub matching: MatchSettings,
    pub settings: RegisterSettings,
    /// Cache of the new images' features; the model's own cache serves its images.
    pub cache_dir: Option<PathBuf>,
}

#[derive(Clone, Debug, Serialize)]
pub struct RegisterReport {
    pub model_images: usize,
    pub images: usize,
    pub registered: usize,
    /// The model's frame as its report says (`site`, `enu`, `model`).
    pub frame: String,
    pub per_image: Vec<Registration>,
    pub seconds: f64,
}

pub struct RegisterRun {
    pub model: Model,
    pub report: RegisterReport,
    /// For a video: the camera over time (the paper's Fig. 10).
    pub series: Option<Vec<PoseSample>>,
}

/// A video frame's camera: where it is, how far it has moved, its height above the ground
/// under it and how far it looks off nadir.
#[derive(Clone, Debug, PartialEq)]
pub struct PoseSample {
    pub frame: usize,
    pub time_s: f64,
    pub centre: nalgebra::Vector3<f64>,
    /// From the first posed frame, metres.
    pub translation_m: f64,
    /// Above the model's ground straight below (a robust local plane of its points, 2 m
    /// window, wider where sparse); `None` where the model has no ground there or its frame has
    /// no up.
    pub altitude_m: Option<f64>,
    /// Angle between the optical axis and straight down, degrees.
    pub off_nadir_deg: f64,
    pub interpolated: bool,
}

/// The camera over time from the frames' poses, in a model whose frame has `up` as its z.
pub fn pose_series(
    model: &Model,
    regs: &[Registration],
    frames: &[usize],
    fps: f64,
    up: bool,
) -> Vec<PoseSample> {
    let ground = up.then(|| crate::terrain::LocalPlanes::new(model.points.clone(), 2.0));
    let poses: Vec<(usize, crate::geom::Rigid3, bool)> = regs
        .iter()
        .zip(frames)
        .filter_map(|(r, &f)| Some((f, r.pose?, r.interpolated)))
        .collect();
    camera_series(
        ground.as_ref().map(|g| g as &dyn HeightSurface),
        &poses,
        fps,
    )
}

/// The camera over time from `(frame, cam_from_world, interpolated)`, the altitude above
/// `ground` (a site frame's, z up) where given.
pub(crate) fn camera_series(
    ground: Option<&dyn HeightSurface>,
    poses: &[(usize, crate::geom::Rigid3, bool)],
    fps: f64,
) -> Vec<PoseSample> {
    let mut first = None;
    let mut out = Vec::new();
    for &(f, pose, interpolated) in poses {
        let c = pose.centre();
        let start = *first.get_or_insert(c);
        let axis = pose.rotation.inverse() * nalgebra::Vector3::z();
        let altitude_m = ground.and_then(|g| g.height(&c.xy())).map(|z| c.z - z);
        out.push(PoseSample {
            frame: f,
            time_s: f as f64 / fps,
            centre: c,
            translation_m: (c - start).norm(),
            altitude_m,
            off_nadir_deg: axis
                .dot(&-nalgebra::Vector3::z())
                .clamp(-1.0, 1.0)
                .acos()
                .to_degrees(),
            interpolated,
        });
    }
    out
}

/// `pose_series.csv`.
pub(crate) fn pose_series_csv(series: &[PoseSample]) -> String {
    let mut s = String::from(
        "frame,time_s,e_m,n_m,u_m,translation_m,altitude_m,off_nadir_deg,interpolated\n",
    );
    for p in series {
        s.push_str(&format!(
            "{},{:.4},{:.4},{:.4},{:.4},{:.4},{},{:.4},{}\n",
            p.frame,
            p.time_s,
            p.centre.x,
            p.centre.y,
            p.centre.z,
            p.translation_m,
            p.altitude_m.map_or(String::new(), |a| format!("{a:.4}")),
            p.off_nadir_deg,
            u8::from(p.interpolated)
        ));
    }
    s
}

/// Which model images (of `m`) each of the `n_new` new ones is matched with: the `neighbours`
/// nearest by EXIF GPS (`all`: the model's photos, then the new ones), else all of them (a video's
/// frames have no EXIF GPS).
fn model_images_to_match(
    job: &RegisterJob,
    all: &[PathBuf],
    m: usize,
    n_new: usize,
) -> Vec<Vec<usize>> {
    let gps: Option<Vec<GpsFix>> = if job.video.is_some() {
        None
    } else {
        // Fixes far from the others' (another continent) are not used: then all are matched.
        let metas: Vec<_> = all
            .iter()
            .map(|p| read_meta(p).unwrap_or_default())
            .collect();
        let names: Vec<String> = all.iter().map(|p| file_name(p)).collect();
        super::job::consistent_gps(&metas, &names)
            .fixes
            .into_iter()
            .collect()
    };
    match gps.as_ref().and_then(|g| enu_of(g)) {
        Some((enu, _)) if job.neighbours > 0 && job.neighbours < m => (0..n_new)
            .map(|i| {
                let model = enu[..m].iter().map(|p| p.xy()).enumerate();
                super::job::nearest_to(enu[m + i].xy(), model, job.neighbours)
            })
            .collect(),
        _ => vec![(0..m).collect(); n_new],
    }
}

/// Runs the registration; `features` and `matching` show their stages' progress.
pub fn run_register(
    job: &RegisterJob,
    features: &dyn Progress,
    matching: &dyn Progress,
) -> Result<RegisterRun, RegisterError> {
    let t = Instant::now();
    // The new images' names and sizes before any work.
    super::job::check_images(&job.images)?;
    if let Some((video, _)) = &job.video
        && let Some(reason) = super::job::name_problem(&file_name(video))
    {
        return Err(SfmJobError::BadName {
            path: video.clone(),
            reason,
        }
        .into());
    }
    let cache = SfmCache::new(job.cache_dir.as_deref());
    let reference = Reference::load(
        &job.model_dir,
        &job.model_images,
        &job.features,
        &cache,
        features,
    )?;
    let model_paths: Vec<PathBuf> = reference
        .model
        .images
        .iter()
        .map(|m| job.model_images.join(&m.name))
        .collect();
    let mut all: Vec<PathBuf> = model_paths;
    all.extend(job.images.iter().cloned());
    let (new_features, new_names, fps) = match &job.video {
        None => (
            extract_features(&job.images, &job.features, &cache, features)?.0,
            job.images.iter().map(|p| file_name(p)).collect::<Vec<_>>(),
            1.0,
        ),
        Some((video, every)) => video_features(video, *every, &job.features, features)?,
    };
    let mut camera = match &job.camera {
        Some(c) => c.clone(),
        None => reference.model.camera.clone(),
    };
    // A calibration at another resolution of the same aspect (a video mode) is scaled.
    if let (Some(f), Some(size)) = (new_features.first(), camera.image_size)
        && (f.width, f.height) != (size.width, size.height)
        && let Some(scaled) = camera.scaled_to(f.width, f.height)
    {
        camera = scaled;
    }
    let size = camera
        .image_size
        .map_or((reference.model.width, reference.model.height), |s| {
            (s.width, s.height)
        });
    if let Some(f) = new_features.first()
        && (f.width, f.height) != size
    {
        return Err(RegisterError::Size {
            path: job
                .video
                .as_ref()
                .map_or_else(|| job.images[0].clone(), |v| v.0.clone()),
            width: f.width,
            height: f.height,
            mw: size.0,
            mh: size.1,
        });
    }
    let m = reference.model.images.len();
    let n_new = new_features.len();
    let chosen = model_images_to_match(job, &all, m, n_new);
    matching.set_length(chosen.iter().map(Vec::len).sum::<usize>() as u64);
    let mut per_image = Vec::new();
    for (i, name) in new_names.iter().enumerate() {
        per_image.push(reference.register(
            &camera,
            name,
            &new_features[i],
            &chosen[i],
            &job.matching,
            &job.settings,
        ));
        matching.inc(chosen[i].len() as u64);
    }
    // A video's frames that failed, between registered ones: interpolated and flagged.
    let mut series = None;
    if job.video.is_some() {
        let frames: Vec<usize> = new_names
            .iter()
            .map(|n| {
                crate::io::frame_of_name(n)
                    .and_then(Result::ok)
                    .unwrap_or(0)
            })
            .collect();
        super::register::interpolate_failed(&mut per_image, &frames);
        series = Some(pose_series(
            &reference.model,
            &per_image,
            &frames,
            fps,
            reference.frame != "model",
        ));
    }
    let report = RegisterReport {
        model_images: m,
        images: n_new,
        registered: per_image
            .iter()
            .filter(|r| r.pose.is_some() && !r.interpolated)
            .count(),
        frame: reference.frame.clone(),
        per_image,
        seconds: t.elapsed().as_secs_f64(),
    };
    Ok(RegisterRun {
        model: reference.model,
        report,
        series,
    })
}

/// Features of every `every`-th frame of a video (from frame 0), named `VIDEO#FRAME`.
fn video_features(
    video: &Path,
    every: usize,
    settings: &FeatureSettings,
    progress: &dyn Progress,
) -> Result<(Vec<super::Features>, Vec<String>, f64), RegisterError> {
    let mut reader = crate::video::source::FrameReader::open(video)
        .map_err(|e| RegisterError::Video(e.to_string()))?;
    let fps = reader.fps;
    let name = file_name(video);
    let (mut found, mut names) = (Vec::new(), Vec::new());
    while let Some((index, grey)) = reader
        .next_gray()
        .map_err(|e| RegisterError::Video(e.to_string()))?
    {
        if index % every.max(1) != 0 {
            continue;
        }
        found.push(
            super::sift::features_of_grey(&grey, settings)
                .map_err(|e| RegisterError::Video(e.to_string()))?,
        );
        names.push(format!("{name}#{index}"));
        progress.inc(1);
    }
    Ok((found, names, fps))
}

/// `cameras.csv` of the new images, as `geostride sfm` writes it: each image, whether
/// registered, the frame, its centre and `cam_from_world` quaternion, its inliers.
pub(crate) fn registered_csv(report: &RegisterReport) -> String {
    let mut s = String::from("image,registered,frame,x,y,z,qw,qx,qy,qz,inliers,rms_px\n");
    for r in &report.per_image {
        match r.pose {
            Some(pose) => {
                let state = if r.interpolated {
                    "interpolated"
                } else {
                    "yes"
                };
                let c = pose.centre();
                let q = nalgebra::UnitQuaternion::from_rotation_matrix(&pose.rotation);
                s.push_str(&format!(
                    "{},{state},{},{:.4},{:.4},{:.4},{:.9},{:.9},{:.9},{:.9},{},{:.3}\n",
                    r.name,
                    report.frame,
                    c.x,
                    c.y,
                    c.z,
                    q.w,
                    q.i,
                    q.j,
                    q.k,
                    r.inliers,
                    r.rms_px.unwrap_or(f64::NAN)
                ));
            }
            None => s.push_str(&format!(
                "{},no,{},,,,,,,,{},\n",
                r.name, report.frame, r.inliers
            )),
        }
    }
    s
}

/// `report.md` of a registration.
pub(crate) fn register_md(r: &RegisterReport) -> String {
    let mut s = format!(
        "# Images registered in a model\n\n\
         - {} of {} images registered in a model of {} images (frame: {})\n\
         - time: {:.1} s\n\n\
         | image | registered | correspondences | inliers | RMS px | why not |\n\
         | --- | --- | --- | --- | --- | --- |\n",
        r.registered, r.images, r.model_images, r.frame, r.seconds
    );
    for i in &r.per_image {
        s.push_str(&format!(
            "| {} | {} | {} | {} | {} | {} |\n",
            i.name,
            match (i.pose.is_some(), i.interpolated) {
                (true, false) => "yes",
                (true, true) => "interpolated",
                _ => "no",
            },
            i.correspondences,
            i.inliers,
            i.rms_px.map_or("-".into(), |v| format!("{v:.3}")),
            i.reason.as_deref().unwrap_or("")
        ));
    }
    s
}

/// Writes `cameras.csv`, `report.json` and `report.md` into `out`; their names.
pub fn write_register_outputs(out: &Path, run: &RegisterRun) -> std::io::Result<Vec<String>> {
    let files = [
        ("cameras.csv", registered_csv(&run.report)),
        (
            "report.json",
            serde_json::to_string_pretty(&run.report).map_err(std::io::Error::other)?,
        ),
        ("report.md", register_md(&run.report)),
    ];
    let mut written = Vec::new();
    for (name, text) in files {
        crate::io::write_atomic(&out.join(name), text.as_bytes())?;
        written.push(name.to_string());
    }
    if let Some(series) = &run.series {
        written.extend(write_pose_series(out, series)?);
    }
    Ok(written)
}

/// `pose_series.csv` and the paper's Fig. 10 as three charts (`pose_translation.png`,
/// `pose_altitude.png`, `pose_off_nadir.png`) in `out`; gives the names written.
pub(crate) fn write_pose_series(out: &Path, series: &[PoseSample]) -> std::io::Result<Vec<String>> {
    let mut written = Vec::new();
    crate::io::write_atomic(
        &out.join("pose_series.csv"),
        pose_series_csv(series).as_bytes(),
    )?;
    written.push("pose_series.csv".to_string());
    let panel = |title: &str, y: &str, v: &dyn Fn(&PoseSample) -> Option<f64>| Chart {
        y_from_data: title.starts_with("Altitude"),
        title: title.into(),
        x_label: "time, s".into(),
        y_label: y.into(),
        series: vec![Series {
            label: title.into(),
            xy: series
                .iter()
                .filter_map(|p| v(p).map(|y| (p.time_s, y)))
                .collect(),
            rgb: [31, 119, 180],
            style: Style::Line,
        }],
        ..Chart::default()
    };
    for (file, chart) in [
        (
            "pose_translation.png",
            panel("Camera translation", "m", &|p| Some(p.translation_m)),
        ),
        (
            "pose_altitude.png",
            panel("Altitude above the ground", "m", &|p| p.altitude_m),
        ),
        (
            "pose_off_nadir.png",
            panel("Off-nadir angle", "degrees", &|p| Some(p.off_nadir_deg)),
        ),
    ] {
        line_chart(&chart, 900, 360)
            .and_then(|c| c.save(&out.join(file)))
            .map_err(std::io::Error::other)?;
        written.push(file.into());
    }
    Ok(written)
}
