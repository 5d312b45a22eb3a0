//! Tracking in the image (pure): trackers turn per-frame detections into image tracks with
//! identities. `association` is the paper's blob association (section 3.2.1), made global.

pub mod association;
pub mod klt;
pub mod link;

use nalgebra::{Matrix2, Vector2};

use crate::detect::Detection;

/// One observed point of an image track.
#[derive(Clone, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct TrackPoint {
    pub frame: usize,
    pub uv: Vector2<f64>,
    pub cov: Matrix2<f64>,
    pub bbox: [f64; 4],
    /// The detector's score of this frame's detection; `None` where the tracker bridged a
    /// frame without one.
    pub score: Option<f64>,
}

/// A person's path through the image.
#[derive(Clone, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct ImageTrack {
    pub id: usize,
    /// Observations in frame order; frames without one are gaps.
    pub points: Vec<TrackPoint>,
}

/// Maps a pixel of the previous frame to where the same head-height point is in this frame
/// (camera motion).
pub type Motion<'a> = &'a dyn Fn(&Vector2<f64>) -> Vector2<f64>;

/// Builds tracks from detections, frame by frame, in order.
pub trait Tracker: Send {
    fn update(&mut self, frame: usize, detections: &[Detection], motion: Motion);
    /// The confirmed tracks.
    fn finish(self: Box<Self>) -> Vec<ImageTrack>;
}
