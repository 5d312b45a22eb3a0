//! Emlid Flow / ReachView CSV, read by column name (27- and 42-column generations alike, in any
//! column order).

use std::collections::HashMap;

use nalgebra::Vector3;

use super::table::{read_table, sniff_delimiter};
use super::{HeightChoice, ReadOptions, apply_fix_policy};
use crate::survey::crs::{Crs, HeightKind, Horizontal};
use crate::survey::model::{Ctx, Gcp, SolutionStatus, Survey, SurveyError, SurveyFormat};

/// Columns of the first generation (27); the second adds 15 more, all optional here.
pub const COLUMNS_27: [&str; 27] = [
    "Name",
    "Easting",
    "Northing",
    "Elevation",
    "Description",
    "Longitude",
    "Latitude",
    "Ellipsoidal height",
    "Easting RMS",
    "Northing RMS",
    "Elevation RMS",
    "Lateral RMS",
    "Antenna height",
    "Antenna height units",
    "Solution status",
    "Averaging start",
    "Averaging end",
    "Samples",
    "PDOP",
    "Base easting",
    "Base northing",
    "Base elevation",
    "Base longitude",
    "Base latitude",
    "Base ellipsoidal height",
    "Baseline",
    "CS name",
];
pub const COLUMNS_42_EXTRA: [&str; 15] = [
    "Code",
    "Code description",
    "Origin",
    "Tilt angle",
    "Correction type",
    "GDOP",
    "Mount point",
    "GPS Satellites",
    "GLONASS Satellites",
    "Galileo Satellites",
    "BeiDou Satellites",
    "QZSS Satellites",
    "Device type",
    "Device serial number",
    "Author",
];

/// The CRS: `--crs`, else the CS name column (one for all rows).
fn crs_of(
    ctx: &Ctx,
    rows: &[super::table::Row],
    cs_col: Option<usize>,
    opts: &ReadOptions,
) -> Result<String, SurveyError> {
    let mut cs_names: Vec<(usize, String)> = Vec::new();
    if let Some(c) = cs_col {
        for r in rows {
            if let Some(v) = r.fields.get(c).map(|s| s.trim()).filter(|s| !s.is_empty())
                && !cs_names.iter().any(|(_, n)| n == v)
            {
                cs_names.push((r.line, v.to_string()));
            }
        }
    }
    if cs_names.len() > 1 && opts.crs.is_none() {
        let list: Vec<String> = cs_names
            .iter()
            .map(|(l, n)| format!("'{n}' (line {l})"))
            .collect();
        return Err(ctx.err(
            None,
            Some("CS name"),
            format!(
                "mixed CRSs in one file: {}; split the file by CRS",
                list.join(", ")
            ),
        ));
    }
    Ok(match (&opts.crs, cs_names.first()) {
        (Some(c), _) => c.clone(),
        (None, Some((line, name))) => {
            Crs::new(name).map_err(|e| {
                ctx.err(
                    Some(*line),
                    Some("CS name"),
                    format!(
                        "PROJ does not know '{name}' ({}); pass --crs with its EPSG code",
                        e.message
                    ),
                )
            })?;
            name.clone()
        }
        (None, None) => {
            return Err(ctx.err(
                None,
                Some("CS name"),
                "no CRS: the CS name column is missing or empty; pass --crs",
            ));
        }
    })
}

/// The file's own longitude and latitude against its easting and northing `xy` in `crs`.
fn check_lon_lat(
    ctx: &Ctx,
    crs: &Crs,
    line: usize,
    (x, y): (f64, f64),
    (lon, lat): (f64, f64),
) -> Result<(), SurveyError> {
    let (clon, clat) = crs
        .to_lon_lat(x, y)
        .map_err(|e| ctx.at(line, e.to_string()))?;
    if (clon - lon).abs() > 0.01 || (clat - lat).abs() > 0.01 {
        return Err(ctx.err(
            Some(line),
            Some("Longitude"),
            format!(
                "the file gives longitude {lon}, latitude {lat}, but its easting and northing in {} are at {clon:.5}, {clat:.5}: is the CRS right?",
                crs.label()
            ),
        ));
    }
    Ok(())
}

/// Which height and its column: `--height`, else what the CRS implies.
fn height_column(
    ctx: &Ctx,
    header_line: usize,
    opts: &ReadOptions,
    crs: &Crs,
    elev_col: Option<usize>,
    ell_col: Option<usize>,
) -> Result<(HeightChoice, usize), SurveyError> {
    let choice = match opts.height {
        Some(h) => h,
        None => match crs.height_kind {
            HeightKind::Ellipsoidal => HeightChoice::Ellipsoidal,
            _ => HeightChoice::Orthometric,
        },
    };
    let zc = match choice {
        HeightChoice::Orthometric => elev_col.ok_or_else(|| {
            ctx.err(
                Some(header_line),
                Some("Elevation"),
                "missing (pass --height ellipsoidal to use Ellipsoidal height)",
            )
        })?,
        HeightChoice::Ellipsoidal => ell_col.ok_or_else(|| {
            ctx.err(
                Some(header_line),
                Some("Ellipsoidal height"),
                "missing (pass --height orthometric to use Elevation)",
            )
        })?,
    };
    Ok((choice, zc))
}

/// The header's columns, by name in any case.
struct Columns {
    index: HashMap<String, usize>,
    line: usize,
}

impl Columns {
    fn of(ctx: &Ctx, header: &super::table::Row) -> Result<Columns, SurveyError> {
        let mut index: HashMap<String, usize> = HashMap::new();
        for (i, h) in header.fields.iter().enumerate() {
            if index.insert(h.trim().to_ascii_lowercase(), i).is_some() {
                return Err(ctx.err(Some(header.line), Some(h), "appears twice in the header"));
            }
        }
        Ok(Columns {
            index,
            line: header.line,
        })
    }

    fn col(&self, name: &str) -> Option<usize> {
        self.index.get(&name.to_ascii_lowercase()).copied()
    }

    fn need(&self, ctx: &Ctx, name: &str) -> Result<usize, SurveyError> {
        self.col(name).ok_or_else(|| {
            ctx.err(
                Some(self.line),
                Some(name),
                format!(
                    "missing; an Emlid CSV has the columns {} (42-column exports add {})",
                    COLUMNS_27.join(", "),
                    COLUMNS_42_EXTRA.join(", ")
                ),
            )
        })
    }
}

pub(super) fn read(ctx: &Ctx, text: &str, opts: &ReadOptions) -> Result<Survey, SurveyError> {
    let table = read_table(
        ctx,
        text,
        opts.delimiter.unwrap_or_else(|| sniff_delimiter(text)),
    )?;
    let mut rows = table.rows.into_iter();
    let header = rows
        .next()
        .ok_or_else(|| ctx.err(Some(1), None, "empty file: expected a header line"))?;
    let columns = Columns::of(ctx, &header)?;
    let col = |name: &str| columns.col(name);
    let need = |name: &str| columns.need(ctx, name);
    let name_col = need("Name")?;
    let cs_col = col("CS name");

    let rows: Vec<_> = rows.collect();
    let crs_spec = crs_of(ctx, &rows, cs_col, opts)?;
    let crs = Crs::new(&crs_spec).map_err(|e| ctx.err(None, None, e.to_string()))?;

    let projected = crs.horizontal == Horizontal::Projected;
    let (xc, yc) = if projected {
        (need("Easting")?, need("Northing")?)
    } else {
        (need("Longitude")?, need("Latitude")?)
    };
    let elev_col = col("Elevation");
    let ell_col = col("Ellipsoidal height");
    let (choice, zc) = height_column(ctx, header.line, opts, &crs, elev_col, ell_col)?;
    let rms = [
        col("Easting RMS"),
        col("Northing RMS"),
        col("Elevation RMS"),
    ];
    let status_col = col("Solution status");
    let code_cols = [col("Code"), col("Description")];

    let mut points: Vec<Gcp> = Vec::new();
    let mut dropped = Vec::new();
    let mut names = super::Names::default();
    let mut same_heights = true;
    let cell = |r: &super::table::Row, c: usize| {
        r.fields
            .get(c)
            .map(|s| s.trim().to_string())
            .unwrap_or_default()
    };
    for r in &rows {
        let fields: Vec<&str> = r.fields.iter().map(String::as_str).collect();
        ctx.field_count(
            &fields,
            r.line,
            1,
            header.fields.len(),
            "the header's columns",
        )?;
        let name = cell(r, name_col);
        if !names.admit(ctx, &mut dropped, &name, r.line)? {
            continue;
        }
        let num = |c: usize, field: &str| ctx.number(&cell(r, c), r.line, field);
        let (xf, yf) = if projected {
            ("Easting", "Northing")
        } else {
            ("Longitude", "Latitude")
        };
        let zf = if choice == HeightChoice::Orthometric {
            "Elevation"
        } else {
            "Ellipsoidal height"
        };
        let mut gcp = Gcp::new(
            name,
            Vector3::new(num(xc, xf)?, num(yc, yf)?, num(zc, zf)?),
            r.line,
        );
        // The file's own longitude and latitude must agree with its eastings and northings in
        // the CRS used: they do not when --crs names the wrong one. A kilometre of slack: the
        // columns may be on another datum.
        if projected
            && let (Some(lc), Some(bc)) = (col("Longitude"), col("Latitude"))
            && let (Ok(lon), Ok(lat)) = (cell(r, lc).parse::<f64>(), cell(r, bc).parse::<f64>())
            && lon.is_finite()
            && lat.is_finite()
        {
            check_lon_lat(
                ctx,
                &crs,
                r.line,
                (gcp.position.x, gcp.position.y),
                (lon, lat),
            )?;
        }
        if let (Some(e), Some(h)) = (elev_col, ell_col)
            && let (Ok(a), Ok(b)) = (cell(r, e).parse::<f64>(), cell(r, h).parse::<f64>())
        {
            same_heights &= (a - b).abs() < 1e-4;
        }
        if let [Some(a), Some(b), Some(c)] = rms {
            let s = [cell(r, a), cell(r, b), cell(r, c)];
            if s.iter().all(|v| !v.is_empty()) {
                gcp.sigma_m = Some(Vector3::new(
                    ctx.positive(&s[0], r.line, "Easting RMS")?,
                    ctx.positive(&s[1], r.line, "Northing RMS")?,
                    ctx.positive(&s[2], r.line, "Elevation RMS")?,
                ));
            }
        }
        gcp.status = status_col.and_then(|c| SolutionStatus::parse(&cell(r, c)));
        gcp.code = code_cols
            .iter()
            .flatten()
            .map(|&c| cell(r, c))
            .find(|s| !s.is_empty());
        points.push(gcp);
    }
    let height = match (choice, &crs.height_kind) {
        (HeightChoice::Ellipsoidal, _) => HeightKind::Ellipsoidal,
        (HeightChoice::Orthometric, HeightKind::Orthometric(d)) => {
            HeightKind::Orthometric(d.clone())
        }
        // Without a vertical datum in the CRS, Emlid's Elevation is the ellipsoidal height.
        (HeightChoice::Orthometric, _) if same_heights && ell_col.is_some() => {
            HeightKind::Ellipsoidal
        }
        (HeightChoice::Orthometric, _) => HeightKind::Orthometric(None),
    };
    let mut survey = Survey {
        source: ctx.path.to_path_buf(),
        format: SurveyFormat::Emlid,
        crs: Some(crs_spec),
        height,
        points,
        dropped,
        warnings: Vec::new(),
    };
    if choice == HeightChoice::Orthometric
        && survey.height == HeightKind::Ellipsoidal
        && opts.height.is_none()
    {
        survey.warnings.push(
            "Elevation equals Ellipsoidal height in every row: the CS has no vertical datum, so the heights are ellipsoidal".into(),
        );
    }
    apply_fix_policy(&mut survey, opts.fix_only);
    Ok(survey)
}
