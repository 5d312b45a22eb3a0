//! One chunk of a video in one decoding pass (OpenCV adapter): the frames are decoded once and
//! handed, in parallel, to the detector and to the stabiliser, which feeds the image tracker
//! with each frame, its detections and the camera's motion.
//!
//! A chunk starts afresh (stabiliser, detector and tracker) at the first frame it decodes,
//! `overlap` frames before the frames it owns, so that a chunk's results depend on its frames
//! only: one machine running the chunks in turn and a cluster running them anywhere give the
//! same bytes. The overlap's frames belong to the chunk before; they are tracked again so that
//! the tracks of the two chunks can be linked by the detections they share there.

use std::collections::BTreeMap;
use std::ops::Range;
use std::path::Path;
use std::sync::Arc;
use std::sync::mpsc::{Receiver, Sender, channel, sync_channel};
use std::time::Instant;

use nalgebra::{Matrix3, Vector2};
use opencv::core::Mat;
use opencv::prelude::*;
use serde::{Deserialize, Serialize};

use super::klt_pass::KltParts;
use crate::detect::{Detection, Detector, FrameDetections, FrameView};
use crate::estimate::homography::transfer;
use crate::pose::stabilise::{FrameTrack, StabiliseSettings, Stabiliser};
use crate::progress::Progress;
use crate::track::{ImageTrack, Tracker};
use crate::video::klt::{Klt, KltSettings};
use crate::video::reduce::area_reduce;
use crate::video::source::{FramePool, FrameReader, MatPool};

/// Seconds spent, summed over the frames (the stages overlap in time).
#[derive(Clone, Debug, Default, Serialize, Deserialize, PartialEq)]
pub struct ScanTimes {
    pub decode_s: f64,
    pub stabilise_s: f64,
    pub detect_s: f64,
    /// The image tracker's, when it runs in the pass.
    #[serde(default)]
    pub track_s: f64,
    pub wall_s: f64,
}

/// Why a pass failed: the detector could not work with this video and these settings (a
/// problem of the inputs), or anything else.
#[derive(Debug)]
pub enum ScanError {
    Detector(String),
    Other(String),
}

impl From<crate::video::source::VideoError> for ScanError {
    fn from(e: crate::video::source::VideoError) -> ScanError {
        ScanError::Other(e.to_string())
    }
}

impl From<String> for ScanError {
    fn from(e: String) -> ScanError {
        ScanError::Other(e)
    }
}

impl std::fmt::Display for ScanError {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            ScanError::Detector(e) | ScanError::Other(e) => f.write_str(e),
        }
    }
}

/// The frames of a video cut into chunks: chunk `c` owns frames `[c·len, (c+1)·len)` and
/// decodes from `overlap` frames before them.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub struct ChunkGrid {
    /// Frames to process (the video's, or fewer).
    pub frames: usize,
    pub chunk_frames: usize,
    pub overlap_frames: usize,
}

impl ChunkGrid {
    /// `chunk_s` and `overlap_s` at `fps`; a chunk has at least 2 frames and more than its
    /// overlap.
    pub fn new(frames: usize, fps: f64, chunk_s: f64, overlap_s: f64) -> ChunkGrid {
        let chunk_frames = ((chunk_s * fps).round() as usize).max(2);
        let overlap_frames = ((overlap_s * fps).round() as usize).min(chunk_frames - 1);
        ChunkGrid {
            frames,
            chunk_frames,
            overlap_frames,
        }
    }

    pub fn chunks(&self) -> usize {
        self.frames.div_ceil(self.chunk_frames).max(1)
    }

    /// The frames chunk `c` owns.
    pub fn own(&self, c: usize) -> Range<usize> {
        let a = c * self.chunk_frames;
        a..(a + self.chunk_frames).min(self.frames)
    }

    /// The first frame chunk `c` decodes.
    pub(crate) fn decode_from(&self, c: usize) -> usize {
        self.own(c).start.saturating_sub(self.overlap_frames)
    }
}

/// The image tracker of a chunk.
pub enum ChunkTracker {
    /// Fed the detections frame by frame.
    Frames(Box<dyn Tracker>),
    /// KLT: fed the frames too.
    Klt(Box<KltParts>),
}

/// What a chunk's pass needs.
pub struct ChunkJob<'a> {
    pub video: &'a Path,
    pub grid: ChunkGrid,
    pub index: usize,
    /// The stabiliser's settings, the picked frame and the picks (`None`: a fixed camera, no
    /// frame tracks).
    pub stabilise: Option<(StabiliseSettings, usize, Vec<Vector2<f64>>)>,
    /// `None`: no detections.
    pub detector: Option<Box<dyn Detector>>,
    /// `None`: no image tracks.
    pub tracker: Option<ChunkTracker>,
}

/// A chunk's results.
#[derive(Clone, Debug, Serialize, Deserialize, PartialEq)]
pub struct ChunkData {
    pub index: usize,
    /// The frames it owns (fewer than the grid's when the video ends early).
    pub start: usize,
    pub end: usize,
    /// The first frame it decoded.
    pub decode_from: usize,
    /// The stabiliser's track of each owned frame.
    pub tracks: Vec<FrameTrack>,
    /// The detections of each owned frame.
    pub detections: Vec<Vec<Detection>>,
    /// The tracker's tracks over every frame decoded (ids local to the chunk).
    pub image_tracks: Vec<ImageTrack>,
    pub detector_summary: Vec<(String, f64)>,
    /// What a check beside the detector found that it missed, in the owned frames
    /// (`[detect] motion_check`).
    pub missed: Vec<crate::detect::Missed>,
    pub times: ScanTimes,
    /// Whether the start was reached by a (checked) seek rather than by reading from frame 0.
    pub seeked: bool,
}

/// A decoded frame's detections, sent to the tracker as the detector gives them.
type DetMsg = Vec<FrameDetections>;

pub(super) fn to_gray(bgr: &Mat) -> Result<Mat, String> {
    let mut g = Mat::default();
    opencv::imgproc::cvt_color_def(bgr, &mut g, opencv::imgproc::COLOR_BGR2GRAY)
        .map_err(|e| e.to_string())?;
    Ok(g)
}

/// Frames waiting for their detections before the tracker can take them.
enum Pending {
    Klt(<Klt as crate::features::FeatureTracker>::Frame),
    None,
}

/// A frame the stabiliser is done with: its index, for a KLT tracker the frame's width and the
/// tracker's working copy of it, and the camera's motion into it.
type Stabilised = (usize, Option<(i32, Arc<Mat>)>, Matrix3<f64>);

/// The stabiliser's part of the chunk.
struct StabiliseJob<'a> {
    video: &'a Path,
    size: (u32, u32),
    first: usize,
    own_start: usize,
    stabilise: Option<(StabiliseSettings, usize, Vec<Vector2<f64>>)>,
    /// The size of a KLT tracker's working copy, when it wants the gray frames: made here, in
    /// the thread that has the gray frame.
    tracker_work: Option<opencv::core::Size>,
}

/// The stabiliser of a pass whose first frame is `first` (its index and gray image), its
/// template the picked frame: that one, or read on its own from the start (the same pixels
/// whichever pass reads it).
pub(super) fn stabiliser(
    video: &Path,
    size: (u32, u32),
    (settings, pick_frame, picks): (&StabiliseSettings, usize, &[Vector2<f64>]),
    (first, gray): (usize, &Mat),
) -> Result<Stabiliser<Klt>, String> {
    let template = if pick_frame == first {
        gray.clone()
    } else {
        to_gray(&FrameReader::frame_bgr(video, pick_frame).map_err(|e| e.to_string())?)?
    };
    let klt = Klt::new(KltSettings::default());
    let template = klt.frame(pick_frame, template).map_err(|e| e.to_string())?;
    Ok(Stabiliser::new(
        klt,
        settings.clone(),
        size,
        template,
        pick_frame,
        picks.to_vec(),
    ))
}

/// The stabiliser, beside the decoder, in frame order: each frame's track (from the chunk's
/// first decoded frame), passing each frame on to the tracker; and busy seconds.
fn stabilise_frames(
    job: StabiliseJob,
    frames: Receiver<Arc<Mat>>,
    to_tracker: Option<std::sync::mpsc::SyncSender<Stabilised>>,
) -> Result<(Vec<FrameTrack>, f64), String> {
    let klt = Klt::new(KltSettings::default());
    let mut stab: Option<Stabiliser<Klt>> = None;
    // Gray frames and the tracker's working copies in reused memory (fresh pages for each 4K
    // frame cost a tenth of a crowd scan).
    let (mut grays, mut working) = (MatPool::default(), MatPool::default());
    let mut tracks = Vec::new();
    let mut spent = 0.0;
    let want_gray = job.stabilise.is_some() || job.tracker_work.is_some();
    for (k, bgr) in frames.iter().enumerate() {
        let f = job.first + k;
        let t = Instant::now();
        let mut motion = Matrix3::identity();
        let mut for_tracker = None;
        if want_gray {
            let (gray, ()) = grays
                .fill(|g| opencv::imgproc::cvt_color_def(&*bgr, g, opencv::imgproc::COLOR_BGR2GRAY))
                .map_err(|e| e.to_string())?;
            if let Some(size) = job.tracker_work {
                // From the full frame: a whole factor of it, reduced faster than the
                // stabiliser's half-size copy by a factor of 1.5.
                let (work, ()) = working
                    .fill(|m| area_reduce(&*gray, m, size))
                    .map_err(|e| e.to_string())?;
                for_tracker = Some((gray.cols(), work));
            }
            if let Some((settings, pick_frame, picks)) = &job.stabilise {
                if stab.is_none() {
                    stab = Some(stabiliser(
                        job.video,
                        job.size,
                        (settings, *pick_frame, picks),
                        (f, &gray),
                    )?);
                }
                let s = stab.as_mut().expect("made above");
                if f == job.own_start && f > job.first {
                    // The frames the chunk owns start with a key frame.
                    s.key_next();
                }
                let frame = klt.frame_shared(f, gray).map_err(|e| e.to_string())?;
                tracks.push(s.push(f, frame).map_err(|e| format!("frame {f}: {e}"))?);
                motion = s.last_motion();
            }
        }
        spent += t.elapsed().as_secs_f64();
        // The tracker stopped on an error of its own: that error is reported.
        if let Some(to) = &to_tracker
            && to.send((f, for_tracker, motion)).is_err()
        {
            break;
        }
    }
    Ok((tracks, spent))
}

/// The image tracker, beside the stabiliser, in frame order: each frame once the stabiliser
/// and the detector are done with it. Its tracks, and busy seconds.
fn track_frames(
    tracker: ChunkTracker,
    first: usize,
    frames: Receiver<Stabilised>,
    detections: Receiver<DetMsg>,
) -> Result<(Vec<ImageTrack>, f64), String> {
    let mut w = Feeder {
        tracker,
        first,
        motions: Vec::new(),
        pending: Default::default(),
        ready: BTreeMap::new(),
        track_s: 0.0,
    };
    for (f, gray, motion) in frames.iter() {
        let t = Instant::now();
        w.motions.push(motion);
        let item = match (gray, &w.tracker) {
            (Some((width, work)), ChunkTracker::Klt(parts)) => Pending::Klt(
                parts
                    .frames
                    .frame_of_working(f, width, &work)
                    .map_err(|e| e.to_string())?,
            ),
            _ => Pending::None,
        };
        w.track_s += t.elapsed().as_secs_f64();
        w.pending.push_back((f, item));
        // Never wait for the detector here: one that holds frames back (learning its palette)
        // would stop the decoder, and so itself. The decoder cannot run more than a few frames
        // ahead of the detector, so few frames wait.
        while let Ok(msg) = detections.try_recv() {
            w.take(msg);
        }
        w.feed()?;
    }
    // The decoder is done: the detector's last detections, then the frames waiting for them.
    for msg in detections.iter() {
        w.take(msg);
        w.feed()?;
    }
    // Frames the detector gave nothing for have no detections.
    while let Some((f, _)) = w.pending.front() {
        let f = *f;
        w.ready.insert(f, Vec::new());
        w.feed()?;
    }
    let t = Instant::now();
    let image_tracks = match w.tracker {
        ChunkTracker::Frames(tr) => tr.finish(),
        ChunkTracker::Klt(parts) => parts.tracker.finish(),
    };
    Ok((image_tracks, w.track_s + t.elapsed().as_secs_f64()))
}

/// The tracker and the frames and detections waiting for it.
struct Feeder {
    tracker: ChunkTracker,
    /// The chunk's first decoded frame.
    first: usize,
    /// The camera's motion into each decoded frame, from the frame before.
    motions: Vec<Matrix3<f64>>,
    /// Frames waiting for their detections, in order.
    pending: std::collections::VecDeque<(usize, Pending)>,
    /// Detections waiting for their frames.
    ready: BTreeMap<usize, Vec<Detection>>,
    track_s: f64,
}

impl Feeder {
    fn take(&mut self, msg: DetMsg) {
        for (i, d) in msg {
            self.ready.insert(i, d);
        }
    }

    /// Hands the tracker the waiting frames whose detections are ready, in order.
    fn feed(&mut self) -> Result<(), String> {
        while let Some((f, _)) = self.pending.front() {
            let Some(dets) = self.ready.remove(f) else {
                break;
            };
            let (f, frame) = self.pending.pop_front().expect("looked at");
            let t = Instant::now();
            let (first, motions) = (self.first, &self.motions);
            let motion_at = |g: usize, x: &Vector2<f64>| -> Vector2<f64> {
                g.checked_sub(first)
                    .and_then(|k| motions.get(k))
                    .and_then(|h| transfer(h, x))
                    .unwrap_or(*x)
            };
            match (&mut self.tracker, frame) {
                (ChunkTracker::Frames(tr), _) => {
                    tr.update(f, &dets, &|x: &Vector2<f64>| motion_at(f, x));
                }
                (ChunkTracker::Klt(parts), Pending::Klt(frame)) => parts
                    .tracker
                    .update(f, frame, &dets, &motion_at)
                    .map_err(|e| format!("frame {f}: {e}"))?,
                (ChunkTracker::Klt(_), Pending::None) => unreachable!("KLT frames are kept"),
            }
            self.track_s += t.elapsed().as_secs_f64();
        }
        Ok(())
    }
}

/// Detections by frame (from the chunk's first decoded frame), busy seconds, the detector's
/// summary and what its check found that it missed.
pub(super) type Detected = (
    Vec<Vec<Detection>>,
    f64,
    Vec<(String, f64)>,
    Vec<crate::detect::Missed>,
);

/// The detector, beside the decoder, in frame order from frame `first`; each frame's detections
/// are also sent to the tracker as they come.
pub(super) fn detect_frames(
    mut det: Box<dyn Detector>,
    first: usize,
    frames: Receiver<Arc<Mat>>,
    to_tracker: Sender<DetMsg>,
) -> Result<Detected, String> {
    let mut out: Vec<Vec<Detection>> = Vec::new();
    let mut spent = 0.0;
    let mut put = |done: Vec<FrameDetections>| {
        for (i, d) in &done {
            let k = i - first;
            if out.len() <= k {
                out.resize(k + 1, Vec::new());
            }
            out[k] = d.clone();
        }
        // The tracker may have stopped on an error of its own: that error is reported.
        let _ = to_tracker.send(done);
    };
    for (k, bgr) in frames.iter().enumerate() {
        let i = first + k;
        let t = Instant::now();
        let bytes = bgr.data_bytes().map_err(|e| e.to_string())?;
        let view = FrameView {
            index: i,
            width: bgr.cols() as usize,
            height: bgr.rows() as usize,
            bgr: bytes,
        };
        let done = det.push(&view).map_err(|e| format!("frame {i}: {e}"))?;
        spent += t.elapsed().as_secs_f64();
        put(done);
    }
    let t = Instant::now();
    let done = det.finish().map_err(|e| e.to_string())?;
    spent += t.elapsed().as_secs_f64();
    put(done);
    Ok((out, spent, det.summary(), det.missed()))
}

/// Runs one chunk. Errors name the video.
pub(crate) fn scan_chunk(job: ChunkJob, progress: &dyn Progress) -> Result<ChunkData, ScanError> {
    let video = job.video;
    let named = |e: String| format!("{}: {e}", video.display());
    let own = job.grid.own(job.index);
    let first = job.grid.decode_from(job.index);
    let started = Instant::now();
    let mut reader = FrameReader::open(video)?;
    let (width, height) = (reader.width, reader.height);
    let seeked = match reader.seek_checked(video, first) {
        Ok(s) => s,
        // The container stated more frames than it holds: this chunk is past the end.
        Err(crate::video::source::VideoError::Ended { .. }) if job.index > 0 => {
            return Ok(ChunkData {
                index: job.index,
                start: own.start,
                end: own.start,
                decode_from: first,
                tracks: Vec::new(),
                detections: Vec::new(),
                image_tracks: Vec::new(),
                detector_summary: Vec::new(),
                missed: Vec::new(),
                times: ScanTimes::default(),
                seeked: false,
            });
        }
        Err(e) => return Err(named(e.to_string()).into()),
    };
    // The decoder, stabiliser, tracker and detector already fill the cores: OpenCV's own
    // worker threads would only compete with them.
    let cv_threads = opencv::core::get_num_threads().unwrap_or(-1);
    let _ = opencv::core::set_num_threads(1);
    let (to_track, for_track) = sync_channel::<Arc<Mat>>(4);
    let (to_detect, for_detector) = sync_channel::<Arc<Mat>>(4);
    let (dets_out, dets_in) = channel::<DetMsg>();
    let ChunkJob {
        stabilise,
        detector,
        tracker,
        ..
    } = job;
    let want_detect = detector.is_some();
    let result = std::thread::scope(|scope| -> Result<ChunkData, ScanError> {
        let (to_tracker, for_tracker) = sync_channel::<Stabilised>(4);
        let tracker_work = match &tracker {
            Some(ChunkTracker::Klt(parts)) => {
                Some(parts.frames.working_size(width as i32, height as i32))
            }
            _ => None,
        };
        let stab_job = StabiliseJob {
            video,
            size: (width, height),
            first,
            own_start: own.start,
            stabilise,
            tracker_work,
        };
        let to_tracker = tracker.is_some().then_some(to_tracker);
        let stab_thread = scope.spawn(move || stabilise_frames(stab_job, for_track, to_tracker));
        let track_thread = tracker
            .map(|tracker| scope.spawn(move || track_frames(tracker, first, for_tracker, dets_in)));
        let detect_thread = detector
            .map(|det| scope.spawn(move || detect_frames(det, first, for_detector, dets_out)));
        let mut decode_s = 0.0;
        let mut decoded = 0;
        let mut failure = None;
        let mut pool = FramePool::default();
        while first + decoded < own.end {
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
            if to_track.send(bgr.clone()).is_err() || (want_detect && to_detect.send(bgr).is_err())
            {
                break;
            }
            if first + decoded >= own.start {
                progress.inc(1);
            }
            decoded += 1;
        }
        drop(to_track);
        drop(to_detect);
        // The detector and the stabiliser first: the tracker waits for them.
        let detected = detect_thread
            .map(|h| h.join())
            .transpose()
            .map_err(|_| "the detector stopped unexpectedly".to_string())?;
        let stabilised = stab_thread
            .join()
            .map_err(|_| "the stabiliser stopped unexpectedly".to_string())?;
        let tracked = track_thread
            .map(|h| h.join())
            .transpose()
            .map_err(|_| "the tracker stopped unexpectedly".to_string())?;
        let (tracks, stabilise_s) = stabilised.map_err(named)?;
        let (image_tracks, track_s) = tracked
            .unwrap_or_else(|| Ok((Vec::new(), 0.0)))
            .map_err(named)?;
        let (mut detections, detect_s, detector_summary, mut missed) = detected
            .unwrap_or_else(|| Ok((Vec::new(), 0.0, Vec::new(), Vec::new())))
            .map_err(|e| ScanError::Detector(named(e)))?;
        if let Some(f) = failure {
            return Err(f.into());
        }
        let end = (first + decoded).max(own.start);
        if end == own.start && job.index == 0 {
            return Err(named("no frames could be decoded".into()).into());
        }
        if want_detect {
            detections.resize(decoded, Vec::new());
        }
        let skip = own.start - first;
        missed.retain(|m| (own.start..end).contains(&m.0));
        Ok(ChunkData {
            index: job.index,
            start: own.start,
            end,
            decode_from: first,
            tracks: tracks.into_iter().skip(skip).collect(),
            detections: detections.into_iter().skip(skip).collect(),
            image_tracks,
            detector_summary,
            missed,
            times: ScanTimes {
                decode_s,
                stabilise_s,
                detect_s,
                track_s,
                wall_s: started.elapsed().as_secs_f64(),
            },
            seeked,
        })
    });
    if cv_threads > 0 {
        let _ = opencv::core::set_num_threads(cv_threads);
    }
    result
}
