//! OpenDroneMap `gcp_list.txt`: a CRS line, then `x y z u v image [name] [extras]` rows,
//! separated by spaces or tabs, `#` comments. Pixels are (column, row) with (0, 0) at the centre
//! of the top-left pixel, as in geostride. For `EPSG:4326`, x is the longitude.

use std::collections::{HashMap, HashSet};

use nalgebra::{Vector2, Vector3};

use super::ReadOptions;
use crate::survey::crs::{Crs, HeightKind};
use crate::survey::model::{Ctx, Dropped, Gcp, Observation, Survey, SurveyError, SurveyFormat};

fn strip_comment(line: &str) -> &str {
    match line.find('#') {
        Some(i) => &line[..i],
        None => line,
    }
}

/// Names for unnamed points: their coordinates, to the millimetre (1e-8° for degrees), with
/// `#2`, `#3`, ... where two points round to the same name.
#[derive(Default)]
struct Unnamed {
    /// Coordinates as written -> generated name.
    keys: HashMap<String, String>,
    /// The generated names taken.
    names: HashSet<String>,
}

impl Unnamed {
    fn name(&mut self, written: &[&str], [x, y, z]: [f64; 3], decimals: usize) -> String {
        let key = written.join(" ");
        if let Some(n) = self.keys.get(&key) {
            return n.clone();
        }
        let base = format!("{x:.decimals$},{y:.decimals$},{z:.3}");
        let mut n = base.clone();
        let mut k = 2;
        while self.names.contains(&n) {
            n = format!("{base}#{k}");
            k += 1;
        }
        self.names.insert(n.clone());
        self.keys.insert(key, n.clone());
        n
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
    let mut unnamed = Unnamed::default();
    let mut index: HashMap<String, usize> = HashMap::new();
    // (point, image) -> line: a point is picked once per image.
    let mut picked: HashMap<(usize, String), usize> = HashMap::new();

    let mut points: Vec<Gcp> = Vec::new();
    let mut dropped: Vec<Dropped> = Vec::new();
    for (line, l) in lines {
        if l.is_empty() {
            continue;
        }
        if l.len() > crate::io::MAX_LINE_BYTES {
            return Err(ctx.at(line, "a line of a gcp_list.txt longer than 1 MiB"));
        }
        let f: Vec<&str> = l.split_whitespace().collect();
        // OpenDroneMap reads x y z u v image [name] and ignores what follows.
        ctx.field_count(&f, line, 6, usize::MAX, "x y z u v image [name]")?;
        let x = ctx.number(f[0], line, "x")?;
        let y = ctx.number(f[1], line, "y")?;
        // NaN is how OpenDroneMap writes an unknown height.
        let z = ctx.number_or_nan(f[2], line, "z")?;
        let u = ctx.number(f[3], line, "u")?;
        let v = ctx.number(f[4], line, "v")?;
        let name = match f.get(6) {
            Some(n) => n.to_string(),
            None => unnamed.name(&f[..3], [x, y, z], decimals),
        };
        let position = Vector3::new(x, y, z);
        let obs = Observation {
            image: f[5].to_string(),
            uv: Vector2::new(u, v),
            sigma_px: None,
            file: ctx.path.to_path_buf(),
            line,
        };
        let same = |a: f64, b: f64| a == b || (a.is_nan() && b.is_nan());
        let k = match index.get(&name) {
            Some(&k) => {
                let p = &points[k];
                if !(same(p.position.x, x) && same(p.position.y, y) && same(p.position.z, z)) {
                    return Err(ctx.at(
                        line,
                        format!(
                            "point '{}' has other coordinates than on line {} ({:?} vs {:?})",
                            crate::io::clip(&name, 40),
                            p.line,
                            (p.position.x, p.position.y, p.position.z),
                            (x, y, z)
                        ),
                    ));
                }
                k
            }
            None => {
                index.insert(name.clone(), points.len());
                points.push(Gcp::new(name, position, line));
                points.len() - 1
            }
        };
        // OpenDroneMap's own lists hold the odd point picked twice in one image (one of the
        // published lists does): the same pixel is kept once; two places are ambiguous, so that
        // image's picks of the point are dropped, and both lines listed.
        if let Some(&first) = picked.get(&(k, obs.image.clone())) {
            let obs_list = &mut points[k].observations;
            if let Some(i) = obs_list.iter().position(|o| o.image == obs.image) {
                if obs_list[i].uv == obs.uv {
                    dropped.push(Dropped {
                        line,
                        reason: format!(
                            "'{}' picked again at the same pixel in image '{}' (line {first}): kept once",
                            crate::io::clip(&points[k].name, 40),
                            crate::io::clip(&obs.image, 60)
                        ),
                    });
                    continue;
                }
                obs_list.remove(i);
            }
            let reason = format!(
                "'{}' is picked at two places in image '{}' (lines {first} and {line}): both picks dropped; keep the right one",
                crate::io::clip(&points[k].name, 40),
                crate::io::clip(&obs.image, 60)
            );
            if !dropped.iter().any(|d| d.line == first) {
                dropped.push(Dropped {
                    line: first,
                    reason: reason.clone(),
                });
            }
            dropped.push(Dropped { line, reason });
            continue;
        }
        picked.insert((k, obs.image.clone()), line);
        points[k].observations.push(obs);
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
        dropped,
        warnings,
    })
}
