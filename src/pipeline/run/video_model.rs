//! A moving camera's reference model from the video itself (`[pose] kind = "model"` with no
//! `model`: there was no survey flight). A frame every `frames_every_s` and every frame with
//! GCP picks are written to `model/frames/`, reconstructed by structure from motion (each
//! frame matched with the next `sequential`, the calibration's intrinsics held) and placed in
//! the site frame by the picks; the result is an ordinary `geostride sfm` model in `model/`,
//! which the pose stage then uses as it would a survey flight's.

use std::collections::BTreeSet;
use std::path::{Path, PathBuf};

use super::RunError;
use crate::camera::Camera;
use crate::pipeline::project::Loaded;
use crate::pipeline::settings::ModelSettings;
use crate::progress::Progress;
use crate::sfm::FeatureSettings;
use crate::sfm::job::{
    CrsPositions, GeorefInput, NamedGroundPoint, SfmJob, ground_points, run_sfm, write_outputs,
};
use crate::sfm::matching::MatchSettings;
use crate::sfm::reconstruct::SfmSettings;
use crate::survey::load::Framed;

/// Features per frame of the video's model (the survey flights' default is 8192 on larger
/// photos; a video frame has fewer pixels).
const VIDEO_MODEL_FEATURES: usize = 6000;

/// The model built, and the folder of its frames.
pub(super) struct VideoModel {
    pub dir: PathBuf,
    pub images: PathBuf,
}

/// The file a frame is written to (names sort in frame order: the sequential pairs).
fn frame_file(frame: usize) -> String {
    format!("frame-{frame:06}.png")
}

/// The frames the survey's picks are made on; a pick naming anything but a frame of the video
/// is an error (the model holds only the video's frames).
fn picked_frames(
    l: &Loaded,
    framed: &Framed,
    video_name: &str,
) -> Result<BTreeSet<usize>, RunError> {
    let mut frames = BTreeSet::new();
    for o in framed.survey.points.iter().flat_map(|p| &p.observations) {
        let frame = match o.image.rsplit_once('#') {
            Some((name, n)) if name == video_name => n.parse::<usize>().ok(),
            _ => None,
        };
        let Some(frame) = frame else {
            return Err(RunError::Input(crate::io::FileError {
                path: o.file.clone(),
                line: Some(o.line),
                field: None,
                message: format!(
                    "the pick's image '{}' is not a frame of the video: without a survey model ([pose] model) the GCPs are picked on the video's frames, named '{video_name}#N' (N from 0)",
                    o.image
                ),
            }));
        };
        frames.insert(frame);
    }
    if frames.is_empty() {
        return Err(RunError::Input(l.error(
            "pose",
            "model",
            format!(
                "no reference model and no GCP picks: pick the GCPs on a few frames of the video ('{video_name}#N' in survey.picks; `geostride gcp pick`), or give a survey flight's model"
            ),
        )));
    }
    Ok(frames)
}

/// The surveyed points with their picks renamed to the frames' files.
fn ground_points_of(l: &Loaded, framed: &Framed) -> Result<Vec<NamedGroundPoint>, RunError> {
    let s = &l.project.survey;
    let frame = |image: &str| Some(frame_file(crate::io::frame_of_name(image)?.ok()?));
    ground_points(
        &framed.survey.points,
        &framed.local,
        (s.pick_sigma_px, s.gcp_sigma_m),
        frame,
    )
    .map_err(|p| {
        RunError::Input(crate::io::FileError {
            path: l.resolve(&s.gcps),
            line: Some(p.line),
            field: None,
            message: format!(
                "'{}' has no height: the model built from the video is placed by 3D points",
                p.name
            ),
        })
    })
}

/// Writes frames `frames` of `video` into `dir` as PNG.
fn write_frames(
    video: &Path,
    frames: &BTreeSet<usize>,
    dir: &Path,
) -> Result<Vec<PathBuf>, RunError> {
    let failed = |m: String| RunError::Failed(format!("{}: {m}", video.display()));
    let io = |path: &Path, source: std::io::Error| RunError::Io {
        path: path.to_path_buf(),
        source,
    };
    std::fs::create_dir_all(dir).map_err(|e| io(dir, e))?;
    let mut reader =
        crate::video::source::FrameReader::open(video).map_err(|e| failed(e.to_string()))?;
    let last = frames.iter().next_back().copied().unwrap_or(0);
    let mut written = Vec::new();
    while let Some((index, bgr, w, h)) =
        reader.next_bgr_bytes().map_err(|e| failed(e.to_string()))?
    {
        if frames.contains(&index) {
            let png = crate::imageio::encode_bgr_png(&bgr, w, h)
                .map_err(|e| failed(format!("frame {index}: {e}")))?;
            let path = dir.join(frame_file(index));
            crate::io::write_atomic(&path, &png).map_err(|e| io(&path, e))?;
            written.push(path);
        }
        if index >= last {
            break;
        }
    }
    Ok(written)
}

/// Builds the video's own reference model into `out/model`.
pub(super) fn build_video_model(
    l: &Loaded,
    m: &ModelSettings,
    framed: &Framed,
    (camera, video, fps, frames_total): (&Camera, &Path, f64, Option<usize>),
    out: &Path,
    progress: (&dyn Progress, &dyn Progress),
) -> Result<VideoModel, RunError> {
    let video_name = video
        .file_name()
        .map_or_else(String::new, |f| f.to_string_lossy().into_owned());
    let mut frames = picked_frames(l, framed, &video_name)?;
    let every = ((m.frames_every_s * fps).round() as usize).max(1);
    let n = frames_total.unwrap_or_else(|| frames.iter().next_back().map_or(0, |f| f + 1));
    frames.extend((0..n).step_by(every));
    if let Some(beyond) = frames.iter().find(|&&f| f >= n) {
        return Err(RunError::Input(l.error(
            "survey",
            "picks",
            format!("a pick is on frame {beyond}, beyond the video's {n} frames"),
        )));
    }
    let dir = out.join("model");
    let images = dir.join("frames");
    let paths = write_frames(video, &frames, &images)?;
    let job = SfmJob {
        images: paths,
        camera: Some(camera.clone()),
        gps_neighbours: 0,
        sequential: m.sequential,
        features: FeatureSettings {
            max_features: m.max_features.unwrap_or(VIDEO_MODEL_FEATURES),
            ..FeatureSettings::default()
        },
        matching: MatchSettings::default(),
        sfm: SfmSettings::default(),
        georef: Some(GeorefInput {
            points: ground_points_of(l, framed)?,
            centres: Vec::new(),
            settings: Default::default(),
            frame: "the run's site frame".into(),
        }),
        cache_dir: Some(out.join(".stages").join("video-model-cache")),
    };
    let run = run_sfm(&job, progress.0, progress.1).map_err(|e| {
        let message = format!("building the model from the video's frames: {e}");
        if e.is_input() {
            RunError::Input(l.error("pose", "model", message))
        } else {
            RunError::Unusable(message)
        }
    })?;
    if run.report.frame != "site" {
        return Err(RunError::Unusable(format!(
            "the model built from the video's {} frames could not be placed by the GCP picks ({} of them registered): pick at least three control points on the video's frames, spread over it",
            run.report.images, run.report.registered
        )));
    }
    let positions = run
        .reconstruction
        .poses
        .iter()
        .map(|p| {
            p.map(|p| framed.frame.source_from_local(&p.centre()))
                .transpose()
                .map(|x| x.map(|x| [x.x, x.y, x.z]))
        })
        .collect::<Result<Vec<_>, _>>()?;
    write_outputs(&dir, &run, Some(&CrsPositions { positions })).map_err(|source| {
        RunError::Io {
            path: dir.clone(),
            source,
        }
    })?;
    Ok(VideoModel { dir, images })
}
