//! The inputs step: every input the stages need read and checked once, before any work (a
//! bad input is found now, not after hours of scanning), into plain data ([`RunInputs`]); the
//! output folder made; the detector and the pose source chosen. All mapping of the project's
//! errors to its keys and lines happens here and in `inputs`.

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

use nalgebra::Vector2;

use super::inputs::{self, load_survey, project_camera};
use super::pose_source;
use super::{ChunkMode, InputRecord, RunError, StageProgress};
use crate::cache::{StageCache, stage_key};
use crate::camera::Camera;
use crate::geom::Rigid3;
use crate::pipeline::chunk_pass::ChunkGrid;
use crate::pipeline::error::output_error;
use crate::pipeline::project::Loaded;
use crate::pipeline::provenance::file_record;
use crate::pipeline::{detectors, grounds, registry, settings};
use crate::survey::crs::{Crs, Transform};
use crate::survey::load::Framed;
use crate::terrain::HeightSurface;

/// The survey in its site frame, with `[picks] auto = true`'s picks added (and their CSV), and
/// the survey's warnings.
fn survey_and_picks(
    l: &Loaded,
    video: &Path,
) -> Result<(Framed, Option<String>, Vec<String>), RunError> {
    let mut framed = load_survey(l)?;
    let auto = if l.project.picks.auto {
        Some(inputs::auto_picks(l, &mut framed, video)?)
    } else {
        None
    };
    let mut warnings = inputs::survey_warnings(&framed);
    warnings.extend(auto.as_ref().and_then(|(_, w)| w.clone()));
    Ok((framed, auto.map(|(csv, _)| csv), warnings))
}

/// `picks-auto.csv`, when the picks were found.
fn write_auto_picks(out: &Path, csv: Option<&str>) -> Result<(), RunError> {
    let Some(csv) = csv else { return Ok(()) };
    let path = out.join("picks-auto.csv");
    crate::io::write_atomic(&path, csv.as_bytes()).map_err(|source| RunError::Io { path, source })
}

/// Reads and checks everything the stages need before any work (a bad input is found now, not
/// after hours of scanning), and makes the output folder. Also gives the detector, the inputs'
/// records and the warnings so far.
pub(super) fn prepare<'a>(
    l: &'a Loaded,
    out: &'a Path,
    progress: &'a dyn StageProgress,
    mode: &ChunkMode,
) -> Result<Prepared<'a>, RunError> {
    let p = &l.project;
    let guard = inputs::input_guard(l);
    guard.check_dir(out).map_err(output_error)?;

    // Inputs and their checksums: every one is part of every stage's key.
    let records = input_records(l)?;
    let sums: Vec<&str> = records.iter().map(|i| i.sha256.as_str()).collect();

    let inputs::VideoFacts {
        path: video,
        fps,
        width,
        height,
        frames_total,
    } = inputs::video_facts(l)?;
    let camera = project_camera(l, width, height)?;
    let (framed, auto_picks, warnings) = survey_and_picks(l, &video)?;
    let pose = pose_source::open(
        l,
        &framed,
        (&camera, &video, fps),
        (width, height),
        frames_total,
        out,
        progress,
    )?;
    let surface = ground_of(l, &framed, pose.as_ref())?;

    // The scale of a head in the image, from a pose of the first frame (the picked one).
    let first_pose = pose.first_pose(&camera, &video)?;
    let px_per_m = head_scale(
        &camera,
        &first_pose,
        surface.as_ref(),
        p.projection.head_height_m,
    )
    .ok_or_else(|| {
        RunError::Input(l.error("ground", "", "the ground is not defined below the camera"))
    })?;

    // What the later stages read, checked now rather than after hours of scanning.
    let (heights, telemetry) = inputs::read_heights_and_telemetry(l)?;
    let (out_crs, transform) = inputs::output_transform(l, &framed)?;
    let frames = inputs::frames_to_process(l, frames_total)?;
    let grid = ChunkGrid::new(frames, fps, p.video.chunk_s, p.video.overlap_s);
    let scan_key = stage_key(
        "scan",
        &sums,
        &(
            &p.camera,
            &p.survey,
            &p.picks,
            &p.video,
            &p.pose,
            &p.detect,
            // The image tracker runs in the scan (per chunk).
            &p.track,
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
    write_auto_picks(out, auto_picks.as_deref())?;
    let palette = match palette {
        Some((pal, key)) => {
            cache.store("palette", &key, &pal)?;
            Some(pal)
        }
        None => None,
    };
    let detectors = Detectors {
        first: detector,
        make: chunk_detectors(
            l,
            &palette,
            (&video, &camera, &first_pose),
            px_per_m,
            frames,
        ),
        at: l.error("detect", p.detect.failure_key(), ""),
    };
    let formats = export_formats(l)?;
    let carried_picks = pose.carried_picks();
    let bodies = bodies(l, &first_pose)?;
    let inputs = RunInputs {
        title: if p.name.is_empty() {
            l.path.display().to_string()
        } else {
            p.name.clone()
        },
        video,
        fps,
        size: (width, height),
        frames_total: frames,
        camera,
        framed,
        surface,
        px_per_m,
        heights,
        telemetry,
        bodies,
        out_crs,
        transform,
        first_pose,
        carried_picks,
        grid,
        scan_key,
        palette,
        formats,
        motion_check: matches!(&p.detect, settings::DetectSection::Onnx(o) if o.motion_check),
    };
    Ok(Prepared {
        env: Env {
            out,
            progress,
            guard,
            cache,
        },
        inputs,
        pose,
        detectors,
        records,
        warnings,
    })
}

/// The detector of each chunk after the first: the colour detector with the palette learnt,
/// else the registry's from the `[detect]` section.
fn chunk_detectors<'a>(
    l: &'a Loaded,
    palette: &Option<crate::detect::colour::Palette>,
    (video, camera, first_pose): (&Path, &Camera, &Rigid3),
    px_per_m: f64,
    frames: usize,
) -> Box<dyn Fn() -> Result<Box<dyn crate::detect::Detector>, RunError> + 'a> {
    let p = &l.project;
    match (&p.detect, palette) {
        (settings::DetectSection::Colour(c), Some(pal)) => {
            let pal = pal.clone();
            Box::new(move || Ok(detectors::colour_with(c, px_per_m, &pal)))
        }
        _ => {
            let (video, camera, first_pose) = (video.to_path_buf(), camera.clone(), *first_pose);
            Box::new(move || {
                registry::detector(
                    &p.detect,
                    &detectors::DetectorInputs {
                        l,
                        video: &video,
                        camera: &camera,
                        first_pose: &first_pose,
                        px_per_m,
                        frames: Some(frames),
                    },
                )
            })
        }
    }
}

/// The `[export]` formats, each known (checked before any work).
fn export_formats(l: &Loaded) -> Result<Vec<crate::export::ExportFormat>, RunError> {
    l.project
        .export
        .formats
        .iter()
        .map(|f| {
            crate::export::ExportFormat::parse(f).ok_or_else(|| {
                RunError::Input(l.error("export", "formats", format!("unknown format '{f}'")))
            })
        })
        .collect()
}

/// What [`first_detector`] needs beside the project.
struct FirstDetector<'a> {
    cache: &'a StageCache,
    progress: &'a dyn StageProgress,
    mode: &'a ChunkMode,
    grid: &'a ChunkGrid,
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
        settings::DetectSection::Colour(c)
            if grid.chunks() == 1 && !matches!(p.track, settings::TrackSection::Klt(_)) =>
        {
            (Some(detectors::colour(c, px_per_m, Some(frames))), None)
        }
        settings::DetectSection::Colour(c) => {
            let key = stage_key("palette", &[scan_key], &());
            let palette = match cache.load::<crate::detect::colour::Palette>("palette", &key) {
                Some(pal) => pal,
                None => {
                    let bar = progress.stage("palette");
                    bar.set_length(c.sample_frames as u64);
                    let pal =
                        detectors::learn_palette(c, video, px_per_m, frames).map_err(|e| {
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
            Some(registry::detector(
                &p.detect,
                &detectors::DetectorInputs {
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

/// Every input file with its checksum.
fn input_records(l: &Loaded) -> Result<Vec<InputRecord>, RunError> {
    l.input_files()
        .iter()
        .map(|(key, path)| file_record(key, path, &l.known_inputs))
        .collect()
}

/// The project's ground; local planes without a model of their own take the pose's.
fn ground_of(
    l: &Loaded,
    framed: &Framed,
    pose: &dyn pose_source::PoseSource,
) -> Result<Box<dyn HeightSurface>, RunError> {
    let inputs = grounds::GroundInputs {
        l,
        framed,
        pose_model: pose.model_dir(),
    };
    registry::ground(&l.project.ground, &inputs)
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
pub(super) struct Prepared<'a> {
    pub(super) env: Env<'a>,
    pub(super) inputs: RunInputs,
    /// Where every frame's pose comes from (the `[pose]` kind).
    pub(super) pose: Box<dyn pose_source::PoseSource + 'a>,
    pub(super) detectors: Detectors<'a>,
    /// Every input file with its checksum.
    pub(super) records: Vec<InputRecord>,
    pub(super) warnings: Vec<String>,
}

/// Where the stages write and how they report: the output folder, its stage cache, the guard
/// that keeps every output off the inputs, and the progress display.
pub(super) struct Env<'a> {
    pub(super) out: &'a Path,
    pub(super) progress: &'a dyn StageProgress,
    pub(super) guard: crate::io::Inputs,
    pub(super) cache: StageCache,
}

/// The project's inputs, read and checked once by [`prepare`]: plain data. A stage takes these,
/// its own settings section and its predecessor's artifact; none reads the project file.
pub(super) struct RunInputs {
    /// The views' title: the project's name, else its file.
    pub(super) title: String,
    pub(super) video: PathBuf,
    pub(super) fps: f64,
    /// The video's frame size, pixels.
    pub(super) size: (u32, u32),
    /// Frames processed.
    pub(super) frames_total: usize,
    pub(super) camera: Camera,
    pub(super) framed: Framed,
    pub(super) surface: Box<dyn HeightSurface>,
    /// Image scale at head height below the camera, pixels per metre.
    pub(super) px_per_m: f64,
    /// Heights given per track: (height, σ), metres.
    pub(super) heights: BTreeMap<usize, (f64, f64)>,
    /// The drone's telemetry (`[video] telemetry`).
    pub(super) telemetry: Option<super::telemetry_site::Telemetry>,
    /// Where the detector boxes whole bodies: how their boxes are read.
    pub(super) bodies: Option<Bodies>,
    pub(super) out_crs: Option<Crs>,
    pub(super) transform: Option<Transform>,
    /// The first frame's pose (the picked frame's for a hovering camera).
    pub(super) first_pose: Rigid3,
    /// The frame whose picks the scan carries, and their pixels (none for a model pose).
    pub(super) carried_picks: (usize, Vec<Vector2<f64>>),
    /// The chunks the video is processed in.
    pub(super) grid: ChunkGrid,
    /// The key of the scan: every chunk's key derives from it.
    pub(super) scan_key: String,
    /// The colour detector's palette.
    pub(super) palette: Option<crate::detect::colour::Palette>,
    /// The export formats, in the project's order.
    pub(super) formats: Vec<crate::export::ExportFormat>,
    /// Whether the detector is checked by the motion detector (`motion-check.csv`).
    pub(super) motion_check: bool,
}

/// How a whole-body detector's boxes are read at projection (both ends), unless the model gave
/// the heads (`[detect] head`); None for the hat detector.
fn bodies(l: &Loaded, first_pose: &crate::geom::Rigid3) -> Result<Option<Bodies>, RunError> {
    let p = &l.project;
    let model_heads = match &p.detect {
        settings::DetectSection::Onnx(o) => detectors::onnx_model_heads(o, l, first_pose)?,
        _ => false,
    };
    Ok(match p.detect.body() {
        Some(b) if !model_heads => Some(Bodies {
            shape: b.shape(),
            error: b.error_model(),
        }),
        _ => None,
    })
}

/// The image scale of a head, pixels per metre, where the camera looks: at the head-height point
/// seen at the image's centre (below the camera when it looks straight down, out on the ground
/// when it looks obliquely), else below the camera. None where the ground is not defined there.
pub(crate) fn head_scale(
    camera: &Camera,
    cam_from_world: &crate::geom::Rigid3,
    surface: &dyn HeightSurface,
    head_height_m: f64,
) -> Option<f64> {
    let f = 0.5 * (camera.fx + camera.fy);
    let centre_px = nalgebra::Vector2::new(camera.cx, camera.cy);
    let seen =
        crate::projection::intersect(camera, cam_from_world, surface, head_height_m, &centre_px)
            .map(|p| cam_from_world.apply(&p).z);
    let depth = match seen {
        Some(d) => d,
        None => {
            let c = cam_from_world.centre();
            c.z - (surface.height(&c.xy())? + head_height_m)
        }
    };
    Some(f / depth.max(1.0))
}

/// How a body detector's boxes become ground positions (`projection::body`).
pub(super) struct Bodies {
    pub(super) shape: crate::projection::body::BodyShape,
    /// The detection error of a box's edges.
    pub(super) error: crate::detect::ErrorModel,
}

/// The detector of each chunk computed: the one made while checking the inputs for the first,
/// then a new one from the registry for each; and where a detector's failure points in the
/// project file.
pub(super) struct Detectors<'a> {
    pub(super) first: Option<Box<dyn crate::detect::Detector>>,
    pub(super) make: Box<dyn Fn() -> Result<Box<dyn crate::detect::Detector>, RunError> + 'a>,
    /// The `[detect]` key a failure names (its message filled in).
    pub(super) at: crate::io::FileError,
}

impl Detectors<'_> {
    /// The next chunk's detector.
    pub(super) fn next(&mut self) -> Result<Box<dyn crate::detect::Detector>, RunError> {
        match self.first.take() {
            Some(d) => Ok(d),
            None => (self.make)(),
        }
    }

    /// A detector's failure, as the project's error at the `[detect]` key.
    pub(super) fn failed(&self, message: String) -> RunError {
        RunError::Input(crate::io::FileError {
            message,
            ..self.at.clone()
        })
    }
}
