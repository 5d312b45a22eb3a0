//! OpenDroneMap `gcp_list.txt`: a CRS line, then `x y z u v image [name] [extras]` rows,
//! separated by spaces or tabs, `#` comments. Pixels are (column, row) with (0, 0) at the centre
//! of the top-left pixel, as in geostride. For `EPSG:4326`, x is the longitude.

use nalgebra::{Vector2, Vector3};

use super::ReadOptions;
use crate::survey::crs::{Crs, HeightKind};
use crate::survey::model::{Ctx, Gcp, Observation, Survey, SurveyError, SurveyFormat};

fn strip_comment(line: &str) -> &str {
    match line.find('#') {
        Some(i) => &line[..i],
        None => line,
    }
}

pub(super) fn read(ctx: &Ctx, text: &str, opts: &ReadOptions) -> Result<Survey, SurveyError> {
    let mut lines = text
        .lines()
        .enumerate()
        .map(|(i, l)| (i + 1, strip_comment(l).trim()));
    let (crs_line, crs_text) = lines.by_ref().find(|(_, l)| !l.is_empty()).ok_or_else(|| {
        ctx.err(
            Some(1),
            None,
            "empty file: expected a CRS line such as 'EPSG:32631' or 'WGS84 UTM 17N'",
        )
    })?;
    let spec = opts.crs.clone().unwrap_or_else(|| crs_text.to_string());
    let crs = Crs::new(&spec)
        .map_err(|e| ctx.at(crs_line, format!("first line must be the CRS: {e}")))?;
    // Unnamed points are named by their coordinates, to the millimetre (1e-8° for degrees).
    let decimals = if crs.horizontal == crate::survey::crs::Horizontal::Geographic {
        8
    } else {
        3
    };
    let mut unnamed_keys: Vec<(String, String)> = Vec::new();

    let mut points: Vec<Gcp> = Vec::new();
    for (line, l) in lines {
        if l.is_empty() {
            continue;
        }
        let f: Vec<&str> = l.split_whitespace().collect();
        if f.len() < 6 {
            return Err(ctx.at(
                line,
                format!(
                    "expected 'x y z u v image [name]', found {} field(s): '{l}'",
                    f.len()
                ),
            ));
        }
        let x = ctx.number(f[0], line, "x")?;
        let y = ctx.number(f[1], line, "y")?;
        // NaN is how OpenDroneMap writes an unknown height.
        let z = ctx.number_or_nan(f[2], line, "z")?;
        let u = ctx.number(f[3], line, "u")?;
        let v = ctx.number(f[4], line, "v")?;
        let name = match f.get(6) {
            Some(n) => n.to_string(),
            None => {
                let key = format!("{} {} {}", f[0], f[1], f[2]);
                match unnamed_keys.iter().find(|(k, _)| *k == key) {
                    Some((_, n)) => n.clone(),
                    None => {
                        let base = format!("{x:.decimals$},{y:.decimals$},{z:.3}");
                        let taken = |n: &str| unnamed_keys.iter().any(|(_, m)| m == n);
                        let mut n = base.clone();
                        let mut k = 2;
                        while taken(&n) {
                            n = format!("{base}#{k}");
                            k += 1;
                        }
                        unnamed_keys.push((key, n.clone()));
                        n
                    }
                }
            }
        };
        let position = Vector3::new(x, y, z);
        let obs = Observation {
            image: f[5].to_string(),
            uv: Vector2::new(u, v),
            sigma_px: None,
            line,
        };
        let same = |a: f64, b: f64| a == b || (a.is_nan() && b.is_nan());
        match points.iter_mut().find(|p| p.name == name) {
            Some(p) => {
                if !(same(p.position.x, x) && same(p.position.y, y) && same(p.position.z, z)) {
                    return Err(ctx.at(
                        line,
                        format!(
                            "point '{name}' has other coordinates than on line {} ({:?} vs {:?})",
                            p.line,
                            (p.position.x, p.position.y, p.position.z),
                            (x, y, z)
                        ),
                    ));
                }
                p.observations.push(obs);
            }
            None => {
                let mut g = Gcp::new(name, position, line);
                g.observations.push(obs);
                points.push(g);
            }
        }
    }
    if points.is_empty() {
        return Err(ctx.err(None, None, "no GCP rows after the CRS line"));
    }
    let mut warnings = Vec::new();
    let nan = points.iter().filter(|p| p.position.z.is_nan()).count();
    if nan > 0 {
        warnings.push(format!(
            "{nan} point(s) have no height (NaN z): they are used horizontally only"
        ));
    }
    Ok(Survey {
        source: ctx.path.to_path_buf(),
        format: SurveyFormat::Odm,
        crs: Some(spec),
        height: HeightKind::Unknown,
        points,
        dropped: Vec::new(),
        warnings,
    })
}
