//! Estimation from correspondences (pure): a robust MSAC framework and minimal and linear
//! solvers (homography DLT, P3P, EPnP, the five-point essential matrix).

pub mod epnp;
pub mod essential;
pub mod homography;
pub mod p3p;
pub mod pnp;
pub mod ransac;

use thiserror::Error;

#[derive(Debug, Error, Clone, PartialEq)]
pub enum EstimateError {
    #[error("need at least {needed} correspondences, got {got}")]
    TooFewPoints { needed: usize, got: usize },
    #[error("degenerate configuration: {0}")]
    Degenerate(String),
}
