//! The one interface to image features (pure): corners found in a frame and followed into
//! another. The stabiliser (`pose::stabilise`) and the people tracker (`track::klt`) use it; the
//! adapter is `video::klt` (OpenCV's corners and pyramidal Lucas–Kanade with a forward–backward
//! check), the tests use synthetic ones.

use nalgebra::Vector2;

/// Finds and follows image features. Points are pixels of the full-resolution frame.
pub trait FeatureTracker {
    type Frame;

    /// Well-textured points of a whole frame, spread over it.
    fn detect(&mut self, frame: &Self::Frame) -> Result<Vec<Vector2<f64>>, crate::PluginError>;

    /// Up to `max` corners inside `bbox` (`[x, y, w, h]`, pixels).
    fn detect_in(
        &mut self,
        frame: &Self::Frame,
        bbox: [f64; 4],
        max: usize,
    ) -> Result<Vec<Vector2<f64>>, crate::PluginError>;

    /// Where `pts` of `from` are in `to`, starting from `guess` when given (else where they
    /// were), searching widely; `None` for a point lost or failing the forward–backward check.
    fn track(
        &mut self,
        from: &Self::Frame,
        to: &Self::Frame,
        pts: &[Vector2<f64>],
        guess: Option<&[Vector2<f64>]>,
    ) -> Result<Vec<Option<Vector2<f64>>>, crate::PluginError>;

    /// Where `pts` of `from` are in `to`, searching only near `guess` (a good prediction): a
    /// coarse search could slide along the long edges of railings and lane lines.
    fn refine(
        &mut self,
        from: &Self::Frame,
        to: &Self::Frame,
        pts: &[Vector2<f64>],
        guess: &[Vector2<f64>],
    ) -> Result<Vec<Option<Vector2<f64>>>, crate::PluginError>;
}
