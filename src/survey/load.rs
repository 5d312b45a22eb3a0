//! A survey file read into its site frame, ready for use (pose, pipeline): points, picks, roles
//! and every point's site-frame position.

use std::path::{Path, PathBuf};

use nalgebra::Vector3;

use super::frame::{Origin, SiteFrame};
use super::read::{ReadOptions, assign_roles, read, read_picks};
use super::{Survey, SurveyError};

/// How to read a survey besides its file's own content.
#[derive(Clone, Debug, Default)]
pub struct LoadOptions {
    pub read: ReadOptions,
    /// Pick files to merge.
    pub picks: Vec<PathBuf>,
    /// Points whose names start with this are check points.
    pub check_prefix: Option<String>,
    pub check: Vec<String>,
    pub disable: Vec<String>,
    pub origin: Option<Origin>,
}

/// A survey in its site frame.
pub struct Framed {
    pub survey: Survey,
    pub frame: SiteFrame,
    /// Every point's site-frame position, in the survey's order.
    pub local: Vec<Vector3<f64>>,
}

/// Reads a survey file and its picks, assigns roles and sets up the site frame.
pub fn load_framed(file: &Path, o: &LoadOptions) -> Result<Framed, SurveyError> {
    let mut survey = read(file, &o.read)?;
    for p in &o.picks {
        read_picks(p, &mut survey)?;
    }
    assign_roles(&mut survey, o.check_prefix.as_deref(), &o.check, &o.disable)?;
    let frame = SiteFrame::new(&survey, o.origin.as_ref().unwrap_or(&Origin::Centroid))?;
    let local = survey
        .points
        .iter()
        .map(|p| frame.local_from_source(&p.position))
        .collect::<Result<Vec<_>, _>>()
        .map_err(|e| SurveyError {
            path: file.to_path_buf(),
            line: None,
            field: None,
            message: e.to_string(),
        })?;
    Ok(Framed {
        survey,
        frame,
        local,
    })
}
