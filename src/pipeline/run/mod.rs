//! Running a project: the stages in order, each cached in the output folder under a key of its
//! inputs and parameters, so that a re-run reuses what is done and an interrupted run resumes.
//!
//! First `prepare` (the inputs step): every input read and checked into plain data
//! ([`prepare::RunInputs`]), the output folder made. Then the stages: `scan` (one decoding pass
//! per chunk: stabilisation, detection, image tracking), `pose` (a pose for every frame),
//! `track` (the chunks' tracks joined), `project` (to the head-height surface), `smooth`
//! (Kalman/RTS with EM), `export` (the files), `views`. Each takes where it writes
//! ([`prepare::Env`]: the output folder, the stage cache, progress), those inputs, its own
//! settings section and its predecessor's artifact (`artifacts`); none reads the project. Every
//! artifact is written atomically; a stage whose key matches its artifact is not run again.

use std::path::Path;
use std::time::Instant;

use serde::{Deserialize, Serialize};

use super::error::output_error;
pub use super::error::{RunError, chunk_list};
pub use super::provenance::{InputRecord, KnownInput};
use super::provenance::{file_record, size_and_time};
use super::report::report_markdown;
pub use super::report::{RunReport, Silent, StageProgress, StageRecord, StageStatus};
use crate::cache::build_id;

use super::project::Loaded;
use crate::geom::Rigid3;
use crate::io::write_atomic;

mod artifacts;
mod cached;
mod export_stage;
mod inputs;
mod model_pose;
mod pose_source;
mod pose_stage;
mod prepare;
mod project_stage;
mod scan_stage;
mod smooth_stage;
mod telemetry_check;
mod telemetry_site;
mod track_stage;
mod video_model;
mod views_stage;

use export_stage::export_stage;
pub use inputs::{MAX_HEIGHTS, check_known_inputs, check_recorded_inputs, parse_heights};
use pose_stage::pose_stage;
use project_stage::project_stage;
use scan_stage::scan_stage;
use smooth_stage::smooth_stage;
use track_stage::track_stage;
use views_stage::views_stage;

use artifacts::{FramePoseData, PoseData, ScanData, WorldTrack};
use cached::{cached, cached_seq};
use prepare::{Detectors, Env, Prepared, RunInputs, prepare};

/// Which chunks of the video a call computes; the others must be in the output folder's cache
/// already.
#[derive(Clone, Debug, PartialEq, Eq)]
pub enum ChunkMode {
    /// Every chunk not done yet (`geostride run`).
    All,
    /// These (a segment of `geostride split`); the later stages do not run.
    Only(std::ops::Range<usize>),
    /// None (`geostride merge`): a chunk not done is an error.
    None,
}

/// Runs a project into `out`. Every input is read and checked before anything is written, so
/// a bad project leaves nothing behind.
pub fn run(l: &Loaded, out: &Path, progress: &dyn StageProgress) -> Result<RunReport, RunError> {
    run_with(l, out, progress, &ChunkMode::All)
}

/// What a segment's run did.
#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct SegmentDone {
    pub chunks: std::ops::Range<usize>,
    pub computed: usize,
    pub reused: usize,
    pub frames: usize,
    pub seconds: f64,
}

/// Computes chunks `chunks` of a project's video into `out`'s cache (a segment of a split run),
/// reusing those done already; the later stages are left to [`run_with`] and
/// [`ChunkMode::None`].
pub fn run_segment(
    l: &Loaded,
    out: &Path,
    progress: &dyn StageProgress,
    chunks: std::ops::Range<usize>,
) -> Result<SegmentDone, RunError> {
    let t0 = Instant::now();
    let Prepared {
        env,
        inputs,
        mut detectors,
        ..
    } = prepare(l, out, progress, &ChunkMode::Only(chunks.clone()))?;
    let n = inputs.grid.chunks();
    if chunks.end > n || chunks.is_empty() {
        return Err(RunError::Unusable(format!(
            "chunks {}..{} asked for; the video has {n} chunk(s) of {} s",
            chunks.start, chunks.end, l.project.video.chunk_s
        )));
    }
    let (computed, reused) = scan_stage::chunks_of(
        &env,
        &inputs,
        &scan_stage::ScanSettings::of(&l.project),
        &ChunkMode::Only(chunks.clone()),
        &mut detectors,
        &mut |_| Ok(()),
    )?;
    Ok(SegmentDone {
        frames: chunks.clone().map(|c| inputs.grid.own(c).len()).sum(),
        chunks,
        computed,
        reused,
        seconds: t0.elapsed().as_secs_f64(),
    })
}

/// What [`plan_chunks`] gives: the chunk grid and every chunk's key.
#[derive(Clone, Debug, Serialize, Deserialize, PartialEq)]
pub struct ChunkPlan {
    pub grid: super::chunk_pass::ChunkGrid,
    pub fps: f64,
    pub chunk_keys: Vec<String>,
    /// Whether a colour palette was learnt (it is in the output folder's cache).
    pub palette: bool,
    /// Chunks done already (in the cache under their key).
    pub done: Vec<usize>,
    /// The inputs' checksums, for the segments and the merge.
    pub inputs: Vec<KnownInput>,
}

/// Checks a project as [`run`] does, makes `out` and decides what is decided once for the whole
/// video (the chunk grid, the colour palette, the chunks' keys), without processing a chunk.
pub fn plan_chunks(
    l: &Loaded,
    out: &Path,
    progress: &dyn StageProgress,
) -> Result<ChunkPlan, RunError> {
    let Prepared {
        env,
        inputs,
        records,
        ..
    } = prepare(l, out, progress, &ChunkMode::All)?;
    let keys: Vec<String> = (0..inputs.grid.chunks())
        .map(|c| scan_stage::chunk_key(&inputs.scan_key, c))
        .collect();
    let done = (0..keys.len())
        .filter(|&c| scan_stage::chunk_done(&env.cache, &inputs.scan_key, c))
        .collect();
    Ok(ChunkPlan {
        grid: inputs.grid,
        fps: inputs.fps,
        chunk_keys: keys,
        palette: inputs.palette.is_some(),
        done,
        inputs: records.iter().filter_map(KnownInput::of).collect(),
    })
}

/// [`run`], computing only the chunks `mode` says (the rest must be done already).
pub fn run_with(
    l: &Loaded,
    out: &Path,
    progress: &dyn StageProgress,
    mode: &ChunkMode,
) -> Result<RunReport, RunError> {
    let Prepared {
        env,
        inputs: x,
        pose,
        mut detectors,
        records,
        mut warnings,
    } = prepare(l, out, progress, mode)?;
    let p = &l.project;
    let mut stages = Vec::new();
    // No segment of a split run writes now: a killed run's temporaries can go (the stages'
    // files half-written, the tracks and observations set aside).
    for dir in [out.join(".stages").join("chunks"), out.join(".stages")] {
        crate::io::remove_stale_temps(&dir).map_err(|source| RunError::Io { path: dir, source })?;
    }

    let scan = scan_stage::ScanSettings::of(p);
    let (scan_data, scan_key, record) = scan_stage(&env, &x, &scan, mode, &mut detectors)?;
    stages.push(record);
    let (pose_data, pose_key, record) = pose_stage(
        &env,
        &x,
        pose.as_ref(),
        &scan_key,
        &scan_data,
        &mut warnings,
    )?;
    stages.push(record);
    if let Some(record) = telemetry_check::telemetry_check(&env, &x, &pose_data, &mut warnings)? {
        stages.push(record);
    }
    let frames = scan_data.frames;
    drop(scan_data);
    let poses: Vec<Rigid3> = pose_data.frames.iter().map(FramePoseData::pose).collect();
    // From here on each stage reads its predecessor's data back from the cache a track or a
    // batch at a time and writes its own the same way: the merge of a long video holds the
    // tracks under way, never all of them.
    let (tracks, track_key, record) = track_stage(&env, &x, &p.track, &scan_key, frames)?;
    stages.push(record);
    release_freed();
    let (projected, project_key, record) = project_stage(
        &env,
        &x,
        (&p.projection, &p.ground),
        [&track_key, &pose_key],
        (&tracks, &pose_data, &poses),
        &mut warnings,
    )?;
    stages.push(record);
    release_freed();
    let (smoothed, smooth_key, record) =
        smooth_stage(&env, &x, &p.smooth, &project_key, &projected, &mut warnings)?;
    stages.push(record);
    release_freed();
    let (mut outputs, transformations, record) = export_stage(
        &env,
        &x,
        &p.analysis,
        (&smooth_key, &track_key, smoothed.trajectories),
        &mut warnings,
    )?;
    stages.push(record);
    let (views, record) = views_stage(
        &env,
        &x,
        (&p.output, &p.analysis),
        (&pose_data, &smooth_key, &smoothed),
        &mut warnings,
    )?;
    if let Some(record) = record {
        stages.push(record);
    }
    outputs.extend(views.iter().map(|(_, f)| f.clone()));

    let framed = &x.framed;
    let out_crs_label = x
        .out_crs
        .as_ref()
        .or(framed.frame.crs.as_ref())
        .map_or(framed.frame.origin_note.clone(), |c| c.label());
    let report = RunReport {
        project: x.title.clone(),
        geostride_version: build_id().into(),
        inputs: records,
        parameters: p.clone(),
        site_frame: framed.frame.origin_note.clone(),
        output_crs: out_crs_label,
        wgs84_transformations: transformations,
        stages,
        outputs,
        views,
        // Absolute: `geostride render` may run from elsewhere.
        project_file: std::fs::canonicalize(&l.path)
            .unwrap_or_else(|_| l.path.clone())
            .display()
            .to_string(),
        warnings,
    };
    let json =
        serde_json::to_string_pretty(&report).map_err(|e| RunError::Failed(e.to_string()))?;
    write_atomic(&out.join("report.json"), json.as_bytes())
        .map_err(|e| RunError::Failed(e.to_string()))?;
    write_atomic(&out.join("report.md"), report_markdown(&report).as_bytes())
        .map_err(|e| RunError::Failed(e.to_string()))?;
    Ok(report)
}

/// Gives the memory freed by a stage back to the system (glibc keeps it in its arenas, one per
/// thread that allocated: after a long video's stages that showed as memory that grew with the
/// video although the data held did not).
fn release_freed() {
    #[cfg(all(target_os = "linux", target_env = "gnu"))]
    // SAFETY: glibc's malloc_trim only returns free memory to the system; it touches no live
    // allocation.
    unsafe {
        libc::malloc_trim(0);
    }
}

/// The most frames a run processes: a day at 120 frames a second.
pub const MAX_FRAMES: usize = 24 * 3600 * 120;
