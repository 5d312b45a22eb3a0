//! Reading truth back (pure): per-frame camera poses (`truth/camera.csv`, and geostride's own
//! `poses.csv`, which share the `rvec_*`/`tvec_*` columns), the exact GCPs, and how far apart two
//! poses put the GCPs in the image.

use std::collections::HashMap;
use std::path::Path;

use nalgebra::Vector3;

use crate::camera::Camera;
use crate::geom::Rigid3;
use crate::io::{FileCtx, FileError};

/// A data row: its line number and its fields by column name.
type Row = (usize, HashMap<String, String>);

/// A CSV with a header: each row as a map from column name to field, with its line number. Every
/// row has the header's number of fields.
fn rows(path: &Path, text: &str, needed: &[&str]) -> Result<Vec<Row>, FileError> {
    let ctx = FileCtx { path };
    let mut lines = ctx.lines(text);
    let header: Vec<String> = match lines.next().transpose()? {
        Some((_, h)) => h.split(',').map(|s| s.trim().to_string()).collect(),
        None => Vec::new(),
    };
    if let Some(missing) = needed.iter().find(|n| !header.iter().any(|h| h == *n)) {
        return Err(ctx.at(1, format!("no column '{missing}' in the header")));
    }
    let mut out = Vec::new();
    for row in lines {
        let (line, l) = row?;
        if l.trim().is_empty() {
            continue;
        }
        let f: Vec<&str> = l.split(',').map(str::trim).collect();
        ctx.field_count(&f, line, header.len(), header.len(), "the header's columns")?;
        out.push((
            line,
            header
                .iter()
                .cloned()
                .zip(f.iter().map(|s| s.to_string()))
                .collect(),
        ));
    }
    Ok(out)
}

/// `cam_from_world` of every frame, by frame number, from a CSV with `frame`, `rvec_x..z` and
/// `tvec_x..z` columns.
pub fn read_poses(path: &Path) -> Result<Vec<(usize, Rigid3)>, FileError> {
    let text = FileCtx { path }.read_text("a CSV of camera poses")?;
    parse_poses(path, &text)
}

/// [`read_poses`] on text; `path` names the file in messages.
pub fn parse_poses(path: &Path, text: &str) -> Result<Vec<(usize, Rigid3)>, FileError> {
    let cols = [
        "frame", "rvec_x", "rvec_y", "rvec_z", "tvec_x", "tvec_y", "tvec_z",
    ];
    let ctx = FileCtx { path };
    rows(path, text, &cols)?
        .into_iter()
        .map(|(line, r)| {
            let v: Vec<f64> = cols[1..]
                .iter()
                .map(|c| ctx.number(&r[*c], line, c))
                .collect::<Result<_, _>>()?;
            Ok((
                ctx.whole(&r["frame"], line, "frame")? as usize,
                Rigid3::from_rvec_tvec(
                    &Vector3::new(v[0], v[1], v[2]),
                    &Vector3::new(v[3], v[4], v[5]),
                ),
            ))
        })
        .collect()
}

/// The exact GCPs of `truth/gcps.csv`: name and site-frame position.
pub fn read_gcps(path: &Path) -> Result<Vec<(String, Vector3<f64>)>, FileError> {
    let text = FileCtx { path }.read_text("a CSV of GCPs")?;
    parse_gcps(path, &text)
}

/// [`read_gcps`] on text; `path` names the file in messages.
pub fn parse_gcps(path: &Path, text: &str) -> Result<Vec<(String, Vector3<f64>)>, FileError> {
    let ctx = FileCtx { path };
    rows(path, text, &["name", "e_m", "n_m", "u_m"])?
        .into_iter()
        .map(|(line, r)| {
            Ok((
                r["name"].clone(),
                Vector3::new(
                    ctx.number(&r["e_m"], line, "e_m")?,
                    ctx.number(&r["n_m"], line, "n_m")?,
                    ctx.number(&r["u_m"], line, "u_m")?,
                ),
            ))
        })
        .collect()
}

/// Every person's height from `truth/people.csv`: person id → height, metres.
pub fn read_people_heights(path: &Path) -> Result<HashMap<usize, f64>, FileError> {
    let text = FileCtx { path }.read_text("a CSV of people")?;
    parse_people_heights(path, &text)
}

/// [`read_people_heights`] on text; `path` names the file in messages.
pub(crate) fn parse_people_heights(
    path: &Path,
    text: &str,
) -> Result<HashMap<usize, f64>, FileError> {
    let ctx = FileCtx { path };
    rows(path, text, &["person", "height_m"])?
        .into_iter()
        .map(|(line, r)| {
            Ok((
                ctx.whole(&r["person"], line, "person")? as usize,
                ctx.number(&r["height_m"], line, "height_m")?,
            ))
        })
        .collect()
}

/// The mean distance in pixels between where `a` and `b` project `points`; `None` when a point
/// is behind either camera.
pub fn mean_reprojection_px(
    camera: &Camera,
    a: &Rigid3,
    b: &Rigid3,
    points: &[Vector3<f64>],
) -> Option<f64> {
    let mut sum = 0.0;
    for p in points {
        let pa = camera.project(&a.apply(p)).ok()?;
        let pb = camera.project(&b.apply(p)).ok()?;
        sum += (pa - pb).norm();
    }
    Some(sum / points.len().max(1) as f64)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn people_heights_read_with_their_line() {
        let p = Path::new("people.csv");
        let h = parse_people_heights(p, "person,height_m,speed_m_s\n1,1.72,3\n2,1.65,3\n").unwrap();
        assert_eq!(h.get(&2), Some(&1.65));
        let e = parse_people_heights(p, "person,height_m\n1,tall\n").unwrap_err();
        assert_eq!(e.line, Some(2));
    }
}
