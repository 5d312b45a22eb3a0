//! The stages' implementations by the names a project file uses: adding a detector, a tracker or
//! a smoother is adding a line here (and its settings to the project file).

use crate::detect::Detector;
use crate::detect::colour::{ColourDetector, ColourSettings, Palette};
use crate::smooth::{KalmanRts, SmoothSettings, Smoother, Unsmoothed};
use crate::track::Tracker;
use crate::track::association::{AssociationSettings, AssociationTracker};

/// The detectors, by name.
pub const DETECTORS: [&str; 1] = ["colour"];
/// The trackers, by name.
pub const TRACKERS: [&str; 1] = ["association"];
/// The smoothers, by name.
pub const SMOOTHERS: [&str; 2] = ["kalman_rts", "none"];

/// A colour detector from its learnt palette.
pub fn colour_detector(palette: &Palette, settings: ColourSettings) -> Box<dyn Detector> {
    Box::new(ColourDetector::new(palette, settings))
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
