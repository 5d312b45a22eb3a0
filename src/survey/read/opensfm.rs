//! OpenSfM `ground_control_points.json`: WGS 84 latitude, longitude and altitude (OpenSfM treats
//! the altitude as height above the WGS 84 ellipsoid), and observations in OpenSfM's normalised
//! image coordinates, converted to pixels:
//! `u = x·max(w, h) + w/2 − 0.5`, `v = y·max(w, h) + h/2 − 0.5`.

use std::collections::{HashMap, HashSet};

use nalgebra::{Vector2, Vector3};
use serde::Deserialize;

use super::ReadOptions;
use crate::survey::crs::HeightKind;
use crate::survey::model::{Ctx, Gcp, Observation, Survey, SurveyError, SurveyFormat};

#[derive(Deserialize)]
struct File {
    points: Vec<Point>,
}

#[derive(Deserialize)]
struct Point {
    id: String,
    position: Option<Position>,
    #[serde(default)]
    observations: Vec<Obs>,
}

#[derive(Deserialize)]
struct Position {
    latitude: f64,
    longitude: f64,
    altitude: Option<f64>,
}

#[derive(Deserialize)]
struct Obs {
    shot_id: String,
    projection: [f64; 2],
}

/// OpenSfM normalised image coordinates to pixels (pixel centres at integers).
pub fn pixel_from_normalized(p: [f64; 2], width: u32, height: u32) -> Vector2<f64> {
    let (w, h) = (f64::from(width), f64::from(height));
    let s = w.max(h);
    Vector2::new(p[0] * s + w / 2.0 - 0.5, p[1] * s + h / 2.0 - 0.5)
}

/// Pixels to OpenSfM normalised image coordinates.
pub fn normalized_from_pixel(uv: &Vector2<f64>, width: u32, height: u32) -> [f64; 2] {
    let (w, h) = (f64::from(width), f64::from(height));
    let s = w.max(h);
    [(uv.x + 0.5 - w / 2.0) / s, (uv.y + 0.5 - h / 2.0) / s]
}

pub(super) fn read(ctx: &Ctx, text: &str, opts: &ReadOptions) -> Result<Survey, SurveyError> {
    let file: File = serde_json::from_str(text).map_err(|e| {
        ctx.err(
            Some(e.line()),
            None,
            format!(
                "not an OpenSfM ground_control_points.json: {}",
                crate::io::clip(&e.to_string(), 200)
            ),
        )
    })?;
    if file.points.is_empty() {
        return Err(ctx.err(None, Some("points"), "no points"));
    }
    if file.points.len() > super::MAX_SURVEY_ROWS {
        return Err(ctx.err(
            None,
            Some("points"),
            format!(
                "{} points: a survey has at most {} (is it the right file?)",
                file.points.len(),
                super::MAX_SURVEY_ROWS
            ),
        ));
    }
    // Line numbers of the points, for messages: the first line where each id appears, found in
    // one pass over the lines that hold an "id" key.
    let mut lines_of: HashMap<&str, usize> = HashMap::new();
    for (i, l) in text.lines().enumerate() {
        let mut rest = l;
        while let Some(k) = rest.find("\"id\"") {
            rest = &rest[k + 4..];
            let Some(q) = rest.find('"') else { break };
            rest = &rest[q + 1..];
            let Some(end) = rest.find('"') else { break };
            lines_of.entry(&rest[..end]).or_insert(i + 1);
            rest = &rest[end + 1..];
        }
    }
    let line_of = |id: &str| lines_of.get(id).copied().unwrap_or(1);
    let mut points: Vec<Gcp> = Vec::new();
    let mut ids: HashSet<String> = HashSet::new();
    let mut dropped = Vec::new();
    let mut missing_alt = 0;
    for p in file.points {
        let line = line_of(&p.id);
        if !ids.insert(p.id.clone()) {
            return Err(ctx.at(
                line,
                format!("duplicate point id '{}'", crate::io::clip(&p.id, 40)),
            ));
        }
        let Some(pos) = p.position else {
            dropped.push(crate::survey::model::Dropped {
                line,
                reason: format!("point {} has no position", p.id),
            });
            continue;
        };
        let z = pos.altitude.unwrap_or_else(|| {
            missing_alt += 1;
            f64::NAN
        });
        let mut g = Gcp::new(
            p.id.clone(),
            Vector3::new(pos.longitude, pos.latitude, z),
            line,
        );
        if !p.observations.is_empty() {
            let (w, h) = opts.image_size.ok_or_else(|| {
                ctx.at(line, "OpenSfM observations are in normalised image coordinates; pass --image-size WxH to convert them to pixels")
            })?;
            for o in p.observations {
                g.observations.push(Observation {
                    image: o.shot_id,
                    uv: pixel_from_normalized(o.projection, w, h),
                    sigma_px: None,
                    file: ctx.path.to_path_buf(),
                    line,
                });
            }
        }
        points.push(g);
    }
    let mut warnings = Vec::new();
    if missing_alt > 0 {
        warnings.push(format!(
            "{missing_alt} point(s) have no altitude: they are used horizontally only"
        ));
    }
    Ok(Survey {
        source: ctx.path.to_path_buf(),
        format: SurveyFormat::OpenSfm,
        crs: Some("EPSG:4326".into()),
        height: HeightKind::Ellipsoidal,
        points,
        dropped,
        warnings,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn normalised_coordinates_round_trip() {
        let uv = Vector2::new(123.25, 987.5);
        let n = normalized_from_pixel(&uv, 4000, 3000);
        assert!((pixel_from_normalized(n, 4000, 3000) - uv).norm() < 1e-9);
        // The image centre is 0.
        assert_eq!(
            normalized_from_pixel(&Vector2::new(1999.5, 1499.5), 4000, 3000),
            [0.0, 0.0]
        );
    }
}
