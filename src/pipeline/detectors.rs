//! Each detector built from its `[detect]` settings and what the run knows by then (the
//! video, the camera and its first pose, the image scale). `registry::detector` picks one.

use std::path::Path;

use nalgebra::Vector2;

use super::error::RunError;
use super::project::Loaded;
use super::settings::{
    BackgroundSection, BodySettings, BoxesSection, ColourSection, HeadSource, MotionSection,
    OnnxSection,
};
use crate::camera::Camera;
use crate::detect::Detector;
use crate::detect::FrameView;
use crate::detect::boxes::{BoxFormat, ShadowModel, read_boxes};
use crate::detect::colour::{ColourDetector, ColourSettings, LearningColourDetector, Palette};
use crate::detect::person::{BoxesDetector, HeadsFromBodies};
use crate::geom::Rigid3;
use crate::video::source::FrameReader;

/// Memory the colour detector may fill with frames held back while it learns its palette.
pub const COLOUR_BUDGET_BYTES: usize = 1 << 30;

/// What a detector may need beside its settings.
pub struct DetectorInputs<'a> {
    pub l: &'a Loaded,
    pub video: &'a Path,
    pub camera: &'a Camera,
    /// The pose of the picked frame.
    pub first_pose: &'a Rigid3,
    /// Image scale at head height, pixels per metre.
    pub px_per_m: f64,
    /// The frames processed, when known.
    pub frames: Option<usize>,
}

impl DetectorInputs<'_> {
    fn input(&self, key: &str, e: impl Into<String>) -> RunError {
        RunError::Input(self.l.error("detect", key, e))
    }
}

fn colour_settings(c: &ColourSection, px_per_m: f64) -> ColourSettings {
    ColourSettings {
        target_rgb: c.colour,
        clusters: c.clusters,
        max_hue_difference_deg: c.max_hue_difference_deg,
        seed: c.seed,
        hat_diameter_m: c.hat_diameter_m,
        px_per_m,
        centroid_sigma_px: c.centroid_sigma_px,
        ..ColourSettings::default()
    }
}

/// A colour detector that learns its palette from `sample_frames` frames drawn from the
/// `frames` of the video as it goes by (every 97th pixel of each).
pub fn colour(c: &ColourSection, px_per_m: f64, frames: Option<usize>) -> Box<dyn Detector> {
    Box::new(LearningColourDetector::new(
        colour_settings(c, px_per_m),
        frames,
        c.sample_frames,
        97,
        COLOUR_BUDGET_BYTES,
    ))
}

/// The colour detector with a palette learnt before.
pub(crate) fn colour_with(
    c: &ColourSection,
    px_per_m: f64,
    palette: &Palette,
) -> Box<dyn Detector> {
    Box::new(ColourDetector::new(palette, colour_settings(c, px_per_m)))
}

/// The palette the colour detector learns over the whole video, learnt before the pass: the
/// frames it samples are read on their own (checked seeks), so that every chunk of the video
/// is detected with the one palette. Fails, in words, when no hat colour is found.
pub(crate) fn learn_palette(
    c: &ColourSection,
    video: &Path,
    px_per_m: f64,
    frames: usize,
) -> Result<Palette, String> {
    let mut learner = LearningColourDetector::new(
        colour_settings(c, px_per_m),
        Some(frames),
        c.sample_frames,
        97,
        COLOUR_BUDGET_BYTES,
    );
    let wanted = learner.frames_to_sample().to_vec();
    FrameReader::visit_frames(video, &wanted, |index, bgr, width, height| {
        learner.sample(&FrameView {
            index,
            width,
            height,
            bgr,
        })
    })
    .map_err(|e| e.to_string())?;
    learner
        .learn_now()
        .map(|(_, p)| p)
        .map_err(|e| e.to_string())
}

/// An external detector's boxes, filtered, their heads found.
pub fn boxes(b: &BoxesSection, x: &DetectorInputs) -> Result<Box<dyn Detector>, RunError> {
    let path = x.l.resolve(&b.boxes);
    let format = b.boxes_format.as_deref().and_then(BoxFormat::parse);
    let boxes = read_boxes(&path, format)?;
    if let Some(n) = x.frames
        && !boxes.iter().any(|b| b.frame < n)
    {
        let first = boxes.iter().map(|b| b.frame).min().unwrap_or(0);
        return Err(x.input(
            "boxes",
            format!(
                "none of the {} boxes is on one of the {n} frames processed (the first is on frame {first}, counting from 0): is it the box file of another video?",
                boxes.len()
            ),
        ));
    }
    if let Some(size) = x.camera.image_size
        && let Some(out) = boxes.iter().find(|r| {
            let c = (r.bbox[0] + r.bbox[2] / 2.0, r.bbox[1] + r.bbox[3] / 2.0);
            !(c.0 >= -0.5
                && c.1 >= -0.5
                && c.0 <= f64::from(size.width) - 0.5
                && c.1 <= f64::from(size.height) - 0.5)
        })
    {
        return Err(x.input(
            "boxes",
            format!(
                "{}:{}: the box [{}, {}, {}, {}] (x, y, width, height) has its centre outside the \
                 {}x{} frames: are these boxes for another size of the video? Scale them to its \
                 frames",
                path.display(),
                out.line,
                out.bbox[0],
                out.bbox[1],
                out.bbox[2],
                out.bbox[3],
                size.width,
                size.height
            ),
        ));
    }
    let shadow = if b.shadow_samples.is_empty() {
        None
    } else {
        Some(shadow_model(&b.shadow_samples, x)?)
    };
    let filter = b.filter(x.px_per_m, shadow);
    let inner = BoxesDetector::new(boxes, filter)
        .map_err(|e| x.input(e.key, e.to_string()))?
        .with_video_frames(x.frames);
    Ok(Box::new(heads_from_bodies(Box::new(inner), &b.body(), x)))
}

/// The most a camera's optical axis may lean from straight down for the overhead model to be
/// the default (it was trained on views up to 40° off nadir at a tile's centre).
pub const OVERHEAD_MAX_OFF_NADIR_DEG: f64 = 40.0;

/// How far the camera's optical axis leans from straight down (the site's −z), degrees.
pub fn off_nadir_deg(cam_from_world: &crate::geom::Rigid3) -> f64 {
    let axis_world = cam_from_world.rotation.inverse() * nalgebra::Vector3::z();
    (-axis_world.z).clamp(-1.0, 1.0).acos().to_degrees()
}

/// The model an `onnx` section runs: the one it names, else by the view (from above
/// geostride's own, from the side YOLOv3-tiny (COCO)).
pub fn onnx_model(
    o: &OnnxSection,
    l: &Loaded,
    first_pose: &Rigid3,
) -> Result<std::path::PathBuf, RunError> {
    use crate::detect::onnx::{YOLO_MODEL, bundled_model, given_model, overhead_model};
    let yolo = || {
        bundled_model().ok_or_else(|| {
            RunError::Input(l.error(
                "detect",
                "model",
                format!("the bundled model ({YOLO_MODEL}) is not here: run ./scripts/fetch-models.sh, or name a model"),
            ))
        })
    };
    Ok(match &o.model {
        Some(m) => given_model(m, l.resolve(m)),
        None if off_nadir_deg(first_pose) <= OVERHEAD_MAX_OFF_NADIR_DEG => {
            overhead_model().map_or_else(yolo, Ok)?
        }
        None => yolo()?,
    })
}

/// Whether an `onnx` detector's heads are its model's head points: `head = "model"` (refused
/// for a model that gives none), `"box"` never, unset where the model gives them.
fn heads_from_model(head: Option<HeadSource>, gives_heads: bool) -> Result<bool, String> {
    match head {
        Some(HeadSource::Model) if !gives_heads => Err(
            "head = \"model\": this model gives no head points (only geostride's overhead model, layout centre_heatmap, does); use head = \"box\"".into(),
        ),
        Some(HeadSource::Model) => Ok(true),
        Some(HeadSource::Box) => Ok(false),
        None => Ok(gives_heads),
    }
}

/// Whether a run's `onnx` detector takes its model's head points (then its tracks are heads,
/// projected as the hat detector's are, and not whole bodies' boxes).
pub fn onnx_model_heads(
    o: &OnnxSection,
    l: &Loaded,
    first_pose: &Rigid3,
) -> Result<bool, RunError> {
    if o.head == Some(HeadSource::Box) {
        return Ok(false);
    }
    // The model's session and metadata only: the detector itself is built (and tried on an
    // input) by `onnx`.
    use crate::detect::yolo::CENTRE_HEATMAP_LAYOUT;
    let model = onnx_model(o, l, first_pose)?;
    let net = crate::detect::onnx::OnnxModel::load(&model, 1)
        .map_err(|e| RunError::Input(l.error("detect", "model", e.to_string())))?;
    let gives_heads = match &o.layout {
        Some(layout) => layout == "centre_heatmap",
        None => net.metadata("geostride.layout").as_deref() == Some(CENTRE_HEATMAP_LAYOUT),
    };
    heads_from_model(o.head, gives_heads).map_err(|e| RunError::Input(l.error("detect", "head", e)))
}

/// A neural detector's boxes (an ONNX model on every frame), filtered, their heads found (or
/// the model's own, [`onnx_model_heads`]).
pub fn onnx(o: &OnnxSection, x: &DetectorInputs) -> Result<Box<dyn Detector>, RunError> {
    use crate::detect::neural::NeuralDetector;
    let model = onnx_model(o, x.l, x.first_pose)?;
    let settings = o.neural();
    let mut net =
        NeuralDetector::load(&model, &settings).map_err(|e| x.input("model", e.to_string()))?;
    let model_heads =
        heads_from_model(o.head, net.gives_heads()).map_err(|e| x.input("head", e))?;
    if o.tile.is_none() {
        // Tiles at the model's scale: a person about their height at the view's centre.
        let region = match (settings.roi, x.camera.image_size) {
            (Some([_, _, w, h]), _) => Some([w, h]),
            (None, Some(s)) => Some([s.width as usize, s.height as usize]),
            (None, None) => None,
        };
        let person_px = x.l.project.projection.head_height_m * x.px_per_m;
        if net.trained_gsd_m().is_some() {
            // A model that states its scales sees the frames at them (the pose's scale at head
            // height: within a few per cent of the ground's from 30 m), whole where they fit.
            net.settings.frame_gsd_m = Some(1.0 / x.px_per_m);
            net.settings.tile = 0;
            net.settings.overlap = person_px.ceil() as usize;
        } else if let Some(region) = region {
            let (tile, overlap) =
                crate::detect::neural::auto_tiles(region, net.input_wh(), person_px);
            net.settings.tile = tile;
            net.settings.overlap = overlap;
        }
    }
    let filter = o.filter(x.px_per_m);
    let inner = BoxesDetector::from_model(Box::new(net), o.stride, filter)
        .map_err(|e| x.input(e.key, e.to_string()))?;
    let heads = heads_from_bodies(Box::new(inner), &o.body(), x);
    let found: Box<dyn Detector> = if model_heads {
        Box::new(heads.with_model_heads())
    } else {
        Box::new(heads)
    };
    if !o.motion_check {
        return Ok(found);
    }
    // A moving blob that no box lies on (within a quarter of a person's height) is reported.
    let check = motion(&MotionSection::default(), x)?;
    let margin_px = 0.25 * x.l.project.projection.head_height_m * x.px_per_m;
    Ok(Box::new(crate::detect::check::CrossCheck::new(
        found, check, margin_px,
    )))
}

/// The shadows' colours from patches `[frame, x, y, w, h]` of the video.
fn shadow_model(samples: &[[f64; 5]], x: &DetectorInputs) -> Result<ShadowModel, RunError> {
    let mut patches = Vec::new();
    for s in samples {
        let whole = |v: f64| v >= 0.0 && v.fract() == 0.0 && v < 1e9;
        if !s.iter().all(|v| whole(*v)) || s[3] < 1.0 || s[4] < 1.0 {
            return Err(x.input(
                "shadow_samples",
                format!("expected [frame, x, y, width, height] in whole pixels, found {s:?}"),
            ));
        }
        let frame = s[0] as usize;
        if x.frames.is_some_and(|n| frame >= n) {
            return Err(x.input(
                "shadow_samples",
                format!("frame {frame} is beyond the frames processed"),
            ));
        }
        let bgr = crate::video::source::FrameReader::frame_bgr_bytes(x.video, frame)
            .map_err(|e| x.input("shadow_samples", e.to_string()))?;
        patches.push((bgr, [s[1], s[2], s[3], s[4]].map(|v| v as usize)));
    }
    let views: Vec<(crate::detect::FrameView, [usize; 4])> = patches
        .iter()
        .map(|((bgr, width, height), r)| {
            (
                crate::detect::FrameView {
                    index: 0,
                    width: *width,
                    height: *height,
                    bgr,
                },
                *r,
            )
        })
        .collect();
    ShadowModel::from_patches(&views).map_err(|e| x.input("shadow_samples", e.to_string()))
}

/// Background subtraction (a stationary camera), its blobs' heads found.
pub fn background(
    b: &BackgroundSection,
    x: &DetectorInputs,
) -> Result<Box<dyn Detector>, RunError> {
    let inner =
        crate::detect::background::BackgroundDetector::new(background_settings(b, x.px_per_m))
            .map_err(|e| x.input("method", e.to_string()))?;
    Ok(Box::new(heads_from_bodies(Box::new(inner), &b.body(), x)))
}

/// The background detector's settings for a project's `[detect]` and image scale.
pub fn background_settings(
    b: &BackgroundSection,
    px_per_m: f64,
) -> crate::detect::background::BackgroundSettings {
    crate::detect::background::BackgroundSettings {
        method: b.method,
        history: b.history,
        px_per_m,
        min_area_m2: b.min_area_m2,
        max_area_m2: b.max_area_m2,
        warmup_frames: b.warmup_frames,
        // The method's own threshold: MOG2's 16 would make nearly every pixel KNN foreground.
        ..crate::detect::background::BackgroundSettings::for_method(b.method)
    }
}

/// Frame differencing on the ground's motion (a moving camera), its blobs' heads found.
pub fn motion(m: &MotionSection, x: &DetectorInputs) -> Result<Box<dyn Detector>, RunError> {
    let inner = crate::detect::motion::MotionDetector::new(crate::detect::motion::MotionSettings {
        step_frames: m.step_frames,
        threshold: m.threshold,
        px_per_m: x.px_per_m,
        min_area_m2: m.min_area_m2,
        max_area_m2: m.max_area_m2,
        ..crate::detect::motion::MotionSettings::default()
    })
    .map_err(|e| x.input("step_frames", e.to_string()))?;
    Ok(Box::new(heads_from_bodies(Box::new(inner), &m.body(), x)))
}

/// A whole-body detector's boxes turned into heads: each moved `body_radius_m` in from the
/// box's end away from the nadir.
fn heads_from_bodies(
    inner: Box<dyn Detector>,
    body: &BodySettings,
    x: &DetectorInputs,
) -> HeadsFromBodies {
    // Where vertical lines meet: the image of a point straight below the camera.
    let below = x.first_pose.centre() - nalgebra::Vector3::new(0.0, 0.0, 100.0);
    let nadir = x
        .camera
        .project(&x.first_pose.apply(&below))
        .unwrap_or_else(|_| Vector2::new(x.camera.cx, x.camera.cy));
    HeadsFromBodies::new(
        inner,
        nadir,
        body.body_radius_m * x.px_per_m,
        body.error_model(),
    )
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::detect::background::{BackgroundSettings, Subtractor};

    #[test]
    fn each_background_method_gets_its_own_threshold() {
        for method in [Subtractor::Mog2, Subtractor::Knn] {
            let b = BackgroundSection {
                method,
                ..BackgroundSection::default()
            };
            let s = background_settings(&b, 40.0);
            assert_eq!(s.method, method);
            assert_eq!(
                s.var_threshold,
                BackgroundSettings::for_method(method).var_threshold
            );
            assert_eq!(s.px_per_m, 40.0);
        }
    }

    #[test]
    fn the_models_heads_are_taken_where_it_gives_them_unless_told() {
        use HeadSource::{Box as FromBox, Model};
        assert_eq!(heads_from_model(None, true), Ok(true));
        assert_eq!(heads_from_model(None, false), Ok(false));
        assert_eq!(heads_from_model(Some(FromBox), true), Ok(false));
        assert_eq!(heads_from_model(Some(Model), true), Ok(true));
        assert!(heads_from_model(Some(Model), false).is_err());
    }
}
