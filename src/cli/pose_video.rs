//! `geostride pose --video`: every frame's pose of a hovering camera.

use std::fmt::Write as _;
use std::path::Path;

use anyhow::{Context, anyhow};
use nalgebra::Matrix3;
use serde::Serialize;

use super::bad_input;
use super::pose::{Args, camera_for, choose_image, seen_in};
use super::survey::read_framed;
use crate::camera::Camera;
use crate::draw::{Chart, Series, Style, line_chart};
use crate::estimate::p3p::RigidPose;
use crate::geom::{Pose, rvec_of};
use crate::io::write_atomic;
use crate::pose::hover::{HoverGcp, HoverResult, solve_hover};
use crate::pose::refine::project_pose;
use crate::pose::stabilise::{FrameTrack, StabiliseSettings, Stabiliser};
use crate::pose::{Attitude, PoseSettings};
use crate::progress::NoProgress;
use crate::video::klt::{Klt, KltSettings};
use crate::video::source::FrameReader;

/// The picked frame: `--picks-frame`, else the `#N` ending of the picks' image name, else 0.
fn picks_frame(args: &Args, image: &str) -> (usize, Option<String>) {
    if let Some(n) = args.picks_frame {
        return (n, None);
    }
    match image
        .rsplit_once('#')
        .and_then(|(_, n)| n.parse::<usize>().ok())
    {
        Some(n) => (n, None),
        None => (
            0,
            Some(format!(
                "the picks' image '{image}' names no frame ('NAME#N'): taken as frame 0; say --picks-frame N otherwise"
            )),
        ),
    }
}

fn csv_num(v: Option<f64>, decimals: usize) -> String {
    v.filter(|v| v.is_finite())
        .map_or(String::new(), |v| format!("{v:.decimals$}"))
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
    let mut reader = FrameReader::open(video).map_err(|e| bad_input(anyhow!(e)))?;
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
    std::fs::create_dir_all(out).with_context(|| format!("creating {}", out.display()))?;
    let last_frame = args.duration.map(|d| (d * reader.fps).ceil() as usize);
    let total = match (reader.frame_count, last_frame) {
        (Some(c), Some(l)) => Some(c.min(l)),
        (c, l) => c.or(l),
    };
    if let Some(t) = total
        && pick_frame >= t
    {
        return Err(bad_input(anyhow!(
            "the picks are on frame {pick_frame}, beyond the {t} frame(s) processed"
        )));
    }

    // Tracking pass: the picks of control and check points travel together.
    let all: Vec<_> = seen.control.iter().chain(&seen.check).collect();
    let klt = Klt::new(KltSettings::default());
    let template = {
        let bgr = FrameReader::frame_bgr(video, pick_frame).map_err(|e| bad_input(anyhow!(e)))?;
        let mut gray = opencv::core::Mat::default();
        opencv::imgproc::cvt_color_def(&bgr, &mut gray, opencv::imgproc::COLOR_BGR2GRAY)?;
        klt.frame(pick_frame, gray).map_err(|e| anyhow!(e))?
    };
    let settings = StabiliseSettings {
        min_features: args.min_features,
        min_fraction: args.key_fraction,
        max_interval: args
            .key_every
            .map(|s| (s * reader.fps).round().max(1.0) as usize),
        ..StabiliseSettings::default()
    };
    let mut stab = Stabiliser::new(
        Klt::new(KltSettings::default()),
        settings,
        (reader.width, reader.height),
        template,
        pick_frame,
        all.iter().map(|o| o.uv).collect(),
    );
    let bar = super::progress_bar(
        args.quiet,
        total.unwrap_or(0) as u64,
        "tracking {bar:40} {pos}/{len} frames, {msg} [{elapsed_precise}<{eta_precise}]",
    );
    let mut tracks: Vec<FrameTrack> = Vec::new();
    let mut keys = 0;
    while last_frame.is_none_or(|l| tracks.len() < l) {
        let Some((i, gray)) = reader
            .next_gray()
            .map_err(|e| anyhow!("{}: {e}", video.display()))?
        else {
            break;
        };
        let frame = klt.frame(i, gray).map_err(|e| anyhow!(e))?;
        let t = stab.push(i, frame).map_err(|e| anyhow!("frame {i}: {e}"))?;
        keys += usize::from(t.key.is_some());
        tracks.push(t);
        bar.inc(1);
        bar.set_message(format!("{keys} key frame(s)"));
    }
    bar.finish_and_clear();
    if tracks.len() <= pick_frame {
        return Err(bad_input(anyhow!(
            "{}: the video has {} frame(s); the picks are on frame {pick_frame}",
            video.display(),
            tracks.len()
        )));
    }

    // Poses: control picks only; the check picks are evaluated afterwards.
    let nc = seen.control.len();
    let gcps: Vec<HoverGcp> = seen
        .control
        .iter()
        .map(|o| HoverGcp {
            name: o.name.clone(),
            world: o.world,
            world_cov: o.world_cov,
            sigma_px: o.sigma_px,
        })
        .collect();
    let control_tracks: Vec<FrameTrack> = tracks
        .iter()
        .map(|t| FrameTrack {
            picks: t.picks[..nc].to_vec(),
            ..t.clone()
        })
        .collect();
    let pose_settings = PoseSettings {
        threshold_px: args.threshold,
        seed: args.seed,
        loss: args.loss,
        ..PoseSettings::default()
    };
    let result = solve_hover(&camera, &gcps, &control_tracks, &pose_settings, &NoProgress)
        .map_err(|e| bad_input(anyhow!("{}: {e}", video.display())))?;

    let check_mean: Vec<Option<f64>> = tracks
        .iter()
        .zip(&result.frames)
        .map(|(t, f)| {
            let errs: Vec<f64> = seen
                .check
                .iter()
                .enumerate()
                .filter_map(|(k, o)| {
                    Some(
                        (t.picks[nc + k]? - project_pose(&camera, &f.cam_from_world, &o.world)?.0)
                            .norm(),
                    )
                })
                .collect();
            (!errs.is_empty()).then(|| errs.iter().sum::<f64>() / errs.len() as f64)
        })
        .collect();
    let run = Run {
        camera: &camera,
        result: &result,
        tracks: &tracks,
        check_mean: &check_mean,
        fps: reader.fps,
        framed: &framed,
        seen: &seen,
    };
    let written = write_outputs(out, &run)?;

    // Report.
    let means: Vec<(usize, f64)> = result
        .frames
        .iter()
        .filter_map(|f| f.mean_reprojection_px.map(|m| (f.index, m)))
        .collect();
    let mean = means.iter().map(|m| m.1).sum::<f64>() / means.len().max(1) as f64;
    let worst = means
        .iter()
        .copied()
        .fold((0, 0.0), |a, b| if b.1 > a.1 { b } else { a });
    let interpolated = result.frames.iter().filter(|f| f.interpolated).count();
    let key_idx: Vec<usize> = result.key_frames.iter().map(|k| k.index).collect();
    let failed: Vec<usize> = result
        .key_frames
        .iter()
        .filter(|k| k.solution.is_err())
        .map(|k| k.index)
        .collect();
    let shifts: Vec<f64> = result
        .joint
        .points
        .iter()
        .zip(&gcps)
        .map(|(p, g)| (p - g.world).norm())
        .collect();
    let check_all: Vec<f64> = check_mean.iter().flatten().copied().collect();
    let check_avg =
        (!check_all.is_empty()).then(|| check_all.iter().sum::<f64>() / check_all.len() as f64);
    let t = framed.frame.tangent.as_ref();
    let summary = Summary {
        video: video.display().to_string(),
        frames: tracks.len(),
        fps: reader.fps,
        image_size: [reader.width, reader.height],
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
        key_frames: key_idx.clone(),
        key_frames_failed: failed.clone(),
        frames_interpolated: interpolated,
        mean_reprojection_px: mean,
        max_reprojection_px: worst.1,
        check_mean_reprojection_px: check_avg,
        joint_chi2: result.joint.chi2,
        largest_gcp_shift_m: shifts.iter().copied().fold(0.0, f64::max),
    };
    let json_path = out.join("pose.json");
    write_atomic(
        &json_path,
        serde_json::to_string_pretty(&summary)?.as_bytes(),
    )
    .with_context(|| json_path.display().to_string())?;

    let mut s = String::new();
    writeln!(
        s,
        "Video {}: {} frame(s) of {}x{} at {:.3} fps; picks of {} control and {} check point(s) on frame {pick_frame}",
        video.display(),
        tracks.len(),
        reader.width,
        reader.height,
        reader.fps,
        nc,
        seen.check.len()
    )?;
    if let Some(n) = note {
        writeln!(s, "  note: {n}")?;
    }
    writeln!(s, "  camera: {camera_source}")?;
    writeln!(
        s,
        "Key frames: {} ({})",
        key_idx.len(),
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
        gcps.len(),
        result.joint.chi2,
        summary.largest_gcp_shift_m
    )?;
    writeln!(
        s,
        "Frames: {} solved, {} interpolated; mean reprojection error {:.3} px (worst frame {} at {:.3} px)",
        tracks.len() - interpolated,
        interpolated,
        mean,
        worst.0,
        worst.1
    )?;
    if let Some(c) = check_avg {
        writeln!(s, "Check points: mean reprojection error {c:.3} px")?;
    }
    for w in written {
        writeln!(s, "Written: {}", w.display())?;
    }
    print!("{s}");
    Ok(())
}

/// What a video run produced, for the output files.
struct Run<'a> {
    camera: &'a Camera,
    result: &'a HoverResult,
    tracks: &'a [FrameTrack],
    check_mean: &'a [Option<f64>],
    fps: f64,
    framed: &'a super::survey::Framed,
    seen: &'a super::pose::Seen,
}

/// Writes the per-frame, key-frame and GCP tables and the plot; returns the paths.
fn write_outputs(out: &Path, run: &Run) -> anyhow::Result<Vec<std::path::PathBuf>> {
    let Run {
        camera,
        result: r,
        tracks,
        check_mean,
        fps,
        framed,
        seen,
    } = *run;
    let mut written = Vec::new();
    let mut put = |name: &str, text: String| -> anyhow::Result<()> {
        let p = out.join(name);
        write_atomic(&p, text.as_bytes()).with_context(|| p.display().to_string())?;
        written.push(p);
        Ok(())
    };
    let mut poses = String::from(
        "frame,time_s,key,reference,interpolated,features,feature_inliers,picks_used,mean_reprojection_px,max_reprojection_px,centre_e_m,centre_n_m,centre_u_m,sigma_e_m,sigma_n_m,sigma_u_m,x,y,z,yaw_deg,pitch_deg,roll_deg,off_nadir_deg,rvec_x,rvec_y,rvec_z,tvec_x,tvec_y,tvec_z\n",
    );
    let mut reproj = String::from(
        "frame,time_s,key,picks_used,mean_reprojection_px,max_reprojection_px,check_mean_reprojection_px\n",
    );
    for ((f, t), chk) in r.frames.iter().zip(tracks).zip(check_mean) {
        let time = f.index as f64 / fps;
        let c = f.cam_from_world.centre();
        let src = framed
            .frame
            .source_from_local(&c)
            .map_err(|e| anyhow!("camera position to the GCP file's CRS: {e}"))?;
        let att = Attitude::from_world_from_cam(&f.cam_from_world.rotation.inverse().into_inner());
        let pose: Pose = f.cam_from_world.into();
        let rv = rvec_of(&pose);
        let tv = f.cam_from_world.translation;
        let sg = f.centre_sigma_m;
        writeln!(
            poses,
            "{},{time:.6},{},{},{},{},{},{},{},{},{:.4},{:.4},{:.4},{},{},{},{:.4},{:.4},{:.4},{:.5},{:.5},{:.5},{:.5},{:.9},{:.9},{:.9},{:.6},{:.6},{:.6}",
            f.index,
            u8::from(f.key),
            t.reference,
            u8::from(f.interpolated),
            t.features,
            t.inliers,
            f.picks_used,
            csv_num(f.mean_reprojection_px, 4),
            csv_num(f.max_reprojection_px, 4),
            c.x,
            c.y,
            c.z,
            csv_num(sg.map(|s| s.x), 4),
            csv_num(sg.map(|s| s.y), 4),
            csv_num(sg.map(|s| s.z), 4),
            src.x,
            src.y,
            src.z,
            att.yaw_deg,
            att.pitch_deg,
            att.roll_deg,
            att.off_nadir_deg,
            rv.x,
            rv.y,
            rv.z,
            tv.x,
            tv.y,
            tv.z
        )?;
        writeln!(
            reproj,
            "{},{time:.6},{},{},{},{},{}",
            f.index,
            u8::from(f.key),
            f.picks_used,
            csv_num(f.mean_reprojection_px, 4),
            csv_num(f.max_reprojection_px, 4),
            csv_num(*chk, 4)
        )?;
    }
    put("poses.csv", poses)?;
    put("reprojection.csv", reproj)?;

    let mut keys =
        String::from("frame,time_s,reason,features,picks,inliers,outliers,rms_px,sigma0,error\n");
    for k in &r.key_frames {
        let t = tracks.iter().find(|t| t.index == k.index);
        match &k.solution {
            Ok(s) => writeln!(
                keys,
                "{},{:.6},{},{},{},{},{},{:.4},{:.3},",
                k.index,
                k.index as f64 / fps,
                k.reason.as_str(),
                t.map_or(0, |t| t.features),
                k.picks,
                s.inliers,
                k.picks - s.inliers,
                s.rms_px,
                s.sigma0
            )?,
            Err(e) => writeln!(
                keys,
                "{},{:.6},{},{},{},,,,,\"{}\"",
                k.index,
                k.index as f64 / fps,
                k.reason.as_str(),
                t.map_or(0, |t| t.features),
                k.picks,
                e.to_string().replace('"', "'")
            )?,
        }
    }
    put("key_frames.csv", keys)?;

    let mut g = String::from(
        "name,e_m,n_m,u_m,shift_e_m,shift_n_m,shift_u_m,sigma_e_m,sigma_n_m,sigma_u_m,x,y,z\n",
    );
    for ((o, p), c) in seen
        .control
        .iter()
        .zip(&r.joint.points)
        .zip(&r.joint.point_cov)
    {
        let d = p - o.world;
        let src = framed
            .frame
            .source_from_local(p)
            .map_err(|e| anyhow!("GCP {} to the file's CRS: {e}", o.name))?;
        let sd = |m: &Matrix3<f64>, k: usize| m[(k, k)].max(0.0).sqrt();
        writeln!(
            g,
            "{},{:.4},{:.4},{:.4},{:.4},{:.4},{:.4},{:.4},{:.4},{:.4},{:.4},{:.4},{:.4}",
            o.name,
            p.x,
            p.y,
            p.z,
            d.x,
            d.y,
            d.z,
            sd(c, 0),
            sd(c, 1),
            sd(c, 2),
            src.x,
            src.y,
            src.z
        )?;
    }
    put("gcps_adjusted.csv", g)?;

    // The paper's Fig. 13: mean reprojection error per frame, and the level the survey's
    // uncertainty alone explains.
    let mean: Vec<(f64, f64)> = r
        .frames
        .iter()
        .map(|f| {
            (
                f.index as f64 / fps,
                f.mean_reprojection_px.unwrap_or(f64::NAN),
            )
        })
        .collect();
    let mut series = vec![Series {
        label: "mean reprojection error".into(),
        xy: mean,
        rgb: [0, 0, 0],
        style: Style::Line,
    }];
    if check_mean.iter().any(Option::is_some) {
        series.push(Series {
            label: "check points".into(),
            xy: r
                .frames
                .iter()
                .zip(check_mean)
                .map(|(f, c)| (f.index as f64 / fps, c.unwrap_or(f64::NAN)))
                .collect(),
            rgb: [230, 120, 0],
            style: Style::Line,
        });
    }
    if let Some(level) = survey_level_px(r, seen, camera) {
        series.push(Series {
            label: format!("GCP survey sigma ({level:.2} px)"),
            xy: vec![
                (0.0, level),
                (tracks.len().saturating_sub(1) as f64 / fps, level),
            ],
            rgb: [150, 150, 150],
            style: Style::Dashed,
        });
    }
    let chart = Chart {
        title: "Mean reprojection error of the GCPs per frame".into(),
        x_label: "time (s)".into(),
        y_label: "pixels".into(),
        series,
        ticks: r.key_frames.iter().map(|k| k.index as f64 / fps).collect(),
        ticks_label: "key frames".into(),
    };
    let png = out.join("reprojection.png");
    line_chart(&chart, 1200, 500)
        .and_then(|c| c.save(&png))
        .map_err(|e| anyhow!(e))?;
    written.push(png);
    Ok(written)
}

/// The pixel error the GCPs' survey σ alone explains: the mean over GCPs of the horizontal σ
/// seen at its depth in the first solved key frame.
fn survey_level_px(r: &HoverResult, seen: &super::pose::Seen, camera: &Camera) -> Option<f64> {
    let pose: RigidPose = *r.joint.poses.first()?;
    let focal = 0.5 * (camera.fx + camera.fy);
    let mut sum = 0.0;
    for o in &seen.control {
        let depth = pose.apply(&o.world).z;
        if depth <= 0.0 {
            return None;
        }
        sum += focal * (0.5 * (o.world_cov[(0, 0)] + o.world_cov[(1, 1)])).sqrt() / depth;
    }
    Some(sum / seen.control.len() as f64)
}
