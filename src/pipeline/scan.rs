//! One pass over a video (OpenCV adapters): frames are decoded once and handed, in parallel, to
//! the stabiliser (reference frames, carried picks) and to a detector.

use std::path::Path;
use std::sync::Arc;
use std::sync::mpsc::sync_channel;
use std::time::Instant;

use nalgebra::Vector2;
use opencv::core::Mat;
use opencv::prelude::*;
use serde::{Deserialize, Serialize};

use crate::detect::{Detection, Detector, FrameView};
use crate::pose::stabilise::{FrameTrack, StabiliseSettings, Stabiliser};
use crate::progress::Progress;
use crate::video::klt::{Klt, KltSettings};
use crate::video::source::FrameReader;

/// What to do with the frames besides decoding them.
pub struct ScanJob<'a> {
    pub video: &'a Path,
    /// Stop after this many frames.
    pub max_frames: Option<usize>,
    /// Stabilise, carrying these picks made on frame `picks_frame`.
    pub stabilise: Option<(StabiliseSettings, usize, Vec<Vector2<f64>>)>,
    pub detector: Option<Box<dyn Detector>>,
}

/// Seconds spent, summed over the frames (the stages overlap in time).
#[derive(Clone, Debug, Default, Serialize, Deserialize, PartialEq)]
pub struct ScanTimes {
    pub decode_s: f64,
    pub stabilise_s: f64,
    pub detect_s: f64,
    pub wall_s: f64,
}

/// The pass's results.
pub struct Scanned {
    pub fps: f64,
    pub width: u32,
    pub height: u32,
    pub frames: usize,
    pub tracks: Vec<FrameTrack>,
    pub detections: Vec<Vec<Detection>>,
    pub times: ScanTimes,
}

fn to_gray(bgr: &Mat) -> Result<Mat, String> {
    let mut g = Mat::default();
    opencv::imgproc::cvt_color_def(bgr, &mut g, opencv::imgproc::COLOR_BGR2GRAY)
        .map_err(|e| e.to_string())?;
    Ok(g)
}

/// Runs the pass. Errors name the video.
pub fn scan(job: ScanJob, progress: &dyn Progress) -> Result<Scanned, String> {
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
    let stabiliser = match &job.stabilise {
        Some((settings, pick_frame, picks)) => {
            if total.is_some_and(|t| *pick_frame >= t) {
                return Err(named(format!(
                    "the picks are on frame {pick_frame}, beyond the {} frame(s) processed",
                    total.unwrap_or(0)
                )));
            }
            let klt = Klt::new(KltSettings::default());
            let template = klt.frame(
                *pick_frame,
                to_gray(&FrameReader::frame_bgr(video, *pick_frame)?)?,
            )?;
            Some(Stabiliser::new(
                Klt::new(KltSettings::default()),
                settings.clone(),
                (width, height),
                template,
                *pick_frame,
                picks.clone(),
            ))
        }
        None => None,
    };
    let mut detector = job.detector;
    let max_frames = job.max_frames;
    let (to_stab, from_decoder) = sync_channel::<Arc<Mat>>(4);
    let (to_detect, for_detector) = sync_channel::<Arc<Mat>>(4);
    let want_stab = stabiliser.is_some();
    let want_detect = detector.is_some();
    std::thread::scope(|scope| -> Result<Scanned, String> {
        // The stabiliser runs beside the decoder and the detector, in frame order.
        let stab_thread = stabiliser.map(|mut stab| {
            scope.spawn(move || -> Result<(Vec<FrameTrack>, f64), String> {
                let klt = Klt::new(KltSettings::default());
                let mut tracks = Vec::new();
                let mut spent = 0.0;
                for (i, bgr) in from_decoder.iter().enumerate() {
                    let t = Instant::now();
                    let frame = klt.frame(i, to_gray(&bgr)?)?;
                    tracks.push(stab.push(i, frame).map_err(|e| format!("frame {i}: {e}"))?);
                    spent += t.elapsed().as_secs_f64();
                }
                Ok((tracks, spent))
            })
        });
        let detect_thread = detector.take().map(|mut det| {
            scope.spawn(move || -> Result<(Vec<Vec<Detection>>, f64), String> {
                let mut out = Vec::new();
                let mut spent = 0.0;
                for (i, bgr) in for_detector.iter().enumerate() {
                    let t = Instant::now();
                    let bytes = bgr.data_bytes().map_err(|e| e.to_string())?;
                    let view = FrameView {
                        index: i,
                        width: bgr.cols() as usize,
                        height: bgr.rows() as usize,
                        bgr: bytes,
                    };
                    out.push(det.detect(&view));
                    spent += t.elapsed().as_secs_f64();
                }
                Ok((out, spent))
            })
        });
        let mut decode_s = 0.0;
        let mut frames = 0;
        let mut failure = None;
        while max_frames.is_none_or(|m| frames < m) {
            let t = Instant::now();
            let next = reader.next_bgr();
            decode_s += t.elapsed().as_secs_f64();
            let bgr = match next {
                Ok(Some((_, bgr))) => Arc::new(bgr),
                Ok(None) => break,
                Err(e) => {
                    failure = Some(named(e));
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
        let (detections, detect_s) = match detect_thread {
            Some(h) => h
                .join()
                .map_err(|_| "the detector stopped unexpectedly".to_string())?
                .map_err(named)?,
            None => (Vec::new(), 0.0),
        };
        if let Some(f) = failure {
            return Err(f);
        }
        if frames == 0 {
            return Err(named("no frames could be decoded".into()));
        }
        Ok(Scanned {
            fps,
            width,
            height,
            frames,
            tracks,
            detections,
            times: ScanTimes {
                decode_s,
                stabilise_s,
                detect_s,
                wall_s: started.elapsed().as_secs_f64(),
            },
        })
    })
}

/// Sample pixels (sRGB) from `count` frames spread over the first `frames` of the video, chosen
/// by a seeded draw, for learning a colour palette: every `step`-th pixel of each.
pub fn sample_pixels(
    video: &Path,
    frames: usize,
    count: usize,
    step: usize,
    seed: u64,
) -> Result<Vec<[u8; 3]>, String> {
    use rand::{RngExt, SeedableRng};
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(seed);
    let mut wanted: Vec<usize> = if count >= frames {
        (0..frames).collect()
    } else {
        (0..count).map(|_| rng.random_range(0..frames)).collect()
    };
    wanted.sort_unstable();
    wanted.dedup();
    let mut reader = FrameReader::open(video)?;
    let mut pixels = Vec::new();
    let mut next = 0;
    let mut at = 0;
    while let Some(&target) = wanted.get(next) {
        // Far ahead: seek (the backend decodes from the last key frame); near: read on.
        if target > at + 30 {
            reader.seek(target);
        }
        let Some((i, bgr)) = reader.next_bgr()? else {
            break;
        };
        at = i + 1;
        if i < target {
            continue;
        }
        next += 1;
        let bytes = bgr.data_bytes().map_err(|e| e.to_string())?;
        let (w, h) = (bgr.cols() as usize, bgr.rows() as usize);
        let view = FrameView {
            index: i,
            width: w,
            height: h,
            bgr: bytes,
        };
        let mut k = (i * 7919) % step.max(1);
        while k < w * h {
            pixels.push(view.pixel(k % w, k / w));
            k += step.max(1);
        }
    }
    Ok(pixels)
}
