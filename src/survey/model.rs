//! Ground control points as surveyors' files describe them (pure).

use std::path::PathBuf;

use nalgebra::{Vector2, Vector3};
use serde::Serialize;

use super::crs::HeightKind;

/// What a point is used for.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum Role {
    /// Constrains fits and poses.
    Control,
    /// Held out: only its residuals are reported, as an independent accuracy check.
    Check,
    /// Ignored (kept in outputs, marked).
    Disabled,
}

impl std::fmt::Display for Role {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(match self {
            Role::Control => "control",
            Role::Check => "check",
            Role::Disabled => "disabled",
        })
    }
}

/// GNSS solution status, as RTK receivers report it.
#[derive(Clone, Debug, PartialEq, Eq, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum SolutionStatus {
    Fix,
    Float,
    Single,
    Other(String),
}

impl SolutionStatus {
    pub fn parse(s: &str) -> Option<SolutionStatus> {
        let t = s.trim();
        if t.is_empty() {
            return None;
        }
        Some(match t.to_ascii_uppercase().as_str() {
            "FIX" | "FIXED" => SolutionStatus::Fix,
            "FLOAT" => SolutionStatus::Float,
            "SINGLE" | "AUTONOMOUS" => SolutionStatus::Single,
            _ => SolutionStatus::Other(t.to_string()),
        })
    }
}

impl std::fmt::Display for SolutionStatus {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            SolutionStatus::Fix => f.write_str("FIX"),
            SolutionStatus::Float => f.write_str("FLOAT"),
            SolutionStatus::Single => f.write_str("SINGLE"),
            SolutionStatus::Other(s) => f.write_str(s),
        }
    }
}

/// A GCP seen in an image or a video frame.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct Observation {
    /// Image file name, or `VIDEO#FRAME` for a video frame.
    pub image: String,
    /// Pixel, (0, 0) at the centre of the top-left pixel.
    pub uv: Vector2<f64>,
    pub sigma_px: Option<f64>,
    /// The file it came from (the survey's or a picks file) and its line there.
    pub file: std::path::PathBuf,
    pub line: usize,
}

/// A ground control point.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct Gcp {
    pub name: String,
    /// In the survey's CRS: (easting or longitude, northing or latitude, height in metres). A
    /// file without a CRS gives metres in its own local frame. The height may be NaN (unknown).
    pub position: Vector3<f64>,
    /// Standard deviations along east, north and up, metres.
    pub sigma_m: Option<Vector3<f64>>,
    pub status: Option<SolutionStatus>,
    pub role: Role,
    pub code: Option<String>,
    pub observations: Vec<Observation>,
    /// Line of the file that defines it.
    pub line: usize,
}

impl Gcp {
    pub fn new(name: impl Into<String>, position: Vector3<f64>, line: usize) -> Self {
        Gcp {
            name: name.into(),
            position,
            sigma_m: None,
            status: None,
            role: Role::Control,
            code: None,
            observations: Vec::new(),
            line,
        }
    }
}

/// A row that was read but not used, and why. Nothing is dropped silently.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct Dropped {
    pub line: usize,
    pub reason: String,
}

/// The file formats geostride reads (and most of which it writes).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum SurveyFormat {
    /// Emlid Flow / ReachView CSV (27- and 42-column generations).
    Emlid,
    /// OpenDroneMap `gcp_list.txt`.
    Odm,
    /// OpenSfM `ground_control_points.json`.
    OpenSfm,
    /// Agisoft Metashape reference CSV.
    Metashape,
    /// PeTrack `.3dc` (centimetres, local frame).
    Petrack,
    /// CSV with an explicit column map.
    Csv,
}

impl SurveyFormat {
    pub fn name(self) -> &'static str {
        match self {
            SurveyFormat::Emlid => "emlid",
            SurveyFormat::Odm => "odm",
            SurveyFormat::OpenSfm => "opensfm",
            SurveyFormat::Metashape => "metashape",
            SurveyFormat::Petrack => "petrack",
            SurveyFormat::Csv => "csv",
        }
    }
}

/// The points of one file, in its CRS.
#[derive(Clone, Debug, Serialize)]
pub struct Survey {
    pub source: PathBuf,
    pub format: SurveyFormat,
    /// CRS specification; `None` for a file in its own local metric frame (PeTrack).
    pub crs: Option<String>,
    pub height: HeightKind,
    pub points: Vec<Gcp>,
    pub dropped: Vec<Dropped>,
    pub warnings: Vec<String>,
}

impl Survey {
    pub fn observation_count(&self) -> usize {
        self.points.iter().map(|p| p.observations.len()).sum()
    }

    pub fn point(&self, name: &str) -> Option<&Gcp> {
        self.points.iter().find(|p| p.name == name)
    }

    pub fn count(&self, role: Role) -> usize {
        self.points.iter().filter(|p| p.role == role).count()
    }
}

/// A survey file that cannot be read.
pub type SurveyError = crate::io::FileError;
pub use crate::io::FileCtx as Ctx;
