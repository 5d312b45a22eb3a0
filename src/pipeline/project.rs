//! The project file (TOML): everything a run needs, paths relative to the file. Unknown keys and
//! bad values are errors that name the key and its line.

use std::path::{Path, PathBuf};

use serde::{Deserialize, Serialize};

use crate::io::{FileCtx, FileError};

fn default_true() -> bool {
    true
}

/// The whole project.
#[derive(Clone, Debug, Deserialize, Serialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct Project {
    #[serde(default)]
    pub name: String,
    pub camera: CameraSection,
    pub survey: SurveySection,
    pub video: VideoSection,
    #[serde(default)]
    pub pose: PoseSection,
    pub ground: GroundSection,
    #[serde(default)]
    pub detect: DetectSection,
    #[serde(default)]
    pub track: TrackSection,
    #[serde(default)]
    pub projection: ProjectionSection,
    #[serde(default)]
    pub smooth: SmoothSection,
    #[serde(default)]
    pub export: ExportSection,
}

#[derive(Clone, Debug, Deserialize, Serialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct CameraSection {
    /// A calibration file or a preset name; scaled to the video's size.
    pub calibration: String,
}

#[derive(Clone, Debug, Deserialize, Serialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct SurveySection {
    /// The GCP file (any format `geostride survey` reads).
    pub gcps: String,
    /// Pick files `name,image,u,v[,sigma]`; the image is `VIDEO#N` for frame N.
    #[serde(default)]
    pub picks: Vec<String>,
    /// The GCP file's CRS when it does not say, or to override it.
    #[serde(default)]
    pub crs: Option<String>,
    /// `ellipsoidal` or `orthometric`.
    #[serde(default)]
    pub height: Option<String>,
    /// Site frame origin: `centroid`, `point:NAME` or `LAT,LON,H`.
    #[serde(default)]
    pub origin: Option<String>,
    #[serde(default)]
    pub check: Vec<String>,
    #[serde(default = "SurveySection::default_check_prefix")]
    pub check_prefix: String,
    #[serde(default = "SurveySection::default_pick_sigma")]
    pub pick_sigma_px: f64,
    #[serde(default = "SurveySection::default_gcp_sigma")]
    pub gcp_sigma_m: f64,
}

impl SurveySection {
    fn default_check_prefix() -> String {
        "CHK-".into()
    }
    fn default_pick_sigma() -> f64 {
        1.0
    }
    fn default_gcp_sigma() -> f64 {
        0.02
    }
}

#[derive(Clone, Debug, Deserialize, Serialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct VideoSection {
    pub path: String,
    /// Process only the first this many seconds.
    #[serde(default)]
    pub duration_s: Option<f64>,
}

#[derive(Clone, Debug, Deserialize, Serialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct PoseSection {
    /// `hover`: a pose for every frame of a hovering camera (key frames, carried picks).
    #[serde(default = "PoseSection::default_kind")]
    pub kind: String,
    /// The frame the picks were made on [default: from the picks' image name].
    #[serde(default)]
    pub picks_frame: Option<usize>,
    #[serde(default = "PoseSection::default_min_features")]
    pub min_features: usize,
    #[serde(default = "PoseSection::default_key_fraction")]
    pub key_fraction: f64,
    #[serde(default)]
    pub key_every_s: Option<f64>,
}

impl PoseSection {
    fn default_kind() -> String {
        "hover".into()
    }
    fn default_min_features() -> usize {
        40
    }
    fn default_key_fraction() -> f64 {
        0.5
    }
}

impl Default for PoseSection {
    fn default() -> Self {
        toml::from_str("").expect("every field has a default")
    }
}

/// The ground under the people.
#[derive(Clone, Debug, Deserialize, Serialize, PartialEq)]
#[serde(deny_unknown_fields, tag = "kind", rename_all = "snake_case")]
pub enum GroundSection {
    /// A plane: at `height_m` (site frame) or fitted to the control GCPs.
    Plane {
        #[serde(default)]
        height_m: Option<f64>,
    },
    /// A deck along a centre line (coordinates in the GCP file's CRS), its height profile a
    /// least-squares polynomial through the control GCPs on it (`degree`, 2 by default) or
    /// stations `[[chainage, height], ...]` (site-frame heights).
    Deck {
        centre_line: Vec<[f64; 2]>,
        width_m: f64,
        #[serde(default)]
        stations: Vec<[f64; 2]>,
        #[serde(default = "default_degree")]
        degree: usize,
    },
    /// A DEM raster in any CRS (heights of the survey's kind).
    Dem { path: String },
}

fn default_degree() -> usize {
    2
}

#[derive(Clone, Debug, Deserialize, Serialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct DetectSection {
    /// `colour`: coloured hats.
    #[serde(default = "DetectSection::default_kind")]
    pub kind: String,
    #[serde(default = "DetectSection::default_colour")]
    pub colour: [u8; 3],
    #[serde(default = "DetectSection::default_clusters")]
    pub clusters: usize,
    #[serde(default = "DetectSection::default_sample_frames")]
    pub sample_frames: usize,
    #[serde(default = "DetectSection::default_hat")]
    pub hat_diameter_m: f64,
    #[serde(default = "DetectSection::default_hue")]
    pub max_hue_difference_deg: f64,
    #[serde(default = "DetectSection::default_sigma")]
    pub centroid_sigma_px: f64,
    #[serde(default)]
    pub seed: u64,
    // `boxes`: an external detector's boxes.
    /// The box file (MOTChallenge txt, JSON Lines or COCO JSON).
    pub boxes: Option<String>,
    /// `mot`, `jsonl` or `coco`; guessed from the file when absent.
    pub boxes_format: Option<String>,
    #[serde(default = "DetectSection::default_min_score")]
    pub min_score: f64,
    /// Boxes are kept where their centre is inside `[x0, y0, x1, y1]`, pixels.
    pub roi: Option<[f64; 4]>,
    #[serde(default = "DetectSection::default_nms")]
    pub nms_iou: f64,
    #[serde(default = "DetectSection::default_merge")]
    pub merge_iou: f64,
    #[serde(default = "DetectSection::default_aspect")]
    pub aspect: [f64; 2],
    /// Limits on a box's longer side, metres at head height.
    #[serde(default = "DetectSection::default_size")]
    pub size_m: [f64; 2],
    /// One person's length along a box, metres: boxes of two or more such lengths are split
    /// (off unless given: seen obliquely, one person's box is long too).
    pub person_m: Option<f64>,
    /// Shadow samples `[frame, x, y, w, h]`, pixels: boxes mostly of that colour are dropped.
    #[serde(default)]
    pub shadow_samples: Vec<[f64; 5]>,
    #[serde(default = "DetectSection::default_shadow_fraction")]
    pub max_shadow_fraction: f64,
    /// A body's radius seen from above, metres: the head is this far in from the box's end.
    #[serde(default = "DetectSection::default_body_radius")]
    pub body_radius_m: f64,
    /// Detection error `[vertical, horizontal at the centre, horizontal at the left and right
    /// edges]`, px² (the paper's section 4.1.3), for `boxes` and `background`
    /// [default: `[10, 10, 20]`].
    #[serde(default)]
    pub error_px2: Option<[f64; 3]>,
    /// Detection error as rows `[t, vertical, horizontal]` (px²) at places `t` across the image
    /// (0 the vertical centre line, 1 the left and right edges), linear between them: what
    /// `geostride fit-error` writes. Instead of `error_px2`.
    #[serde(default)]
    pub error_profile_px2: Option<Vec<[f64; 3]>>,
    // `background`: background subtraction for a stationary camera.
    /// `mog2` or `knn`.
    #[serde(default = "DetectSection::default_method")]
    pub method: String,
    #[serde(default = "DetectSection::default_history")]
    pub history: i32,
    #[serde(default = "DetectSection::default_warmup")]
    pub warmup_frames: usize,
    #[serde(default = "DetectSection::default_min_area")]
    pub min_area_m2: f64,
    #[serde(default = "DetectSection::default_max_area")]
    pub max_area_m2: f64,
}

impl DetectSection {
    /// The detection error model these settings give (checked when the project is read).
    pub fn error_model(&self) -> crate::detect::ErrorModel {
        use crate::detect::ErrorModel;
        match (&self.error_profile_px2, self.error_px2) {
            (Some(rows), _) => ErrorModel::from_rows(rows).unwrap_or_default(),
            (None, Some([v, hc, he])) => ErrorModel::paper(v, hc, he),
            (None, None) => ErrorModel::default(),
        }
    }
    fn default_min_score() -> f64 {
        0.3
    }
    fn default_nms() -> f64 {
        0.5
    }
    fn default_merge() -> f64 {
        0.85
    }
    fn default_aspect() -> [f64; 2] {
        [0.25, 4.0]
    }
    fn default_size() -> [f64; 2] {
        // Seen obliquely, a whole body's box is long: up to about 2.5 m at a 4K frame's edge.
        [0.25, 3.0]
    }
    fn default_shadow_fraction() -> f64 {
        0.6
    }
    fn default_body_radius() -> f64 {
        // Half a runner's length along the box (swinging arms and legs), from the simulator's
        // bodies: 0.3 m left the head 0.25 m too far out at the image's sides.
        0.55
    }
    fn default_method() -> String {
        "mog2".into()
    }
    fn default_history() -> i32 {
        300
    }
    fn default_warmup() -> usize {
        25
    }
    fn default_min_area() -> f64 {
        0.08
    }
    fn default_max_area() -> f64 {
        4.0
    }
    fn default_kind() -> String {
        "colour".into()
    }
    fn default_colour() -> [u8; 3] {
        [255, 0, 255]
    }
    fn default_clusters() -> usize {
        15
    }
    fn default_sample_frames() -> usize {
        50
    }
    fn default_hat() -> f64 {
        0.24
    }
    fn default_hue() -> f64 {
        30.0
    }
    fn default_sigma() -> f64 {
        0.5
    }
}

impl Default for DetectSection {
    fn default() -> Self {
        toml::from_str("").expect("every field has a default")
    }
}

#[derive(Clone, Debug, Deserialize, Serialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct TrackSection {
    /// `association`: global assignment with camera-motion-compensated prediction.
    #[serde(default = "TrackSection::default_kind")]
    pub kind: String,
    /// Gate between prediction and detection, metres at head height.
    #[serde(default = "TrackSection::default_gate")]
    pub gate_m: f64,
    #[serde(default = "TrackSection::default_confirm")]
    pub confirm_frames: usize,
    /// Longest gap a track survives, seconds.
    #[serde(default = "TrackSection::default_gap")]
    pub max_gap_s: f64,
    /// Tracks shorter than this are dropped, seconds.
    #[serde(default = "TrackSection::default_min")]
    pub min_length_s: f64,
    // `klt`: feature tracking.
    /// Lucas–Kanade window side, full-resolution pixels.
    #[serde(default = "TrackSection::default_window")]
    pub window_px: f64,
    #[serde(default = "TrackSection::default_levels")]
    pub levels: i32,
    #[serde(default = "TrackSection::default_min_features")]
    pub min_features: usize,
    #[serde(default = "TrackSection::default_max_features")]
    pub max_features: usize,
    /// Tracks with fewer detections than this are dropped.
    #[serde(default = "TrackSection::default_min_hits")]
    pub min_hits: usize,
}

impl TrackSection {
    fn default_kind() -> String {
        "association".into()
    }
    fn default_gate() -> f64 {
        0.35
    }
    fn default_confirm() -> usize {
        3
    }
    fn default_gap() -> f64 {
        0.5
    }
    fn default_min() -> f64 {
        0.5
    }
    fn default_window() -> f64 {
        50.0
    }
    fn default_levels() -> i32 {
        3
    }
    fn default_min_features() -> usize {
        5
    }
    fn default_max_features() -> usize {
        40
    }
    fn default_min_hits() -> usize {
        5
    }
}

impl Default for TrackSection {
    fn default() -> Self {
        toml::from_str("").expect("every field has a default")
    }
}

#[derive(Clone, Debug, Deserialize, Serialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct ProjectionSection {
    /// Head height above the ground when a person's is not known, metres, and its σ.
    #[serde(default = "ProjectionSection::default_height")]
    pub head_height_m: f64,
    #[serde(default = "ProjectionSection::default_height_sd")]
    pub head_height_sd_m: f64,
    /// CSV `id,height_m[,sd_m]` of known heights by track id.
    #[serde(default)]
    pub heights: Option<String>,
}

impl ProjectionSection {
    fn default_height() -> f64 {
        1.7
    }
    fn default_height_sd() -> f64 {
        0.1
    }
}

impl Default for ProjectionSection {
    fn default() -> Self {
        toml::from_str("").expect("every field has a default")
    }
}

#[derive(Clone, Debug, Deserialize, Serialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct SmoothSection {
    /// `kalman_rts`, or `none` to keep the projected points.
    #[serde(default = "SmoothSection::default_kind")]
    pub kind: String,
    #[serde(default = "default_true")]
    pub em: bool,
    /// `white_acceleration`, `full` or `diagonal`.
    #[serde(default = "SmoothSection::default_model")]
    pub model: String,
    #[serde(default = "SmoothSection::default_qp")]
    pub q_position_m: f64,
    #[serde(default = "SmoothSection::default_qv")]
    pub q_velocity_m_s: f64,
}

impl SmoothSection {
    fn default_kind() -> String {
        "kalman_rts".into()
    }
    fn default_model() -> String {
        "white_acceleration".into()
    }
    fn default_qp() -> f64 {
        0.5
    }
    fn default_qv() -> f64 {
        0.25
    }
}

impl Default for SmoothSection {
    fn default() -> Self {
        toml::from_str("").expect("every field has a default")
    }
}

#[derive(Clone, Debug, Deserialize, Serialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct ExportSection {
    /// Output CRS [default: the GCP file's].
    #[serde(default)]
    pub crs: Option<String>,
    /// Any of `csv`, `geojson`, `gpkg`, `petrack`, `mot`, `detections`.
    #[serde(default = "ExportSection::default_formats")]
    pub formats: Vec<String>,
}

impl ExportSection {
    fn default_formats() -> Vec<String> {
        ["csv", "geojson", "gpkg", "petrack", "mot", "detections"]
            .map(String::from)
            .to_vec()
    }
}

impl Default for ExportSection {
    fn default() -> Self {
        toml::from_str("").expect("every field has a default")
    }
}

/// The line of `section.key` (or of `[section]` when `key` is empty) in a TOML text.
pub fn key_line(text: &str, section: &str, key: &str) -> Option<usize> {
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

/// A project read from its file, with the folder its paths are relative to.
#[derive(Clone, Debug)]
pub struct Loaded {
    pub project: Project,
    pub path: PathBuf,
    pub text: String,
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
    pub fn input_files(&self) -> Vec<(&'static str, PathBuf)> {
        let p = &self.project;
        let mut files = Vec::new();
        if crate::camera::presets::preset(&p.camera.calibration).is_none() {
            files.push(("camera.calibration", self.resolve(&p.camera.calibration)));
        }
        files.push(("survey.gcps", self.resolve(&p.survey.gcps)));
        for pk in &p.survey.picks {
            files.push(("survey.picks", self.resolve(pk)));
        }
        files.push(("video.path", self.resolve(&p.video.path)));
        if let Some(h) = &p.projection.heights {
            files.push(("projection.heights", self.resolve(h)));
        }
        if p.detect.kind == "boxes"
            && let Some(b) = &p.detect.boxes
        {
            files.push(("detect.boxes", self.resolve(b)));
        }
        if let GroundSection::Dem { path } = &p.ground {
            files.push(("ground.path", self.resolve(path)));
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
            .map(|s| text[..s.start.min(text.len())].matches('\n').count() + 1);
        ctx.err(line, None, format!("not a valid project: {}", e.message()))
    })?;
    let l = Loaded {
        project,
        path: path.to_path_buf(),
        text,
    };
    check_finite(&l)?;
    check(&l)?;
    Ok(l)
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
    exists(l, "survey", "gcps", &p.survey.gcps)?;
    for pk in &p.survey.picks {
        exists(l, "survey", "picks", pk)?;
    }
    exists(l, "video", "path", &p.video.path)?;
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
    if p.pose.kind != "hover" {
        return Err(l.error(
            "pose",
            "kind",
            format!(
                "expected 'hover' (a hovering camera), got '{}'",
                p.pose.kind
            ),
        ));
    }
    if !(0.0..=1.0).contains(&p.pose.key_fraction) {
        return Err(l.error("pose", "key_fraction", "expected a fraction from 0 to 1"));
    }
    if p.pose.key_every_s.is_some_and(|s| !(s > 0.0)) {
        return Err(l.error("pose", "key_every_s", "must be positive"));
    }
    if p.pose.min_features < 4 {
        return Err(l.error("pose", "min_features", "must be at least 4"));
    }
    match &p.ground {
        GroundSection::Deck {
            centre_line,
            width_m,
            stations,
            degree,
        } => {
            if centre_line.len() < 2 {
                return Err(l.error(
                    "ground",
                    "centre_line",
                    "a deck needs a centre line of at least 2 points",
                ));
            }
            if !(*width_m > 0.0) {
                return Err(l.error("ground", "width_m", "must be positive"));
            }
            if stations.len() == 1 {
                return Err(l.error(
                    "ground",
                    "stations",
                    "give at least 2 stations, or none to fit the GCPs",
                ));
            }
            if stations.windows(2).any(|w| !(w[1][0] > w[0][0])) {
                return Err(l.error(
                    "ground",
                    "stations",
                    "stations are [chainage, height] with the chainages increasing",
                ));
            }
            if *degree > 3 {
                return Err(l.error(
                    "ground",
                    "degree",
                    "a deck profile polynomial has degree 0 to 3",
                ));
            }
        }
        GroundSection::Dem { path } => exists(l, "ground", "path", path)?,
        GroundSection::Plane { .. } => {}
    }
    check_detect(l)?;
    check_later_stages(l)
}

/// The `[detect]` section's checks.
fn check_detect(l: &Loaded) -> Result<(), FileError> {
    let p = &l.project;
    if !super::registry::DETECTORS.contains(&p.detect.kind.as_str()) {
        return Err(l.error(
            "detect",
            "kind",
            format!(
                "expected one of {:?}, got '{}'",
                super::registry::DETECTORS,
                p.detect.kind
            ),
        ));
    }
    if p.detect.kind == "boxes" {
        match &p.detect.boxes {
            Some(b) => exists(l, "detect", "boxes", b)?,
            None => {
                return Err(l.error(
                    "detect",
                    "boxes",
                    "the 'boxes' detector needs a box file: boxes = \"detections.txt\"",
                ));
            }
        }
    }
    if let Some(f) = &p.detect.boxes_format
        && crate::detect::boxes::BoxFormat::parse(f).is_none()
    {
        return Err(l.error(
            "detect",
            "boxes_format",
            "expected 'mot', 'jsonl' or 'coco'",
        ));
    }
    if !["mog2", "knn"].contains(&p.detect.method.as_str()) {
        return Err(l.error("detect", "method", "expected 'mog2' or 'knn'"));
    }
    if p.detect
        .error_px2
        .is_some_and(|e| e.iter().any(|v| !(v.is_finite() && *v > 0.0)))
    {
        return Err(l.error(
            "detect",
            "error_px2",
            "expected three positive variances, px²",
        ));
    }
    if let Some(rows) = &p.detect.error_profile_px2 {
        if p.detect.error_px2.is_some() {
            return Err(l.error(
                "detect",
                "error_profile_px2",
                "give error_px2 or error_profile_px2, not both",
            ));
        }
        if crate::detect::ErrorModel::from_rows(rows).is_none() {
            return Err(l.error(
                "detect",
                "error_profile_px2",
                "expected rows [t, vertical, horizontal]: t rising within 0 to 1, positive \
                 variances in px² (as geostride fit-error writes them)",
            ));
        }
    }
    if !(2..=64).contains(&p.detect.clusters) {
        return Err(l.error("detect", "clusters", "expected 2 to 64"));
    }
    if p.detect.sample_frames == 0 {
        return Err(l.error("detect", "sample_frames", "must be at least 1"));
    }
    if !(p.detect.hat_diameter_m > 0.0) {
        return Err(l.error("detect", "hat_diameter_m", "must be positive"));
    }
    if p.detect.sample_frames > 10_000 {
        return Err(l.error("detect", "sample_frames", "at most 10000"));
    }
    if !(p.detect.max_hue_difference_deg > 0.0 && p.detect.max_hue_difference_deg <= 180.0) {
        return Err(l.error(
            "detect",
            "max_hue_difference_deg",
            "expected an angle from 0 to 180°",
        ));
    }
    if !(p.detect.centroid_sigma_px > 0.0) {
        return Err(l.error("detect", "centroid_sigma_px", "must be positive"));
    }
    if !(p.detect.body_radius_m >= 0.0) {
        return Err(l.error("detect", "body_radius_m", "must not be negative"));
    }
    if p.detect.person_m.is_some_and(|m| !(m > 0.0)) {
        return Err(l.error("detect", "person_m", "must be positive"));
    }
    Ok(())
}

/// The checks of `[track]`, `[projection]`, `[smooth]` and `[export]`.
fn check_later_stages(l: &Loaded) -> Result<(), FileError> {
    let p = &l.project;
    if !super::registry::TRACKERS.contains(&p.track.kind.as_str()) {
        return Err(l.error(
            "track",
            "kind",
            format!(
                "expected one of {:?}, got '{}'",
                super::registry::TRACKERS,
                p.track.kind
            ),
        ));
    }
    if !(p.track.gate_m > 0.0) || p.track.confirm_frames == 0 || !(p.track.max_gap_s >= 0.0) {
        return Err(l.error(
            "track",
            "gate_m",
            "gate_m must be positive, confirm_frames at least 1, max_gap_s not negative",
        ));
    }
    if !(p.track.window_px >= 5.0) || !(0..=6).contains(&p.track.levels) {
        return Err(l.error(
            "track",
            "window_px",
            "window_px must be at least 5 and levels 0 to 6",
        ));
    }
    if !(p.track.min_length_s >= 0.0) {
        return Err(l.error("track", "min_length_s", "must not be negative"));
    }
    if p.track.min_features == 0 || p.track.max_features < p.track.min_features {
        return Err(l.error(
            "track",
            "min_features",
            "min_features must be at least 1 and no more than max_features",
        ));
    }
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
    if !super::registry::SMOOTHERS.contains(&p.smooth.kind.as_str()) {
        return Err(l.error(
            "smooth",
            "kind",
            format!("expected 'kalman_rts' or 'none', got '{}'", p.smooth.kind),
        ));
    }
    if !(p.smooth.q_position_m > 0.0) {
        return Err(l.error("smooth", "q_position_m", "must be positive"));
    }
    if !(p.smooth.q_velocity_m_s > 0.0) {
        return Err(l.error("smooth", "q_velocity_m_s", "must be positive"));
    }
    if p.smooth.model.parse::<crate::smooth::NoiseModel>().is_err() {
        return Err(l.error(
            "smooth",
            "model",
            format!(
                "expected 'white_acceleration', 'full' or 'diagonal', got '{}'",
                p.smooth.model
            ),
        ));
    }
    for f in &p.export.formats {
        if !["csv", "geojson", "gpkg", "petrack", "mot", "detections"].contains(&f.as_str()) {
            return Err(l.error(
                "export",
                "formats",
                format!(
                    "unknown format '{f}': expected csv, geojson, gpkg, petrack, mot or detections"
                ),
            ));
        }
    }
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
}
