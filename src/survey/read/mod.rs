//! Survey file readers, with format detection from the content.

pub(crate) mod emlid;
mod metashape;
mod odm;
pub(crate) mod opensfm;
mod petrack;
mod picks;
mod table;

use std::collections::HashMap;
use std::path::Path;

pub use picks::{MAX_PICKS, parse_picks, read_picks};
pub use table::ColumnMap;

use super::crs::{Crs, HeightKind};
use super::model::{Ctx, Role, Survey, SurveyError, SurveyFormat};

/// Which height a file's reader should take, when the file has both (Emlid) or does not say.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum HeightChoice {
    Orthometric,
    Ellipsoidal,
}

/// How to read a survey file.
#[derive(Clone, Debug, Default)]
pub struct ReadOptions {
    /// Skip detection.
    pub format: Option<SurveyFormat>,
    /// The CRS, overriding (or supplying) the file's.
    pub crs: Option<String>,
    /// Which height to take (Emlid), or what the heights are (other formats).
    pub height: Option<HeightChoice>,
    /// Exclude points whose solution is not FIX.
    pub fix_only: bool,
    /// Column map for `csv` and `metashape` (`name=Label,x=E,...` or by position).
    pub columns: Option<ColumnMap>,
    pub delimiter: Option<u8>,
    /// Image size for OpenSfM's normalised image coordinates.
    pub image_size: Option<(u32, u32)>,
    /// Image name for PeTrack's pixel picks.
    pub image: Option<String>,
}

/// Detects the format from the content.
pub fn detect(text: &str) -> Option<SurveyFormat> {
    // The first lines decide; a file of one huge line must not be split whole.
    let mut head = text.len().min(64 * 1024);
    while !text.is_char_boundary(head) {
        head -= 1;
    }
    let t = text[..head].trim_start_matches('\u{feff}').trim_start();
    if t.starts_with('{') {
        return t.contains("\"points\"").then_some(SurveyFormat::OpenSfm);
    }
    let lines: Vec<&str> = t
        .lines()
        .map(str::trim)
        .filter(|l| !l.is_empty())
        .take(6)
        .collect();
    let first = *lines.first()?;
    let lower = first.to_ascii_lowercase();
    if lower.contains("name")
        && (lower.contains("easting") || lower.contains("longitude"))
        && (lower.contains("solution status") || lower.contains("cs name") || lower.contains("rms"))
    {
        return Some(SurveyFormat::Emlid);
    }
    if first.starts_with('#') && (lower.contains("coordinatesystem") || lower.contains("label")) {
        return Some(SurveyFormat::Metashape);
    }
    let data: Vec<&str> = lines
        .iter()
        .copied()
        .filter(|l| !l.starts_with('#'))
        .collect();
    let first_data = *data.first()?;
    if first_data.parse::<usize>().is_ok()
        && data[1..].iter().all(|l| {
            let f: Vec<&str> = l.split_whitespace().collect();
            (f.len() == 3 || f.len() == 5) && f.iter().all(|x| x.parse::<f64>().is_ok())
        })
    {
        return Some(SurveyFormat::Petrack);
    }
    let looks_crs = first_data.starts_with("EPSG:")
        || first_data.starts_with('+')
        || first_data.to_ascii_uppercase().starts_with("WGS84 UTM")
        || first_data.starts_with("PROJCS[")
        || first_data.starts_with("PROJCRS[")
        || first_data.starts_with("GEOGCS[");
    if looks_crs {
        return Some(SurveyFormat::Odm);
    }
    // label,x,y,z rows with a delimiter (Metashape's reference export without comments),
    // possibly under a header line.
    let label_xyz = |l: &str| {
        let f: Vec<&str> = l.split([',', '\t', ';']).collect();
        f.len() >= 4 && f[1..4].iter().all(|x| x.trim().parse::<f64>().is_ok())
    };
    if label_xyz(first_data)
        || (data.len() > 1 && label_xyz(data[1]) && first_data.to_ascii_lowercase().contains('x'))
    {
        return Some(SurveyFormat::Metashape);
    }
    None
}

/// Reads a survey file.
pub fn read(path: &Path, opts: &ReadOptions) -> Result<Survey, SurveyError> {
    let text = Ctx { path }.read_text("a survey file saved as UTF-8")?;
    parse(path, &text, opts)
}

/// The most rows a survey file may have: surveys hold tens of points; a file of more is not a
/// survey (and its table would take memory in proportion).
pub const MAX_SURVEY_ROWS: usize = 100_000;

/// Parses a survey file's text; `path` names it in messages and says where it is.
pub fn parse(path: &Path, text: &str, opts: &ReadOptions) -> Result<Survey, SurveyError> {
    let ctx = Ctx { path };
    let rows = text.lines().count();
    if rows > MAX_SURVEY_ROWS {
        return Err(ctx.err(
            None,
            None,
            format!(
                "{rows} lines: a survey file has at most {MAX_SURVEY_ROWS} (is it the right file?)"
            ),
        ));
    }
    let format = match opts.format.or_else(|| detect(text)) {
        Some(f) => f,
        None => {
            return Err(ctx.err(
                Some(1),
                None,
                "cannot tell the format: expected an Emlid CSV, an OpenDroneMap gcp_list.txt, an \
                 OpenSfM JSON, a Metashape reference CSV or a PeTrack .3dc; pass --format (and \
                 --columns for a generic CSV)",
            ));
        }
    };
    let mut survey = match format {
        SurveyFormat::Emlid => emlid::read(&ctx, text, opts)?,
        SurveyFormat::Odm => odm::read(&ctx, text, opts)?,
        SurveyFormat::OpenSfm => opensfm::read(&ctx, text, opts)?,
        SurveyFormat::Metashape => metashape::read(&ctx, text, opts, SurveyFormat::Metashape)?,
        SurveyFormat::Csv => metashape::read(&ctx, text, opts, SurveyFormat::Csv)?,
        SurveyFormat::Petrack => petrack::read(&ctx, text, opts)?,
    };
    match opts.crs.as_deref() {
        Some("local") if format == SurveyFormat::Odm => {
            return Err(ctx.err(
                None,
                None,
                "an OpenDroneMap gcp_list.txt needs a CRS; --crs local does not apply",
            ));
        }
        Some(_) if format == SurveyFormat::Petrack => {
            return Err(ctx.err(
                None,
                None,
                "a PeTrack .3dc is in its own local frame (centimetres); --crs does not apply",
            ));
        }
        Some("local") => survey.crs = None,
        Some(crs) => survey.crs = Some(crs.to_string()),
        None => {}
    }
    resolve_height(&ctx, &mut survey, opts)?;
    check_positions(&ctx, &mut survey)?;
    Ok(survey)
}

/// How far outside its CRS's area of use a point may lie, degrees, before it is an error: a CRS
/// is often used somewhat beyond its official area (Norway maps in UTM 33), but not across a
/// continent (swapped or mistyped coordinates, the wrong CRS).
pub const AREA_MARGIN_DEG: f64 = 10.0;

/// Coordinates that fit the CRS: latitudes within ±90° and longitudes within ±360° for a
/// geographic CRS, and every point within [`AREA_MARGIN_DEG`] of the CRS's area of use (a
/// warning beyond 1°).
fn check_positions(ctx: &Ctx, survey: &mut Survey) -> Result<(), SurveyError> {
    let Some(spec) = &survey.crs else {
        return Ok(());
    };
    let crs = Crs::new(spec).map_err(|e| ctx.err(None, None, e.to_string()))?;
    let geographic = crs.horizontal == crate::survey::crs::Horizontal::Geographic;
    let mut worst: Option<(f64, usize, String)> = None;
    for p in &survey.points {
        let (x, y) = (p.position.x, p.position.y);
        if geographic && !((-90.0..=90.0).contains(&y) && (-360.0..=360.0).contains(&x)) {
            return Err(ctx.at(
                p.line,
                format!(
                    "'{}': longitude {x}, latitude {y} are out of range (a latitude is within ±90°): are the columns swapped, or is the CRS wrong?",
                    crate::io::clip(&p.name, 40)
                ),
            ));
        }
        let (lon, lat) = crs
            .to_lon_lat(x, y)
            .map_err(|e| ctx.at(p.line, e.to_string()))?;
        if let Some(area) = &crs.area_of_use {
            let d = area.distance_deg(lon, lat);
            if d > AREA_MARGIN_DEG {
                return Err(ctx.at(
                    p.line,
                    format!(
                        "'{}' ({x}, {y}) is at longitude {lon:.3}°, latitude {lat:.3}°, {d:.0}° outside where {} is used ({}): are the coordinates or the CRS wrong?",
                        crate::io::clip(&p.name, 40),
                        crs.label(),
                        area.name
                    ),
                ));
            }
            if d > 1.0 && worst.as_ref().is_none_or(|w| d > w.0) {
                worst = Some((d, p.line, area.name.clone()));
            }
        }
    }
    if let Some((d, line, area)) = worst {
        survey.warnings.push(format!(
            "points lie up to {d:.1}° outside where {} is meant to be used ({area}; line {line}): check the CRS",
            crs.label()
        ));
    }
    Ok(())
}

/// Settles what the heights mean: what the CRS says, what the reader found, or `--height`;
/// a contradiction is an error, never a silent mix.
fn resolve_height(ctx: &Ctx, survey: &mut Survey, opts: &ReadOptions) -> Result<(), SurveyError> {
    // An Emlid file has both heights; its reader picked one with the CRS and --height in mind.
    // A file in its own local frame has local heights.
    if survey.format == SurveyFormat::Emlid || survey.crs.is_none() {
        return Ok(());
    }
    let from_crs = match &survey.crs {
        Some(spec) => Crs::new(spec)
            .map_err(|e| ctx.err(None, None, e.to_string()))?
            .height_kind
            .clone(),
        None => HeightKind::Unknown,
    };
    let from_user = opts.height.map(|h| match h {
        HeightChoice::Ellipsoidal => HeightKind::Ellipsoidal,
        HeightChoice::Orthometric => HeightKind::Orthometric(None),
    });
    let same_kind = |a: &HeightKind, b: &HeightKind| {
        matches!(
            (a, b),
            (HeightKind::Ellipsoidal, HeightKind::Ellipsoidal)
                | (HeightKind::Orthometric(_), HeightKind::Orthometric(_))
        )
    };
    let says = [
        ("the CRS", from_crs.clone()),
        ("--height", from_user.clone().unwrap_or(HeightKind::Unknown)),
        ("the file", survey.height.clone()),
    ];
    let known: Vec<&(&str, HeightKind)> = says
        .iter()
        .filter(|(_, k)| *k != HeightKind::Unknown)
        .collect();
    for pair in known.windows(2) {
        if !same_kind(&pair[0].1, &pair[1].1) {
            return Err(ctx.err(
                None,
                None,
                format!(
                    "{} says the heights are {} but {} says {}; heights of different kinds are never mixed",
                    pair[0].0, pair[0].1, pair[1].0, pair[1].1
                ),
            ));
        }
    }
    // The most specific statement wins: a named vertical datum over a bare kind.
    if let Some((_, k)) = known
        .iter()
        .find(|(_, k)| matches!(k, HeightKind::Orthometric(Some(_))))
        .or(known.first())
    {
        survey.height = k.clone();
    } else {
        survey.warnings.push(
            "the file does not say whether heights are ellipsoidal or orthometric; pass --height to record it".into(),
        );
    }
    Ok(())
}

/// Assigns check and disabled roles: explicit names first, then a name prefix. Unknown names in
/// the lists are errors.
pub fn assign_roles(
    survey: &mut Survey,
    check_prefix: Option<&str>,
    check: &[String],
    disable: &[String],
) -> Result<(), SurveyError> {
    let ctx = Ctx {
        path: &survey.source.clone(),
    };
    let mut explicit: HashMap<&str, Role> = HashMap::new();
    for n in check {
        explicit.insert(n, Role::Check);
    }
    for n in disable {
        explicit.insert(n, Role::Disabled);
    }
    for name in explicit.keys() {
        if survey.point(name).is_none() {
            return Err(ctx.err(
                None,
                None,
                format!("--check/--disable name '{name}' is not a point of this file"),
            ));
        }
    }
    for p in &mut survey.points {
        if let Some(r) = explicit.get(p.name.as_str()) {
            p.role = *r;
        } else if p.role == Role::Control
            && let Some(prefix) = check_prefix.filter(|s| !s.is_empty())
            && p.name
                .to_ascii_uppercase()
                .starts_with(&prefix.to_ascii_uppercase())
        {
            p.role = Role::Check;
        }
    }
    Ok(())
}

/// The names of the points read so far, with their lines, to refuse a second point of a name.
#[derive(Default)]
pub(crate) struct Names(HashMap<String, usize>);

impl Names {
    /// Whether a row's point name may start a new point: an empty name is a dropped row
    /// (Ok(false)), a name seen before is an error naming both lines.
    pub(crate) fn admit(
        &mut self,
        ctx: &Ctx,
        dropped: &mut Vec<super::model::Dropped>,
        name: &str,
        line: usize,
    ) -> Result<bool, SurveyError> {
        if name.is_empty() {
            dropped.push(super::model::Dropped {
                line,
                reason: "no point name".into(),
            });
            return Ok(false);
        }
        if let Some(prev) = self.0.insert(name.to_string(), line) {
            return Err(ctx.at(
                line,
                format!(
                    "duplicate point name '{}' (first on line {prev})",
                    crate::io::clip(name, 40)
                ),
            ));
        }
        Ok(true)
    }
}

/// Warns about, or with `fix_only` drops, points whose solution is not FIX.
pub(crate) fn apply_fix_policy(survey: &mut Survey, fix_only: bool) {
    use super::model::{Dropped, SolutionStatus};
    let mut kept = Vec::with_capacity(survey.points.len());
    for p in std::mem::take(&mut survey.points) {
        match &p.status {
            Some(s) if *s != SolutionStatus::Fix => {
                if fix_only {
                    survey.dropped.push(Dropped {
                        line: p.line,
                        reason: format!("point {} has solution {s}, not FIX (--fix-only)", p.name),
                    });
                    continue;
                }
                survey.warnings.push(format!(
                    "point {} (line {}) has solution {s}, not FIX: its position may be off by decimetres or more; --fix-only excludes such points",
                    p.name, p.line
                ));
                kept.push(p);
            }
            _ => kept.push(p),
        }
    }
    survey.points = kept;
}

#[cfg(test)]
mod tests;
