//! Feature tracking of people (pure logic; the pixels go through the [`Features`] adapter),
//! after the paper's section 3.2.2, made better:
//!
//! - a detection that no track explains starts a track, with corner features inside its box
//!   (so a person missed at the entry is picked up later, which the paper did by hand);
//! - features move by pyramidal Lucas–Kanade with a forward–backward check, predicted by the
//!   camera's motion (the hovering camera's per-frame pose) and the track's own velocity; the
//!   track moves with the densest cluster of its features (legs swing, the head and shoulders
//!   do not); fewer than `min_features` left: new features in the person's box;
//! - detections are assigned to tracks globally (Hungarian) and fused with the feature motion
//!   by a Kalman filter over the track's frames; at the end a Rauch–Tung–Striebel pass runs
//!   back over them, so every point uses the whole crossing, not only the frames before it
//!   (the paper's backward pass from the image centre);
//! - a track ends at the image border or after `max_gap` frames without a detection; tracks
//!   with too few detections (false alarms, shadows) are dropped, and each track is cut to its
//!   first and last detection.

use nalgebra::{Matrix2, Vector2};

use super::{ImageTrack, Motion, TrackPoint};
use crate::detect::Detection;
use crate::optim::assignment::assign;

/// Finds and follows corner features (an adapter: OpenCV's corners and Lucas–Kanade).
pub trait Features {
    type Frame;
    /// Up to `max` corners inside `bbox` (`[x, y, w, h]`, pixels).
    fn features_in(
        &mut self,
        frame: &Self::Frame,
        bbox: [f64; 4],
        max: usize,
    ) -> Result<Vec<Vector2<f64>>, String>;
    /// Where each point of `from` is in `to`, starting from `guess`; `None` for a point lost
    /// or failing the forward–backward check.
    fn follow(
        &mut self,
        from: &Self::Frame,
        to: &Self::Frame,
        pts: &[Vector2<f64>],
        guess: &[Vector2<f64>],
    ) -> Result<Vec<Option<Vector2<f64>>>, String>;
}

#[derive(Clone, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct KltTrackSettings {
    /// Detections farther than this from a track's position are not its, pixels.
    pub gate_px: f64,
    /// A person's size in the image (the box of a track without a detection), pixels.
    pub person_px: f64,
    /// Radius of the cluster of features that moves a track, pixels.
    pub cluster_px: f64,
    pub min_features: usize,
    pub max_features: usize,
    /// A track whose position comes this close to the image border ends, pixels.
    pub border_px: f64,
    /// A track ends after this many frames without a detection.
    pub max_gap: usize,
    /// Tracks with fewer detections than this, or fewer than `min_hit_fraction` of their
    /// frames, are dropped.
    pub min_hits: usize,
    pub min_hit_fraction: f64,
    /// Variance of a frame's feature motion, px² (the random walk between detections).
    pub motion_var_px2: f64,
    /// A frame's motion with no feature left: the prediction, with this variance, px².
    pub lost_var_px2: f64,
}

impl Default for KltTrackSettings {
    fn default() -> Self {
        KltTrackSettings {
            gate_px: 40.0,
            person_px: 40.0,
            cluster_px: 10.0,
            min_features: 5,
            max_features: 40,
            border_px: 2.0,
            max_gap: 25,
            min_hits: 5,
            min_hit_fraction: 0.3,
            motion_var_px2: 0.5,
            lost_var_px2: 25.0,
        }
    }
}

/// One frame of a live track: the filter's prediction and estimate.
struct Step {
    frame: usize,
    pred: Vector2<f64>,
    pred_cov: Matrix2<f64>,
    est: Vector2<f64>,
    est_cov: Matrix2<f64>,
    bbox: [f64; 4],
    detected: bool,
}

struct Live {
    features: Vec<Vector2<f64>>,
    /// Image velocity net of the camera's motion, pixels per frame.
    velocity: Vector2<f64>,
    steps: Vec<Step>,
    since_detection: usize,
    hits: usize,
    bbox: [f64; 4],
}

impl Live {
    fn position(&self) -> Vector2<f64> {
        self.steps.last().expect("a live track has a step").est
    }
}

/// Tracks people by their features; frames come in order with their detections.
pub struct KltTracker<F: Features> {
    pub settings: KltTrackSettings,
    features: F,
    size: (f64, f64),
    live: Vec<Live>,
    done: Vec<Live>,
    prev: Option<F::Frame>,
    /// Counts for the run report.
    pub reinitialised: usize,
    pub started: usize,
}

/// The densest cluster of points: mean shift with a flat kernel from the median.
fn densest(points: &[Vector2<f64>], radius: f64) -> Vec<usize> {
    if points.is_empty() {
        return Vec::new();
    }
    let median = |v: &mut Vec<f64>| {
        v.sort_by(f64::total_cmp);
        v[v.len() / 2]
    };
    let mut c = Vector2::new(
        median(&mut points.iter().map(|p| p.x).collect()),
        median(&mut points.iter().map(|p| p.y).collect()),
    );
    let mut members = Vec::new();
    for _ in 0..20 {
        members = (0..points.len())
            .filter(|&i| (points[i] - c).norm() <= radius)
            .collect();
        if members.is_empty() {
            return (0..points.len()).collect();
        }
        let m = members.iter().map(|&i| points[i]).sum::<Vector2<f64>>() / members.len() as f64;
        if (m - c).norm() < 0.05 {
            break;
        }
        c = m;
    }
    members
}

impl<F: Features> KltTracker<F> {
    pub fn new(settings: KltTrackSettings, features: F, size: (f64, f64)) -> Self {
        KltTracker {
            settings,
            features,
            size,
            live: Vec::new(),
            done: Vec::new(),
            prev: None,
            reinitialised: 0,
            started: 0,
        }
    }

    fn inside(&self, p: &Vector2<f64>) -> bool {
        let b = self.settings.border_px;
        p.x >= b && p.y >= b && p.x <= self.size.0 - 1.0 - b && p.y <= self.size.1 - 1.0 - b
    }

    fn box_around(&self, p: &Vector2<f64>) -> [f64; 4] {
        let s = self.settings.person_px;
        [p.x - s / 2.0, p.y - s / 2.0, s, s]
    }

    /// The next frame, its detections and the camera's motion since the previous frame.
    pub fn update(
        &mut self,
        index: usize,
        frame: F::Frame,
        detections: &[Detection],
        motion: Motion,
    ) -> Result<(), String> {
        let s = self.settings.clone();
        // Features into this frame; each track predicted by the motion of its densest cluster.
        let mut predicted = Vec::with_capacity(self.live.len());
        for t in &mut self.live {
            let p = t.position();
            let prediction = motion(&p) + t.velocity;
            let mut moved_by = None;
            if let (Some(prev), false) = (&self.prev, t.features.is_empty()) {
                let guess: Vec<Vector2<f64>> =
                    t.features.iter().map(|f| motion(f) + t.velocity).collect();
                let next = self.features.follow(prev, &frame, &t.features, &guess)?;
                let (mut from, mut to) = (Vec::new(), Vec::new());
                for (a, b) in t.features.iter().zip(&next) {
                    if let Some(b) = b {
                        from.push(*a);
                        to.push(*b);
                    }
                }
                let members = densest(&to, s.cluster_px);
                if !members.is_empty() {
                    let mut dx: Vec<f64> = members.iter().map(|&i| to[i].x - from[i].x).collect();
                    let mut dy: Vec<f64> = members.iter().map(|&i| to[i].y - from[i].y).collect();
                    dx.sort_by(f64::total_cmp);
                    dy.sort_by(f64::total_cmp);
                    moved_by = Some(Vector2::new(dx[dx.len() / 2], dy[dy.len() / 2]));
                }
                t.features = to;
            }
            let (pred, var) = match moved_by {
                Some(d) => (p + d, s.motion_var_px2),
                None => (prediction, s.lost_var_px2),
            };
            let last = t.steps.last().expect("a live track has a step");
            let pred_cov = last.est_cov + Matrix2::identity() * var;
            // Velocity net of the camera: what the features did beyond the camera's motion.
            if moved_by.is_some() {
                t.velocity = 0.7 * t.velocity + 0.3 * (pred - motion(&p));
            }
            predicted.push((pred, pred_cov));
        }

        // Detections to tracks.
        let cost: Vec<Vec<f64>> = predicted
            .iter()
            .map(|(p, _)| {
                detections
                    .iter()
                    .map(|d| {
                        let r = (d.uv - p).norm();
                        if r <= s.gate_px { r } else { f64::INFINITY }
                    })
                    .collect()
            })
            .collect();
        let matched = assign(&cost, s.gate_px);
        let mut taken = vec![false; detections.len()];
        let mut keep = Vec::with_capacity(self.live.len());
        for ((mut t, (pred, pred_cov)), m) in std::mem::take(&mut self.live)
            .into_iter()
            .zip(predicted)
            .zip(matched)
        {
            let (est, est_cov, detected) = match m {
                Some(j) => {
                    taken[j] = true;
                    let d = &detections[j];
                    // Kalman update of a position with its prediction's covariance.
                    let gain = pred_cov * (pred_cov + d.cov).try_inverse().unwrap_or_default();
                    let est = pred + gain * (d.uv - pred);
                    let est_cov = (Matrix2::identity() - gain) * pred_cov;
                    t.bbox = d.bbox;
                    (est, 0.5 * (est_cov + est_cov.transpose()), true)
                }
                None => (pred, pred_cov, false),
            };
            if detected {
                t.hits += 1;
                t.since_detection = 0;
            } else {
                t.since_detection += 1;
            }
            // The box follows the track.
            let shift = est - t.position();
            t.bbox[0] += shift.x;
            t.bbox[1] += shift.y;
            t.steps.push(Step {
                frame: index,
                pred,
                pred_cov,
                est,
                est_cov,
                bbox: t.bbox,
                detected,
            });
            if !self.inside(&est) || t.since_detection > s.max_gap {
                self.done.push(t);
                continue;
            }
            // Drop features that strayed from the person; renew when too few are left.
            let reach = s.person_px;
            t.features.retain(|f| (f - est).norm() <= reach);
            if t.features.len() < s.min_features {
                let b = if detected {
                    t.bbox
                } else {
                    self.box_around(&est)
                };
                t.features = self.features.features_in(&frame, b, s.max_features)?;
                self.reinitialised += 1;
            }
            keep.push(t);
        }
        // Detections no track explains start tracks.
        for (j, d) in detections.iter().enumerate() {
            if taken[j] || !self.inside(&d.uv) {
                continue;
            }
            if keep
                .iter()
                .any(|t| (t.position() - d.uv).norm() < 0.5 * s.gate_px)
            {
                continue;
            }
            let features = self.features.features_in(&frame, d.bbox, s.max_features)?;
            self.started += 1;
            keep.push(Live {
                features,
                velocity: Vector2::zeros(),
                steps: vec![Step {
                    frame: index,
                    pred: d.uv,
                    pred_cov: d.cov,
                    est: d.uv,
                    est_cov: d.cov,
                    bbox: d.bbox,
                    detected: true,
                }],
                since_detection: 0,
                hits: 1,
                bbox: d.bbox,
            });
        }
        self.live = keep;
        self.prev = Some(frame);
        Ok(())
    }

    /// The tracks, smoothed back over their frames, cut to their first and last detection,
    /// numbered from 1 in order of their first frame.
    pub fn finish(mut self) -> Vec<ImageTrack> {
        let s = self.settings.clone();
        let mut all: Vec<Live> = std::mem::take(&mut self.done);
        all.append(&mut self.live);
        let mut tracks: Vec<Vec<TrackPoint>> = Vec::new();
        for t in all {
            let first = t.steps.iter().position(|x| x.detected);
            let last = t.steps.iter().rposition(|x| x.detected);
            let (Some(a), Some(b)) = (first, last) else {
                continue;
            };
            let span = b - a + 1;
            if t.hits < s.min_hits || (t.hits as f64) < s.min_hit_fraction * span as f64 {
                continue;
            }
            // Rauch–Tung–Striebel over a random walk: x_s(k) = x(k) + C (x_s(k+1) − pred(k+1)).
            let steps = &t.steps[..=b];
            let mut smooth: Vec<(Vector2<f64>, Matrix2<f64>)> =
                steps.iter().map(|x| (x.est, x.est_cov)).collect();
            for k in (0..steps.len() - 1).rev() {
                let next = &steps[k + 1];
                let c = steps[k].est_cov * next.pred_cov.try_inverse().unwrap_or_default();
                let (xs, ps) = smooth[k + 1];
                let x = steps[k].est + c * (xs - next.pred);
                let p = steps[k].est_cov + c * (ps - next.pred_cov) * c.transpose();
                smooth[k] = (x, 0.5 * (p + p.transpose()));
            }
            tracks.push(
                steps[a..=b]
                    .iter()
                    .zip(&smooth[a..=b])
                    .map(|(x, (uv, cov))| TrackPoint {
                        frame: x.frame,
                        uv: *uv,
                        cov: *cov,
                        bbox: x.bbox,
                    })
                    .collect(),
            );
        }
        tracks.sort_by_key(|p| p[0].frame);
        tracks
            .into_iter()
            .enumerate()
            .map(|(i, points)| ImageTrack { id: i + 1, points })
            .collect()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A synthetic world: people are points moving at constant velocity; each carries a cloud
    /// of features that follow it exactly (and a few that stay behind, like swinging legs).
    struct Synthetic {
        /// Per frame, each person's true position.
        truth: Vec<Vec<Vector2<f64>>>,
    }

    impl Features for Synthetic {
        type Frame = usize;
        fn features_in(
            &mut self,
            frame: &usize,
            bbox: [f64; 4],
            _max: usize,
        ) -> Result<Vec<Vector2<f64>>, String> {
            let c = Vector2::new(bbox[0] + bbox[2] / 2.0, bbox[1] + bbox[3] / 2.0);
            // The person nearest the box, if any.
            let near = self.truth[*frame]
                .iter()
                .min_by(|a, b| (*a - c).norm().total_cmp(&(*b - c).norm()))
                .copied();
            Ok(match near {
                Some(p) if (p - c).norm() < 20.0 => (0..12)
                    .map(|k| {
                        let a = k as f64 * 0.52;
                        p + Vector2::new(a.cos(), a.sin()) * (1.0 + (k % 3) as f64 * 2.0)
                    })
                    .collect(),
                _ => Vec::new(),
            })
        }
        fn follow(
            &mut self,
            from: &usize,
            to: &usize,
            pts: &[Vector2<f64>],
            _guess: &[Vector2<f64>],
        ) -> Result<Vec<Option<Vector2<f64>>>, String> {
            Ok(pts
                .iter()
                .map(|p| {
                    let (k, q) = self.truth[*from]
                        .iter()
                        .enumerate()
                        .min_by(|a, b| (a.1 - p).norm().total_cmp(&(b.1 - p).norm()))?;
                    let to_q = self.truth[*to].get(k)?;
                    Some(p + (to_q - q))
                })
                .collect())
        }
    }

    #[test]
    fn follows_people_through_missed_detections_and_drops_false_alarms() {
        let frames = 120;
        let truth: Vec<Vec<Vector2<f64>>> = (0..frames)
            .map(|f| {
                (0..3)
                    .map(|k| Vector2::new(10.0 + 4.0 * f as f64, 100.0 + 60.0 * k as f64))
                    .collect()
            })
            .collect();
        let mut tracker = KltTracker::new(
            KltTrackSettings::default(),
            Synthetic {
                truth: truth.clone(),
            },
            (640.0, 360.0),
        );
        let still = |p: &Vector2<f64>| *p;
        for (f, people) in truth.iter().enumerate() {
            let mut dets: Vec<Detection> = people
                .iter()
                .enumerate()
                // Every fourth frame misses one person; person 2 is missed at the entry.
                .filter(|(k, _)| !((f % 4 == 1 && *k == 0) || (*k == 2 && f < 20)))
                .map(|(_, p)| Detection {
                    uv: p + Vector2::new(((f * 7) % 5) as f64 - 2.0, 0.0),
                    cov: Matrix2::identity() * 4.0,
                    bbox: [p.x - 15.0, p.y - 15.0, 30.0, 30.0],
                    area_px: 900.0,
                    score: 1.0,
                })
                .collect();
            if f == 50 {
                // A false alarm on empty ground.
                dets.push(Detection {
                    uv: Vector2::new(300.0, 330.0),
                    cov: Matrix2::identity() * 4.0,
                    bbox: [285.0, 315.0, 30.0, 30.0],
                    area_px: 900.0,
                    score: 0.4,
                });
            }
            tracker.update(f, f, &dets, &still).unwrap();
        }
        let tracks = tracker.finish();
        assert_eq!(
            tracks.len(),
            3,
            "{:?}",
            tracks.iter().map(|t| t.points.len()).collect::<Vec<_>>()
        );
        for t in &tracks {
            let k = ((t.points[0].uv.y - 100.0) / 60.0).round() as usize;
            for q in &t.points {
                let err = (q.uv - truth[q.frame][k]).norm();
                assert!(err < 1.5, "track {} frame {}: {err}", t.id, q.frame);
            }
        }
        // The person missed at the entry is followed from the first detection on.
        assert!(tracks.iter().any(|t| t.points[0].frame == 20));
    }

    #[test]
    fn densest_cluster_ignores_stragglers() {
        let mut pts: Vec<Vector2<f64>> =
            (0..10).map(|k| Vector2::new(k as f64 * 0.3, 0.0)).collect();
        pts.extend([Vector2::new(30.0, 0.0), Vector2::new(31.0, 0.0)]);
        let m = densest(&pts, 5.0);
        assert_eq!(m.len(), 10);
    }
}
