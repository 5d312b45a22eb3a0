//! Pixel picks of GCPs: CSV rows `name,image,u,v[,sigma]` (a header line is optional), merged
//! into a survey by point name. Pixels have (0, 0) at the centre of the top-left pixel.

use std::path::Path;

use nalgebra::Vector2;

use super::table::{read_table, sniff_delimiter};
use crate::survey::model::{Ctx, Dropped, Observation, Survey, SurveyError};

/// Adds the picks in `path` to the survey's points. Picks of names the survey lacks are
/// recorded as dropped rows, not lost silently.
pub fn read_picks(path: &Path, survey: &mut Survey) -> Result<usize, SurveyError> {
    let ctx = Ctx { path };
    let text = ctx.read_text("a CSV of picks")?;
    let table = read_table(&ctx, &text, sniff_delimiter(&text))?;
    let mut added = 0;
    for (i, r) in table.rows.iter().enumerate() {
        if r.fields.len() < 4 {
            return Err(ctx.at(
                r.line,
                format!(
                    "expected 'name,image,u,v[,sigma]', found {} field(s)",
                    r.fields.len()
                ),
            ));
        }
        if i == 0 && r.fields[2].trim().parse::<f64>().is_err() {
            continue; // header
        }
        let u = ctx.number(&r.fields[2], r.line, "u")?;
        let v = ctx.number(&r.fields[3], r.line, "v")?;
        let sigma_px = match r.fields.get(4).map(|s| s.trim()).filter(|s| !s.is_empty()) {
            Some(s) => Some(ctx.number(s, r.line, "sigma")?),
            None => None,
        };
        let name = r.fields[0].trim();
        match survey.points.iter_mut().find(|p| p.name == name) {
            Some(p) => {
                p.observations.push(Observation {
                    image: r.fields[1].trim().to_string(),
                    uv: Vector2::new(u, v),
                    sigma_px,
                    line: r.line,
                });
                added += 1;
            }
            None => survey.dropped.push(Dropped {
                line: r.line,
                reason: format!(
                    "pick of '{name}' in {}: no such point in {}",
                    path.display(),
                    survey.source.display()
                ),
            }),
        }
    }
    Ok(added)
}
