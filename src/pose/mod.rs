//! Camera pose from ground control points (pure): one image by P3P + MSAC and refinement, and
//! every frame of a hovering camera from key frames, carried picks and a joint refinement.

pub mod attitude;
pub mod hover;
pub mod joint;
#[cfg(feature = "opencv")]
pub mod oracle;
pub mod refine;
pub mod solve;
pub mod stabilise;

use thiserror::Error;

pub use attitude::Attitude;
pub use solve::{GcpObservation, GcpResidual, PoseSettings, PoseSolution, solve_pose};

/// A frame `i` without a pose between the frames that have one (`known`, ascending, not empty):
/// the nearest known frames before and after it and how far `i` lies from the first to the
/// second (0 to 1); at either end the nearest known frame twice and 0. The one rule the hovering
/// and the moving camera fill their gaps by.
pub fn gap_neighbours(known: &[usize], i: usize) -> (usize, usize, f64) {
    let after = known.iter().copied().find(|&k| k > i);
    let before = known.iter().copied().rev().find(|&k| k < i);
    match (before, after) {
        (Some(a), Some(b)) => (a, b, (i - a) as f64 / (b - a) as f64),
        (Some(a), None) => (a, a, 0.0),
        (None, Some(b)) => (b, b, 0.0),
        (None, None) => {
            let k = *known.first().expect("a known frame");
            (k, k, 0.0)
        }
    }
}

#[derive(Debug, Error, Clone, PartialEq)]
pub enum PoseError {
    #[error("a pose needs at least 4 GCPs with picks, got {got}")]
    TooFewPoints { got: usize },
    #[error("degenerate input: {0}")]
    Degenerate(String),
    #[error(
        "{} GCP(s) lie behind the camera for every pose that fits the picks (indices {points:?}): \
         check the heights (units, ellipsoidal vs orthometric) and that the picks belong to these points",
        points.len()
    )]
    BehindCamera { points: Vec<usize> },
    #[error(
        "no pose fits more than {agreeing} of the {total} GCPs within {threshold_px:.1} px (at least half \
         must agree): check the point names in the picks, the CRS and heights of the GCP file (points \
         behind the camera cannot be fitted), and the camera calibration"
    )]
    NoConsensus {
        agreeing: usize,
        total: usize,
        threshold_px: f64,
    },
    #[error("pick of '{name}': {message}")]
    BadPick { name: String, message: String },
}

#[cfg(test)]
mod tests {
    use super::gap_neighbours;

    #[test]
    fn a_gap_lies_between_its_nearest_known_frames_and_is_held_at_the_ends() {
        let known = [2, 5, 9];
        assert_eq!(gap_neighbours(&known, 3), (2, 5, 1.0 / 3.0));
        assert_eq!(gap_neighbours(&known, 8), (5, 9, 0.75));
        assert_eq!(gap_neighbours(&known, 0), (2, 2, 0.0));
        assert_eq!(gap_neighbours(&known, 12), (9, 9, 0.0));
    }
}
