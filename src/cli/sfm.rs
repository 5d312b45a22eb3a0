//! `geostride sfm IMAGES-OR-FOLDERS... --camera CAL --out DIR`: structure from motion.

use std::path::{Path, PathBuf};

use anyhow::anyhow;

use super::{bad_input, create_output_dir, load_camera, progress_bar};
use geostride::sfm::FeatureSettings;
use geostride::sfm::job::{SfmJob, SfmJobError, run_sfm, write_outputs};
use geostride::sfm::matching::MatchSettings;
use geostride::sfm::reconstruct::SfmSettings;

#[derive(clap::Args)]
pub struct Args {
    /// Images, or folders of images (JPEG, PNG, TIFF; a folder's images in name order)
    #[arg(required = true, value_name = "IMAGES-OR-FOLDERS")]
    inputs: Vec<PathBuf>,
    /// The camera of every image: a calibration file or a preset [default: a pinhole from the
    /// EXIF 35 mm focal length, refined]
    #[arg(long, value_name = "CAL")]
    camera: Option<String>,
    /// Refine the focal lengths and the first two radial terms at the end (a calibration known
    /// only roughly)
    #[arg(long)]
    refine_intrinsics: bool,
    /// Features per image at most
    #[arg(long, default_value = "8192", value_name = "N")]
    max_features: usize,
    /// Output folder: COLMAP text model, points.ply, report.json, report.md
    #[arg(long, value_name = "DIR")]
    out: PathBuf,
    /// Print the report as JSON
    #[arg(long)]
    json: bool,
    /// No progress bars
    #[arg(long)]
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

pub fn run(args: Args) -> anyhow::Result<()> {
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
        None => (None, "EXIF focal length (refined)".to_string()),
    };
    if args.max_features < 100 {
        return Err(bad_input(anyhow!(
            "--max-features {}: too few to match images (8192 is the default)",
            args.max_features
        )));
    }
    let inputs: Vec<&Path> = images
        .iter()
        .map(PathBuf::as_path)
        .chain(args.camera.iter().map(Path::new))
        .collect();
    create_output_dir(&args.out, inputs)?;
    let job = SfmJob {
        images,
        camera,
        gps_neighbours: 8,
        features: FeatureSettings {
            max_features: args.max_features,
            ..FeatureSettings::default()
        },
        matching: MatchSettings::default(),
        sfm: SfmSettings {
            refine_intrinsics: args.refine_intrinsics,
            ..SfmSettings::default()
        },
    };
    let features = progress_bar(
        args.quiet || args.json,
        0,
        "{spinner} features {bar:30} {pos}/{len} images ({eta})",
    );
    let matching = progress_bar(
        args.quiet || args.json,
        0,
        "{spinner} matching {bar:30} {pos}/{len} pairs ({eta})",
    );
    let run = run_sfm(&job, &features, &matching).map_err(|e: SfmJobError| {
        if e.is_input() {
            bad_input(e)
        } else {
            anyhow::Error::new(e)
        }
    })?;
    features.finish_and_clear();
    matching.finish_and_clear();
    let written =
        write_outputs(&args.out, &run).map_err(|e| anyhow!("{}: {e}", args.out.display()))?;
    let r = &run.report;
    if args.json {
        println!("{}", serde_json::to_string_pretty(r)?);
        return Ok(());
    }
    println!("Camera: {camera_source}");
    println!(
        "Registered {} of {} images; {} points, {} observations (mean track {:.2}); mean reprojection error {:.3} px",
        r.registered,
        r.images,
        r.points,
        r.observations,
        r.mean_track_length,
        r.mean_reprojection_px
    );
    if let Some(g) = &r.gps {
        println!(
            "Placed on the EXIF GPS of {} images (east-north-up at {:.7}, {:.7}): cameras {:.2} m RMS horizontally, {:.2} m vertically from their GPS",
            g.images, g.origin[0], g.origin[1], g.rms_horizontal_m, g.rms_vertical_m
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
        "Time: features {:.1} s, matching {:.1} s ({} pairs), reconstruction {:.1} s",
        r.seconds_features, r.seconds_matching, r.pairs_matched, r.seconds_reconstruction
    );
    for f in written {
        println!("Written: {}", args.out.join(f).display());
    }
    Ok(())
}
