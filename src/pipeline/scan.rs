//! One pass over a whole video for the commands without a project (`pose --video`, `track`):
//! the chunk pass of a project's run (`chunk_pass::scan_chunk`) over one chunk from frame 0. The
//! frames are decoded once and handed, in parallel, to the stabiliser (reference frames, carried
//! picks), a detector and an image tracker, each optional.

use std::path::Path;

use nalgebra::Vector2;

use super::chunk_pass::{ChunkGrid, ChunkJob, ChunkTracker, ScanError, ScanTimes, scan_chunk};
use crate::detect::{Detection, Detector};
use crate::pose::stabilise::{FrameTrack, StabiliseSettings};
use crate::progress::Progress;
use crate::track::ImageTrack;
use crate::video::source::FrameReader;

/// What to do with the frames besides decoding them.
pub struct ScanJob<'a> {
    pub video: &'a Path,
    /// Stop after this many frames.
    pub max_frames: Option<usize>,
    /// Stabilise, carrying these picks made on frame `picks_frame`.
    pub stabilise: Option<(StabiliseSettings, usize, Vec<Vector2<f64>>)>,
    pub detector: Option<Box<dyn Detector>>,
    /// Tracks people in the image, fed each frame's detections (and, for KLT, the frame).
    pub tracker: Option<ChunkTracker>,
}

/// The pass's results.
pub struct Scanned {
    pub fps: f64,
    pub width: u32,
    pub height: u32,
    pub frames: usize,
    pub tracks: Vec<FrameTrack>,
    pub detections: Vec<Vec<Detection>>,
    /// The image tracker's tracks (ids from 1, in the tracker's order).
    pub image_tracks: Vec<ImageTrack>,
    /// What the detector reports about itself.
    pub detector_summary: Vec<(String, f64)>,
    pub times: ScanTimes,
}

/// Runs the pass: the chunk pass of a project's run over one chunk, from frame 0 to the end (or
/// `max_frames`). Errors name the video.
pub fn scan(job: ScanJob, progress: &dyn Progress) -> Result<Scanned, ScanError> {
    let video = job.video;
    let reader = FrameReader::open(video)?;
    let (fps, width, height) = (reader.fps, reader.width, reader.height);
    let total = match (reader.frame_count, job.max_frames) {
        (Some(c), Some(m)) => Some(c.min(m)),
        (c, m) => c.or(m),
    };
    drop(reader);
    progress.set_length(total.unwrap_or(0) as u64);
    if let Some((_, pick_frame, _)) = &job.stabilise
        && total.is_some_and(|t| *pick_frame >= t)
    {
        return Err(format!(
            "{}: the picks are on frame {pick_frame}, beyond the {} frame(s) processed",
            video.display(),
            total.unwrap_or(0)
        )
        .into());
    }
    // One chunk: to the end of a video whose length the container does not state.
    let frames = total.unwrap_or(usize::MAX);
    let chunk = scan_chunk(
        ChunkJob {
            video,
            grid: ChunkGrid {
                frames,
                chunk_frames: frames.max(2),
                overlap_frames: 0,
            },
            index: 0,
            stabilise: job.stabilise,
            detector: job.detector,
            tracker: job.tracker,
        },
        progress,
    )?;
    Ok(Scanned {
        fps,
        width,
        height,
        frames: chunk.end,
        tracks: chunk.tracks,
        detections: chunk.detections,
        image_tracks: chunk.image_tracks,
        detector_summary: chunk.detector_summary,
        times: chunk.times,
    })
}
