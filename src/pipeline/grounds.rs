//! Each ground kind built from its `[ground]` settings and the survey in its site frame: a
//! plane, a bridge deck, a DEM, local planes of a reference model. `registry::ground` picks
//! one; the run asks it for the head-height surface's ground.

use std::path::Path;

use nalgebra::{Vector2, Vector3};

use super::error::RunError;
use super::project::Loaded;
use crate::geom::similarity::{ScaleMode, Similarity, fit as fit_similarity};
use crate::survey::Role;
use crate::survey::frame::Origin;
use crate::survey::load::Framed;
use crate::terrain::{DeckProfile, HeightSurface, LocalPlanes, Plane};

/// What every ground builder reads beside its settings.
pub struct GroundInputs<'a> {
    pub l: &'a Loaded,
    /// The survey in the site frame.
    pub framed: &'a Framed,
    /// The `model` pose's reference model (the project's, or the one the run built from the
    /// video): local planes without a `model` of their own use it.
    pub pose_model: Option<&'a Path>,
}

impl GroundInputs<'_> {
    /// The control GCPs in the site frame (what a plane or a deck profile is fitted to).
    fn control(&self) -> Vec<Vector3<f64>> {
        self.framed
            .survey
            .points
            .iter()
            .zip(&self.framed.local)
            .filter(|(p, _)| p.role == Role::Control)
            .map(|(_, x)| *x)
            .collect()
    }

    /// An error about `[ground] key`, with its line.
    fn error(&self, key: &str, message: String) -> RunError {
        RunError::Input(self.l.error("ground", key, message))
    }
}

/// A horizontal plane at `height_m` (site frame), or fitted to the control GCPs.
pub fn plane(height_m: Option<f64>, x: &GroundInputs) -> Result<Box<dyn HeightSurface>, RunError> {
    if let Some(h) = height_m {
        return Ok(Box::new(Plane::from_gradient(0.0, 0.0, h)));
    }
    let (plane, _) = Plane::fit(&x.control()).map_err(|e| {
        x.error(
            "height_m",
            format!("fitting a plane to the control GCPs: {e}"),
        )
    })?;
    Ok(Box::new(plane))
}

/// A deck along `centre_line` (the GCP file's CRS), `width_m` wide: its profile through
/// `stations` when given, else a polynomial of `degree` fitted to the control GCPs on it.
pub fn deck(
    centre_line: &[[f64; 2]],
    width_m: f64,
    stations: &[[f64; 2]],
    degree: usize,
    x: &GroundInputs,
) -> Result<Box<dyn HeightSurface>, RunError> {
    let line = centre_line
        .iter()
        .map(|p| {
            x.framed
                .frame
                .local_from_source(&Vector3::new(p[0], p[1], f64::NAN))
                .map(|x| x.xy())
        })
        .collect::<Result<Vec<Vector2<f64>>, _>>()
        .map_err(|e| x.error("centre_line", e.to_string()))?;
    if !stations.is_empty() {
        return Ok(Box::new(DeckProfile {
            centre_line: line,
            start_s: 0.0,
            width_m,
            alignment: crate::terrain::deck::VerticalAlignment::Stations(
                stations.iter().map(|s| (s[0], s[1])).collect(),
            ),
        }));
    }
    let control = x.control();
    let (deck, _) = DeckProfile::fit_polynomial(line, 0.0, width_m, degree, &control).map_err(
        |e| {
            if matches!(e, crate::terrain::deck::DeckError::TooFewPoints { got: 0, .. }) {
                x.error(
                    "centre_line",
                    format!("none of the {} control GCPs lies on the deck ({width_m} m wide along the centre line): check the centre line and the survey's CRS (survey.crs, or the GCP file's own)", control.len()),
                )
            } else {
                x.error(
                    "degree",
                    format!("fitting the deck profile to the control GCPs: {e}"),
                )
            }
        },
    )?;
    Ok(Box::new(deck))
}

/// Local planes fitted to the points of the reference model in `model` (moved into the site
/// frame), in a `window_m` square around each person.
pub fn local_planes(
    model: &str,
    window_m: f64,
    x: &GroundInputs,
) -> Result<Box<dyn HeightSurface>, RunError> {
    let dir = match (model.is_empty(), x.pose_model) {
        (false, _) => x.l.resolve(model),
        (true, Some(d)) => d.to_path_buf(),
        (true, None) => {
            return Err(x.error(
                "model",
                "local planes need a model's folder (geostride sfm PHOTOS --gcps GCPS --out model)"
                    .to_string(),
            ));
        }
    };
    let points = model_points_in_site(x.l, &dir, x.framed)?;
    Ok(Box::new(LocalPlanes::new(points, window_m)))
}

/// A DEM raster in any CRS, read through GDAL and PROJ.
pub fn dem(path: &str, x: &GroundInputs) -> Result<Box<dyn HeightSurface>, RunError> {
    let l = x.l;
    let (grid, wkt) = crate::terrain::raster::load(&l.resolve(path))
        .map_err(|e| x.error("path", e.to_string()))?;
    // The DEM surface keeps its own handle on the site frame (PROJ handles are not shared).
    let origin = match &l.project.survey.origin {
        Some(o) => o.parse::<Origin>().map_err(|e| x.error("path", e))?,
        None => Origin::Centroid,
    };
    let frame = std::rc::Rc::new(
        crate::survey::frame::SiteFrame::new(&x.framed.survey, &origin)
            .map_err(|e| x.error("path", e.to_string()))?,
    );
    let dem = crate::survey::frame::dem_surface(frame, grid, &wkt)
        .map_err(|e| x.error("path", e.to_string()))?;
    Ok(Box::new(dem))
}

/// A model's points in the site frame (for the ground's local planes).
fn model_points_in_site(
    l: &Loaded,
    dir: &Path,
    framed: &Framed,
) -> Result<Vec<Vector3<f64>>, RunError> {
    let model = crate::sfm::register::read_model(dir)
        .map_err(|e| RunError::Input(l.error("ground", "model", e.to_string())))?;
    let (s, _, _) = site_from_model(l, "ground", dir, framed)?;
    Ok(model.points.iter().map(|p| s.apply(p)).collect())
}

/// The transform from a model's frame to the site frame, from its cameras' CRS positions (the
/// model pose's and the local planes' `model`, named in errors as `[section] model`).
pub(crate) fn site_from_model(
    l: &Loaded,
    section: &str,
    dir: &Path,
    framed: &Framed,
) -> Result<(Similarity, f64, Vec<crate::sfm::reference::GeoCamera>), RunError> {
    let cams = crate::sfm::reference::read_geo_cameras(dir).map_err(RunError::Input)?;
    let model: Vec<Vector3<f64>> = cams.iter().map(|c| c.centre).collect();
    let site = cams
        .iter()
        .map(|c| framed.frame.local_from_source(&c.crs))
        .collect::<Result<Vec<_>, _>>()?;
    let fit = fit_similarity(
        &model,
        &site,
        &vec![1.0; model.len()],
        ScaleMode::Fixed,
        false,
    )
    .map_err(|e| RunError::Input(l.error(section, "model", format!("placing the model: {e}"))))?;
    let rms = (fit.residuals.iter().map(|r| r.norm_squared()).sum::<f64>()
        / fit.residuals.len() as f64)
        .sqrt();
    // The model's site frame and the run's differ by their origins only: anything more is a
    // model of another survey, or another CRS.
    if rms > 0.01 {
        return Err(RunError::Input(l.error(
            section,
            "model",
            format!(
                "the model's cameras are {rms:.3} m RMS from their CRS positions moved into this run's frame: build the model with this project's GCP file and CRS"
            ),
        )));
    }
    Ok((fit.transform, rms, cams))
}
