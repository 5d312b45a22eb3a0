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
            let one = |t: &ImageTrack, surface: &dyn HeightSurface| -> (WorldTrack, usize) {
                let (h, sd, source) = match heights.get(&t.id) {
                    Some((h, sd)) => (*h, *sd, "given"),
                    None => (
                        p.projection.head_height_m,
                        p.projection.head_height_sd_m,
                        "default",
                    ),
                };
                let mut points = Vec::new();
                let mut dropped = 0;
                for q in &t.points {
                    let fp = &pose_data.frames[q.frame];
                    match project(
                        camera,
                        &poses[q.frame],
                        fp.covariance.as_ref(),
                        surface,
                        &q.uv,
                        &q.cov,
                        h,
                        sd,
                    ) {
                        Some(w) => points.push((q.frame, w)),
                        None => dropped += 1,
                    }
                }
                let track = WorldTrack {
                    id: t.id,
                    height_m: h,
                    height_sd_m: sd,
                    height_source: source.into(),
                    points,
                };
                (track, dropped)
            };
            // Tracks are independent: side by side where the surface can be shared, in order.
            let projected: Vec<(WorldTrack, usize)> = match surface.shareable() {
                Some(shared) => {
                    use rayon::prelude::*;
                    tracks.par_iter().map(|t| one(t, shared)).collect()
                }
                None => tracks.iter().map(|t| one(t, surface.as_ref())).collect(),
            };
            let dropped: usize = projected.iter().map(|(_, d)| d).sum();
            let world: Vec<WorldTrack> = projected.into_iter().map(|(t, _)| t).collect();
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
