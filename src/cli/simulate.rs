//! `geostride simulate`: render a scene with exact ground truth.

use std::path::{Path, PathBuf};

use anyhow::{Context, anyhow};

use super::bad_input;
use super::{load_camera, scale_to};
use geostride::simulate::run::{Overrides, SimError, Summary, simulate, site_in_crs};
use geostride::simulate::scene::Scene;

#[derive(clap::Args)]
#[command(
    after_help = "The scene file format is described in docs/simulate.md; examples are in surveys/."
)]
pub struct Args {
    /// Scene description (TOML)
    scene: PathBuf,
    /// Output folder (created): video, frames, truth/, gcps.csv, picks.csv, checkerboards/
    #[arg(long, value_name = "DIR")]
    out: PathBuf,
    /// Seed, overriding the scene's
    #[arg(long)]
    seed: Option<u64>,
    /// Duration in seconds, overriding the scene's
    #[arg(long, value_name = "S")]
    duration: Option<f64>,
    /// Write every N-th frame as PNG, overriding the scene's output.frames_every
    #[arg(long, value_name = "N")]
    frames_every: Option<u32>,
    /// Skip the video (truth and exports only)
    #[arg(long)]
    no_video: bool,
    /// The people without hats, whatever the scene says (for a detector that needs none)
    #[arg(long)]
    no_hats: bool,
    /// Put the site in this CRS (EPSG code, PROJ string or WKT) at the same place: the scene's
    /// origin is converted with PROJ
    #[arg(long, value_name = "CRS")]
    crs: Option<String>,
    /// No progress bar
    #[arg(short, long)]
    quiet: bool,
}

/// Loads a scene and its camera (a preset name, or a file relative to the scene), with the site
/// moved to `site_crs` when given.
pub(crate) fn load(
    scene_path: &Path,
    site_crs: Option<&str>,
) -> anyhow::Result<(Scene, geostride::camera::Camera, String)> {
    let mut scene = Scene::load(scene_path).map_err(bad_input)?;
    // Coded targets' cells, as OpenCV draws the markers.
    for g in &mut scene.gcp {
        if let Some(code) = g.code {
            let d = g
                .marker_dictionary()
                .map_err(|e| bad_input(anyhow!("{}: {e}", scene_path.display())))?;
            g.cells = Some(
                geostride::targets::aruco_cv::marker_cells(&d, code).map_err(|e| {
                    bad_input(anyhow!("{}: gcp '{}': {e}", scene_path.display(), g.name))
                })?,
            );
        }
    }
    if let Some(crs) = site_crs {
        scene.site = site_in_crs(&scene.site, crs).map_err(|e| bad_input(anyhow!(e)))?;
    }
    let spec = &scene.camera.calibration;
    let cam_spec = if geostride::camera::presets::preset(spec).is_some() {
        spec.clone()
    } else {
        scene
            .calibration_path(scene_path)
            .to_string_lossy()
            .into_owned()
    };
    let (mut camera, source) = load_camera(&cam_spec)
        .with_context(|| format!("{}: camera.calibration", scene_path.display()))?;
    if let Some([w, h]) = scene.camera.video_mode {
        camera = scale_to(camera, w, h)?;
    }
    Ok((scene, camera, source))
}

/// Runs one scene with a progress bar.
pub(crate) fn run_scene(
    scene_path: &Path,
    out: &Path,
    over: &Overrides,
    quiet: bool,
) -> anyhow::Result<Summary> {
    let (scene, camera, source) = load(scene_path, over.site_crs.as_deref())?;
    if let Some(d) = over.duration_s
        && !(d > 0.0 && d <= 3600.0)
    {
        return Err(bad_input(anyhow!(
            "--duration must be positive and at most 3600 s"
        )));
    }
    let input = |m: String| bad_input(anyhow!("{}: {m}", scene_path.display()));
    geostride::simulate::run::check(&scene, &camera).map_err(|e| input(e.to_string()))?;
    let calibration = scene.calibration_path(scene_path);
    super::create_output_dir(out, [scene_path, calibration.as_path()])?;
    let bar = super::progress_bar(
        quiet,
        0,
        "{spinner} rendering {bar:30} {pos}/{len} frames ({per_sec}, {eta})",
    );
    if !quiet {
        eprintln!(
            "{}: {} with {}",
            scene_path.display(),
            if scene.name.is_empty() {
                "scene"
            } else {
                &scene.name
            },
            source
        );
    }
    let summary = simulate(&scene, &camera, out, over, &bar).map_err(|e| match e {
        SimError::Input(m) => bad_input(anyhow!("{}: {m}", scene_path.display())),
        SimError::Output(m) => anyhow!(m),
    })?;
    bar.finish_and_clear();
    Ok(summary)
}

pub fn run(args: Args) -> anyhow::Result<()> {
    let over = Overrides {
        seed: args.seed,
        duration_s: args.duration,
        no_video: args.no_video,
        frames_every: args.frames_every,
        site_crs: args.crs,
        no_hats: args.no_hats,
    };
    let s = run_scene(&args.scene, &args.out, &over, args.quiet)?;
    print_summary(&s);
    Ok(())
}

pub(crate) fn print_summary(s: &Summary) {
    println!(
        "Rendered {} frame(s) of {}x{}: {} people, {} of them seen",
        s.frames, s.image_size[0], s.image_size[1], s.people, s.people_in_view
    );
    if let (Some(v), Some(c)) = (&s.video, &s.codec) {
        println!("  video: {} ({c})", v.display());
    }
    for f in &s.files {
        if Some(f) != s.video.as_ref() && !f.to_string_lossy().contains("checkerboards") {
            println!("  {}", f.display());
        }
    }
    let boards = s
        .files
        .iter()
        .filter(|f| f.to_string_lossy().contains("checkerboards"))
        .count();
    if boards > 0 {
        println!("  {boards} checkerboard image(s) in checkerboards/");
    }
}
