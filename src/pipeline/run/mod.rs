//! Running a project: the stages in order, each cached in the output folder under a key of its
//! inputs and parameters, so that a re-run reuses what is done and an interrupted run resumes.
//!
//! Stages: `scan` (one decode pass: stabilisation and detection), `pose` (a pose for every
//! frame), `track` (image tracks), `project` (to the head-height surface), `smooth` (Kalman/RTS
//! with EM), `export` (the files). Every artifact is written atomically; a stage whose key
//! matches its artifact is not run again.

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::time::Instant;

use nalgebra::{Matrix2, Matrix3, Matrix6, Vector2, Vector3};
use serde::de::DeserializeOwned;
use serde::{Deserialize, Serialize};

use super::error::output_error;
pub use super::error::{RunError, chunk_list};
pub use super::provenance::{InputRecord, KnownInput};
use super::provenance::{file_record, size_and_time};
pub use super::report::{
    RunReport, Silent, StageProgress, StageRecord, StageStatus, report_markdown,
};
use crate::cache::{StageCache, build_id, cache_gone, in_batches, stage_key};

use super::chunk_pass::{ScanError, ScanTimes};
use super::pose_outputs::{PoseRun, write_pose_outputs};
use super::project::Loaded;
use crate::camera::Camera;
use crate::detect::Detection;
use crate::export::gis::write_geopackage;
use crate::export::{PointCov, Trajectory, TrajectoryPoint};
use crate::geom::Rigid3;
use crate::io::write_atomic;
use crate::pose::hover::solve_with_checks;
use crate::pose::stabilise::{FrameTrack, StabiliseSettings};
use crate::pose::{GcpObservation, PoseSettings, solve_pose};
use crate::progress::Progress;
use crate::projection::{WorldPoint, project};
use crate::smooth::Observation;
use crate::survey::crs::{Crs, HeightKind, Transform, UsedOperations};
use crate::survey::load::Framed;
use crate::terrain::HeightSurface;
use crate::track::ImageTrack;

mod export_stage;
mod inputs;
mod model_pose;
mod pose_source;
mod pose_stage;
mod project_stage;
mod scan_stage;
mod smooth_stage;
mod track_stage;
mod views_stage;

use export_stage::export_stage;
pub use inputs::{MAX_HEIGHTS, check_known_inputs, check_recorded_inputs, parse_heights};
use inputs::{load_survey, picked, project_camera, read_heights};
use pose_stage::pose_stage;
use project_stage::project_stage;
use scan_stage::scan_stage;
use smooth_stage::smooth_stage;
use track_stage::track_stage;
use views_stage::views_stage;

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

/// What writing one export format gave: files, warnings, and the WGS 84 transformations used.
#[derive(Default)]
struct Written {
    outputs: Vec<String>,
    warnings: Vec<String>,
    transformations: Vec<String>,
}

/// What the scan stage gives: its chunks put together.
#[derive(Clone, Debug)]
struct ScanData {
    fps: f64,
    width: u32,
    height: u32,
    frames: usize,
    px_per_m: f64,
    detector_summary: Vec<(String, f64)>,
    tracks: Vec<FrameTrack>,
    /// How many detections the chunks hold.
    detections: usize,
    times: ScanTimes,
}

/// A frame's pose as the later stages need it.
#[derive(Clone, Debug, Serialize, Deserialize)]
struct FramePoseData {
    frame: usize,
    rotation: Matrix3<f64>,
    translation: Vector3<f64>,
    covariance: Option<Matrix6<f64>>,
    interpolated: bool,
    mean_reprojection_px: Option<f64>,
}

impl FramePoseData {
    fn pose(&self) -> Rigid3 {
        Rigid3 {
            rotation: nalgebra::Rotation3::from_matrix_unchecked(self.rotation),
            translation: self.translation,
        }
    }
}

#[derive(Clone, Debug, Serialize, Deserialize)]
struct PoseData {
    frames: Vec<FramePoseData>,
    key_frames: Vec<usize>,
    key_frames_failed: Vec<usize>,
    mean_reprojection_px: f64,
    max_reprojection_px: f64,
    check_mean_reprojection_px: Option<f64>,
}

impl PoseData {
    /// The frames' poses and the key frames, with the mean and the largest of the frames'
    /// reprojection errors (over the frames that have one).
    fn new(
        frames: Vec<FramePoseData>,
        key_frames: Vec<usize>,
        key_frames_failed: Vec<usize>,
        check_mean_reprojection_px: Option<f64>,
    ) -> PoseData {
        let rms: Vec<f64> = frames
            .iter()
            .filter_map(|f| f.mean_reprojection_px)
            .collect();
        PoseData {
            mean_reprojection_px: rms.iter().sum::<f64>() / rms.len().max(1) as f64,
            max_reprojection_px: rms.iter().copied().fold(0.0, f64::max),
            check_mean_reprojection_px,
            frames,
            key_frames,
            key_frames_failed,
        }
    }
}

/// A track projected to the world.
#[derive(Clone, Debug, Serialize, Deserialize)]
struct WorldTrack {
    id: usize,
    height_m: f64,
    height_sd_m: f64,
    height_source: String,
    points: Vec<(usize, WorldPoint)>,
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
    let Prepared { ctx, detector, .. } =
        prepare(l, out, progress, &ChunkMode::Only(chunks.clone()))?;
    let n = ctx.grid.chunks();
    if chunks.end > n || chunks.is_empty() {
        return Err(RunError::Unusable(format!(
            "chunks {}..{} asked for; the video has {n} chunk(s) of {} s",
            chunks.start, chunks.end, l.project.video.chunk_s
        )));
    }
    let (computed, reused) = scan_stage::chunks_of(
        &ctx,
        &ChunkMode::Only(chunks.clone()),
        detector,
        &mut |_| Ok(()),
    )?;
    Ok(SegmentDone {
        frames: chunks.clone().map(|c| ctx.grid.own(c).len()).sum(),
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
    let Prepared { ctx, inputs, .. } = prepare(l, out, progress, &ChunkMode::All)?;
    let keys: Vec<String> = (0..ctx.grid.chunks())
        .map(|c| scan_stage::chunk_key(&ctx, c))
        .collect();
    let done = (0..keys.len())
        .filter(|&c| scan_stage::chunk_done(&ctx, c))
        .collect();
    Ok(ChunkPlan {
        grid: ctx.grid,
        fps: ctx.fps,
        chunk_keys: keys,
        palette: ctx.palette.is_some(),
        done,
        inputs: inputs.iter().filter_map(KnownInput::of).collect(),
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
        ctx,
        detector,
        inputs,
        mut warnings,
    } = prepare(l, out, progress, mode)?;
    let p = &l.project;
    let mut stages = Vec::new();
    // No segment of a split run writes now: a killed run's temporaries can go (the stages'
    // files half-written, the tracks and observations set aside).
    for dir in [out.join(".stages").join("chunks"), out.join(".stages")] {
        crate::io::remove_stale_temps(&dir).map_err(|source| RunError::Io { path: dir, source })?;
    }

    let (scan_data, scan_key, record) = scan_stage(&ctx, mode, detector)?;
    stages.push(record);
    let (pose_data, pose_key, record) = pose_stage(&ctx, &scan_key, &scan_data, &mut warnings)?;
    stages.push(record);
    let frames = scan_data.frames;
    drop(scan_data);
    let poses: Vec<Rigid3> = pose_data.frames.iter().map(FramePoseData::pose).collect();
    // From here on each stage reads its predecessor's data back from the cache a track or a
    // batch at a time and writes its own the same way: the merge of a long video holds the
    // tracks under way, never all of them.
    let (tracks, track_key, record) = track_stage(&ctx, &scan_key, frames)?;
    stages.push(record);
    release_freed();
    let (projected, project_key, record) = project_stage(
        &ctx,
        [&track_key, &pose_key],
        &tracks,
        &pose_data,
        &poses,
        &mut warnings,
    )?;
    stages.push(record);
    release_freed();
    let (smoothed, smooth_key, record) =
        smooth_stage(&ctx, &project_key, &projected, &mut warnings)?;
    stages.push(record);
    release_freed();
    let (mut outputs, transformations, record) =
        export_stage(&ctx, &smooth_key, &track_key, &mut warnings)?;
    stages.push(record);
    let (views, record) = views_stage(&ctx, &pose_data, &smooth_key, &smoothed, &mut warnings)?;
    if let Some(record) = record {
        stages.push(record);
    }
    outputs.extend(views.iter().map(|(_, f)| f.clone()));

    let framed = &ctx.framed;
    let out_crs_label = ctx
        .out_crs
        .as_ref()
        .or(framed.frame.crs.as_ref())
        .map_or("the GCP file's local frame".to_string(), |c| c.label());
    let report = RunReport {
        project: if p.name.is_empty() {
            l.path.display().to_string()
        } else {
            p.name.clone()
        },
        geostride_version: build_id().into(),
        inputs,
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

/// Reads and checks everything the stages need before any work (a bad input is found now, not
/// after hours of scanning), and makes the output folder. Also gives the detector, the inputs'
/// records and the warnings so far.
fn prepare<'a>(
    l: &'a Loaded,
    out: &'a Path,
    progress: &'a dyn StageProgress,
    mode: &ChunkMode,
) -> Result<Prepared<'a>, RunError> {
    let p = &l.project;
    let files = l.input_files();
    let guard = inputs::input_guard(l);
    guard.check_dir(out).map_err(output_error)?;

    // Inputs and their checksums: every one is part of every stage's key.
    let inputs = files
        .iter()
        .map(|(key, path)| file_record(key, path, &l.known_inputs))
        .collect::<Result<Vec<_>, _>>()?;
    let sums: Vec<&str> = inputs.iter().map(|i| i.sha256.as_str()).collect();

    let inputs::VideoFacts {
        path: video,
        fps,
        width,
        height,
        frames_total,
    } = inputs::video_facts(l)?;
    let camera = project_camera(l, width, height)?;
    let framed = load_survey(l)?;
    let warnings = inputs::survey_warnings(&framed);
    let pose = pose_source::open(l, &framed, (width, height), frames_total, out, progress)?;
    let surface = super::registry::ground(
        &p.ground,
        &super::grounds::GroundInputs { l, framed: &framed },
    )?;

    // The scale of a head in the image, from a pose of the first frame (the picked one).
    let first_pose = pose.first_pose(&camera, &video)?;
    let centre = first_pose.centre();
    let head_z = surface.height(&centre.xy()).ok_or_else(|| {
        RunError::Input(l.error("ground", "", "the ground is not defined below the camera"))
    })? + p.projection.head_height_m;
    let px_per_m = 0.5 * (camera.fx + camera.fy) / (centre.z - head_z).max(1.0);

    // What the later stages read, checked now rather than after hours of scanning.
    let heights = match &p.projection.heights {
        Some(h) => read_heights(&l.resolve(h))?,
        None => BTreeMap::new(),
    };
    let (out_crs, transform) = inputs::output_transform(l, &framed)?;
    let frames = inputs::frames_to_process(l, frames_total)?;
    let grid = super::chunk_pass::ChunkGrid::new(frames, fps, p.video.chunk_s, p.video.overlap_s);
    let scan_key = stage_key(
        "scan",
        &sums,
        &(
            &p.camera,
            &p.survey,
            &p.video,
            &p.pose,
            &p.detect,
            &p.projection.head_height_m,
            &p.ground,
            &grid,
        ),
    );
    let cache = StageCache::new(out.join(".stages"));
    let (detector, palette) = first_detector(
        l,
        &FirstDetector {
            cache: &cache,
            progress,
            mode,
            grid: &grid,
            scan_key: &scan_key,
            video: &video,
            camera: &camera,
            first_pose: &first_pose,
            px_per_m,
            frames,
            frames_total,
        },
    )?;
    make_out_dirs(&guard, out)?;
    let palette = match palette {
        Some((pal, key)) => {
            cache.store("palette", &key, &pal)?;
            Some(pal)
        }
        None => None,
    };
    let ctx = Ctx {
        l,
        out,
        progress,
        guard,
        cache,
        video,
        fps,
        camera,
        framed,
        pose,
        surface,
        px_per_m,
        heights,
        out_crs,
        transform,
        first_pose,
        grid,
        scan_key,
        palette,
        frames_total: frames,
        size: (width, height),
    };
    Ok(Prepared {
        ctx,
        detector,
        inputs,
        warnings,
    })
}

/// What [`first_detector`] needs beside the project.
struct FirstDetector<'a> {
    cache: &'a StageCache,
    progress: &'a dyn StageProgress,
    mode: &'a ChunkMode,
    grid: &'a super::chunk_pass::ChunkGrid,
    scan_key: &'a str,
    video: &'a Path,
    camera: &'a Camera,
    first_pose: &'a crate::geom::Rigid3,
    px_per_m: f64,
    frames: usize,
    frames_total: Option<usize>,
}

/// The detector made now, to check its inputs, for the first chunk computed (`None`: made for
/// each chunk), and the colour palette learnt before the chunks with its cache key.
#[allow(clippy::type_complexity)]
fn first_detector(
    l: &Loaded,
    x: &FirstDetector<'_>,
) -> Result<
    (
        Option<Box<dyn crate::detect::Detector>>,
        Option<(crate::detect::colour::Palette, String)>,
    ),
    RunError,
> {
    // The colour detector's palette is learnt once, before the chunks (each detects with it);
    // a video of one chunk learns it in its one pass, from the same frames (no frame is
    // decoded twice).
    let p = &l.project;
    let FirstDetector {
        cache,
        progress,
        mode,
        grid,
        scan_key,
        video,
        camera,
        first_pose,
        px_per_m,
        frames,
        frames_total,
    } = *x;
    Ok(match &p.detect {
        super::settings::DetectSection::Colour(c)
            if grid.chunks() == 1 && !matches!(p.track, super::settings::TrackSection::Klt(_)) =>
        {
            (
                Some(super::detectors::colour(c, px_per_m, Some(frames))),
                None,
            )
        }
        super::settings::DetectSection::Colour(c) => {
            let key = stage_key("palette", &[scan_key], &());
            let palette = match cache.load::<crate::detect::colour::Palette>("palette", &key) {
                Some(pal) => pal,
                None => {
                    let bar = progress.stage("palette");
                    bar.set_length(c.sample_frames as u64);
                    let pal = super::detectors::learn_palette(c, video, px_per_m, frames).map_err(
                        |e| RunError::Input(l.error("detect", p.detect.failure_key(), e)),
                    )?;
                    bar.inc(c.sample_frames as u64);
                    pal
                }
            };
            (None, Some((palette, key)))
        }
        // The merge detects nothing (its chunks were checked and made by the segments): an
        // hour's box file is not read.
        _ if *mode == ChunkMode::None => (None, None),
        _ => (
            Some(super::registry::detector(
                &p.detect,
                &super::detectors::DetectorInputs {
                    l,
                    video,
                    camera,
                    first_pose,
                    px_per_m,
                    frames: frames_total,
                },
            )?),
            None,
        ),
    })
}

/// The output folder and its stage cache's folders, once every input is checked.
fn make_out_dirs(guard: &crate::io::Inputs, out: &Path) -> Result<(), RunError> {
    guard.create_dir(out).map_err(output_error)?;
    guard
        .create_dir(&out.join(".stages"))
        .map_err(output_error)?;
    // Not `create_dir`: segments on other machines may be writing their chunks here (their
    // temporaries' process ids mean nothing on this one). `run` and `merge` clear it.
    let chunks_dir = out.join(".stages").join("chunks");
    std::fs::create_dir_all(&chunks_dir).map_err(|source| RunError::Io {
        path: chunks_dir.clone(),
        source,
    })?;
    // pose/ is written only when the pose stage runs; a killed one's temporaries go now.
    crate::io::remove_stale_temps(&out.join("pose")).map_err(|source| RunError::Io {
        path: out.join("pose"),
        source,
    })?;
    Ok(())
}

/// What [`prepare`] gives.
struct Prepared<'a> {
    ctx: Ctx<'a>,
    /// The detector, made to check its inputs, for the first chunk computed (`None`: made for
    /// each chunk).
    detector: Option<Box<dyn crate::detect::Detector>>,
    inputs: Vec<InputRecord>,
    warnings: Vec<String>,
}

/// A point's site-frame coordinates to the output CRS.
type ToOut<'a> = dyn Fn(&Vector3<f64>) -> Result<Vector3<f64>, RunError> + 'a;

/// What every stage reads: the project, its checked inputs and where the results go.
struct Ctx<'a> {
    l: &'a Loaded,
    out: &'a Path,
    progress: &'a dyn StageProgress,
    guard: crate::io::Inputs,
    cache: StageCache,
    video: PathBuf,
    fps: f64,
    camera: Camera,
    framed: Framed,
    /// Where every frame's pose comes from (the `[pose]` kind).
    pose: Box<dyn pose_source::PoseSource + 'a>,
    surface: Box<dyn HeightSurface>,
    px_per_m: f64,
    heights: BTreeMap<usize, (f64, f64)>,
    out_crs: Option<Crs>,
    transform: Option<Transform>,
    /// The first frame's pose (the picked frame's for a hovering camera).
    first_pose: Rigid3,
    /// The chunks the video is processed in.
    grid: super::chunk_pass::ChunkGrid,
    /// The key of the scan: every chunk's key derives from it.
    scan_key: String,
    /// The colour detector's palette.
    palette: Option<crate::detect::colour::Palette>,
    /// Frames processed.
    frames_total: usize,
    /// The video's frame size, pixels.
    size: (u32, u32),
}

/// A stage's result: the one cached under `key` when there is one (and `valid`), else
/// `compute`d and cached. Says which.
fn cached<T: Serialize + DeserializeOwned>(
    cache: &StageCache,
    progress: &dyn StageProgress,
    stage: &str,
    key: &str,
    valid: bool,
    compute: impl FnOnce() -> Result<T, RunError>,
) -> Result<(T, StageStatus), RunError> {
    if valid && let Some(d) = cache.load::<T>(stage, key) {
        return Ok((d, StageStatus::Reused));
    }
    let d = compute()?;
    cache.store(stage, key, &d)?;
    progress.stored(stage);
    Ok((d, StageStatus::Computed))
}

/// A stage whose data are a sequence written a piece at a time (its `compute` stores them with
/// [`StageCache::store_seq`] and gives their summary): the summary cached beside them (as
/// `STAGE-summary`) under the same key, the data left on disk. Reused only when both are
/// there whole under `key`.
fn cached_seq<S: Serialize + DeserializeOwned>(
    cache: &StageCache,
    progress: &dyn StageProgress,
    stage: &str,
    key: &str,
    compute: impl FnOnce() -> Result<S, RunError>,
) -> Result<(S, StageStatus), RunError> {
    // The summary's key is not the data's: neither file passes for the other.
    let (summary, summary_key) = (format!("{stage}-summary"), format!("{key}/summary"));
    if cache.has(stage, key)
        && let Some(d) = cache.load::<S>(&summary, &summary_key)
    {
        return Ok((d, StageStatus::Reused));
    }
    let d = compute()?;
    cache.store(&summary, &summary_key, &d)?;
    progress.stored(stage);
    Ok((d, StageStatus::Computed))
}

/// Trajectories to WGS 84 for GeoJSON, one at a time, and what the report should say about them.
struct Wgs84 {
    crs: Crs,
    to_wgs84: Transform,
    used: UsedOperations,
    heights_ellipsoidal: bool,
    /// The survey's kind of height, for the report.
    heights: String,
}

impl Wgs84 {
    /// Converts output-CRS coordinates (`crs`, in the CRS `spec`) to WGS 84 with the
    /// transformation PROJ picks for each point (datum change included; the one `cs2cs` uses).
    /// Heights are kept, as WGS 84 ellipsoidal heights, only when the survey's are ellipsoidal:
    /// RFC 7946 allows no other kind.
    fn new(spec: &str, heights: &HeightKind) -> Result<Wgs84, RunError> {
        let failed = RunError::Crs;
        let crs = Crs::new(spec).map_err(failed)?;
        let to_wgs84 =
            Transform::new(&crs, &Crs::new("EPSG:4326").map_err(failed)?).map_err(failed)?;
        Ok(Wgs84 {
            crs,
            to_wgs84,
            used: UsedOperations::default(),
            heights_ellipsoidal: *heights == HeightKind::Ellipsoidal,
            heights: heights.to_string(),
        })
    }

    /// The trajectory's points as (longitude, latitude, ellipsoidal height or NaN).
    fn convert(&mut self, t: &Trajectory) -> Result<Vec<Vector3<f64>>, RunError> {
        t.points
            .iter()
            .map(|q| {
                let (lon, lat, h) = self
                    .to_wgs84
                    .apply_3d_noting(q.crs.x, q.crs.y, q.crs.z, &mut self.used)
                    .map_err(RunError::Crs)?;
                Ok(Vector3::new(
                    lon,
                    lat,
                    if self.heights_ellipsoidal {
                        h
                    } else {
                        f64::NAN
                    },
                ))
            })
            .collect()
    }

    /// PROJ's operations used, with their accuracy, and the notes for the report.
    fn report(&self) -> (Vec<String>, Vec<String>) {
        let operations = self
            .used
            .infos()
            .iter()
            .map(|op| {
                let acc = op.accuracy_m.map_or("accuracy unknown".to_string(), |a| {
                    format!("accuracy {a} m")
                });
                format!(
                    "{} to WGS 84: PROJ's '{}' ({acc})",
                    self.crs.label(),
                    op.name
                )
            })
            .collect();
        let mut notes = Vec::new();
        if !self.heights_ellipsoidal {
            notes.push(format!(
                "GeoJSON positions are 2D: RFC 7946 heights are ellipsoidal on WGS 84 and the survey's are {}; the heights are in trajectories.csv and the GeoPackage",
                self.heights
            ));
        }
        (operations, notes)
    }
}
