//! Stage 2, `pose`.

use std::collections::BTreeMap;
use std::time::Instant;

use super::pose_source::PoseSource;
use super::{Env, PoseData, RunError, RunInputs, ScanData, StageRecord, cached};

/// Stage 2: a pose for every frame from the project's pose source, and the `pose/` files.
pub(super) fn pose_stage(
    env: &Env,
    x: &RunInputs,
    source: &dyn PoseSource,
    scan_key: &str,
    scan_data: &ScanData,
    warnings: &mut Vec<String>,
) -> Result<(PoseData, String, StageRecord), RunError> {
    let pose_key = source.stage_key(scan_key);
    let t0 = Instant::now();
    let pose_dir = env.out.join("pose");
    let (pose_data, status) = cached(
        &env.cache,
        env.progress,
        "pose",
        &pose_key,
        pose_dir.join("poses.csv").is_file(),
        || source.poses(env, x, scan_data, &pose_dir),
    )?;
    let notes = source.notes();
    if !pose_data.key_frames_failed.is_empty() {
        warnings.push(format!(
            "{}: {:?}",
            notes.failed, pose_data.key_frames_failed
        ));
    }
    let interpolated = pose_data.frames.iter().filter(|f| f.interpolated).count();
    if interpolated > 0 {
        warnings.push(format!(
            "{interpolated} frame(s) have interpolated poses{}",
            notes.interpolated
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
    counts.extend(source.own_counts(&pose_data));
    let record = StageRecord {
        name: "pose".into(),
        status,
        seconds: t0.elapsed().as_secs_f64(),
        counts,
    };
    Ok((pose_data, pose_key, record))
}
