//! The project file (TOML): everything a run needs, paths relative to the file. Unknown keys and
//! bad values are errors that name the key and its line.

use std::path::{Path, PathBuf};

use serde::{Deserialize, Serialize};

use crate::io::{FileCtx, FileError};

use super::settings::GroundInput;
pub use super::settings::GroundSection;
use super::settings::with_default_kind;
pub use super::settings::{
    AssociationSection, BackgroundSection, BodySettings, BoxesSection, ColourSection,
    DetectSection, HoverSettings, KalmanRtsSection, KltSection, ModelSettings, NoSmoothing,
    PoseSection, SmoothSection, TrackSection,
};

/// The whole project.
#[derive(Clone, Debug, Deserialize, Serialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct Project {
    #[serde(default)]
    pub name: String,
    pub camera: CameraSection,
    /// Required but for a fixed camera (`[pose] kind = "fixed"`).
    #[serde(default)]
    pub survey: SurveySection,
    pub video: VideoSection,
    /// Picks found in the video instead of read from `survey.picks`.
    #[serde(default, skip_serializing_if = "PicksSection::is_off")]
    pub picks: PicksSection,
    #[serde(default, deserialize_with = "with_default_kind")]
    pub pose: PoseSection,
    pub ground: GroundSection,
    #[serde(default, deserialize_with = "with_default_kind")]
    pub detect: DetectSection,
    #[serde(default, deserialize_with = "with_default_kind")]
    pub track: TrackSection,
    #[serde(default)]
    pub projection: ProjectionSection,
    #[serde(default, deserialize_with = "with_default_kind")]
    pub smooth: SmoothSection,
    #[serde(default)]
    pub export: ExportSection,
    #[serde(default)]
    pub output: OutputSection,
    #[serde(default)]
    pub analysis: AnalysisSection,
}

#[derive(Clone, Debug, Deserialize, Serialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct CameraSection {
    /// A calibration file or a preset name; scaled to the video's size.
    pub calibration: String,
}

#[derive(Clone, Debug, Deserialize, Serialize, PartialEq)]
#[serde(default, deny_unknown_fields)]
pub struct SurveySection {
    /// The GCP file (any format `geostride survey` reads); required.
    pub gcps: String,
    /// Pick files `name,image,u,v[,sigma]`; the image is `VIDEO#N` for frame N.
    pub picks: Vec<String>,
    /// The GCP file's CRS when it does not say, or to override it.
    pub crs: Option<String>,
    /// `ellipsoidal` or `orthometric`.
    pub height: Option<String>,
    /// Site frame origin: `centroid`, `point:NAME` or `LAT,LON,H`.
    pub origin: Option<String>,
    pub check: Vec<String>,
    pub check_prefix: String,
    pub pick_sigma_px: f64,
    pub gcp_sigma_m: f64,
}

/// `[picks] auto = true`: the GCP targets found in the picked frame (`geostride gcp find`:
/// checker targets, identified from their layout) instead of read from pick files.
#[derive(Clone, Debug, Deserialize, Serialize, PartialEq)]
#[serde(default, deny_unknown_fields)]
pub struct PicksSection {
    pub auto: bool,
    /// The image's rough bearing (degrees from north through east of its top edge): a
    /// symmetric layout of targets is told apart only with it.
    pub heading_deg: Option<f64>,
    pub heading_tolerance_deg: f64,
    /// Least difference between a target's white and black quadrants, grey levels.
    pub min_contrast: f64,
    /// The target designs to look for.
    pub designs: Vec<TargetDesignName>,
    /// Coded markers' dictionary (`geostride gcp find --dictionary`'s names).
    pub dictionary: String,
    /// Which point each marker id is: a CSV of `id,name` lines (else id N names the point N,
    /// or the one point whose name ends in N).
    pub codes: Option<String>,
}

/// A GCP target design `[picks] designs` names.
#[derive(Clone, Copy, Debug, Deserialize, Serialize, PartialEq, Eq)]
#[serde(rename_all = "lowercase")]
pub enum TargetDesignName {
    /// Four quadrants, two black and two white.
    Checker,
    /// A bow-tie: two black and two white triangles.
    X,
    /// A white cross on a black square.
    Cross,
    /// ArUco or AprilTag markers, named by their ids.
    Coded,
}

impl Default for PicksSection {
    fn default() -> Self {
        PicksSection {
            auto: false,
            heading_deg: None,
            heading_tolerance_deg: 45.0,
            min_contrast: 40.0,
            designs: vec![TargetDesignName::Checker, TargetDesignName::X],
            dictionary: "4x4_50".into(),
            codes: None,
        }
    }
}

impl PicksSection {
    fn is_off(&self) -> bool {
        *self == PicksSection::default()
    }
}

impl SurveySection {
    /// The GCP file `gcps` with every other key at its default.
    pub fn new(gcps: &str) -> SurveySection {
        SurveySection {
            gcps: gcps.into(),
            ..SurveySection::default()
        }
    }
}

impl Default for SurveySection {
    fn default() -> Self {
        SurveySection {
            gcps: String::new(),
            picks: Vec::new(),
            crs: None,
            height: None,
            origin: None,
            check: Vec::new(),
            check_prefix: "CHK-".into(),
            pick_sigma_px: 1.0,
            gcp_sigma_m: 0.02,
        }
    }
}

#[derive(Clone, Debug, Deserialize, Serialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct VideoSection {
    pub path: String,
    /// Process only the first this many seconds.
    #[serde(default)]
    pub duration_s: Option<f64>,
    /// The video is processed in chunks of this many seconds, each on its own (one machine
    /// runs them in turn; `geostride split` hands them to a cluster): the same results either
    /// way.
    #[serde(default = "default_chunk_s")]
    pub chunk_s: f64,
    /// Each chunk is tracked from this many seconds before its start, to join its tracks to
    /// the chunk before's.
    #[serde(default = "default_overlap_s")]
    pub overlap_s: f64,
    /// The drone's flight telemetry beside the video (DJI's `.SRT`): each frame's camera
    /// centre is checked against its position (`pose/telemetry.csv`), and a moving camera's
    /// key frames are matched with the model photos nearest it.
    #[serde(default)]
    pub telemetry: Option<String>,
    /// σ of the telemetry's horizontal positions about their common offset, metres.
    #[serde(default = "default_telemetry_sigma_m")]
    pub telemetry_sigma_m: f64,
    /// What the telemetry's `abs_alt` is above: "ellipsoidal" (WGS 84) or "egm96" (the geoid,
    /// "above sea level", DJI's consumer drones). DJI's files do not say: unset, heights are not
    /// compared.
    #[serde(default)]
    pub telemetry_height: Option<String>,
    /// σ of the telemetry's heights about their common offset, metres.
    #[serde(default = "default_telemetry_sigma_vertical_m")]
    pub telemetry_sigma_vertical_m: f64,
}

impl VideoSection {
    /// The whole video at `path`, in the default chunks.
    pub fn new(path: impl Into<String>) -> VideoSection {
        VideoSection {
            path: path.into(),
            duration_s: None,
            chunk_s: default_chunk_s(),
            overlap_s: default_overlap_s(),
            telemetry: None,
            telemetry_sigma_m: default_telemetry_sigma_m(),
            telemetry_height: None,
            telemetry_sigma_vertical_m: default_telemetry_sigma_vertical_m(),
        }
    }
}

fn default_telemetry_sigma_m() -> f64 {
    1.5
}

fn default_telemetry_sigma_vertical_m() -> f64 {
    3.0
}

fn default_chunk_s() -> f64 {
    10.0
}

fn default_overlap_s() -> f64 {
    1.0
}

#[derive(Clone, Debug, Deserialize, Serialize, PartialEq)]
#[serde(default, deny_unknown_fields)]
pub struct ProjectionSection {
    /// Head height above the ground when a person's is not known, metres, and its σ.
    pub head_height_m: f64,
    pub head_height_sd_m: f64,
    /// CSV `id,height_m[,sd_m]` of known heights by track id.
    pub heights: Option<String>,
}

impl Default for ProjectionSection {
    fn default() -> Self {
        ProjectionSection {
            head_height_m: 1.7,
            head_height_sd_m: 0.1,
            heights: None,
        }
    }
}

#[derive(Clone, Debug, Deserialize, Serialize, PartialEq)]
#[serde(default, deny_unknown_fields)]
pub struct ExportSection {
    /// Output CRS [default: the GCP file's].
    pub crs: Option<String>,
    /// Names of [`crate::export::ExportFormat`]s [default: all of them].
    pub formats: Vec<String>,
}

impl Default for ExportSection {
    fn default() -> Self {
        ExportSection {
            crs: None,
            formats: crate::export::ExportFormat::ALL
                .map(|f| f.name().to_string())
                .to_vec(),
        }
    }
}

/// What a run shows besides its data files: the annotated video, the rectified site image and
/// the report's plots.
#[derive(Clone, Debug, Deserialize, Serialize, PartialEq)]
#[serde(default, deny_unknown_fields)]
pub struct OutputSection {
    /// `annotated.mp4`: heads, identities, tracks and their 95 % ellipses over the video
    /// (a second decoding pass: off by default; `geostride render RUN_DIR` makes it later).
    pub video: bool,
    /// The annotated video's largest width, pixels (the video's own when narrower).
    pub video_width: u32,
    /// Seconds of each track drawn behind its head.
    pub trail_s: f64,
    /// `site.tif` (in the output CRS) and `site.png` with the trajectories.
    pub site_image: bool,
    /// The site image's ground sample distance, metres [default: the video's at the ground,
    /// rounded up to 1, 2 or 5 times a power of ten].
    pub site_gsd_m: Option<f64>,
    /// The report's plots (`plots/*.png`) and the measures they show (`measures.csv`).
    pub plots: bool,
}

impl Default for OutputSection {
    fn default() -> Self {
        OutputSection {
            video: false,
            video_width: 1920,
            trail_s: 3.0,
            site_image: true,
            site_gsd_m: None,
            plots: true,
        }
    }
}

/// Where the density and speed of the fundamental diagram are measured (PedPy's definitions).
#[derive(Clone, Debug, Default, Deserialize, Serialize, PartialEq)]
#[serde(default, deny_unknown_fields)]
pub struct AnalysisSection {
    /// A convex polygon in the site frame, `[[e, n], ...]` metres; none: no fundamental diagram.
    pub measurement_area: Vec<[f64; 2]>,
    /// The convex area people can walk in (Voronoi cells end at its edge) [default: a deck's
    /// outline, else the trajectories' bounding box, 1 m wider on every side].
    pub walkable_area: Vec<[f64; 2]>,
    /// Lines across the flow, `[[[e, n], [e, n]], ...]` in the site frame, metres: written
    /// for PedPy's line measures (`measurement_lines.wkt`, `areas.geojson`).
    pub measurement_lines: Vec<[[f64; 2]; 2]>,
}

impl AnalysisSection {
    /// The measurement and walkable areas as polygons (either may be absent); the key and what
    /// is wrong otherwise.
    pub(crate) fn polygons(
        &self,
    ) -> Result<
        (
            Option<crate::analysis::ConvexPolygon>,
            Option<crate::analysis::ConvexPolygon>,
        ),
        (&'static str, String),
    > {
        let poly = |key: &'static str, v: &[[f64; 2]]| {
            if v.is_empty() {
                return Ok(None);
            }
            crate::analysis::ConvexPolygon::new(
                v.iter()
                    .map(|p| nalgebra::Vector2::new(p[0], p[1]))
                    .collect(),
            )
            .map(Some)
            .map_err(|m| {
                (
                    key,
                    format!("{m} (a convex polygon [[e, n], ...] in the site frame, metres)"),
                )
            })
        };
        let m = poly("measurement_area", &self.measurement_area)?;
        let w = poly("walkable_area", &self.walkable_area)?;
        if let (Some(m), Some(w)) = (&m, &w)
            && m.vertices().iter().any(|v| !w.contains(v))
        {
            return Err((
                "measurement_area",
                "the measurement area must lie inside the walkable area".into(),
            ));
        }
        Ok((m, w))
    }

    /// The measurement lines, checked: finite ends at least 1 cm apart.
    pub(crate) fn lines(&self) -> Result<Vec<[nalgebra::Vector2<f64>; 2]>, (&'static str, String)> {
        self.measurement_lines
            .iter()
            .enumerate()
            .map(|(k, [a, b])| {
                let (a, b) = (
                    nalgebra::Vector2::new(a[0], a[1]),
                    nalgebra::Vector2::new(b[0], b[1]),
                );
                if !(a.iter().chain(b.iter()).all(|v| v.is_finite()) && (a - b).norm() >= 0.01) {
                    return Err((
                        "measurement_lines",
                        format!(
                            "line {} is not two distinct points (each line is [[e, n], [e, n]] in the site frame, metres)",
                            k + 1
                        ),
                    ));
                }
                Ok([a, b])
            })
            .collect()
    }
}

/// The line of `section.key` (or of `[section]` when `key` is empty) in a TOML text.
pub(crate) fn key_line(text: &str, section: &str, key: &str) -> Option<usize> {
    let mut current = String::new();
    for (i, line) in text.lines().enumerate() {
        let l = line.trim();
        if let Some(h) = l.strip_prefix('[').and_then(|h| h.strip_suffix(']')) {
            current = h.trim_matches(|c| c == '[' || c == ']').trim().to_string();
            if key.is_empty() && current == section {
                return Some(i + 1);
            }
            continue;
        }
        if current == section && !key.is_empty() {
            let name = l.split('=').next().unwrap_or("").trim();
            if name == key {
                return Some(i + 1);
            }
        }
    }
    None
}

/// The line of a stage section's error: serde reports a tagged section's errors at its
/// `[section]` line; an unknown key or kind is found on its own line below it.
fn within_section(text: &str, line: usize, message: &str) -> usize {
    let Some(header) = text.lines().nth(line - 1) else {
        return line;
    };
    let Some(section) = header
        .trim()
        .strip_prefix('[')
        .and_then(|h| h.strip_suffix(']'))
    else {
        return line;
    };
    let quoted = |after: &str| {
        message
            .split_once(after)
            .and_then(|(_, rest)| rest.split('`').next())
            .map(str::to_string)
    };
    if let Some(key) = quoted("unknown field `") {
        return key_line(text, section.trim(), &key).unwrap_or(line);
    }
    if let Some(value) = quoted("unknown variant `") {
        let mut in_section = false;
        for (i, l) in text.lines().enumerate().skip(line - 1) {
            let l = l.trim();
            if l.starts_with('[') {
                if in_section {
                    break;
                }
                in_section = true;
                continue;
            }
            let v = l
                .split_once('=')
                .map(|(_, v)| v.split('#').next().unwrap_or("").trim());
            // A value may be quoted with either quote mark.
            if v.is_some_and(|v| v.trim_matches(|c| matches!(c, '\u{22}' | '\u{27}')) == value) {
                return i + 1;
            }
        }
    }
    line
}

/// A project read from its file, with the folder its paths are relative to.
#[derive(Clone, Debug)]
pub struct Loaded {
    pub project: Project,
    pub path: PathBuf,
    pub text: String,
    /// Input checksums known already (a split's), taken while each file's size and time match.
    pub known_inputs: Vec<super::provenance::KnownInput>,
}

impl Loaded {
    /// A path of the project, resolved against the project's folder.
    pub fn resolve(&self, p: &str) -> PathBuf {
        let q = Path::new(p);
        if q.is_absolute() {
            q.to_path_buf()
        } else {
            self.path.parent().unwrap_or(Path::new(".")).join(q)
        }
    }

    /// Every file the project reads, with its key (`section.key`), resolved: the calibration
    /// (unless a preset), the GCPs, the picks, the video, the heights, the detector's boxes and
    /// the DEM.
    pub(crate) fn input_files(&self) -> Vec<(&'static str, PathBuf)> {
        let p = &self.project;
        let mut files = Vec::new();
        if crate::camera::presets::preset(&p.camera.calibration).is_none() {
            files.push(("camera.calibration", self.resolve(&p.camera.calibration)));
        }
        if !p.survey.gcps.is_empty() {
            files.push(("survey.gcps", self.resolve(&p.survey.gcps)));
        }
        if let PoseSection::Fixed(f) = &p.pose
            && let Some(file) = &f.extrinsics
        {
            files.push(("pose.extrinsics", self.resolve(file)));
        }
        for pk in &p.survey.picks {
            files.push(("survey.picks", self.resolve(pk)));
        }
        if let Some(c) = &p.picks.codes {
            files.push(("picks.codes", self.resolve(c)));
        }
        files.push(("video.path", self.resolve(&p.video.path)));
        if let Some(t) = &p.video.telemetry {
            files.push(("video.telemetry", self.resolve(t)));
        }
        if let Some(h) = &p.projection.heights {
            files.push(("projection.heights", self.resolve(h)));
        }
        if let Some(b) = p.detect.boxes_file() {
            files.push(("detect.boxes", self.resolve(b)));
        }
        if let super::settings::DetectSection::Onnx(o) = &p.detect
            && let Some(m) = &o.model
        {
            files.push((
                "detect.model",
                crate::detect::models::given_model(m, self.resolve(m)),
            ));
        }
        match p.ground.reads() {
            Some(GroundInput::File(path)) => files.push(("ground.path", self.resolve(path))),
            Some(GroundInput::Model(dir)) => {
                files.push(("ground.model", self.resolve(dir).join("points3D.txt")))
            }
            None => {}
        }
        if let PoseSection::Model(m) = &p.pose
            && !m.model.is_empty()
        {
            for f in ["cameras.txt", "images.txt", "points3D.txt", "cameras.csv"] {
                files.push(("pose.model", self.resolve(&m.model).join(f)));
            }
        }
        files
    }

    /// An error about `section.key`, with its line.
    pub fn error(&self, section: &str, key: &str, message: impl Into<String>) -> FileError {
        let field = if key.is_empty() {
            section.to_string()
        } else {
            format!("{section}.{key}")
        };
        FileError {
            path: self.path.clone(),
            line: key_line(&self.text, section, key).or_else(|| key_line(&self.text, section, "")),
            field: Some(field),
            message: message.into(),
        }
    }
}

/// The largest project file read: a project is a page of settings.
pub const MAX_PROJECT_BYTES: u64 = 1 << 20;

/// Reads and checks a project file.
pub fn load(path: &Path) -> Result<Loaded, FileError> {
    let ctx = FileCtx { path };
    let text = ctx.read_small_text("a TOML project file", MAX_PROJECT_BYTES)?;
    parse(path, text)
}

/// Parses and checks a project file's text; `path` names it and anchors its relative paths.
pub fn parse(path: &Path, text: String) -> Result<Loaded, FileError> {
    let ctx = FileCtx { path };
    let project: Project = toml::from_str(&text).map_err(|e| {
        let line = e
            .span()
            .map(|s| text[..s.start.min(text.len())].matches('\n').count() + 1)
            .map(|l| within_section(&text, l, e.message()));
        ctx.err(line, None, format!("not a valid project: {}", e.message()))
    })?;
    let l = Loaded {
        project,
        path: path.to_path_buf(),
        text,
        known_inputs: Vec::new(),
    };
    check_finite(&l)?;
    check(&l)?;
    Ok(l)
}

fn check_picks(l: &Loaded) -> Result<(), FileError> {
    let (p, a) = (&l.project, &l.project.picks);
    if !(a.heading_tolerance_deg > 0.0 && a.heading_tolerance_deg <= 180.0) {
        return Err(l.error(
            "picks",
            "heading_tolerance_deg",
            "expected degrees in (0, 180]",
        ));
    }
    if !(a.min_contrast > 0.0 && a.min_contrast < 255.0) {
        return Err(l.error("picks", "min_contrast", "expected grey levels in (0, 255)"));
    }
    if a.designs.is_empty() {
        return Err(l.error(
            "picks",
            "designs",
            "name at least one design: \"checker\", \"x\", \"cross\" or \"coded\"",
        ));
    }
    if let Err(e) = a.dictionary.parse::<crate::targets::codes::Dictionary>() {
        return Err(l.error("picks", "dictionary", e));
    }
    if a.codes.is_some() && !a.designs.contains(&TargetDesignName::Coded) {
        return Err(l.error(
            "picks",
            "codes",
            "a code table is for coded markers: add \"coded\" to designs",
        ));
    }
    if !a.auto {
        return Ok(());
    }
    if !p.survey.picks.is_empty() {
        return Err(l.error(
            "picks",
            "auto",
            "survey.picks also gives picks: keep one (a person's picks from `geostride gcp pick` \
             go in survey.picks, with auto = false)",
        ));
    }
    if !matches!(p.pose, PoseSection::Hover(_)) {
        return Err(l.error(
            "picks",
            "auto",
            "automatic picks serve the hovering camera ([pose] kind = \"hover\"); for a model or \
             a fixed camera, give survey.picks",
        ));
    }
    Ok(())
}

/// Every number in the file finite (TOML allows `nan` and `inf`).
fn check_finite(l: &Loaded) -> Result<(), FileError> {
    match crate::io::toml_nonfinite_key(&l.text) {
        Some((section, key)) => {
            Err(l.error(&section, &key, "expected finite numbers (not nan or inf)"))
        }
        None => Ok(()),
    }
}

fn check(l: &Loaded) -> Result<(), FileError> {
    let p = &l.project;
    if crate::camera::presets::preset(&p.camera.calibration).is_none() {
        exists(l, "camera", "calibration", &p.camera.calibration)?;
    }
    let fixed = matches!(p.pose, PoseSection::Fixed(_));
    if p.survey.gcps.is_empty() && !fixed {
        return Err(l.error(
            "survey",
            "gcps",
            "the GCP file is required: gcps = \"gcps.csv\" (a fixed camera, [pose] kind = \
             \"fixed\", may do without)",
        ));
    }
    if !p.survey.gcps.is_empty() {
        exists(l, "survey", "gcps", &p.survey.gcps)?;
    }
    if let PoseSection::Fixed(f) = &p.pose
        && let Some(file) = &f.extrinsics
    {
        exists(l, "pose", "extrinsics", file)?;
    }
    for pk in &p.survey.picks {
        exists(l, "survey", "picks", pk)?;
    }
    check_picks(l)?;
    exists(l, "video", "path", &p.video.path)?;
    if let Some(t) = &p.video.telemetry {
        exists(l, "video", "telemetry", t)?;
    }
    for (key, v) in [
        ("telemetry_sigma_m", p.video.telemetry_sigma_m),
        (
            "telemetry_sigma_vertical_m",
            p.video.telemetry_sigma_vertical_m,
        ),
    ] {
        if !(v > 0.0 && v.is_finite()) {
            return Err(l.error("video", key, "expected a positive number of metres"));
        }
    }
    if let Some(h) = &p.video.telemetry_height
        && h != "ellipsoidal"
        && h != "egm96"
    {
        return Err(l.error(
            "video",
            "telemetry_height",
            format!(
                "expected \"ellipsoidal\" or \"egm96\" (what DJI's abs_alt is above), got \"{}\"",
                crate::io::clip(h, 40)
            ),
        ));
    }
    if let Some(h) = &p.survey.height
        && h != "ellipsoidal"
        && h != "orthometric"
    {
        return Err(l.error(
            "survey",
            "height",
            format!("expected 'ellipsoidal' or 'orthometric', got '{h}'"),
        ));
    }
    if !(p.survey.pick_sigma_px > 0.0) {
        return Err(l.error("survey", "pick_sigma_px", "σ must be positive"));
    }
    if !(p.survey.gcp_sigma_m > 0.0) {
        return Err(l.error("survey", "gcp_sigma_m", "σ must be positive"));
    }
    if let Some(c) = &p.survey.crs {
        crate::survey::crs::Crs::new(c).map_err(|e| l.error("survey", "crs", e.to_string()))?;
    }
    if let Some(o) = &p.survey.origin {
        o.parse::<crate::survey::frame::Origin>()
            .map_err(|e| l.error("survey", "origin", e))?;
    }
    if let Some(c) = &p.export.crs {
        crate::survey::crs::Crs::new(c).map_err(|e| l.error("export", "crs", e.to_string()))?;
    }
    if p.video.duration_s.is_some_and(|d| !(d > 0.0)) {
        return Err(l.error("video", "duration_s", "must be positive"));
    }
    if !(p.video.chunk_s > 0.0 && p.video.chunk_s.is_finite()) {
        return Err(l.error("video", "chunk_s", "must be a positive number of seconds"));
    }
    if !(p.video.overlap_s >= 0.0 && p.video.overlap_s < p.video.chunk_s) {
        return Err(l.error(
            "video",
            "overlap_s",
            format!(
                "must be at least 0 and less than chunk_s ({} s)",
                p.video.chunk_s
            ),
        ));
    }
    p.pose.check().map_err(|(key, m)| l.error("pose", key, m))?;
    p.ground
        .check()
        .map_err(|(key, m)| l.error("ground", key, m))?;
    check_models(l)?;
    check_detect(l)?;
    check_later_stages(l)
}

/// The files and folders the ground and the pose read: a model's folder whole.
fn check_models(l: &Loaded) -> Result<(), FileError> {
    let p = &l.project;
    match p.ground.reads() {
        Some(GroundInput::File(path)) => exists(l, "ground", "path", path)?,
        Some(GroundInput::Model(dir)) => model_exists(l, "ground", "model", dir)?,
        None => {}
    }
    if let super::settings::GroundSection::LocalPlanes { model, .. } = &p.ground
        && model.is_empty()
        && !matches!(p.pose, super::settings::PoseSection::Model(_))
    {
        return Err(l.error(
            "ground",
            "model",
            "local planes need a model: name its folder (geostride sfm PHOTOS --gcps GCPS --out model); it may be left out only with [pose] kind = \"model\", whose model they then use",
        ));
    }
    if let super::settings::PoseSection::Model(m) = &p.pose
        && !m.model.is_empty()
    {
        model_exists(l, "pose", "model", &m.model)?;
        if !l.resolve(&m.model_images).is_dir() {
            return Err(l.error(
                "pose",
                "model_images",
                format!("{} is not a folder", l.resolve(&m.model_images).display()),
            ));
        }
    }
    Ok(())
}

/// A reference model's folder: `points3D.txt` and its siblings inside.
fn model_exists(l: &Loaded, section: &str, key: &str, dir: &str) -> Result<(), FileError> {
    let d = l.resolve(dir);
    for f in ["cameras.txt", "images.txt", "points3D.txt"] {
        if !d.join(f).is_file() {
            return Err(l.error(
                section,
                key,
                format!(
                    "{} has no {f}: give the folder geostride sfm wrote (geostride sfm PHOTOS --gcps GCPS --out DIR)",
                    d.display()
                ),
            ));
        }
    }
    Ok(())
}

/// The `[detect]` section's checks.
fn check_detect(l: &Loaded) -> Result<(), FileError> {
    let d = &l.project.detect;
    d.check().map_err(|(key, m)| l.error("detect", key, m))?;
    if let super::settings::DetectSection::Onnx(o) = d
        && let Some(m) = &o.model
    {
        // A bundled model's name is no file (`detect::models::given_model`).
        if crate::detect::models::named_model(m).is_none() || l.resolve(m).exists() {
            exists(l, "detect", "model", m)?;
        }
    }
    match d.boxes_file() {
        Some(b) => exists(l, "detect", "boxes", b),
        None => Ok(()),
    }
}

/// The checks of `[track]`, `[projection]`, `[smooth]` and `[export]`.
fn check_later_stages(l: &Loaded) -> Result<(), FileError> {
    let p = &l.project;
    p.track
        .check()
        .map_err(|(key, m)| l.error("track", key, m))?;
    let height_ok = p.projection.head_height_m > 0.0 && p.projection.head_height_m < 3.0;
    let sd_ok = p.projection.head_height_sd_m >= 0.0;
    if !(height_ok && sd_ok) {
        return Err(l.error(
            "projection",
            "head_height_m",
            "expected a height between 0 and 3 m and a σ ≥ 0",
        ));
    }
    if let Some(h) = &p.projection.heights {
        exists(l, "projection", "heights", h)?;
    }
    p.smooth
        .check()
        .map_err(|(key, m)| l.error("smooth", key, m))?;
    for f in &p.export.formats {
        if crate::export::ExportFormat::parse(f).is_none() {
            return Err(l.error(
                "export",
                "formats",
                format!(
                    "unknown format '{f}': expected one of {}",
                    crate::export::ExportFormat::ALL
                        .map(|f| f.name())
                        .join(", ")
                ),
            ));
        }
    }
    let o = &p.output;
    if !(o.video_width >= 160 && o.video_width <= 7680) {
        return Err(l.error("output", "video_width", "expected 160 to 7680 pixels"));
    }
    if !(o.trail_s >= 0.0 && o.trail_s <= 60.0) {
        return Err(l.error("output", "trail_s", "expected 0 to 60 seconds"));
    }
    if let Some(g) = o.site_gsd_m
        && !(g >= 0.001 && g <= 10.0)
    {
        return Err(l.error("output", "site_gsd_m", "expected 0.001 to 10 metres"));
    }
    p.analysis
        .polygons()
        .map_err(|(key, m)| l.error("analysis", key, m))?;
    p.analysis
        .lines()
        .map_err(|(key, m)| l.error("analysis", key, m))?;
    Ok(())
}

/// An error unless `path` (relative to the project file) is a file.
fn exists(l: &Loaded, section: &str, key: &str, path: &str) -> Result<(), FileError> {
    let resolved = l.resolve(path);
    if resolved.is_file() {
        Ok(())
    } else if resolved.is_dir() {
        Err(l.error(
            section,
            key,
            format!("'{path}' is a folder; expected a file"),
        ))
    } else {
        Err(l.error(
            section,
            key,
            format!("'{path}': no such file (relative to the project file's folder)"),
        ))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn finds_the_line_of_a_key() {
        let text = "name = \"x\"\n[camera]\ncalibration = \"c.yaml\"\n\n[detect]\nkind = \"colour\"\nclusters = 1\n";
        assert_eq!(key_line(text, "detect", "clusters"), Some(7));
        assert_eq!(key_line(text, "camera", ""), Some(2));
        assert_eq!(key_line(text, "detect", "colour"), None);
    }

    const BASE: &str = "name = \"x\"\n[camera]\ncalibration = \"mini3pro\"\n[survey]\ngcps = \"g.csv\"\n[video]\npath = \"v.mp4\"\n[ground]\nkind = \"plane\"\n";

    fn error_of(extra: &str) -> FileError {
        parse(Path::new("p.toml"), format!("{BASE}{extra}")).unwrap_err()
    }

    #[test]
    fn a_bundled_models_name_is_not_taken_for_a_missing_file() {
        let loaded = |model: &str| {
            let text = format!("{BASE}[detect]\nkind = \"onnx\"\nmodel = \"{model}\"\n");
            Loaded {
                project: toml::from_str(&text).unwrap(),
                path: "p.toml".into(),
                text,
                known_inputs: Vec::new(),
            }
        };
        for name in crate::detect::models::BUNDLED_MODELS {
            check_detect(&loaded(name)).unwrap();
        }
        let e = check_detect(&loaded("nope.onnx")).unwrap_err();
        assert!(e.message.contains("no such file"), "{e}");
    }

    #[test]
    fn a_section_without_kind_takes_the_default_kind() {
        let p: Project = toml::from_str(&format!(
            "{BASE}[detect]\nclusters = 9\n[smooth]\nem = false\n"
        ))
        .unwrap();
        match &p.detect {
            DetectSection::Colour(c) => assert_eq!(c.clusters, 9),
            other => panic!("{other:?}"),
        }
        assert!(matches!(&p.smooth, SmoothSection::KalmanRts(k) if !k.em));
        assert_eq!(p.track, TrackSection::default());
        assert_eq!(p.pose, PoseSection::default());
    }

    #[test]
    fn a_key_of_another_kind_is_refused_with_its_line() {
        let e = error_of("[detect]\nkind = \"boxes\"\nboxes = \"b.txt\"\nclusters = 15\n");
        assert!(e.message.contains("unknown field `clusters`"), "{e}");
        assert_eq!(e.line, Some(13), "{e}");
        let e = error_of("[smooth]\nkind = \"none\"\n\nem = true\n");
        assert!(e.message.contains("unknown field `em`"), "{e}");
        assert_eq!(e.line, Some(13), "{e}");
    }

    #[test]
    fn an_unknown_kind_lists_the_kinds() {
        let e = error_of("[detect]\nkind = \"yolo\"\n");
        assert!(
            e.message.contains("colour") && e.message.contains("background"),
            "{e}"
        );
        assert_eq!(e.line, Some(11), "{e}");
        let e = error_of("[smooth]\nmodel = \"fancy\"\n");
        assert!(e.message.contains("white_acceleration"), "{e}");
        assert_eq!(e.line, Some(11), "{e}");
    }

    #[test]
    fn the_motion_detector_takes_its_defaults_and_refuses_a_bad_step() {
        let p: Project = toml::from_str(&format!("{BASE}[detect]\nkind = \"motion\"\n")).unwrap();
        match &p.detect {
            DetectSection::Motion(m) => assert_eq!((m.step_frames, m.threshold), (5, 25.0)),
            other => panic!("{other:?}"),
        }
        let p: Project = toml::from_str(&format!(
            "{BASE}[detect]\nkind = \"motion\"\nstep_frames = 0\n"
        ))
        .unwrap();
        assert_eq!(p.detect.check().unwrap_err().0, "step_frames");
    }

    #[test]
    fn the_motion_check_needs_every_frame_detected() {
        let detect = |extra: &str| {
            let p: Project = toml::from_str(&format!(
                "{BASE}[detect]\nkind = \"onnx\"\nmotion_check = true\n{extra}"
            ))
            .unwrap();
            p.detect.check()
        };
        assert!(detect("").is_ok());
        assert_eq!(detect("stride = 2\n").unwrap_err().0, "motion_check");
    }
}
