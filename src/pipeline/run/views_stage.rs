//! Stage 7, `views`: the report's plots, the rectified site image and the annotated video
//! (`pipeline::views`). Not cached: made again by every run (and by `geostride render`).

use super::*;
use crate::pipeline::views::{GcpMark, Views, make_views};

/// Makes the views the project asks for; their (title, file) and the stage's record (none when
/// nothing is asked for).
pub(super) fn views_stage(
    ctx: &Ctx,
    pose_data: &PoseData,
    smooth_key: &str,
    warnings: &mut Vec<String>,
) -> Result<(Vec<(String, String)>, Option<StageRecord>), RunError> {
    let p = &ctx.l.project;
    let o = &p.output;
    if !(o.plots || o.site_image || o.video) {
        return Ok((Vec::new(), None));
    }
    let t0 = Instant::now();
    // The views draw from every trajectory at once (the fundamental diagram's frames, the
    // annotated video's): read back whole, the one stage whose memory grows with the video.
    let trajectories: Vec<Trajectory> = ctx
        .cache
        .load_seq::<Trajectory>("smooth", smooth_key)
        .ok_or_else(|| cache_gone(&ctx.cache, "smooth"))?
        .collect::<std::io::Result<_>>()
        .map_err(|e| RunError::Failed(e.to_string()))?;
    let mut poses: Vec<Option<Rigid3>> = vec![None; ctx.frames_total];
    for f in &pose_data.frames {
        if let Some(slot) = poses.get_mut(f.frame) {
            *slot = Some(f.pose());
        }
    }
    let framed = &ctx.framed;
    let gcps = framed
        .survey
        .points
        .iter()
        .zip(&framed.local)
        .filter(|(g, _)| g.role != crate::survey::Role::Disabled)
        .map(|(g, local)| GcpMark {
            name: g.name.clone(),
            local: *local,
            control: g.role == crate::survey::Role::Control,
        })
        .collect();
    let transform = &ctx.transform;
    let to_crs = |en: &Vector2<f64>| -> Option<Vector2<f64>> {
        let src = framed
            .frame
            .source_from_local(&Vector3::new(en.x, en.y, 0.0))
            .ok()?;
        match transform {
            Some(t) => t.apply(src.x, src.y).ok().map(|(x, y)| Vector2::new(x, y)),
            None => Some(src.xy()),
        }
    };
    let out_crs = ctx.out_crs.as_ref().or(framed.frame.crs.as_ref());
    let views = Views {
        out: ctx.out,
        video: &ctx.video,
        title: if p.name.is_empty() {
            ctx.l.path.display().to_string()
        } else {
            p.name.clone()
        },
        fps: ctx.fps,
        size: ctx.size,
        frames: ctx.frames_total,
        camera: &ctx.camera,
        poses: &poses,
        key_frames: &pose_data.key_frames,
        trajs: &trajectories,
        gcps,
        ground: ctx.surface.as_ref(),
        to_crs: Some(&to_crs),
        crs_wkt: out_crs.map(|c| c.wkt.clone()).unwrap_or_default(),
        crs_label: out_crs.map_or("the survey's local frame".into(), |c| c.label()),
        settings: o,
        analysis: &p.analysis,
    };
    let bar = ctx.progress.stage("views");
    if o.video {
        bar.set_length(ctx.frames_total as u64);
    }
    let made =
        make_views(&views, bar.as_ref()).map_err(|e| RunError::Failed(format!("views: {e}")))?;
    warnings.extend(made.warnings);
    let record = StageRecord {
        name: "views".into(),
        status: "computed".into(),
        seconds: t0.elapsed().as_secs_f64(),
        counts: BTreeMap::from([("files".into(), made.files.len() as f64)]),
    };
    Ok((made.files, Some(record)))
}
