//! `geostride sfm IMAGES-OR-FOLDERS... --camera CAL --out DIR`: structure from motion.

use std::path::{Path, PathBuf};

use anyhow::anyhow;

use super::survey::{ReadArgs, read_framed, read_other};
use super::{bad_input, check_output_dir, load_camera, output_error, progress_bar};
use geostride::sfm::FeatureSettings;
use geostride::sfm::georef::GeorefSettings;
use geostride::sfm::job::{
    CrsPositions, GeorefInput, NamedCentre, SfmJob, SfmJobError, SfmRun, ground_points, run_sfm,
    write_outputs,
};
use geostride::sfm::matching::MatchSettings;
use geostride::sfm::reconstruct::SfmSettings;
use geostride::survey::frame::SiteFrame;
use geostride::survey::gis::{CameraPoint, write_cameras};
use nalgebra::Vector3;

#[derive(clap::Args)]
#[command(args_conflicts_with_subcommands = true, subcommand_negates_reqs = true)]
pub struct Args {
    #[command(subcommand)]
    command: Option<SfmCommand>,
    /// Images, or folders of images (JPEG, PNG, TIFF; a folder's images in name order)
    #[arg(required = true, value_name = "IMAGES-OR-FOLDERS")]
    inputs: Vec<PathBuf>,
    /// The camera of every image: a calibration file or a preset [default: a pinhole whose focal
    /// length starts from the EXIF (its 35 mm equivalent, else the focal length on the sensor's
    /// pixel pitch), else from 1.2 times the image's longer side, refined]
    #[arg(long, value_name = "CAL")]
    camera: Option<String>,
    /// Refine the focal lengths and the first two radial terms as the model grows (a calibration
    /// known only roughly)
    #[arg(long)]
    refine_intrinsics: bool,
    /// Ordered photos or frames: match each image with the next N only (name order) instead of
    /// every other or its GPS neighbours
    #[arg(long, value_name = "N")]
    sequential: Option<usize>,
    /// With a position for every photo (--centres, else the EXIF GPS): match each with its N
    /// nearest (horizontally) instead of every other
    #[arg(long, default_value = "8", value_name = "N")]
    neighbours: usize,
    /// Features per image at most
    #[arg(long, default_value = "8192", value_name = "N")]
    max_features: usize,
    /// Ground control and check points with their pixel picks: a survey file (Emlid CSV,
    /// OpenDroneMap gcp_list.txt with its picks, Metashape CSV, ...; more picks with --picks).
    /// The model is placed in the survey's site frame and adjusted with it
    #[arg(long, value_name = "FILE")]
    gcps: Option<PathBuf>,
    #[command(flatten)]
    read: ReadArgs,
    /// Camera centres measured in flight (RTK, PPK): a survey-format file whose point names are
    /// the image names, in the CRS of --gcps; priors of the adjustment (alone they place the
    /// model too)
    #[arg(long, value_name = "FILE")]
    centres: Option<PathBuf>,
    /// σ of picks that do not state one, pixels
    #[arg(long, default_value = "1.0", value_parser = super::parse_positive, value_name = "PX")]
    pick_sigma: f64,
    /// σ of surveyed points that do not state one (each axis), metres
    #[arg(long, default_value = "0.02", value_parser = super::parse_positive, value_name = "M")]
    gcp_sigma: f64,
    /// σ of camera centres that do not state one: horizontal,vertical metres
    #[arg(
        long,
        default_value = "0.03,0.05",
        value_delimiter = ',',
        value_name = "H,V"
    )]
    centre_sigma: Vec<f64>,
    /// Output folder: COLMAP text model, points.ply, cameras.csv (and cameras.gpkg when
    /// georeferenced), topview.png, report.json, report.md
    #[arg(long, value_name = "DIR", required = true)]
    out: Option<PathBuf>,
    /// Print the report as JSON
    #[arg(long)]
    json: bool,
    /// No progress bars
    #[arg(short, long)]
    quiet: bool,
}

const IMAGE_EXTENSIONS: [&str; 5] = ["jpg", "jpeg", "png", "tif", "tiff"];

/// The images named, folders expanded to their images in name order.
fn list_images(inputs: &[PathBuf]) -> anyhow::Result<Vec<PathBuf>> {
    let mut out = Vec::new();
    for p in inputs {
        if p.is_dir() {
            let mut found: Vec<PathBuf> = std::fs::read_dir(p)
                .map_err(|e| bad_input(anyhow!("{}: {e}", p.display())))?
                .flatten()
                .map(|e| e.path())
                .filter(|f| {
                    f.is_file()
                        && f.extension().is_some_and(|e| {
                            IMAGE_EXTENSIONS.contains(&e.to_string_lossy().to_lowercase().as_str())
                        })
                })
                .collect();
            found.sort();
            if found.is_empty() {
                return Err(bad_input(anyhow!(
                    "{}: no images in this folder (looked for .jpg, .jpeg, .png, .tif, .tiff)",
                    p.display()
                )));
            }
            out.extend(found);
        } else if p.is_file() {
            out.push(p.clone());
        } else {
            return Err(bad_input(anyhow!(
                "{}: no such file or folder",
                p.display()
            )));
        }
    }
    Ok(out)
}

#[derive(clap::Subcommand)]
enum SfmCommand {
    /// Register more images in an existing model (its frame, its points held): their poses
    Register(RegisterArgs),
    /// Georeference a COLMAP model (text or binary) with GCPs and their picks: the same
    /// GCP-constrained adjustment, check points and camera σ as `geostride sfm --gcps`; the model
    /// written back in COLMAP's format in the survey's site frame
    Georef(GeorefArgs),
    /// Convert a COLMAP model between text and binary, byte for byte as `colmap
    /// model_converter` does
    Convert(ConvertArgs),
}

#[derive(clap::Args)]
struct ConvertArgs {
    /// The COLMAP model folder (cameras, images, points3D; .bin or .txt)
    #[arg(value_name = "MODEL_DIR")]
    model: PathBuf,
    /// Format written
    #[arg(long, value_enum, value_name = "FORMAT")]
    output_type: OutputType,
    /// Output folder (created; its model files replaced)
    #[arg(long, value_name = "DIR")]
    out: PathBuf,
}

/// `geostride sfm convert MODEL_DIR --output-type txt|bin --out DIR`.
fn run_convert_cli(args: ConvertArgs) -> anyhow::Result<()> {
    use geostride::sfm::colmap_model::{ModelFormat, read_model_dir};
    let (model, _) = read_model_dir(&args.model).map_err(bad_input)?;
    let format = match args.output_type {
        OutputType::Txt => ModelFormat::Text,
        OutputType::Bin => ModelFormat::Binary,
    };
    if args.out.canonicalize().ok() == args.model.canonicalize().ok()
        && geostride::sfm::colmap_model::detect_format(&args.model) == Some(format)
    {
        return Err(bad_input(anyhow!(
            "{}: the output folder is the model's and the format its own: give another --out",
            args.out.display()
        )));
    }
    std::fs::create_dir_all(&args.out)
        .map_err(|e| anyhow!("{}: cannot create it: {e}", args.out.display()))?;
    let written = model
        .write(&args.out, format)
        .map_err(|e| anyhow!("{}: {e}", args.out.display()))?;
    println!(
        "{} cameras, {} images, {} points",
        model.cameras.len(),
        model.images.len(),
        model.points.len()
    );
    for f in written {
        println!("Written: {}", args.out.join(f).display());
    }
    Ok(())
}

#[derive(clap::Args)]
struct GeorefArgs {
    /// The COLMAP model folder (cameras, images, points3D; .bin or .txt), e.g. sparse/0
    #[arg(value_name = "MODEL_DIR")]
    model: PathBuf,
    /// Ground control and check points with their pixel picks (as for `geostride sfm --gcps`);
    /// picks name the model's images (file name, or file name without extension)
    #[arg(long, value_name = "FILE", required = true)]
    gcps: Option<PathBuf>,
    #[command(flatten)]
    read: ReadArgs,
    /// Camera centres measured in flight (RTK, PPK), named after the images, in the CRS of
    /// --gcps: priors of the adjustment
    #[arg(long, value_name = "FILE")]
    centres: Option<PathBuf>,
    /// σ of picks that do not state one, pixels
    #[arg(long, default_value = "1.0", value_parser = super::parse_positive, value_name = "PX")]
    pick_sigma: f64,
    /// σ of surveyed points that do not state one (each axis), metres
    #[arg(long, default_value = "0.02", value_parser = super::parse_positive, value_name = "M")]
    gcp_sigma: f64,
    /// σ of camera centres that do not state one: horizontal,vertical metres
    #[arg(
        long,
        default_value = "0.03,0.05",
        value_delimiter = ',',
        value_name = "H,V"
    )]
    centre_sigma: Vec<f64>,
    /// Format of the model written [default: the input's]
    #[arg(long, value_enum, value_name = "FORMAT")]
    output_type: Option<OutputType>,
    /// Output folder: the COLMAP model in the site frame, points.ply, cameras.csv (and
    /// cameras.gpkg with a CRS), report.json, report.md
    #[arg(long, value_name = "DIR")]
    out: PathBuf,
    /// Print the report as JSON
    #[arg(long)]
    json: bool,
}

#[derive(Clone, Copy, clap::ValueEnum)]
enum OutputType {
    /// cameras.txt, images.txt, points3D.txt
    Txt,
    /// cameras.bin, images.bin, points3D.bin
    Bin,
}

#[derive(clap::Args)]
struct RegisterArgs {
    /// The model: a folder `geostride sfm` wrote (cameras.txt, images.txt, points3D.txt)
    #[arg(value_name = "MODEL")]
    model: PathBuf,
    /// Images, or folders of images, to register
    #[arg(required_unless_present = "video", value_name = "IMAGES-OR-FOLDERS")]
    inputs: Vec<PathBuf>,
    /// Or frames of a video: every --every-th, named VIDEO#FRAME
    #[arg(long, value_name = "VIDEO", conflicts_with = "inputs")]
    video: Option<PathBuf>,
    /// With --video: register every N-th frame (from frame 0)
    #[arg(long, default_value = "25", value_name = "N", requires = "video")]
    every: usize,
    /// The camera of the new images (a video's): a calibration file or a preset [default: the
    /// model's]
    #[arg(long, value_name = "CAL")]
    camera: Option<String>,
    /// Where the model's images are [default: the folder of the first image given; with
    /// --video, required]
    #[arg(long, value_name = "DIR")]
    model_images: Option<PathBuf>,
    /// Features per image at most [default: the model's, from its report.json]
    #[arg(long, value_name = "N")]
    max_features: Option<usize>,
    /// Model images each image is matched with, nearest by EXIF GPS (all without GPS)
    #[arg(long, default_value = "8", value_name = "N")]
    neighbours: usize,
    /// Output folder: cameras.csv, report.json, report.md
    #[arg(long, value_name = "DIR")]
    out: PathBuf,
    /// Print the report as JSON
    #[arg(long)]
    json: bool,
    /// No progress bars
    #[arg(short, long)]
    quiet: bool,
}

/// The progress bars of the features and matching stages.
fn stage_bars(quiet: bool) -> (indicatif::ProgressBar, indicatif::ProgressBar) {
    (
        progress_bar(
            quiet,
            0,
            "{spinner} features {bar:30} {pos}/{len} images ({eta})",
        ),
        progress_bar(
            quiet,
            0,
            "{spinner} matching {bar:30} {pos}/{len} pairs ({eta})",
        ),
    )
}

/// An error as the command's: exit 2 when the inputs are at fault.
fn exit_for<E: std::error::Error + Send + Sync + 'static>(e: E, input: bool) -> anyhow::Error {
    if input {
        bad_input(e)
    } else {
        anyhow::Error::new(e)
    }
}

use geostride::sfm::reference::model_max_features;

fn run_register_cli(args: RegisterArgs) -> anyhow::Result<()> {
    use geostride::sfm::register_job::{RegisterJob, run_register, write_register_outputs};
    let images = if args.video.is_some() {
        Vec::new()
    } else {
        list_images(&args.inputs)?
    };
    let model_images = match (&args.model_images, images.first()) {
        (Some(d), _) => d.clone(),
        (None, Some(first)) => first
            .parent()
            .map(Path::to_path_buf)
            .unwrap_or_else(|| PathBuf::from(".")),
        (None, None) => {
            return Err(bad_input(anyhow!(
                "--video needs --model-images DIR: the folder of the model's photos"
            )));
        }
    };
    if let Some(v) = &args.video
        && !v.is_file()
    {
        return Err(bad_input(anyhow!("{}: no such video", v.display())));
    }
    if args.every == 0 {
        return Err(bad_input(anyhow!(
            "--every 0: register every N-th frame, N ≥ 1"
        )));
    }
    let camera = match &args.camera {
        Some(spec) => Some(load_camera(spec)?.0),
        None => None,
    };
    if !args.model.join("images.txt").is_file() {
        return Err(bad_input(anyhow!(
            "{}: not a model folder (no images.txt): give the --out folder of `geostride sfm`",
            args.model.display()
        )));
    }
    if args.max_features.is_some_and(|n| n < 100) {
        return Err(bad_input(anyhow!(
            "--max-features {}: too few to match images (the model's own is the default)",
            args.max_features.unwrap_or_default()
        )));
    }
    let inputs: Vec<&Path> = images
        .iter()
        .map(PathBuf::as_path)
        .chain([args.model.as_path(), model_images.as_path()])
        .chain(
            args.inputs
                .iter()
                .filter(|p| p.is_dir())
                .map(PathBuf::as_path),
        )
        .chain(args.video.iter().map(PathBuf::as_path))
        .collect();
    let guard = check_output_dir(&args.out, inputs)?;
    let job = RegisterJob {
        model_dir: args.model.clone(),
        model_images,
        images,
        video: args.video.clone().map(|v| (v, args.every)),
        camera,
        neighbours: args.neighbours,
        features: FeatureSettings {
            max_features: args
                .max_features
                .unwrap_or_else(|| model_max_features(&args.model)),
            ..FeatureSettings::default()
        },
        matching: MatchSettings::default(),
        settings: Default::default(),
        cache_dir: Some(args.out.join("cache")),
    };
    let (features, matching) = stage_bars(args.quiet || args.json);
    let run = run_register(&job, &features, &matching).map_err(|e| {
        let input = e.is_input();
        exit_for(e, input)
    })?;
    features.finish_and_clear();
    matching.finish_and_clear();
    guard.create_dir(&args.out).map_err(output_error)?;
    let written = write_register_outputs(&args.out, &run)
        .map_err(|e| anyhow!("{}: {e}", args.out.display()))?;
    let r = &run.report;
    if args.json {
        println!("{}", serde_json::to_string_pretty(r)?);
        return Ok(());
    }
    println!(
        "Registered {} of {} images in the model of {} images (frame: {})",
        r.registered, r.images, r.model_images, r.frame
    );
    for i in &r.per_image {
        match (&i.pose, &i.reason) {
            (Some(_), _) => println!(
                "  {}: {} of {} correspondences, {:.3} px RMS",
                i.name,
                i.inliers,
                i.correspondences,
                i.rms_px.unwrap_or(f64::NAN)
            ),
            (None, reason) => println!(
                "  not registered: {}: {}",
                i.name,
                reason.as_deref().unwrap_or("")
            ),
        }
    }
    for f in written {
        println!("Written: {}", args.out.join(f).display());
    }
    Ok(())
}

/// What `geostride sfm` built and wrote.
pub(super) struct Built {
    pub run: geostride::sfm::job::SfmRun,
    pub written: Vec<String>,
    pub camera_source: String,
    pub out: PathBuf,
}

/// `geostride sfm IMAGES...` without its printout: the model built and its files written.
pub(super) fn build(args: &Args) -> anyhow::Result<Built> {
    let out = args.out.clone().expect("clap requires --out");
    let images = list_images(&args.inputs)?;
    if images.len() < 2 {
        return Err(bad_input(anyhow!(
            "structure from motion needs at least two overlapping images, got {}",
            images.len()
        )));
    }
    let (camera, camera_source) = match &args.camera {
        Some(spec) => {
            let (c, s) = load_camera(spec)?;
            (Some(c), s)
        }
        None => (None, String::new()),
    };
    if args.sequential == Some(0) {
        return Err(bad_input(anyhow!(
            "--sequential 0: give the number of following images to match each with (1 or more)"
        )));
    }
    if args.max_features < 100 {
        return Err(bad_input(anyhow!(
            "--max-features {}: too few to match images (8192 is the default)",
            args.max_features
        )));
    }
    if args.centre_sigma.len() != 2
        || args
            .centre_sigma
            .iter()
            .any(|v| !(*v > 0.0 && v.is_finite()))
    {
        return Err(bad_input(anyhow!(
            "--centre-sigma {:?}: two positive numbers, horizontal,vertical metres",
            args.centre_sigma
        )));
    }
    if args.gcps.is_none() && !args.read.picks.is_empty() {
        return Err(bad_input(anyhow!(
            "--picks needs --gcps: the picks' points and their coordinates come from the GCP file"
        )));
    }
    let (georef, frame) = georef_input(&args)?;
    let inputs: Vec<&Path> = images
        .iter()
        .map(PathBuf::as_path)
        .chain(args.camera.iter().map(Path::new))
        .chain(args.gcps.iter().map(PathBuf::as_path))
        .chain(args.centres.iter().map(PathBuf::as_path))
        .chain(args.read.picks.iter().map(PathBuf::as_path))
        .chain(
            args.inputs
                .iter()
                .filter(|p| p.is_dir())
                .map(PathBuf::as_path),
        )
        .collect();
    let guard = check_output_dir(&out, inputs)?;
    let job = SfmJob {
        images,
        camera,
        gps_neighbours: args.neighbours,
        sequential: args.sequential.unwrap_or(0),
        features: FeatureSettings {
            max_features: args.max_features,
            ..FeatureSettings::default()
        },
        matching: MatchSettings::default(),
        sfm: SfmSettings {
            refine_intrinsics: args.refine_intrinsics,
            ..SfmSettings::default()
        },
        georef,
        cache_dir: Some(out.join("cache")),
    };
    let (features, matching) = stage_bars(args.quiet || args.json);
    let run = run_sfm(&job, &features, &matching).map_err(|e: SfmJobError| {
        let input = e.is_input();
        exit_for(e, input)
    })?;
    features.finish_and_clear();
    matching.finish_and_clear();
    guard.create_dir(&out).map_err(output_error)?;
    let crs = match &frame {
        Some(f) => Some(crs_positions(&run, f)?),
        None => None,
    };
    let mut written =
        write_outputs(&out, &run, crs.as_ref()).map_err(|e| anyhow!("{}: {e}", out.display()))?;
    if let (Some(f), Some(c)) = (&frame, &crs) {
        write_gpkg(&out.join("cameras.gpkg"), &run, f, c)?;
        written.push("cameras.gpkg".into());
    }
    geostride::sfm::topview::write_topview(&out.join("topview.png"), &run)
        .map_err(|e| anyhow!("{}: {e}", out.join("topview.png").display()))?;
    written.push("topview.png".into());
    Ok(Built {
        run,
        written,
        camera_source,
        out,
    })
}

/// `geostride sfm` read from its words (the demo runs it as a user would).
pub(super) fn args_from<I: IntoIterator<Item = String>>(words: I) -> anyhow::Result<Args> {
    #[derive(clap::Parser)]
    struct Words {
        #[command(flatten)]
        args: Args,
    }
    let w = <Words as clap::Parser>::try_parse_from(
        std::iter::once("geostride sfm".to_string()).chain(words),
    )?;
    Ok(w.args)
}

pub fn run(args: Args) -> anyhow::Result<()> {
    match args.command {
        Some(SfmCommand::Register(r)) => return run_register_cli(r),
        Some(SfmCommand::Georef(g)) => return run_georef_cli(g),
        Some(SfmCommand::Convert(c)) => return run_convert_cli(c),
        None => {}
    }
    let Built {
        run,
        written,
        camera_source,
        out,
    } = build(&args)?;
    let r = &run.report;
    if args.json {
        println!("{}", serde_json::to_string_pretty(r)?);
        return Ok(());
    }
    if camera_source.is_empty() {
        // No camera given: where its focal length started, refined.
        let source = match r.camera_source.as_str() {
            "exif" => "the EXIF 35 mm focal length",
            "exif-focal-plane" => "the EXIF focal length on the sensor's pixel pitch",
            _ => "no focal length in the EXIF: 1.2 times the longer side, as COLMAP guesses",
        };
        println!(
            "Camera: from {source} ({:.1} px), refined to fx {:.1}, fy {:.1}",
            r.starting_focal_px, r.camera[0], r.camera[1]
        );
    } else {
        println!("Camera: {camera_source}");
    }
    if let Some(p) = r.principal_point {
        println!(
            "Principal point: {} at ({:.1}, {:.1}) px (σ {:.2}, {:.2} px with the images)",
            if p.refined {
                "refined"
            } else {
                "too loosely determined to refine, held"
            },
            r.camera[2],
            r.camera[3],
            p.sigma_px[0],
            p.sigma_px[1]
        );
    }
    println!(
        "Registered {} of {} images; {} points, {} observations (mean track {:.2}); mean reprojection error {:.3} px",
        r.registered,
        r.images,
        r.points,
        r.observations,
        r.mean_track_length,
        r.mean_reprojection_px
    );
    if !r.other_models.is_empty() {
        println!(
            "The photos make {} models that share no points; the largest is kept. Left out:",
            r.other_models.len() + 1
        );
        for (k, m) in r.other_models.iter().enumerate() {
            println!(
                "  model {}: {} images ({}), {} points",
                k + 2,
                m.images.len(),
                m.images.join(", "),
                m.points
            );
        }
    }
    if let Some(g) = &r.gps {
        println!(
            "Placed on the EXIF GPS of {} images (east-north-up at {:.7}, {:.7}; adjusted with them as priors, σ {:.2}/{:.2} m horizontally/vertically{}): cameras {:.2} m RMS horizontally, {:.2} m vertically from their GPS",
            g.images,
            g.origin[0],
            g.origin[1],
            g.prior_sigma_m[0],
            g.prior_sigma_m[2],
            if g.rtk { ", DJI RTK" } else { "" },
            g.rms_horizontal_m,
            g.rms_vertical_m
        );
        for (name, why) in &g.left_out {
            println!("  left out: {name}: {why}");
        }
    }
    if let Some(g) = r.georef.as_ref().filter(|_| r.frame == "site") {
        print_georef_summary(g, r.site_frame.as_deref().unwrap_or("the site frame"));
    }
    if !r.unmatched_names.is_empty() {
        println!(
            "Note: picks or centres name images not given here (ignored): {}",
            r.unmatched_names.join(", ")
        );
    }
    for i in r.per_image.iter().filter(|i| !i.registered) {
        println!(
            "  not registered: {}: {}",
            i.name,
            i.reason.as_deref().unwrap_or("")
        );
    }
    println!(
        "Time: features {:.1} s ({} of {} images from the cache), matching {:.1} s ({} pairs, {} from the cache), reconstruction {:.1} s",
        r.seconds_features,
        r.features_cached,
        r.images,
        r.seconds_matching,
        r.pairs_matched,
        r.pairs_cached,
        r.seconds_reconstruction
    );
    for f in written {
        println!("Written: {}", out.join(f).display());
    }
    Ok(())
}

/// The surveyed points, picks and camera centres in the site frame, and the frame.
fn georef_input(args: &Args) -> anyhow::Result<(Option<GeorefInput>, Option<SiteFrame>)> {
    georef_input_of(&GeorefFiles {
        gcps: args.gcps.as_deref(),
        read: &args.read,
        centres: args.centres.as_deref(),
        pick_sigma: args.pick_sigma,
        gcp_sigma: args.gcp_sigma,
        centre_sigma: &args.centre_sigma,
    })
}

/// The georeferencing options `geostride sfm` and `geostride sfm georef` share.
struct GeorefFiles<'a> {
    gcps: Option<&'a Path>,
    read: &'a ReadArgs,
    centres: Option<&'a Path>,
    pick_sigma: f64,
    gcp_sigma: f64,
    centre_sigma: &'a [f64],
}

/// The surveyed points, picks and camera centres in the site frame, and the frame.
fn georef_input_of(args: &GeorefFiles) -> anyhow::Result<(Option<GeorefInput>, Option<SiteFrame>)> {
    let (points, frame, source) = match args.gcps {
        Some(file) => {
            let framed = read_framed(file, args.read, None)?;
            let points = ground_points(
                &framed.survey.points,
                &framed.local,
                (args.pick_sigma, args.gcp_sigma),
                |image| Some(image.to_string()),
            )
            .map_err(|p| {
                bad_input(anyhow!(
                    "{}:{}: '{}' has no height; georeferencing needs 3D points",
                    file.display(),
                    p.line,
                    p.name
                ))
            })?;
            if points.iter().all(|p| p.picks.is_empty()) {
                return Err(bad_input(anyhow!(
                    "{}: no pixel picks: add them with --picks FILE (CSV 'name,image,u,v[,sigma]') or use a GCP file with picks (ODM gcp_list.txt)",
                    file.display()
                )));
            }
            (points, Some(framed.frame), Some(framed.survey))
        }
        None => (Vec::new(), None, None),
    };
    let mut centres = Vec::new();
    let frame = match args.centres {
        None => frame,
        Some(file) => {
            let survey = read_other(file, args.read)?;
            if let Some(g) = &source
                && (g.crs != survey.crs || g.height != survey.height)
            {
                return Err(bad_input(anyhow!(
                    "{}: its coordinates are in {} ({} heights), the GCPs' in {} ({} heights): give both in one CRS (geostride survey convert)",
                    file.display(),
                    survey.crs.as_deref().unwrap_or("a local frame"),
                    survey.height,
                    g.crs.as_deref().unwrap_or("a local frame"),
                    g.height
                )));
            }
            let frame = match frame {
                Some(f) => f,
                None => SiteFrame::new(&survey, &args.read.origin).map_err(bad_input)?,
            };
            let [h, v] = [args.centre_sigma[0], args.centre_sigma[1]];
            for p in &survey.points {
                let local = frame
                    .local_from_source(&p.position)
                    .map_err(|e| bad_input(anyhow!("{}:{}: {e}", file.display(), p.line)))?;
                if !local.z.is_finite() {
                    return Err(bad_input(anyhow!(
                        "{}:{}: the centre of '{}' has no height",
                        file.display(),
                        p.line,
                        p.name
                    )));
                }
                centres.push(NamedCentre {
                    image: p.name.clone(),
                    position: local,
                    sigma_m: p.sigma_m.unwrap_or(Vector3::new(h, h, v)),
                });
            }
            Some(frame)
        }
    };
    let Some(frame) = frame else {
        return Ok((None, None));
    };
    let description = match &frame.crs {
        Some(c) => format!(
            "east-north-up metres of {} ({} heights), {}",
            c.name, frame.height, frame.origin_note
        ),
        None => format!("the survey's own local frame, {}", frame.origin_note),
    };
    Ok((
        Some(GeorefInput {
            points,
            centres,
            settings: GeorefSettings::default(),
            frame: description,
        }),
        Some(frame),
    ))
}

/// Each registered camera's centre in the survey's CRS.
fn crs_positions(run: &SfmRun, frame: &SiteFrame) -> anyhow::Result<CrsPositions> {
    crs_positions_of(&run.reconstruction.poses, frame)
}

/// Each registered camera's centre (`poses`, site frame) in the survey's CRS.
fn crs_positions_of(
    poses: &[Option<geostride::geom::Rigid3>],
    frame: &SiteFrame,
) -> anyhow::Result<CrsPositions> {
    let positions = poses
        .iter()
        .map(|p| match p {
            Some(p) => frame
                .source_from_local(&p.centre())
                .map(|x| Some([x.x, x.y, x.z]))
                .map_err(|e| anyhow!("camera centre to the survey's CRS: {e}")),
            None => Ok(None),
        })
        .collect::<anyhow::Result<Vec<_>>>()?;
    Ok(CrsPositions { positions })
}

/// `cameras.gpkg`: the registered cameras in the survey's CRS.
fn write_gpkg(
    path: &Path,
    run: &SfmRun,
    frame: &SiteFrame,
    crs: &CrsPositions,
) -> anyhow::Result<()> {
    write_gpkg_of(path, &run.names, &run.reconstruction.poses, frame, crs)
}

/// `cameras.gpkg` of images `names` with `poses` (site frame).
fn write_gpkg_of(
    path: &Path,
    names: &[String],
    poses: &[Option<geostride::geom::Rigid3>],
    frame: &SiteFrame,
    crs: &CrsPositions,
) -> anyhow::Result<()> {
    let cams: Vec<CameraPoint> = names
        .iter()
        .enumerate()
        .filter_map(|(i, name)| {
            let pose = poses[i]?;
            let q = nalgebra::UnitQuaternion::from_rotation_matrix(&pose.rotation);
            let c = pose.centre();
            Some(CameraPoint {
                image: name,
                position: crs.positions[i]?,
                quaternion: [q.w, q.i, q.j, q.k],
                local: [c.x, c.y, c.z],
            })
        })
        .collect();
    let wkt = frame
        .crs
        .as_ref()
        .map(|c| c.wkt.clone())
        .unwrap_or_default();
    write_cameras(path, &wkt, &frame.height.to_string(), &cams)
        .map_err(|e| anyhow!("{}: {e}", path.display()))
}

/// `geostride sfm georef MODEL_DIR --gcps FILE --out DIR`.
fn run_georef_cli(args: GeorefArgs) -> anyhow::Result<()> {
    use geostride::sfm::colmap_model::ModelFormat;
    use geostride::sfm::georef_job::{GeorefModelJob, run_georef_model, write_georef_outputs};
    if args.centre_sigma.len() != 2
        || args
            .centre_sigma
            .iter()
            .any(|v| !(*v > 0.0 && v.is_finite()))
    {
        return Err(bad_input(anyhow!(
            "--centre-sigma {:?}: two positive numbers, horizontal,vertical metres",
            args.centre_sigma
        )));
    }
    if !args.model.is_dir() {
        return Err(bad_input(anyhow!(
            "{}: no such folder (give the COLMAP model's folder, e.g. sparse/0)",
            args.model.display()
        )));
    }
    let (georef, frame) = georef_input_of(&GeorefFiles {
        gcps: args.gcps.as_deref(),
        read: &args.read,
        centres: args.centres.as_deref(),
        pick_sigma: args.pick_sigma,
        gcp_sigma: args.gcp_sigma,
        centre_sigma: &args.centre_sigma,
    })?;
    let (Some(georef), Some(frame)) = (georef, frame) else {
        return Err(bad_input(anyhow!("--gcps: no surveyed points")));
    };
    let inputs: Vec<&Path> = [args.model.as_path()]
        .into_iter()
        .chain(args.gcps.iter().map(PathBuf::as_path))
        .chain(args.centres.iter().map(PathBuf::as_path))
        .chain(args.read.picks.iter().map(PathBuf::as_path))
        .collect();
    let guard = check_output_dir(&args.out, inputs)?;
    let job = GeorefModelJob {
        model_dir: args.model.clone(),
        georef,
        format: args.output_type.map(|t| match t {
            OutputType::Txt => ModelFormat::Text,
            OutputType::Bin => ModelFormat::Binary,
        }),
    };
    let run = run_georef_model(&job).map_err(|e| {
        let input = e.is_input();
        exit_for(e, input)
    })?;
    let r = &run.converted.reconstruction;
    let crs = crs_positions_of(&r.poses, &frame)?;
    guard.create_dir(&args.out).map_err(output_error)?;
    let mut written = write_georef_outputs(&args.out, &run, Some(&crs))
        .map_err(|e| anyhow!("{}: {e}", args.out.display()))?;
    if frame.crs.is_some() {
        write_gpkg_of(
            &args.out.join("cameras.gpkg"),
            &run.converted.names,
            &r.poses,
            &frame,
            &crs,
        )?;
        written.push("cameras.gpkg".into());
    }
    let report = &run.report;
    if args.json {
        println!("{}", serde_json::to_string_pretty(report)?);
        return Ok(());
    }
    let g = &report.georef;
    println!(
        "Model: {} images, {} points, camera {} {}x{}; mean reprojection {:.3} px as read, {:.3} px adjusted",
        report.images,
        report.points,
        report.camera_model,
        report.width,
        report.height,
        report.mean_reprojection_px_before,
        report.mean_reprojection_px
    );
    print_georef_summary(g, &report.site_frame);
    if !report.unmatched_names.is_empty() {
        println!(
            "Note: picks or centres name images not in the model (ignored): {}",
            report.unmatched_names.join(", ")
        );
    }
    for f in written {
        println!("Written: {}", args.out.join(f).display());
    }
    Ok(())
}

/// The georeferencing's lines of the terminal summary.
fn print_georef_summary(g: &geostride::sfm::georef::GeorefReport, site_frame: &str) {
    let rms = |x: &Option<geostride::sfm::georef::Rms>| match x {
        Some(x) => format!(
            "{:.3} m horizontally, {:.3} m vertically ({} points)",
            x.horizontal_m, x.vertical_m, x.points
        ),
        None => "none".into(),
    };
    println!(
        "Georeferenced in {} (placed by the {}): control {}; check {}{}",
        site_frame,
        g.placed_by,
        rms(&g.control_rms),
        rms(&g.check_rms),
        g.check_rms_px
            .map(|p| format!(", check picks {p:.2} px"))
            .unwrap_or_default()
    );
    if let Some(c) = &g.centres_rms {
        println!(
            "Camera centres {:.3} m horizontally, {:.3} m vertically from their measurements ({} images)",
            c.horizontal_m, c.vertical_m, c.points
        );
    }
    for (name, why) in &g.left_out {
        println!("  left out: {name}: {why}");
    }
    if g.sigma_scale > 1.0 {
        println!(
            "  camera σ scaled by {:.2}: the surveyed points and centres spread more than their σ say",
            g.sigma_scale
        );
    }
}
