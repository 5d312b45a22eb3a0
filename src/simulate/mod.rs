//! Synthetic scenes with exact ground truth (pure).

pub mod board;
pub mod plan;
