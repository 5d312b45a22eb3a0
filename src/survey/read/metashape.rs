//! Agisoft Metashape reference CSV (label, x, y, z and optional accuracies; `#` comment lines,
//! one of which may name the CRS: `#CoordinateSystem: ... (EPSG::32631)`), and generic CSV with
//! an explicit column map. The delimiter is detected (`,` `\t` `;` or spaces) unless given.

use nalgebra::Vector3;

use super::ReadOptions;
use super::table::{Field, Row, read_table, sniff_delimiter};
use crate::survey::crs::HeightKind;
use crate::survey::model::{Ctx, Gcp, Role, SolutionStatus, Survey, SurveyError, SurveyFormat};

/// The CRS named in a Metashape comment: `EPSG::nnnn` in parentheses, or a local frame.
fn crs_from_comments(comments: &[(usize, String)]) -> Option<Option<String>> {
    for (_, c) in comments {
        let lower = c.to_ascii_lowercase();
        if !lower.contains("coordinatesystem") && !lower.contains("coordinate system") {
            continue;
        }
        if let Some(i) = c.find("EPSG::") {
            let code: String = c[i + 6..]
                .chars()
                .take_while(char::is_ascii_digit)
                .collect();
            if !code.is_empty() {
                return Some(Some(format!("EPSG:{code}")));
            }
        }
        if lower.contains("local coordinates") {
            return Some(None);
        }
    }
    None
}

/// A column map from a Metashape header comment such as `#Label,X/Easting,Y/Northing,Z/Altitude,X_accuracy,...`.
fn map_from_header(fields: &[String]) -> Option<Vec<(Field, usize)>> {
    let mut out = Vec::new();
    for (i, f) in fields.iter().enumerate() {
        let l = f.trim().trim_start_matches('#').to_ascii_lowercase();
        let field = if l == "label" || l == "name" {
            Field::Name
        } else if l.contains("accuracy") || l.ends_with("_acc") {
            match l.chars().next() {
                Some('x') => Field::SigmaX,
                Some('y') => Field::SigmaY,
                Some('z') => Field::SigmaZ,
                _ => Field::Sigma,
            }
        } else if l.starts_with("x/") || l == "x" || l == "easting" || l == "longitude" {
            Field::X
        } else if l.starts_with("y/") || l == "y" || l == "northing" || l == "latitude" {
            Field::Y
        } else if l.starts_with("z/") || l == "z" || l == "altitude" || l == "elevation" {
            Field::Z
        } else if l == "enable" || l == "enabled" {
            Field::Enabled
        } else {
            continue;
        };
        if !out.iter().any(|(f, _)| *f == field) {
            out.push((field, i));
        }
    }
    (out.iter().any(|(f, _)| *f == Field::X) && out.iter().any(|(f, _)| *f == Field::Y))
        .then_some(out)
}

fn parse_role(ctx: &Ctx, text: &str, line: usize) -> Result<Role, SurveyError> {
    match text.trim().to_ascii_lowercase().as_str() {
        "" | "control" | "gcp" | "1" | "true" | "yes" | "on" => Ok(Role::Control),
        "check" | "chk" | "checkpoint" | "check point" | "cp" => Ok(Role::Check),
        "disabled" | "0" | "false" | "no" | "off" => Ok(Role::Disabled),
        other => Err(ctx.err(
            Some(line),
            Some("role"),
            format!("expected control, check or disabled (or 1/0), found '{other}'"),
        )),
    }
}

/// Column indices: `--columns`, else (Metashape) a header comment or the default order; and the
/// header's width, when there is one (it bounds every row's). A header row is taken off `rows`.
fn column_map(
    ctx: &Ctx,
    comments: &[(usize, String)],
    rows: &mut Vec<Row>,
    opts: &ReadOptions,
    format: SurveyFormat,
) -> Result<(Vec<(Field, usize)>, Option<usize>), SurveyError> {
    let first_is_header = |rows: &[Row], x_index: usize| {
        rows.first()
            .and_then(|r| r.fields.get(x_index))
            .is_some_and(|f| f.trim().parse::<f64>().is_err())
    };

    let mut header_width: Option<usize> = None;
    let columns: Vec<(Field, usize)> = match &opts.columns {
        Some(map) => {
            let names_columns = map
                .entries
                .iter()
                .any(|(_, c)| matches!(c, super::table::Column::Header(_)));
            let x_pos = map.entries.iter().find_map(|(f, c)| match (f, c) {
                (Field::X, super::table::Column::Position(n)) => Some(n - 1),
                _ => None,
            });
            let header = if names_columns || x_pos.is_some_and(|x| first_is_header(rows, x)) {
                Some(rows.remove(0))
            } else {
                None
            };
            header_width = header.as_ref().map(|h| h.fields.len());
            map.resolve(ctx, header.as_ref())?
        }
        None if format == SurveyFormat::Csv => {
            return Err(ctx.err(
                None,
                None,
                format!("a generic CSV needs --columns, e.g. 'name=Label,x=E,y=N,z=H' or 'name,x,y,z' (fields: {})", Field::HELP),
            ));
        }
        None => {
            let from_comment = comments.iter().rev().find_map(|(_, c)| {
                let fields = c
                    .split([',', '\t', ';'])
                    .map(str::to_string)
                    .collect::<Vec<_>>();
                map_from_header(&fields).map(|m| (m, fields.len()))
            });
            match from_comment {
                Some((m, width)) => {
                    header_width = Some(width);
                    m
                }
                None if first_is_header(rows, 1) => {
                    let header = rows.remove(0);
                    header_width = Some(header.fields.len());
                    map_from_header(&header.fields).ok_or_else(|| {
                        ctx.err(
                            Some(header.line),
                            None,
                            "cannot tell the columns from this header; pass --columns",
                        )
                    })?
                }
                None => vec![
                    (Field::Name, 0),
                    (Field::X, 1),
                    (Field::Y, 2),
                    (Field::Z, 3),
                ],
            }
        }
    };
    Ok((columns, header_width))
}

pub(super) fn read(
    ctx: &Ctx,
    text: &str,
    opts: &ReadOptions,
    format: SurveyFormat,
) -> Result<Survey, SurveyError> {
    let table = read_table(
        ctx,
        text,
        opts.delimiter.unwrap_or_else(|| sniff_delimiter(text)),
    )?;
    let mut rows: Vec<Row> = table.rows;
    let (columns, header_width) = column_map(ctx, &table.comments, &mut rows, opts, format)?;
    let get = |f: Field| columns.iter().find(|(c, _)| *c == f).map(|(_, i)| *i);

    let crs = match (&opts.crs, crs_from_comments(&table.comments)) {
        (Some(c), _) => Some(c.clone()),
        (None, Some(c)) => c,
        (None, None) => {
            return Err(ctx.err(
                None,
                None,
                "no CRS: the file names none (no '#CoordinateSystem: ... (EPSG::nnnn)' line); pass --crs",
            ));
        }
    };

    let mut points: Vec<Gcp> = Vec::new();
    let mut dropped = Vec::new();
    let mut names = super::Names::default();
    let mut warnings = Vec::new();
    let used_max = columns.iter().map(|(_, i)| *i).max().unwrap_or(0);
    let mut extra_columns = false;
    // Without a header, the first row sets the width: a longer row is a shifted one.
    let width = header_width.or_else(|| rows.first().map(|r| r.fields.len()));
    for r in rows {
        if let Some(w) = width
            && r.fields.len() > w
        {
            let fields: Vec<&str> = r.fields.iter().map(String::as_str).collect();
            ctx.field_count(
                &fields,
                r.line,
                1,
                w,
                "as many as the header or the first row",
            )?;
        }
        let cell = |i: Option<usize>| {
            i.and_then(|i| r.fields.get(i))
                .map(|s| s.trim())
                .unwrap_or("")
        };
        extra_columns |= r.fields.len() > used_max + 1;
        if r.fields.len() <= get(Field::Y).unwrap_or(0).max(get(Field::X).unwrap_or(0)) {
            return Err(ctx.at(
                r.line,
                format!(
                    "{} field(s), fewer than the column map needs",
                    r.fields.len()
                ),
            ));
        }
        let name = match get(Field::Name) {
            Some(_) => cell(get(Field::Name)).to_string(),
            None => format!("P{}", points.len() + 1),
        };
        if !names.admit(ctx, &mut dropped, &name, r.line)? {
            continue;
        }
        let x = ctx.number(cell(get(Field::X)), r.line, "x")?;
        let y = ctx.number(cell(get(Field::Y)), r.line, "y")?;
        let z = match get(Field::Z) {
            Some(_) if !cell(get(Field::Z)).is_empty() => {
                ctx.number(cell(get(Field::Z)), r.line, "z")?
            }
            _ => f64::NAN,
        };
        let mut g = Gcp::new(name, Vector3::new(x, y, z), r.line);
        let sig = |f: Field, label: &str| -> Result<Option<f64>, SurveyError> {
            match cell(get(f)) {
                "" => Ok(None),
                t => ctx.positive(t, r.line, label).map(Some),
            }
        };
        let all = sig(Field::Sigma, "sigma")?;
        let (sx, sy, sz) = (
            sig(Field::SigmaX, "sx")?.or(all),
            sig(Field::SigmaY, "sy")?.or(all),
            sig(Field::SigmaZ, "sz")?.or(all),
        );
        if let (Some(a), Some(b), Some(c)) = (sx, sy, sz) {
            g.sigma_m = Some(Vector3::new(a, b, c));
        }
        if get(Field::Role).is_some() {
            g.role = parse_role(ctx, cell(get(Field::Role)), r.line)?;
        }
        // Metashape: an unticked marker is a check point.
        if get(Field::Enabled).is_some() {
            g.role = match cell(get(Field::Enabled)).to_ascii_lowercase().as_str() {
                "" | "1" | "true" | "yes" => Role::Control,
                "0" | "false" | "no" => Role::Check,
                other => {
                    return Err(ctx.err(
                        Some(r.line),
                        Some("enabled"),
                        format!("expected 1 or 0, found '{other}'"),
                    ));
                }
            };
        }
        g.status = SolutionStatus::parse(cell(get(Field::Status)));
        g.code = Some(cell(get(Field::Code)).to_string()).filter(|s| !s.is_empty());
        points.push(g);
    }
    if points.is_empty() {
        return Err(ctx.err(None, None, "no point rows"));
    }
    if extra_columns && opts.columns.is_none() {
        warnings
            .push("some rows have more columns than were read; pass --columns to use them".into());
    }
    let mut survey = Survey {
        source: ctx.path.to_path_buf(),
        format,
        crs,
        height: HeightKind::Unknown,
        points,
        dropped,
        warnings,
    };
    super::apply_fix_policy(&mut survey, opts.fix_only);
    Ok(survey)
}
