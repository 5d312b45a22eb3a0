//! The KLT tracker set up from a project's `[track]` settings (`klt_tracker`, which the
//! chunks' decoding pass feeds), and a pass of its own over a video for `geostride track`
//! (`klt_over_video`: it decodes the video after the detections and hands the gray frames to the
//! pure tracker in `track::klt`).

use std::path::Path;

use nalgebra::Vector2;

use super::settings::KltSection;
use crate::detect::Detection;
use crate::progress::Progress;
use crate::track::ImageTrack;
use crate::track::klt::{KltTrackSettings, KltTracker};
use crate::video::klt::{Klt, KltSettings};

/// What the pass needs: the video, the detections of each of its frames, and the scale.
pub struct KltPass<'a> {
    pub video: &'a Path,
    pub detections: &'a [Vec<Detection>],
    /// The frames' size, pixels.
    pub size: (u32, u32),
    pub fps: f64,
    pub track: &'a KltSection,
    /// A person's length in the image, metres (the box of a track without a detection).
    pub person_m: Option<f64>,
    /// Image scale at head height, pixels per metre.
    pub px_per_m: f64,
}

/// The KLT tracker a pass feeds, and the feature frames it wants (made from gray frames).
pub struct KltParts {
    pub tracker: KltTracker<Klt>,
    pub frames: Klt,
}

/// The tracker for frames of `size` at `px_per_m` and `fps`, with the project's settings.
pub fn klt_tracker(
    t: &KltSection,
    size: (u32, u32),
    fps: f64,
    person_m: Option<f64>,
    px_per_m: f64,
) -> KltParts {
    // The working copy: no wider than the features' default, and reduced further to about
    // `working_px_per_m` at head height (a person stays over a dozen pixels wide; a 4K frame of
    // people 100 px/m apart costs a ninth of its pixels).
    let default_width = f64::from(KltSettings::default().max_width);
    let factor = (f64::from(size.0) / default_width)
        .ceil()
        .max((px_per_m / t.working_px_per_m).floor())
        .max(1.0);
    let base = KltSettings {
        max_width: (f64::from(size.0) / factor).ceil() as i32,
        ..KltSettings::default()
    };
    // An odd window in the working copy's pixels, no wider than a person (0.6 m): a window
    // mostly of ground follows the ground.
    let window_px = t.window_px.min(0.6 * px_per_m);
    let window = (((window_px / factor).round() as i32).max(5)) | 1;
    let klt = Klt::new(KltSettings {
        window,
        levels: t.levels,
        fast_levels: t.levels,
        quality: 0.01,
        min_distance: 2.0,
        ..base
    });
    let settings = KltTrackSettings {
        gate_px: t.gate_m * px_per_m,
        person_px: person_m.unwrap_or(0.7) * px_per_m,
        // One body's features move within about 4 cm per frame of each other.
        flow_px: (0.04 * px_per_m).max(1.5),
        min_features: t.min_features,
        max_features: t.max_features,
        max_gap: (t.max_gap_s * fps).round() as usize,
        min_hits: t.min_hits,
        ..KltTrackSettings::default()
    };
    let frames = Klt::new(klt.settings.clone());
    KltParts {
        tracker: KltTracker::new(settings, klt, (f64::from(size.0), f64::from(size.1))),
        frames,
    }
}

/// Why the tracking pass stopped.
#[derive(Debug, thiserror::Error)]
pub enum KltPassError {
    #[error(transparent)]
    Video(#[from] crate::video::VideoError),
    /// A frame could not be read or tracked.
    #[error("{}: frame {frame}: {message}", video.display())]
    Frame {
        video: std::path::PathBuf,
        frame: usize,
        message: String,
    },
    /// The video ended before the frames scanned for detections.
    #[error("{}: ended at frame {frame}, before the {scanned} frames scanned", video.display())]
    Ended {
        video: std::path::PathBuf,
        frame: usize,
        scanned: usize,
    },
}

/// Tracks people through the video; `motion_at(f, x)` carries a point of frame `f − 1` into
/// frame `f` (the identity for a fixed camera).
pub fn klt_over_video(
    job: &KltPass,
    motion_at: &dyn Fn(usize, &Vector2<f64>) -> Vector2<f64>,
    bar: &dyn Progress,
) -> Result<Vec<ImageTrack>, KltPassError> {
    let KltParts {
        mut tracker,
        frames,
    } = klt_tracker(job.track, job.size, job.fps, job.person_m, job.px_per_m);
    let mut reader = crate::video::source::FrameReader::open(job.video)?;
    let failed = |frame: usize, message: String| KltPassError::Frame {
        video: job.video.to_path_buf(),
        frame,
        message,
    };
    for (f, dets) in job.detections.iter().enumerate() {
        let Some((_, gray)) = reader
            .next_gray_reusing()
            .map_err(|e| failed(f, e.to_string()))?
        else {
            return Err(KltPassError::Ended {
                video: job.video.to_path_buf(),
                frame: f,
                scanned: job.detections.len(),
            });
        };
        let frame = frames
            .frame(f, gray)
            .map_err(|e| failed(f, e.to_string()))?;
        tracker
            .update(f, frame, dets, motion_at)
            .map_err(|e| failed(f, e.to_string()))?;
        bar.inc(1);
    }
    Ok(tracker.finish())
}
