//! Moving people under a moving camera (OpenCV adapter): frames warped onto each other through
//! the ground, then differenced.
//!
//! Each frame is reduced (`INTER_AREA`, by a whole factor) to a grey working copy no wider than
//! `max_width` and lightly blurred. Corners of the previous frame are followed into it
//! (`video::klt`: pyramidal Lucas–Kanade with a forward–backward check) and a homography fitted
//! to them by MSAC (`estimate::homography`): the ground's motion between the two frames, since
//! the ground holds most corners and people are MSAC's outliers. Frame `t` is then compared
//! with frames `t − k` and `t + k` (`step_frames`), each warped onto it through the chained
//! homographies: a pixel is moving when it differs from BOTH by more than `threshold` grey
//! levels. Requiring both keeps where a person is at `t` and drops the ghosts of where they
//! were at `t − k` and will be at `t + k`. The mask then goes through the background detector's
//! blob finder (opening, closing, components of a person's area on the ground).
//!
//! Frames are returned `k` frames late; the first and last `k` frames, and frames whose
//! neighbours could not be aligned (fewer than `min_inliers` corners agree), have no
//! detections. People standing still are not found: this detector sees motion, not people. Tall
//! things the camera passes (a deck high above the ground, trees) move against the ground too.

use std::collections::VecDeque;

use nalgebra::Matrix3;
use opencv::core::{self, Mat, Scalar, Size};
use opencv::imgproc;
use opencv::prelude::*;

use super::background::{BlobFinder, check_blobs, e};
use super::{Detection, Detector, FrameDetections, FrameView};
use crate::estimate::homography::homography_robust;
use crate::estimate::ransac::RansacSettings;
use crate::features::FeatureTracker;
use crate::video::klt::{GrayFrame, Klt, KltSettings};

/// Settings of [`MotionDetector`].
#[derive(Clone, Debug)]
pub struct MotionSettings {
    /// Frames between the compared ones: people must move about their own width in that time
    /// (5 frames at 30 fps: 0.17 s, 0.25 m at a walk, 0.8 m at a run).
    pub step_frames: usize,
    /// Grey-level difference (0-255) above which a pixel has changed.
    pub threshold: f64,
    /// The working copy's largest width, pixels.
    pub max_width: i32,
    /// Opening and closing kernels, full-resolution pixels (as the background detector's).
    pub open_px: i32,
    pub close_px: i32,
    /// Image scale at head height, pixels per metre.
    pub px_per_m: f64,
    /// A blob's area on the ground, m².
    pub min_area_m2: f64,
    pub max_area_m2: f64,
    /// Fewer corners agreeing on a homography than this: the two frames are not aligned.
    pub min_inliers: usize,
    /// σ of a centroid in each axis, pixels.
    pub centroid_sigma_px: f64,
}

impl Default for MotionSettings {
    fn default() -> Self {
        MotionSettings {
            step_frames: 5,
            threshold: 25.0,
            max_width: 960,
            open_px: 3,
            close_px: 9,
            px_per_m: 1.0,
            min_area_m2: 0.08,
            max_area_m2: 4.0,
            min_inliers: 30,
            centroid_sigma_px: 3.0,
        }
    }
}

impl MotionSettings {
    fn check(&self) -> Result<(), String> {
        let s = self;
        if !(1..=60).contains(&s.step_frames) {
            return Err(format!(
                "step_frames must be 1 to 60 frames, not {}",
                s.step_frames
            ));
        }
        if !(s.threshold > 0.0 && s.threshold < 255.0) {
            return Err(format!(
                "threshold must be between 0 and 255 grey levels, not {}",
                s.threshold
            ));
        }
        if s.max_width < 64 {
            return Err(format!(
                "max_width must be at least 64 pixels, not {}",
                s.max_width
            ));
        }
        if s.min_inliers < 8 {
            return Err(format!(
                "min_inliers must be at least 8, not {}",
                s.min_inliers
            ));
        }
        check_blobs(
            (s.open_px, s.close_px),
            s.px_per_m,
            [s.min_area_m2, s.max_area_m2],
            s.centroid_sigma_px,
        )
    }
}

/// The homography from `cur`'s working pixels to `prev`'s, when at least `min_inliers`
/// corners agree on it.
fn align(
    klt: &mut Klt,
    min_inliers: usize,
    prev: &GrayFrame,
    cur: &GrayFrame,
) -> Result<Option<Matrix3<f64>>, String> {
    let corners = klt.detect(prev).map_err(|m| m.to_string())?;
    let tracked = klt
        .track(prev, cur, &corners, None)
        .map_err(|m| m.to_string())?;
    let (src, dst): (Vec<_>, Vec<_>) = corners
        .iter()
        .zip(&tracked)
        .filter_map(|(p, q)| q.map(|q| (q, *p)))
        .unzip();
    if src.len() < min_inliers {
        return Ok(None);
    }
    let ransac = RansacSettings {
        threshold: 1.5,
        ..RansacSettings::default()
    };
    Ok(homography_robust(&src, &dst, &ransac)
        .ok()
        .filter(|r| r.inlier_count >= min_inliers)
        .map(|r| r.model))
}

/// A setting out of its range: which, and what it must be.
#[derive(Debug, thiserror::Error)]
#[error("motion detector: {0}")]
pub struct MotionError(pub String);

/// One frame kept: its index, grey working copy, pyramid, and the homography taking its
/// working pixels to the previous frame's (none when they could not be aligned).
struct Kept {
    index: usize,
    grey: Mat,
    pyramid: GrayFrame,
    to_previous: Option<Matrix3<f64>>,
}

/// Frame-differencing on the ground's motion; see the module documentation.
pub struct MotionDetector {
    settings: MotionSettings,
    klt: Klt,
    /// Frame size, frame pixels per working pixel, working size; fixed by the first frame.
    size: Option<(usize, usize)>,
    factor: i32,
    work: Size,
    blobs: Option<BlobFinder>,
    /// A working-size image of 255s, warped to find where another frame covers one.
    ones: Mat,
    frames: VecDeque<Kept>,
    /// Frames judged, frames without detections for want of alignment, alignments failed.
    judged: usize,
    unaligned: usize,
    alignments_failed: usize,
    changed_fraction: f64,
}

impl MotionDetector {
    pub fn new(settings: MotionSettings) -> Result<MotionDetector, MotionError> {
        settings.check().map_err(MotionError)?;
        let klt = Klt::new(KltSettings {
            max_width: settings.max_width,
            ..KltSettings::default()
        });
        Ok(MotionDetector {
            settings,
            klt,
            size: None,
            factor: 1,
            work: Size::new(0, 0),
            blobs: None,
            ones: Mat::default(),
            frames: VecDeque::new(),
            judged: 0,
            unaligned: 0,
            alignments_failed: 0,
            changed_fraction: 0.0,
        })
    }

    /// The frame's size checked (the first one fixes it), and its grey working copy.
    fn working_grey(&mut self, frame: &FrameView) -> Result<Mat, String> {
        let (w, h) = (frame.width, frame.height);
        if w == 0 || h == 0 || w > i32::MAX as usize / 3 || frame.bgr.len() != 3 * w * h {
            return Err(format!(
                "frame {}: {} bytes for a {w}x{h} BGR frame",
                frame.index,
                frame.bgr.len()
            ));
        }
        match self.size {
            Some(s) if s != (w, h) => {
                return Err(format!(
                    "frame {}: size {w}x{h}, but the video began at {}x{}",
                    frame.index, s.0, s.1
                ));
            }
            Some(_) => {}
            None => {
                let s = &self.settings;
                let factor = (w as i32 + s.max_width - 1) / s.max_width;
                self.work = Size::new(w as i32 / factor, h as i32 / factor);
                if self.work.width < 16 || self.work.height < 16 {
                    return Err(format!("frame {}: {w}x{h} is too small", frame.index));
                }
                self.factor = factor;
                self.ones =
                    Mat::new_size_with_default(self.work, core::CV_8UC1, Scalar::all(255.0))
                        .map_err(e)?;
                self.blobs = Some(BlobFinder::new(
                    factor,
                    (s.open_px, s.close_px),
                    s.px_per_m,
                    [s.min_area_m2, s.max_area_m2],
                    s.centroid_sigma_px,
                )?);
                self.size = Some((w, h));
            }
        }
        let flat = Mat::new_rows_cols_with_data(h as i32, w as i32 * 3, frame.bgr).map_err(e)?;
        let bgr = flat.reshape(3, h as i32).map_err(e)?;
        let mut grey = Mat::default();
        imgproc::cvt_color_def(&bgr, &mut grey, imgproc::COLOR_BGR2GRAY).map_err(e)?;
        let mut small = Mat::default();
        if self.factor > 1 {
            imgproc::resize(&grey, &mut small, self.work, 0.0, 0.0, imgproc::INTER_AREA)
                .map_err(e)?;
        } else {
            small = grey;
        }
        let mut out = Mat::default();
        imgproc::gaussian_blur_def(&small, &mut out, Size::new(3, 3), 0.0).map_err(e)?;
        Ok(out)
    }

    /// The homography from the working pixels of kept frame `from` to those of kept frame
    /// `to`, through the chain between them; none where a link is missing.
    fn chain(&self, from: usize, to: usize) -> Option<Matrix3<f64>> {
        let mut h = Matrix3::identity();
        if from > to {
            // Later to earlier: each frame's `to_previous`, the latest applied first.
            for j in to + 1..=from {
                h *= self.frames[j].to_previous?;
            }
            Some(h)
        } else {
            self.chain(to, from)?.try_inverse()
        }
    }

    /// Kept frame `other` warped onto kept frame `centre`, and where it covers it (255).
    fn warped(&self, other: usize, centre: usize) -> Result<Option<(Mat, Mat)>, String> {
        let Some(h) = self.chain(other, centre) else {
            return Ok(None);
        };
        let m = Mat::from_slice_2d(&[
            [h[(0, 0)], h[(0, 1)], h[(0, 2)]],
            [h[(1, 0)], h[(1, 1)], h[(1, 2)]],
            [h[(2, 0)], h[(2, 1)], h[(2, 2)]],
        ])
        .map_err(e)?;
        let src = &self.frames[other].grey;
        let mut image = Mat::default();
        imgproc::warp_perspective(
            src,
            &mut image,
            &m,
            self.work,
            imgproc::INTER_LINEAR,
            core::BORDER_CONSTANT,
            Scalar::all(0.0),
        )
        .map_err(e)?;
        let mut cover = Mat::default();
        // Nearest, so that the edge is not blurred into grey that a threshold would cut.
        imgproc::warp_perspective(
            &self.ones,
            &mut cover,
            &m,
            self.work,
            imgproc::INTER_NEAREST,
            core::BORDER_CONSTANT,
            Scalar::all(0.0),
        )
        .map_err(e)?;
        Ok(Some((image, cover)))
    }

    /// The detections of the middle kept frame, against the first and the last.
    fn judge_middle(&mut self) -> Result<Vec<Detection>, String> {
        let k = self.settings.step_frames;
        self.judged += 1;
        let (Some((before, cover_b)), Some((after, cover_a))) =
            (self.warped(0, k)?, self.warped(2 * k, k)?)
        else {
            self.unaligned += 1;
            return Ok(Vec::new());
        };
        let centre = &self.frames[k].grey;
        let (mut d1, mut d2, mut d) = (Mat::default(), Mat::default(), Mat::default());
        core::absdiff(centre, &before, &mut d1).map_err(e)?;
        core::absdiff(centre, &after, &mut d2).map_err(e)?;
        core::min(&d1, &d2, &mut d).map_err(e)?;
        let mut changed = Mat::default();
        imgproc::threshold(
            &d,
            &mut changed,
            self.settings.threshold,
            255.0,
            imgproc::THRESH_BINARY,
        )
        .map_err(e)?;
        let (mut covered, mut mask) = (Mat::default(), Mat::default());
        core::bitwise_and_def(&cover_b, &cover_a, &mut covered).map_err(e)?;
        core::bitwise_and_def(&changed, &covered, &mut mask).map_err(e)?;
        let total = f64::from(self.work.width) * f64::from(self.work.height);
        self.changed_fraction += f64::from(core::count_non_zero(&mask).map_err(e)?) / total;
        self.blobs
            .as_mut()
            .expect("set with the first frame")
            .find(&mut mask)
    }
}

impl Detector for MotionDetector {
    fn push(&mut self, frame: &FrameView) -> Result<Vec<FrameDetections>, crate::PluginError> {
        let at = |m: String| format!("frame {}: motion detector: {m}", frame.index);
        let grey = self.working_grey(frame).map_err(at)?;
        let pyramid = self
            .klt
            .frame(frame.index, grey.clone())
            .map_err(|x| at(e(x)))?;
        let to_previous = match self.frames.back() {
            Some(prev) => {
                let h = align(
                    &mut self.klt,
                    self.settings.min_inliers,
                    &prev.pyramid,
                    &pyramid,
                )
                .map_err(at)?;
                if h.is_none() {
                    self.alignments_failed += 1;
                }
                h
            }
            None => None,
        };
        self.frames.push_back(Kept {
            index: frame.index,
            grey,
            pyramid,
            to_previous,
        });
        let k = self.settings.step_frames;
        let mut out = Vec::new();
        // The first k frames have no earlier frame to be compared with.
        if self.frames.len() <= k {
            out.push((frame.index, Vec::new()));
        }
        if self.frames.len() == 2 * k + 1 {
            let found = self
                .judge_middle()
                .map_err(|m| format!("frame {}: motion detector: {m}", self.frames[k].index))?;
            out.push((self.frames[k].index, found));
            self.frames.pop_front();
        }
        Ok(out)
    }

    fn finish(&mut self) -> Result<Vec<FrameDetections>, crate::PluginError> {
        // The last k frames have no later frame to be compared with.
        let k = self.settings.step_frames;
        // Those before were returned already (empty, or judged as the middle frame).
        let first = self.frames.len().min(k);
        Ok(self
            .frames
            .drain(..)
            .skip(first)
            .map(|f| (f.index, Vec::new()))
            .collect())
    }

    fn summary(&self) -> Vec<(String, f64)> {
        let b = self.blobs.as_ref();
        vec![
            ("frames_judged".into(), self.judged as f64),
            ("frames_unaligned".into(), self.unaligned as f64),
            ("alignments_failed".into(), self.alignments_failed as f64),
            (
                "changed_fraction_mean".into(),
                self.changed_fraction / self.judged.max(1) as f64,
            ),
            ("components_kept".into(), b.map_or(0, |b| b.kept) as f64),
            (
                "components_too_small".into(),
                b.map_or(0, |b| b.too_small) as f64,
            ),
            (
                "components_too_large".into(),
                b.map_or(0, |b| b.too_large) as f64,
            ),
        ]
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A textured ground seen by a camera sliding 3 px right and 1 px down a frame, and a dark
    /// 24-px square (a person) walking 8 px right and 2 px down a frame across it.
    fn frame(t: usize, w: usize, h: usize) -> (Vec<u8>, [f64; 2]) {
        let (ox, oy) = (3.0 * t as f64, t as f64);
        let mut bgr = vec![0u8; 3 * w * h];
        let person = [60.0 + 8.0 * t as f64, 100.0 + 2.0 * t as f64];
        for y in 0..h {
            for x in 0..w {
                let (u, v) = (x as f64 + ox, y as f64 + oy);
                let g = 130.0
                    + 35.0 * (u * 0.21 + v * 0.07).sin()
                    + 35.0 * (u * -0.06 + v * 0.23 + 1.0).sin()
                    + 20.0 * (u * 0.13 - v * 0.17 + 2.0).sin();
                let inside = (x as f64) >= person[0]
                    && (x as f64) < person[0] + 24.0
                    && (y as f64) >= person[1]
                    && (y as f64) < person[1] + 24.0;
                let g = if inside { 20.0 } else { g };
                bgr[3 * (y * w + x)..3 * (y * w + x) + 3].fill(g.clamp(0.0, 255.0) as u8);
            }
        }
        (bgr, [person[0] + 11.5, person[1] + 11.5])
    }

    #[test]
    fn a_walker_is_found_on_a_sliding_ground_and_nothing_else() {
        let (w, h) = (320, 240);
        let mut d = MotionDetector::new(MotionSettings {
            step_frames: 3,
            px_per_m: 40.0,
            ..MotionSettings::default()
        })
        .unwrap();
        let mut all: Vec<FrameDetections> = Vec::new();
        let mut truth = Vec::new();
        for t in 0..16 {
            let (bgr, centre) = frame(t, w, h);
            truth.push(centre);
            let view = FrameView {
                index: t,
                width: w,
                height: h,
                bgr: &bgr,
            };
            all.extend(d.push(&view).unwrap());
        }
        all.extend(d.finish().unwrap());
        all.sort_by_key(|f| f.0);
        assert_eq!(
            all.iter().map(|f| f.0).collect::<Vec<_>>(),
            (0..16).collect::<Vec<_>>()
        );
        for (t, found) in &all {
            if *t < 3 || *t >= 13 {
                assert!(found.is_empty(), "frame {t}: {found:?}");
                continue;
            }
            assert_eq!(found.len(), 1, "frame {t}: {found:?}");
            let err = (found[0].uv - nalgebra::Vector2::from(truth[*t])).norm();
            assert!(err < 2.0, "frame {t}: {:?} vs {:?}", found[0].uv, truth[*t]);
        }
        let summary: std::collections::HashMap<_, _> = d.summary().into_iter().collect();
        assert_eq!(summary["frames_judged"], 10.0);
        assert_eq!(summary["frames_unaligned"], 0.0);
    }

    #[test]
    fn bad_settings_are_refused() {
        for s in [
            MotionSettings {
                step_frames: 0,
                ..MotionSettings::default()
            },
            MotionSettings {
                threshold: 300.0,
                ..MotionSettings::default()
            },
            MotionSettings {
                min_area_m2: 5.0,
                ..MotionSettings::default()
            },
        ] {
            assert!(MotionDetector::new(s).is_err());
        }
    }
}
