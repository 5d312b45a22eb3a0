//! Association tracking (pure): every frame, the detections are assigned to the tracks' predicted
//! positions by the Hungarian method (globally, not greedily), within a gate.
//!
//! A track predicts by constant velocity in the image, after moving its last position with the
//! camera (the `Motion` of each frame). A detection no track takes starts a tentative track,
//! confirmed after a few hits in a row; a confirmed track survives misses (occlusion, a missed
//! detection) for a while, predicting on, with a gate that widens with the misses, so that it
//! keeps its identity when the person reappears. A stray detection right beside one a track took
//! is a duplicate (a hat cut in two), not a new person.

use nalgebra::Vector2;

use super::{ImageTrack, Motion, TrackPoint, Tracker};
use crate::detect::Detection;
use crate::optim::assignment::assign;

/// Tracker settings.
#[derive(Clone, Debug)]
pub struct AssociationSettings {
    /// Largest distance between a prediction and a detection, pixels.
    pub gate_px: f64,
    /// Hits in a row that confirm a new track.
    pub confirm_hits: usize,
    /// Frames a confirmed track may go without a detection before it ends.
    pub max_misses: usize,
    /// Weight of a new velocity measurement (0..1).
    pub velocity_gain: f64,
    /// A detection no track takes, this close to one a track took, is a duplicate (a piece of
    /// the same head), not a new person, pixels.
    pub duplicate_px: f64,
}

impl Default for AssociationSettings {
    fn default() -> Self {
        AssociationSettings {
            gate_px: 15.0,
            confirm_hits: 3,
            max_misses: 12,
            velocity_gain: 0.5,
            duplicate_px: 8.0,
        }
    }
}

struct Live {
    id: Option<usize>,
    /// Predicted (or last observed) position in the current frame, and velocity per frame.
    position: Vector2<f64>,
    velocity: Vector2<f64>,
    hits: usize,
    misses: usize,
    points: Vec<TrackPoint>,
}

/// The tracker's state.
pub struct AssociationTracker {
    settings: AssociationSettings,
    live: Vec<Live>,
    done: Vec<ImageTrack>,
    next_id: usize,
    last_frame: Option<usize>,
}

impl AssociationTracker {
    pub fn new(settings: AssociationSettings) -> Self {
        AssociationTracker {
            settings,
            live: Vec::new(),
            done: Vec::new(),
            next_id: 1,
            last_frame: None,
        }
    }

    fn retire(&mut self, t: Live) {
        if let Some(id) = t.id {
            self.done.push(ImageTrack {
                id,
                points: t.points,
            });
        }
    }
}

impl Tracker for AssociationTracker {
    fn update(&mut self, frame: usize, detections: &[Detection], motion: Motion) {
        let s = self.settings.clone();
        // Predict: move with the camera, then by the track's velocity.
        for t in &mut self.live {
            t.position = motion(&t.position) + t.velocity;
        }
        let cost: Vec<Vec<f64>> = self
            .live
            .iter()
            .map(|t| {
                let gate = s.gate_px * (1.0 + t.misses as f64).sqrt();
                detections
                    .iter()
                    .map(|d| {
                        let dist = (d.uv - t.position).norm();
                        // Scale so that one gate works for all: the distance in units of its gate.
                        if dist <= gate {
                            dist / gate * s.gate_px
                        } else {
                            f64::INFINITY
                        }
                    })
                    .collect()
            })
            .collect();
        let matched = assign(&cost, s.gate_px);
        let mut taken = vec![false; detections.len()];
        let mut keep = Vec::with_capacity(self.live.len());
        for (mut t, m) in std::mem::take(&mut self.live).into_iter().zip(matched) {
            match m {
                Some(j) => {
                    let d = &detections[j];
                    taken[j] = true;
                    let innovation = d.uv - t.position;
                    t.velocity += innovation * s.velocity_gain;
                    t.position = d.uv;
                    t.hits += 1;
                    t.misses = 0;
                    t.points.push(TrackPoint {
                        frame,
                        uv: d.uv,
                        cov: d.cov,
                        bbox: d.bbox,
                        score: Some(d.score),
                    });
                    if t.id.is_none() && t.hits >= s.confirm_hits {
                        t.id = Some(self.next_id);
                        self.next_id += 1;
                    }
                    keep.push(t);
                }
                None => {
                    t.misses += 1;
                    // A tentative track ends at its first miss; a confirmed one after max_misses.
                    if t.id.is_none() || t.misses > s.max_misses {
                        self.retire(t);
                    } else {
                        keep.push(t);
                    }
                }
            }
        }
        let taken_at: Vec<Vector2<f64>> = detections
            .iter()
            .zip(&taken)
            .filter(|(_, t)| **t)
            .map(|(d, _)| d.uv)
            .collect();
        for (d, _) in detections.iter().zip(&taken).filter(|(_, t)| !**t) {
            if taken_at.iter().any(|p| (p - d.uv).norm() < s.duplicate_px) {
                continue;
            }
            keep.push(Live {
                id: (s.confirm_hits <= 1).then(|| {
                    self.next_id += 1;
                    self.next_id - 1
                }),
                position: d.uv,
                velocity: Vector2::zeros(),
                hits: 1,
                misses: 0,
                points: vec![TrackPoint {
                    frame,
                    uv: d.uv,
                    cov: d.cov,
                    bbox: d.bbox,
                    score: Some(d.score),
                }],
            });
        }
        self.live = keep;
        self.last_frame = Some(frame);
    }

    fn finish(mut self: Box<Self>) -> Vec<ImageTrack> {
        for mut t in std::mem::take(&mut self.live) {
            // Seen in every frame since it appeared, but the video ended before it could be
            // confirmed: someone walking into view at the end.
            if t.id.is_none() && t.hits >= 2 && t.misses == 0 {
                t.id = Some(self.next_id);
                self.next_id += 1;
            }
            self.retire(t);
        }
        let mut done = std::mem::take(&mut self.done);
        done.sort_by_key(|t| t.id);
        done
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::Matrix2;

    fn det(x: f64, y: f64) -> Detection {
        Detection {
            uv: Vector2::new(x, y),
            cov: Matrix2::identity() * 0.25,
            bbox: [x - 5.0, y - 5.0, 10.0, 10.0],
            area_px: 80.0,
            score: 1.0,
            model_head: None,
        }
    }

    #[test]
    fn crossing_runners_keep_their_identities_through_a_miss_and_a_false_alarm() {
        let mut t: Box<dyn Tracker> =
            Box::new(AssociationTracker::new(AssociationSettings::default()));
        let still = |p: &Vector2<f64>| *p;
        for f in 0..60 {
            let x = f as f64 * 7.0;
            // Two runners crossing paths, one missed in frames 30–34, a false alarm at frame 20.
            let mut dets = vec![det(100.0 + x, 300.0 + 0.5 * x)];
            if !(30..35).contains(&f) {
                dets.push(det(100.0 + x, 500.0 - 0.5 * x));
            }
            if f == 20 {
                dets.push(det(900.0, 100.0));
            }
            t.update(f, &dets, &still);
        }
        let tracks = t.finish();
        assert_eq!(
            tracks.len(),
            2,
            "{:?}",
            tracks
                .iter()
                .map(|t| (t.id, t.points.len()))
                .collect::<Vec<_>>()
        );
        for tr in &tracks {
            // Each keeps to its own line: y rises or falls monotonically.
            let ys: Vec<f64> = tr.points.iter().map(|p| p.uv.y).collect();
            let up = ys.windows(2).all(|w| w[1] >= w[0]);
            let down = ys.windows(2).all(|w| w[1] <= w[0]);
            assert!(up || down, "track {} switched", tr.id);
        }
        assert_eq!(tracks.iter().map(|t| t.points.len()).sum::<usize>(), 115);
    }

    #[test]
    fn camera_motion_is_compensated() {
        let mut t: Box<dyn Tracker> =
            Box::new(AssociationTracker::new(AssociationSettings::default()));
        // The camera pans 12 px per frame while a person stands still in the world.
        let pan = |p: &Vector2<f64>| p - Vector2::new(12.0, 0.0);
        for f in 0..30 {
            t.update(
                f,
                &[
                    det(800.0 - 12.0 * f as f64, 400.0),
                    det(300.0 - 12.0 * f as f64 + 30.0, 420.0),
                ],
                &pan,
            );
        }
        let tracks = t.finish();
        assert_eq!(tracks.len(), 2);
        assert!(tracks.iter().all(|t| t.points.len() == 30));
    }
}
