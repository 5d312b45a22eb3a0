//! The whole job, from video to trajectories (orchestration over the stages; adapters for I/O).

pub mod chunk_pass;
pub mod cluster;
pub mod detectors;
pub mod error;
pub mod grounds;
pub mod klt_pass;
pub mod pose_outputs;
pub mod project;
pub mod provenance;
pub mod registry;
pub mod report;
pub mod run;
pub mod scan;
pub mod settings;
pub mod views;
