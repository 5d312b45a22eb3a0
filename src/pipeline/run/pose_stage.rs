//! Stage 2, `pose`.

use super::*;

/// Stage 2: a pose for every frame, and the `pose/` files.
pub(super) fn pose_stage(
    ctx: &Ctx,
    scan_key: &str,
    scan_data: &ScanData,
    warnings: &mut Vec<String>,
) -> Result<(PoseData, String, StageRecord), RunError> {
    if let crate::pipeline::settings::PoseSection::Model(m) = &ctx.l.project.pose {
        return super::model_pose::model_pose_stage(ctx, m, scan_key, scan_data, warnings);
    }
    let out = ctx.out;
    let progress = ctx.progress;
    let guard = &ctx.guard;
    let video = &ctx.video;
    let fps = ctx.fps;
    let camera = &ctx.camera;
    let framed = &ctx.framed;
    let control = &ctx.control;
    let check = &ctx.check;
    let p = &ctx.l.project;
    let pose_key = stage_key("pose", &[scan_key], &(&p.survey, &p.pose));
    let t0 = Instant::now();
    let pose_dir = out.join("pose");
    let (pose_data, status) = cached(
        &ctx.cache,
        ctx.progress,
        "pose",
        &pose_key,
        pose_dir.join("poses.csv").is_file(),
        || {
            let (result, check_mean) = solve_with_checks(
                camera,
                control,
                check,
                &scan_data.tracks,
                &PoseSettings::default(),
                progress.stage("pose").as_ref(),
            )
            .map_err(|e| RunError::Unusable(format!("{}: {e}", video.display())))?;
            guard.create_dir(&pose_dir).map_err(output_error)?;
            write_pose_outputs(
                &pose_dir,
                &PoseRun {
                    camera,
                    result: &result,
                    tracks: &scan_data.tracks,
                    check_mean: &check_mean,
                    fps,
                    framed,
                    control,
                },
            )?;
            let means: Vec<f64> = result
                .frames
                .iter()
                .filter_map(|f| f.mean_reprojection_px)
                .collect();
            let checks: Vec<f64> = check_mean.iter().flatten().copied().collect();
            let d = PoseData {
                frames: result
                    .frames
                    .iter()
                    .map(|f| FramePoseData {
                        frame: f.index,
                        rotation: *f.cam_from_world.rotation.matrix(),
                        translation: f.cam_from_world.translation,
                        covariance: f.covariance,
                        interpolated: f.interpolated,
                        mean_reprojection_px: f.mean_reprojection_px,
                    })
                    .collect(),
                key_frames: result.key_frames.iter().map(|k| k.index).collect(),
                key_frames_failed: result.failed_key_frames(),
                mean_reprojection_px: means.iter().sum::<f64>() / means.len().max(1) as f64,
                max_reprojection_px: means.iter().copied().fold(0.0, f64::max),
                check_mean_reprojection_px: (!checks.is_empty())
                    .then(|| checks.iter().sum::<f64>() / checks.len() as f64),
            };
            Ok(d)
        },
    )?;
    if !pose_data.key_frames_failed.is_empty() {
        warnings.push(format!(
            "key frames not solved (too few carried picks): {:?}",
            pose_data.key_frames_failed
        ));
    }
    let interpolated = pose_data.frames.iter().filter(|f| f.interpolated).count();
    if interpolated > 0 {
        warnings.push(format!(
            "{interpolated} frame(s) have interpolated poses (fewer than 4 usable picks)"
        ));
    }
    let mut counts = BTreeMap::from([
        ("key_frames".into(), pose_data.key_frames.len() as f64),
        (
            "mean_reprojection_px".into(),
            pose_data.mean_reprojection_px,
        ),
        ("max_reprojection_px".into(), pose_data.max_reprojection_px),
        ("interpolated_frames".into(), interpolated as f64),
    ]);
    if let Some(c) = pose_data.check_mean_reprojection_px {
        counts.insert("check_mean_reprojection_px".into(), c);
    }
    let record = StageRecord {
        name: "pose".into(),
        status,
        seconds: t0.elapsed().as_secs_f64(),
        counts,
    };

    Ok((pose_data, pose_key, record))
}
