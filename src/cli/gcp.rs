//! `geostride gcp find`: ground control targets found in photos or video frames and identified
//! (from their layout, or a coded marker's id), written as picks.

use std::fmt::Write as _;
use std::path::{Path, PathBuf};

use anyhow::{Context, anyhow};
use serde::Serialize;

use super::survey::{ReadArgs, read_framed};
use super::{bad_input, check_output_file};
mod http;
mod pick;

use geostride::targets::codes::CodeTable;
use geostride::targets::search::Search;
use geostride::targets::{Gray, LayoutSettings, TargetSettings};

#[derive(clap::Subcommand)]
pub enum Command {
    /// Find GCP targets (checker, X, cross, ArUco/AprilTag markers) in photos or a video
    /// frame, tell which surveyed point each is (from their layout, or a marker's id), and
    /// write the picks
    Find(FindArgs),
    /// Serve the picking page on 127.0.0.1: confirm, move or reject picks, place missing ones,
    /// see each pick's residual against a live fit, and save the picks CSV
    Pick(pick::PickArgs),
}

#[derive(clap::Args)]
pub struct FindArgs {
    /// Photos (any format OpenCV reads) or videos (.mp4, .mov, .avi, .mkv, .m4v, .mts: the
    /// frame --frame is searched)
    #[arg(required = true, value_name = "IMAGE-OR-VIDEO")]
    inputs: Vec<PathBuf>,
    /// Ground control points: any survey file `geostride survey` reads
    #[arg(long, value_name = "FILE")]
    gcps: PathBuf,
    #[command(flatten)]
    read: ReadArgs,
    /// The video frame to search, from 0; its picks are named 'VIDEO#N' as `pose` reads them
    #[arg(long, default_value = "0", value_name = "N")]
    frame: usize,
    #[command(flatten)]
    search: SearchArgs,
    /// The picks CSV to write (name,image,u,v,sigma)
    #[arg(long, value_name = "FILE")]
    out: PathBuf,
    /// Print the report as JSON
    #[arg(long)]
    json: bool,
}

/// A target design `--design` names.
#[derive(Clone, Copy, Debug, PartialEq, Eq, clap::ValueEnum)]
pub(crate) enum Design {
    Checker,
    X,
    Cross,
    /// ArUco or AprilTag markers (--dictionary), each id a surveyed point (--codes)
    Coded,
}

/// How targets are searched for and told apart: the options of `gcp find` and `gcp pick
/// --find`.
#[derive(clap::Args)]
pub(crate) struct SearchArgs {
    /// Where the image's top points, a bearing in degrees from north through east, with a
    /// tolerance (default 45): needed when the targets' layout is symmetric
    #[arg(long, value_parser = parse_heading, value_name = "DEG[:TOL]")]
    heading: Option<(f64, f64)>,
    /// Least difference between a target's white and black quadrants, grey levels
    #[arg(long, default_value = "40", value_name = "LEVELS")]
    min_contrast: f64,
    /// The target designs to look for, comma-separated: checker (four quadrants), x (a
    /// bow-tie), cross (a white cross on a black square), coded (ArUco or AprilTag markers)
    #[arg(
        long,
        value_delimiter = ',',
        default_value = "checker,x",
        value_name = "DESIGNS"
    )]
    design: Vec<Design>,
    /// The coded markers' dictionary: 4x4_50 ... 7x7_1000, aruco_original, apriltag_16h5,
    /// apriltag_25h9, apriltag_36h10, apriltag_36h11
    #[arg(long, default_value = "4x4_50", value_name = "NAME")]
    dictionary: geostride::targets::codes::Dictionary,
    /// Which surveyed point each marker id is: a CSV of 'id,name' lines. Without it, id N is
    /// the point named N, else the one point whose name ends in the number N (GCP7, T07)
    #[arg(long, value_name = "FILE")]
    codes: Option<PathBuf>,
}

/// A search made ready: the surveyed points' names and ground positions, and the settings.
pub(crate) struct Searcher(Search);

impl Searcher {
    /// The search `args` ask for, over the points of `framed` (`gcps` names the file in
    /// errors). A code table that cannot be read, or names a point the survey lacks, is bad
    /// input.
    pub(crate) fn new(
        framed: &geostride::survey::load::Framed,
        args: &SearchArgs,
    ) -> anyhow::Result<Searcher> {
        let designs = &args.design;
        let names: Vec<String> = framed
            .survey
            .points
            .iter()
            .map(|p| p.name.clone())
            .collect();
        let coded = match (designs.contains(&Design::Coded), &args.codes) {
            (false, Some(_)) => {
                return Err(bad_input(anyhow!(
                    "--codes is for coded markers: add 'coded' to --design"
                )));
            }
            (false, None) => None,
            (true, None) => Some((args.dictionary, CodeTable::from_names(&names))),
            (true, Some(path)) => {
                let table = CodeTable::read(path, &names, &args.dictionary)
                    .map_err(|e| bad_input(anyhow!(e)))?;
                Some((args.dictionary, table))
            }
        };
        Ok(Searcher(Search {
            names,
            ground: framed.local.iter().map(|p| p.xy()).collect(),
            by_layout: designs.iter().any(|d| *d != Design::Coded),
            coded,
            // Checker and X are both saddles.
            targets: TargetSettings {
                min_contrast: args.min_contrast,
                saddles: designs
                    .iter()
                    .any(|d| matches!(d, Design::Checker | Design::X)),
                crosses: designs.contains(&Design::Cross),
                ..TargetSettings::default()
            },
            layout: LayoutSettings {
                heading_deg: args.heading,
                ..LayoutSettings::default()
            },
        }))
    }
}

fn parse_heading(s: &str) -> Result<(f64, f64), String> {
    let (d, t) = s.split_once(':').unwrap_or((s, "45"));
    let d: f64 = d
        .trim()
        .parse()
        .map_err(|_| format!("'{s}': a bearing in degrees, e.g. 0 or 90:30"))?;
    let t: f64 = t
        .trim()
        .parse()
        .map_err(|_| format!("'{s}': the tolerance after ':' is not a number"))?;
    if !(d.is_finite() && t > 0.0 && t <= 180.0) {
        return Err(format!(
            "'{s}': a finite bearing and a tolerance in (0, 180] degrees"
        ));
    }
    Ok((d, t))
}

pub fn run(cmd: Command) -> anyhow::Result<()> {
    match cmd {
        Command::Find(args) => find(&args),
        Command::Pick(args) => pick::pick(&args),
    }
}

#[derive(Serialize)]
struct ImageReport {
    image: String,
    width: usize,
    height: usize,
    /// The bearing of the image's top the layout was matched with, degrees, and where it came
    /// from (`--heading`, or the photo's XMP gimbal yaw).
    heading_deg: Option<f64>,
    heading_from: Option<String>,
    targets: Vec<TargetReport>,
    identified: usize,
    /// Why nothing was identified, when so.
    not_identified: Option<String>,
    rejected: Vec<RejectedReport>,
}

#[derive(Serialize)]
struct TargetReport {
    u: f64,
    v: f64,
    sigma_px: f64,
    contrast: f64,
    size_px: f64,
    /// The surveyed point it is, when identified.
    name: Option<String>,
    residual_px: Option<f64>,
    /// A coded marker's id.
    code: Option<u32>,
}

#[derive(Serialize)]
struct RejectedReport {
    u: f64,
    v: f64,
    reason: String,
}

const VIDEO_EXTENSIONS: [&str; 6] = ["mp4", "mov", "avi", "mkv", "m4v", "mts"];

fn is_video(path: &Path) -> bool {
    path.extension()
        .and_then(|e| e.to_str())
        .is_some_and(|e| VIDEO_EXTENSIONS.contains(&e.to_ascii_lowercase().as_str()))
}

/// The image to search and the name its picks carry.
fn load(path: &Path, frame: usize) -> anyhow::Result<(Gray, String)> {
    let (bytes, w, h, name) = load_bgr(path, frame)?;
    Ok((Gray::from_bgr(&bytes, w, h), name))
}

/// A photo, or a video's frame `frame`, as BGR bytes, width, height and the name its picks
/// carry (a video's frames are 'VIDEO#N').
fn load_bgr(path: &Path, frame: usize) -> anyhow::Result<(Vec<u8>, usize, usize, String)> {
    let file_name = path
        .file_name()
        .and_then(|n| n.to_str())
        .ok_or_else(|| bad_input(anyhow!("{}: not a file name", path.display())))?
        .to_string();
    if is_video(path) {
        let (bytes, w, h) = geostride::video::source::FrameReader::frame_bgr_bytes(path, frame)
            .map_err(|e| bad_input(anyhow!("{}: {e}", path.display())))?;
        Ok((bytes, w, h, format!("{file_name}#{frame}")))
    } else {
        let (bytes, w, h) = geostride::imageio::read_bgr_bytes(path).map_err(bad_input)?;
        Ok((bytes, w, h, file_name))
    }
}

/// Tolerance on a heading taken from a photo's gimbal yaw, degrees: the gimbal's compass errs by
/// a few degrees, a view from aside turns the layout's image further.
const XMP_HEADING_TOLERANCE_DEG: f64 = 30.0;

/// The bearing of a photo's top from its DJI XMP gimbal yaw, when the gimbal looks down at
/// least 45° (nearer the horizon the layout's image is too foreshortened for a heading to help
/// much, and the roll would matter).
fn xmp_heading(photo: &Path) -> Option<(f64, f64)> {
    if is_video(photo) {
        return None;
    }
    let [yaw, pitch, _] = geostride::sfm::exif::read_meta(photo)
        .ok()?
        .gimbal_ypr_deg?;
    (pitch <= -45.0).then_some((yaw.rem_euclid(360.0), XMP_HEADING_TOLERANCE_DEG))
}

/// How far from every surveyed point a photo's EXIF GPS may lie before the survey is taken for
/// another area's, km (a drone photo sees a few hundred metres; GPS errs by metres).
const AREA_KM: f64 = 5.0;

/// A photo whose EXIF GPS lies far from every surveyed point: the survey of another area is
/// bad input. Videos, photos without GPS and surveys in their own local frame pass unchecked.
pub(crate) fn check_area(
    framed: &geostride::survey::load::Framed,
    gcps: &Path,
    photo: &Path,
) -> anyhow::Result<()> {
    if is_video(photo) || framed.local.is_empty() {
        return Ok(());
    }
    // An unreadable photo is reported when it is loaded.
    let Some(gps) = geostride::sfm::exif::read_meta(photo)
        .ok()
        .and_then(|m| m.gps)
    else {
        return Ok(());
    };
    let Some(at) = framed.frame.local_from_lat_lon(gps.lat_deg, gps.lon_deg) else {
        return Ok(());
    };
    let nearest_m = framed
        .local
        .iter()
        .map(|p| (p.xy() - at).norm())
        .fold(f64::INFINITY, f64::min);
    if nearest_m > AREA_KM * 1000.0 {
        return Err(bad_input(anyhow!(
            "{}: taken at latitude {:.5}, longitude {:.5} (its EXIF GPS), {:.0} km from the \
             nearest point of {}: the survey of another area? Give this site's GCP file",
            photo.display(),
            gps.lat_deg,
            gps.lon_deg,
            nearest_m / 1000.0,
            gcps.display()
        )));
    }
    Ok(())
}

fn find(args: &FindArgs) -> anyhow::Result<()> {
    let mut inputs: Vec<&Path> = args.inputs.iter().map(PathBuf::as_path).collect();
    inputs.push(&args.gcps);
    inputs.extend(args.read.picks.iter().map(PathBuf::as_path));
    check_output_file(&args.out, &inputs)?;
    let framed = read_framed(&args.gcps, &args.read, None).map_err(bad_input)?;
    for path in &args.inputs {
        check_area(&framed, &args.gcps, path)?;
    }
    let searcher = Searcher::new(&framed, &args.search)?;
    if searcher.0.by_layout && searcher.0.ground.len() < 4 {
        return Err(bad_input(anyhow!(
            "{}: {} points; telling targets apart by their layout needs at least four",
            args.gcps.display(),
            searcher.0.ground.len()
        )));
    }
    let mut csv = String::from("name,image,u,v,sigma\n");
    let mut reports = Vec::new();
    for path in &args.inputs {
        let (gray, image) = load(path, args.frame)?;
        let report = searcher.search(&gray, image, path);
        for t in &report.targets {
            if let Some(name) = &t.name {
                let _ = writeln!(
                    csv,
                    "{name},{},{:.3},{:.3},{:.3}",
                    report.image, t.u, t.v, t.sigma_px
                );
            }
        }
        reports.push(report);
    }
    let picked: usize = reports.iter().map(|r| r.identified).sum();
    if args.json {
        println!("{}", serde_json::to_string_pretty(&reports)?);
    } else {
        print!("{}", text_report(&reports));
    }
    if picked == 0 {
        return Err(anyhow!(
            "no target identified in {} image(s); nothing written (see the report above)",
            reports.len()
        ));
    }
    geostride::io::write_atomic(&args.out, csv.as_bytes())
        .with_context(|| format!("writing {}", args.out.display()))?;
    if !args.json {
        println!("Written: {} ({picked} picks)", args.out.display());
    }
    Ok(())
}

impl Searcher {
    /// The targets of one image (from `path`: a photo's XMP may give its heading), and which
    /// point each is.
    fn search(&self, gray: &Gray, image: String, path: &Path) -> ImageReport {
        let (heading, heading_from) = match self.0.layout.heading_deg {
            Some(h) => (Some(h), Some("--heading".to_string())),
            None => match xmp_heading(path) {
                Some(h) => (Some(h), Some("the photo's XMP gimbal yaw".to_string())),
                None => (None, None),
            },
        };
        let out = if heading == self.0.layout.heading_deg {
            self.0.run(gray)
        } else {
            let mut search = self.0.clone();
            search.layout.heading_deg = heading;
            search.run(gray)
        };
        ImageReport {
            image,
            width: gray.width,
            height: gray.height,
            heading_deg: heading.map(|h| h.0),
            heading_from,
            targets: out
                .found
                .into_iter()
                .map(|t| TargetReport {
                    u: t.uv.x,
                    v: t.uv.y,
                    sigma_px: t.sigma_px,
                    contrast: t.contrast,
                    size_px: t.size_px,
                    name: t.point.map(|k| self.0.names[k].clone()),
                    residual_px: t.residual_px,
                    code: t.code,
                })
                .collect(),
            identified: out.named.len(),
            not_identified: out.not_identified,
            rejected: out
                .rejected
                .into_iter()
                .map(|r| RejectedReport {
                    u: r.uv.x,
                    v: r.uv.y,
                    reason: r.reason,
                })
                .collect(),
        }
    }
}

fn text_report(reports: &[ImageReport]) -> String {
    let mut s = String::new();
    for r in reports {
        let _ = writeln!(
            s,
            "{} ({}x{}): {} targets, {} identified{}",
            r.image,
            r.width,
            r.height,
            r.targets.len(),
            r.identified,
            match (&r.heading_deg, &r.heading_from) {
                (Some(h), Some(from)) => format!(" (heading {h:.1}° from {from})"),
                _ => String::new(),
            }
        );
        for t in &r.targets {
            let _ = writeln!(
                s,
                "  {:<12} ({:8.2}, {:8.2})  σ {:.2} px  size {:.0} px  contrast {:.0}{}",
                t.name.as_deref().unwrap_or("?"),
                t.u,
                t.v,
                t.sigma_px,
                t.size_px,
                t.contrast,
                t.residual_px
                    .map_or(String::new(), |e| format!("  residual {e:.2} px"))
                    + &t.code.map_or(String::new(), |c| format!("  marker {c}"))
            );
        }
        if let Some(why) = &r.not_identified {
            let _ = writeln!(s, "  not identified: {why}");
        }
        if !r.rejected.is_empty() {
            let _ = writeln!(s, "  {} places refused:", r.rejected.len());
            for x in r.rejected.iter().take(8) {
                let _ = writeln!(s, "    ({:8.2}, {:8.2})  {}", x.u, x.v, x.reason);
            }
            if r.rejected.len() > 8 {
                let _ = writeln!(
                    s,
                    "    ... and {} more (--json lists all)",
                    r.rejected.len() - 8
                );
            }
        }
    }
    s
}
