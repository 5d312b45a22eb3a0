//! Command-line interface: argument parsing and output only; the work is in the library.

mod ba;
mod calibrate;
mod camera;
mod cluster;
mod dataset;
pub mod demo;
mod detect;
mod evaluate;
mod fit_error;
mod gcp;
mod plan;
mod pose;
mod pose_video;
mod render;
mod run;
mod sfm;
mod simulate;
pub(crate) mod survey;
mod telemetry;
mod track;

use std::path::Path;

use anyhow::anyhow;
use clap::{Parser, Subcommand};

use geostride::camera::{Camera, formats, presets};
use geostride::io::Inputs;

/// An error caused by the user's input or usage (exit code 2), as opposed to a failure while
/// running (exit code 1).
#[derive(Debug)]
pub struct BadInput(pub anyhow::Error);

impl std::fmt::Display for BadInput {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "{:#}", self.0)
    }
}

impl std::error::Error for BadInput {}

/// Wraps an input error so that `main` exits with code 2.
pub fn bad_input(e: impl Into<anyhow::Error>) -> anyhow::Error {
    anyhow::Error::new(BadInput(e.into()))
}

#[derive(Parser)]
#[command(
    name = "geostride",
    version,
    about = "Photogrammetry for people-tracking from drone video: calibration, survey, pose, trajectories",
    long_about = None
)]
pub struct Cli {
    #[command(subcommand)]
    command: Command,
}

// Parsed once per run; boxing the big variants would buy nothing.
#[allow(clippy::large_enum_variant)]
#[derive(Subcommand)]
enum Command {
    /// Bundle adjustment of a BAL problem (Bundle Adjustment in the Large)
    Ba(ba::Args),
    /// Calibrate a camera from checkerboard images, folders of images or videos
    Calibrate(calibrate::Args),
    /// Inspect and convert camera calibration files (OpenCV YAML, Metashape XML, geostride JSON)
    #[command(subcommand)]
    Camera(camera::Command),
    /// Render training tiles for the overhead person detector from the simulator, with exact
    /// boxes and head points
    Dataset(dataset::Args),
    /// Run the bundled example end to end and check it against its ground truth
    Demo(demo::Args),
    /// Find people with a neural detector (a YOLO-family ONNX model; the bundled YOLOv3-tiny
    /// by default): MOTChallenge boxes and an annotated preview
    Detect(detect::Args),
    /// Compare trajectories with the truth: position errors and tracking metrics
    Evaluate(evaluate::Args),
    /// Fit a detector's error model (detect.error_px2) to heads annotated in some frames
    FitError(fit_error::Args),
    /// Ground control targets in photos and video: found and identified automatically
    #[command(subcommand)]
    Gcp(gcp::Command),
    /// Render a simulated scene (drone video of walkers or runners) with exact ground truth
    Simulate(simulate::Args),
    /// Camera pose from ground control points: one image, or every frame of a hovering video
    Pose(pose::Args),
    /// Run a project: from a video to geolocated trajectories with their accuracy
    Run(run::Args),
    /// A finished run's views again: plots, rectified site image and the annotated video
    Render(render::Args),
    /// Split a project's run into segments for a cluster (a manifest; then `segment` for each,
    /// anywhere, and `merge`): the same outputs as `run`
    Split(cluster::SplitArgs),
    /// Run one segment of a split run (the index from --index or the batch engine's variable)
    Segment(cluster::SegmentArgs),
    /// Merge a split run's segments into the run's outputs (says which segments are missing)
    Merge(cluster::MergeArgs),
    /// Split a project's run and write (or submit) a Slurm job array and its dependent merge
    Slurm(cluster::SlurmArgs),
    /// Track people in the image only (a fixed camera, no survey): background subtraction or
    /// an external detector's boxes, then KLT
    Track(track::Args),
    /// Plan a flight: footprint, ground sample distance and error maps for a camera and altitude
    Plan(plan::Args),
    /// Structure from motion: camera poses and sparse points from overlapping photos (COLMAP
    /// text model, PLY, report)
    Sfm(sfm::Args),
    /// Read, inspect and convert ground control point surveys (RTK exports, GCP lists)
    #[command(subcommand)]
    Survey(survey::Command),
    /// Read a DJI flight telemetry subtitle file (.SRT): positions, heights, gimbal and camera
    /// settings per block, as CSV
    Telemetry(telemetry::Args),
}

impl Cli {
    pub fn run(self) -> anyhow::Result<()> {
        match self.command {
            Command::Ba(args) => ba::run(args),
            Command::Calibrate(args) => calibrate::run(args),
            Command::Camera(cmd) => camera::run(cmd),
            Command::Dataset(args) => dataset::run(args),
            Command::Demo(args) => demo::run(args),
            Command::Detect(args) => detect::run(args),
            Command::Evaluate(args) => evaluate::run(args),
            Command::FitError(args) => fit_error::run(args),
            Command::Run(args) => run::run(args),
            Command::Render(args) => render::run(args),
            Command::Split(args) => cluster::run_split(args),
            Command::Segment(args) => cluster::run_segment_cmd(args),
            Command::Merge(args) => cluster::run_merge(args),
            Command::Slurm(args) => cluster::run_slurm(args),
            Command::Track(args) => track::run(args),
            Command::Survey(cmd) => survey::run(cmd),
            Command::Telemetry(args) => telemetry::run(args),
            Command::Gcp(cmd) => gcp::run(cmd),
            Command::Plan(args) => plan::run(args),
            Command::Pose(args) if args.video.is_some() => pose_video::run(&args),
            Command::Pose(args) => pose::run(args),
            Command::Simulate(args) => simulate::run(args),
            Command::Sfm(args) => sfm::run(args),
        }
    }
}

/// Parses `COLSxROWS` (inner corners), e.g. `9x6`.
pub(crate) fn parse_board_size(s: &str) -> Result<(u32, u32), String> {
    let (c, r) = s
        .split_once(['x', 'X'])
        .ok_or_else(|| format!("expected COLSxROWS of inner corners, e.g. 9x6; got '{s}'"))?;
    let parse = |t: &str| {
        t.trim()
            .parse::<u32>()
            .map_err(|_| format!("expected whole numbers in COLSxROWS, e.g. 9x6; got '{s}'"))
    };
    let (c, r) = (parse(c)?, parse(r)?);
    if c < 3 || r < 3 {
        return Err(format!(
            "a board needs at least 3x3 inner corners; got {c}x{r}"
        ));
    }
    Ok((c, r))
}

/// A positive finite number.
pub(crate) fn parse_positive(s: &str) -> Result<f64, String> {
    match s.parse::<f64>() {
        Ok(v) if v > 0.0 && v.is_finite() => Ok(v),
        _ => Err(format!("expected a positive number, got '{s}'")),
    }
}

/// An unusable output path is the user's to fix (exit 2); an I/O failure on it is not (exit 1).
pub(crate) fn output_error(e: geostride::io::OutputError) -> anyhow::Error {
    match e {
        geostride::io::OutputError::Io { .. } => anyhow::Error::new(e),
        _ => bad_input(e),
    }
}

/// A calibration not written: exit 2 when the calibration or the name is the problem, 1 when the
/// file system failed.
pub(crate) fn write_error(e: formats::WriteError) -> anyhow::Error {
    match e {
        formats::WriteError::Format(f) => bad_input(f),
        io => anyhow::Error::new(io),
    }
}

/// Refuses, before any work, an output file that is a folder, whose folder does not exist, or
/// that would replace one of `inputs`.
pub(crate) fn check_output_file<P: AsRef<Path>>(
    out: &Path,
    inputs: impl IntoIterator<Item = P>,
) -> anyhow::Result<()> {
    Inputs::with_folders(inputs)
        .check_file(out)
        .map_err(output_error)
}

/// Refuses, before any work, an output folder that is a file or holds one of `inputs`, without
/// making it: the guard then makes it ([`Inputs::create_dir`]) once the command's own checks
/// passed, so that a refused command leaves no folder behind.
pub(crate) fn check_output_dir<P: AsRef<Path>>(
    out: &Path,
    inputs: impl IntoIterator<Item = P>,
) -> anyhow::Result<Inputs> {
    // A folder given as an input is read as a whole: nothing goes inside it.
    let guard = Inputs::with_folders(inputs);
    guard.check_dir(out).map_err(output_error)?;
    Ok(guard)
}

/// Creates an output folder, refusing, before any work, a file or a folder that holds one of
/// `inputs`; clears the temporary files a killed run left in it.
pub(crate) fn create_output_dir<P: AsRef<Path>>(
    out: &Path,
    inputs: impl IntoIterator<Item = P>,
) -> anyhow::Result<()> {
    Inputs::with_folders(inputs)
        .create_dir(out)
        .map_err(output_error)
}

/// `WIDTHxHEIGHT` in pixels, e.g. `3840x2160`.
pub(crate) fn parse_size(s: &str) -> Result<(u32, u32), String> {
    let bad = || {
        format!(
            "expected WIDTHxHEIGHT in pixels from 1 to {}, e.g. 3840x2160; got '{}'",
            geostride::camera::MAX_IMAGE_SIDE,
            geostride::io::clip(s, 40)
        )
    };
    let (w, h) = s.split_once(['x', 'X']).ok_or_else(bad)?;
    let side = 1..=geostride::camera::MAX_IMAGE_SIDE;
    match (w.parse::<u32>(), h.parse::<u32>()) {
        (Ok(w), Ok(h)) if side.contains(&w) && side.contains(&h) => Ok((w, h)),
        _ => Err(bad()),
    }
}

/// A progress bar on stderr with a template, or a hidden one when `quiet`.
pub(crate) fn progress_bar(quiet: bool, len: u64, template: &str) -> indicatif::ProgressBar {
    if quiet {
        return indicatif::ProgressBar::hidden();
    }
    let b = indicatif::ProgressBar::with_draw_target(
        Some(len),
        indicatif::ProgressDrawTarget::stderr(),
    );
    b.set_style(indicatif::ProgressStyle::with_template(template).expect("progress template"));
    b
}

/// A progress bar per stage of a run (`run`, `demo`).
pub(crate) struct StageBars {
    pub quiet: bool,
}

impl geostride::pipeline::run::StageProgress for StageBars {
    fn stage(&self, name: &str) -> Box<dyn geostride::progress::Progress> {
        Box::new(progress_bar(
            self.quiet,
            0,
            &format!("{name:>7} {{bar:40}} {{pos}}/{{len}} [{{elapsed_precise}}<{{eta_precise}}]"),
        ))
    }

    /// For the tests of interrupted runs: `GEOSTRIDE_TEST_KILL_AFTER=STAGE` dies like a killed
    /// process right after that stage is stored.
    fn stored(&self, stage: &str) {
        if std::env::var("GEOSTRIDE_TEST_KILL_AFTER").is_ok_and(|s| s == stage) {
            std::process::abort();
        }
    }
}

/// A preset by name or a calibration file.
pub(crate) fn load_camera(spec: &str) -> anyhow::Result<(Camera, String)> {
    if let Some(cal) = presets::preset(spec) {
        return Ok((cal.camera, format!("preset {spec} (nominal)")));
    }
    let path = Path::new(spec);
    if !path.exists() {
        return Err(bad_input(anyhow!(
            "--camera '{spec}' is neither a preset ({}) nor a file",
            presets::names().join(", ")
        )));
    }
    let cal = formats::read(path, None).map_err(bad_input)?;
    Ok((cal.camera, spec.to_string()))
}

/// The camera scaled to another resolution of the same aspect ratio.
pub(crate) fn scale_to(camera: Camera, w: u32, h: u32) -> anyhow::Result<Camera> {
    let size = camera
        .image_size
        .ok_or_else(|| bad_input(anyhow!("the camera has no image size to scale from")))?;
    camera.scaled_to(w, h).ok_or_else(|| {
        bad_input(anyhow!(
            "video mode {w}x{h} has another aspect ratio than the camera's {}x{}: the sensor crop is unknown; use a calibration made in that mode",
            size.width,
            size.height
        ))
    })
}

/// A number from 0 to 1.
pub(crate) fn parse_fraction(s: &str) -> Result<f64, String> {
    match s.parse::<f64>() {
        Ok(v) if (0.0..=1.0).contains(&v) => Ok(v),
        _ => Err(format!("expected a fraction from 0 to 1, got '{s}'")),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn board_sizes() {
        assert_eq!(parse_board_size("9x6"), Ok((9, 6)));
        assert_eq!(parse_board_size("7X5"), Ok((7, 5)));
        assert!(parse_board_size("9").is_err());
        assert!(parse_board_size("2x6").is_err());
        assert!(parse_board_size("ax6").is_err());
    }

    #[test]
    fn every_option_is_documented() {
        use clap::CommandFactory;
        let cmd = Cli::command();
        fn walk(cmd: &clap::Command) {
            for arg in cmd.get_arguments() {
                if arg.get_id() == "help" || arg.get_id() == "version" {
                    continue;
                }
                assert!(
                    arg.get_help().is_some(),
                    "{} --{} has no help text",
                    cmd.get_name(),
                    arg.get_id()
                );
            }
            for sub in cmd.get_subcommands() {
                walk(sub);
            }
        }
        walk(&cmd);
        cmd.debug_assert();
    }
}
