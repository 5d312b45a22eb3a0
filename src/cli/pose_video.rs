//! `geostride pose --video`: every frame's pose of a hovering camera.

use std::fmt::Write as _;
use std::path::{Path, PathBuf};

use anyhow::{Context, anyhow};
use serde::Serialize;

use super::bad_input;
use super::pose::{Args, Seen, camera_for, choose_image, seen_in};
use super::survey::read_framed;
use geostride::io::write_atomic;
use geostride::pipeline::pose_outputs::{PoseRun, write_pose_outputs};
use geostride::pipeline::scan::{ScanJob, Scanned, scan};
use geostride::pose::PoseSettings;
use geostride::pose::hover::{HoverResult, solve_with_checks};
use geostride::pose::stabilise::StabiliseSettings;
use geostride::progress::NoProgress;
use geostride::video::source::FrameReader;

/// The picked frame: `--picks-frame`, else the `#N` ending of the picks' image name, else 0.
fn picks_frame(args: &Args, image: &str) -> (usize, Option<String>) {
    if let Some(n) = args.picks_frame {
        return (n, None);
    }
    match geostride::io::frame_of_name(image) {
        Some(Ok(n)) => (n, None),
        _ => (
            0,
            Some(format!(
                "the picks' image '{image}' names no frame ('NAME#N'): taken as frame 0; say --picks-frame N otherwise"
            )),
        ),
    }
}

#[derive(Serialize)]
struct Summary<'a> {
    video: String,
    frames: usize,
    fps: f64,
    image_size: [u32; 2],
    camera: &'a str,
    picks_frame: usize,
    crs: Option<String>,
    height: String,
    site_frame: &'a str,
    /// Latitude, longitude (degrees) and height of the site frame's origin.
    site_origin: Option<[f64; 3]>,
    key_frames: Vec<usize>,
    key_frames_failed: Vec<usize>,
    frames_interpolated: usize,
    mean_reprojection_px: f64,
    max_reprojection_px: f64,
    check_mean_reprojection_px: Option<f64>,
    joint_chi2: f64,
    largest_gcp_shift_m: f64,
}

pub fn run(args: &Args) -> anyhow::Result<()> {
    let video = args.video.as_ref().expect("video mode");
    let out = args.out.as_ref().expect("clap requires --out with --video");
    let reader = FrameReader::open(video).map_err(|e| bad_input(anyhow!(e)))?;
    let fps = reader.fps;
    if !(reader.fps > 0.0) {
        return Err(bad_input(anyhow!(
            "{}: the video states no frame rate",
            video.display()
        )));
    }
    let (camera, camera_source) = camera_for(&args.camera, Some((reader.width, reader.height)))?;
    let framed = read_framed(&args.gcps, &args.read, None)?;
    let image = choose_image(&framed, args.picks_image.as_deref(), None)?;
    let (pick_frame, note) = picks_frame(args, &image);
    let seen = seen_in(&framed, &image, args.pick_sigma, args.gcp_sigma, &camera)?;
    if seen.control.len() < 4 {
        return Err(bad_input(anyhow!(
            "image '{image}' has picks of {} control point(s); a pose needs at least 4",
            seen.control.len()
        )));
    }
    let mut inputs = vec![
        video.as_path(),
        Path::new(&args.camera),
        args.gcps.as_path(),
    ];
    inputs.extend(args.read.picks.iter().map(PathBuf::as_path));
    super::create_output_dir(out, inputs)?;
    let max_frames = args.duration.map(|d| (d * reader.fps).ceil() as usize);
    drop(reader);

    // Tracking pass: the picks of control and check points travel together.
    let scanned = track_picks(args, video, max_frames, fps, pick_frame, &seen)?;
    let tracks = &scanned.tracks;
    if tracks.len() <= pick_frame {
        return Err(bad_input(anyhow!(
            "{}: the video has {} frame(s); the picks are on frame {pick_frame}",
            video.display(),
            tracks.len()
        )));
    }

    // Poses from the control picks; the check picks are evaluated afterwards.
    let pose_settings = PoseSettings {
        threshold_px: args.threshold,
        seed: args.seed,
        loss: args.loss,
        ..PoseSettings::default()
    };
    let (result, check_mean) = solve_with_checks(
        &camera,
        &seen.control,
        &seen.check,
        tracks,
        &pose_settings,
        &NoProgress,
    )
    .map_err(|e| bad_input(anyhow!("{}: {e}", video.display())))?;
    let run = PoseRun {
        camera: &camera,
        result: &result,
        tracks,
        check_mean: &check_mean,
        fps,
        framed: &framed,
        control: &seen.control,
    };
    let written = write_pose_outputs(out, &run)?;

    // Report.
    let stats = FrameStats::of(&result, &seen, &check_mean);
    let t = framed.frame.tangent.as_ref();
    let summary = Summary {
        video: video.display().to_string(),
        frames: tracks.len(),
        fps,
        image_size: [scanned.width, scanned.height],
        camera: &camera_source,
        picks_frame: pick_frame,
        crs: framed.frame.crs.as_ref().map(|c| c.label()),
        height: framed.frame.height.to_string(),
        site_frame: &framed.frame.origin_note,
        site_origin: t.map(|t| {
            [
                t.origin.lat.to_degrees(),
                t.origin.lon.to_degrees(),
                t.origin.h,
            ]
        }),
        key_frames: result.key_frames.iter().map(|k| k.index).collect(),
        key_frames_failed: result.failed_key_frames(),
        frames_interpolated: stats.interpolated,
        mean_reprojection_px: stats.mean_px,
        max_reprojection_px: stats.worst.1,
        check_mean_reprojection_px: stats.check_mean_px,
        joint_chi2: result.joint.chi2,
        largest_gcp_shift_m: stats.largest_shift_m,
    };
    let json_path = out.join("pose.json");
    write_atomic(
        &json_path,
        serde_json::to_string_pretty(&summary)?.as_bytes(),
    )
    .with_context(|| json_path.display().to_string())?;
    let counts = (seen.control.len(), seen.check.len());
    print!(
        "{}",
        report_text(&summary, &result, &stats, counts, note, &written)?
    );
    Ok(())
}

/// Every frame's track of the picks of `seen` (control, then check points) from `pick_frame`
/// on, key frames chosen as `args` say.
fn track_picks(
    args: &Args,
    video: &Path,
    max_frames: Option<usize>,
    fps: f64,
    pick_frame: usize,
    seen: &Seen,
) -> anyhow::Result<Scanned> {
    let settings =
        StabiliseSettings::key_frames(args.min_features, args.key_fraction, args.key_every, fps);
    let picks = seen
        .control
        .iter()
        .chain(&seen.check)
        .map(|o| o.uv)
        .collect();
    let bar = super::progress_bar(
        args.quiet,
        0,
        "tracking {bar:40} {pos}/{len} frames [{elapsed_precise}<{eta_precise}]",
    );
    let scanned = scan(
        ScanJob {
            video,
            max_frames,
            stabilise: Some((settings, pick_frame, picks)),
            detector: None,
            tracker: None,
        },
        &bar,
    )
    .map_err(|e| bad_input(anyhow!(e)))?;
    bar.finish_and_clear();
    Ok(scanned)
}

/// The figures of the report beyond the result's own.
struct FrameStats {
    /// Mean of the frames' mean reprojection errors, pixels.
    mean_px: f64,
    /// The worst frame and its mean reprojection error, pixels.
    worst: (usize, f64),
    interpolated: usize,
    check_mean_px: Option<f64>,
    /// How far the joint refinement moved a GCP from its survey, metres.
    largest_shift_m: f64,
}

impl FrameStats {
    fn of(result: &HoverResult, seen: &Seen, check_mean: &[Option<f64>]) -> Self {
        let means: Vec<(usize, f64)> = result
            .frames
            .iter()
            .filter_map(|f| f.mean_reprojection_px.map(|m| (f.index, m)))
            .collect();
        let check_all: Vec<f64> = check_mean.iter().flatten().copied().collect();
        FrameStats {
            mean_px: means.iter().map(|m| m.1).sum::<f64>() / means.len().max(1) as f64,
            worst: means
                .iter()
                .copied()
                .fold((0, 0.0), |a, b| if b.1 > a.1 { b } else { a }),
            interpolated: result.frames.iter().filter(|f| f.interpolated).count(),
            check_mean_px: (!check_all.is_empty())
                .then(|| check_all.iter().sum::<f64>() / check_all.len() as f64),
            largest_shift_m: result
                .joint
                .points
                .iter()
                .zip(&seen.control)
                .map(|(p, g)| (p - g.world).norm())
                .fold(0.0, f64::max),
        }
    }
}

/// What `pose --video` prints; `counts`: the control and check points picked.
fn report_text(
    summary: &Summary,
    result: &HoverResult,
    stats: &FrameStats,
    counts: (usize, usize),
    note: Option<String>,
    written: &[PathBuf],
) -> anyhow::Result<String> {
    let mut s = String::new();
    writeln!(
        s,
        "Video {}: {} frame(s) of {}x{} at {:.3} fps; picks of {} control and {} check point(s) on frame {}",
        summary.video,
        summary.frames,
        summary.image_size[0],
        summary.image_size[1],
        summary.fps,
        counts.0,
        counts.1,
        summary.picks_frame
    )?;
    if let Some(n) = note {
        writeln!(s, "  note: {n}")?;
    }
    writeln!(s, "  camera: {}", summary.camera)?;
    writeln!(
        s,
        "Key frames: {} ({})",
        summary.key_frames.len(),
        result
            .key_frames
            .iter()
            .map(|k| format!("{} {}", k.index, k.reason.as_str()))
            .collect::<Vec<_>>()
            .join(", ")
    )?;
    for k in &result.key_frames {
        match &k.solution {
            Ok(sol) => writeln!(
                s,
                "  frame {:>6}: {} pick(s), {} inlier(s), RMS {:.3} px",
                k.index, k.picks, sol.inliers, sol.rms_px
            )?,
            Err(e) => writeln!(s, "  frame {:>6}: not solved: {e}", k.index)?,
        }
    }
    writeln!(
        s,
        "Joint refinement of {} key frame(s) and {} GCP(s): χ² {:.1}, largest GCP shift {:.3} m",
        result.joint.poses.len(),
        counts.0,
        result.joint.chi2,
        summary.largest_gcp_shift_m
    )?;
    writeln!(
        s,
        "Frames: {} solved, {} interpolated; mean reprojection error {:.3} px (worst frame {} at {:.3} px)",
        summary.frames - stats.interpolated,
        stats.interpolated,
        stats.mean_px,
        stats.worst.0,
        stats.worst.1
    )?;
    if let Some(c) = stats.check_mean_px {
        writeln!(s, "Check points: mean reprojection error {c:.3} px")?;
    }
    for w in written {
        writeln!(s, "Written: {}", w.display())?;
    }
    Ok(s)
}
