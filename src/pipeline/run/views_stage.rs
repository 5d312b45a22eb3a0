//! Stage 7, `views`: the report's plots, the rectified site image and the annotated video
//! (`pipeline::views`). Not cached: made again by every run (and by `geostride render`).

use std::collections::BTreeMap;
use std::time::Instant;

use nalgebra::{Vector2, Vector3};

use super::{Env, PoseData, RunError, RunInputs, StageRecord, StageStatus};
use crate::cache::StageCache;
use crate::export::Trajectory;
use crate::geom::Rigid3;
use crate::pipeline::project::{AnalysisSection, OutputSection};
use crate::pipeline::views::{
    GcpMark, Trajectories, TrajectoryReader, ViewError, Views, make_views,
};

/// The smooth stage's trajectories, read from its cache for each pass of a view.
pub(super) struct Cached<'a> {
    pub(super) cache: &'a StageCache,
    pub(super) key: &'a str,
    pub(super) count: usize,
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
///
/// Reads the `[output]` section (which views) and the `[analysis]` one (the density plots'
/// areas), the pose stage's data and the smooth stage's trajectories.
pub(super) fn views_stage(
    env: &Env,
    x: &RunInputs,
    (o, analysis): (&OutputSection, &AnalysisSection),
    (pose_data, smooth_key, smoothed): (&PoseData, &str, &super::smooth_stage::SmoothSummary),
    warnings: &mut Vec<String>,
) -> Result<(Vec<(String, String)>, Option<StageRecord>), RunError> {
    if !(o.plots || o.site_image || o.video) {
        return Ok((Vec::new(), None));
    }
    let t0 = Instant::now();
    // Every view reads the trajectories back from the smooth stage's cache, one at a time, as
    // often as it needs them.
    let trajectories = Cached {
        cache: &env.cache,
        key: smooth_key,
        count: smoothed.trajectories,
    };
    let mut poses: Vec<Option<Rigid3>> = vec![None; x.frames_total];
    for f in &pose_data.frames {
        if let Some(slot) = poses.get_mut(f.frame) {
            *slot = Some(f.pose());
        }
    }
    let framed = &x.framed;
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
    let transform = &x.transform;
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
    let out_crs = x.out_crs.as_ref().or(framed.frame.crs.as_ref());
    let views = Views {
        out: env.out,
        video: &x.video,
        title: x.title.clone(),
        fps: x.fps,
        size: x.size,
        frames: x.frames_total,
        camera: &x.camera,
        poses: &poses,
        key_frames: &pose_data.key_frames,
        trajs: &trajectories,
        gcps,
        ground: x.surface.as_ref(),
        to_crs: Some(&to_crs),
        crs_wkt: out_crs.map(|c| c.wkt.clone()).unwrap_or_default(),
        crs_label: out_crs.map_or("the survey's local frame".into(), |c| c.label()),
        settings: o,
        analysis,
    };
    let bar = env.progress.stage("views");
    if o.video {
        bar.set_length(x.frames_total as u64);
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
