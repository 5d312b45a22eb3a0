//! The KLT tracker set up from a project's `[track]` settings (`klt_tracker`), which the
//! decoding pass (`chunk_pass`) feeds with each frame and its detections; the tracking itself
//! is the pure tracker in `track::klt`.

use super::settings::KltSection;
use crate::track::klt::{KltTrackSettings, KltTracker};
use crate::video::klt::{Klt, KltSettings};

/// The KLT tracker a pass feeds, and the feature frames it wants (made from gray frames).
pub struct KltParts {
    pub tracker: KltTracker<Klt>,
    pub frames: Klt,
}

/// The tracker for frames of `size` at `px_per_m` and `fps`, with the project's settings.
pub fn klt_tracker(
    t: &KltSection,
    size: (u32, u32),
    fps: f64,
    person_m: Option<f64>,
    px_per_m: f64,
) -> KltParts {
    // The working copy: no wider than the features' default, and reduced further to about
    // `working_px_per_m` at head height (a person stays over a dozen pixels wide; a 4K frame of
    // people 100 px/m apart costs a ninth of its pixels).
    let default_width = f64::from(KltSettings::default().max_width);
    let factor = (f64::from(size.0) / default_width)
        .ceil()
        .max((px_per_m / t.working_px_per_m).floor())
        .max(1.0);
    let base = KltSettings {
        max_width: (f64::from(size.0) / factor).ceil() as i32,
        ..KltSettings::default()
    };
    // An odd window in the working copy's pixels, no wider than a person (0.6 m): a window
    // mostly of ground follows the ground.
    let window_px = t.window_px.min(0.6 * px_per_m);
    let window = (((window_px / factor).round() as i32).max(5)) | 1;
    let klt = Klt::new(KltSettings {
        window,
        levels: t.levels,
        fast_levels: t.levels,
        quality: 0.01,
        min_distance: 2.0,
        ..base
    });
    let settings = KltTrackSettings {
        gate_px: t.gate_m * px_per_m,
        person_px: person_m.unwrap_or(0.7) * px_per_m,
        // One body's features move within about 4 cm per frame of each other.
        flow_px: (0.04 * px_per_m).max(1.5),
        min_features: t.min_features,
        max_features: t.max_features,
        max_gap: (t.max_gap_s * fps).round() as usize,
        min_hits: t.min_hits,
        ..KltTrackSettings::default()
    };
    let frames = Klt::new(klt.settings.clone());
    KltParts {
        tracker: KltTracker::new(settings, klt, (f64::from(size.0), f64::from(size.1))),
        frames,
    }
}
