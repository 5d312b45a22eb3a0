//! The annotated video: each head with its identity, the last seconds of its track and the
//! 95 % ellipse of its position (the smoothed point projected back into the frame), GCPs and
//! key frames marked, the frame number as in every output.

use nalgebra::{Matrix2, Vector2, Vector3};
use opencv::core::{Mat, Size};
use opencv::prelude::*;

use super::{ViewError, Views, id_colour};
use crate::draw::Canvas;
use crate::progress::Progress;

/// χ² of 2 degrees of freedom at 95 %.
const CHI2_95: f64 = 5.991;

/// Writes `annotated.mp4` (or `.avi` where OpenCV cannot encode H.264).
pub(crate) fn annotated_video(
    v: &Views,
    progress: &dyn Progress,
) -> Result<(String, String), ViewError> {
    let (w, h) = v.size;
    let scale = (f64::from(v.settings.video_width) / f64::from(w)).min(1.0);
    let (ow, oh) = (
        ((f64::from(w) * scale).round() as u32) & !1,
        ((f64::from(h) * scale).round() as u32) & !1,
    );
    // The trajectories frame by frame, only those under way held.
    let mut sweep = super::FrameSweep::new(v.trajs)?;
    let mut next = sweep.next_frame()?;
    let trail = (v.settings.trail_s * v.fps).round() as usize;
    let keys: std::collections::BTreeSet<usize> = v.key_frames.iter().copied().collect();
    let mut sink = crate::video::FrameSink::create(&v.out.join("annotated"), ow, oh, v.fps)?;
    let thick = ((f64::from(ow) / 960.0).round() as i32).max(1);
    let text = 0.45 * f64::from(ow) / 1280.0;
    let text = text.max(0.35);
    let mut f = 0usize;
    // Decoding and reducing on a thread of their own, drawing here, encoding in ffmpeg's
    // process: the three side by side.
    let (frames_tx, frames_rx) =
        std::sync::mpsc::sync_channel::<Result<(usize, Mat), ViewError>>(3);
    let (video, total) = (v.video, v.frames);
    std::thread::scope(|scope| -> Result<(), ViewError> {
        scope.spawn(move || {
            let read = || -> Result<(), ViewError> {
                let mut reader = crate::video::source::FrameReader::open(video)?;
                for _ in 0..total {
                    let Some((index, bgr)) = reader.next_bgr()? else {
                        return Ok(());
                    };
                    // Reduced, or trimmed to the encoder's even size.
                    let frame = if (bgr.cols(), bgr.rows()) != (ow as i32, oh as i32) {
                        let mut small = Mat::default();
                        opencv::imgproc::resize(
                            &bgr,
                            &mut small,
                            Size::new(ow as i32, oh as i32),
                            0.0,
                            0.0,
                            opencv::imgproc::INTER_AREA,
                        )?;
                        small
                    } else {
                        bgr
                    };
                    if frames_tx.send(Ok((index, frame))).is_err() {
                        return Ok(());
                    }
                }
                Ok(())
            };
            if let Err(e) = read() {
                let _ = frames_tx.send(Err(e));
            }
        });
        for item in frames_rx.iter() {
            let (index, frame) = item?;
            while next.as_ref().is_some_and(|(f, _)| *f < index) {
                next = sweep.next_frame()?;
            }
            let who = match &next {
                Some((f, who)) if *f == index => &who[..],
                _ => &[],
            };
            draw_frame(
                v,
                index,
                frame,
                &mut sink,
                (scale, thick, text),
                (&sweep.live, who, trail, &keys),
            )?;
            progress.inc(1);
            f += 1;
        }
        Ok(())
    })?;
    let path = sink.finish()?;
    let name = path
        .file_name()
        .map(|n| n.to_string_lossy().into_owned())
        .unwrap_or_default();
    Ok((format!("Annotated video ({f} frames, {ow}x{oh})"), name))
}

/// The trajectories under way, each with its next point (`FrameSweep::live`).
type Live = [(crate::export::Trajectory, usize)];

/// Draws frame `index` (already at the output size) and appends it to `sink`.
fn draw_frame(
    v: &Views,
    index: usize,
    frame: Mat,
    sink: &mut crate::video::FrameSink,
    (scale, thick, text): (f64, i32, f64),
    (live, who, trail, keys): (
        &Live,
        &[(usize, usize)],
        usize,
        &std::collections::BTreeSet<usize>,
    ),
) -> Result<(), ViewError> {
    let ow = frame.cols() as u32;
    {
        let mut c = Canvas::from_bgr(frame);
        let im = |e| ViewError::Image(format!("frame {index}"), e);
        let to_out = |uv: Vector2<f64>| (uv + Vector2::repeat(0.5)) * scale - Vector2::repeat(0.5);
        let people = who.len();
        for &(ti, pi) in who {
            let t = &live[ti].0;
            let p = &t.points[pi];
            let rgb = id_colour(t.id);
            let Some(head) = v.image_point(index, &p.local) else {
                continue;
            };
            // The trail: this frame's view of the last seconds of the track.
            let from = pi.saturating_sub(trail);
            let trail_px: Vec<Vector2<f64>> = t.points[from..=pi]
                .iter()
                .filter_map(|q| v.image_point(index, &q.local))
                .map(to_out)
                .collect();
            c.polyline(&trail_px, rgb, thick).map_err(im)?;
            // The 95 % ellipse: the ground covariance through the projection's Jacobian.
            if let Some((axes, angle)) = image_ellipse(v, index, &p.local, &p.cov.total()) {
                c.ellipse(
                    &to_out(head),
                    (axes.0 * scale, axes.1 * scale),
                    angle,
                    rgb,
                    1,
                )
                .map_err(im)?;
            }
            let hp = to_out(head);
            // Filled: detected in this frame; hollow: carried through a gap.
            c.circle(
                &hp,
                3.0 * f64::from(thick),
                rgb,
                if p.observed { -1 } else { thick },
            )
            .map_err(im)?;
            c.text(
                &(hp + Vector2::new(6.0, -6.0) * f64::from(thick)),
                &t.id.to_string(),
                text,
                rgb,
                1,
            )
            .map_err(im)?;
        }
        for g in &v.gcps {
            if let Some(uv) = v.image_point(index, &g.local) {
                let rgb = if g.control {
                    [40, 220, 40]
                } else {
                    [255, 150, 0]
                };
                let q = to_out(uv);
                c.cross(&q, 8.0 * f64::from(thick), rgb, thick)
                    .map_err(im)?;
                c.text(
                    &(q + Vector2::new(8.0, 14.0) * f64::from(thick)),
                    &g.name,
                    text,
                    rgb,
                    1,
                )
                .map_err(im)?;
            }
        }
        let label = format!(
            "frame {index}  {:.2} s  {people} people{}",
            index as f64 / v.fps,
            if v.poses.get(index).is_some_and(Option::is_none) {
                "  (no pose)"
            } else {
                ""
            }
        );
        c.text(
            &Vector2::new(10.0, 24.0 * text / 0.45),
            &label,
            text * 1.2,
            [255, 255, 255],
            1,
        )
        .map_err(im)?;
        if keys.contains(&index) {
            let s = "KEY FRAME";
            let x = f64::from(ow) - f64::from(Canvas::text_width(s, text * 1.2, 2)) - 10.0;
            c.text(
                &Vector2::new(x, 24.0 * text / 0.45),
                s,
                text * 1.2,
                [255, 220, 0],
                2,
            )
            .map_err(im)?;
        }
        sink.write_bgr(c.mat())?;
    }
    Ok(())
}

/// The image ellipse (semi-axes in pixels, angle in degrees) holding 95 % of a site-frame point's
/// horizontal covariance `cov`, through the projection's Jacobian at the point.
fn image_ellipse(
    v: &Views,
    frame: usize,
    local: &Vector3<f64>,
    cov: &Matrix2<f64>,
) -> Option<((f64, f64), f64)> {
    // d(u, v)/d(e, n): the camera's point Jacobian through the pose's rotation.
    let pose = v.poses.get(frame)?.as_ref()?;
    let (_, j_cam, _) = v.camera.project_with_jacobians(&pose.apply(local)).ok()?;
    let j = (j_cam * pose.rotation.matrix())
        .fixed_columns::<2>(0)
        .into_owned();
    let c = j * cov * j.transpose() * CHI2_95;
    let eig = nalgebra::SymmetricEigen::new(c);
    let (k0, k1) = if eig.eigenvalues[0] >= eig.eigenvalues[1] {
        (0, 1)
    } else {
        (1, 0)
    };
    let major = eig.eigenvectors.column(k0);
    let axes = (
        eig.eigenvalues[k0].max(0.0).sqrt(),
        eig.eigenvalues[k1].max(0.0).sqrt(),
    );
    (axes.0.is_finite() && axes.1.is_finite())
        .then(|| (axes, major[1].atan2(major[0]).to_degrees()))
}
