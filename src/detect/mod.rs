//! Person detection (pure): detectors turn a frame into head positions in pixels with a
//! covariance. `colour` finds coloured hats (the paper's section 3.1.1).

pub mod colour;
pub mod morph;

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
