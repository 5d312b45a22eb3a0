//! Person detection: detectors turn a frame into head positions in pixels with a covariance.
//! `colour` finds coloured hats (the paper's section 3.1.1); `boxes` reads an external
//! detector's boxes (`boxes`, `person`); `background` (an OpenCV adapter, the only module here
//! that is not pure) finds moving people under a stationary camera.

pub mod background;
pub mod boxes;
pub mod colour;
pub mod morph;
pub mod person;
pub mod simulated;

use nalgebra::{Matrix2, Vector2};

/// A frame as 8-bit BGR (OpenCV's order), row-major, tightly packed.
#[derive(Clone, Copy, Debug)]
pub struct FrameView<'a> {
    pub index: usize,
    pub width: usize,
    pub height: usize,
    pub bgr: &'a [u8],
}

impl FrameView<'_> {
    pub fn pixel(&self, x: usize, y: usize) -> [u8; 3] {
        let i = 3 * (y * self.width + x);
        [self.bgr[i + 2], self.bgr[i + 1], self.bgr[i]]
    }
}

/// One detected head.
#[derive(Clone, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct Detection {
    /// The head's centre, pixels ((0, 0) the centre of the top-left pixel).
    pub uv: Vector2<f64>,
    /// Covariance of `uv`, px².
    pub cov: Matrix2<f64>,
    /// Bounding box `[x, y, width, height]`, pixels.
    pub bbox: [f64; 4],
    pub area_px: f64,
    /// 1 for a clean detection, lower for doubtful ones.
    pub score: f64,
}

/// Detections of one frame, by frame index.
pub type FrameDetections = (usize, Vec<Detection>);

/// Finds people in frames, which come in order. Implementations keep whatever they learn (a
/// colour model, a background) between calls; one still learning may hold frames back and
/// return them later, so each call returns the frames it completed, in order.
pub trait Detector: Send {
    /// Takes the next frame. Errors mean the video cannot be processed with these settings.
    fn push(&mut self, frame: &FrameView) -> Result<Vec<FrameDetections>, String>;
    /// After the last frame: the frames still held back.
    fn finish(&mut self) -> Result<Vec<FrameDetections>, String> {
        Ok(Vec::new())
    }
    /// Numbers for the run report (what was learnt, say).
    fn summary(&self) -> Vec<(String, f64)> {
        Vec::new()
    }
}

/// The detection error of a person detector across the image (the paper's section 4.1.3): the
/// vertical variance is constant, the horizontal one rises linearly from the centre to the
/// left and right edges, where people are seen most obliquely.
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct ErrorModel {
    pub vertical_px2: f64,
    pub horizontal_centre_px2: f64,
    pub horizontal_edge_px2: f64,
}

impl Default for ErrorModel {
    fn default() -> Self {
        ErrorModel {
            vertical_px2: 10.0,
            horizontal_centre_px2: 10.0,
            horizontal_edge_px2: 20.0,
        }
    }
}

impl ErrorModel {
    /// Covariance (px²) of a detection at `uv` in an image `width` pixels wide.
    pub fn cov(&self, uv: &Vector2<f64>, width: f64) -> Matrix2<f64> {
        let half = (width / 2.0).max(1.0);
        let t = ((uv.x - (width - 1.0) / 2.0).abs() / half).min(1.0);
        let h = self.horizontal_centre_px2
            + (self.horizontal_edge_px2 - self.horizontal_centre_px2) * t;
        Matrix2::new(h, 0.0, 0.0, self.vertical_px2)
    }
}

/// A person's head from the box around the whole body, seen from above: vertical lines meet at
/// the nadir's image, so the body lies along the line from the nadir through the box and the
/// head is at its far end, one body radius (`body_radius_px`) in from the box's edge.
pub fn head_from_box(bbox: &[f64; 4], nadir: &Vector2<f64>, body_radius_px: f64) -> Vector2<f64> {
    let c = Vector2::new(bbox[0] + bbox[2] / 2.0, bbox[1] + bbox[3] / 2.0);
    let away = c - nadir;
    let Some(d) = away.try_normalize(1e-9) else {
        return c;
    };
    // Half the box's extent along d.
    let half = d.x.abs() * bbox[2] / 2.0 + d.y.abs() * bbox[3] / 2.0;
    c + d * (half - body_radius_px).max(0.0)
}

#[cfg(test)]
mod model_tests {
    use super::*;

    #[test]
    fn error_model_rises_to_the_edges_and_head_lies_away_from_the_nadir() {
        let m = ErrorModel::default();
        let w = 3840.0;
        assert_eq!(
            m.cov(&Vector2::new((w - 1.0) / 2.0, 100.0), w)[(0, 0)],
            10.0
        );
        assert!((m.cov(&Vector2::new(0.0, 100.0), w)[(0, 0)] - 20.0).abs() < 0.01);
        assert!((m.cov(&Vector2::new(w * 0.75, 5.0), w)[(0, 0)] - 15.0).abs() < 0.01);
        assert_eq!(m.cov(&Vector2::new(0.0, 100.0), w)[(1, 1)], 10.0);
        // A body lying to the right of the nadir: the head at the right end, one radius in.
        let nadir = Vector2::new(100.0, 100.0);
        let h = head_from_box(&[300.0, 90.0, 60.0, 20.0], &nadir, 10.0);
        assert!((h - Vector2::new(350.0, 100.0)).norm() < 1e-9, "{h}");
        // Below the nadir: the box centre.
        let h = head_from_box(&[90.0, 90.0, 20.0, 20.0], &nadir, 10.0);
        assert!((h - Vector2::new(100.0, 100.0)).norm() < 1e-9);
    }
}
