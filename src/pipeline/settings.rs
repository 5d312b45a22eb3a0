//! The stages' settings as a project file gives them: one tagged enum per stage (`kind = ...`),
//! each variant its own struct whose every key has one default (its `Default`). A key that is
//! not one of its kind's is refused with its line. `pipeline::registry` maps each variant to its
//! implementation.

use serde::de::{DeserializeOwned, Error as _};
use serde::{Deserialize, Deserializer, Serialize};

/// A stage section whose `kind` may be left out.
pub trait DefaultKind {
    /// The kind of a section without one.
    const DEFAULT_KIND: &'static str;
}

/// Reads a `kind`-tagged section, taking [`DefaultKind::DEFAULT_KIND`] when `kind` is absent.
pub(crate) fn with_default_kind<'de, D, T>(d: D) -> Result<T, D::Error>
where
    D: Deserializer<'de>,
    T: DeserializeOwned + DefaultKind,
{
    let mut table = toml::Table::deserialize(d)?;
    table
        .entry("kind")
        .or_insert_with(|| T::DEFAULT_KIND.into());
    T::deserialize(toml::Value::Table(table)).map_err(|e| D::Error::custom(e.message()))
}

// ---- pose ----

/// `[pose]`: where each frame's camera pose comes from.
#[derive(Clone, Debug, Deserialize, Serialize, PartialEq)]
#[serde(tag = "kind", rename_all = "snake_case")]
pub enum PoseSection {
    /// A hovering camera: key frames from the picked GCPs, carried to every frame.
    Hover(HoverSettings),
    /// A moving camera: key frames registered in a reference model (`geostride sfm`'s output),
    /// the frames between them from the key frame's 2D–3D points carried by the stabiliser.
    Model(ModelSettings),
    /// A camera that does not move, its pose from a calibration file (a Tsai calibration, or
    /// geostride JSON with `extrinsics`): no picks, no stabiliser.
    Fixed(FixedSettings),
}

impl DefaultKind for PoseSection {
    const DEFAULT_KIND: &'static str = "hover";
}

impl Default for PoseSection {
    fn default() -> Self {
        PoseSection::Hover(HoverSettings::default())
    }
}

impl PoseSection {
    /// The frame the picks were made on, when the project says.
    pub fn picks_frame(&self) -> Option<usize> {
        match self {
            PoseSection::Hover(h) => h.picks_frame,
            PoseSection::Model(_) | PoseSection::Fixed(_) => None,
        }
    }

    /// The stabiliser's key-frame settings: (fewest features, fraction, seconds); `None` for a
    /// fixed camera, which is not stabilised.
    pub fn key_frames(&self) -> Option<(usize, f64, Option<f64>)> {
        match self {
            PoseSection::Hover(h) => Some((h.min_features, h.key_fraction, h.key_every_s)),
            PoseSection::Model(m) => Some((m.min_features, m.key_fraction, m.key_every_s)),
            PoseSection::Fixed(_) => None,
        }
    }
}

/// `[pose] kind = "fixed"`.
#[derive(Clone, Debug, Deserialize, Serialize, PartialEq)]
#[serde(default, deny_unknown_fields)]
pub struct FixedSettings {
    /// The file with the camera's pose [default: `[camera] calibration`].
    pub extrinsics: Option<String>,
    /// The pose's σ: attitude about each axis, degrees.
    pub sigma_deg: f64,
    /// ... and the camera centre along each axis, metres.
    pub sigma_m: f64,
}

impl Default for FixedSettings {
    fn default() -> Self {
        // A camera calibrated on surveyed ground points: a few centimetres, a tenth of a degree.
        FixedSettings {
            extrinsics: None,
            sigma_deg: 0.1,
            sigma_m: 0.05,
        }
    }
}

/// `[pose] kind = "model"`.
#[derive(Clone, Debug, Deserialize, Serialize, PartialEq)]
#[serde(default, deny_unknown_fields)]
pub struct ModelSettings {
    /// The reference model's folder (`geostride sfm ... --gcps --out DIR`, georeferenced in
    /// the same survey); left out (no survey flight): built by the run from the video's own
    /// frames and the survey's picks on them (`model/` in the output).
    #[serde(skip_serializing_if = "String::is_empty")]
    pub model: String,
    /// The folder of the model's photos (their features are matched with the key frames');
    /// required with `model`.
    #[serde(skip_serializing_if = "String::is_empty")]
    pub model_images: String,
    /// Without `model`: a frame of the video in the model every this many seconds (and every
    /// picked frame).
    pub frames_every_s: f64,
    /// ... each matched with the next this many of them.
    pub sequential: usize,
    /// Model photos each key frame is matched with, nearest the last placed frame first
    /// (0: all of them).
    pub neighbours: usize,
    /// Features per key frame [default: the model's].
    pub max_features: Option<usize>,
    /// Fewest 2D–3D inliers that place a key frame.
    pub min_inliers: usize,
    /// Side of the square around each detection whose features are left out (the person and
    /// their shadow move), metres.
    pub mask_m: f64,
    /// A new key frame when fewer tracked features than this are left.
    pub min_features: usize,
    /// ... or fewer than this fraction of the key frame's.
    pub key_fraction: f64,
    /// ... or this long after the last one, seconds.
    pub key_every_s: Option<f64>,
}

impl Default for ModelSettings {
    fn default() -> Self {
        ModelSettings {
            model: String::new(),
            model_images: String::new(),
            frames_every_s: 0.5,
            sequential: 6,
            neighbours: 6,
            max_features: None,
            min_inliers: 30,
            mask_m: 2.0,
            min_features: 40,
            key_fraction: 0.5,
            key_every_s: Some(1.0),
        }
    }
}

/// `[pose] kind = "hover"`.
#[derive(Clone, Debug, Deserialize, Serialize, PartialEq)]
#[serde(default, deny_unknown_fields)]
pub struct HoverSettings {
    /// The frame the picks were made on [default: from the picks' image name].
    pub picks_frame: Option<usize>,
    /// A new key frame when fewer features than this are left.
    pub min_features: usize,
    /// ... or fewer than this fraction of the key frame's.
    pub key_fraction: f64,
    /// ... or this long after the last one, seconds.
    pub key_every_s: Option<f64>,
}

impl Default for HoverSettings {
    fn default() -> Self {
        HoverSettings {
            picks_frame: None,
            min_features: 40,
            key_fraction: 0.5,
            key_every_s: None,
        }
    }
}

// ---- detect ----

/// `[detect]`: the detector.
#[derive(Clone, Debug, Deserialize, Serialize, PartialEq)]
#[serde(tag = "kind", rename_all = "snake_case")]
pub enum DetectSection {
    /// Coloured hats (the paper's 3.1.1).
    Colour(ColourSection),
    /// An external detector's boxes.
    Boxes(BoxesSection),
    /// Background subtraction for a stationary camera.
    Background(BackgroundSection),
    /// A neural detector: a YOLO-family ONNX model run on every frame (the bundled YOLOv3-tiny
    /// by default), its boxes filtered and their heads found as for `boxes`.
    Onnx(OnnxSection),
    /// Frame differencing after warping frames onto each other through the ground: moving
    /// people under a moving camera.
    Motion(MotionSection),
}

impl DefaultKind for DetectSection {
    const DEFAULT_KIND: &'static str = "colour";
}

impl Default for DetectSection {
    fn default() -> Self {
        DetectSection::Colour(ColourSection::default())
    }
}

/// Two detections closer than a hat's diameter are one, for detectors without a hat size.
pub const DEFAULT_HAT_DIAMETER_M: f64 = 0.24;

impl DetectSection {
    /// The key a detector's failure is reported against.
    pub(crate) fn failure_key(&self) -> &'static str {
        match self {
            DetectSection::Colour(_) => "colour",
            DetectSection::Boxes(_) => "boxes",
            DetectSection::Background(_) => "method",
            DetectSection::Onnx(_) => "model",
            DetectSection::Motion(_) => "step_frames",
        }
    }

    /// Detections closer than this are one person, metres at head height.
    pub(crate) fn duplicate_m(&self) -> f64 {
        match self {
            DetectSection::Colour(c) => c.hat_diameter_m,
            _ => DEFAULT_HAT_DIAMETER_M,
        }
    }

    /// One person's length along a box, metres, where the detector gives bodies and says.
    pub(crate) fn person_m(&self) -> Option<f64> {
        match self {
            DetectSection::Colour(_) => None,
            DetectSection::Boxes(b) => b.person_m,
            DetectSection::Background(b) => b.person_m,
            DetectSection::Onnx(b) => b.person_m,
            DetectSection::Motion(b) => b.person_m,
        }
    }

    /// The body keys, where the detector gives whole bodies' boxes.
    pub(crate) fn body(&self) -> Option<BodySettings> {
        match self {
            DetectSection::Colour(_) => None,
            DetectSection::Boxes(b) => Some(b.body()),
            DetectSection::Background(b) => Some(b.body()),
            DetectSection::Onnx(b) => Some(b.body()),
            DetectSection::Motion(b) => Some(b.body()),
        }
    }

    /// The box file, for `boxes`.
    pub(crate) fn boxes_file(&self) -> Option<&str> {
        match self {
            DetectSection::Boxes(b) => Some(&b.boxes),
            _ => None,
        }
    }
}

/// `[detect] kind = "colour"`.
#[derive(Clone, Debug, Deserialize, Serialize, PartialEq)]
#[serde(default, deny_unknown_fields)]
pub struct ColourSection {
    /// The hats' colour, sRGB.
    pub colour: [u8; 3],
    /// k-means clusters of the palette.
    pub clusters: usize,
    /// Frames the palette is learnt from, drawn at random (seeded by `seed`).
    pub sample_frames: usize,
    pub hat_diameter_m: f64,
    pub max_hue_difference_deg: f64,
    /// σ of a hat's centre, pixels.
    pub centroid_sigma_px: f64,
    pub seed: u64,
}

impl Default for ColourSection {
    fn default() -> Self {
        ColourSection {
            colour: [255, 0, 255],
            clusters: 15,
            sample_frames: 50,
            hat_diameter_m: DEFAULT_HAT_DIAMETER_M,
            max_hue_difference_deg: 30.0,
            centroid_sigma_px: 0.5,
            seed: 0,
        }
    }
}

/// What a whole-body detector's boxes become: a head, with an error model (the keys that
/// `boxes` and `background` share).
#[derive(Clone, Debug, PartialEq)]
pub struct BodySettings {
    pub body_radius_m: f64,
    pub feet_radius_m: f64,
    pub feet_sd_m: f64,
    pub person_m: Option<f64>,
    pub error_px2: Option<[f64; 3]>,
    pub error_profile_px2: Option<Vec<[f64; 3]>>,
}

/// Seen from above, how far a box's ends reach beyond the body's axis (shoulders, arms, the
/// swinging legs), from the simulator's silhouette boxes of walkers and runners 30 m below:
/// 0.1 and 0.2 m bias the crowd demo's positions by a third of their σ inwards and outwards.
/// (0.55 m fitted the boxes of the bodies' loose 3D bounds the simulator drew before.)
pub const DEFAULT_BODY_RADIUS_M: f64 = 0.15;

impl BodySettings {
    /// The detection error model these settings give (checked when the project is read).
    pub(crate) fn error_model(&self) -> crate::detect::ErrorModel {
        use crate::detect::ErrorModel;
        match (&self.error_profile_px2, self.error_px2) {
            (Some(rows), _) => ErrorModel::from_rows(rows).unwrap_or_default(),
            (None, Some([v, hc, he])) => ErrorModel::paper(v, hc, he),
            (None, None) => ErrorModel::default(),
        }
    }

    /// How far a box reaches beyond the body (`projection::body`).
    pub(crate) fn shape(&self) -> crate::projection::body::BodyShape {
        crate::projection::body::BodyShape {
            reach_m: self.body_radius_m,
            head_radius_m: HEAD_RADIUS_M,
            feet_radius_m: self.feet_radius_m,
            feet_sd_m: self.feet_sd_m,
        }
    }
}

/// Seen from the side, a box's top is the top of the head, a head's radius out.
pub const HEAD_RADIUS_M: f64 = 0.1;
/// Seen from the side, how far a box's bottom lies before the person's ground point: the nearer
/// foot's toes. (The simulator's walkers, seen 15° to 60° below the horizon, fit 0.2 m; PETS
/// 2009's truth, the bottom of hand-drawn boxes, fits the ACF boxes at 0.05 m.)
pub const DEFAULT_FEET_RADIUS_M: f64 = 0.15;
/// σ of where the box's bottom lies under a walking body (the stride).
pub const DEFAULT_FEET_SD_M: f64 = 0.15;

/// `[detect] kind = "boxes"`.
#[derive(Clone, Debug, Deserialize, Serialize, PartialEq)]
#[serde(default, deny_unknown_fields)]
pub struct BoxesSection {
    /// The box file (MOTChallenge txt, JSON Lines or COCO JSON); required.
    pub boxes: String,
    /// `mot`, `jsonl` or `coco`; guessed from the file when absent.
    pub boxes_format: Option<String>,
    pub min_score: f64,
    /// Boxes are kept where their centre is inside `[x0, y0, x1, y1]`, pixels.
    pub roi: Option<[f64; 4]>,
    pub nms_iou: f64,
    pub merge_iou: f64,
    /// Limits on a box's aspect ratio.
    pub aspect: [f64; 2],
    /// Limits on a box's longer side, metres at head height.
    pub size_m: [f64; 2],
    /// Shadow samples `[frame, x, y, w, h]`, pixels: boxes mostly of that colour are dropped.
    pub shadow_samples: Vec<[f64; 5]>,
    pub max_shadow_fraction: f64,
    /// A body's radius seen from above, metres: the head is this far in from the box's end.
    pub body_radius_m: f64,
    /// Seen from the side: the box's bottom lies this far before the person's ground point (the
    /// nearer foot), metres.
    pub feet_radius_m: f64,
    /// σ of `feet_radius_m` (the stride), metres.
    pub feet_sd_m: f64,
    /// One person's length along a box, metres: boxes of two or more such lengths are split
    /// (off unless given: seen obliquely, one person's box is long too).
    pub person_m: Option<f64>,
    /// Detection error `[vertical, horizontal at the centre, horizontal at the left and right
    /// edges]`, px² (the paper's section 4.1.3) [default: `[10, 10, 20]`].
    pub error_px2: Option<[f64; 3]>,
    /// Detection error as rows `[t, vertical, horizontal]` (px²) at places `t` across the image
    /// (0 the vertical centre line, 1 the left and right edges), linear between them: what
    /// `geostride fit-error` writes. Instead of `error_px2`.
    pub error_profile_px2: Option<Vec<[f64; 3]>>,
}

impl Default for BoxesSection {
    fn default() -> Self {
        BoxesSection {
            boxes: String::new(),
            boxes_format: None,
            min_score: 0.3,
            roi: None,
            nms_iou: 0.5,
            merge_iou: 0.85,
            aspect: [0.25, 4.0],
            // Seen obliquely, a whole body's box is long: up to about 2.5 m at a 4K frame's edge.
            size_m: [0.25, 3.0],
            shadow_samples: Vec::new(),
            max_shadow_fraction: 0.6,
            body_radius_m: DEFAULT_BODY_RADIUS_M,
            feet_radius_m: DEFAULT_FEET_RADIUS_M,
            feet_sd_m: DEFAULT_FEET_SD_M,
            person_m: None,
            error_px2: None,
            error_profile_px2: None,
        }
    }
}

/// `[detect] kind = "onnx"`: the model's keys (`detect::neural`), then the box filter's and the
/// body keys as for `boxes`.
#[derive(Clone, Debug, Deserialize, Serialize, PartialEq)]
#[serde(default, deny_unknown_fields)]
pub struct OnnxSection {
    /// The ONNX model, or a bundled one by name: `overhead` (geostride's own,
    /// `models/overhead-person.onnx`) or `yolov3-tiny` (COCO,
    /// `third_party/models/yolov3-tiny.onnx`) [default: `overhead` where the camera looks within
    /// 40° of straight down, else `yolov3-tiny`].
    pub model: Option<String>,
    /// `darknet`, `yolov5`, `yolov8`, `yolox` or `centre_heatmap` [default: the model's metadata, else its outputs].
    pub layout: Option<String>,
    /// Input `[width, height]` [default: the model's].
    pub input_size: Option<[usize; 2]>,
    pub letterbox: bool,
    /// The model takes BGR.
    pub bgr: bool,
    /// Per channel `(v/255 − mean)/std`, in the model's channel order.
    pub mean: [f32; 3],
    pub std: [f32; 3],
    /// Classes kept, by name or id.
    pub classes: Vec<String>,
    /// The box threshold (the paper's 0.3).
    pub min_score: f64,
    pub nms_iou: f64,
    /// Also suppressed: a box lying more than this share of its area inside a better one
    /// [default: the model's metadata, else 1: never].
    pub nms_contained: Option<f64>,
    /// At most this many boxes a frame.
    pub max_boxes: usize,
    /// The model runs on every `stride`-th frame only (the trackers bridge the others).
    pub stride: usize,
    /// Tiles of this many pixels (0: whole frames), overlapping by `overlap` [default: chosen
    /// from the model's input, the frames and a person's length in them: `detect::neural::
    /// auto_tiles`].
    pub tile: Option<usize>,
    pub overlap: usize,
    /// The model runs only inside `[x, y, width, height]`, pixels (the paper's strip).
    pub roi: Option<[usize; 4]>,
    /// ONNX Runtime's threads (0: its choice).
    pub threads: usize,
    /// The box filter, as for `boxes`.
    pub merge_iou: f64,
    pub aspect: [f64; 2],
    pub size_m: [f64; 2],
    pub body_radius_m: f64,
    /// Seen from the side: the box's bottom lies this far before the person's ground point (the
    /// nearer foot), metres.
    pub feet_radius_m: f64,
    /// σ of `feet_radius_m` (the stride), metres.
    pub feet_sd_m: f64,
    pub person_m: Option<f64>,
    pub error_px2: Option<[f64; 3]>,
    pub error_profile_px2: Option<Vec<[f64; 3]>>,
    /// Where each person's head point comes from: `model` (the model's own head point) or
    /// `box` (found from the box's geometry) [default: `model` where the model gives one,
    /// as geostride's overhead model does, else `box`].
    pub head: Option<HeadSource>,
    /// Also run the motion detector (`kind = "motion"` with its defaults) as a check: its
    /// moving blobs that no box lies on are reported (`motion-check.csv`, the run report's
    /// `check_*` counts) [default: false; it about doubles the detection's time].
    pub motion_check: bool,
}

/// Where an `onnx` detector's head points come from.
#[derive(Clone, Copy, Debug, Deserialize, Serialize, PartialEq, Eq)]
#[serde(rename_all = "snake_case")]
pub enum HeadSource {
    /// The model's head point (its `centre_heatmap` output's).
    Model,
    /// Found from the box: [`crate::detect::head_from_box`] and `projection::body`.
    Box,
}

impl Default for OnnxSection {
    fn default() -> Self {
        let n = crate::detect::neural::NeuralSettings::default();
        let b = BoxesSection::default();
        OnnxSection {
            model: None,
            layout: None,
            input_size: None,
            letterbox: n.letterbox,
            bgr: n.bgr,
            mean: n.mean,
            std: n.std,
            classes: n.classes,
            min_score: n.min_score,
            nms_iou: n.nms_iou,
            nms_contained: None,
            max_boxes: n.max_boxes,
            stride: 1,
            tile: None,
            overlap: n.overlap,
            roi: None,
            threads: n.threads,
            merge_iou: b.merge_iou,
            aspect: b.aspect,
            size_m: b.size_m,
            body_radius_m: b.body_radius_m,
            feet_radius_m: b.feet_radius_m,
            feet_sd_m: b.feet_sd_m,
            person_m: None,
            error_px2: None,
            error_profile_px2: None,
            head: None,
            motion_check: false,
        }
    }
}

/// `[detect] kind = "background"`: the body keys as for `boxes`.
#[derive(Clone, Debug, Deserialize, Serialize, PartialEq)]
#[serde(default, deny_unknown_fields)]
pub struct BackgroundSection {
    pub method: crate::detect::background::Subtractor,
    /// Frames the background model remembers.
    pub history: i32,
    /// Frames before detections are trusted.
    pub warmup_frames: usize,
    /// Limits on a foreground blob's area, m² at head height.
    pub min_area_m2: f64,
    pub max_area_m2: f64,
    pub body_radius_m: f64,
    /// Seen from the side: the box's bottom lies this far before the person's ground point (the
    /// nearer foot), metres.
    pub feet_radius_m: f64,
    /// σ of `feet_radius_m` (the stride), metres.
    pub feet_sd_m: f64,
    pub person_m: Option<f64>,
    pub error_px2: Option<[f64; 3]>,
    pub error_profile_px2: Option<Vec<[f64; 3]>>,
}

impl Default for BackgroundSection {
    fn default() -> Self {
        BackgroundSection {
            method: crate::detect::background::Subtractor::Mog2,
            history: 300,
            warmup_frames: 25,
            min_area_m2: 0.08,
            max_area_m2: 4.0,
            body_radius_m: DEFAULT_BODY_RADIUS_M,
            feet_radius_m: DEFAULT_FEET_RADIUS_M,
            feet_sd_m: DEFAULT_FEET_SD_M,
            person_m: None,
            error_px2: None,
            error_profile_px2: None,
        }
    }
}

/// `[detect] kind = "motion"`: the body keys as for `boxes`.
#[derive(Clone, Debug, Deserialize, Serialize, PartialEq)]
#[serde(default, deny_unknown_fields)]
pub struct MotionSection {
    /// Frames between the compared ones (frame t against t - k and t + k).
    pub step_frames: usize,
    /// Grey-level difference (0-255) above which a pixel has changed.
    pub threshold: f64,
    /// Limits on a moving blob's area, m² at head height.
    pub min_area_m2: f64,
    pub max_area_m2: f64,
    pub body_radius_m: f64,
    pub feet_radius_m: f64,
    pub feet_sd_m: f64,
    pub person_m: Option<f64>,
    pub error_px2: Option<[f64; 3]>,
    pub error_profile_px2: Option<Vec<[f64; 3]>>,
}

impl Default for MotionSection {
    fn default() -> Self {
        // The detector's own defaults (`detect::motion::MotionSettings`).
        MotionSection {
            step_frames: 5,
            threshold: 25.0,
            min_area_m2: 0.08,
            max_area_m2: 4.0,
            body_radius_m: DEFAULT_BODY_RADIUS_M,
            feet_radius_m: DEFAULT_FEET_RADIUS_M,
            feet_sd_m: DEFAULT_FEET_SD_M,
            person_m: None,
            error_px2: None,
            error_profile_px2: None,
        }
    }
}

/// The body keys of `boxes` and `background`, gathered.
macro_rules! body_settings {
    ($t:ty) => {
        impl $t {
            /// The keys about bodies.
            pub fn body(&self) -> BodySettings {
                BodySettings {
                    body_radius_m: self.body_radius_m,
                    feet_radius_m: self.feet_radius_m,
                    feet_sd_m: self.feet_sd_m,
                    person_m: self.person_m,
                    error_px2: self.error_px2,
                    error_profile_px2: self.error_profile_px2.clone(),
                }
            }
        }
    };
}
body_settings!(BoxesSection);
body_settings!(BackgroundSection);
body_settings!(OnnxSection);
body_settings!(MotionSection);

// ---- track ----

/// `[track]`: the tracker.
#[derive(Clone, Debug, Deserialize, Serialize, PartialEq)]
#[serde(tag = "kind", rename_all = "snake_case")]
pub enum TrackSection {
    /// Global assignment with camera-motion-compensated prediction.
    Association(AssociationSection),
    /// Features followed through every frame (a second decoding pass).
    Klt(KltSection),
}

impl DefaultKind for TrackSection {
    const DEFAULT_KIND: &'static str = "association";
}

impl Default for TrackSection {
    fn default() -> Self {
        TrackSection::Association(AssociationSection::default())
    }
}

impl TrackSection {
    /// Tracks shorter than this are dropped, seconds.
    pub fn min_length_s(&self) -> f64 {
        match self {
            TrackSection::Association(a) => a.min_length_s,
            TrackSection::Klt(k) => k.min_length_s,
        }
    }
}

/// `[track] kind = "association"`.
#[derive(Clone, Debug, Deserialize, Serialize, PartialEq)]
#[serde(default, deny_unknown_fields)]
pub struct AssociationSection {
    /// Gate between prediction and detection, metres at head height.
    pub gate_m: f64,
    /// Detections before a track is confirmed.
    pub confirm_frames: usize,
    /// Longest gap a track survives, seconds.
    pub max_gap_s: f64,
    /// Tracks shorter than this are dropped, seconds.
    pub min_length_s: f64,
}

impl Default for AssociationSection {
    fn default() -> Self {
        AssociationSection {
            gate_m: 0.35,
            confirm_frames: 3,
            max_gap_s: 0.5,
            min_length_s: 0.5,
        }
    }
}

/// `[track] kind = "klt"`.
#[derive(Clone, Debug, Deserialize, Serialize, PartialEq)]
#[serde(default, deny_unknown_fields)]
pub struct KltSection {
    /// Gate between a track's box and a detection, metres at head height.
    pub gate_m: f64,
    /// Longest gap a track survives, seconds.
    pub max_gap_s: f64,
    /// Tracks shorter than this are dropped, seconds.
    pub min_length_s: f64,
    /// Lucas–Kanade window side, full-resolution pixels.
    pub window_px: f64,
    /// Pyramid levels.
    pub levels: i32,
    /// The tracker works on a copy of each frame reduced to about this many pixels per metre
    /// at head height (and no wider than 1920 pixels).
    #[serde(default = "default_working_px_per_m")]
    pub working_px_per_m: f64,
    /// Features per track: fewer and it is topped up, at most this many.
    pub min_features: usize,
    pub max_features: usize,
    /// Tracks with fewer detections than this are dropped.
    pub min_hits: usize,
}

fn default_working_px_per_m() -> f64 {
    32.0
}

impl Default for KltSection {
    fn default() -> Self {
        KltSection {
            gate_m: 0.35,
            max_gap_s: 0.5,
            min_length_s: 0.5,
            window_px: 50.0,
            levels: 2,
            working_px_per_m: 32.0,
            min_features: 5,
            max_features: 40,
            min_hits: 5,
        }
    }
}

// ---- smooth ----

/// `[smooth]`: the smoother.
#[derive(Clone, Debug, Deserialize, Serialize, PartialEq)]
#[serde(tag = "kind", rename_all = "snake_case")]
pub enum SmoothSection {
    /// Kalman filter and RTS smoother per track, process noise by EM.
    KalmanRts(KalmanRtsSection),
    /// The projected points as they are.
    None(NoSmoothing),
}

impl DefaultKind for SmoothSection {
    const DEFAULT_KIND: &'static str = "kalman_rts";
}

impl Default for SmoothSection {
    fn default() -> Self {
        SmoothSection::KalmanRts(KalmanRtsSection::default())
    }
}

/// `[smooth] kind = "kalman_rts"`.
#[derive(Clone, Debug, Deserialize, Serialize, PartialEq)]
#[serde(default, deny_unknown_fields)]
pub struct KalmanRtsSection {
    /// Estimate the process noise by EM.
    pub em: bool,
    /// How the process noise is constrained.
    pub model: crate::smooth::NoiseModel,
    /// Initial process noise, σ per step.
    pub q_position_m: f64,
    pub q_velocity_m_s: f64,
}

impl Default for KalmanRtsSection {
    fn default() -> Self {
        KalmanRtsSection {
            em: true,
            model: crate::smooth::NoiseModel::WhiteAcceleration,
            q_position_m: 0.5,
            q_velocity_m_s: 0.25,
        }
    }
}

/// `[smooth] kind = "none"`: no keys.
#[derive(Clone, Debug, Default, Deserialize, Serialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct NoSmoothing {}

// ---- ground ----

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
    /// Local planes fitted robustly to a reference model's points (`geostride sfm`'s output)
    /// in a `window_m` square around each person (the paper: 2 m), wider where too few;
    /// `model` left out: the `model` pose's.
    LocalPlanes {
        #[serde(default, skip_serializing_if = "String::is_empty")]
        model: String,
        #[serde(default = "default_window")]
        window_m: f64,
    },
}

fn default_window() -> f64 {
    2.0
}

fn default_degree() -> usize {
    2
}

impl GroundSection {
    /// The checks of the section on its own (files are checked by the project).
    pub fn check(&self) -> Result<(), Bad> {
        match self {
            GroundSection::Deck {
                centre_line,
                width_m,
                stations,
                degree,
            } => {
                if centre_line.len() < 2 {
                    return bad(
                        "centre_line",
                        "a deck needs a centre line of at least 2 points",
                    );
                }
                if !(*width_m > 0.0) {
                    return bad("width_m", "must be positive");
                }
                if stations.len() == 1 {
                    return bad(
                        "stations",
                        "give at least 2 stations, or none to fit the GCPs",
                    );
                }
                if stations.windows(2).any(|w| !(w[1][0] > w[0][0])) {
                    return bad(
                        "stations",
                        "stations are [chainage, height] with the chainages increasing",
                    );
                }
                if *degree > 3 {
                    return bad("degree", "a deck profile polynomial has degree 0 to 3");
                }
            }
            GroundSection::LocalPlanes { window_m, .. } => {
                if !(*window_m > 0.0 && *window_m <= 50.0) {
                    return bad("window_m", "expected 0 to 50 metres");
                }
            }
            GroundSection::Plane { .. } | GroundSection::Dem { .. } => {}
        }
        Ok(())
    }

    /// What the ground reads beside the project file, as written there.
    pub fn reads(&self) -> Option<GroundInput<'_>> {
        match self {
            GroundSection::Dem { path } => Some(GroundInput::File(path)),
            GroundSection::LocalPlanes { model, .. } if !model.is_empty() => {
                Some(GroundInput::Model(model))
            }
            GroundSection::LocalPlanes { .. } => None,
            GroundSection::Plane { .. } | GroundSection::Deck { .. } => None,
        }
    }
}

/// A file or a folder a ground reads.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum GroundInput<'a> {
    /// A file (`path`): a DEM.
    File(&'a str),
    /// A reference model's folder (`model`), read whole.
    Model(&'a str),
}

// ---- checks ----

/// A bad value: its key and what was expected.
pub type Bad = (&'static str, String);

fn bad(key: &'static str, message: &str) -> Result<(), Bad> {
    Err((key, message.to_string()))
}

impl PoseSection {
    /// The values' checks (the types are serde's).
    pub fn check(&self) -> Result<(), Bad> {
        match self {
            PoseSection::Hover(h) => {
                if !(0.0..=1.0).contains(&h.key_fraction) {
                    return bad("key_fraction", "expected a fraction from 0 to 1");
                }
                if h.key_every_s.is_some_and(|s| !(s > 0.0)) {
                    return bad("key_every_s", "must be positive");
                }
                if h.min_features < 4 {
                    return bad("min_features", "must be at least 4");
                }
                Ok(())
            }
            PoseSection::Fixed(f) => {
                if !(f.sigma_deg >= 0.0 && f.sigma_deg <= 90.0) {
                    return bad("sigma_deg", "expected 0 to 90 degrees");
                }
                if !(f.sigma_m >= 0.0 && f.sigma_m.is_finite()) {
                    return bad("sigma_m", "expected 0 or more metres");
                }
                if f.extrinsics.as_deref() == Some("") {
                    return bad(
                        "extrinsics",
                        "name the file with the camera's pose, or leave the key out to use [camera] calibration",
                    );
                }
                Ok(())
            }
            PoseSection::Model(m) => {
                if !m.model.is_empty() && m.model_images.is_empty() {
                    return bad(
                        "model_images",
                        "a reference model needs the folder of its photos: model_images = \"photos\"",
                    );
                }
                if m.model.is_empty() && !m.model_images.is_empty() {
                    return bad(
                        "model",
                        "model_images is given without its model: name the model's folder (geostride sfm PHOTOS --gcps GCPS --out model), or leave both out to build the model from the video",
                    );
                }
                if !(m.frames_every_s > 0.0 && m.frames_every_s.is_finite()) {
                    return bad("frames_every_s", "must be positive seconds");
                }
                if m.sequential == 0 {
                    return bad("sequential", "at least 1 (the frames each is matched with)");
                }
                if !(0.0..=1.0).contains(&m.key_fraction) {
                    return bad("key_fraction", "expected a fraction from 0 to 1");
                }
                if m.key_every_s.is_some_and(|s| !(s > 0.0)) {
                    return bad("key_every_s", "must be positive");
                }
                if m.min_features < 4 {
                    return bad("min_features", "must be at least 4");
                }
                if m.min_inliers < 6 {
                    return bad("min_inliers", "must be at least 6");
                }
                if !(m.mask_m >= 0.0) {
                    return bad("mask_m", "must be 0 or more");
                }
                if m.max_features.is_some_and(|n| n < 100) {
                    return bad("max_features", "at least 100");
                }
                Ok(())
            }
        }
    }
}

/// A box filter's values, checked before any work (the image scale does not matter here).
fn filter_check(f: &crate::detect::boxes::BoxFilter) -> Result<(), Bad> {
    f.check().map_err(|e| (e.key, e.message))
}

impl BoxesSection {
    /// The box filter at `px_per_m` pixels a metre at head height.
    pub fn filter(
        &self,
        px_per_m: f64,
        shadow: Option<crate::detect::boxes::ShadowModel>,
    ) -> crate::detect::boxes::BoxFilter {
        crate::detect::boxes::BoxFilter {
            min_score: self.min_score,
            roi: self.roi,
            merge_iou: self.merge_iou,
            nms_iou: self.nms_iou,
            aspect: self.aspect,
            size_m: self.size_m,
            person_m: self.person_m.unwrap_or(1.0),
            max_split: if self.person_m.is_some() { 4 } else { 1 },
            shadow,
            max_shadow_fraction: self.max_shadow_fraction,
            ..crate::detect::boxes::BoxFilter::new(px_per_m)
        }
    }
}

impl OnnxSection {
    /// The box filter at `px_per_m` pixels a metre at head height.
    pub fn filter(&self, px_per_m: f64) -> crate::detect::boxes::BoxFilter {
        crate::detect::boxes::BoxFilter {
            min_score: self.min_score,
            merge_iou: self.merge_iou,
            nms_iou: self.nms_iou,
            aspect: self.aspect,
            size_m: self.size_m,
            person_m: self.person_m.unwrap_or(1.0),
            max_split: if self.person_m.is_some() { 4 } else { 1 },
            ..crate::detect::boxes::BoxFilter::new(px_per_m)
        }
    }

    /// How the model is run, as `geostride detect` takes it.
    pub fn neural(&self) -> crate::detect::neural::NeuralSettings {
        use crate::detect::yolo::Layout;
        crate::detect::neural::NeuralSettings {
            layout: self.layout.as_deref().and_then(Layout::from_name),
            want_darknet: self.layout.as_deref() == Some("darknet"),
            input_size: self.input_size,
            letterbox: self.letterbox,
            bgr: self.bgr,
            mean: self.mean,
            std: self.std,
            classes: self.classes.clone(),
            min_score: self.min_score,
            nms_iou: self.nms_iou,
            nms_contained: self.nms_contained,
            max_boxes: self.max_boxes,
            tile: self.tile.unwrap_or(0),
            overlap: self.overlap,
            roi: self.roi,
            threads: self.threads,
            // The pose's scale, set where the detector is made.
            frame_gsd_m: None,
        }
    }
}

impl DetectSection {
    /// The values' checks (that the box file exists is the project's).
    pub fn check(&self) -> Result<(), Bad> {
        match self {
            DetectSection::Colour(c) => c.check(),
            DetectSection::Boxes(b) => {
                if b.boxes.is_empty() {
                    return bad(
                        "boxes",
                        "the 'boxes' detector needs a box file: boxes = \"detections.txt\"",
                    );
                }
                if let Some(f) = &b.boxes_format
                    && crate::detect::boxes::BoxFormat::parse(f).is_none()
                {
                    return bad("boxes_format", "expected 'mot', 'jsonl' or 'coco'");
                }
                filter_check(&b.filter(1.0, None))?;
                b.body().check()
            }
            DetectSection::Background(b) => b.body().check(),
            DetectSection::Motion(m) => {
                if !(1..=60).contains(&m.step_frames) {
                    return bad("step_frames", "expected 1 to 60 frames");
                }
                if !(m.threshold > 0.0 && m.threshold < 255.0) {
                    return bad(
                        "threshold",
                        "expected a grey-level difference between 0 and 255",
                    );
                }
                if !(m.min_area_m2 >= 0.0 && m.max_area_m2 > m.min_area_m2) {
                    return bad("max_area_m2", "expected 0 <= min_area_m2 < max_area_m2");
                }
                m.body().check()
            }
            DetectSection::Onnx(o) => {
                if let Some(l) = &o.layout
                    && !["darknet", "yolov5", "yolov8", "yolox", "centre_heatmap"]
                        .contains(&l.as_str())
                {
                    return bad(
                        "layout",
                        "expected 'darknet', 'yolov5', 'yolov8', 'yolox' or 'centre_heatmap'",
                    );
                }
                if o.stride == 0 {
                    return bad("stride", "expected 1 or more");
                }
                if o.motion_check && o.stride > 1 {
                    return bad(
                        "motion_check",
                        "the check compares every frame: it needs stride = 1 (the frames the model skips would all count as missed)",
                    );
                }
                o.neural().check()?;
                filter_check(&o.filter(1.0))?;
                o.body().check()
            }
        }
    }
}

impl ColourSection {
    fn check(&self) -> Result<(), Bad> {
        if !(2..=64).contains(&self.clusters) {
            return bad("clusters", "expected 2 to 64");
        }
        if self.sample_frames == 0 {
            return bad("sample_frames", "must be at least 1");
        }
        if !(self.hat_diameter_m > 0.0) {
            return bad("hat_diameter_m", "must be positive");
        }
        if self.sample_frames > 10_000 {
            return bad("sample_frames", "at most 10000");
        }
        if !(self.max_hue_difference_deg > 0.0 && self.max_hue_difference_deg <= 180.0) {
            return bad("max_hue_difference_deg", "expected an angle from 0 to 180°");
        }
        if !(self.centroid_sigma_px > 0.0) {
            return bad("centroid_sigma_px", "must be positive");
        }
        Ok(())
    }
}

impl BodySettings {
    fn check(&self) -> Result<(), Bad> {
        if self
            .error_px2
            .is_some_and(|e| e.iter().any(|v| !(v.is_finite() && *v > 0.0)))
        {
            return bad("error_px2", "expected three positive variances, px²");
        }
        if let Some(rows) = &self.error_profile_px2 {
            if self.error_px2.is_some() {
                return bad(
                    "error_profile_px2",
                    "give error_px2 or error_profile_px2, not both",
                );
            }
            if crate::detect::ErrorModel::from_rows(rows).is_none() {
                return bad(
                    "error_profile_px2",
                    "expected rows [t, vertical, horizontal]: t rising within 0 to 1, positive \
                     variances in px² (as geostride fit-error writes them)",
                );
            }
        }
        if !(self.body_radius_m >= 0.0) {
            return bad("body_radius_m", "must not be negative");
        }
        if !(self.feet_radius_m >= 0.0 && self.feet_radius_m < 2.0) {
            return bad("feet_radius_m", "expected metres from 0 to 2 (default 0.1)");
        }
        if !(self.feet_sd_m >= 0.0 && self.feet_sd_m < 2.0) {
            return bad("feet_sd_m", "expected metres from 0 to 2 (default 0.15)");
        }
        if self.person_m.is_some_and(|m| !(m > 0.0)) {
            return bad("person_m", "must be positive");
        }
        Ok(())
    }
}

impl TrackSection {
    /// The values' checks.
    pub fn check(&self) -> Result<(), Bad> {
        let (gate_m, max_gap_s, min_length_s) = match self {
            TrackSection::Association(a) => {
                if a.confirm_frames == 0 {
                    return bad("confirm_frames", "must be at least 1");
                }
                (a.gate_m, a.max_gap_s, a.min_length_s)
            }
            TrackSection::Klt(k) => {
                if !(k.window_px >= 5.0) || !(0..=6).contains(&k.levels) {
                    return bad(
                        "window_px",
                        "window_px must be at least 5 and levels 0 to 6",
                    );
                }
                if !(k.working_px_per_m >= 5.0 && k.working_px_per_m.is_finite()) {
                    return bad(
                        "working_px_per_m",
                        "must be at least 5 pixels per metre (a person a few pixels wide)",
                    );
                }
                if k.min_features == 0 || k.max_features < k.min_features {
                    return bad(
                        "min_features",
                        "min_features must be at least 1 and no more than max_features",
                    );
                }
                (k.gate_m, k.max_gap_s, k.min_length_s)
            }
        };
        if !(gate_m > 0.0) || !(max_gap_s >= 0.0) {
            return bad(
                "gate_m",
                "gate_m must be positive and max_gap_s not negative",
            );
        }
        if !(min_length_s >= 0.0) {
            return bad("min_length_s", "must not be negative");
        }
        Ok(())
    }
}

impl SmoothSection {
    /// The values' checks.
    pub fn check(&self) -> Result<(), Bad> {
        match self {
            SmoothSection::KalmanRts(k) => {
                if !(k.q_position_m > 0.0) {
                    return bad("q_position_m", "must be positive");
                }
                if !(k.q_velocity_m_s > 0.0) {
                    return bad("q_velocity_m_s", "must be positive");
                }
                Ok(())
            }
            SmoothSection::None(_) => Ok(()),
        }
    }
}
