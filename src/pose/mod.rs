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
