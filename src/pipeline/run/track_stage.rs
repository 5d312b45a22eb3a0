//! Stage 3, `track`.

use super::*;
use crate::pipeline::registry::{TrackScale, TrackerChoice};

/// Stage 3: image tracks.
pub(super) fn track_stage(
    ctx: &Ctx,
    scan_key: &str,
    pose_key: &str,
    scan_data: &ScanData,
    poses: &[Rigid3],
) -> Result<(Vec<ImageTrack>, String, StageRecord), RunError> {
    let progress = ctx.progress;
    let video = &ctx.video;
    let fps = ctx.fps;
    let camera = &ctx.camera;
    let surface = &ctx.surface;
    let px_per_m = ctx.px_per_m;
    let p = &ctx.l.project;
    let track_key = stage_key("track", &[scan_key, pose_key], &p.track);
    let t0 = Instant::now();
    let head = p.projection.head_height_m;
    let (tracks, status) = cached(&ctx.cache, ctx.progress, "track", &track_key, true, || {
        // Camera motion: where a head-height point of the previous frame is now.
        let motion_at = |f: usize, uv: &Vector2<f64>| -> Vector2<f64> {
            if f == 0 {
                return *uv;
            }
            crate::projection::intersect(camera, &poses[f - 1], surface.as_ref(), head, uv)
                .and_then(|x| camera.project(&poses[f].apply(&x)).ok())
                .unwrap_or(*uv)
        };
        let bar = progress.stage("track");
        bar.set_length(scan_data.detections.len() as u64);
        let scale = TrackScale {
            px_per_m,
            fps,
            duplicate_px: p.detect.duplicate_m() * px_per_m,
        };
        let tracks = match crate::pipeline::registry::tracker(&p.track, &scale) {
            TrackerChoice::Klt(k) => crate::pipeline::klt_pass::klt_over_video(
                &KltPass {
                    video,
                    detections: &scan_data.detections,
                    size: (scan_data.width, scan_data.height),
                    fps: scan_data.fps,
                    track: k,
                    person_m: p.detect.person_m(),
                    px_per_m,
                },
                &motion_at,
                bar.as_ref(),
            )
            .map_err(RunError::Failed)?,
            TrackerChoice::Frames(mut tracker) => {
                for (f, dets) in scan_data.detections.iter().enumerate() {
                    tracker.update(f, dets, &|uv: &Vector2<f64>| motion_at(f, uv));
                    bar.inc(1);
                }
                tracker.finish()
            }
        };
        // Short tracks are mostly false alarms, unless the video's start or end cut them.
        let min_frames = (p.track.min_length_s() * fps).round() as usize;
        let last = scan_data.detections.len().saturating_sub(1);
        let tracks: Vec<ImageTrack> = tracks
            .into_iter()
            .filter(|t| {
                let (a, b) = (
                    t.points.first().map_or(0, |q| q.frame),
                    t.points.last().map_or(0, |q| q.frame),
                );
                b - a + 1 >= min_frames || a == 0 || b == last
            })
            .collect();
        Ok(tracks)
    })?;
    let lengths: Vec<f64> = tracks.iter().map(|t| t.points.len() as f64 / fps).collect();
    let record = StageRecord {
        name: "track".into(),
        status: status.into(),
        seconds: t0.elapsed().as_secs_f64(),
        counts: BTreeMap::from([
            ("tracks".into(), tracks.len() as f64),
            (
                "points".into(),
                tracks.iter().map(|t| t.points.len()).sum::<usize>() as f64,
            ),
            (
                "mean_length_s".into(),
                lengths.iter().sum::<f64>() / lengths.len().max(1) as f64,
            ),
        ]),
    };

    Ok((tracks, track_key, record))
}
