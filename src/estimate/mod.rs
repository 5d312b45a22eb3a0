//! Estimation from correspondences (pure): minimal and linear solvers.

pub mod homography;

use thiserror::Error;

#[derive(Debug, Error, Clone, PartialEq)]
pub enum EstimateError {
    #[error("need at least {needed} correspondences, got {got}")]
    TooFewPoints { needed: usize, got: usize },
    #[error("degenerate configuration: {0}")]
    Degenerate(String),
}
