//! `geostride survey inspect|convert`.

use std::collections::BTreeSet;
use std::fmt::Write as _;
use std::path::{Path, PathBuf};

use anyhow::anyhow;
use clap::ValueEnum;
use nalgebra::Vector3;
use serde::Serialize;

use super::{bad_input, check_output_file};
use geostride::geom::similarity::ScaleMode;
use geostride::survey::crs::{Crs, HeightKind, Horizontal, Transform};
use geostride::survey::fit::{FitPoint, FitReport, helmert};
use geostride::survey::frame::{Origin, SiteFrame};
use geostride::survey::gis::{GisFormat, write_points};
use geostride::survey::load::{LoadOptions, load_framed};
use geostride::survey::read::{ColumnMap, HeightChoice, ReadOptions, assign_roles, read};
use geostride::survey::write::{self, OutCrs, OutPoint};
use geostride::survey::{Role, Survey, SurveyFormat};

#[derive(Clone, Copy, Debug, ValueEnum)]
pub enum InFormat {
    /// Emlid Flow / ReachView CSV
    Emlid,
    /// OpenDroneMap gcp_list.txt
    Odm,
    /// OpenSfM ground_control_points.json
    Opensfm,
    /// Agisoft Metashape reference CSV
    Metashape,
    /// PeTrack .3dc (centimetres, local frame)
    Petrack,
    /// CSV with --columns
    Csv,
}

impl From<InFormat> for SurveyFormat {
    fn from(f: InFormat) -> Self {
        match f {
            InFormat::Emlid => SurveyFormat::Emlid,
            InFormat::Odm => SurveyFormat::Odm,
            InFormat::Opensfm => SurveyFormat::OpenSfm,
            InFormat::Metashape => SurveyFormat::Metashape,
            InFormat::Petrack => SurveyFormat::Petrack,
            InFormat::Csv => SurveyFormat::Csv,
        }
    }
}

#[derive(Clone, Copy, Debug, ValueEnum)]
pub enum OutFormat {
    /// OpenDroneMap gcp_list.txt (one row per image pick)
    Odm,
    /// OpenSfM ground_control_points.json (WGS 84)
    Opensfm,
    /// Agisoft Metashape reference CSV
    Metashape,
    /// PeTrack .3dc (site frame, centimetres)
    Petrack,
    /// Emlid CSV (27 columns)
    Emlid,
    /// CSV with source and site coordinates, sigma, roles and residuals
    Csv,
    /// RFC 7946 GeoJSON (WGS 84 longitude/latitude), through GDAL
    Geojson,
    /// GeoPackage in the survey's (or --to-crs) CRS, through GDAL
    Gpkg,
}

#[derive(Clone, Copy, Debug, ValueEnum)]
pub enum HeightArg {
    /// Gravity-related heights (Emlid: the Elevation column)
    Orthometric,
    /// Heights above the ellipsoid (Emlid: the Ellipsoidal height column)
    Ellipsoidal,
}

fn parse_delimiter(s: &str) -> Result<u8, String> {
    match s {
        "tab" | "\\t" => Ok(b'\t'),
        "space" => Ok(b' '),
        s if s.len() == 1 && s.is_ascii() => Ok(s.as_bytes()[0]),
        _ => Err(format!(
            "expected one character, 'tab' or 'space', got '{s}'"
        )),
    }
}

/// How to read a survey file into the site frame; shared by `survey` and `pose`.
#[derive(clap::Args)]
pub struct ReadArgs {
    /// Input format, when detection from the content is not wanted (csv needs --columns)
    #[arg(long, value_enum)]
    format: Option<InFormat>,
    /// CRS of the file's coordinates (EPSG:nnnn, a PROJ string, a CRS name; 'local' for none),
    /// overriding or supplying the file's own
    #[arg(long, value_name = "CRS")]
    crs: Option<String>,
    /// Which heights (Emlid has both), or what the file's heights are
    #[arg(long, value_enum)]
    height: Option<HeightArg>,
    /// Exclude points whose solution is not FIX (they are listed as dropped)
    #[arg(long)]
    fix_only: bool,
    /// Columns for csv and metashape: 'name=Label,x=E,y=N,z=H,sx=..' (header names or 1-based
    /// positions) or the fields in order, 'name,x,y,z,sx,sy,sz'
    #[arg(long, value_name = "MAP")]
    columns: Option<ColumnMap>,
    /// Field delimiter for CSV formats: a character, 'tab' or 'space' [default: detected]
    #[arg(long, value_parser = parse_delimiter, value_name = "C")]
    delimiter: Option<u8>,
    /// Size WIDTHxHEIGHT of the picked images: converts OpenSfM's normalised image coordinates;
    /// `pose` scales the camera to it
    #[arg(long, value_parser = super::parse_size, value_name = "WxH")]
    pub image_size: Option<(u32, u32)>,
    /// CSV of pixel picks 'name,image,u,v[,sigma]' to add (repeatable)
    #[arg(long, value_name = "FILE")]
    pub picks: Vec<PathBuf>,
    /// Points whose names start with this are check points ('' for none)
    #[arg(long, default_value = "CHK-", value_name = "PREFIX")]
    check_prefix: String,
    /// Check points by name, comma-separated (held out of fits, reported apart)
    #[arg(long, value_delimiter = ',', value_name = "NAMES")]
    check: Vec<String>,
    /// Points to ignore, comma-separated
    #[arg(long, value_delimiter = ',', value_name = "NAMES")]
    disable: Vec<String>,
    /// Origin of the local east-north-up frame: 'centroid' (of the control points), 'point:NAME'
    /// or 'LAT,LON,H'
    #[arg(long, default_value = "centroid", value_name = "ORIGIN")]
    pub(crate) origin: Origin,
}

/// How to read the survey and what to do with it; shared by `inspect` and `convert`.
#[derive(clap::Args)]
pub struct Input {
    /// Survey file: Emlid CSV, OpenDroneMap gcp_list.txt, OpenSfM JSON, Metashape CSV, PeTrack .3dc, CSV
    file: PathBuf,
    #[command(flatten)]
    read: ReadArgs,
    /// Image name of PeTrack's pixel picks
    #[arg(long, value_name = "NAME")]
    image: Option<String>,
    /// Fit a 7-parameter Helmert transform from this file's points onto a reference file's
    /// (matched by name) and report control and check residuals
    #[arg(long, value_name = "REF")]
    fit_to: Option<PathBuf>,
    /// CRS of the --fit-to reference file, when it does not name one
    #[arg(long, value_name = "CRS")]
    fit_to_crs: Option<String>,
    /// Robust (Huber) Helmert fit, down-weighting outlying control points
    #[arg(long)]
    robust: bool,
    /// Rigid fit (scale held at 1)
    #[arg(long)]
    rigid: bool,
}

#[derive(clap::Subcommand)]
pub enum Command {
    /// List the points of a survey file with their site-frame coordinates, and summarise it
    Inspect {
        #[command(flatten)]
        input: Input,
        /// Print JSON instead of the table
        #[arg(long)]
        json: bool,
    },
    /// Convert a survey file to another format and/or CRS
    Convert {
        #[command(flatten)]
        input: Input,
        /// Output format
        #[arg(long, value_enum)]
        to: OutFormat,
        /// Output file
        #[arg(short, long, value_name = "FILE")]
        output: PathBuf,
        /// Output CRS (horizontal; heights are carried unchanged) [default: the survey's]
        #[arg(long, value_name = "CRS")]
        to_crs: Option<String>,
    },
}

pub(crate) use geostride::survey::load::Framed;

/// Reads a survey file (and its picks), assigns roles and sets up the site frame.
pub(crate) fn read_framed(
    file: &Path,
    args: &ReadArgs,
    petrack_image: Option<String>,
) -> anyhow::Result<Framed> {
    let opts = LoadOptions {
        read: read_options(args, petrack_image),
        picks: args.picks.clone(),
        check_prefix: Some(args.check_prefix.clone()),
        check: args.check.clone(),
        disable: args.disable.clone(),
        origin: Some(args.origin.clone()),
    };
    load_framed(file, &opts).map_err(bad_input)
}

/// How `args` say a survey file is to be read.
pub(crate) fn read_options(args: &ReadArgs, petrack_image: Option<String>) -> ReadOptions {
    ReadOptions {
        format: args.format.map(SurveyFormat::from),
        crs: args.crs.clone(),
        height: args.height.map(|h| match h {
            HeightArg::Orthometric => HeightChoice::Orthometric,
            HeightArg::Ellipsoidal => HeightChoice::Ellipsoidal,
        }),
        fix_only: args.fix_only,
        columns: args.columns.clone(),
        delimiter: args.delimiter,
        image_size: args.image_size,
        image: petrack_image,
    }
}

/// Reads another survey-like file (camera centres) with the CRS and height choices of `args`,
/// its format detected from its content.
pub(crate) fn read_other(file: &Path, args: &ReadArgs) -> anyhow::Result<Survey> {
    let mut o = read_options(args, None);
    o.format = None;
    o.columns = None;
    read(file, &o).map_err(bad_input)
}

/// A survey read, framed and (optionally) fitted.
struct Loaded {
    survey: Survey,
    frame: SiteFrame,
    local: Vec<Vector3<f64>>,
    fit: Option<FitReport>,
}

fn load(input: &Input) -> anyhow::Result<Loaded> {
    let Framed {
        survey,
        frame,
        local,
    } = read_framed(&input.file, &input.read, input.image.clone())?;
    let prefix = Some(input.read.check_prefix.as_str());
    let fit = match &input.fit_to {
        None => None,
        Some(ref_path) => {
            let ref_opts = ReadOptions {
                crs: input.fit_to_crs.clone(),
                ..ReadOptions::default()
            };
            let mut reference = read(ref_path, &ref_opts).map_err(bad_input)?;
            assign_roles(&mut reference, prefix, &[], &[]).map_err(bad_input)?;
            let ref_frame = SiteFrame::new(&reference, &Origin::Centroid).map_err(bad_input)?;
            let to_fit = |s: &Survey,
                          f: &SiteFrame,
                          local: Option<&[Vector3<f64>]>|
             -> anyhow::Result<Vec<FitPoint>> {
                s.points
                    .iter()
                    .enumerate()
                    .map(|(i, p)| {
                        let position = match local {
                            Some(l) => l[i],
                            None => f
                                .local_from_source(&p.position)
                                .map_err(|e| bad_input(anyhow!("{e}")))?,
                        };
                        Ok(FitPoint {
                            name: p.name.clone(),
                            role: p.role,
                            position,
                            sigma_m: p.sigma_m.map(|s| (s.norm_squared() / 3.0).sqrt()),
                        })
                    })
                    .collect()
            };
            let src = to_fit(&survey, &frame, Some(&local))?;
            let dst = to_fit(&reference, &ref_frame, None)?;
            let scale = if input.rigid {
                ScaleMode::Fixed
            } else {
                ScaleMode::Free
            };
            Some(
                helmert(&src, &dst, scale, input.robust)
                    .map_err(|e| bad_input(anyhow!("--fit-to {}: {e}", ref_path.display())))?,
            )
        }
    };
    Ok(Loaded {
        survey,
        frame,
        local,
        fit,
    })
}

pub fn run(cmd: Command) -> anyhow::Result<()> {
    match cmd {
        Command::Inspect { input, json } => {
            let l = load(&input)?;
            if json {
                println!("{}", serde_json::to_string_pretty(&json_report(&l))?);
            } else {
                print!("{}", table(&l));
            }
            Ok(())
        }
        Command::Convert {
            input,
            to,
            output,
            to_crs,
        } => {
            let inputs = std::iter::once(&input.file)
                .chain(&input.read.picks)
                .chain(&input.fit_to);
            check_output_file(&output, inputs)?;
            let l = load(&input)?;
            let notes = convert(&l, to, &output, to_crs.as_deref(), input.read.image_size)?;
            for w in &l.survey.warnings {
                eprintln!("warning: {w}");
            }
            for n in notes {
                eprintln!("note: {n}");
            }
            for d in &l.survey.dropped {
                eprintln!("dropped: line {}: {}", d.line, d.reason);
            }
            println!(
                "Written: {} ({} point(s), {} observation(s))",
                output.display(),
                l.survey.points.len(),
                l.survey.observation_count()
            );
            Ok(())
        }
    }
}

fn crs_label(l: &Loaded) -> String {
    match &l.frame.crs {
        Some(c) => c.label(),
        None => "none (the file's own local frame, metres)".into(),
    }
}

fn table(l: &Loaded) -> String {
    let s = &l.survey;
    let mut out = String::new();
    let _ = writeln!(
        out,
        "Survey {} ({} format)",
        s.source.display(),
        s.format.name()
    );
    let _ = writeln!(out, "  CRS: {}", crs_label(l));
    let _ = writeln!(out, "  heights: {}", s.height);
    match &l.frame.tangent {
        Some(t) => {
            let _ = writeln!(
                out,
                "  site frame: east-north-up, origin {:.8}°, {:.8}°, {:.3} m ({})",
                t.origin.lat.to_degrees(),
                t.origin.lon.to_degrees(),
                t.origin.h,
                l.frame.origin_note
            );
        }
        None => {
            let _ = writeln!(out, "  site frame: {}", l.frame.origin_note);
        }
    }
    let w = s
        .points
        .iter()
        .map(|p| p.name.chars().count())
        .max()
        .unwrap_or(0)
        .max(8);
    let _ = writeln!(
        out,
        "\n  {:<w$} {:<8} {:>11} {:>11} {:>9}  {:>6} {:>6} {:>6}  {:<7} {:>4}",
        "name", "role", "E (m)", "N (m)", "U (m)", "σE", "σN", "σU", "status", "obs"
    );
    for (p, loc) in s.points.iter().zip(&l.local) {
        let sig = p.sigma_m.map_or_else(
            || format!("{:>6} {:>6} {:>6}", "-", "-", "-"),
            |v| format!("{:>6.3} {:>6.3} {:>6.3}", v.x, v.y, v.z),
        );
        let _ = writeln!(
            out,
            "  {:<w$} {:<8} {:>11.3} {:>11.3} {:>9.3}  {}  {:<7} {:>4}",
            p.name,
            p.role,
            loc.x,
            loc.y,
            loc.z,
            sig,
            p.status
                .as_ref()
                .map_or_else(|| "-".to_string(), |x| x.to_string()),
            p.observations.len()
        );
    }
    let images: BTreeSet<&str> = s
        .points
        .iter()
        .flat_map(|p| p.observations.iter().map(|o| o.image.as_str()))
        .collect();
    let _ = writeln!(
        out,
        "\n  {} point(s): {} control, {} check, {} disabled; {} observation(s) in {} image(s)",
        s.points.len(),
        s.count(Role::Control),
        s.count(Role::Check),
        s.count(Role::Disabled),
        s.observation_count(),
        images.len()
    );
    if !s.dropped.is_empty() {
        let _ = writeln!(out, "  {} row(s) dropped:", s.dropped.len());
        for d in &s.dropped {
            let _ = writeln!(out, "    line {}: {}", d.line, d.reason);
        }
    }
    for w in &s.warnings {
        let _ = writeln!(out, "  warning: {w}");
    }
    if let Some(f) = &l.fit {
        let _ = writeln!(
            out,
            "\n  Helmert fit onto the reference: scale {:.8} ({:+.1} ppm ± {:.1}), rotation [{:.6} {:.6} {:.6}] rad, translation [{:.3} {:.3} {:.3}] m ± [{:.3} {:.3} {:.3}], σ0 {:.3}{}",
            f.scale,
            f.scale_ppm,
            f.std_dev[6] * 1e6,
            f.rotation_rad[0],
            f.rotation_rad[1],
            f.rotation_rad[2],
            f.translation_m[0],
            f.translation_m[1],
            f.translation_m[2],
            f.std_dev[3],
            f.std_dev[4],
            f.std_dev[5],
            f.sigma0,
            if f.robust { ", robust" } else { "" }
        );
        let _ = writeln!(
            out,
            "  {:<w$} {:<8} {:>9} {:>9} {:>9} {:>9}  weight",
            "name", "role", "dE (m)", "dN (m)", "dU (m)", "|d| (m)"
        );
        for r in &f.residuals {
            let _ = writeln!(
                out,
                "  {:<w$} {:<8} {:>9.4} {:>9.4} {:>9.4} {:>9.4}  {:.2}",
                r.name,
                r.role,
                r.residual_m[0],
                r.residual_m[1],
                r.residual_m[2],
                r.norm_m,
                r.robust_weight
            );
        }
        for (what, rmse) in [("control", &f.control), ("check", &f.check)] {
            match rmse {
                Some(r) => {
                    let _ = writeln!(
                        out,
                        "  RMSE {what} ({} points): E {:.4} N {:.4} U {:.4} horizontal {:.4} 3D {:.4} m",
                        r.count, r.east_m, r.north_m, r.up_m, r.horizontal_m, r.total_m
                    );
                }
                None => {
                    let _ = writeln!(out, "  RMSE {what}: no {what} points");
                }
            }
        }
        if !f.unmatched.is_empty() {
            let _ = writeln!(out, "  not in the fit: {}", f.unmatched.join(", "));
        }
    }
    out
}

#[derive(Serialize)]
struct JsonReport<'a> {
    source: &'a Path,
    format: SurveyFormat,
    crs: Option<&'a str>,
    crs_name: Option<String>,
    height: &'a HeightKind,
    frame: JsonFrame,
    points: Vec<JsonPoint<'a>>,
    counts: JsonCounts,
    dropped: &'a [geostride::survey::Dropped],
    warnings: &'a [String],
    fit: Option<&'a FitReport>,
}

#[derive(Serialize)]
struct JsonFrame {
    origin_lat_deg: Option<f64>,
    origin_lon_deg: Option<f64>,
    origin_h_m: Option<f64>,
    note: String,
}

#[derive(Serialize)]
struct JsonPoint<'a> {
    #[serde(flatten)]
    gcp: &'a geostride::survey::Gcp,
    local_enu_m: [f64; 3],
}

#[derive(Serialize)]
struct JsonCounts {
    points: usize,
    control: usize,
    check: usize,
    disabled: usize,
    observations: usize,
    images: usize,
}

fn json_report(l: &Loaded) -> JsonReport<'_> {
    let s = &l.survey;
    let t = l.frame.tangent.as_ref();
    let images: BTreeSet<&str> = s
        .points
        .iter()
        .flat_map(|p| p.observations.iter().map(|o| o.image.as_str()))
        .collect();
    JsonReport {
        source: &s.source,
        format: s.format,
        crs: s.crs.as_deref(),
        crs_name: l.frame.crs.as_ref().map(Crs::label),
        height: &s.height,
        frame: JsonFrame {
            origin_lat_deg: t.map(|t| t.origin.lat.to_degrees()),
            origin_lon_deg: t.map(|t| t.origin.lon.to_degrees()),
            origin_h_m: t.map(|t| t.origin.h),
            note: l.frame.origin_note.clone(),
        },
        points: s
            .points
            .iter()
            .zip(&l.local)
            .map(|(g, loc)| JsonPoint {
                gcp: g,
                local_enu_m: (*loc).into(),
            })
            .collect(),
        counts: JsonCounts {
            points: s.points.len(),
            control: s.count(Role::Control),
            check: s.count(Role::Check),
            disabled: s.count(Role::Disabled),
            observations: s.observation_count(),
            images: images.len(),
        },
        dropped: &s.dropped,
        warnings: &s.warnings,
        fit: l.fit.as_ref(),
    }
}

/// The points' positions converted from `src` to `dst` (heights written unchanged; a change of
/// height kind refused), with a note when the datum changes.
fn converted_positions(
    points: &[geostride::survey::Gcp],
    height: &HeightKind,
    src: &Crs,
    dst: &Crs,
    notes: &mut Vec<String>,
) -> anyhow::Result<Vec<Vector3<f64>>> {
    if let (k, HeightKind::Orthometric(_) | HeightKind::Ellipsoidal) = (height, &dst.height_kind) {
        let same = matches!(
            (k, &dst.height_kind),
            (HeightKind::Ellipsoidal, HeightKind::Ellipsoidal)
                | (HeightKind::Orthometric(_), HeightKind::Orthometric(_))
        );
        if !same {
            return Err(bad_input(anyhow!(
                "the target CRS {} has {} heights but the survey's are {}; geostride does not convert heights between kinds",
                dst.label(),
                dst.height_kind,
                k
            )));
        }
    }
    if src.geodetic_name != dst.geodetic_name {
        notes.push(format!(
            "the datum changes ({} -> {}): PROJ's best available transformation is used; without its grid files it can be off by up to a metre",
            src.geodetic_name, dst.geodetic_name
        ));
    }
    let t = Transform::new(src, dst).map_err(bad_input)?;
    let positions = points
        .iter()
        .map(|p| {
            // The height goes through the operation as cs2cs takes it (a datum's
            // rotation moves a point by its height's lever); it is written unchanged.
            let h = if p.position.z.is_finite() {
                p.position.z
            } else {
                0.0
            };
            t.apply_3d(p.position.x, p.position.y, h)
                .map(|(x, y, _)| Vector3::new(x, y, p.position.z))
        })
        .collect::<Result<_, _>>()
        .map_err(bad_input)?;
    Ok(positions)
}

/// Writes the converted survey; returns notes for the user.
fn convert(
    l: &Loaded,
    to: OutFormat,
    output: &Path,
    to_crs: Option<&str>,
    image_size: Option<(u32, u32)>,
) -> anyhow::Result<Vec<String>> {
    let s = &l.survey;
    let mut notes = Vec::new();
    let needs_wgs84 = matches!(to, OutFormat::Geojson | OutFormat::Opensfm);
    let target_spec = match (needs_wgs84, to_crs) {
        (true, Some(c))
            if Crs::new(c)
                .map(|c| c.id.as_deref() != Some("EPSG:4326"))
                .unwrap_or(true) =>
        {
            return Err(bad_input(anyhow!(
                "{to:?} output is always in WGS 84 longitude/latitude (EPSG:4326); drop --to-crs"
            )));
        }
        (true, _) => Some("EPSG:4326".to_string()),
        (false, Some(c)) => Some(c.to_string()),
        (false, None) => s.crs.clone(),
    };
    let source_crs = l.frame.crs.as_ref();
    let target_crs = match &target_spec {
        Some(spec) => Some(Crs::new(spec).map_err(bad_input)?),
        None => None,
    };
    let positions: Vec<Vector3<f64>> = match (source_crs, &target_crs) {
        (None, Some(_)) if !matches!(to, OutFormat::Petrack) => {
            return Err(bad_input(anyhow!(
                "{} is in its own local frame, so it cannot be written in a CRS ({:?} output); choose csv, metashape, petrack or gpkg",
                s.source.display(),
                to
            )));
        }
        (Some(src), Some(dst)) if src.spec != dst.spec => {
            converted_positions(&s.points, &s.height, src, dst, &mut notes)?
        }
        _ => s.points.iter().map(|p| p.position).collect(),
    };
    let out_crs = OutCrs {
        spec: target_crs.as_ref().map(|c| {
            c.id.clone()
                .unwrap_or_else(|| geostride::survey::crs::normalise_spec(&c.spec))
        }),
        name: target_crs
            .as_ref()
            .map(|c| c.name.clone())
            .unwrap_or_else(|| "local".into()),
        projected: target_crs
            .as_ref()
            .is_some_and(|c| c.horizontal == Horizontal::Projected),
        height: s.height.clone(),
    };
    let points: Vec<OutPoint> = s
        .points
        .iter()
        .zip(&positions)
        .zip(&l.local)
        .map(|((g, pos), local)| OutPoint {
            gcp: g,
            position: *pos,
            lon_lat: target_crs
                .as_ref()
                .and_then(|c| c.to_lon_lat(pos.x, pos.y).ok()),
            local: *local,
            residual: l
                .fit
                .as_ref()
                .and_then(|f| f.residuals.iter().find(|r| r.name == g.name)),
        })
        .collect();
    let text = match to {
        OutFormat::Odm => Some(write::odm(&out_crs, &points)),
        OutFormat::Opensfm => Some(write::opensfm(&points, image_size)),
        OutFormat::Metashape => Some(Ok(write::metashape(&out_crs, &points))),
        OutFormat::Petrack => Some(write::petrack(&points)),
        OutFormat::Emlid => Some(write::emlid(&out_crs, &points)),
        OutFormat::Csv => Some(Ok(write::csv(&points))),
        OutFormat::Geojson | OutFormat::Gpkg => None,
    };
    match text {
        Some(t) => {
            let t = t.map_err(|e| bad_input(anyhow!("{}: {e}", output.display())))?;
            geostride::io::write_atomic(output, t.as_bytes())
                .map_err(|e| anyhow!("{}: {e}", output.display()))?;
        }
        None => {
            let format = if matches!(to, OutFormat::Geojson) {
                GisFormat::GeoJson
            } else {
                GisFormat::GeoPackage
            };
            let wkt = target_crs
                .as_ref()
                .map(|c| c.wkt.clone())
                .unwrap_or_default();
            if matches!(to, OutFormat::Gpkg) && target_crs.is_none() {
                notes
                    .push("the GeoPackage has no CRS: the survey is in its own local frame".into());
            }
            write_points(output, format, &wkt, &s.height.to_string(), &points)
                .map_err(|e| anyhow!(e))?;
        }
    }
    if matches!(to, OutFormat::Metashape) && s.count(Role::Disabled) > 0 {
        notes.push(format!(
            "{} disabled point(s) not written: Metashape has no disabled state",
            s.count(Role::Disabled)
        ));
    }
    if matches!(to, OutFormat::Odm) {
        let without = s
            .points
            .iter()
            .filter(|p| p.observations.is_empty())
            .count();
        if without > 0 {
            notes.push(format!(
                "{without} point(s) without image picks have no row in a gcp_list.txt"
            ));
        }
    }
    Ok(notes)
}
