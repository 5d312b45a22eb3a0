//! Stage 7, `views`: the report's plots, the rectified site image and the annotated video
//! (`pipeline::views`). Not cached: made again by every run (and by `geostride render`).

use super::*;
use crate::pipeline::views::{
    GcpMark, Trajectories, TrajectoryReader, ViewError, Views, make_views,
};

/// The smooth stage's trajectories, read from its cache for each pass of a view.
struct Cached<'a> {
    cache: &'a StageCache,
    key: &'a str,
    count: usize,
}

impl Trajectories for Cached<'_> {
    fn count(&self) -> usize {
        self.count
    }

    fn read(&self) -> Result<TrajectoryReader<'_>, ViewError> {
        let seq = self
            .cache
            .read_seq::<Trajectory>("smooth", self.key)
            .map_err(|e| ViewError::Failed(e.to_string()))?;
        Ok(Box::new(
            seq.map(|t| t.map_err(|e| ViewError::Failed(e.to_string()))),
        ))
    }
}

/// Makes the views the project asks for; their (title, file) and the stage's record (none when
/// nothing is asked for).
pub(super) fn views_stage(
    ctx: &Ctx,
    pose_data: &PoseData,
    smooth_key: &str,
    smoothed: &super::smooth_stage::SmoothSummary,
    warnings: &mut Vec<String>,
) -> Result<(Vec<(String, String)>, Option<StageRecord>), RunError> {
    let p = &ctx.l.project;
    let o = &p.output;
    if !(o.plots || o.site_image || o.video) {
        return Ok((Vec::new(), None));
    }
    let t0 = Instant::now();
    // Every view reads the trajectories back from the smooth stage's cache, one at a time, as
    // often as it needs them.
    let trajectories = Cached {
        cache: &ctx.cache,
        key: smooth_key,
        count: smoothed.trajectories,
    };
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
        status: StageStatus::Computed,
        seconds: t0.elapsed().as_secs_f64(),
        counts: BTreeMap::from([("files".into(), made.files.len() as f64)]),
    };
    Ok((made.files, Some(record)))
}
