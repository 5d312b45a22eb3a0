//! Moving people on a still background (OpenCV adapter): background subtraction for a hovering
//! camera (the stream event's detector when no box detector is at hand).
//!
//! Each frame is reduced (`INTER_AREA`, by a whole factor) to a working copy no wider than
//! `max_width`, given to OpenCV's MOG2 or KNN background model, and its foreground mask is
//! thresholded (shadows, 127 in the mask, are dropped), opened, closed and cut into connected
//! components. A component whose area on the ground lies between `min_area_m2` and
//! `max_area_m2` is one detection: its centroid, bounding box and area, all in the frame's own
//! pixels. The first `warmup_frames` frames only teach the model and yield no detections.
//!
//! The model absorbs what stays: with MOG2's background ratio of 0.9, a colour that covers a
//! pixel for about 0.1 / rate frames becomes background (rate 1/history once the model is
//! running, 30 frames at the default history of 300; faster in its first frames, where OpenCV's
//! automatic rate is 1/(2n)). A person standing still for longer fades from the mask.

use nalgebra::{Matrix2, Vector2};
use opencv::core::{self, CV_8UC3, CV_32S, Mat, Point, Ptr, Size};
use opencv::prelude::*;
use opencv::{imgproc, video};

use super::{Detection, Detector, FrameDetections, FrameView};

/// OpenCV's background models.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, serde::Deserialize, serde::Serialize)]
#[serde(rename_all = "lowercase")]
pub enum Subtractor {
    /// Gaussian mixture per pixel (`createBackgroundSubtractorMOG2`).
    #[default]
    Mog2,
    /// K nearest neighbours among past samples per pixel (`createBackgroundSubtractorKNN`).
    Knn,
}

/// Settings of [`BackgroundDetector`].
#[derive(Clone, Debug)]
pub struct BackgroundSettings {
    pub method: Subtractor,
    /// Frames the model remembers.
    pub history: i32,
    /// MOG2: squared Mahalanobis distance to a mode beyond which a pixel is foreground (16).
    /// KNN: squared colour distance to a sample (400). [`BackgroundSettings::for_method`] picks
    /// the method's value.
    pub var_threshold: f64,
    /// Whether the model marks shadows (which are never foreground here).
    pub detect_shadows: bool,
    /// The model's learning rate per frame, 0 to 1; negative for OpenCV's automatic rate.
    pub learning_rate: f64,
    /// The working copy's largest width, pixels.
    pub max_width: i32,
    /// Sides of the elliptic kernels of the opening (removes specks) and the closing (joins a
    /// person's parts), full-resolution pixels; scaled to the working copy, 1 or less skips.
    pub open_px: i32,
    pub close_px: i32,
    /// Image scale at head height, pixels per metre.
    pub px_per_m: f64,
    /// Components smaller than this on the ground are noise, larger ones are not one person
    /// (or not people), m².
    pub min_area_m2: f64,
    pub max_area_m2: f64,
    /// Frames, from the first, that only teach the model (returned with no detections).
    pub warmup_frames: usize,
    /// Standard deviation of a centroid in each axis, pixels: `Detection::cov` is σ²·I.
    pub centroid_sigma_px: f64,
}

impl BackgroundSettings {
    /// The defaults, with the threshold that suits `method`.
    pub fn for_method(method: Subtractor) -> BackgroundSettings {
        BackgroundSettings {
            method,
            history: 300,
            var_threshold: match method {
                Subtractor::Mog2 => 16.0,
                Subtractor::Knn => 400.0,
            },
            detect_shadows: true,
            learning_rate: -1.0,
            max_width: 960,
            open_px: 3,
            close_px: 9,
            px_per_m: 1.0,
            min_area_m2: 0.08,
            max_area_m2: 4.0,
            warmup_frames: 25,
            centroid_sigma_px: 3.0,
        }
    }

    fn check(&self) -> Result<(), String> {
        let s = self;
        if s.history < 1 {
            return Err(format!(
                "history must be at least 1 frame, not {}",
                s.history
            ));
        }
        if !(s.var_threshold > 0.0 && s.var_threshold.is_finite()) {
            return Err(format!(
                "var_threshold must be positive, not {}",
                s.var_threshold
            ));
        }
        if !(s.learning_rate <= 1.0) {
            return Err(format!(
                "learning_rate must be at most 1 (negative for automatic), not {}",
                s.learning_rate
            ));
        }
        if s.max_width < 16 {
            return Err(format!(
                "max_width must be at least 16 pixels, not {}",
                s.max_width
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

impl Default for BackgroundSettings {
    fn default() -> Self {
        BackgroundSettings::for_method(Subtractor::Mog2)
    }
}

/// The checks of [`BlobFinder`]'s settings, as both detectors that use it take them.
pub(crate) fn check_blobs(
    (open_px, close_px): (i32, i32),
    px_per_m: f64,
    area_m2: [f64; 2],
    centroid_sigma_px: f64,
) -> Result<(), String> {
    if open_px < 0 || close_px < 0 {
        return Err(format!(
            "open_px and close_px must not be negative (0 skips), not {} and {}",
            open_px, close_px
        ));
    }
    if !(px_per_m > 0.0 && px_per_m.is_finite()) {
        return Err(format!(
            "px_per_m must be positive (the image scale at head height), not {}",
            px_per_m
        ));
    }
    if !(area_m2[0] >= 0.0 && area_m2[1] > area_m2[0]) {
        return Err(format!(
            "need 0 <= min_area_m2 < max_area_m2, not {} and {}",
            area_m2[0], area_m2[1]
        ));
    }
    if !(centroid_sigma_px > 0.0 && centroid_sigma_px.is_finite()) {
        return Err(format!(
            "centroid_sigma_px must be positive, not {}",
            centroid_sigma_px
        ));
    }
    Ok(())
}

/// The OpenCV model. Both pointers are `Send` in the `opencv` crate (the models hold no
/// thread-bound state); the detector uses its model from one thread at a time.
enum Model {
    Mog2(Ptr<video::BackgroundSubtractorMOG2>),
    Knn(Ptr<video::BackgroundSubtractorKNN>),
}

impl Model {
    fn apply(
        &mut self,
        image: &impl core::ToInputArray,
        mask: &mut Mat,
        rate: f64,
    ) -> opencv::Result<()> {
        match self {
            Model::Mog2(m) => video::BackgroundSubtractorTrait::apply(m, image, mask, rate),
            Model::Knn(m) => video::BackgroundSubtractorTrait::apply(m, image, mask, rate),
        }
    }
}

/// What depends on the frame size, fixed by the first frame.
struct Geometry {
    width: usize,
    height: usize,
    /// Frame pixels per working pixel (a whole number), and the working size.
    factor: i32,
    work: Size,
    blobs: BlobFinder,
}

/// People-sized blobs of a working-resolution mask: opened (specks go), closed (a person's
/// parts join), cut into connected components, those of a person's area on the ground kept as
/// detections in the frame's own pixels. Shared by the background and the motion detectors.
pub(crate) struct BlobFinder {
    factor: i32,
    open: Option<Mat>,
    close: Option<Mat>,
    px_per_m: f64,
    area_m2: [f64; 2],
    centroid_sigma_px: f64,
    scratch: Mat,
    labels: Mat,
    stats: Mat,
    centroids: Mat,
    pub kept: usize,
    pub too_small: usize,
    pub too_large: usize,
}

impl BlobFinder {
    /// `factor` frame pixels a working pixel; kernels and limits as [`BackgroundSettings`]'s.
    pub(crate) fn new(
        factor: i32,
        (open_px, close_px): (i32, i32),
        px_per_m: f64,
        area_m2: [f64; 2],
        centroid_sigma_px: f64,
    ) -> Result<BlobFinder, String> {
        Ok(BlobFinder {
            factor,
            open: kernel(open_px, factor)?,
            close: kernel(close_px, factor)?,
            px_per_m,
            area_m2,
            centroid_sigma_px,
            scratch: Mat::default(),
            labels: Mat::default(),
            stats: Mat::default(),
            centroids: Mat::default(),
            kept: 0,
            too_small: 0,
            too_large: 0,
        })
    }

    /// The blobs of a binary mask (255 foreground), which the morphology changes in place.
    pub(crate) fn find(&mut self, mask: &mut Mat) -> Result<Vec<Detection>, String> {
        for (op, k) in [
            (imgproc::MORPH_OPEN, &self.open),
            (imgproc::MORPH_CLOSE, &self.close),
        ] {
            if let Some(k) = k {
                imgproc::morphology_ex_def(&*mask, &mut self.scratch, op, k).map_err(e)?;
                std::mem::swap(mask, &mut self.scratch);
            }
        }
        let n = imgproc::connected_components_with_stats(
            &*mask,
            &mut self.labels,
            &mut self.stats,
            &mut self.centroids,
            8,
            CV_32S,
        )
        .map_err(e)?;
        let f = f64::from(self.factor);
        let m2_per_px = 1.0 / (self.px_per_m * self.px_per_m);
        let cov = Matrix2::identity() * (self.centroid_sigma_px * self.centroid_sigma_px);
        let full = |x: f64| (x + 0.5) * f - 0.5;
        let mut out = Vec::new();
        // Label 0 is the background.
        for i in 1..n {
            let stat = |c: i32| self.stats.at_2d::<i32>(i, c).copied().map_err(e);
            let area_px = f64::from(stat(imgproc::CC_STAT_AREA)?) * f * f;
            let area_m2 = area_px * m2_per_px;
            if area_m2 < self.area_m2[0] {
                self.too_small += 1;
                continue;
            }
            if area_m2 > self.area_m2[1] {
                self.too_large += 1;
                continue;
            }
            self.kept += 1;
            let cx = *self.centroids.at_2d::<f64>(i, 0).map_err(e)?;
            let cy = *self.centroids.at_2d::<f64>(i, 1).map_err(e)?;
            out.push(Detection {
                uv: Vector2::new(full(cx), full(cy)),
                cov,
                // Edges: the left edge of working pixel x is frame coordinate x·f − ½.
                bbox: [
                    f64::from(stat(imgproc::CC_STAT_LEFT)?) * f - 0.5,
                    f64::from(stat(imgproc::CC_STAT_TOP)?) * f - 0.5,
                    f64::from(stat(imgproc::CC_STAT_WIDTH)?) * f,
                    f64::from(stat(imgproc::CC_STAT_HEIGHT)?) * f,
                ],
                area_px,
                score: 1.0,
                model_head: None,
            });
        }
        Ok(out)
    }
}

/// Background subtraction for a stationary camera; see the module documentation.
pub struct BackgroundDetector {
    settings: BackgroundSettings,
    model: Model,
    geometry: Option<Geometry>,
    /// Working buffers, reused from frame to frame.
    small: Mat,
    raw: Mat,
    mask: Mat,
    frames: usize,
    /// Sum over frames after warm-up of the foreground fraction (before morphology).
    foreground: f64,
}

pub(crate) fn e(e: opencv::Error) -> String {
    format!("OpenCV: {e}")
}

/// An elliptic kernel for a side of `px` full-resolution pixels, or none when it would do
/// nothing on the working copy.
pub(crate) fn kernel(px: i32, factor: i32) -> Result<Option<Mat>, String> {
    let side = (f64::from(px) / f64::from(factor)).round() as i32;
    if side <= 1 {
        return Ok(None);
    }
    let side = side | 1; // odd, so that the kernel is centred
    imgproc::get_structuring_element(
        imgproc::MORPH_ELLIPSE,
        Size::new(side, side),
        Point::new(-1, -1),
    )
    .map(Some)
    .map_err(e)
}

/// Why a background detector could not be made.
#[derive(Debug, thiserror::Error)]
pub enum BackgroundError {
    /// A setting out of its range: which, and what it must be.
    #[error("background detector: {0}")]
    Settings(String),
    /// OpenCV could not create the model.
    #[error(transparent)]
    OpenCv(#[from] opencv::Error),
}

impl BackgroundDetector {
    pub fn new(settings: BackgroundSettings) -> Result<BackgroundDetector, BackgroundError> {
        settings.check().map_err(BackgroundError::Settings)?;
        let s = &settings;
        let model = match s.method {
            Subtractor::Mog2 => Model::Mog2(video::create_background_subtractor_mog2(
                s.history,
                s.var_threshold,
                s.detect_shadows,
            )?),
            Subtractor::Knn => Model::Knn(video::create_background_subtractor_knn(
                s.history,
                s.var_threshold,
                s.detect_shadows,
            )?),
        };
        Ok(BackgroundDetector {
            settings,
            model,
            geometry: None,
            small: Mat::default(),
            raw: Mat::default(),
            mask: Mat::default(),
            frames: 0,
            foreground: 0.0,
        })
    }

    pub fn settings(&self) -> &BackgroundSettings {
        &self.settings
    }

    /// The geometry for a frame: made from the first, checked against every later one.
    fn geometry(&mut self, frame: &FrameView) -> Result<(), String> {
        let (w, h) = (frame.width, frame.height);
        if w == 0 || h == 0 || w > i32::MAX as usize / 3 || h > i32::MAX as usize {
            return Err(format!("frame {}: bad frame size {w}x{h}", frame.index));
        }
        if frame.bgr.len() != 3 * w * h {
            return Err(format!(
                "frame {}: {} bytes for a {w}x{h} BGR frame, expected {}",
                frame.index,
                frame.bgr.len(),
                3 * w * h
            ));
        }
        if let Some(g) = &self.geometry {
            if (g.width, g.height) != (w, h) {
                return Err(format!(
                    "frame {}: size {w}x{h}, but the video began at {}x{}",
                    frame.index, g.width, g.height
                ));
            }
            return Ok(());
        }
        let (wi, hi) = (w as i32, h as i32);
        let max_w = self.settings.max_width;
        let factor = (wi + max_w - 1) / max_w;
        let work = Size::new(wi / factor, hi / factor);
        if work.width < 1 || work.height < 1 {
            return Err(format!(
                "frame {}: {w}x{h} is too small to reduce to at most {max_w} pixels wide",
                frame.index
            ));
        }
        let s = &self.settings;
        self.geometry = Some(Geometry {
            width: w,
            height: h,
            factor,
            work,
            blobs: BlobFinder::new(
                factor,
                (s.open_px, s.close_px),
                s.px_per_m,
                [s.min_area_m2, s.max_area_m2],
                s.centroid_sigma_px,
            )?,
        });
        Ok(())
    }

    /// The model's mask of one frame in `self.raw` (working resolution).
    fn subtract(&mut self, frame: &FrameView) -> Result<(), String> {
        let g = self.geometry.as_ref().expect("geometry set first");
        let (w, h) = (g.width as i32, g.height as i32);
        // The caller's bytes, not copied: a w·3 × h single-channel view reshaped to 3 channels.
        let flat = Mat::new_rows_cols_with_data(h, w * 3, frame.bgr).map_err(e)?;
        let bgr = flat.reshape(3, h).map_err(e)?;
        debug_assert_eq!(bgr.typ(), CV_8UC3);
        let rate = self.settings.learning_rate;
        if g.factor > 1 {
            imgproc::resize(&bgr, &mut self.small, g.work, 0.0, 0.0, imgproc::INTER_AREA)
                .map_err(e)?;
            self.model.apply(&self.small, &mut self.raw, rate)
        } else {
            self.model.apply(&bgr, &mut self.raw, rate)
        }
        .map_err(e)
    }

    /// Threshold, morphology and components of `self.raw`: the frame's detections.
    fn components(&mut self) -> Result<Vec<Detection>, String> {
        let g = self.geometry.as_mut().expect("geometry set first");
        // Foreground is 255, shadows 127: keep only the former.
        imgproc::threshold(
            &self.raw,
            &mut self.mask,
            200.0,
            255.0,
            imgproc::THRESH_BINARY,
        )
        .map_err(e)?;
        let total = f64::from(g.work.width) * f64::from(g.work.height);
        self.foreground += f64::from(core::count_non_zero(&self.mask).map_err(e)?) / total;
        g.blobs.find(&mut self.mask)
    }
}

impl Detector for BackgroundDetector {
    fn push(&mut self, frame: &FrameView) -> Result<Vec<FrameDetections>, crate::PluginError> {
        self.geometry(frame)?;
        self.subtract(frame)
            .map_err(|m| format!("frame {}: background model: {m}", frame.index))?;
        self.frames += 1;
        if self.frames <= self.settings.warmup_frames {
            return Ok(vec![(frame.index, Vec::new())]);
        }
        let found = self
            .components()
            .map_err(|m| format!("frame {}: foreground components: {m}", frame.index))?;
        Ok(vec![(frame.index, found)])
    }

    fn summary(&self) -> Vec<(String, f64)> {
        let judged = self.frames.saturating_sub(self.settings.warmup_frames);
        let b = self.geometry.as_ref().map(|g| &g.blobs);
        vec![
            ("frames".into(), self.frames as f64),
            (
                "warmup_frames".into(),
                self.frames.min(self.settings.warmup_frames) as f64,
            ),
            (
                "foreground_fraction_mean".into(),
                if judged > 0 {
                    self.foreground / judged as f64
                } else {
                    0.0
                },
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
    use std::path::PathBuf;
    use std::time::Instant;

    /// A still, textured BGR background (band-limited plane waves, 40 to 200 in each channel).
    fn background(w: usize, h: usize) -> Vec<u8> {
        let mut px = vec![0u8; 3 * w * h];
        for y in 0..h {
            for x in 0..w {
                let (u, v) = (x as f64, y as f64);
                for c in 0..3 {
                    let k = c as f64;
                    let s = (u * (0.11 + 0.03 * k) + v * 0.07 + k).sin()
                        + (u * -0.05 + v * (0.13 - 0.02 * k) + 2.0 * k).sin();
                    px[3 * (y * w + x) + c] = (120.0 + 40.0 * s).round() as u8;
                }
            }
        }
        px
    }

    /// A seeded generator of small noise.
    struct Lcg(u64);
    impl Lcg {
        fn next(&mut self) -> u32 {
            self.0 = self
                .0
                .wrapping_mul(6364136223846793005)
                .wrapping_add(1442695040888963407);
            (self.0 >> 33) as u32
        }
    }

    /// Two bright squares moving across a noisy still background, `scale` times 640×360 (the
    /// working copy is 640 wide; at scale 2 the squares' edges cut working pixels in half);
    /// returns the detections' worst centroid error after warm-up, pixels.
    fn synthetic(method: Subtractor, scale: usize) -> f64 {
        let (w, h) = (640 * scale, 360 * scale);
        let side = 24 * scale;
        let base = background(w, h);
        let mut det = BackgroundDetector::new(BackgroundSettings {
            max_width: 640,
            px_per_m: 40.0 * scale as f64,
            ..BackgroundSettings::for_method(method)
        })
        .unwrap();
        let warmup = det.settings().warmup_frames;
        let mut rng = Lcg(7);
        let mut worst: f64 = 0.0;
        for i in 0..80usize {
            let mut frame = base.clone();
            for p in frame.iter_mut() {
                *p = (i32::from(*p) + (rng.next() % 7) as i32 - 3) as u8;
            }
            // The squares enter at frame 10, so the model first learns a clean background.
            let t = i.saturating_sub(10);
            let squares = [
                (30 + 8 * t, 80 + t / 2),   // right and a little down
                (590 - 8 * t, 260 - t / 2), // left and a little up
            ]
            .map(|(x, y)| (x * scale + scale / 2, y * scale + scale / 2));
            if i >= 10 {
                for &(x0, y0) in &squares {
                    for y in y0..y0 + side {
                        for x in x0..x0 + side {
                            let k = 3 * (y * w + x);
                            frame[k..k + 3].copy_from_slice(&[235, 245, 250]);
                        }
                    }
                }
            }
            let view = FrameView {
                index: i,
                width: w,
                height: h,
                bgr: &frame,
            };
            let out = det.push(&view).unwrap();
            assert_eq!(out.len(), 1);
            let (index, found) = &out[0];
            assert_eq!(*index, i);
            if i < warmup {
                assert!(found.is_empty(), "frame {i}: detections during warm-up");
                continue;
            }
            assert_eq!(found.len(), 2, "frame {i}: {found:?}");
            let half = (side as f64 - 1.0) / 2.0;
            for &(x0, y0) in &squares {
                let truth = Vector2::new(x0 as f64 + half, y0 as f64 + half);
                let d = found
                    .iter()
                    .min_by(|a, b| (a.uv - truth).norm().total_cmp(&(b.uv - truth).norm()))
                    .unwrap();
                let err = (d.uv - truth).norm();
                worst = worst.max(err);
                assert!(err <= 1.5, "frame {i}: {d:?} vs true {truth:?}");
                // The box and area describe the square at full resolution.
                let s = side as f64;
                assert!((d.bbox[0] - (x0 as f64 - 0.5)).abs() <= 2.0 * scale as f64);
                assert!((d.bbox[2] - s).abs() <= 3.0 * scale as f64, "{:?}", d.bbox);
                assert!((d.area_px / (s * s) - 1.0).abs() < 0.2, "{}", d.area_px);
                assert_eq!(d.cov, Matrix2::identity() * 9.0);
            }
        }
        let sum = det.summary();
        println!("{method:?}, {w}x{h}: worst centroid error {worst:.3} px; summary {sum:?}");
        worst
    }

    #[test]
    fn finds_moving_squares_mog2() {
        synthetic(Subtractor::Mog2, 1);
    }

    #[test]
    fn finds_moving_squares_knn() {
        synthetic(Subtractor::Knn, 1);
    }

    #[test]
    fn finds_moving_squares_on_reduced_copy() {
        synthetic(Subtractor::Mog2, 2);
    }

    #[test]
    fn rejects_bad_settings_and_frames() {
        let bad = BackgroundDetector::new(BackgroundSettings {
            px_per_m: 0.0,
            ..Default::default()
        });
        assert!(bad.err().unwrap().to_string().contains("px_per_m"));
        let mut det = BackgroundDetector::new(BackgroundSettings::default()).unwrap();
        let bytes = vec![0u8; 3 * 64 * 48];
        let view = |width, height| FrameView {
            index: 3,
            width,
            height,
            bgr: &bytes,
        };
        let err = det.push(&view(64, 40)).unwrap_err();
        assert!(err.to_string().contains("bytes"), "{err}");
        det.push(&view(64, 48)).unwrap();
        let err = det.push(&view(48, 64)).unwrap_err();
        assert!(err.to_string().contains("began at 64x48"), "{err}");
    }

    #[test]
    fn vtest_people() {
        let Some(root) = std::env::var_os("GEOSTRIDE_DATA") else {
            println!("GEOSTRIDE_DATA is not set: skipping the vtest video");
            return;
        };
        let path = PathBuf::from(root).join("video/vtest_480x360_h264.avi");
        let mut reader = crate::video::source::FrameReader::open(&path)
            .unwrap_or_else(|m| panic!("GEOSTRIDE_DATA is set but: {m}"));
        // People there are 25–40 px tall and 10–15 px wide: 100 px² and more of foreground.
        let mut det = BackgroundDetector::new(BackgroundSettings {
            px_per_m: 20.0,
            min_area_m2: 0.2,
            max_area_m2: 6.0,
            ..Default::default()
        })
        .unwrap();
        let warmup = det.settings().warmup_frames;
        let mut mat = Mat::default();
        let mut counts = Vec::new();
        let mut spent = 0.0;
        while counts.len() < 200 {
            let Some(i) = reader.read_bgr_into(&mut mat).unwrap() else {
                break;
            };
            let view = FrameView {
                index: i,
                width: mat.cols() as usize,
                height: mat.rows() as usize,
                bgr: mat.data_bytes().unwrap(),
            };
            let t = Instant::now();
            let out = det.push(&view).unwrap();
            spent += t.elapsed().as_secs_f64();
            assert_eq!(out.len(), 1);
            assert_eq!(out[0].0, i);
            counts.push(out[0].1.len());
        }
        assert_eq!(counts.len(), 200, "the video is shorter than 200 frames");
        let after = &counts[warmup..];
        let good = after.iter().filter(|&&n| (1..=15).contains(&n)).count();
        let mean = after.iter().sum::<usize>() as f64 / after.len() as f64;
        println!(
            "vtest: {good} of {} frames after warm-up have 1-15 detections, mean {mean:.2}, \
             min {}, max {}; {:.2} ms per frame; summary {:?}",
            after.len(),
            after.iter().min().unwrap(),
            after.iter().max().unwrap(),
            1e3 * spent / counts.len() as f64,
            det.summary()
        );
        println!("counts after warm-up: {after:?}");
        assert!(counts[..warmup].iter().all(|&n| n == 0));
        assert!(
            good as f64 >= 0.9 * after.len() as f64,
            "only {good} of {} frames have 1-15 detections",
            after.len()
        );
    }
}
