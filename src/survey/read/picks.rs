//! Pixel picks of GCPs: CSV rows `name,image,u,v[,sigma]` (a header line is optional), merged
//! into a survey by point name. Pixels have (0, 0) at the centre of the top-left pixel.

use std::collections::HashMap;
use std::path::Path;

use nalgebra::Vector2;

use super::table::{read_table, sniff_delimiter};
use crate::survey::model::{Ctx, Dropped, Observation, Survey, SurveyError};

/// Adds the picks in `path` to the survey's points. Picks of names the survey lacks are
/// recorded as dropped rows, not lost silently.
pub fn read_picks(path: &Path, survey: &mut Survey) -> Result<usize, SurveyError> {
    let text = Ctx { path }.read_text("a CSV of picks")?;
    parse_picks(path, &text, survey)
}

/// The most picks a file may hold (50 GCPs in 20 000 images).
pub const MAX_PICKS: usize = 1_000_000;

/// [`read_picks`] on text; `path` names the file in messages.
pub fn parse_picks(path: &Path, text: &str, survey: &mut Survey) -> Result<usize, SurveyError> {
    let ctx = Ctx { path };
    let lines = text.lines().count();
    if lines > MAX_PICKS + 1 {
        return Err(ctx.err(
            None,
            None,
            format!("{lines} lines: a picks file has at most {MAX_PICKS} picks"),
        ));
    }
    let table = read_table(&ctx, text, sniff_delimiter(text))?;
    let index: HashMap<String, usize> = survey
        .points
        .iter()
        .enumerate()
        .map(|(i, p)| (p.name.clone(), i))
        .collect();
    // (point, image) -> line, to refuse a second pick of a point in one image.
    let mut seen: HashMap<(usize, String), usize> = HashMap::new();
    for p in &survey.points {
        for o in &p.observations {
            if o.file == path {
                seen.insert((index[&p.name], o.image.clone()), o.line);
            }
        }
    }
    let mut added = 0;
    let mut rows = 0;
    for (i, r) in table.rows.iter().enumerate() {
        let fields: Vec<&str> = r.fields.iter().map(String::as_str).collect();
        ctx.field_count(&fields, r.line, 4, 5, "name,image,u,v[,sigma]")?;
        if i == 0 && r.fields[2].trim().parse::<f64>().is_err() {
            continue; // header
        }
        rows += 1;
        let u = ctx.number(&r.fields[2], r.line, "u")?;
        let v = ctx.number(&r.fields[3], r.line, "v")?;
        let sigma_px = match r.fields.get(4).map(|s| s.trim()).filter(|s| !s.is_empty()) {
            Some(s) => Some(ctx.positive(s, r.line, "sigma")?),
            None => None,
        };
        let name = r.fields[0].trim();
        let image = r.fields[1].trim().to_string();
        if image.is_empty() {
            return Err(ctx.err(Some(r.line), Some("image"), "no image name"));
        }
        match index.get(name) {
            Some(&k) => {
                if let Some(first) = seen.insert((k, image.clone()), r.line) {
                    return Err(ctx.at(
                        r.line,
                        format!(
                            "'{}' is picked twice in image '{}' (lines {first} and {}); keep one",
                            crate::io::clip(name, 40),
                            crate::io::clip(&image, 60),
                            r.line
                        ),
                    ));
                }
                survey.points[k].observations.push(Observation {
                    image,
                    uv: Vector2::new(u, v),
                    sigma_px,
                    file: path.to_path_buf(),
                    line: r.line,
                });
                added += 1;
            }
            None => survey.dropped.push(Dropped {
                line: r.line,
                reason: format!(
                    "pick of '{}' in {}: no such point in {}",
                    crate::io::clip(name, 40),
                    path.display(),
                    survey.source.display()
                ),
            }),
        }
    }
    if rows == 0 {
        return Err(ctx.err(
            None,
            None,
            "no picks: expected rows of 'name,image,u,v[,sigma]'",
        ));
    }
    Ok(added)
}
