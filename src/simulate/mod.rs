//! Synthetic scenes with exact ground truth (pure), and survey planning.

pub mod backdrop;
pub mod board;
pub mod dataset;
pub mod flight;
pub mod gcp_view;
pub mod noise;
pub mod people;
pub mod plan;
#[cfg(all(feature = "opencv", feature = "gdal", feature = "onnx"))]
pub mod project;
pub mod render;
#[cfg(all(feature = "opencv", feature = "gdal", feature = "onnx"))]
pub mod run;
pub mod scene;
pub mod truth;
pub mod world;
