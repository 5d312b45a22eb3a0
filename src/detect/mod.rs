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

/// Finds people in frames. Implementations keep whatever they learnt (a colour model, a
/// background) between calls.
pub trait Detector: Send {
    fn detect(&mut self, frame: &FrameView) -> Vec<Detection>;
}
