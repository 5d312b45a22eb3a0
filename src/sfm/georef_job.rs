//! `geostride sfm georef` as a library call: a COLMAP model (text or binary), surveyed points
//! with their picks and measured camera centres in; the model placed in the survey's site frame
//! by the same GCP-constrained adjustment `geostride sfm` runs, with its check points and each
//! camera's σ; the model written back in COLMAP's format with every field it had, and the
//! report, `cameras.csv` and `points.ply` beside it.

use std::path::{Path, PathBuf};

use serde::Serialize;

use super::colmap::ply;
use super::colmap_convert::{ConvertError, Converted, apply, to_reconstruction};
use super::colmap_model::{ColmapError, ColmapModel, ModelFormat, read_model_dir};
use super::georef::{GeorefReport, georeference};
use super::job::{
    CrsPositions, GeorefInput, SfmJobError, cameras_csv_of, check_centres_near_gcps, georef_md,
    index_georef,
};

#[derive(Clone, Debug)]
pub struct GeorefModelJob {
    pub model_dir: PathBuf,
    pub georef: GeorefInput,
    /// The format written; `None`: the model's own.
    pub format: Option<ModelFormat>,
}

/// What `geostride sfm georef` did.
#[derive(Clone, Debug, Serialize)]
pub struct GeorefModelReport {
    /// The model folder read, and its format.
    pub model: String,
    pub format: ModelFormat,
    /// The format the georeferenced model is written in.
    pub written_format: ModelFormat,
    pub images: usize,
    pub points: usize,
    pub observations: usize,
    /// COLMAP's name of the camera model, and the camera as geostride holds it:
    /// `[fx, fy, cx, cy, skew, k1, k2, p1, p2, k3, k4, k5, k6]`, pixel centres at integers.
    pub camera_model: String,
    pub camera: Vec<f64>,
    pub width: u32,
    pub height: u32,
    /// Mean distance of every observation from its point's projection, pixels: as read, and
    /// after the adjustment.
    pub mean_reprojection_px_before: f64,
    pub mean_reprojection_px: f64,
    pub georef: GeorefReport,
    /// Always `site`: the survey's frame, `site_frame` says which.
    pub frame: String,
    pub site_frame: String,
    /// Picks and centres naming images that are not in the model.
    pub unmatched_names: Vec<String>,
}

pub struct GeorefModelRun {
    /// The model, georeferenced.
    pub model: ColmapModel,
    pub converted: Converted,
    pub report: GeorefModelReport,
}

#[derive(Debug, thiserror::Error)]
pub enum GeorefModelError {
    #[error(transparent)]
    Model(#[from] ColmapError),
    #[error("{}: {error}", dir.display())]
    Convert { dir: PathBuf, error: ConvertError },
    #[error(transparent)]
    Job(#[from] SfmJobError),
}

impl GeorefModelError {
    /// Whether the inputs are at fault (exit code 2).
    pub fn is_input(&self) -> bool {
        match self {
            GeorefModelError::Job(e) => e.is_input(),
            _ => true,
        }
    }
}

/// Reads the model, places and adjusts it with the survey; nothing is written.
pub fn run_georef_model(job: &GeorefModelJob) -> Result<GeorefModelRun, GeorefModelError> {
    let (mut model, format) = read_model_dir(&job.model_dir)?;
    let mut converted = to_reconstruction(&model).map_err(|e| GeorefModelError::Convert {
        dir: job.model_dir.clone(),
        error: e,
    })?;
    check_centres_near_gcps(&job.georef)?;
    let mut unmatched_names = Vec::new();
    let (points, centres) = index_georef(
        &job.georef,
        &converted.names,
        converted.width,
        converted.height,
        &mut unmatched_names,
    )?;
    let before = converted.reconstruction.mean_reprojection_px;
    let georef = georeference(
        &mut converted.reconstruction,
        &converted.keypoints,
        None,
        &points,
        &centres,
        &converted.names,
        &job.georef.settings,
    )
    .map_err(SfmJobError::from)?;
    apply(&mut model, &converted);
    let r = &converted.reconstruction;
    let camera = model
        .cameras
        .iter()
        .find(|c| model.images.first().is_some_and(|i| i.camera_id == c.id))
        .map_or("", |c| c.model_name());
    let report = GeorefModelReport {
        model: job.model_dir.display().to_string(),
        format,
        written_format: job.format.unwrap_or(format),
        images: model.images.len(),
        points: model.points.len(),
        observations: r.points.iter().map(|p| p.observations.len()).sum(),
        camera_model: camera.to_string(),
        camera: r.camera.params().to_vec(),
        width: converted.width,
        height: converted.height,
        mean_reprojection_px_before: before,
        mean_reprojection_px: r.mean_reprojection_px,
        georef,
        frame: "site".into(),
        site_frame: job.georef.frame.clone(),
        unmatched_names,
    };
    Ok(GeorefModelRun {
        model,
        converted,
        report,
    })
}

/// `report.md` of a georeferenced COLMAP model.
pub fn report_md(r: &GeorefModelReport) -> String {
    let format = |f: ModelFormat| match f {
        ModelFormat::Text => "text",
        ModelFormat::Binary => "binary",
    };
    let mut s = format!(
        "# A COLMAP model georeferenced\n\n\
         - model: {} ({})\n\
         - written as: {}\n\
         - images: {}, points: {}, observations: {}\n\
         - camera: COLMAP {} {}x{}, held (fx {:.2}, fy {:.2}, cx {:.2}, cy {:.2}, pixel centres at integers)\n\
         - mean reprojection: {:.3} px as read, {:.3} px adjusted\n",
        r.model,
        format(r.format),
        format(r.written_format),
        r.images,
        r.points,
        r.observations,
        r.camera_model,
        r.width,
        r.height,
        r.camera[0],
        r.camera[1],
        r.camera[2],
        r.camera[3],
        r.mean_reprojection_px_before,
        r.mean_reprojection_px,
    );
    s.push_str(&georef_md(&r.georef, &r.site_frame));
    if !r.unmatched_names.is_empty() {
        s.push_str(&format!(
            "\nPicks or centres name images that are not in the model (ignored): {}\n",
            r.unmatched_names.join(", ")
        ));
    }
    s
}

/// Writes the georeferenced model (COLMAP's three files), `points.ply`, `cameras.csv`,
/// `report.json` and `report.md` into `out` (which exists). Returns their names.
pub fn write_georef_outputs(
    out: &Path,
    run: &GeorefModelRun,
    crs: Option<&CrsPositions>,
) -> std::io::Result<Vec<String>> {
    let mut written = run.model.write(out, run.report.written_format)?;
    let r = &run.converted.reconstruction;
    let files = [
        ("points.ply", ply(r)),
        (
            "cameras.csv",
            cameras_csv_of(
                &run.converted.names,
                &r.poses,
                "site",
                Some(&run.report.georef.camera_sigma),
                crs,
            ),
        ),
        (
            "report.json",
            serde_json::to_string_pretty(&run.report).map_err(std::io::Error::other)?,
        ),
        ("report.md", report_md(&run.report)),
    ];
    for (name, text) in files {
        crate::io::write_atomic(&out.join(name), text.as_bytes())?;
        written.push(name.to_string());
    }
    Ok(written)
}
