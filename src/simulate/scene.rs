//! Scene descriptions (`SCENE.toml`) for `geostride simulate`: the ground, the camera and its
//! motion, the people, and what to write. Everything has a documented default; unknown keys are
//! errors, so a misspelt option never goes unnoticed. Lengths in metres, angles in degrees in
//! the file, times in seconds. Positions are in the site frame (east, north, up from the site
//! origin).

use std::path::{Path, PathBuf};

use serde::Deserialize;

use crate::io::{FileCtx, FileError};

/// The widest or tallest image a scene may render, pixels (8K video is 7680 wide): frame
/// buffers grow with the area.
pub const MAX_SIDE_PX: u32 = 8192;

fn default_fps() -> f64 {
    25.0
}
fn default_detail() -> f64 {
    1.0
}
fn default_duration() -> f64 {
    10.0
}
fn default_height() -> [f64; 2] {
    [1.7, 0.1]
}

#[derive(Clone, Debug, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct Scene {
    /// A title for reports.
    #[serde(default)]
    pub name: String,
    #[serde(default)]
    pub seed: u64,
    #[serde(default = "default_duration")]
    pub duration_s: f64,
    #[serde(default = "default_fps")]
    pub fps: f64,
    /// CRS of the exported GCP file and the site origin's position in it.
    #[serde(default)]
    pub site: Site,
    pub camera: CameraSpec,
    pub ground: Ground,
    /// Contrast of the ground's fine texture: 1 by default; 3 to 4 gives the grain of real grass,
    /// gravel and asphalt that structure from motion finds features in.
    #[serde(default = "default_detail")]
    pub ground_detail: f64,
    #[serde(default)]
    pub gcp: Vec<GcpSpec>,
    #[serde(default)]
    pub people: PeopleSpec,
    #[serde(default)]
    pub output: OutputSpec,
    /// `[survey_flight]`: photos of the site for structure from motion, before the event.
    #[serde(default)]
    pub survey_flight: Option<SurveyFlightSpec>,
}

/// A photo survey of the site: a nadir grid in flight lines running east, and oblique photos
/// around it looking at its centre; each photo's centre recorded with RTK-like noise.
#[derive(Clone, Debug, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct SurveyFlightSpec {
    /// Height above the site origin, metres.
    #[serde(default = "SurveyFlightSpec::default_altitude")]
    pub altitude_m: f64,
    /// The east-north box the nadir grid covers: `[[min_e, min_n], [max_e, max_n]]`.
    pub area: [[f64; 2]; 2],
    /// Overlap of neighbouring photos along and across the flight lines.
    #[serde(default = "SurveyFlightSpec::default_forward")]
    pub forward_overlap: f64,
    #[serde(default = "SurveyFlightSpec::default_side")]
    pub side_overlap: f64,
    /// Oblique photos, evenly around the area, each tilted `oblique_deg` from nadir towards
    /// its centre.
    #[serde(default = "SurveyFlightSpec::default_obliques")]
    pub obliques: u32,
    #[serde(default = "SurveyFlightSpec::default_oblique_deg")]
    pub oblique_deg: f64,
    /// Photo size: the scene's camera scaled (same aspect ratio), pixels.
    pub image_size: [u32; 2],
    /// Noise of the recorded camera centres: horizontal and vertical σ, metres.
    #[serde(default = "SurveyFlightSpec::default_rtk")]
    pub rtk_noise_m: [f64; 2],
    /// Attitude scatter of the nadir photos (σ about each axis), degrees.
    #[serde(default = "SurveyFlightSpec::default_jitter")]
    pub jitter_deg: f64,
}

impl SurveyFlightSpec {
    fn default_altitude() -> f64 {
        30.0
    }
    fn default_forward() -> f64 {
        0.75
    }
    fn default_side() -> f64 {
        0.65
    }
    fn default_obliques() -> u32 {
        4
    }
    fn default_oblique_deg() -> f64 {
        30.0
    }
    fn default_rtk() -> [f64; 2] {
        [0.02, 0.03]
    }
    fn default_jitter() -> f64 {
        1.0
    }
}

#[derive(Clone, Debug, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct Site {
    pub crs: String,
    /// The site origin in that CRS: easting, northing (or longitude, latitude) and ellipsoidal height.
    pub origin: [f64; 3],
}

impl Default for Site {
    fn default() -> Self {
        // Ghent, Belgium (the paper's footbridges), in Belgian Lambert 2008.
        Site {
            crs: "EPSG:3812".into(),
            origin: [654_500.0, 696_000.0, 52.0],
        }
    }
}

#[derive(Clone, Debug, Deserialize, PartialEq)]
#[serde(deny_unknown_fields, rename_all = "snake_case", tag = "kind")]
pub enum Motion {
    /// Hovering (or on a pole, with no drift or jitter): slow sinusoidal drift and per-frame
    /// rotation jitter.
    Hover {
        position: [f64; 3],
        #[serde(default)]
        heading_deg: f64,
        /// How far the optical axis points below the horizon, towards `heading_deg`: 90 is
        /// straight down (nadir), 15 a pole camera looking across a plaza.
        #[serde(default = "Motion::default_below_horizon")]
        below_horizon_deg: f64,
        #[serde(default = "Motion::default_drift")]
        drift_m: f64,
        #[serde(default = "Motion::default_drift_period")]
        drift_period_s: f64,
        #[serde(default = "Motion::default_jitter")]
        jitter_deg: f64,
    },
    /// Along waypoints at a constant speed (the last waypoint holds).
    Path {
        waypoints: Vec<[f64; 3]>,
        speed_m_s: f64,
        #[serde(default)]
        heading_deg: f64,
        #[serde(default = "Motion::default_jitter")]
        jitter_deg: f64,
    },
    /// Above the centroid of the group, at a height, smoothed (the paper's group events).
    Follow {
        altitude_m: f64,
        #[serde(default)]
        heading_deg: f64,
        #[serde(default = "Motion::default_jitter")]
        jitter_deg: f64,
    },
}

impl Motion {
    fn default_below_horizon() -> f64 {
        90.0
    }
    fn default_drift() -> f64 {
        0.3
    }
    fn default_drift_period() -> f64 {
        40.0
    }
    fn default_jitter() -> f64 {
        0.02
    }
}

#[derive(Clone, Debug, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct CameraSpec {
    /// A calibration file (relative to the scene file) or a preset name (`mavic3e`, `mini3pro`).
    pub calibration: String,
    /// Scale the camera to this resolution (same aspect ratio).
    #[serde(default)]
    pub video_mode: Option<[u32; 2]>,
    /// `[camera.motion]` with `kind = "hover" | "path" | "follow"`.
    pub motion: Motion,
}

#[derive(Clone, Debug, Deserialize, PartialEq)]
#[serde(deny_unknown_fields, rename_all = "snake_case", tag = "kind")]
pub enum Ground {
    /// A 400 m athletics track: two straights and two semicircles, lanes outward from the inner
    /// edge; reddish surface, white lane lines, grass infield.
    Track {
        #[serde(default)]
        centre: [f64; 2],
        /// Direction of the straights, degrees from north.
        #[serde(default)]
        heading_deg: f64,
        #[serde(default = "Ground::default_lanes")]
        lanes: u32,
        #[serde(default = "Ground::default_lane_width")]
        lane_width_m: f64,
        #[serde(default = "Ground::default_straight")]
        straight_m: f64,
        /// Radius of the inner edge of lane 1.
        #[serde(default = "Ground::default_radius")]
        radius_m: f64,
    },
    /// A footbridge deck over lower surroundings, along a straight centre line through `centre`.
    Deck {
        #[serde(default)]
        centre: [f64; 2],
        /// Direction of the deck, degrees from north.
        #[serde(default)]
        heading_deg: f64,
        width_m: f64,
        length_m: f64,
        /// Height of the deck's ends above the surroundings.
        #[serde(default = "Ground::default_deck_height")]
        height_m: f64,
        /// The rise of the deck's middle above its ends (a parabolic profile).
        #[serde(default)]
        camber_m: f64,
    },
}

impl Ground {
    fn default_lanes() -> u32 {
        8
    }
    fn default_lane_width() -> f64 {
        1.22
    }
    fn default_straight() -> f64 {
        84.39
    }
    fn default_radius() -> f64 {
        36.5
    }
    fn default_deck_height() -> f64 {
        6.0
    }
}

#[derive(Clone, Debug, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct GcpSpec {
    pub name: String,
    /// East, north; the height is that of the surface there.
    pub position: [f64; 2],
    /// The target's pattern.
    #[serde(default)]
    pub design: TargetDesign,
    /// The target's side, metres (0.6 by default); for a coded marker, its black square's
    /// (a white margin of one cell is drawn around it).
    #[serde(default = "GcpSpec::default_size")]
    pub size_m: f64,
    /// A coded marker's id (`design = "coded"`).
    #[serde(default)]
    pub code: Option<u32>,
    /// A coded marker's dictionary (`geostride gcp find --dictionary` names; 4x4_50 by default).
    #[serde(default)]
    pub dictionary: Option<String>,
    /// A coded marker's cells, filled in by the loader that can draw them (OpenCV's).
    #[serde(skip)]
    pub cells: Option<crate::targets::codes::MarkerCells>,
}

impl GcpSpec {
    /// A 0.6 m checker target.
    pub fn new(name: impl Into<String>, position: [f64; 2]) -> GcpSpec {
        GcpSpec {
            name: name.into(),
            position,
            design: TargetDesign::default(),
            size_m: Self::default_size(),
            code: None,
            dictionary: None,
            cells: None,
        }
    }

    fn default_size() -> f64 {
        super::world::GCP_TARGET_M
    }

    /// A coded marker's dictionary: the one named, else 4x4_50.
    pub fn marker_dictionary(
        &self,
    ) -> Result<crate::targets::codes::Dictionary, crate::targets::codes::CodeError> {
        self.dictionary
            .as_deref()
            .unwrap_or("4x4_50")
            .parse()
            .map_err(crate::targets::codes::CodeError::UnknownDictionary)
    }
}

/// A GCP target's pattern, each on a square of the target's side.
#[derive(Clone, Copy, Debug, Default, Deserialize, PartialEq, Eq)]
#[serde(rename_all = "snake_case")]
pub enum TargetDesign {
    /// Four quadrants, black and white diagonally opposite (the north-east one black).
    #[default]
    Checker,
    /// An "X" (bow-tie): black triangles north and south, white east and west, meeting at the
    /// centre.
    X,
    /// A white cross (bars a fifth of the side wide) on a black square.
    Cross,
    /// An ArUco or AprilTag marker (`code`, `dictionary`), its top to the north.
    Coded,
}

#[derive(Clone, Copy, Debug, Deserialize, PartialEq, Eq)]
#[serde(rename_all = "snake_case")]
pub enum Gait {
    Walk,
    Run,
}

#[derive(Clone, Debug, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct PeopleSpec {
    /// `stream`: arrivals at `rate_per_s` at one end of the deck (or the track's start line);
    /// `group`: `count` people together from the start.
    #[serde(default = "PeopleSpec::default_mode")]
    pub mode: String,
    #[serde(default = "PeopleSpec::default_count")]
    pub count: u32,
    #[serde(default = "PeopleSpec::default_rate")]
    pub rate_per_s: f64,
    #[serde(default = "PeopleSpec::default_gait")]
    pub gait: Gait,
    /// Mean and standard deviation, m/s.
    #[serde(default = "PeopleSpec::default_speed")]
    pub speed_m_s: [f64; 2],
    /// Mean and standard deviation, metres.
    #[serde(default = "default_height")]
    pub height_m: [f64; 2],
    #[serde(default = "PeopleSpec::yes")]
    pub hats: bool,
    /// RGB.
    #[serde(default = "PeopleSpec::default_hat")]
    pub hat_colour: [u8; 3],
    #[serde(default = "PeopleSpec::yes")]
    pub shadows: bool,
    #[serde(default = "PeopleSpec::default_sun_azimuth")]
    pub sun_azimuth_deg: f64,
    #[serde(default = "PeopleSpec::default_sun_elevation")]
    pub sun_elevation_deg: f64,
    /// Lane (lateral position) changes per person per minute.
    #[serde(default = "PeopleSpec::default_lane_changes")]
    pub lane_changes_per_min: f64,
    /// Amplitude of the slow brightness changes (clouds), 0 to 1.
    #[serde(default = "PeopleSpec::default_light")]
    pub light_change: f64,
    /// People keep at least this far apart (feet to feet, metres): each arrival's lateral
    /// position and lane changes are drawn again until it passes everyone at this distance (in
    /// a stream waiting 0.2 s after every ten draws; a group's pack starts together), the
    /// widest of 300 draws otherwise.
    /// 0: people may pass through each other.
    #[serde(default)]
    pub min_spacing_m: f64,
}

impl PeopleSpec {
    fn default_mode() -> String {
        "stream".into()
    }
    fn default_count() -> u32 {
        20
    }
    fn default_rate() -> f64 {
        2.0
    }
    fn default_gait() -> Gait {
        Gait::Run
    }
    fn default_speed() -> [f64; 2] {
        [3.5, 0.4]
    }
    fn yes() -> bool {
        true
    }
    fn default_hat() -> [u8; 3] {
        [255, 0, 255]
    }
    fn default_sun_azimuth() -> f64 {
        135.0
    }
    fn default_sun_elevation() -> f64 {
        50.0
    }
    fn default_lane_changes() -> f64 {
        0.5
    }
    fn default_light() -> f64 {
        0.1
    }
}

impl Default for PeopleSpec {
    fn default() -> Self {
        toml::from_str("").expect("every field has a default")
    }
}

#[derive(Clone, Debug, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct OutputSpec {
    /// Write a video (`video.mp4` in H.264 where OpenCV can, else `video.avi` in MJPEG).
    #[serde(default = "PeopleSpec::yes")]
    pub video: bool,
    /// Write every n-th frame as PNG (0 = none).
    #[serde(default)]
    pub frames_every: u32,
    /// Checkerboard images taken with the same camera.
    #[serde(default = "OutputSpec::default_boards")]
    pub checkerboards: u32,
    /// RTK noise of the exported GCP coordinates: horizontal and vertical σ, metres.
    #[serde(default = "OutputSpec::default_gcp_noise")]
    pub gcp_noise_m: [f64; 2],
    /// Noise of the GCP picks on the first frame, pixels.
    #[serde(default = "OutputSpec::default_pick_noise")]
    pub pick_noise_px: f64,
    /// Grey-level noise of the rendered frames (σ, 0-255).
    #[serde(default = "OutputSpec::default_image_noise")]
    pub image_noise: f64,
    /// Frames rendered as a plain grey instead (a frame of sky, fog or a lens flare: no feature
    /// to place it by), by index; the truth still has the camera and people there.
    #[serde(default)]
    pub lost_frames: Vec<u32>,
}

impl OutputSpec {
    fn default_boards() -> u32 {
        10
    }
    fn default_gcp_noise() -> [f64; 2] {
        [0.01, 0.02]
    }
    fn default_pick_noise() -> f64 {
        0.5
    }
    fn default_image_noise() -> f64 {
        1.5
    }
}

impl Default for OutputSpec {
    fn default() -> Self {
        toml::from_str("").expect("every field has a default")
    }
}

impl Scene {
    /// Reads and checks a scene file.
    pub fn load(path: &Path) -> Result<Scene, FileError> {
        let ctx = FileCtx { path };
        let text = ctx.read_small_text("a TOML scene", 1 << 20)?;
        Self::parse(&ctx, &text)
    }

    pub fn parse(ctx: &FileCtx, text: &str) -> Result<Scene, FileError> {
        let scene: Scene = toml::from_str(text).map_err(|e| {
            let line = e
                .span()
                .map(|s| text[..s.start.min(text.len())].matches('\n').count() + 1);
            ctx.err(line, None, format!("not a valid scene: {}", e.message()))
        })?;
        let bad = |field: &str, m: &str| Err(ctx.err(None, Some(field), m.to_string()));
        let bad_field = |(field, m): Bad| ctx.err(None, Some(field), m);
        if let Some((section, key)) = crate::io::toml_nonfinite_key(text) {
            let field = if section.is_empty() {
                key
            } else {
                format!("{section}.{key}")
            };
            return bad(&field, "expected finite numbers (not nan or inf)");
        }
        // Video encoders take no fewer than one frame a second.
        if !(scene.fps >= 1.0 && scene.fps <= 240.0) {
            return bad("fps", "must be from 1 to 240 frames a second");
        }
        if !(scene.duration_s > 0.0 && scene.duration_s <= 3600.0) {
            return bad("duration_s", "must be in (0, 3600]");
        }
        if let Some([w, h]) = scene.camera.video_mode
            && !((16..=MAX_SIDE_PX).contains(&w) && (16..=MAX_SIDE_PX).contains(&h))
        {
            return bad(
                "camera.video_mode",
                &format!("expected [width, height] from 16 to {MAX_SIDE_PX} pixels"),
            );
        }
        match scene.people.mode.as_str() {
            "stream" | "group" => {}
            _ => return bad("people.mode", "must be 'stream' or 'group'"),
        }
        check_people(&scene.people).map_err(bad_field)?;
        if !(0.0..=10.0).contains(&scene.ground_detail) {
            return bad("ground_detail", "must be from 0 to 10");
        }
        if let Some(f) = &scene.survey_flight {
            check_survey_flight(f).map_err(bad_field)?;
        }
        check_output(&scene.output).map_err(bad_field)?;
        check_motion(&scene.camera.motion).map_err(bad_field)?;
        check_ground(&scene.ground).map_err(bad_field)?;
        check_gcp_names(&scene.gcp).map_err(bad_field)?;
        if matches!(scene.camera.motion, Motion::Follow { .. }) && scene.people.mode != "group" {
            return bad(
                "camera.motion",
                "'follow' follows a group: set people.mode = \"group\"",
            );
        }
        Ok(scene)
    }

    /// Number of frames.
    #[cfg(test)]
    pub(crate) fn frame_count(&self) -> usize {
        (self.duration_s * self.fps).round() as usize
    }

    /// The calibration file a scene names, relative to the scene file's folder.
    pub fn calibration_path(&self, scene_path: &Path) -> PathBuf {
        let p = Path::new(&self.camera.calibration);
        if p.is_absolute() {
            p.to_path_buf()
        } else {
            scene_path.parent().unwrap_or(Path::new(".")).join(p)
        }
    }
}

/// A scene field that fails its check, and why.
type Bad = (&'static str, String);

fn bad<T>(field: &'static str, m: &str) -> Result<T, Bad> {
    Err((field, m.to_string()))
}

/// The people's section within what the simulator models.
fn check_people(pp: &PeopleSpec) -> Result<(), Bad> {
    if pp.height_m[0] <= 0.5 || pp.height_m[0] > 2.5 || !(0.0..=0.5).contains(&pp.height_m[1]) {
        return bad(
            "people.height_m",
            "expected [mean, sd] with a mean from 0.5 to 2.5 m and an sd from 0 to 0.5 m",
        );
    }
    let speed_ok = pp.speed_m_s[0] > 0.0
        && pp.speed_m_s[0] <= 15.0
        && (0.0..=pp.speed_m_s[0] / 2.0).contains(&pp.speed_m_s[1]);
    if !speed_ok {
        return bad(
            "people.speed_m_s",
            "expected [mean, sd] with a mean from 0 to 15 m/s and an sd up to half the mean",
        );
    }
    if pp.count > 10_000 {
        return bad("people.count", "at most 10000");
    }
    if !(pp.rate_per_s > 0.0 && pp.rate_per_s <= 50.0) {
        return bad("people.rate_per_s", "must be in (0, 50]");
    }
    if !(0.0..=60.0).contains(&pp.lane_changes_per_min) {
        return bad("people.lane_changes_per_min", "must be from 0 to 60");
    }
    if !(0.0..=1.0).contains(&pp.light_change) {
        return bad("people.light_change", "must be from 0 to 1");
    }
    if !(0.0..=5.0).contains(&pp.min_spacing_m) {
        return bad("people.min_spacing_m", "must be from 0 to 5 m");
    }
    if !(1.0..=89.0).contains(&pp.sun_elevation_deg) {
        return bad(
            "people.sun_elevation_deg",
            "must be between 1 and 89 degrees",
        );
    }
    Ok(())
}

/// The survey flight's section.
fn check_survey_flight(f: &SurveyFlightSpec) -> Result<(), Bad> {
    if !(5.0..=500.0).contains(&f.altitude_m) {
        return bad("survey_flight.altitude_m", "must be from 5 to 500 m");
    }
    if !(f.area[0][0] < f.area[1][0] && f.area[0][1] < f.area[1][1]) {
        return bad(
            "survey_flight.area",
            "expected [[min_e, min_n], [max_e, max_n]] with min < max",
        );
    }
    if !((0.0..=0.95).contains(&f.forward_overlap) && (0.0..=0.95).contains(&f.side_overlap)) {
        return bad(
            "survey_flight.forward_overlap",
            "overlaps must be from 0 to 0.95",
        );
    }
    if f.obliques > 64 || !(0.0..=70.0).contains(&f.oblique_deg) {
        return bad(
            "survey_flight.obliques",
            "at most 64 oblique photos, tilted 0 to 70 degrees",
        );
    }
    let [w, h] = f.image_size;
    if !((64..=MAX_SIDE_PX).contains(&w) && (64..=MAX_SIDE_PX).contains(&h)) {
        return bad(
            "survey_flight.image_size",
            &format!("expected [width, height] from 64 to {MAX_SIDE_PX} pixels"),
        );
    }
    if !(f.rtk_noise_m.iter().all(|v| (0.0..=10.0).contains(v))
        && (0.0..=10.0).contains(&f.jitter_deg))
    {
        return bad(
            "survey_flight.rtk_noise_m",
            "expected two σ from 0 to 10 m, and a jitter from 0 to 10 degrees",
        );
    }
    Ok(())
}

/// The output section's counts and noise.
fn check_output(o: &OutputSpec) -> Result<(), Bad> {
    if o.checkerboards > 100 {
        return bad("output.checkerboards", "at most 100");
    }
    if !(o.gcp_noise_m.iter().all(|v| (0.0..=10.0).contains(v))) {
        return bad("output.gcp_noise_m", "expected two σ from 0 to 10 m");
    }
    if !(0.0..=100.0).contains(&o.pick_noise_px) {
        return bad("output.pick_noise_px", "must be from 0 to 100 px");
    }
    if !(0.0..=100.0).contains(&o.image_noise) {
        return bad("output.image_noise", "must be from 0 to 100");
    }
    Ok(())
}

/// The camera's motion.
fn check_motion(motion: &Motion) -> Result<(), Bad> {
    let jitter_ok = |j: f64| (0.0..=10.0).contains(&j);
    match motion {
        Motion::Path {
            waypoints,
            speed_m_s,
            jitter_deg,
            ..
        } => {
            if waypoints.is_empty() || !(*speed_m_s > 0.0) {
                return bad(
                    "camera.waypoints",
                    "a path needs waypoints and a positive speed_m_s",
                );
            }
            if !jitter_ok(*jitter_deg) {
                return bad("camera.motion.jitter_deg", "must be from 0 to 10 degrees");
            }
        }
        Motion::Hover {
            drift_m,
            drift_period_s,
            jitter_deg,
            below_horizon_deg,
            ..
        } => {
            if !(*drift_m >= 0.0 && *drift_period_s > 0.0 && jitter_ok(*jitter_deg)) {
                return bad(
                    "camera.motion",
                    "drift_m must not be negative, drift_period_s positive, jitter_deg from 0 to 10",
                );
            }
            if !(5.0..=90.0).contains(below_horizon_deg) {
                return bad(
                    "camera.motion.below_horizon_deg",
                    "must be from 5 (looking across the site) to 90 (straight down) degrees",
                );
            }
        }
        Motion::Follow {
            altitude_m,
            jitter_deg,
            ..
        } => {
            if !(*altitude_m > 2.0 && jitter_ok(*jitter_deg)) {
                return bad(
                    "camera.motion",
                    "altitude_m must be above 2 m, jitter_deg from 0 to 10",
                );
            }
        }
    }
    Ok(())
}

/// The ground's size.
fn check_ground(ground: &Ground) -> Result<(), Bad> {
    match ground {
        Ground::Deck {
            width_m,
            length_m,
            height_m,
            camber_m,
            ..
        } => {
            // People walk at least 0.45 m from the parapets.
            if !(*width_m >= 1.0 && *length_m > 0.0 && *length_m <= 2000.0) {
                return bad(
                    "ground.width_m",
                    "a deck needs a width of at least 1 m and a length up to 2000 m",
                );
            }
            if !(*height_m >= 0.0 && camber_m.abs() <= *length_m) {
                return bad(
                    "ground.height_m",
                    "height_m must not be negative and camber_m no more than the length",
                );
            }
        }
        Ground::Track {
            lanes,
            lane_width_m,
            straight_m,
            radius_m,
            ..
        } => {
            let track_ok = (1..=12).contains(lanes)
                && (0.9..=5.0).contains(lane_width_m)
                && *straight_m > 0.0
                && *straight_m <= 1000.0
                && (1.0..=1000.0).contains(radius_m);
            if !track_ok {
                return bad(
                    "ground",
                    "a track needs 1 to 12 lanes of 0.9 to 5 m, straights up to 1000 m and a radius of 1 to 1000 m",
                );
            }
        }
    }
    Ok(())
}

/// GCP names: unique, non-empty, writable to CSV.
fn check_gcp_names(gcps: &[GcpSpec]) -> Result<(), Bad> {
    let mut names = std::collections::HashSet::new();
    for g in gcps {
        if !names.insert(g.name.as_str()) {
            return bad(
                "gcp.name",
                &format!("two GCPs are named '{}'", crate::io::clip(&g.name, 40)),
            );
        }
        if g.name.trim().is_empty() || g.name.contains([',', '\n', '"']) {
            return bad(
                "gcp.name",
                "a GCP name must be non-empty text without commas or quotes",
            );
        }
        if !(g.size_m >= 0.05 && g.size_m <= 5.0) {
            return bad("gcp.size_m", "a target's side must be from 0.05 to 5 m");
        }
        let coded = g.design == TargetDesign::Coded;
        if coded != g.code.is_some() || (!coded && g.dictionary.is_some()) {
            return bad(
                "gcp.code",
                &format!(
                    "'{}': a coded target (design = \"coded\") takes a code, and only it takes \
                     a code or a dictionary",
                    crate::io::clip(&g.name, 40)
                ),
            );
        }
        if let Some(code) = g.code {
            let d = g
                .marker_dictionary()
                .map_err(|e| ("gcp.dictionary", e.to_string()))?;
            if code >= d.ids {
                return bad(
                    "gcp.code",
                    &format!(
                        "{code} is not in dictionary {} (0 to {})",
                        d.name,
                        d.ids - 1
                    ),
                );
            }
        }
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    const MINIMAL: &str = "[camera]\ncalibration = \"mini3pro\"\n[camera.motion]\nkind = \"hover\"\nposition = [0, 0, 30]\n\n[ground]\nkind = \"deck\"\nwidth_m = 4\nlength_m = 60\n";

    #[test]
    fn minimal_scene_takes_the_defaults() {
        let ctx = FileCtx {
            path: Path::new("s.toml"),
        };
        let s = Scene::parse(&ctx, MINIMAL).unwrap();
        assert_eq!(s.fps, 25.0);
        assert_eq!(s.frame_count(), 250);
        assert_eq!(s.people.hat_colour, [255, 0, 255]);
        assert_eq!(s.people.height_m, [1.7, 0.1]);
        assert!(matches!(s.camera.motion, Motion::Hover { drift_m, .. } if drift_m == 0.3));
        assert!(s.output.video);
    }

    #[test]
    fn mistakes_are_reported_with_their_line_or_field() {
        let ctx = FileCtx {
            path: Path::new("s.toml"),
        };
        let e = Scene::parse(
            &ctx,
            &format!("{MINIMAL}\n[people]\nheigth_m = [1.7, 0.1]\n"),
        )
        .unwrap_err();
        assert_eq!(e.line, Some(13), "{e}");
        assert!(e.message.contains("heigth_m"), "{e}");
        let e = Scene::parse(&ctx, &format!("fps = -1\n{MINIMAL}")).unwrap_err();
        assert_eq!(e.field.as_deref(), Some("fps"));
        let e = Scene::parse(&ctx, &MINIMAL.replace("hover", "teleport")).unwrap_err();
        assert!(
            e.message.contains("teleport") || e.message.contains("motion"),
            "{e}"
        );
    }
}
