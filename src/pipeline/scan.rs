//! One pass over a video (OpenCV adapters): frames are decoded once and handed, in parallel, to
//! the stabiliser (reference frames, carried picks) and to a detector.

use std::path::Path;
use std::sync::Arc;
use std::sync::mpsc::{Receiver, sync_channel};
use std::time::Instant;

use nalgebra::Vector2;
use opencv::core::Mat;

use crate::detect::{Detection, Detector};
use crate::pose::stabilise::{FrameTrack, StabiliseSettings};
use crate::progress::Progress;
use crate::video::klt::{Klt, KltSettings};
use crate::video::source::{FramePool, FrameReader};

/// What to do with the frames besides decoding them.
pub struct ScanJob<'a> {
    pub video: &'a Path,
    /// Stop after this many frames.
    pub max_frames: Option<usize>,
    /// Stabilise, carrying these picks made on frame `picks_frame`.
    pub stabilise: Option<(StabiliseSettings, usize, Vec<Vector2<f64>>)>,
    pub detector: Option<Box<dyn Detector>>,
}

/// The pass's results.
pub struct Scanned {
    pub fps: f64,
    pub width: u32,
    pub height: u32,
    pub frames: usize,
    pub tracks: Vec<FrameTrack>,
    pub detections: Vec<Vec<Detection>>,
    /// What the detector reports about itself.
    pub detector_summary: Vec<(String, f64)>,
    pub times: ScanTimes,
}

use super::chunk_pass::{Detected, stabiliser, to_gray};
use super::chunk_pass::{ScanError, ScanTimes};

/// The stabiliser's part of a pass.
struct StabiliseJob<'a> {
    video: &'a Path,
    size: (u32, u32),
    settings: StabiliseSettings,
    pick_frame: usize,
    picks: Vec<Vector2<f64>>,
}

/// The stabiliser, beside the decoder, in frame order: each frame's track, and busy seconds.
fn stabilise_frames(
    job: StabiliseJob,
    frames: Receiver<Arc<Mat>>,
) -> Result<(Vec<FrameTrack>, f64), String> {
    let klt = Klt::new(KltSettings::default());
    let mut tracks = Vec::new();
    let mut spent = 0.0;
    let mut stab = None;
    for (i, bgr) in frames.iter().enumerate() {
        let t = Instant::now();
        let gray = to_gray(&bgr)?;
        if stab.is_none() {
            stab = Some(stabiliser(
                job.video,
                job.size,
                (&job.settings, job.pick_frame, &job.picks),
                (i, &gray),
            )?);
        }
        let stab = stab.as_mut().expect("made above");
        let frame = klt.frame(i, gray).map_err(|e| e.to_string())?;
        tracks.push(stab.push(i, frame).map_err(|e| format!("frame {i}: {e}"))?);
        spent += t.elapsed().as_secs_f64();
    }
    Ok((tracks, spent))
}

/// The detector, beside the decoder, in frame order (as in a chunk's pass, from frame 0, with
/// no tracker waiting for its detections).
fn detect_frames(det: Box<dyn Detector>, frames: Receiver<Arc<Mat>>) -> Result<Detected, String> {
    let (to_nobody, _) = std::sync::mpsc::channel();
    super::chunk_pass::detect_frames(det, 0, frames, to_nobody)
}

/// Runs the pass. Errors name the video.
pub fn scan(job: ScanJob, progress: &dyn Progress) -> Result<Scanned, ScanError> {
    let video = job.video;
    let named = |e: String| format!("{}: {e}", video.display());
    let mut reader = FrameReader::open(video)?;
    let (fps, width, height) = (reader.fps, reader.width, reader.height);
    let total = match (reader.frame_count, job.max_frames) {
        (Some(c), Some(m)) => Some(c.min(m)),
        (c, m) => c.or(m),
    };
    progress.set_length(total.unwrap_or(0) as u64);
    let started = Instant::now();
    if let Some((_, pick_frame, _)) = &job.stabilise
        && total.is_some_and(|t| *pick_frame >= t)
    {
        return Err(named(format!(
            "the picks are on frame {pick_frame}, beyond the {} frame(s) processed",
            total.unwrap_or(0)
        ))
        .into());
    }
    // The decoder, stabiliser and detector already fill the cores: OpenCV's own worker threads
    // would only compete with them.
    let cv_threads = opencv::core::get_num_threads().unwrap_or(-1);
    let _ = opencv::core::set_num_threads(1);
    let stabiliser = job.stabilise;
    let mut detector = job.detector;
    let max_frames = job.max_frames;
    let (to_stab, from_decoder) = sync_channel::<Arc<Mat>>(4);
    let (to_detect, for_detector) = sync_channel::<Arc<Mat>>(4);
    let want_stab = stabiliser.is_some();
    let want_detect = detector.is_some();
    let scanned = std::thread::scope(|scope| -> Result<Scanned, ScanError> {
        // The stabiliser runs beside the decoder and the detector, in frame order.
        let stab_thread = stabiliser.map(|(settings, pick_frame, picks)| {
            let job = StabiliseJob {
                video,
                size: (width, height),
                settings,
                pick_frame,
                picks,
            };
            scope.spawn(move || stabilise_frames(job, from_decoder))
        });
        let detect_thread = detector
            .take()
            .map(|det| scope.spawn(move || detect_frames(det, for_detector)));
        let mut decode_s = 0.0;
        let mut frames = 0;
        let mut failure = None;
        let mut pool = FramePool::default();
        while max_frames.is_none_or(|m| frames < m) {
            let t = Instant::now();
            let next = pool.read(&mut reader);
            decode_s += t.elapsed().as_secs_f64();
            let bgr = match next {
                Ok(Some(bgr)) => bgr,
                Ok(None) => break,
                Err(e) => {
                    failure = Some(named(e.to_string()));
                    break;
                }
            };
            // A worker that stopped (on an error) closes its channel: stop decoding.
            if want_stab && to_stab.send(bgr.clone()).is_err() {
                break;
            }
            if want_detect && to_detect.send(bgr).is_err() {
                break;
            }
            frames += 1;
            progress.inc(1);
        }
        drop(to_stab);
        drop(to_detect);
        let (tracks, stabilise_s) = match stab_thread {
            Some(h) => h
                .join()
                .map_err(|_| "the stabiliser stopped unexpectedly".to_string())?
                .map_err(named)?,
            None => (Vec::new(), 0.0),
        };
        let (mut detections, detect_s, detector_summary) = match detect_thread {
            Some(h) => h
                .join()
                .map_err(|_| "the detector stopped unexpectedly".to_string())?
                .map_err(|e| ScanError::Detector(named(e)))?,
            None => (Vec::new(), 0.0, Vec::new()),
        };
        if let Some(f) = failure {
            return Err(f.into());
        }
        if frames == 0 {
            return Err(named("no frames could be decoded".into()).into());
        }
        if want_detect {
            detections.resize(frames, Vec::new());
        }
        Ok(Scanned {
            fps,
            width,
            height,
            frames,
            tracks,
            detections,
            detector_summary,
            times: ScanTimes {
                decode_s,
                stabilise_s,
                detect_s,
                track_s: 0.0,
                wall_s: started.elapsed().as_secs_f64(),
            },
        })
    });
    if cv_threads > 0 {
        let _ = opencv::core::set_num_threads(cv_threads);
    }
    scanned
}
