//! Survey data: ground control points from surveyors' files, CRSs, the local frame, fits.

pub mod crs;
