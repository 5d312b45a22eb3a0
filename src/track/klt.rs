//! Feature tracking of people (pure logic; the pixels go through a [`FeatureTracker`]),
//! after the paper's section 3.2.2, made better:
//!
//! - a detection that no track explains starts a track, with corner features inside its box
//!   (so a person missed at the entry is picked up later, which the paper did by hand);
//! - features move by pyramidal Lucas–Kanade with a forward–backward check, predicted by the
//!   camera's motion (the hovering camera's per-frame pose) and the track's own velocity. A
//!   person's box holds ground too, so the track moves with one mode of its features' motion
//!   net of the camera's (mean shift): the one that agrees with the velocity of its recent
//!   detections and with the detections; features of the other modes are dropped, and fewer
//!   than `min_features` left means new features in the person's box;
//! - detections are assigned to tracks globally (Hungarian), confirmed tracks first, then the
//!   tentative ones (fewer than three detections; they end after three frames without one);
//!   the gate widens for a track whose features were lost; each detection is fused with the
//!   feature motion by a Kalman filter over the track's frames, and at the end a
//!   Rauch–Tung–Striebel pass runs back over them, so every point uses the whole crossing;
//! - the backward pass: when a track is confirmed, the features of its first frame are followed
//!   back through the last `backward_frames` frames to where the person entered the image (a
//!   detector cannot place a head whose body the border cuts); likewise a track that leaves
//!   the image keeps the feature-measured frames after its last detection, up to the border;
//! - a track ends at the image border or after `max_gap` frames without a detection; tracks
//!   with too few detections (false alarms, shadows) are dropped.

use nalgebra::{Matrix2, Vector2};

use std::collections::VecDeque;

use super::{ImageTrack, TrackPoint};
use crate::detect::Detection;
use crate::features::FeatureTracker;
use crate::optim::assignment::assign;

#[derive(Clone, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct KltTrackSettings {
    /// Detections farther than this from a track's position are not its, pixels.
    pub gate_px: f64,
    /// A person's size in the image (the box of a track without a detection), pixels.
    pub person_px: f64,
    /// Radius of a mode of the features' motion (one body's features move together), pixels
    /// per frame.
    pub flow_px: f64,
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
    /// The backward pass follows a new track's first features back at most this many frames;
    /// a track that leaves the image keeps at most this many frames after its last detection.
    pub backward_frames: usize,
    /// Variance of a frame's feature motion, px² (the random walk between detections).
    pub motion_var_px2: f64,
    /// A frame's motion with no feature left: the prediction, with this variance, px².
    pub lost_var_px2: f64,
    /// A detection whose box's longer side is more than this factor larger or smaller than
    /// the track's last is not its: seen obliquely, two people who meet in the image are at
    /// different distances, so of different sizes.
    pub max_size_ratio: f64,
}

impl Default for KltTrackSettings {
    fn default() -> Self {
        KltTrackSettings {
            gate_px: 40.0,
            person_px: 40.0,
            flow_px: 2.0,
            min_features: 5,
            max_features: 40,
            border_px: 2.0,
            max_gap: 25,
            min_hits: 5,
            min_hit_fraction: 0.3,
            backward_frames: 25,
            motion_var_px2: 0.5,
            lost_var_px2: 25.0,
            max_size_ratio: 1.6,
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
    /// Whether the features measured this frame's motion.
    measured: bool,
    /// The detection's position and covariance, when there was one.
    det: Option<(Vector2<f64>, Matrix2<f64>)>,
    /// The detection's score, when there was one.
    score: Option<f64>,
}

struct Live {
    features: Vec<Vector2<f64>>,
    /// Image velocity net of the camera's motion, pixels per frame.
    velocity: Vector2<f64>,
    steps: Vec<Step>,
    since_detection: usize,
    hits: usize,
    /// The last detections (frame, position), carried into the current frame by the
    /// camera's motion: their slope is the velocity that ground features cannot bias.
    recent: Vec<(usize, Vector2<f64>)>,
    /// The features found in the first frame, for the backward pass.
    first_features: Vec<Vector2<f64>>,
    /// Frames before the first detection, from the backward pass: (frame, position), the
    /// nearest first.
    lead: Vec<(usize, Vector2<f64>)>,
    /// Whether the track left the image (or the video ended) rather than lost its person.
    exited: bool,
    bbox: [f64; 4],
}

/// A track with fewer detections is tentative: it is matched after the others, and it ends
/// after `TENTATIVE_GAP` frames without one.
const CONFIRM_HITS: usize = 3;
const TENTATIVE_GAP: usize = 3;

/// Detections that give a track's velocity: the last this many frames.
const VELOCITY_FRAMES: usize = 12;

impl Live {
    /// The least-squares slope of the recent detections, pixels per frame; `None` before three
    /// detections.
    fn detected_velocity(&self) -> Option<Vector2<f64>> {
        if self.recent.len() < 3 {
            return None;
        }
        let n = self.recent.len() as f64;
        let mean_f = self.recent.iter().map(|r| r.0 as f64).sum::<f64>() / n;
        let mean_p = self.recent.iter().map(|r| r.1).sum::<Vector2<f64>>() / n;
        let (mut sff, mut sfp) = (0.0, Vector2::zeros());
        for (f, p) in &self.recent {
            let df = *f as f64 - mean_f;
            sff += df * df;
            sfp += df * (p - mean_p);
        }
        (sff > 0.0).then(|| sfp / sff)
    }

    fn position(&self) -> Vector2<f64> {
        self.steps.last().expect("a live track has a step").est
    }
}

/// Tracks people by their features; frames come in order with their detections.
pub struct KltTracker<F: FeatureTracker> {
    pub settings: KltTrackSettings,
    features: F,
    size: (f64, f64),
    live: Vec<Live>,
    done: Vec<Live>,
    /// The last frames (index, frame), for the backward pass; the newest last.
    frames: VecDeque<(usize, F::Frame)>,
    /// Counts for the run report.
    pub reinitialised: usize,
    pub started: usize,
}

/// A mode of a set of points: its centre and the points near it.
type Mode = (Vector2<f64>, Vec<usize>);

/// The modes of a set of points: mean shift with a flat kernel from every point; each mode
/// with the points within `radius` of it, the largest first.
fn modes(points: &[Vector2<f64>], radius: f64) -> Vec<Mode> {
    let within = |c: &Vector2<f64>| -> Vec<usize> {
        (0..points.len())
            .filter(|&i| (points[i] - c).norm() <= radius)
            .collect()
    };
    let mut centres: Vec<Vector2<f64>> = Vec::new();
    for start in points {
        let mut c = *start;
        for _ in 0..30 {
            let members = within(&c);
            if members.is_empty() {
                break;
            }
            let m = members.iter().map(|&i| points[i]).sum::<Vector2<f64>>() / members.len() as f64;
            let moved = (m - c).norm();
            c = m;
            if moved < 1e-3 * radius {
                break;
            }
        }
        if !centres.iter().any(|q| (q - c).norm() < 0.5 * radius) {
            centres.push(c);
        }
    }
    let mut out: Vec<Mode> = centres.into_iter().map(|c| (c, within(&c))).collect();
    out.sort_by_key(|m| std::cmp::Reverse(m.1.len()));
    out
}

/// The largest eigenvalue of a symmetric 2×2 matrix.
fn largest_eigenvalue(m: &Matrix2<f64>) -> f64 {
    let (a, b, c) = (m[(0, 0)], 0.5 * (m[(0, 1)] + m[(1, 0)]), m[(1, 1)]);
    0.5 * (a + c) + (0.25 * (a - c) * (a - c) + b * b).sqrt()
}

/// A live track carried into the next frame: where it is predicted, its covariance, where it
/// would be had it stood still, whether its features measured its motion.
type Prediction = (Vector2<f64>, Matrix2<f64>, Vector2<f64>, bool);

impl<F: FeatureTracker> KltTracker<F> {
    pub fn new(settings: KltTrackSettings, features: F, size: (f64, f64)) -> Self {
        KltTracker {
            settings,
            features,
            size,
            live: Vec::new(),
            done: Vec::new(),
            frames: VecDeque::new(),
            reinitialised: 0,
            started: 0,
        }
    }

    /// The backward pass: once a track is confirmed (its velocity known), the features of its
    /// first frame are followed back through the frames kept, to where the person entered the
    /// image or the features stop agreeing with the track's velocity.
    fn backward(
        &mut self,
        t: &mut Live,
        motion_at: &dyn Fn(usize, &Vector2<f64>) -> Vector2<f64>,
    ) -> Result<(), crate::PluginError> {
        let s = &self.settings;
        let Some(v) = t.detected_velocity() else {
            return Ok(());
        };
        let first = &t.steps[0];
        let Some(mut i) = self.frames.iter().position(|(f, _)| *f == first.frame) else {
            return Ok(());
        };
        let mut pts = t.first_features.clone();
        let mut pos = first.est;
        let mut lead = Vec::new();
        while i > 0 && lead.len() < s.backward_frames && pts.len() >= 2 {
            let ((fa, a), (fb, b)) = (&self.frames[i], &self.frames[i - 1]);
            if fb + 1 != *fa {
                break;
            }
            // The camera's motion from fb to fa, undone to first order (it is small).
            let back = |x: &Vector2<f64>| 2.0 * x - motion_at(*fa, x);
            let guess: Vec<Vector2<f64>> = pts.iter().map(|x| back(x) - v).collect();
            let next = self.features.track(a, b, &pts, Some(&guess))?;
            let (mut to, mut flow) = (Vec::new(), Vec::new());
            for (x, y) in pts.iter().zip(&next) {
                if let Some(y) = y {
                    to.push(*y);
                    flow.push(y - back(x));
                }
            }
            // The person's features move by −v; the ground's by nothing.
            let Some((c, members)) = modes(&flow, s.flow_px)
                .into_iter()
                .filter(|m| m.1.len() >= 2 && (m.0 + v).norm() <= s.flow_px.max(0.35 * v.norm()))
                .min_by(|a, b| (a.0 + v).norm().total_cmp(&(b.0 + v).norm()))
            else {
                break;
            };
            pos = back(&pos) + c;
            if !self.inside(&pos) {
                break;
            }
            pts = members.iter().map(|&k| to[k]).collect();
            lead.push((*fb, pos));
            i -= 1;
        }
        t.lead = lead;
        Ok(())
    }

    fn inside(&self, p: &Vector2<f64>) -> bool {
        let b = self.settings.border_px;
        p.x >= b && p.y >= b && p.x <= self.size.0 - 1.0 - b && p.y <= self.size.1 - 1.0 - b
    }

    fn box_around(&self, p: &Vector2<f64>) -> [f64; 4] {
        let s = self.settings.person_px;
        [p.x - s / 2.0, p.y - s / 2.0, s, s]
    }

    /// The next frame and its detections; `motion_at(f, x)` carries a point `x` of frame `f − 1`
    /// into frame `f` (the camera's motion).
    pub fn update(
        &mut self,
        index: usize,
        frame: F::Frame,
        detections: &[Detection],
        motion_at: &dyn Fn(usize, &Vector2<f64>) -> Vector2<f64>,
    ) -> Result<(), crate::PluginError> {
        let motion = |x: &Vector2<f64>| motion_at(index, x);
        let predicted = self.predict(&frame, detections, &motion)?;
        let matched = self.associate(&predicted, detections);
        let (keep, taken) =
            self.correct(index, &frame, detections, predicted, matched, motion_at)?;
        // Detections no track explains start tracks.
        let keep = self.start_tracks(index, &frame, detections, keep, &taken)?;
        self.live = keep;
        self.frames.push_back((index, frame));
        while self.frames.len() > self.settings.backward_frames + 2 * CONFIRM_HITS + TENTATIVE_GAP {
            self.frames.pop_front();
        }
        Ok(())
    }

    /// Each live track carried into this frame by its features (one mode of their motion net of
    /// the camera's): where it is predicted, the prediction's covariance, where it would be had
    /// it stood still, and whether its features measured its motion.
    fn predict(
        &mut self,
        frame: &F::Frame,
        detections: &[Detection],
        motion: &dyn Fn(&Vector2<f64>) -> Vector2<f64>,
    ) -> Result<Vec<Prediction>, crate::PluginError> {
        // Features into this frame. Inside a person's box some features are on the ground, so
        // each track moves with one mode of its features' motion net of the camera's: the one
        // that agrees with its velocity and the detections (ground features have none).
        let s = self.settings.clone();
        let mut predicted = Vec::with_capacity(self.live.len());
        for t in &mut self.live {
            let p = t.position();
            for r in &mut t.recent {
                r.1 = motion(&r.1);
            }
            let mut moved_by = None;
            if let (Some((_, prev)), false) = (self.frames.back(), t.features.is_empty()) {
                let guess: Vec<Vector2<f64>> =
                    t.features.iter().map(|f| motion(f) + t.velocity).collect();
                let next = self
                    .features
                    .track(prev, frame, &t.features, Some(&guess))?;
                let (mut to, mut flow) = (Vec::new(), Vec::new());
                for (a, b) in t.features.iter().zip(&next) {
                    if let Some(b) = b {
                        to.push(*b);
                        flow.push(b - motion(a));
                    }
                }
                let found = modes(&flow, s.flow_px);
                let least = if found.iter().any(|m| m.1.len() >= 2) {
                    2
                } else {
                    1
                };
                // With a velocity from the detections, a mode far from it is the ground (or a
                // neighbour): no measurement, and the features are renewed.
                let known = t.detected_velocity();
                let admissible = |c: &Vector2<f64>| {
                    known.is_none_or(|v| (c - v).norm() <= s.flow_px.max(0.35 * v.norm()))
                };
                let score = |c: &Vector2<f64>| {
                    let at = motion(&p) + c;
                    let to_detection = detections
                        .iter()
                        .map(|d| (d.uv - at).norm())
                        .fold(s.gate_px, f64::min);
                    let to_velocity = if t.hits >= 2 {
                        (c - t.velocity).norm()
                    } else {
                        0.0
                    };
                    to_detection + to_velocity
                };
                let mut best: Option<(f64, &Mode)> = None;
                for m in found
                    .iter()
                    .filter(|m| m.1.len() >= least && admissible(&m.0))
                {
                    let v = score(&m.0);
                    if best.is_none_or(|(b, _)| v < b) {
                        best = Some((v, m));
                    }
                }
                t.features = match best {
                    Some((_, (_, members))) => {
                        let mut dx: Vec<f64> = members.iter().map(|&i| flow[i].x).collect();
                        let mut dy: Vec<f64> = members.iter().map(|&i| flow[i].y).collect();
                        dx.sort_by(f64::total_cmp);
                        dy.sort_by(f64::total_cmp);
                        moved_by = Some(Vector2::new(dx[dx.len() / 2], dy[dy.len() / 2]));
                        members.iter().map(|&i| to[i]).collect()
                    }
                    None => Vec::new(),
                };
            }
            let (pred, var) = match moved_by {
                Some(d) => (motion(&p) + d, s.motion_var_px2),
                None => (motion(&p) + t.velocity, s.lost_var_px2),
            };
            let last = t.steps.last().expect("a live track has a step");
            let pred_cov = last.est_cov + Matrix2::identity() * var;
            predicted.push((pred, pred_cov, motion(&p), moved_by.is_some()));
        }
        Ok(predicted)
    }

    /// The detection each live track takes, if any.
    fn associate(&self, predicted: &[Prediction], detections: &[Detection]) -> Vec<Option<usize>> {
        // Detections to tracks: first the confirmed ones, then the tentative ones take what is
        // left (a false alarm's young track must not take a person's detection from its track).
        let s = &self.settings;
        let size = |b: &[f64; 4]| b[2].max(b[3]);
        let gated = |(p, cov, _, _): &Prediction, track_box: &[f64; 4], d: &Detection| {
            // A track that lost its features is less sure where it is: a wider gate, up to
            // twice the base.
            let spread = largest_eigenvalue(&(cov + d.cov)).sqrt();
            let gate = s.gate_px + (3.0 * spread).min(s.gate_px);
            let r = (d.uv - p).norm();
            // And a size unlike the track's costs as much as half a gate at the limit.
            let scale = (size(&d.bbox) / size(track_box)).ln().abs();
            let limit = s.max_size_ratio.ln();
            if r > gate || (scale.is_finite() && scale > limit) {
                return f64::INFINITY;
            }
            r + if scale.is_finite() {
                0.5 * s.gate_px * scale / limit
            } else {
                0.0
            }
        };
        let confirmed: Vec<bool> = self.live.iter().map(|t| t.hits >= CONFIRM_HITS).collect();
        let mut matched: Vec<Option<usize>> = vec![None; self.live.len()];
        let mut used = vec![false; detections.len()];
        for stage in [true, false] {
            let rows: Vec<usize> = (0..self.live.len())
                .filter(|&i| confirmed[i] == stage)
                .collect();
            let cost: Vec<Vec<f64>> = rows
                .iter()
                .map(|&i| {
                    detections
                        .iter()
                        .zip(&used)
                        .map(|(d, &u)| {
                            if u {
                                f64::INFINITY
                            } else {
                                gated(&predicted[i], &self.live[i].bbox, d)
                            }
                        })
                        .collect()
                })
                .collect();
            for (&i, m) in rows.iter().zip(assign(&cost, 2.5 * s.gate_px)) {
                if let Some(j) = m {
                    used[j] = true;
                    matched[i] = Some(j);
                }
            }
        }
        matched
    }

    /// Each track's Kalman update, velocity and features; tracks that ended go to `done`. The
    /// tracks kept, and which detections were taken.
    fn correct(
        &mut self,
        index: usize,
        frame: &F::Frame,
        detections: &[Detection],
        predicted: Vec<Prediction>,
        matched: Vec<Option<usize>>,
        motion_at: &dyn Fn(usize, &Vector2<f64>) -> Vector2<f64>,
    ) -> Result<(Vec<Live>, Vec<bool>), crate::PluginError> {
        let s = self.settings.clone();
        let mut taken = vec![false; detections.len()];
        let mut keep = Vec::with_capacity(self.live.len());
        for ((mut t, (pred, pred_cov, still_at, measured)), m) in std::mem::take(&mut self.live)
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
            // Velocity net of the camera's motion: set by the first detection after the start,
            // then smoothed.
            if let Some(j) = m {
                t.recent.push((index, detections[j].uv));
                let first = t.recent.len().saturating_sub(VELOCITY_FRAMES);
                t.recent.drain(..first);
            }
            let step = est - still_at;
            if let Some(v) = t.detected_velocity() {
                t.velocity = v;
            } else if detected && t.hits == 1 {
                t.velocity = step;
            } else if detected || measured {
                t.velocity = 0.6 * t.velocity + 0.4 * step;
            }
            if detected {
                t.hits += 1;
                t.since_detection = 0;
            } else {
                t.since_detection += 1;
            }
            // Without a detection, the box follows the track (a detection's box is where the
            // person is already).
            if !detected {
                let shift = est - t.position();
                t.bbox[0] += shift.x;
                t.bbox[1] += shift.y;
            }
            t.steps.push(Step {
                frame: index,
                pred,
                pred_cov,
                est,
                est_cov,
                bbox: t.bbox,
                detected,
                measured,
                det: m.map(|j| (detections[j].uv, detections[j].cov)),
                score: m.map(|j| detections[j].score),
            });
            let gap = if t.hits >= CONFIRM_HITS {
                s.max_gap
            } else {
                TENTATIVE_GAP.min(s.max_gap)
            };
            if detected && t.hits == CONFIRM_HITS && s.backward_frames > 0 {
                self.backward(&mut t, motion_at)?;
            }
            if !self.inside(&est) {
                t.exited = true;
            }
            if !self.inside(&est) || t.since_detection > gap {
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
                t.features = self.features.detect_in(frame, b, s.max_features)?;
                self.reinitialised += 1;
            }
            keep.push(t);
        }
        Ok((keep, taken))
    }

    /// New tracks from the detections no track took.
    fn start_tracks(
        &mut self,
        index: usize,
        frame: &F::Frame,
        detections: &[Detection],
        mut keep: Vec<Live>,
        taken: &[bool],
    ) -> Result<Vec<Live>, crate::PluginError> {
        let s = self.settings.clone();
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
            let features = self.features.detect_in(frame, d.bbox, s.max_features)?;
            self.started += 1;
            keep.push(Live {
                features: features.clone(),
                velocity: Vector2::zeros(),
                steps: vec![Step {
                    frame: index,
                    pred: d.uv,
                    pred_cov: d.cov,
                    est: d.uv,
                    est_cov: d.cov,
                    bbox: d.bbox,
                    detected: true,
                    measured: false,
                    det: Some((d.uv, d.cov)),
                    score: Some(d.score),
                }],
                since_detection: 0,
                hits: 1,
                recent: vec![(index, d.uv)],
                first_features: features,
                lead: Vec::new(),
                exited: false,
                bbox: d.bbox,
            });
        }
        Ok(keep)
    }

    /// The tracks, smoothed back over their frames, cut to their first and last detection,
    /// numbered from 1 in order of their first frame.
    pub fn finish(mut self) -> Vec<ImageTrack> {
        let s = self.settings.clone();
        let mut all: Vec<Live> = std::mem::take(&mut self.done);
        for mut t in std::mem::take(&mut self.live) {
            t.exited = true;
            all.push(t);
        }
        // Smoothed first, then the share of the detections' error that persists over frames
        // (pooled over the tracks), which smoothing cannot average and which KLT carries along:
        // added back to every point (`smooth::persistent_share`).
        let mut smoothed = Vec::new();
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
            // A track that left the image keeps the frames after its last detection that its
            // features measured, up to the border.
            let mut e = b;
            while t.exited
                && e + 1 < t.steps.len()
                && e - b < s.backward_frames
                && t.steps[e + 1].measured
                && self.inside(&t.steps[e + 1].est)
            {
                e += 1;
            }
            // Rauch–Tung–Striebel over a random walk: x_s(k) = x(k) + C (x_s(k+1) − pred(k+1)).
            let steps = &t.steps[..=e];
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
            smoothed.push((t, a, e, smooth));
        }
        let persistent = crate::smooth::persistent_of(smoothed.iter().map(|(t, a, e, smooth)| {
            t.steps[*a..=*e]
                .iter()
                .zip(&smooth[*a..=*e])
                .filter_map(|(x, (uv, _))| x.det.map(|(d, c)| (x.frame, d - uv, c)))
                .collect::<Vec<_>>()
        }));
        let persistent = persistent.unwrap_or(crate::smooth::Persistent::none());
        let mut tracks: Vec<Vec<TrackPoint>> = Vec::new();
        for (t, a, e, smooth) in smoothed {
            let steps = &t.steps[..=e];
            // Each point's detection covariance: its own, else the nearest earlier one's.
            let mut det_cov = Vec::with_capacity(steps.len());
            let mut last = steps[a].det.map_or(Matrix2::zeros(), |d| d.1);
            for x in steps {
                if let Some((_, c)) = x.det {
                    last = c;
                }
                det_cov.push(persistent.of(&last));
            }
            // The backward pass's frames, tied to the smoothed first point; the variance grows
            // by a frame's feature motion per frame.
            let (uv0, cov0) = smooth[a];
            let shift = uv0 - steps[a].est;
            let mut points: Vec<TrackPoint> = t
                .lead
                .iter()
                .enumerate()
                .rev()
                .map(|(m, (frame, pos))| {
                    let uv = pos + shift;
                    let mut bbox = steps[a].bbox;
                    bbox[0] += uv.x - uv0.x;
                    bbox[1] += uv.y - uv0.y;
                    TrackPoint {
                        frame: *frame,
                        uv,
                        cov: cov0
                            + det_cov[a]
                            + Matrix2::identity() * (s.motion_var_px2 * (m + 1) as f64),
                        bbox,
                        // Followed back before the first detection: none here.
                        score: None,
                    }
                })
                .collect();
            points.extend(
                steps[a..=e]
                    .iter()
                    .zip(&smooth[a..=e])
                    .zip(&det_cov[a..=e])
                    .map(|((x, (uv, cov)), extra)| {
                        // The box moved with the smoothing, so that what is read from it (its
                        // ends, seen obliquely) gains from the features' motion too.
                        let moved = uv - x.det.map_or(x.est, |d| d.0);
                        let mut bbox = x.bbox;
                        bbox[0] += moved.x;
                        bbox[1] += moved.y;
                        TrackPoint {
                            frame: x.frame,
                            uv: *uv,
                            cov: cov + extra,
                            bbox,
                            score: x.score,
                        }
                    }),
            );
            tracks.push(points);
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

    impl FeatureTracker for Synthetic {
        type Frame = usize;
        fn detect(&mut self, frame: &usize) -> Result<Vec<Vector2<f64>>, crate::PluginError> {
            Ok(self.truth[*frame].clone())
        }
        fn refine(
            &mut self,
            from: &usize,
            to: &usize,
            pts: &[Vector2<f64>],
            guess: &[Vector2<f64>],
        ) -> Result<Vec<Option<Vector2<f64>>>, crate::PluginError> {
            self.track(from, to, pts, Some(guess))
        }
        fn detect_in(
            &mut self,
            frame: &usize,
            bbox: [f64; 4],
            _max: usize,
        ) -> Result<Vec<Vector2<f64>>, crate::PluginError> {
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
        fn track(
            &mut self,
            from: &usize,
            to: &usize,
            pts: &[Vector2<f64>],
            _guess: Option<&[Vector2<f64>]>,
        ) -> Result<Vec<Option<Vector2<f64>>>, crate::PluginError> {
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

    /// A detection at `uv` whose 30 px box is centred on `centre`, σ 2 px.
    /// A tracker with the default settings on a 640 × 360 synthetic video of `truth`.
    fn synthetic_tracker(truth: &[Vec<Vector2<f64>>]) -> KltTracker<Synthetic> {
        KltTracker::new(
            KltTrackSettings::default(),
            Synthetic {
                truth: truth.to_vec(),
            },
            (640.0, 360.0),
        )
    }

    fn detection(centre: &Vector2<f64>, uv: Vector2<f64>, score: f64) -> Detection {
        Detection {
            uv,
            cov: Matrix2::identity() * 4.0,
            bbox: [centre.x - 15.0, centre.y - 15.0, 30.0, 30.0],
            area_px: 900.0,
            score,
            model_head: None,
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
        let mut tracker = synthetic_tracker(&truth);
        let still = |_: usize, p: &Vector2<f64>| *p;
        for (f, people) in truth.iter().enumerate() {
            let mut dets: Vec<Detection> = people
                .iter()
                .enumerate()
                // Every fourth frame misses one person; person 2 is missed at the entry.
                .filter(|(k, _)| !((f % 4 == 1 && *k == 0) || (*k == 2 && f < 20)))
                .map(|(_, p)| detection(p, p + Vector2::new(((f * 7) % 5) as f64 - 2.0, 0.0), 1.0))
                .collect();
            if f == 50 {
                // A false alarm on empty ground.
                let at = Vector2::new(300.0, 330.0);
                dets.push(detection(&at, at, 0.4));
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
                // The box is where the person is too (the detections' boxes are centred on the
                // truth, their points off by up to 2 px): a detected frame's box was once moved
                // on by the track's step, 4 px ahead.
                let centre = Vector2::new(q.bbox[0] + q.bbox[2] / 2.0, q.bbox[1] + q.bbox[3] / 2.0);
                let off = (centre - truth[q.frame][k]).norm();
                assert!(
                    off < 2.5,
                    "track {} frame {}: box {off} px off",
                    t.id,
                    q.frame
                );
            }
        }
        // The person missed until frame 20 is followed back by the backward pass, as far as
        // the frames kept reach (25).
        let late = tracks.iter().find(|t| t.points[0].uv.y > 200.0).unwrap();
        assert_eq!(late.points[0].frame, 0);
        // Its uncertainty grows going back from the first detection.
        let sd = |f: usize| late.points[f].cov[(0, 0)];
        assert!(
            sd(0) > sd(10) && sd(10) > sd(20),
            "{} {} {}",
            sd(0),
            sd(10),
            sd(20)
        );
    }

    #[test]
    fn backward_pass_stops_where_the_person_entered() {
        // One person entering from the left at 4 px per frame, first detected at frame 20.
        let truth: Vec<Vec<Vector2<f64>>> = (0..60)
            .map(|f| vec![Vector2::new(-30.0 + 4.0 * f as f64, 150.0)])
            .collect();
        let mut tracker = synthetic_tracker(&truth);
        let still = |_: usize, p: &Vector2<f64>| *p;
        for (f, people) in truth.iter().enumerate() {
            let dets: Vec<Detection> = people
                .iter()
                .filter(|_| f >= 20)
                .map(|p| detection(p, *p, 1.0))
                .collect();
            tracker.update(f, f, &dets, &still).unwrap();
        }
        let tracks = tracker.finish();
        assert_eq!(tracks.len(), 1);
        // x = −30 + 4 f is inside the 2 px border from frame 8 on.
        assert_eq!(tracks[0].points[0].frame, 8);
        for q in &tracks[0].points {
            assert!(
                (q.uv - truth[q.frame][0]).norm() < 1e-6,
                "frame {}",
                q.frame
            );
        }
    }

    #[test]
    fn motion_modes_separate_a_person_from_the_ground() {
        // Ground features stay (flow ≈ 0), the person's move 7 px; one limb straggles.
        let mut flow: Vec<Vector2<f64>> = (0..6)
            .map(|k| Vector2::new(0.1 * k as f64, -0.05 * k as f64))
            .collect();
        flow.extend((0..9).map(|k| Vector2::new(7.0 + 0.1 * k as f64, 0.2)));
        flow.push(Vector2::new(12.0, 3.0));
        let found = modes(&flow, 2.0);
        assert_eq!(found.len(), 3);
        assert_eq!(found[0].1, (6..15).collect::<Vec<_>>());
        assert!((found[0].0 - Vector2::new(7.4, 0.2)).norm() < 1e-9);
        assert_eq!(found[1].1.len(), 6);
        assert!(found[1].0.norm() < 0.3);
        assert!((largest_eigenvalue(&Matrix2::new(4.0, 1.0, 1.0, 4.0)) - 5.0).abs() < 1e-12);
    }
}
