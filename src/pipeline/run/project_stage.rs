//! Stage 4, `project`.

use std::collections::BTreeMap;
use std::time::Instant;

use serde::{Deserialize, Serialize};

use super::{Env, PoseData, RunError, RunInputs, StageRecord, WorldTrack, cached_seq};
use crate::cache::stage_key;
use crate::geom::Rigid3;
use crate::pipeline::project::ProjectionSection;
use crate::pipeline::settings::GroundSection;
use crate::projection::project;
use crate::terrain::HeightSurface;
use crate::track::ImageTrack;

/// What the project stage's cache holds besides the projected tracks (`project.bin`, a track
/// at a time in order of identity).
#[derive(Clone, Debug, Serialize, Deserialize)]
pub(super) struct ProjectSummary {
    pub tracks: usize,
    pub points: usize,
    pub heights_given: usize,
}

/// Stage 4: image tracks to the head-height surface, read from the track stage's cache and
/// written to this stage's a batch of tracks at a time.
///
/// Reads the `[projection]` section (the ground's in its key: the surface it projects to),
/// the track and pose stages' keys and data.
pub(super) fn project_stage(
    env: &Env,
    x: &RunInputs,
    (projection, ground): (&ProjectionSection, &GroundSection),
    keys: [&str; 2],
    (tracks, pose_data, poses): (&super::track_stage::TrackSummary, &PoseData, &[Rigid3]),
    warnings: &mut Vec<String>,
) -> Result<(ProjectSummary, String, StageRecord), RunError> {
    let camera = &x.camera;
    let surface = &x.surface;
    let heights = &x.heights;
    let project_key = stage_key(
        "project",
        &[keys[0], keys[1]],
        &(
            projection,
            ground,
            &heights
                .iter()
                .map(|(k, v)| (*k, v.0, v.1))
                .collect::<Vec<_>>(),
        ),
    );
    let t0 = Instant::now();
    let (summary, status) = cached_seq(&env.cache, env.progress, "project", &project_key, || {
        let one = |t: &ImageTrack, surface: &dyn HeightSurface| -> (WorldTrack, usize) {
            let (h, sd, source) = match heights.get(&t.id) {
                Some((h, sd)) => (*h, *sd, "given"),
                None => (
                    projection.head_height_m,
                    projection.head_height_sd_m,
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
        let mut summary = ProjectSummary {
            tracks: tracks.tracks,
            points: 0,
            heights_given: 0,
        };
        let mut dropped = 0;
        env.cache
            .store_seq::<_, RunError>("project", &project_key, tracks.tracks, |push| {
                env.cache.read_batches::<_, RunError>(
                    "track",
                    keys[0],
                    |t: &ImageTrack| t.points.len(),
                    |batch| {
                        // Tracks are independent: side by side where the surface can be
                        // shared, in order.
                        let projected: Vec<(WorldTrack, usize)> = match surface.shareable() {
                            Some(shared) => {
                                use rayon::prelude::*;
                                batch.par_iter().map(|t| one(t, shared)).collect()
                            }
                            None => batch.iter().map(|t| one(t, surface.as_ref())).collect(),
                        };
                        for (t, d) in &projected {
                            dropped += d;
                            summary.points += t.points.len();
                            summary.heights_given += usize::from(t.height_source == "given");
                            push(t)?;
                        }
                        Ok(())
                    },
                )
            })?;
        if dropped > 0 {
            warnings.push(format!(
                "{dropped} detection(s) could not be projected (off the ground surface)"
            ));
        }
        Ok(summary)
    })?;
    let record = StageRecord {
        name: "project".into(),
        status,
        seconds: t0.elapsed().as_secs_f64(),
        counts: BTreeMap::from([
            ("points".into(), summary.points as f64),
            ("heights_given".into(), summary.heights_given as f64),
        ]),
    };

    Ok((summary, project_key, record))
}
