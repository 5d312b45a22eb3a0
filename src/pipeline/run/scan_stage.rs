//! Stage 1, `scan`: the video's chunks, each in one decoding pass (stabilisation, detection
//! and image tracking), each cached in its own file.

use std::collections::BTreeMap;
use std::time::Instant;

use super::{ChunkMode, Detectors, Env, RunError, RunInputs, ScanData, StageRecord, StageStatus};
use crate::cache::{StageCache, stage_key};
use crate::detect::Detector;
use crate::pipeline::chunk_pass::{
    ChunkData, ChunkJob, ChunkTracker, ScanError, ScanTimes, scan_chunk,
};
use crate::pipeline::klt_pass::klt_tracker;
use crate::pipeline::project::Project;
use crate::pipeline::registry::{self, TrackScale, TrackerChoice};
use crate::pipeline::settings::{DetectSection, PoseSection, TrackSection};
use crate::pose::stabilise::StabiliseSettings;

/// The sections the scan reads: the stabiliser's key frames (`[pose]`), the detector's and the
/// tracker's.
pub(super) struct ScanSettings<'a> {
    pub pose: &'a PoseSection,
    pub detect: &'a DetectSection,
    pub track: &'a TrackSection,
}

impl<'a> ScanSettings<'a> {
    pub fn of(p: &'a Project) -> ScanSettings<'a> {
        ScanSettings {
            pose: &p.pose,
            detect: &p.detect,
            track: &p.track,
        }
    }
}

/// A chunk's file in the cache (under `.stages/`).
pub(super) fn chunk_stage(c: usize) -> String {
    format!("chunks/{c:05}")
}

/// Chunk `c` of the scan `scan_key` as cached; None when it is not there whole under its key.
pub(super) fn load_chunk(cache: &StageCache, scan_key: &str, c: usize) -> Option<ChunkData> {
    cache.load(&chunk_stage(c), &chunk_key(scan_key, c))
}

/// The key of chunk `c` of the scan `scan_key`.
pub(super) fn chunk_key(scan_key: &str, c: usize) -> String {
    stage_key("chunk", &[scan_key], &c)
}

/// Whether chunk `c` is in the cache under its key.
pub(super) fn chunk_done(cache: &StageCache, scan_key: &str, c: usize) -> bool {
    cache.has(&chunk_stage(c), &chunk_key(scan_key, c))
}

/// Computes chunk `c`.
fn compute_chunk(
    x: &RunInputs,
    s: &ScanSettings,
    c: usize,
    detector: Box<dyn Detector>,
    bar: &dyn crate::progress::Progress,
) -> Result<ChunkData, ScanError> {
    let fps = x.fps;
    // A fixed camera is not stabilised: its frames need no motion and no key frames.
    let stabilise = s
        .pose
        .key_frames()
        .map(|(min_features, key_fraction, key_every_s)| {
            let (pick_frame, picks) = x.carried_picks.clone();
            let settings =
                StabiliseSettings::key_frames(min_features, key_fraction, key_every_s, fps);
            (settings, pick_frame, picks)
        });
    let scale = TrackScale {
        px_per_m: x.px_per_m,
        fps,
        duplicate_px: s.detect.duplicate_m() * x.px_per_m,
    };
    let tracker = match registry::tracker(s.track, &scale) {
        TrackerChoice::Frames(t) => ChunkTracker::Frames(t),
        TrackerChoice::Klt(k) => ChunkTracker::Klt(Box::new(klt_tracker(
            k,
            x.size,
            fps,
            s.detect.person_m(),
            x.px_per_m,
        ))),
    };
    scan_chunk(
        ChunkJob {
            video: &x.video,
            grid: x.grid,
            index: c,
            stabilise,
            detector: Some(detector),
            tracker: Some(tracker),
        },
        bar,
    )
}

/// The chunks `mode` asks for, computed or reused, given to `each` in order a chunk at a time
/// (a long video's are never all in memory); and how many were computed and reused. Under
/// [`ChunkMode::Only`] the chunks are only stored, not given.
pub(super) fn chunks_of(
    env: &Env,
    x: &RunInputs,
    s: &ScanSettings,
    mode: &ChunkMode,
    detectors: &mut Detectors,
    each: &mut dyn FnMut(ChunkData) -> Result<(), RunError>,
) -> Result<(usize, usize), RunError> {
    let n = x.grid.chunks();
    let range = match mode {
        ChunkMode::Only(r) => r.clone(),
        _ => 0..n,
    };
    let bar = env.progress.stage("scan");
    let (mut computed, mut reused) = (0, 0);
    // A segment only needs to know which of its chunks are done; the others read them.
    let keep = !matches!(mode, ChunkMode::Only(_));
    let done: Vec<bool> = range
        .clone()
        .map(|c| chunk_done(&env.cache, &x.scan_key, c))
        .collect();
    let missing: Vec<usize> = range
        .clone()
        .zip(&done)
        .filter(|(_, d)| !**d)
        .map(|(c, _)| c)
        .collect();
    if !missing.is_empty() && *mode == ChunkMode::None {
        return Err(RunError::MissingChunks(missing));
    }
    let todo: u64 = missing.iter().map(|&c| x.grid.own(c).len() as u64).sum();
    bar.set_length(todo);
    for (c, done) in range.zip(done) {
        if done && !keep {
            reused += 1;
            continue;
        }
        // Read when it is reached; one damaged since it was checked is made again.
        if let Some(d) = done
            .then(|| load_chunk(&env.cache, &x.scan_key, c))
            .flatten()
        {
            reused += 1;
            each(d)?;
            continue;
        }
        if *mode == ChunkMode::None {
            return Err(RunError::MissingChunks(vec![c]));
        }
        let d = compute_chunk(x, s, c, detectors.next()?, bar.as_ref()).map_err(|e| match e {
            ScanError::Detector(e) => detectors.failed(e),
            ScanError::Other(e) => RunError::Failed(e),
        })?;
        env.cache
            .store(&chunk_stage(c), &chunk_key(&x.scan_key, c), &d)?;
        env.progress.stored(&chunk_stage(c));
        computed += 1;
        // A segment keeps nothing: its memory is one chunk's, however long it is.
        if keep {
            each(d)?;
        }
    }
    Ok((computed, reused))
}

/// Stage 1: every chunk, put together.
pub(super) fn scan_stage(
    env: &Env,
    x: &RunInputs,
    s: &ScanSettings,
    mode: &ChunkMode,
    detectors: &mut Detectors,
) -> Result<(ScanData, String, StageRecord), RunError> {
    let t0 = Instant::now();
    let (width, height) = x.size;
    let mut data = ScanData {
        fps: x.fps,
        width,
        height,
        frames: 0,
        px_per_m: x.px_per_m,
        detector_summary: Vec::new(),
        tracks: Vec::new(),
        detections: 0,
        times: ScanTimes::default(),
    };
    let mut summary: BTreeMap<String, Vec<f64>> = BTreeMap::new();
    let mut seeks = 0;
    // What the later stages need of each chunk is its frames' stabilisation; the track stage
    // and the export read the chunks' tracks and detections back from their files.
    let (computed, reused) = chunks_of(env, x, s, mode, detectors, &mut |c| {
        if c.end > c.start && data.frames != c.start {
            return Err(RunError::Failed(format!(
                "{}: chunk {} starts at frame {} but the chunks before end at {} (the video ended early?)",
                x.video.display(),
                c.index,
                c.start,
                data.frames
            )));
        }
        if c.end > c.start {
            data.frames = c.end;
        }
        data.tracks.extend(c.tracks);
        data.detections += c.detections.iter().map(Vec::len).sum::<usize>();
        for (k, v) in c.detector_summary {
            summary.entry(k).or_default().push(v);
        }
        let t = &mut data.times;
        t.decode_s += c.times.decode_s;
        t.stabilise_s += c.times.stabilise_s;
        t.detect_s += c.times.detect_s;
        t.track_s += c.times.track_s;
        t.wall_s += c.times.wall_s;
        seeks += usize::from(c.seeked);
        Ok(())
    })?;
    if computed > 0 {
        env.progress.stored("scan");
    }
    if data.frames == 0 {
        return Err(RunError::Failed(format!(
            "{}: no frames could be decoded",
            x.video.display()
        )));
    }
    // A number every chunk's detector gives alike is the video's (boxes read from the file,
    // hat colours); others are summed (an overlap's frames count in both its chunks).
    data.detector_summary = summary
        .into_iter()
        .map(|(k, v)| {
            let same = v.iter().all(|x| *x == v[0]) && v.len() > 1;
            (k, if same { v[0] } else { v.iter().sum() })
        })
        .collect();
    let n_det = data.detections;
    let status = match (computed, reused) {
        (0, _) => StageStatus::Reused,
        (_, 0) => StageStatus::Computed,
        _ => StageStatus::PartlyReused,
    };
    let record = StageRecord {
        name: "scan".into(),
        status,
        seconds: t0.elapsed().as_secs_f64(),
        counts: BTreeMap::from([
            ("frames".into(), data.frames as f64),
            ("width_px".into(), data.width as f64),
            ("height_px".into(), data.height as f64),
            ("detections".into(), n_det as f64),
            ("chunks".into(), x.grid.chunks() as f64),
            ("px_per_m".into(), x.px_per_m),
            ("chunks_computed".into(), computed as f64),
            ("chunks_seeked".into(), seeks as f64),
            (
                "key_frames".into(),
                data.tracks.iter().filter(|t| t.key.is_some()).count() as f64,
            ),
            ("decode_s".into(), data.times.decode_s),
            ("stabilise_s".into(), data.times.stabilise_s),
            ("detect_s".into(), data.times.detect_s),
            ("track_s".into(), data.times.track_s),
        ])
        .into_iter()
        .chain(data.detector_summary.iter().cloned())
        .collect(),
    };
    Ok((data, x.scan_key.clone(), record))
}
