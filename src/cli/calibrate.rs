//! `geostride calibrate`.

use std::fmt::Write as _;
use std::path::PathBuf;

use anyhow::{Context, anyhow};
use clap::ValueEnum;

use super::{bad_input, check_output_file, parse_board_size, parse_fraction, parse_positive};
use geostride::calibration::detect::{DetectSettings, Detector};
use geostride::calibration::inputs::{CollectSettings, InputError, InputLog, collect};
use geostride::calibration::{CalibrationError, CalibrationResult, Options, calibrate};
use geostride::camera::formats::{self, Format};
use geostride::camera::{BoardSpec, PARAM_NAMES};
use geostride::optim::LmSettings;

#[derive(Clone, Copy, Debug, ValueEnum)]
pub enum DetectorArg {
    /// findChessboardCorners + cornerSubPix (OpenCV's calibration sample)
    Classic,
    /// findChessboardCornersSB (sector-based; copes better with blur and noise)
    Sb,
}

#[derive(Clone, Copy, Debug, ValueEnum)]
pub enum FormatArg {
    /// OpenCV FileStorage YAML (camera_matrix, distortion_coefficients, ...)
    OpencvYaml,
    /// Agisoft Metashape calibration XML
    MetashapeXml,
    /// geostride JSON with the full parameter covariance
    Json,
    /// Tsai calibration, XML or 19 numbers (read only; PETS 2009, ETH)
    Tsai,
}

impl From<FormatArg> for Format {
    fn from(f: FormatArg) -> Format {
        match f {
            FormatArg::OpencvYaml => Format::OpenCvYaml,
            FormatArg::MetashapeXml => Format::Metashape,
            FormatArg::Json => Format::Json,
            FormatArg::Tsai => Format::Tsai,
        }
    }
}

#[derive(clap::Args)]
#[command(after_help = "\
Examples:
  geostride calibrate --board 9x6 --square 0.025 --fix-aspect -o camera.yaml boards/
  geostride calibrate --board 9x6 --square 0.039 --every 15 -o camera.json board-video.mp4

Outputs: .yaml/.yml OpenCV YAML, .json geostride JSON (with the covariance), .xml Metashape XML.
Exit codes: 0 success, 2 bad input or usage, 1 failure while running.")]
pub struct Args {
    /// Inner corners of the board as COLSxROWS (a board of 10x7 squares has 9x6 inner corners)
    #[arg(long, value_parser = parse_board_size, value_name = "COLSxROWS")]
    board: (u32, u32),
    /// Side of one square, in metres
    #[arg(long, value_parser = parse_positive, value_name = "METRES")]
    square: f64,
    /// Output calibration file; the format follows the extension unless --format is given
    #[arg(short, long, value_name = "FILE")]
    output: Option<PathBuf>,
    /// Output format, overriding the extension
    #[arg(long, value_enum)]
    format: Option<FormatArg>,
    /// Images, folders of images (non-recursive) and videos
    #[arg(required = true, value_name = "INPUTS")]
    inputs: Vec<PathBuf>,
    /// Hold fx/fy at --aspect-ratio (OpenCV's CALIB_FIX_ASPECT_RATIO)
    #[arg(long)]
    fix_aspect: bool,
    /// The fx/fy ratio held by --fix-aspect
    #[arg(long, default_value_t = 1.0, value_parser = parse_positive, value_name = "R")]
    aspect_ratio: f64,
    /// Hold the principal point at the image centre (CALIB_FIX_PRINCIPAL_POINT)
    #[arg(long)]
    fix_principal_point: bool,
    /// Hold the tangential distortion p1, p2 at zero (CALIB_ZERO_TANGENT_DIST)
    #[arg(long)]
    zero_tangential: bool,
    /// Number of polynomial radial terms to estimate: 0 to 3 (k1, k2, k3)
    #[arg(long, default_value_t = 3, value_parser = clap::value_parser!(u8).range(0..=3), value_name = "N")]
    radial_terms: u8,
    /// Also estimate the rational terms k4, k5, k6 (CALIB_RATIONAL_MODEL)
    #[arg(long)]
    rational: bool,
    /// Flag views whose RMS exceeds this multiple of the median view RMS
    #[arg(long, default_value_t = 3.0, value_parser = parse_positive, value_name = "F")]
    outlier_factor: f64,
    /// Recalibrate without the flagged views (at least 3 views are kept)
    #[arg(long)]
    drop_outliers: bool,
    /// Corner detector
    #[arg(long, value_enum, default_value_t = DetectorArg::Classic)]
    detector: DetectorArg,
    /// Half-size of the cornerSubPix window in pixels (OpenCV's calibration sample uses 11)
    #[arg(long, default_value_t = 11, value_parser = clap::value_parser!(i32).range(2..=50), value_name = "PX")]
    subpix_window: i32,
    /// Shrink the cornerSubPix window per image so that it stays inside one square (matters when
    /// the squares are narrower than about twice the window; see docs/calibration.md)
    #[arg(long)]
    cap_subpix_window: bool,
    /// cornerSubPix stops when a corner moves less than this, in pixels
    #[arg(long, default_value_t = 0.001, value_parser = parse_positive, value_name = "PX")]
    subpix_eps: f64,
    /// Videos: use every N-th frame
    #[arg(long, default_value_t = 10, value_parser = clap::value_parser!(u32).range(1..), value_name = "N")]
    every: u32,
    /// Videos: skip frames whose sharpness (variance of the Laplacian) is below this fraction of the median
    #[arg(long, default_value_t = 0.5, value_parser = parse_fraction, value_name = "F")]
    blur_fraction: f64,
    /// Videos: skip views whose corners moved less than this mean distance in pixels from an
    /// accepted view [default: 1 % of the image diagonal]
    #[arg(long, value_parser = parse_positive, value_name = "PX")]
    min_motion: Option<f64>,
    /// Most Levenberg–Marquardt iterations
    #[arg(long, default_value_t = 100, value_name = "N")]
    max_iterations: usize,
    /// Print the result as JSON on stdout instead of the summary table
    #[arg(long)]
    json: bool,
    /// No progress bar
    #[arg(short, long)]
    quiet: bool,
}

/// Everything `calibrate` needs, shared with `demo`.
pub(crate) struct Job {
    pub inputs: Vec<PathBuf>,
    pub board: BoardSpec,
    pub options: Options,
    pub collect: CollectSettings,
    pub drop_outliers: bool,
    pub quiet: bool,
}

pub(crate) struct Outcome {
    pub result: CalibrationResult,
    pub log: InputLog,
}

/// Collects views and calibrates; input problems are [`bad_input`] errors.
pub(crate) fn run_job(job: &Job) -> anyhow::Result<Outcome> {
    let bar = super::progress_bar(
        job.quiet,
        0,
        "{spinner} detecting corners {bar:30} {pos}/{len} {msg} ({eta})",
    );
    let collected = collect(&job.inputs, &job.board, &job.collect, &bar).map_err(|e| match e {
        InputError::OpenCv { .. } => anyhow!(e),
        other => bad_input(other),
    })?;
    bar.finish_and_clear();
    let log = collected.log;
    for u in &log.unreadable {
        eprintln!("warning: skipped unreadable image {u}");
    }
    for w in &log.wrong_size {
        eprintln!("warning: skipped {w}: its size differs from the first image's");
    }
    let b = &job.board;
    let Some(size) = collected.image_size else {
        return Err(bad_input(anyhow!(
            "none of the {} input(s) could be read as an image or video",
            log.tried.max(job.inputs.len())
        )));
    };
    if collected.views.is_empty() {
        return Err(bad_input(anyhow!(
            "the {}x{} board was not found in any of the {} image(s)/frame(s) tried. --board counts \
             inner corners (a board of 10x7 squares is 9x6); check the count, that the whole board \
             is in view, and try --detector sb",
            b.cols,
            b.rows,
            log.tried
        )));
    }
    let result = calibrate(&collected.views, b, size, &job.options, job.drop_outliers).map_err(
        |e| match e {
            CalibrationError::Optimisation(_) => anyhow!(e),
            other => bad_input(anyhow!(
                "{other} (the board was found in {} of {} image(s)/frame(s) tried)",
                collected.views.len(),
                log.tried
            )),
        },
    )?;
    Ok(Outcome { result, log })
}

pub fn run(args: Args) -> anyhow::Result<()> {
    let job = Job {
        inputs: args.inputs,
        board: BoardSpec {
            cols: args.board.0,
            rows: args.board.1,
            square_m: args.square,
        },
        options: Options {
            fix_aspect: args.fix_aspect.then_some(args.aspect_ratio),
            fix_principal_point: args.fix_principal_point,
            zero_tangential: args.zero_tangential,
            radial_terms: usize::from(args.radial_terms),
            rational: args.rational,
            outlier_factor: args.outlier_factor,
            lm: LmSettings {
                max_iterations: args.max_iterations,
                ..LmSettings::default()
            },
        },
        collect: CollectSettings {
            detect: DetectSettings {
                detector: match args.detector {
                    DetectorArg::Classic => Detector::Classic,
                    DetectorArg::Sb => Detector::SectorBased,
                },
                subpix_window: args.subpix_window,
                cap_window: args.cap_subpix_window,
                subpix_eps: args.subpix_eps,
                fast_check: false,
            },
            every: args.every as usize,
            blur_fraction: args.blur_fraction,
            min_motion_px: args.min_motion,
        },
        drop_outliers: args.drop_outliers,
        quiet: args.quiet || args.json,
    };
    // Refuse an unwritable output format before the work, not after it.
    let format = match &args.output {
        Some(p) => {
            Some(formats::output_format(p, args.format.map(Format::from)).map_err(bad_input)?)
        }
        None => args.format.map(Format::from),
    };
    if let Some(out) = &args.output {
        // The folders' images too: an output named like one of them would replace it.
        let files = geostride::calibration::inputs::expand(&job.inputs).map_err(bad_input)?;
        check_output_file(out, job.inputs.iter().chain(&files))?;
    }
    let outcome = run_job(&job)?;
    let written = match &args.output {
        Some(path) => {
            let cal = outcome.result.to_calibration();
            formats::write(&cal, path, format).map_err(super::write_error)?;
            Some((path.clone(), format.expect("format chosen with the output")))
        }
        None => None,
    };
    if args.json {
        let report = outcome.result.json_report();
        println!(
            "{}",
            serde_json::to_string_pretty(&report).context("serialising the report")?
        );
    } else {
        print!("{}", summary(&outcome.result, &outcome.log));
        match written {
            Some((p, f)) => println!("Written: {} ({})", p.display(), f.name()),
            None => println!("No output file written (use -o FILE)."),
        }
    }
    Ok(())
}

/// The human-readable report.
pub(crate) fn summary(r: &CalibrationResult, log: &InputLog) -> String {
    let mut s = String::new();
    let c = &r.camera;
    let _ = writeln!(
        s,
        "Calibrated from {} view(s) of the {}x{} board ({} m squares), images {}x{} px",
        r.views.len(),
        r.board.cols,
        r.board.rows,
        r.board.square_m,
        r.image_size.width,
        r.image_size.height
    );
    let _ = writeln!(
        s,
        "  inputs: {} image(s)/frame(s) tried, board found and used in {}; not found {}, unreadable {}, other size {}, blurred {}, near-duplicate {}",
        log.tried,
        log.used,
        log.no_board.len(),
        log.unreadable.len(),
        log.wrong_size.len(),
        log.blurred.len(),
        log.duplicates.len()
    );
    if !log.no_board.is_empty() && log.no_board.len() <= 10 {
        let _ = writeln!(s, "  board not found in: {}", log.no_board.join(", "));
    }
    if !r.dropped.is_empty() {
        let _ = writeln!(
            s,
            "  dropped as outliers and recalibrated without: {}",
            r.dropped.join(", ")
        );
    }
    let _ = writeln!(s, "\n  parameter          value       std dev");
    let sd = r.std_devs();
    let p = c.params();
    for (i, name) in PARAM_NAMES.iter().enumerate() {
        let fixed = !r.free_parameters.contains(name);
        if fixed && p[i] == 0.0 {
            continue;
        }
        let unit = if i < 5 { "px" } else { "  " };
        if fixed {
            let _ = writeln!(s, "  {name:<6} {:>16.6} {unit}   (fixed)", p[i]);
        } else {
            let _ = writeln!(s, "  {name:<6} {:>16.6} {unit}   ±{:.6}", p[i], sd[i]);
        }
    }
    let _ = writeln!(
        s,
        "\n  RMS reprojection error {:.4} px (σ per coordinate {:.4} px); {} iterations, {}",
        r.rms_px, r.sigma_px, r.iterations, r.termination
    );
    let _ = writeln!(
        s,
        "\n  view                              RMS px   max px   rvec (rad)                tvec (m)"
    );
    for v in &r.views {
        let rv = v.cam_from_board.rvec();
        let t = v.cam_from_board.translation;
        let _ = writeln!(
            s,
            "  {:<32} {:>7.3} {:>8.3}   [{:+.3} {:+.3} {:+.3}]  [{:+.3} {:+.3} {:+.3}]{}",
            truncate(&v.name, 32),
            v.rms_px,
            v.max_px,
            rv.x,
            rv.y,
            rv.z,
            t.x,
            t.y,
            t.z,
            if v.outlier { "  OUTLIER" } else { "" }
        );
    }
    let n_out = r.views.iter().filter(|v| v.outlier).count();
    if n_out > 0 {
        let _ = writeln!(
            s,
            "  {n_out} view(s) flagged as outliers (RMS above the outlier factor times the median); \
             --drop-outliers recalibrates without them"
        );
    }
    let _ = writeln!(
        s,
        "\n  Corner coverage: {:.0} % of the image ({}x{} grid; distortion is only known where corners were):",
        r.coverage.percent(),
        r.coverage.cols,
        r.coverage.rows
    );
    s.push_str(&r.coverage.ascii_map());
    if !r.termination.converged() {
        let _ = writeln!(
            s,
            "  warning: the solver stopped before converging ({}); raise --max-iterations",
            r.termination
        );
    }
    s
}

fn truncate(s: &str, n: usize) -> String {
    if s.chars().count() <= n {
        s.to_string()
    } else {
        let tail: String = s
            .chars()
            .rev()
            .take(n - 1)
            .collect::<Vec<_>>()
            .into_iter()
            .rev()
            .collect();
        format!("…{tail}")
    }
}
