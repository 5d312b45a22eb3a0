//! `geostride demo`: the bundled examples, run end to end against their ground truth. At this
//! stage it (1) renders checkerboard views through a known distorted camera, calibrates from the
//! images exactly as `geostride calibrate` does, and compares the result with the truth; and
//! (2) renders the example scenes in `surveys/` (a stream over a footbridge under a hovering
//! camera, a group on a track under a moving one) with their truth, GCP exports and
//! checkerboards.

use std::path::{Path, PathBuf};

use anyhow::{Context, anyhow, bail};
use rand::SeedableRng;

use super::calibrate::{Job, run_job, summary};
use crate::calibration::Options;
use crate::calibration::inputs::CollectSettings;
use crate::camera::formats::{self, Format};
use crate::camera::{BoardSpec, PARAM_NAMES};
use crate::simulate::board::{BoardRenderer, random_board_poses};
use crate::simulate::run::Overrides;
use crate::simulate::scene::Motion;
use crate::simulate::scene::Scene;
use crate::simulate::truth::{mean_reprojection_px, read_gcps, read_poses};

/// The demo's ground-truth camera (`calib/demo-camera.json`).
const TRUTH_JSON: &str = include_str!("../../calib/demo-camera.json");

const BOARD: BoardSpec = BoardSpec {
    cols: 9,
    rows: 6,
    square_m: 0.03,
};

/// A normalised error beyond this fails the demo's self-check.
const MAX_Z: f64 = 5.0;

#[derive(clap::Args)]
pub struct Args {
    /// Output folder for the rendered boards and the calibration files
    #[arg(long, default_value = "out/demo", value_name = "DIR")]
    out: PathBuf,
    /// Seed of the board poses and the image noise
    #[arg(long, default_value_t = 7)]
    seed: u64,
    /// Number of board views to render
    #[arg(long, default_value_t = 15, value_parser = clap::value_parser!(u32).range(3..=100))]
    views: u32,
    /// Grey-level noise added to the rendered images (standard deviation, 0-255 scale)
    #[arg(long, default_value_t = 2.0, value_parser = parse_non_negative)]
    noise: f64,
    /// Folder of example scenes (each `*/scene.toml` is rendered)
    #[arg(long, default_value = "surveys", value_name = "DIR")]
    surveys: PathBuf,
    /// Only the calibration part
    #[arg(long)]
    skip_scenes: bool,
    /// No progress bars
    #[arg(short, long)]
    quiet: bool,
}

fn parse_non_negative(s: &str) -> Result<f64, String> {
    match s.parse::<f64>() {
        Ok(v) if v >= 0.0 && v.is_finite() => Ok(v),
        _ => Err(format!("expected a number of grey levels >= 0, got '{s}'")),
    }
}

pub fn run(args: Args) -> anyhow::Result<()> {
    let truth = formats::parse(
        Path::new("calib/demo-camera.json"),
        TRUTH_JSON,
        Some(Format::Json),
    )
    .map_err(|e| anyhow!(e))?
    .camera;
    let boards = args.out.join("boards");
    std::fs::create_dir_all(&boards).with_context(|| format!("creating {}", boards.display()))?;

    println!(
        "geostride demo: rendering {} views of a {}x{} board through the camera in calib/demo-camera.json",
        args.views, BOARD.cols, BOARD.rows
    );
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(args.seed);
    let poses = random_board_poses(&truth, &BOARD, args.views as usize, &mut rng);
    let renderer = BoardRenderer::new(&truth, 3);
    let bar = super::progress_bar(
        args.quiet,
        poses.len() as u64,
        "{spinner} rendering {bar:30} {pos}/{len}",
    );
    for (i, pose) in poses.iter().enumerate() {
        let image = renderer.render(&BOARD, pose, args.noise, &mut rng);
        crate::imageio::write_gray(&boards.join(format!("board-{i:02}.png")), &image)
            .map_err(|e| anyhow!(e))?;
        bar.inc(1);
    }
    bar.finish_and_clear();

    let job = Job {
        inputs: vec![boards.clone()],
        board: BOARD,
        options: Options::default(),
        collect: CollectSettings::default(),
        drop_outliers: false,
        quiet: args.quiet,
    };
    let outcome = run_job(&job)?;
    print!("{}", summary(&outcome.result, &outcome.log));
    let cal = outcome.result.to_calibration();
    for name in ["camera.yaml", "camera.json", "camera.xml"] {
        let path = args.out.join(name);
        let f = formats::write(&cal, &path, None).map_err(|e| anyhow!(e))?;
        println!("Written: {} ({})", path.display(), f.name());
    }

    println!("\nAgainst the ground truth:");
    println!("  parameter           truth        estimate     std dev   (est-truth)/σ");
    let (est, tru, sd) = (
        outcome.result.camera.params(),
        truth.params(),
        outcome.result.std_devs(),
    );
    let mut worst: f64 = 0.0;
    for (i, name) in PARAM_NAMES.iter().enumerate() {
        if sd[i] == 0.0 {
            continue;
        }
        let z = (est[i] - tru[i]) / sd[i];
        worst = worst.max(z.abs());
        println!(
            "  {name:<6} {:>16.6} {:>15.6} {:>11.6} {:>+10.2}",
            tru[i], est[i], sd[i], z
        );
    }
    if outcome.result.views.len() != poses.len() {
        bail!(
            "demo self-check failed: the board was detected in {} of {} rendered views",
            outcome.result.views.len(),
            poses.len()
        );
    }
    if worst > MAX_Z {
        bail!(
            "demo self-check failed: an estimate is {worst:.1} standard deviations from the truth"
        );
    }
    println!(
        "\nCalibration OK: all {} views detected; every estimate within {worst:.2} standard deviations of the truth.",
        poses.len()
    );
    if !args.skip_scenes {
        run_scenes(&args)?;
    }
    println!("\nDemo OK.");
    Ok(())
}

/// Renders every example scene under `args.surveys`.
fn run_scenes(args: &Args) -> anyhow::Result<()> {
    let mut scenes: Vec<PathBuf> = std::fs::read_dir(&args.surveys)
        .with_context(|| {
            format!(
                "{}: the example scenes (run the demo from the repository root, or pass --surveys)",
                args.surveys.display()
            )
        })?
        .filter_map(|e| e.ok().map(|e| e.path().join("scene.toml")))
        .filter(|p| p.is_file())
        .collect();
    scenes.sort();
    if scenes.is_empty() {
        bail!("no */scene.toml under {}", args.surveys.display());
    }
    for scene in scenes {
        let name = scene
            .parent()
            .and_then(|p| p.file_name())
            .map(|n| n.to_string_lossy().into_owned())
            .unwrap_or_default();
        let out = args.out.join(&name);
        println!("\nScene {name}:");
        let s = super::simulate::run_scene(&scene, &out, &Overrides::default(), args.quiet)?;
        super::simulate::print_summary(&s);
        if s.people_in_view == 0 {
            bail!(
                "demo self-check failed: nobody is in view in {}",
                scene.display()
            );
        }
        let spec = Scene::load(&scene).map_err(|e| anyhow!(e))?;
        if let (Motion::Hover { .. }, Some(video)) = (&spec.camera.motion, &s.video) {
            hover_poses(args, &scene, &spec, &out, video)?;
        }
    }
    Ok(())
}

/// Solves every frame's pose of a hovering scene with `geostride pose --video`, as a user would,
/// and checks it against the truth: the GCPs must project within 1 px (mean) of where the true
/// pose puts them, in every frame.
fn hover_poses(
    args: &Args,
    scene_path: &Path,
    scene: &Scene,
    out: &Path,
    video: &Path,
) -> anyhow::Result<()> {
    let camera_arg = if crate::camera::presets::preset(&scene.camera.calibration).is_some() {
        scene.camera.calibration.clone()
    } else {
        scene.calibration_path(scene_path).display().to_string()
    };
    // The simulator's site frame is the tangent frame at the scene's origin: use the same one.
    let crs = crate::survey::crs::Crs::new(&scene.site.crs)
        .map_err(|e| anyhow!("{}: site.crs: {e}", scene_path.display()))?;
    let o = scene.site.origin;
    let (lon, lat) = crs
        .to_lon_lat(o[0], o[1])
        .map_err(|e| anyhow!("{}: site.origin: {e}", scene_path.display()))?;
    let pose_dir = out.join("pose");
    let path = |p: &Path| p.display().to_string();
    let mut argv = vec![
        "geostride".to_string(),
        "pose".into(),
        "--camera".into(),
        camera_arg,
        "--gcps".into(),
        path(&out.join("gcps.csv")),
        "--height".into(),
        "ellipsoidal".into(),
        "--picks".into(),
        path(&out.join("picks.csv")),
        "--video".into(),
        path(video),
        "--out".into(),
        path(&pose_dir),
        "--origin".into(),
        format!("{lat:.10},{lon:.10},{}", o[2]),
    ];
    if args.quiet {
        argv.push("-q".into());
    }
    println!(
        "
$ {}",
        argv.join(" ")
    );
    use clap::Parser;
    super::Cli::try_parse_from(&argv)
        .map_err(|e| anyhow!("{e}"))?
        .run()?;

    let truth = read_poses(&out.join("truth/camera.csv")).map_err(|e| anyhow!(e))?;
    let est = read_poses(&pose_dir.join("poses.csv")).map_err(|e| anyhow!(e))?;
    let gcps: Vec<_> = read_gcps(&out.join("truth/gcps.csv"))
        .map_err(|e| anyhow!(e))?
        .into_iter()
        .map(|g| g.1)
        .collect();
    let cal = match crate::camera::presets::preset(&scene.camera.calibration) {
        Some(c) => c,
        None => formats::read(&scene.calibration_path(scene_path), None).map_err(|e| anyhow!(e))?,
    };
    let (w, h) = video_size(&out.join("truth/scene.json"))?;
    let camera = super::scale_to(cal.camera, w, h)?;
    if truth.len() != est.len() {
        bail!(
            "demo self-check failed: {} poses for {} frames",
            est.len(),
            truth.len()
        );
    }
    let (mut worst, mut worst_frame, mut sum) = (0.0f64, 0, 0.0);
    for ((f, t), (_, e)) in truth.iter().zip(&est) {
        let m = mean_reprojection_px(&camera, t, e, &gcps)
            .ok_or_else(|| anyhow!("frame {f}: a GCP is behind the camera"))?;
        sum += m;
        if m > worst {
            (worst, worst_frame) = (m, *f);
        }
    }
    println!(
        "Poses against the truth: the GCPs project {:.3} px (mean over {} frames) from where the true poses put them; worst frame {worst_frame} at {worst:.3} px",
        sum / est.len() as f64,
        est.len()
    );
    if worst > 1.0 {
        bail!(
            "demo self-check failed: frame {worst_frame}'s pose is {worst:.2} px from the truth (limit 1 px)"
        );
    }
    Ok(())
}

/// The image size a scene was rendered at, from its `truth/scene.json`.
fn video_size(scene_json: &Path) -> anyhow::Result<(u32, u32)> {
    let v: serde_json::Value = serde_json::from_str(
        &std::fs::read_to_string(scene_json).with_context(|| scene_json.display().to_string())?,
    )?;
    let size = v["image_size"]
        .as_array()
        .ok_or_else(|| anyhow!("{}: no image_size", scene_json.display()))?;
    let get = |i: usize| {
        size.get(i)
            .and_then(|x| x.as_u64())
            .map(|x| x as u32)
            .ok_or_else(|| anyhow!("{}: bad image_size", scene_json.display()))
    };
    Ok((get(0)?, get(1)?))
}
