//! Stage 1, `scan`: the video's chunks, each in one decoding pass (stabilisation, detection
//! and image tracking), each cached in its own file.

use super::*;
use crate::pipeline::chunk_pass::{ChunkData, ChunkJob, ChunkTracker, scan_chunk};
use crate::pipeline::registry::{TrackScale, TrackerChoice};

/// A chunk's file in the cache (under `.stages/`).
pub(super) fn chunk_stage(c: usize) -> String {
    format!("chunks/{c:05}")
}

/// Chunk `c` as cached; None when it is not there whole under its key.
pub(super) fn load_chunk(ctx: &Ctx, c: usize) -> Option<ChunkData> {
    ctx.cache.load(&chunk_stage(c), &chunk_key(ctx, c))
}

/// The key of chunk `c`.
pub(super) fn chunk_key(ctx: &Ctx, c: usize) -> String {
    stage_key("chunk", &[&ctx.scan_key], &c)
}

/// Whether chunk `c` is in the cache under its key.
pub(super) fn chunk_done(ctx: &Ctx, c: usize) -> bool {
    ctx.cache.has(&chunk_stage(c), &chunk_key(ctx, c))
}

/// The detector for one chunk.
fn chunk_detector(ctx: &Ctx) -> Result<Box<dyn crate::detect::Detector>, RunError> {
    let p = &ctx.l.project;
    match (&p.detect, &ctx.palette) {
        (crate::pipeline::settings::DetectSection::Colour(c), Some(pal)) => Ok(
            crate::pipeline::detectors::colour_with(c, ctx.px_per_m, pal),
        ),
        _ => crate::pipeline::registry::detector(
            &p.detect,
            &crate::pipeline::detectors::DetectorInputs {
                l: ctx.l,
                video: &ctx.video,
                camera: &ctx.camera,
                first_pose: &ctx.first_pose,
                px_per_m: ctx.px_per_m,
                frames: Some(ctx.frames_total),
            },
        ),
    }
}

/// Computes chunk `c`.
fn compute_chunk(
    ctx: &Ctx,
    c: usize,
    detector: Box<dyn crate::detect::Detector>,
    bar: &dyn crate::progress::Progress,
) -> Result<ChunkData, RunError> {
    let l = ctx.l;
    let p = &l.project;
    let fps = ctx.fps;
    let (min_features, key_fraction, key_every_s) = p.pose.key_frames();
    let stabilise = StabiliseSettings::key_frames(min_features, key_fraction, key_every_s, fps);
    let (pick_frame, picks) = ctx.pose.carried_picks();
    let scale = TrackScale {
        px_per_m: ctx.px_per_m,
        fps,
        duplicate_px: p.detect.duplicate_m() * ctx.px_per_m,
    };
    let tracker = match crate::pipeline::registry::tracker(&p.track, &scale) {
        TrackerChoice::Frames(t) => ChunkTracker::Frames(t),
        TrackerChoice::Klt(k) => {
            let size = ctx.size;
            ChunkTracker::Klt(Box::new(crate::pipeline::klt_pass::klt_tracker(
                k,
                size,
                fps,
                p.detect.person_m(),
                ctx.px_per_m,
            )))
        }
    };
    scan_chunk(
        ChunkJob {
            video: &ctx.video,
            grid: ctx.grid,
            index: c,
            stabilise: Some((stabilise, pick_frame, picks)),
            detector: Some(detector),
            tracker: Some(tracker),
        },
        bar,
    )
    .map_err(|e| match e {
        ScanError::Detector(e) => RunError::Input(l.error("detect", p.detect.failure_key(), e)),
        ScanError::Other(e) => RunError::Failed(e),
    })
}

/// The chunks `mode` asks for, computed or reused, given to `each` in order a chunk at a time
/// (a long video's are never all in memory); and how many were computed and reused. Under
/// [`ChunkMode::Only`] the chunks are only stored, not given.
pub(super) fn chunks_of(
    ctx: &Ctx,
    mode: &ChunkMode,
    mut detector: Option<Box<dyn crate::detect::Detector>>,
    each: &mut dyn FnMut(ChunkData) -> Result<(), RunError>,
) -> Result<(usize, usize), RunError> {
    let n = ctx.grid.chunks();
    let range = match mode {
        ChunkMode::Only(r) => r.clone(),
        _ => 0..n,
    };
    let bar = ctx.progress.stage("scan");
    let (mut computed, mut reused) = (0, 0);
    // A segment only needs to know which of its chunks are done; the others read them.
    let keep = !matches!(mode, ChunkMode::Only(_));
    let done: Vec<bool> = range.clone().map(|c| chunk_done(ctx, c)).collect();
    let missing: Vec<usize> = range
        .clone()
        .zip(&done)
        .filter(|(_, d)| !**d)
        .map(|(c, _)| c)
        .collect();
    if !missing.is_empty() && *mode == ChunkMode::None {
        return Err(RunError::MissingChunks(missing));
    }
    let todo: u64 = missing.iter().map(|&c| ctx.grid.own(c).len() as u64).sum();
    bar.set_length(todo);
    for (c, done) in range.zip(done) {
        if done && !keep {
            reused += 1;
            continue;
        }
        // Read when it is reached; one damaged since it was checked is made again.
        if let Some(d) = done.then(|| load_chunk(ctx, c)).flatten() {
            reused += 1;
            each(d)?;
            continue;
        }
        if *mode == ChunkMode::None {
            return Err(RunError::MissingChunks(vec![c]));
        }
        let det = match detector.take() {
            Some(d) => d,
            None => chunk_detector(ctx)?,
        };
        let d = compute_chunk(ctx, c, det, bar.as_ref())?;
        ctx.cache.store(&chunk_stage(c), &chunk_key(ctx, c), &d)?;
        ctx.progress.stored(&chunk_stage(c));
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
    ctx: &Ctx,
    mode: &ChunkMode,
    detector: Option<Box<dyn crate::detect::Detector>>,
) -> Result<(ScanData, String, StageRecord), RunError> {
    let t0 = Instant::now();
    let (width, height) = ctx.size;
    let mut data = ScanData {
        fps: ctx.fps,
        width,
        height,
        frames: 0,
        px_per_m: ctx.px_per_m,
        detector_summary: Vec::new(),
        tracks: Vec::new(),
        detections: 0,
        times: ScanTimes::default(),
    };
    let mut summary: BTreeMap<String, Vec<f64>> = BTreeMap::new();
    let mut seeks = 0;
    // What the later stages need of each chunk is its frames' stabilisation; the track stage
    // and the export read the chunks' tracks and detections back from their files.
    let (computed, reused) = chunks_of(ctx, mode, detector, &mut |c| {
        if c.end > c.start && data.frames != c.start {
            return Err(RunError::Failed(format!(
                "{}: chunk {} starts at frame {} but the chunks before end at {} (the video ended early?)",
                ctx.video.display(),
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
        ctx.progress.stored("scan");
    }
    if data.frames == 0 {
        return Err(RunError::Failed(format!(
            "{}: no frames could be decoded",
            ctx.video.display()
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
            ("chunks".into(), ctx.grid.chunks() as f64),
            ("px_per_m".into(), ctx.px_per_m),
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
    Ok((data, ctx.scan_key.clone(), record))
}
