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
use super::project::{GroundSection, Loaded};
use crate::camera::{Camera, formats, presets};
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
use crate::survey::Role;
use crate::survey::crs::{Crs, HeightKind, Transform, UsedOperations};
use crate::survey::frame::Origin;
use crate::survey::load::{Framed, LoadOptions, load_framed};
use crate::survey::read::{HeightChoice, ReadOptions};
use crate::terrain::{DeckProfile, HeightSurface, Plane};
use crate::track::ImageTrack;

mod export_stage;
mod model_pose;
mod pose_stage;
mod project_stage;
mod scan_stage;
mod smooth_stage;
mod track_stage;
mod views_stage;

use export_stage::export_stage;
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

/// Refuses, naming the project key, an input whose bytes differ from its record in `known` (a
/// split run's inputs: a video replaced after the split would make segments of another video).
/// A file whose size and time are as recorded is taken as unchanged, as everywhere else.
pub fn check_known_inputs(
    l: &Loaded,
    known: &[KnownInput],
    split_dir: &Path,
) -> Result<(), RunError> {
    for (role, path) in l.input_files() {
        let shown = path.display().to_string();
        let Some(k) = known.iter().find(|k| k.path == shown) else {
            continue;
        };
        let (section, key) = role.split_once('.').unwrap_or((role, ""));
        let changed = |how: String| {
            RunError::Input(l.error(
                section,
                key,
                format!(
                    "{shown}: {how} since it was split into {}: the segments would be of another file; split again",
                    split_dir.display()
                ),
            ))
        };
        let now = match size_and_time(&path) {
            Some(now) => now,
            None => return Err(changed("gone".into())),
        };
        if now.0 != k.bytes {
            return Err(changed(format!("{} bytes now, {} then", now.0, k.bytes)));
        }
        if file_record(role, &path, known)?.sha256 != k.sha256 {
            return Err(changed("its content changed".into()));
        }
    }
    Ok(())
}

/// The inputs of `l` hashed now and compared with a finished run's `recorded` ones (`geostride
/// render` draws that run's views: a changed input would make it a new run). Gives the records
/// as known inputs, so that the run does not read the files again.
pub fn check_recorded_inputs(
    l: &Loaded,
    recorded: &[InputRecord],
    run_dir: &Path,
) -> Result<Vec<KnownInput>, RunError> {
    let mut known = Vec::new();
    for (role, path) in l.input_files() {
        let now = file_record(role, &path, &[])?;
        let (section, key) = role.split_once('.').unwrap_or((role, ""));
        // By role and content: the run may have named the file by another path.
        let same = recorded
            .iter()
            .any(|r| r.role == now.role && r.sha256 == now.sha256);
        if !same {
            return Err(RunError::Input(l.error(
                section,
                key,
                format!(
                    "{}: not the file the run in {} read (changed since, or another): render draws that run's views; run the project again (geostride run) for new ones",
                    now.path,
                    run_dir.display()
                ),
            )));
        }
        if let Some((bytes, modified_ns)) = size_and_time(&path) {
            known.push(KnownInput {
                path: now.path,
                bytes,
                modified_ns,
                sha256: now.sha256,
            });
        }
    }
    Ok(known)
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

/// A track projected to the world.
#[derive(Clone, Debug, Serialize, Deserialize)]
struct WorldTrack {
    id: usize,
    height_m: f64,
    height_sd_m: f64,
    height_source: String,
    points: Vec<(usize, WorldPoint)>,
}

/// The camera of the project, scaled to the video.
fn project_camera(l: &Loaded, width: u32, height: u32) -> Result<Camera, RunError> {
    let spec = &l.project.camera.calibration;
    let cal = match presets::preset(spec) {
        Some(c) => c,
        None => formats::read(&l.resolve(spec), None).map_err(RunError::from_input)?,
    };
    let cam = cal.camera;
    match cam.image_size {
        Some(s) if s.width == width && s.height == height => Ok(cam),
        Some(s) => cam.scaled_to(width, height).ok_or_else(|| {
            RunError::Input(l.error("camera", "calibration", format!("the calibration is for {}x{}, the video is {width}x{height}: another aspect ratio", s.width, s.height)))
        }),
        None => Ok(cam.with_image_size(width, height)),
    }
}

fn load_survey(l: &Loaded) -> Result<Framed, RunError> {
    let s = &l.project.survey;
    let origin = match &s.origin {
        Some(o) => Some(
            o.parse::<Origin>()
                .map_err(|e| RunError::Input(l.error("survey", "origin", e)))?,
        ),
        None => None,
    };
    let opts = LoadOptions {
        read: ReadOptions {
            crs: s.crs.clone(),
            height: s.height.as_deref().map(|h| {
                if h == "ellipsoidal" {
                    HeightChoice::Ellipsoidal
                } else {
                    HeightChoice::Orthometric
                }
            }),
            ..ReadOptions::default()
        },
        picks: s.picks.iter().map(|p| l.resolve(p)).collect(),
        check_prefix: Some(s.check_prefix.clone()),
        check: s.check.clone(),
        disable: Vec::new(),
        origin,
    };
    load_framed(&l.resolve(&s.gcps), &opts).map_err(RunError::from_input)
}

/// The picks of the picked frame: (frame, control, check), checked like `geostride pose` checks
/// them (inside the image, one per point, heights) and the frame inside the video.
fn picked(
    l: &Loaded,
    framed: &Framed,
    size: (u32, u32),
    frames: Option<usize>,
) -> Result<(usize, Vec<GcpObservation>, Vec<GcpObservation>), RunError> {
    let s = &l.project.survey;
    let input = |key: &str, m: String| RunError::Input(l.error("survey", key, m));
    let images = framed.picked_images();
    let video_name = Path::new(&l.project.video.path)
        .file_name()
        .map(|f| f.to_string_lossy().into_owned())
        .unwrap_or_default();
    let image = images
        .keys()
        .find(|k| k.starts_with(&format!("{video_name}#")))
        .or_else(|| (images.len() == 1).then(|| images.keys().next()).flatten())
        .cloned()
        .ok_or_else(|| {
            input(
                "picks",
                format!(
                    "no picks of '{video_name}#N' (the frame N of the video); the picks name {:?}",
                    images.keys().take(10).collect::<Vec<_>>()
                ),
            )
        })?;
    let frame = match (l.project.pose.picks_frame(), image.rsplit_once('#')) {
        (Some(f), _) => f,
        (None, Some((_, n))) => n.parse().map_err(|_| {
            input(
                "picks",
                format!(
                    "the picks' image '{}' should end in '#N', N the frame number (from 0)",
                    crate::io::clip(&image, 60)
                ),
            )
        })?,
        (None, None) => 0,
    };
    if let Some(n) = frames
        && frame >= n
    {
        let key = if l.project.pose.picks_frame().is_some() {
            RunError::Input(l.error(
                "pose",
                "picks_frame",
                format!("frame {frame} is beyond the {n} frame(s) processed"),
            ))
        } else {
            input(
                "picks",
                format!("the picks are on frame {frame}, beyond the {n} frame(s) processed"),
            )
        };
        return Err(key);
    }
    let seen = framed
        .observations(&image, s.pick_sigma_px, s.gcp_sigma_m, Some(size))
        .map_err(RunError::from_input)?;
    if seen.control.len() < 4 {
        return Err(input(
            "picks",
            format!(
                "image '{image}' has picks of {} control point(s); a pose needs at least 4",
                seen.control.len()
            ),
        ));
    }
    Ok((frame, seen.control, seen.check))
}

/// The ground of the project in the site frame.
fn ground(l: &Loaded, framed: &Framed) -> Result<Box<dyn HeightSurface>, RunError> {
    let control: Vec<Vector3<f64>> = framed
        .survey
        .points
        .iter()
        .zip(&framed.local)
        .filter(|(p, _)| p.role == Role::Control)
        .map(|(_, x)| *x)
        .collect();
    let err = |key: &str, m: String| RunError::Input(l.error("ground", key, m));
    match &l.project.ground {
        GroundSection::Plane { height_m: Some(h) } => {
            Ok(Box::new(Plane::from_gradient(0.0, 0.0, *h)))
        }
        GroundSection::Plane { height_m: None } => {
            let (plane, _) = Plane::fit(&control).map_err(|e| {
                err(
                    "height_m",
                    format!("fitting a plane to the control GCPs: {e}"),
                )
            })?;
            Ok(Box::new(plane))
        }
        GroundSection::Deck {
            centre_line,
            width_m,
            stations,
            degree,
        } => {
            let line = centre_line
                .iter()
                .map(|p| {
                    framed
                        .frame
                        .local_from_source(&Vector3::new(p[0], p[1], f64::NAN))
                        .map(|x| x.xy())
                })
                .collect::<Result<Vec<Vector2<f64>>, _>>()
                .map_err(|e| err("centre_line", e.to_string()))?;
            if stations.is_empty() {
                let (deck, _) = DeckProfile::fit_polynomial(line, 0.0, *width_m, *degree, &control)
                    .map_err(|e| {
                        if matches!(e, crate::terrain::deck::DeckError::TooFewPoints { got: 0, .. }) {
                            err(
                                "centre_line",
                                format!("none of the {} control GCPs lies on the deck ({width_m} m wide along the centre line): check the centre line and the survey's CRS (survey.crs, or the GCP file's own)", control.len()),
                            )
                        } else {
                            err(
                                "degree",
                                format!("fitting the deck profile to the control GCPs: {e}"),
                            )
                        }
                    })?;
                Ok(Box::new(deck))
            } else {
                Ok(Box::new(DeckProfile {
                    centre_line: line,
                    start_s: 0.0,
                    width_m: *width_m,
                    alignment: crate::terrain::deck::VerticalAlignment::Stations(
                        stations.iter().map(|s| (s[0], s[1])).collect(),
                    ),
                }))
            }
        }
        GroundSection::LocalPlanes { model, window_m } => {
            let points = model_pose::model_points_in_site(l, &l.resolve(model), framed)?;
            Ok(Box::new(crate::terrain::LocalPlanes::new(
                points, *window_m,
            )))
        }
        GroundSection::Dem { path } => {
            let (grid, wkt) = crate::terrain::raster::load(&l.resolve(path))
                .map_err(|e| err("path", e.to_string()))?;
            // The DEM surface keeps its own handle on the site frame (PROJ handles are not shared).
            let origin = match &l.project.survey.origin {
                Some(o) => o.parse::<Origin>().map_err(|e| err("path", e))?,
                None => Origin::Centroid,
            };
            let frame = std::rc::Rc::new(
                crate::survey::frame::SiteFrame::new(&framed.survey, &origin)
                    .map_err(|e| err("path", e.to_string()))?,
            );
            let dem = crate::survey::frame::dem_surface(frame, grid, &wkt)
                .map_err(|e| err("path", e.to_string()))?;
            Ok(Box::new(dem))
        }
    }
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
    let mut guard = crate::io::Inputs::new(files.iter().map(|(_, f)| f));
    guard.add(&l.path);
    // A model is read as a whole: nothing of the run goes inside it.
    if let super::settings::PoseSection::Model(m) = &p.pose {
        guard.add_folder(l.resolve(&m.model));
    }
    if let super::project::GroundSection::LocalPlanes { model, .. } = &p.ground {
        guard.add_folder(l.resolve(model));
    }
    guard.check_dir(out).map_err(output_error)?;

    let mut warnings = Vec::new();

    // Inputs and their checksums: every one is part of every stage's key.
    let inputs = files
        .iter()
        .map(|(key, path)| file_record(key, path, &l.known_inputs))
        .collect::<Result<Vec<_>, _>>()?;
    let sums: Vec<&str> = inputs.iter().map(|i| i.sha256.as_str()).collect();

    let video = l.resolve(&p.video.path);
    let reader = crate::video::source::FrameReader::open(&video)
        .map_err(|e| RunError::Input(l.error("video", "path", e.to_string())))?;
    let (fps, width, height, frame_count) =
        (reader.fps, reader.width, reader.height, reader.frame_count);
    drop(reader);
    if !(fps > 0.0) {
        return Err(RunError::Input(l.error(
            "video",
            "path",
            "the video states no frame rate",
        )));
    }
    let max_frames = p.video.duration_s.map(|d| (d * fps).ceil() as usize);
    let frames_total = match (frame_count, max_frames) {
        (Some(c), Some(m)) => Some(c.min(m)),
        (c, m) => c.or(m),
    };
    let camera = project_camera(l, width, height)?;
    let framed = load_survey(l)?;
    warnings.extend(framed.survey.warnings.iter().cloned());
    warnings.extend(framed.survey.dropped.iter().map(|d| {
        format!(
            "{}:{}: dropped: {}",
            framed.survey.source.display(),
            d.line,
            d.reason
        )
    }));
    let model = match &p.pose {
        super::settings::PoseSection::Model(m) => Some(model_pose::open_model(
            l,
            m,
            &framed,
            &out.join(".stages").join("model-features"),
            progress.stage("model").as_ref(),
        )?),
        _ => None,
    };
    let (pick_frame, control, check) = match &model {
        None => picked(l, &framed, (width, height), frames_total)?,
        Some(_) => (0, Vec::new(), Vec::new()),
    };
    let surface = ground(l, &framed)?;

    // The scale of a head in the image, from a pose of the first frame (the picked one).
    let first_pose = match (&p.pose, &model) {
        (super::settings::PoseSection::Model(m), Some(sm)) => {
            model_pose::first_frame_pose(l, m, sm, &camera, &video)?
        }
        _ => {
            solve_pose(&camera, &control, &PoseSettings::default())
                .map_err(|e| RunError::Unusable(format!("the picks of frame {pick_frame}: {e}")))?
                .cam_from_world
        }
    };
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
    let out_crs = match &p.export.crs {
        Some(c) => Some(
            Crs::new(c).map_err(|e| RunError::Input(l.error("export", "crs", e.to_string())))?,
        ),
        None => None,
    };
    let transform = match (&out_crs, &framed.frame.crs) {
        (Some(o), Some(s)) => Some(
            Transform::new(s, o)
                .map_err(|e| RunError::Input(l.error("export", "crs", e.to_string())))?,
        ),
        (Some(_), None) => {
            return Err(RunError::Input(l.error(
                "export",
                "crs",
                "the GCP file has no CRS to convert from",
            )));
        }
        _ => None,
    };
    let frames = frames_total.ok_or_else(|| {
        RunError::Input(l.error(
            "video",
            "duration_s",
            "the video states no frame count: give the seconds to process",
        ))
    })?;
    if frames > MAX_FRAMES {
        return Err(RunError::Input(l.error(
            "video",
            "duration_s",
            format!(
                "{frames} frames to process: more than a day at 120 frames a second ({MAX_FRAMES}); a damaged video states a wrong count: give the seconds to process"
            ),
        )));
    }
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
    // The colour detector's palette is learnt once, before the chunks (each detects with it);
    // a video of one chunk learns it in its one pass, from the same frames (no frame is
    // decoded twice).
    let (detector, palette) = match &p.detect {
        super::settings::DetectSection::Colour(c)
            if grid.chunks() == 1 && !matches!(p.track, super::settings::TrackSection::Klt(_)) =>
        {
            (
                Some(super::detectors::colour(c, px_per_m, Some(frames))),
                None,
            )
        }
        super::settings::DetectSection::Colour(c) => {
            let key = stage_key("palette", &[&scan_key], &());
            let palette = match cache.load::<crate::detect::colour::Palette>("palette", &key) {
                Some(pal) => pal,
                None => {
                    let bar = progress.stage("palette");
                    bar.set_length(c.sample_frames as u64);
                    let pal = super::detectors::learn_palette(c, &video, px_per_m, frames)
                        .map_err(|e| {
                            RunError::Input(l.error("detect", p.detect.failure_key(), e))
                        })?;
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
                    video: &video,
                    camera: &camera,
                    first_pose: &first_pose,
                    px_per_m,
                    frames: frames_total,
                },
            )?),
            None,
        ),
    };

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
        pick_frame,
        control,
        check,
        surface,
        px_per_m,
        heights,
        out_crs,
        transform,
        model,
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
    pick_frame: usize,
    control: Vec<GcpObservation>,
    check: Vec<GcpObservation>,
    surface: Box<dyn HeightSurface>,
    px_per_m: f64,
    heights: BTreeMap<usize, (f64, f64)>,
    out_crs: Option<Crs>,
    transform: Option<Transform>,
    /// The reference model of a `model` pose, in the site frame.
    model: Option<model_pose::SiteModel>,
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

/// Known head heights from a heights file (`parse_heights`).
fn read_heights(path: &Path) -> Result<BTreeMap<usize, (f64, f64)>, crate::io::FileError> {
    let text = crate::io::FileCtx { path }.read_text("a CSV of heights")?;
    parse_heights(path, &text)
}

/// The most rows of a heights file (tracks of a day of a marathon are fewer).
pub const MAX_HEIGHTS: usize = 1_000_000;

/// Known head heights, `id,height_m[,sd_m]` per line (a header is optional): track id to
/// (height, σ), metres. `path` names the file in messages.
pub fn parse_heights(
    path: &Path,
    text: &str,
) -> Result<BTreeMap<usize, (f64, f64)>, crate::io::FileError> {
    let ctx = crate::io::FileCtx { path };
    let lines = text.lines().count();
    if lines > MAX_HEIGHTS {
        return Err(ctx.err(
            None,
            None,
            format!("{lines} lines: a heights file has at most {MAX_HEIGHTS}, one per track"),
        ));
    }
    // id -> (height, σ, line)
    let mut out: BTreeMap<usize, (f64, f64, usize)> = BTreeMap::new();
    for row in ctx.lines(text) {
        let (line, l) = row?;
        let f: Vec<&str> = l.split(',').map(str::trim).collect();
        if l.trim().is_empty() || (line == 1 && f[0].parse::<f64>().is_err()) {
            continue;
        }
        ctx.field_count(&f, line, 2, 3, "id,height_m[,sd_m]")?;
        let id = ctx.whole(f[0], line, "id")?;
        let h = ctx.number(f[1], line, "height_m")?;
        let sd = match f.get(2).filter(|s| !s.is_empty()) {
            Some(s) => {
                let sd = ctx.number(s, line, "sd_m")?;
                if sd < 0.0 {
                    return Err(ctx.err(
                        Some(line),
                        Some("sd_m"),
                        format!("a σ cannot be negative, found {sd}"),
                    ));
                }
                sd
            }
            None => 0.0,
        };
        if !(h > 0.0 && h < 3.0) {
            return Err(ctx.err(
                Some(line),
                Some("height_m"),
                format!("a head height of {h} m is not plausible (expected 0 to 3 m)"),
            ));
        }
        if let Some((_, _, first)) = out.insert(id as usize, (h, sd, line)) {
            return Err(ctx.at(
                line,
                format!("track {id} has a height on line {first} already; keep one"),
            ));
        }
    }
    Ok(out
        .into_iter()
        .map(|(k, (h, sd, _))| (k, (h, sd)))
        .collect())
}
