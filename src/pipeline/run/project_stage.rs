//! Stage 4, `project`.

use super::*;

/// Stage 4: image tracks to the head-height surface.
pub(super) fn project_stage(
    ctx: &Ctx,
    keys: [&str; 2],
    tracks: &[ImageTrack],
    pose_data: &PoseData,
    poses: &[Rigid3],
    warnings: &mut Vec<String>,
) -> Result<(Vec<WorldTrack>, String, StageRecord), RunError> {
    let camera = &ctx.camera;
    let surface = &ctx.surface;
    let heights = &ctx.heights;
    let p = &ctx.l.project;
    let project_key = stage_key(
        "project",
        &[keys[0], keys[1]],
        &(
            &p.projection,
            &p.ground,
            &heights
                .iter()
                .map(|(k, v)| (*k, v.0, v.1))
                .collect::<Vec<_>>(),
        ),
    );
    let t0 = Instant::now();
    let (world, status) = cached(
        &ctx.cache,
        ctx.progress,
        "project",
        &project_key,
        true,
        || {
            let mut world = Vec::new();
            let mut dropped = 0;
            for t in tracks {
                let (h, sd, source) = match heights.get(&t.id) {
                    Some((h, sd)) => (*h, *sd, "given"),
                    None => (
                        p.projection.head_height_m,
                        p.projection.head_height_sd_m,
                        "default",
                    ),
                };
                let mut points = Vec::new();
                for q in &t.points {
                    let fp = &pose_data.frames[q.frame];
                    match project(
                        camera,
                        &poses[q.frame],
                        fp.covariance.as_ref(),
                        surface.as_ref(),
                        &q.uv,
                        &q.cov,
                        h,
                        sd,
                    ) {
                        Some(w) => points.push((q.frame, w)),
                        None => dropped += 1,
                    }
                }
                world.push(WorldTrack {
                    id: t.id,
                    height_m: h,
                    height_sd_m: sd,
                    height_source: source.into(),
                    points,
                });
            }
            if dropped > 0 {
                warnings.push(format!(
                    "{dropped} detection(s) could not be projected (off the ground surface)"
                ));
            }
            Ok(world)
        },
    )?;
    let record = StageRecord {
        name: "project".into(),
        status: status.into(),
        seconds: t0.elapsed().as_secs_f64(),
        counts: BTreeMap::from([
            (
                "points".into(),
                world.iter().map(|t| t.points.len()).sum::<usize>() as f64,
            ),
            (
                "heights_given".into(),
                world.iter().filter(|t| t.height_source == "given").count() as f64,
            ),
        ]),
    };

    Ok((world, project_key, record))
}
