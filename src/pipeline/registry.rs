//! The one place where a project's stage settings choose an implementation: adding a detector,
//! a tracker, a smoother or a ground is a variant in `settings`, its module, and an arm here (the matches
//! are exhaustive, so the compiler lists every place a new kind must be handled).

use super::detectors::{self, DetectorInputs};
use super::error::RunError;
use super::grounds::{self, GroundInputs};
use super::settings::{DetectSection, GroundSection, KltSection, SmoothSection, TrackSection};
use crate::detect::Detector;
use crate::smooth::{KalmanRts, SmoothSettings, Smoother, Unsmoothed};
use crate::terrain::HeightSurface;
use crate::track::Tracker;
use crate::track::association::{AssociationSettings, AssociationTracker};

/// The detector of a project's `[detect]`.
pub fn detector(d: &DetectSection, x: &DetectorInputs) -> Result<Box<dyn Detector>, RunError> {
    match d {
        DetectSection::Colour(c) => Ok(detectors::colour(c, x.px_per_m, x.frames)),
        DetectSection::Boxes(b) => detectors::boxes(b, x),
        DetectSection::Background(b) => detectors::background(b, x),
        DetectSection::Onnx(o) => detectors::onnx(o, x),
        DetectSection::Motion(m) => detectors::motion(m, x),
    }
}

/// The ground of a project's `[ground]`, in the site frame.
pub fn ground(g: &GroundSection, x: &GroundInputs) -> Result<Box<dyn HeightSurface>, RunError> {
    match g {
        GroundSection::Plane { height_m } => grounds::plane(*height_m, x),
        GroundSection::Deck {
            centre_line,
            width_m,
            stations,
            degree,
        } => grounds::deck(centre_line, *width_m, stations, *degree, x),
        GroundSection::Dem { path } => grounds::dem(path, x),
        GroundSection::LocalPlanes { model, window_m } => {
            grounds::local_planes(model, *window_m, x)
        }
    }
}

/// A tracker: one fed frame by frame, or the KLT pass over the video.
pub enum TrackerChoice<'a> {
    Frames(Box<dyn Tracker>),
    Klt(&'a KltSection),
}

/// The image scale and frame rate a tracker's settings are converted with.
pub struct TrackScale {
    pub px_per_m: f64,
    pub fps: f64,
    /// Detections closer than this are one person, pixels.
    pub duplicate_px: f64,
}

/// The tracker of a project's `[track]`.
pub fn tracker<'a>(t: &'a TrackSection, scale: &TrackScale) -> TrackerChoice<'a> {
    match t {
        TrackSection::Association(a) => {
            TrackerChoice::Frames(Box::new(AssociationTracker::new(AssociationSettings {
                gate_px: a.gate_m * scale.px_per_m,
                confirm_hits: a.confirm_frames,
                max_misses: (a.max_gap_s * scale.fps).round() as usize,
                duplicate_px: scale.duplicate_px,
                ..AssociationSettings::default()
            })))
        }
        TrackSection::Klt(k) => TrackerChoice::Klt(k),
    }
}

/// The smoother of a project's `[smooth]` for frames `dt` seconds apart.
pub fn smoother(s: &SmoothSection, dt: f64) -> Box<dyn Smoother> {
    match s {
        SmoothSection::KalmanRts(k) => Box::new(KalmanRts(SmoothSettings {
            dt,
            q_position_m: k.q_position_m,
            q_velocity_m_s: k.q_velocity_m_s,
            em: k.em,
            model: k.model,
            ..SmoothSettings::default()
        })),
        SmoothSection::None(_) => Box::new(Unsmoothed { dt }),
    }
}
