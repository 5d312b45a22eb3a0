//! Survey data: ground control points from surveyors' files, CRSs, the local frame, fits.

pub mod crs;
pub mod fit;
pub mod frame;
pub mod load;
pub mod model;
pub mod read;

pub use model::{
    Dropped, Gcp, Observation, Role, SolutionStatus, Survey, SurveyError, SurveyFormat,
};
pub mod gis;
pub mod write;
