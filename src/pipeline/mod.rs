//! The whole job, from video to trajectories (orchestration over the stages; adapters for I/O).

pub mod pose_outputs;
pub mod project;
pub mod scan;
