//! PeTrack `.3dc`: a count line, then `X Y Z [px py]` rows in centimetres, in PeTrack's own local
//! frame. Points are named `P1`, `P2`, ... in file order; pixel picks refer to one image.

use nalgebra::{Vector2, Vector3};

use super::ReadOptions;
use crate::survey::crs::HeightKind;
use crate::survey::model::{Ctx, Gcp, Observation, Survey, SurveyError, SurveyFormat};

pub(super) fn read(ctx: &Ctx, text: &str, opts: &ReadOptions) -> Result<Survey, SurveyError> {
    let mut lines = text
        .lines()
        .enumerate()
        .map(|(i, l)| (i + 1, l.trim()))
        .filter(|(_, l)| !l.is_empty() && !l.starts_with('#'));
    let (count_line, count_text) = lines
        .next()
        .ok_or_else(|| ctx.err(Some(1), None, "empty file: expected the number of points"))?;
    let count: usize = count_text.parse().map_err(|_| {
        ctx.at(
            count_line,
            format!(
                "expected the number of points, found '{}'",
                crate::io::clip(count_text, 40)
            ),
        )
    })?;
    if count == 0 {
        return Err(ctx.at(count_line, "the count line says 0 points: no points"));
    }
    let image = opts.image.clone().unwrap_or_else(|| "petrack-image".into());
    let mut points = Vec::new();
    for (line, l) in lines {
        let f: Vec<&str> = l.split_whitespace().collect();
        if f.len() != 3 && f.len() != 5 {
            return Err(ctx.at(
                line,
                format!(
                    "expected 'X Y Z' or 'X Y Z px py' in centimetres, found {} field(s)",
                    f.len()
                ),
            ));
        }
        let cm = |i: usize, name: &str| ctx.number(f[i], line, name).map(|v| v / 100.0);
        let mut g = Gcp::new(
            format!("P{}", points.len() + 1),
            Vector3::new(cm(0, "X")?, cm(1, "Y")?, cm(2, "Z")?),
            line,
        );
        if f.len() == 5 {
            g.observations.push(Observation {
                image: image.clone(),
                uv: Vector2::new(ctx.number(f[3], line, "px")?, ctx.number(f[4], line, "py")?),
                sigma_px: None,
                file: ctx.path.to_path_buf(),
                line,
            });
        }
        points.push(g);
    }
    if points.len() != count {
        return Err(ctx.at(
            count_line,
            format!(
                "the count line says {count} point(s) but the file has {}",
                points.len()
            ),
        ));
    }
    Ok(Survey {
        source: ctx.path.to_path_buf(),
        format: SurveyFormat::Petrack,
        crs: None,
        height: HeightKind::Unknown,
        points,
        dropped: Vec::new(),
        warnings: Vec::new(),
    })
}
