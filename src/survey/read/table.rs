//! Delimited tables with line numbers, and column maps.

use crate::survey::model::{Ctx, SurveyError};

/// A data row with its 1-based line number.
pub(crate) struct Row {
    pub line: usize,
    pub fields: Vec<String>,
}

/// Rows of a delimited file; `#` comment lines kept apart.
pub(crate) struct Table {
    pub comments: Vec<(usize, String)>,
    pub rows: Vec<Row>,
}

/// The delimiter of a text table: the most frequent of `,` `\t` `;` in the first data line, or
/// whitespace (`b' '`) when there is none.
pub(crate) fn sniff_delimiter(text: &str) -> u8 {
    let first = text
        .lines()
        .map(str::trim)
        .find(|l| !l.is_empty() && !l.starts_with('#'))
        .unwrap_or("");
    let count = |c: char| first.matches(c).count();
    [(b',', count(',')), (b'\t', count('\t')), (b';', count(';'))]
        .into_iter()
        .filter(|(_, n)| *n > 0)
        .max_by_key(|(_, n)| *n)
        .map_or(b' ', |(d, _)| d)
}

pub(crate) fn read_table(ctx: &Ctx, text: &str, delimiter: u8) -> Result<Table, SurveyError> {
    // Line lengths first: a huge line would be split into fields whole before any check.
    for l in ctx.lines(text) {
        l?;
    }
    let mut comments = Vec::new();
    let mut rows = Vec::new();
    if delimiter == b' ' {
        for (i, l) in text.lines().enumerate() {
            let t = l.trim();
            if t.is_empty() {
                continue;
            }
            if let Some(c) = t.strip_prefix('#') {
                comments.push((i + 1, c.trim().to_string()));
                continue;
            }
            rows.push(Row {
                line: i + 1,
                fields: t.split_whitespace().map(str::to_string).collect(),
            });
        }
        return Ok(Table { comments, rows });
    }
    for (i, l) in text.lines().enumerate() {
        if let Some(c) = l.trim_start().strip_prefix('#') {
            comments.push((i + 1, c.trim().to_string()));
        }
    }
    // Comment lines are blanked (same length, so byte offsets hold) rather than left to the csv
    // crate, and lines come from byte offsets: the crate's line numbers skip comments.
    let blanked: String = text
        .split_inclusive('\n')
        .map(|l| {
            if l.trim_start().starts_with('#') {
                l.chars()
                    .map(|c| if c == '\n' || c == '\r' { c } else { ' ' })
                    .collect::<String>()
            } else {
                l.to_string()
            }
        })
        .collect();
    let starts: Vec<usize> = std::iter::once(0)
        .chain(text.match_indices('\n').map(|(i, _)| i + 1))
        .collect();
    let bytes = blanked.as_bytes();
    // The line of the first character at or after `byte` that is not blank.
    let line_at = |byte: u64| {
        let mut b = byte as usize;
        while b < bytes.len() && bytes[b].is_ascii_whitespace() {
            b += 1;
        }
        starts.partition_point(|&s| s <= b)
    };
    let mut reader = csv::ReaderBuilder::new()
        .delimiter(delimiter)
        .has_headers(false)
        .flexible(true)
        .trim(csv::Trim::All)
        .from_reader(bytes);
    for rec in reader.records() {
        let rec = rec.map_err(|e| {
            let line = e.position().map(|p| line_at(p.byte()));
            ctx.err(
                line,
                None,
                format!("not valid CSV: {}", crate::io::clip(&e.to_string(), 200)),
            )
        })?;
        // Blank rows first: `line_at` walks over blanks, and a run of blanked comment lines
        // walked once per line was quadratic (16 MB took 2.5 s; found by make fuzz).
        if rec.iter().all(|f| f.is_empty()) {
            continue;
        }
        let line = rec.position().map_or(0, |p| line_at(p.byte()));
        if rec.as_slice().len() > crate::io::MAX_LINE_BYTES {
            return Err(ctx.at(line, "a row longer than 1 MiB: is it the right file?"));
        }
        rows.push(Row {
            line,
            fields: rec.iter().map(str::to_string).collect(),
        });
    }
    Ok(Table { comments, rows })
}

/// What a column holds.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum Field {
    Name,
    X,
    Y,
    Z,
    SigmaX,
    SigmaY,
    SigmaZ,
    /// One accuracy for all three axes.
    Sigma,
    Role,
    /// Metashape's check box: 1 = control, 0 = check point.
    Enabled,
    Status,
    Code,
    Skip,
}

impl Field {
    fn parse(s: &str) -> Option<Field> {
        Some(match s.trim().to_ascii_lowercase().as_str() {
            "name" | "label" | "id" => Field::Name,
            "x" | "e" | "easting" | "lon" | "longitude" => Field::X,
            "y" | "n" | "northing" | "lat" | "latitude" => Field::Y,
            "z" | "h" | "height" | "alt" | "altitude" | "elevation" => Field::Z,
            "sx" | "x_accuracy" | "sigma_x" => Field::SigmaX,
            "sy" | "y_accuracy" | "sigma_y" => Field::SigmaY,
            "sz" | "z_accuracy" | "sigma_z" => Field::SigmaZ,
            "s" | "sxyz" | "accuracy" | "sigma" => Field::Sigma,
            "role" | "type" => Field::Role,
            "enabled" | "enable" => Field::Enabled,
            "status" | "solution" => Field::Status,
            "code" | "description" => Field::Code,
            "skip" | "_" | "-" => Field::Skip,
            _ => return None,
        })
    }

    pub const HELP: &'static str = "name, x, y, z, sx, sy, sz, sigma (one for all axes), role, enabled (1 control, 0 check), status, code, skip";
}

/// Where each field is: by header name or by 1-based position.
#[derive(Clone, Debug, PartialEq)]
pub enum Column {
    Header(String),
    Position(usize),
}

/// `--columns`: either `field=column,...` (a column is a header name or a 1-based position) or
/// the fields in column order, `name,x,y,z,sx,sy,sz`.
#[derive(Clone, Debug, PartialEq)]
pub struct ColumnMap {
    pub entries: Vec<(Field, Column)>,
}

impl std::str::FromStr for ColumnMap {
    type Err = String;

    fn from_str(s: &str) -> Result<Self, String> {
        let mut entries = Vec::new();
        let parts: Vec<&str> = s
            .split(',')
            .map(str::trim)
            .filter(|p| !p.is_empty())
            .collect();
        let keyed = parts.iter().any(|p| p.contains('='));
        for (i, p) in parts.iter().enumerate() {
            if keyed {
                let (k, v) = p.split_once('=').ok_or_else(|| {
                    format!(
                        "'{}': expected field=column (all entries or none use '=')",
                        crate::io::clip(p, 40)
                    )
                })?;
                let field = Field::parse(k).ok_or_else(|| {
                    format!(
                        "unknown field '{}'; fields are {}",
                        crate::io::clip(k, 40),
                        Field::HELP
                    )
                })?;
                let column = match v.trim().parse::<usize>() {
                    Ok(n) if n >= 1 => Column::Position(n),
                    Ok(_) => return Err("column positions start at 1".into()),
                    Err(_) => Column::Header(v.trim().to_string()),
                };
                entries.push((field, column));
            } else {
                let field = Field::parse(p).ok_or_else(|| {
                    format!(
                        "unknown field '{}'; fields are {}",
                        crate::io::clip(p, 40),
                        Field::HELP
                    )
                })?;
                if field != Field::Skip {
                    entries.push((field, Column::Position(i + 1)));
                }
            }
        }
        for f in [Field::X, Field::Y] {
            if !entries.iter().any(|(e, _)| *e == f) {
                return Err(format!(
                    "the column map needs {f:?} (fields are {})",
                    Field::HELP
                ));
            }
        }
        let mut seen = std::collections::HashSet::new();
        for (f, _) in &entries {
            if !seen.insert(*f) {
                return Err(format!("field {f:?} is mapped twice"));
            }
        }
        Ok(ColumnMap { entries })
    }
}

impl ColumnMap {
    /// Resolves the map to 0-based indices against a header (when the map names columns).
    pub(crate) fn resolve(
        &self,
        ctx: &Ctx,
        header: Option<&Row>,
    ) -> Result<Vec<(Field, usize)>, SurveyError> {
        self.entries
            .iter()
            .map(|(f, c)| match c {
                Column::Position(n) => Ok((*f, n - 1)),
                Column::Header(h) => {
                    let header = header.ok_or_else(|| {
                        ctx.err(
                            Some(1),
                            None,
                            format!(
                                "the column map names column '{h}' but the file has no header line"
                            ),
                        )
                    })?;
                    let found: Vec<usize> = header
                        .fields
                        .iter()
                        .enumerate()
                        .filter(|(_, x)| x.eq_ignore_ascii_case(h))
                        .map(|(i, _)| i)
                        .collect();
                    match found.as_slice() {
                        [i] => Ok((*f, *i)),
                        [] => Err(ctx.err(
                            Some(header.line),
                            Some(h),
                            format!(
                                "no such column; the header has: {}",
                                header.fields.join(", ")
                            ),
                        )),
                        _ => Err(ctx.err(
                            Some(header.line),
                            Some(h),
                            "appears more than once in the header",
                        )),
                    }
                }
            })
            .collect()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn column_maps() {
        let m: ColumnMap = "name=Label,x=E,y=N,z=3".parse().unwrap();
        assert_eq!(m.entries[3], (Field::Z, Column::Position(3)));
        let m: ColumnMap = "label,x,y,z,skip,sx".parse().unwrap();
        assert_eq!(m.entries.len(), 5);
        assert_eq!(m.entries[4], (Field::SigmaX, Column::Position(6)));
        assert!("name,y,z".parse::<ColumnMap>().is_err());
        assert!("name=a,x=b,y".parse::<ColumnMap>().is_err());
        assert!("x,y,x".parse::<ColumnMap>().is_err());
        assert!(
            "x,y,banana"
                .parse::<ColumnMap>()
                .unwrap_err()
                .contains("unknown field")
        );
    }

    #[test]
    fn delimiters() {
        assert_eq!(sniff_delimiter("# c\na;b;c\n"), b';');
        assert_eq!(sniff_delimiter("a\tb,c\td\n"), b'\t');
        assert_eq!(sniff_delimiter("a b c\n"), b' ');
    }
}
