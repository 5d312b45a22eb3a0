//! Stage 4, `project`.

use std::collections::BTreeMap;
use std::time::Instant;

use serde::{Deserialize, Serialize};

use super::prepare::Bodies;
use super::{Env, PoseData, RunError, RunInputs, StageRecord, WorldTrack, cached_seq};
use crate::cache::stage_key;
use crate::camera::Camera;
use crate::geom::Rigid3;
use crate::pipeline::project::ProjectionSection;
use crate::pipeline::settings::GroundSection;
use crate::projection::body::{
    BoxError, View, combine_heights, excess_height_var, ground_from_box,
};
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
        let image_wh = (f64::from(x.size.0), f64::from(x.size.1));
        let bodies = x.bodies.as_ref();
        let one = |t: &ImageTrack, surface: &dyn HeightSurface| -> (WorldTrack, usize) {
            let given = heights.get(&t.id).copied();
            let seen = Seen {
                camera,
                poses,
                pose_data,
                surface,
                image_wh,
            };
            match bodies {
                Some(b) => seen.bodies(t, b, given, projection),
                None => seen.heads(t, given, projection),
            }
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

/// What a track's points are projected through.
struct Seen<'a> {
    camera: &'a Camera,
    poses: &'a [Rigid3],
    pose_data: &'a PoseData,
    surface: &'a dyn HeightSurface,
    image_wh: (f64, f64),
}

/// A person's height: given, else the default, with its σ and where it came from.
fn height_of(
    given: Option<(f64, f64)>,
    projection: &ProjectionSection,
) -> (f64, f64, &'static str) {
    match given {
        Some((h, sd)) => (h, sd, "given"),
        None => (
            projection.head_height_m,
            projection.head_height_sd_m,
            "default",
        ),
    }
}

impl Seen<'_> {
    fn view(&self, frame: usize) -> View<'_> {
        View {
            camera: self.camera,
            cam_from_world: &self.poses[frame],
            pose_cov: self.pose_data.frames[frame].covariance.as_ref(),
            surface: self.surface,
            image_wh: self.image_wh,
        }
    }

    /// Heads (hats) projected through the head-height surface.
    fn heads(
        &self,
        t: &ImageTrack,
        given: Option<(f64, f64)>,
        projection: &ProjectionSection,
    ) -> (WorldTrack, usize) {
        let (h, sd, source) = height_of(given, projection);
        world_track(t, (h, sd, source), |q| {
            let fp = &self.pose_data.frames[q.frame];
            project(
                self.camera,
                &self.poses[q.frame],
                fp.covariance.as_ref(),
                self.surface,
                &q.uv,
                &q.cov,
                h,
                sd,
            )
        })
    }

    /// Whole bodies' boxes read for both ends (`projection::body`): the person's height from
    /// every box that shows both, unless given, then each box's ground position at it.
    fn bodies(
        &self,
        t: &ImageTrack,
        b: &Bodies,
        given: Option<(f64, f64)>,
        projection: &ProjectionSection,
    ) -> (WorldTrack, usize) {
        let (mut h, mut sd, mut source) = height_of(given, projection);
        let mut excess = 0.0;
        let width = self.image_wh.0;
        // The box's position error is the tracker's; its length's is the detector's at its
        // feet end (the tracker follows the head end).
        let error = |q: &crate::track::TrackPoint| {
            let feet = nalgebra::Vector2::new(q.bbox[0] + q.bbox[2] / 2.0, q.bbox[1] + q.bbox[3]);
            let e = b.error.cov(&feet, width);
            BoxError {
                position_px2: q.cov,
                length_px2: 0.5 * (e[(0, 0)] + e[(1, 1)]),
            }
        };
        // One box read with its head height free about (h, σ), and the height it says.
        let read = |q: &crate::track::TrackPoint, height: (f64, f64)| {
            ground_from_box(
                &self.view(q.frame),
                &b.shape,
                &q.bbox,
                &error(q),
                height,
                true,
            )
        };
        if given.is_none() {
            let said: Vec<_> = t
                .points
                .iter()
                .filter_map(|q| read(q, (h, sd)))
                .filter_map(|f| f.height)
                .collect();
            if !said.is_empty() {
                (h, sd) = combine_heights((h, sd), &said);
                source = "boxes";
            }
            excess = excess_height_var(&said).unwrap_or(0.0);
        }
        // Each box's position is solved with its head height free about the person's: the
        // head end then weighs by how well this frame's head height is known (the person's σ
        // and the boxes' scatter beyond their pixel error), not as if it were exact.
        let frame_sd = (sd * sd + excess).sqrt();
        world_track(t, (h, sd, source), |q| {
            read(q, (h, frame_sd)).map(|f| f.point)
        })
    }
}

/// A track's points projected by `each` (None: off the ground surface, dropped) at the height
/// `(height, σ, source)`; and how many were dropped.
fn world_track(
    t: &ImageTrack,
    (h, sd, source): (f64, f64, &str),
    each: impl Fn(&crate::track::TrackPoint) -> Option<crate::projection::WorldPoint>,
) -> (WorldTrack, usize) {
    let (mut points, mut scores) = (Vec::new(), Vec::new());
    let mut dropped = 0;
    for q in &t.points {
        match each(q) {
            Some(w) => {
                points.push((q.frame, w));
                scores.push(q.score);
            }
            None => dropped += 1,
        }
    }
    let track = WorldTrack {
        id: t.id,
        height_m: h,
        height_sd_m: sd,
        height_source: source.into(),
        points,
        scores,
    };
    (track, dropped)
}
