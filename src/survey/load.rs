//! A survey file read into its site frame, ready for use (pose, pipeline): points, picks, roles
//! and every point's site-frame position.

use std::path::{Path, PathBuf};

use nalgebra::{Matrix3, Vector3};

use super::frame::{Origin, SiteFrame};
use super::read::{ReadOptions, assign_roles, read, read_picks};
use super::{Role, Survey, SurveyError};
use crate::pose::GcpObservation;

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

impl Framed {
    /// No survey: the site frame is a local metric frame given otherwise (`origin_note` says
    /// which), with no points and heights of no stated kind.
    pub fn without_points(origin_note: &str) -> Framed {
        Framed {
            survey: Survey {
                source: std::path::PathBuf::new(),
                format: crate::survey::SurveyFormat::Csv,
                crs: None,
                height: crate::survey::crs::HeightKind::Unknown,
                points: Vec::new(),
                dropped: Vec::new(),
                warnings: Vec::new(),
            },
            frame: SiteFrame {
                crs: None,
                tangent: None,
                height: crate::survey::crs::HeightKind::Unknown,
                origin_note: origin_note.into(),
            },
            local: Vec::new(),
        }
    }
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

/// The GCPs picked in one image, as the pose solver takes them.
#[derive(Clone, Debug, Default)]
pub struct ImageObservations {
    pub control: Vec<GcpObservation>,
    /// Check points: held out of the pose, reported apart.
    pub check: Vec<GcpObservation>,
}

impl Framed {
    /// The images the enabled points are picked in, with the number of points picked in each.
    pub fn picked_images(&self) -> std::collections::BTreeMap<String, usize> {
        let mut images = std::collections::BTreeMap::new();
        for p in self
            .survey
            .points
            .iter()
            .filter(|p| p.role != Role::Disabled)
        {
            for o in &p.observations {
                *images.entry(o.image.clone()).or_insert(0) += 1;
            }
        }
        images
    }

    /// The observations of `image`: every enabled point picked there, once, with a height, and
    /// inside the image when its size `(width, height)` is known. σ of a pick from the picks
    /// file or `pick_sigma_px`; of a point from the survey or `gcp_sigma_m` on each axis.
    pub fn observations(
        &self,
        image: &str,
        pick_sigma_px: f64,
        gcp_sigma_m: f64,
        image_size: Option<(u32, u32)>,
    ) -> Result<ImageObservations, SurveyError> {
        let mut seen = ImageObservations::default();
        for (p, local) in self.survey.points.iter().zip(&self.local) {
            if p.role == Role::Disabled {
                continue;
            }
            let picks: Vec<_> = p.observations.iter().filter(|o| o.image == image).collect();
            let Some(o) = picks.first() else { continue };
            let at = |o: &super::Observation, message: String| SurveyError {
                path: o.file.clone(),
                line: Some(o.line),
                field: None,
                message,
            };
            if let Some(second) = picks.get(1) {
                return Err(at(
                    second,
                    format!(
                        "'{}' is picked {} times in image '{image}' (lines {} and {}); keep one",
                        p.name,
                        picks.len(),
                        o.line,
                        second.line
                    ),
                ));
            }
            if !local.z.is_finite() {
                return Err(SurveyError {
                    path: self.survey.source.clone(),
                    line: Some(p.line),
                    field: None,
                    message: format!("'{}' has no height; a pose needs 3D points", p.name),
                });
            }
            if let Some((w, h)) = image_size {
                let (w, h) = (f64::from(w), f64::from(h));
                if !(o.uv.x >= -0.5 && o.uv.x <= w - 0.5 && o.uv.y >= -0.5 && o.uv.y <= h - 0.5) {
                    return Err(at(
                        o,
                        format!(
                            "the pick of '{}' at ({:.1}, {:.1}) lies outside the {w}x{h} image: check the picks' image and pixel origin",
                            p.name, o.uv.x, o.uv.y
                        ),
                    ));
                }
            }
            let sigma = p.sigma_m.unwrap_or(Vector3::from_element(gcp_sigma_m));
            let world_cov = self
                .frame
                .local_covariance(&p.position, &sigma)
                .unwrap_or_else(|_| Matrix3::from_diagonal(&sigma.component_mul(&sigma)));
            let obs = GcpObservation {
                name: p.name.clone(),
                world: *local,
                world_cov,
                uv: o.uv,
                sigma_px: o.sigma_px.unwrap_or(pick_sigma_px),
            };
            match p.role {
                Role::Check => seen.check.push(obs),
                _ => seen.control.push(obs),
            }
        }
        Ok(seen)
    }
}
