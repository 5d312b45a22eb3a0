//! Stabilisation of a hovering camera against reference frames (pure; the feature tracker is
//! injected): the frame-from-reference homography of every frame, the key frames where the
//! reference is renewed, and the GCP picks of one frame carried to every frame.
//!
//! Features found in the reference frame are tracked frame to frame; the homography from the
//! reference to the current frame is fitted to them robustly (MSAC, then least squares on the
//! inliers) and the outliers (people, shadows) are dropped from the set. The reference is
//! renewed, making a key frame, when the features still agreeing fall below a threshold or the
//! homography becomes ill-conditioned (paper, section 3.3.3). GCP picks are carried by tracking
//! each pick's neighbourhood in the picked frame directly into the current frame, so that they do
//! not drift, starting from the pick's last position moved by the frame-to-frame homography; a
//! track that lands far from that prediction or fails the forward–backward check is dropped for
//! that frame (a runner over the target, say) and the prediction carries on.

use nalgebra::{Matrix3, Vector2};

use crate::estimate::homography::{homography_robust, transfer};
use crate::estimate::ransac::RansacSettings;

pub use crate::features::FeatureTracker;

/// When to renew the reference, and how strictly to accept tracks.
#[derive(Clone, Debug)]
pub struct StabiliseSettings {
    /// Renew when fewer features than this agree with the homography.
    pub min_features: usize,
    /// Renew when the agreeing features fall below this fraction of the reference's.
    pub min_fraction: f64,
    /// Renew when the homography, in coordinates normalised to the image, has a condition
    /// number above this (it is near 1 for a hovering camera).
    pub max_condition: f64,
    /// Renew at least every this many frames (`None`: only on the criteria above).
    pub max_interval: Option<usize>,
    /// Inlier threshold of the homography fit, pixels.
    pub inlier_px: f64,
    /// A carried pick further than this from the homography's prediction is dropped, pixels.
    pub max_pick_jump_px: f64,
}

impl StabiliseSettings {
    /// Key frames renewed below `min_features` agreeing features or `min_fraction` of the
    /// reference's, and at least every `every_s` seconds of a video at `fps` when given.
    pub fn key_frames(
        min_features: usize,
        min_fraction: f64,
        every_s: Option<f64>,
        fps: f64,
    ) -> Self {
        StabiliseSettings {
            min_features,
            min_fraction,
            max_interval: every_s.map(|s| (s * fps).round().max(1.0) as usize),
            ..StabiliseSettings::default()
        }
    }
}

impl Default for StabiliseSettings {
    fn default() -> Self {
        StabiliseSettings {
            min_features: 40,
            min_fraction: 0.5,
            max_condition: 2.0,
            max_interval: None,
            inlier_px: 1.5,
            max_pick_jump_px: 6.0,
        }
    }
}

/// Why a frame became a key frame.
#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum KeyReason {
    First,
    FewFeatures,
    IllConditioned,
    Interval,
    /// The first frame of a chunk of the video (chunks are processed on their own).
    Chunk,
}

impl KeyReason {
    pub fn as_str(self) -> &'static str {
        match self {
            KeyReason::First => "first frame",
            KeyReason::FewFeatures => "few features agree",
            KeyReason::IllConditioned => "transform ill-conditioned",
            KeyReason::Interval => "interval",
            KeyReason::Chunk => "start of a chunk",
        }
    }
}

/// One frame's stabilisation.
#[derive(Clone, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct FrameTrack {
    pub index: usize,
    /// Set when this frame is a key frame (a new reference).
    pub key: Option<KeyReason>,
    /// The key frame this frame was registered to (itself for a key frame).
    pub reference: usize,
    /// Maps reference pixels to this frame's pixels (for a key frame: from the previous reference).
    pub frame_from_ref: Matrix3<f64>,
    /// Features tracked into this frame, and how many agree with the homography.
    pub features: usize,
    pub inliers: usize,
    /// The carried picks, in the order given.
    pub picks: Vec<Option<Vector2<f64>>>,
}

/// Condition number of a homography in coordinates scaled to about [−1, 1].
pub fn normalised_condition(h: &Matrix3<f64>, width: f64, height: f64) -> f64 {
    let n = Matrix3::new(
        2.0 / width,
        0.0,
        -1.0,
        0.0,
        2.0 / height,
        -1.0,
        0.0,
        0.0,
        1.0,
    );
    let Some(n_inv) = n.try_inverse() else {
        return f64::INFINITY;
    };
    let hn = n * h * n_inv;
    let sv = hn.singular_values();
    let (max, min) = (sv.max(), sv.min());
    if min > 0.0 { max / min } else { f64::INFINITY }
}

/// The frame-to-frame state of the stabiliser.
pub struct Stabiliser<T: FeatureTracker> {
    tracker: T,
    settings: StabiliseSettings,
    size: (f64, f64),
    /// The picked frame, its index and the picks.
    template: T::Frame,
    pick_frame: usize,
    picks: Vec<Vector2<f64>>,
    /// Reference (key) frame index, the reference-frame positions of the live features and
    /// their positions in the previous frame, and the count when the reference was set.
    reference: Option<usize>,
    ref_pts: Vec<Vector2<f64>>,
    prev_pts: Vec<Vector2<f64>>,
    ref_count: usize,
    prev: Option<T::Frame>,
    /// Homographies from the first frame to the reference and to the previous frame.
    ref_from_first: Matrix3<f64>,
    prev_from_first: Matrix3<f64>,
    /// Each pick's position in the previous frame: tracked, or predicted while it is lost;
    /// `None` before any estimate exists.
    pick_state: Vec<Option<Vector2<f64>>>,
    /// The last frame's frame-from-previous-frame homography (the camera's motion).
    last_motion: Matrix3<f64>,
    /// Make the next frame a key frame whatever the criteria say.
    force_key: bool,
}

impl<T: FeatureTracker> Stabiliser<T> {
    /// `template` is the frame `pick_frame` in which `picks` were made.
    pub fn new(
        tracker: T,
        settings: StabiliseSettings,
        size: (u32, u32),
        template: T::Frame,
        pick_frame: usize,
        picks: Vec<Vector2<f64>>,
    ) -> Self {
        let n = picks.len();
        Stabiliser {
            tracker,
            settings,
            size: (f64::from(size.0), f64::from(size.1)),
            template,
            pick_frame,
            picks,
            reference: None,
            ref_pts: Vec::new(),
            prev_pts: Vec::new(),
            ref_count: 0,
            prev: None,
            ref_from_first: Matrix3::identity(),
            prev_from_first: Matrix3::identity(),
            pick_state: vec![None; n],
            last_motion: Matrix3::identity(),
            force_key: false,
        }
    }

    fn set_reference(&mut self, index: usize, frame: &T::Frame) -> Result<(), crate::PluginError> {
        let pts = self.tracker.detect(frame)?;
        self.reference = Some(index);
        self.ref_count = pts.len();
        self.ref_pts = pts.clone();
        self.prev_pts = pts;
        Ok(())
    }

    /// Registers the next frame (frames must come in order).
    pub fn push(
        &mut self,
        index: usize,
        frame: T::Frame,
    ) -> Result<FrameTrack, crate::PluginError> {
        let (w, h) = self.size;
        let mut track = FrameTrack {
            index,
            key: None,
            reference: index,
            frame_from_ref: Matrix3::identity(),
            features: 0,
            inliers: 0,
            picks: vec![None; self.picks.len()],
        };
        let frame_from_first;
        match (self.reference, &self.prev) {
            (Some(reference), Some(prev)) => {
                let moved = self.tracker.track(prev, &frame, &self.prev_pts, None)?;
                let (mut src, mut dst) = (Vec::new(), Vec::new());
                for (r, m) in self.ref_pts.iter().zip(&moved) {
                    if let Some(m) = m {
                        src.push(*r);
                        dst.push(*m);
                    }
                }
                track.features = src.len();
                let fit = if src.len() >= 8 {
                    self.fit(&src, &dst, index)
                } else {
                    None
                };
                let needed = self
                    .settings
                    .min_features
                    .max((self.settings.min_fraction * self.ref_count as f64).ceil() as usize);
                match fit {
                    Some(fit) => {
                        track.inliers = fit.inlier_count;
                        track.frame_from_ref = fit.model;
                        track.reference = reference;
                        frame_from_first = fit.model * self.ref_from_first;
                        // Keep the features that agree.
                        let keep: Vec<usize> = (0..src.len()).filter(|&i| fit.inliers[i]).collect();
                        self.ref_pts = keep.iter().map(|&i| src[i]).collect();
                        self.prev_pts = keep.iter().map(|&i| dst[i]).collect();
                        let cond = normalised_condition(&fit.model, w, h);
                        if fit.inlier_count < needed {
                            track.key = Some(KeyReason::FewFeatures);
                        } else if !(cond <= self.settings.max_condition) {
                            track.key = Some(KeyReason::IllConditioned);
                        } else if self
                            .settings
                            .max_interval
                            .is_some_and(|n| index - reference >= n)
                        {
                            track.key = Some(KeyReason::Interval);
                        }
                    }
                    None => {
                        // Nothing relates this frame to the reference: assume it did not move.
                        frame_from_first = self.prev_from_first;
                        track.key = Some(KeyReason::FewFeatures);
                    }
                }
            }
            _ => {
                frame_from_first = Matrix3::identity();
                track.key = Some(KeyReason::First);
                // A start after the picked frame (a chunk of a long video): the picks are
                // predicted through this frame's homography from the picked frame.
                if index != self.pick_frame && !self.picks.is_empty() {
                    self.predict_picks_from_template(index, &frame)?;
                }
            }
        }
        if std::mem::take(&mut self.force_key) && track.key.is_none() {
            track.key = Some(KeyReason::Chunk);
        }
        if track.key.is_some() {
            self.set_reference(index, &frame)?;
            self.ref_from_first = frame_from_first;
            track.reference = index;
        }
        let frame_from_prev = frame_from_first
            * self
                .prev_from_first
                .try_inverse()
                .unwrap_or_else(Matrix3::identity);
        self.last_motion = frame_from_prev;
        track.picks = self.carry_picks(index, &frame, &frame_from_prev)?;
        self.prev_from_first = frame_from_first;
        self.prev = Some(frame);
        Ok(track)
    }

    /// Makes the next frame pushed a key frame ([`KeyReason::Chunk`]): a chunk of the video
    /// starts there.
    pub fn key_next(&mut self) {
        self.force_key = true;
    }

    /// The homography from `src` to `dst`, robustly (MSAC seeded by the frame's index).
    fn fit(
        &self,
        src: &[Vector2<f64>],
        dst: &[Vector2<f64>],
        index: usize,
    ) -> Option<crate::estimate::ransac::RansacResult<Matrix3<f64>>> {
        homography_robust(
            src,
            dst,
            &RansacSettings {
                threshold: self.settings.inlier_px,
                confidence: 0.999,
                max_iterations: 2000,
                seed: index as u64,
                ..RansacSettings::default()
            },
        )
        .ok()
    }

    /// Sets each pick's prediction from the homography from the picked frame to `frame`, when
    /// one fits (features of the picked frame tracked straight into `frame`).
    fn predict_picks_from_template(
        &mut self,
        index: usize,
        frame: &T::Frame,
    ) -> Result<(), crate::PluginError> {
        let pts = self.tracker.detect(&self.template)?;
        let moved = self.tracker.track(&self.template, frame, &pts, None)?;
        let (mut src, mut dst) = (Vec::new(), Vec::new());
        for (r, m) in pts.iter().zip(&moved) {
            if let Some(m) = m {
                src.push(*r);
                dst.push(*m);
            }
        }
        if src.len() < self.settings.min_features.max(8) {
            return Ok(());
        }
        let Some(fit) = self.fit(&src, &dst, index) else {
            return Ok(());
        };
        if fit.inlier_count < self.settings.min_features {
            return Ok(());
        }
        self.pick_state = self.picks.iter().map(|p| transfer(&fit.model, p)).collect();
        Ok(())
    }

    /// Maps pixels of the frame before the last one pushed to the last one (the identity for
    /// the first frame).
    pub fn last_motion(&self) -> Matrix3<f64> {
        self.last_motion
    }

    fn carry_picks(
        &mut self,
        index: usize,
        frame: &T::Frame,
        frame_from_prev: &Matrix3<f64>,
    ) -> Result<Vec<Option<Vector2<f64>>>, crate::PluginError> {
        if self.picks.is_empty() {
            return Ok(Vec::new());
        }
        if index == self.pick_frame {
            self.pick_state = self.picks.iter().map(|p| Some(*p)).collect();
            return Ok(self.pick_state.clone());
        }
        // Predict each pick from its last position through the frame-to-frame homography (over
        // one frame the parallax of relief is negligible); without any, from the pick itself.
        let predicted: Vec<(Vector2<f64>, bool)> = self
            .pick_state
            .iter()
            .zip(&self.picks)
            .map(|(s, p)| match s {
                Some(s) => (transfer(frame_from_prev, s).unwrap_or(*s), true),
                None => (*p, false),
            })
            .collect();
        let guess: Vec<Vector2<f64>> = predicted.iter().map(|p| p.0).collect();
        let tracked = self
            .tracker
            .refine(&self.template, frame, &self.picks, &guess)?;
        let max = self.settings.max_pick_jump_px;
        let out: Vec<Option<Vector2<f64>>> = tracked
            .iter()
            .zip(&predicted)
            .map(|(t, (p, known))| {
                t.filter(|t| (t - p).norm() <= if *known { max } else { 4.0 * max })
            })
            .collect();
        for ((s, o), (p, known)) in self.pick_state.iter_mut().zip(&out).zip(&predicted) {
            *s = o.or(known.then_some(*p));
        }
        Ok(out)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A synthetic tracker: frames are homographies from a textured plane; features are a grid.
    struct Planar {
        lose_after: usize,
    }

    struct Frame {
        index: usize,
        from_plane: Matrix3<f64>,
    }

    impl FeatureTracker for Planar {
        type Frame = Frame;
        fn detect(&mut self, f: &Frame) -> Result<Vec<Vector2<f64>>, crate::PluginError> {
            Ok((0..100)
                .map(|i| {
                    transfer(
                        &f.from_plane,
                        &Vector2::new(
                            100.0 + 170.0 * (i % 10) as f64,
                            100.0 + 90.0 * (i / 10) as f64,
                        ),
                    )
                    .unwrap()
                })
                .collect())
        }
        fn track(
            &mut self,
            from: &Frame,
            to: &Frame,
            pts: &[Vector2<f64>],
            _guess: Option<&[Vector2<f64>]>,
        ) -> Result<Vec<Option<Vector2<f64>>>, crate::PluginError> {
            let m = to.from_plane * from.from_plane.try_inverse().unwrap();
            // Lose a feature now and then, and all of a far half after `lose_after`.
            Ok(pts
                .iter()
                .enumerate()
                .map(|(i, p)| {
                    // Picks (few points) are never lost here.
                    let lost = pts.len() > 10
                        && ((i + to.index).is_multiple_of(37)
                            || (to.index >= self.lose_after && p.x > 960.0));
                    (!lost).then(|| transfer(&m, p).unwrap())
                })
                .collect())
        }
        fn refine(
            &mut self,
            from: &Frame,
            to: &Frame,
            pts: &[Vector2<f64>],
            guess: &[Vector2<f64>],
        ) -> Result<Vec<Option<Vector2<f64>>>, crate::PluginError> {
            self.track(from, to, pts, Some(guess))
        }
        fn detect_in(
            &mut self,
            f: &Frame,
            b: [f64; 4],
            max: usize,
        ) -> Result<Vec<Vector2<f64>>, crate::PluginError> {
            let inside = |p: &Vector2<f64>| {
                p.x >= b[0] && p.y >= b[1] && p.x <= b[0] + b[2] && p.y <= b[1] + b[3]
            };
            Ok(self
                .detect(f)?
                .into_iter()
                .filter(inside)
                .take(max)
                .collect())
        }
    }

    fn frame(index: usize) -> Frame {
        let t = index as f64;
        Frame {
            index,
            from_plane: Matrix3::new(
                1.0,
                0.001 * t.sin(),
                0.3 * t,
                -0.001 * t.sin(),
                1.0,
                -0.2 * t,
                0.0,
                0.0,
                1.0,
            ),
        }
    }

    #[test]
    fn registers_frames_renews_the_reference_and_carries_picks() {
        let picks = vec![Vector2::new(500.0, 300.0), Vector2::new(1500.0, 800.0)];
        let mut s = Stabiliser::new(
            Planar { lose_after: 20 },
            StabiliseSettings::default(),
            (1920, 1080),
            frame(0),
            0,
            picks.clone(),
        );
        let mut keys = Vec::new();
        for i in 0..40 {
            let t = s.push(i, frame(i)).unwrap();
            if t.key.is_some() {
                keys.push(i);
            }
            // The carried picks are where the plane puts them.
            let m = frame(i).from_plane;
            for (p, c) in picks.iter().zip(&t.picks) {
                let truth = transfer(&m, p).unwrap();
                assert!((c.unwrap() - truth).norm() < 1e-6, "frame {i}");
            }
            if t.key.is_none() {
                let r = frame(t.reference).from_plane;
                let expect = m * r.try_inverse().unwrap();
                assert!((t.frame_from_ref / t.frame_from_ref[(2, 2)] - expect).norm() < 1e-6);
            }
        }
        // The first frame, and a renewal when half of the features are lost at frame 20.
        assert_eq!(keys[0], 0);
        assert!(keys.contains(&20), "{keys:?}");
    }

    #[test]
    fn condition_of_a_hovering_homography_is_near_one() {
        let h = Matrix3::new(1.0, 0.001, 3.0, -0.001, 1.0, -2.0, 0.0, 0.0, 1.0);
        assert!(normalised_condition(&h, 1920.0, 1080.0) < 1.02);
        let squash = Matrix3::new(1.0, 0.0, 0.0, 0.0, 0.3, 0.0, 0.0, 0.0, 1.0);
        assert!(normalised_condition(&squash, 1920.0, 1080.0) > 2.0);
    }
}
