//! The stages' implementations by the names a project file uses: adding a detector, a tracker or
//! a smoother is adding a line here (and its settings to the project file).

use crate::detect::Detector;
use crate::detect::colour::{ColourSettings, LearningColourDetector};
use crate::smooth::{KalmanRts, SmoothSettings, Smoother, Unsmoothed};
use crate::track::Tracker;
use crate::track::association::{AssociationSettings, AssociationTracker};

/// The detectors, by name.
pub const DETECTORS: [&str; 3] = ["colour", "boxes", "background"];
/// The trackers, by name.
pub const TRACKERS: [&str; 2] = ["association", "klt"];
/// The smoothers, by name.
pub const SMOOTHERS: [&str; 2] = ["kalman_rts", "none"];

/// Memory the colour detector may fill with frames held back while it learns its palette.
pub const COLOUR_BUDGET_BYTES: usize = 1 << 30;

/// A colour detector that learns its palette from `sample_frames` frames drawn from the
/// `frames` of the video as it goes by (every 97th pixel of each).
pub fn colour_detector(
    settings: ColourSettings,
    frames: Option<usize>,
    sample_frames: usize,
) -> Box<dyn Detector> {
    Box::new(LearningColourDetector::new(
        settings,
        frames,
        sample_frames,
        97,
        COLOUR_BUDGET_BYTES,
    ))
}

/// A tracker by name.
pub fn tracker(name: &str, settings: AssociationSettings) -> Option<Box<dyn Tracker>> {
    match name {
        "association" => Some(Box::new(AssociationTracker::new(settings))),
        _ => None,
    }
}

/// A smoother by name.
pub fn smoother(name: &str, settings: SmoothSettings) -> Option<Box<dyn Smoother>> {
    match name {
        "kalman_rts" => Some(Box::new(KalmanRts(settings))),
        "none" => Some(Box::new(Unsmoothed { dt: settings.dt })),
        _ => None,
    }
}
