//! A neural person detector: any YOLO-family ONNX model (`detect::onnx`), its outputs decoded
//! (`detect::yolo`), over the whole frame or in tiles (small people seen from 30 m), inside a
//! region of interest.

use std::path::{Path, PathBuf};

use serde::{Deserialize, Serialize};

use super::boxes::intersection;
use super::onnx::{OnnxError, OnnxModel, Output};
use super::opencv_dnn::OpenCvNet;
use super::yolo::{Fit, Keep, Layout, RawBox, decode, nms, tiles, to_input};

/// How the model is run and read.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct NeuralSettings {
    /// The output layout [default: the model's `darknet_yolo` metadata, else told from its
    /// outputs' shapes].
    pub layout: Option<Layout>,
    /// Input width and height [default: the model's, else 640].
    pub input_size: Option<[usize; 2]>,
    /// Letterbox (one scale, grey bars) or stretch to the input.
    pub letterbox: bool,
    /// Per channel `(v/255 − mean)/std`, in the model's channel order.
    pub mean: [f32; 3],
    pub std: [f32; 3],
    /// The model wants BGR (darknet and most YOLO exports want RGB).
    pub bgr: bool,
    /// Classes kept, by name (the model's `names` metadata) or by id.
    pub classes: Vec<String>,
    /// Lowest score kept (the paper's box threshold: 0.3).
    pub min_score: f64,
    /// Non-maximum suppression's overlap.
    pub nms_iou: f64,
    /// Also suppressed: a box lying more than this share of its area inside a better one
    /// [default: the model's `geostride.nms_contained` metadata, else 1: never].
    pub nms_contained: Option<f64>,
    pub max_boxes: usize,
    /// Tiles of this many pixels (0: the whole frame at once), overlapping by `overlap`; each
    /// tile is fitted to the input, so a tile smaller than the input is enlarged.
    pub tile: usize,
    pub overlap: usize,
    /// Only inside `[x, y, width, height]` (the paper: a strip along the entry edge).
    pub roi: Option<[usize; 4]>,
    /// ONNX Runtime's threads (0: its choice).
    pub threads: usize,
    /// The darknet layout was asked for: the model must carry its anchors (`layout` cannot
    /// name them).
    pub want_darknet: bool,
    /// The frames' ground sample distance, metres a pixel: a model that states the scales it
    /// was trained at (`geostride.gsd_m`) sees the frames scaled to them ([`model_scale`]).
    pub frame_gsd_m: Option<f64>,
}

/// The most threads a model runs on: more than any machine geostride runs on has cores.
pub const MAX_THREADS: usize = 256;
/// The model's input side, pixels.
pub const INPUT_SIDE: std::ops::RangeInclusive<usize> = 32..=4096;
/// The smallest tile, pixels.
pub const MIN_TILE: usize = 32;
/// The most tiles one frame is cut into.
pub const MAX_TILES: usize = 4096;
/// The most tiles a frame is cut into when the tiling is chosen ([`auto_tiles`]): each is a run
/// of the model.
pub const MAX_AUTO_TILES: usize = 24;
/// The most boxes a frame keeps.
pub const MAX_BOXES: usize = 10_000;

impl NeuralSettings {
    /// Every value in range and consistent with the others (the same check for `geostride
    /// detect` and a project's `[detect] kind = "onnx"`): the key at fault, as the project file
    /// names it, and what was expected.
    pub fn check(&self) -> Result<(), (&'static str, String)> {
        if let Some([w, h]) = self.input_size
            && !(INPUT_SIDE.contains(&w) && INPUT_SIDE.contains(&h))
        {
            return Err((
                "input_size",
                format!(
                    "{w}x{h}: expected {} to {} pixels a side",
                    INPUT_SIDE.start(),
                    INPUT_SIDE.end()
                ),
            ));
        }
        if self
            .mean
            .iter()
            .any(|m| !(m.is_finite() && m.abs() <= 10.0))
        {
            return Err((
                "mean",
                format!(
                    "{:?}: expected numbers from -10 to 10 (subtracted from v/255)",
                    self.mean
                ),
            ));
        }
        if self
            .std
            .iter()
            .any(|s| !(s.is_finite() && *s >= 1e-6 && *s <= 1e3))
        {
            return Err((
                "std",
                format!(
                    "{:?}: expected numbers from 1e-6 to 1000 (dividing v/255 − mean)",
                    self.std
                ),
            ));
        }
        for (key, v) in [("min_score", self.min_score), ("nms_iou", self.nms_iou)] {
            if !(0.0..=1.0).contains(&v) {
                return Err((key, format!("{v}: expected a fraction from 0 to 1")));
            }
        }
        if let Some(v) = self.nms_contained
            && !(v > 0.0 && v <= 1.0)
        {
            return Err((
                "nms_contained",
                format!("{v}: expected a fraction above 0, up to 1 (1: never)"),
            ));
        }
        if !(1..=MAX_BOXES).contains(&self.max_boxes) {
            return Err((
                "max_boxes",
                format!(
                    "{}: expected 1 to {MAX_BOXES} boxes a frame",
                    self.max_boxes
                ),
            ));
        }
        if self.classes.is_empty() || self.classes.iter().any(|c| c.trim().is_empty()) {
            return Err((
                "classes",
                "name at least one class (\"person\"), none empty".into(),
            ));
        }
        if self.tile > 0 && (self.tile < MIN_TILE || self.overlap > self.tile / 2) {
            return Err((
                "tile",
                format!(
                    "tiles of {} pixels overlapping by {}: expected tiles of {MIN_TILE} pixels or more, overlapping by at most half a tile (0: whole frames)",
                    self.tile, self.overlap
                ),
            ));
        }
        if let Some([x, y, w, h]) = self.roi {
            let side = crate::camera::MAX_IMAGE_SIDE as usize;
            if w == 0 || h == 0 || x >= side || y >= side || w > side || h > side {
                return Err((
                    "roi",
                    format!(
                        "[{x}, {y}, {w}, {h}]: expected x, y, width, height in pixels, the width and height at least 1"
                    ),
                ));
            }
        }
        if self.threads > MAX_THREADS {
            return Err((
                "threads",
                format!(
                    "{}: expected 0 (ONNX Runtime's choice) to {MAX_THREADS}",
                    self.threads
                ),
            ));
        }
        Ok(())
    }
}

impl Default for NeuralSettings {
    fn default() -> Self {
        NeuralSettings {
            layout: None,
            input_size: None,
            letterbox: true,
            mean: [0.0; 3],
            std: [1.0; 3],
            bgr: false,
            classes: vec!["person".into()],
            min_score: 0.3,
            nms_iou: 0.45,
            nms_contained: None,
            max_boxes: 300,
            tile: 0,
            overlap: 64,
            roi: None,
            threads: 0,
            want_darknet: false,
            frame_gsd_m: None,
        }
    }
}

/// Why the detector cannot run.
#[derive(Debug, thiserror::Error)]
pub enum NeuralError {
    #[error(transparent)]
    Onnx(#[from] OnnxError),
    /// The model and the settings disagree (layout, classes, input size).
    #[error("{}: {message}", path.display())]
    Model { path: PathBuf, message: String },
    /// A setting out of range ([`NeuralSettings::check`]).
    #[error("{key}: {message}")]
    Settings { key: &'static str, message: String },
}

/// One detection in frame pixels.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Detected {
    pub xywh: [f64; 4],
    pub score: f64,
    pub class: usize,
    /// The top of the head in frame pixels, where the model gives it.
    pub head: Option<[f64; 2]>,
}

/// The model's class names from its metadata: a JSON list, or Ultralytics' `{0: 'person', ...}`.
pub fn parse_names(text: &str) -> Option<Vec<String>> {
    if let Ok(v) = serde_json::from_str::<Vec<String>>(text) {
        return Some(v);
    }
    let inner = text.trim().strip_prefix('{')?.strip_suffix('}')?;
    let mut names = Vec::new();
    for (k, item) in inner.split(',').enumerate() {
        let (id, name) = item.split_once(':')?;
        if id.trim().parse::<usize>().ok()? != k {
            return None;
        }
        names.push(name.trim().trim_matches(['\'', '"']).to_string());
    }
    Some(names)
}

/// What runs the model: ONNX Runtime, or OpenCV's dnn (the oracle and benchmark peer).
pub enum Backend {
    OnnxRuntime(OnnxModel),
    OpenCv(OpenCvNet),
}

impl Backend {
    fn run(&mut self, input: Vec<f32>, wh: [usize; 2]) -> Result<Vec<Output>, OnnxError> {
        match self {
            Backend::OnnxRuntime(m) => m.run(input, wh),
            Backend::OpenCv(n) => n.run(input, wh),
        }
    }
}

/// Tiles for a model whose input is `input_wh` on a region of `region_wh` pixels where a person
/// is about `person_px` long: none when the region fits the input; otherwise tiles of the
/// input's shorter side, or the region's shorter side when that is smaller, so that the model
/// never sees the people shrunk, yet two and a half people long and overlapping by one, so that
/// every person is whole in some tile; a quarter larger at a time while that makes more than
/// [`MAX_AUTO_TILES`]. `(tile, overlap)`, pixels; `(0, 0)` for whole frames.
pub fn auto_tiles(region_wh: [usize; 2], input_wh: [usize; 2], person_px: f64) -> (usize, usize) {
    let [w, h] = region_wh;
    if w <= input_wh[0] && h <= input_wh[1] {
        return (0, 0);
    }
    let person = if person_px.is_finite() {
        person_px.clamp(1.0, 1e6).ceil() as usize
    } else {
        1
    };
    let mut tile = input_wh[0]
        .min(input_wh[1])
        .min(w.min(h))
        .max((5 * person).div_ceil(2))
        .max(MIN_TILE);
    while tile < w.max(h) {
        let overlap = person.min(tile / 2);
        if tiles([0, 0, w, h], tile, overlap).len() <= MAX_AUTO_TILES {
            return (tile, overlap);
        }
        tile += tile.div_ceil(4);
    }
    (0, 0)
}

/// How much a frame of `frame_gsd_m` metres a pixel is scaled before a model trained at
/// `trained_gsd_m` (`[finest, coarsest]`) sees it: not at all inside the trained range, else to
/// the range's geometric middle (scripts/train_detector.py's `model_scale` is the same rule).
pub fn model_scale(frame_gsd_m: f64, trained_gsd_m: [f64; 2]) -> f64 {
    let [lo, hi] = trained_gsd_m;
    if (lo..=hi).contains(&frame_gsd_m) {
        1.0
    } else {
        frame_gsd_m / (lo * hi).sqrt()
    }
}

/// The most pixels a side of what the model sees at once at its own scale: a larger region is
/// cut into tiles.
const MODEL_SCALE_SIDE: usize = 4096;

/// A model's `geostride.gsd_m` metadata: `[finest, coarsest]` metres a pixel.
fn parse_trained_gsd(text: &str) -> Option<[f64; 2]> {
    let v: Vec<f64> = serde_json::from_str(text).ok()?;
    match v[..] {
        [lo, hi] if lo.is_finite() && hi.is_finite() && 0.0 < lo && lo <= hi && hi < 10.0 => {
            Some([lo, hi])
        }
        _ => None,
    }
}

/// `bgr` (`wh`) averaged over blocks of `k`×`k` pixels (a large reduction without aliasing).
fn shrink_bgr(bgr: &[u8], wh: [usize; 2], k: usize) -> (Vec<u8>, [usize; 2]) {
    let [w, h] = wh;
    let (ow, oh) = (w.div_ceil(k), h.div_ceil(k));
    let mut out = vec![0u8; ow * oh * 3];
    for oy in 0..oh {
        for ox in 0..ow {
            let mut sum = [0u32; 3];
            let mut n = 0u32;
            for y in oy * k..((oy + 1) * k).min(h) {
                for x in ox * k..((ox + 1) * k).min(w) {
                    for c in 0..3 {
                        sum[c] += u32::from(bgr[(y * w + x) * 3 + c]);
                    }
                    n += 1;
                }
            }
            for c in 0..3 {
                out[(oy * ow + ox) * 3 + c] = ((sum[c] + n / 2) / n) as u8;
            }
        }
    }
    (out, [ow, oh])
}

impl super::person::FrameBoxes for NeuralDetector {
    fn summary(&self) -> Vec<(String, f64)> {
        let mut v = vec![
            ("model_tile_px".into(), self.settings.tile as f64),
            ("model_tile_overlap_px".into(), self.settings.overlap as f64),
        ];
        if let Some(f) = self.frame_scale() {
            v.push(("model_frame_scale".into(), f));
        }
        v
    }

    fn boxes(
        &mut self,
        bgr: &[u8],
        wh: [usize; 2],
    ) -> Result<Vec<super::person::FoundBox>, crate::PluginError> {
        Ok(self
            .detect(bgr, wh)
            .map_err(|e| crate::PluginError::from(e.to_string()))?
            .into_iter()
            .map(|d| super::person::FoundBox {
                bbox: d.xywh,
                score: d.score,
                head: d.head,
            })
            .collect())
    }
}

/// A loaded detector.
pub struct NeuralDetector {
    path: PathBuf,
    model: Backend,
    layout: Layout,
    input_wh: [usize; 2],
    class_ids: Vec<usize>,
    pub names: Vec<String>,
    pub settings: NeuralSettings,
    /// The scales the model was trained at, metres a pixel (its `geostride.gsd_m`).
    trained_gsd_m: Option<[f64; 2]>,
    /// The suppression's containment in use ([`NeuralSettings::nms_contained`], else the
    /// model's, else 1).
    nms_contained: f64,
}

impl NeuralDetector {
    /// The model's input `[width, height]`, pixels.
    pub fn input_wh(&self) -> [usize; 2] {
        self.input_wh
    }

    /// The same detector with OpenCV's dnn running the model (its settings, layout and classes
    /// as read through ONNX Runtime).
    pub fn on_opencv(&self) -> Result<NeuralDetector, NeuralError> {
        Ok(NeuralDetector {
            path: self.path.clone(),
            model: Backend::OpenCv(OpenCvNet::load(&self.path)?),
            layout: self.layout.clone(),
            input_wh: self.input_wh,
            class_ids: self.class_ids.clone(),
            names: self.names.clone(),
            settings: self.settings.clone(),
            trained_gsd_m: self.trained_gsd_m,
            nms_contained: self.nms_contained,
        })
    }

    /// Loads `path` and checks the settings against it.
    pub fn load(path: &Path, settings: &NeuralSettings) -> Result<NeuralDetector, NeuralError> {
        settings
            .check()
            .map_err(|(key, message)| NeuralError::Settings { key, message })?;
        let model = OnnxModel::load(path, settings.threads)?;
        let bad = |message: String| NeuralError::Model {
            path: path.to_path_buf(),
            message,
        };
        let names = model
            .metadata("names")
            .and_then(|t| parse_names(&t))
            .unwrap_or_default();
        let darknet = model.metadata("darknet_yolo");
        // A model trained by geostride says its layout; one this build does not know is refused.
        let own = match model.metadata("geostride.layout") {
            Some(l) if l == super::yolo::CENTRE_HEATMAP_LAYOUT => Some(Layout::CentreHeatmap),
            Some(l) => {
                return Err(bad(format!(
                    "its geostride.layout metadata is '{}': this geostride reads '{}' (a model \
                     from another version of scripts/train_detector.py?)",
                    crate::io::clip(&l, 60),
                    super::yolo::CENTRE_HEATMAP_LAYOUT
                )));
            }
            None => None,
        };
        let trained_gsd_m = match model.metadata("geostride.gsd_m") {
            Some(t) => Some(parse_trained_gsd(&t).ok_or_else(|| {
                bad(format!(
                    "its geostride.gsd_m metadata is '{}': expected [finest, coarsest] metres a pixel, as JSON",
                    crate::io::clip(&t, 60)
                ))
            })?),
            None => None,
        };
        let own_contained = match model.metadata("geostride.nms_contained") {
            Some(t) => Some(
                t.trim()
                    .parse::<f64>()
                    .ok()
                    .filter(|v| *v > 0.0 && *v <= 1.0)
                    .ok_or_else(|| {
                        bad(format!(
                            "its geostride.nms_contained metadata is '{}': expected a fraction above 0, up to 1",
                            crate::io::clip(&t, 60)
                        ))
                    })?,
            ),
            None => None,
        };
        if let Some(g) = settings.frame_gsd_m
            && trained_gsd_m.is_none()
        {
            return Err(bad(format!(
                "frames of {:.2} cm a pixel were to be scaled to the model's scale, but it does not state the scales it was trained at (geostride.gsd_m metadata): give tiles instead",
                g * 100.0
            )));
        }
        let names = if own.is_some() && names.is_empty() {
            vec!["person".to_string()]
        } else {
            names
        };
        let input_wh = match (settings.input_size, &model.input_shape[..]) {
            (Some(s), _) => s,
            (None, [_, _, h, w]) if *h > 0 && *w > 0 => {
                let [w, h] = [*w as usize, *h as usize];
                if !(INPUT_SIDE.contains(&w) && INPUT_SIDE.contains(&h)) {
                    return Err(bad(format!(
                        "its input is {w}x{h} pixels: expected {} to {} a side",
                        INPUT_SIDE.start(),
                        INPUT_SIDE.end()
                    )));
                }
                [w, h]
            }
            _ => [640, 640],
        };
        if let [_, c, h, w] = model.input_shape[..] {
            if c > 0 && c != 3 {
                return Err(bad(format!("the input has {c} channels; an image has 3")));
            }
            if (h > 0 && h as usize != input_wh[1]) || (w > 0 && w as usize != input_wh[0]) {
                return Err(bad(format!(
                    "the model's input is {w}x{h}; input_size says {}x{}",
                    input_wh[0], input_wh[1]
                )));
            }
        } else if !model.input_shape.is_empty() {
            return Err(bad(format!(
                "the input's shape is {:?}; an image detector takes [1, 3, H, W]",
                model.input_shape
            )));
        }
        if settings.want_darknet && darknet.is_none() {
            return Err(bad(
                "the darknet layout needs the anchors in the model's darknet_yolo metadata (scripts/darknet_to_onnx.py writes them)".into(),
            ));
        }
        let layout = match (&settings.layout, darknet) {
            // A model that says its own layout is not read as another (its rows would decode
            // into boxes that mean nothing).
            (Some(l), _) if own.as_ref().is_some_and(|o| o.name() != l.name()) => {
                return Err(bad(format!(
                    "its geostride.layout metadata says it is a {} model: the {} layout was asked for (leave the layout out)",
                    own.as_ref().map_or("", Layout::name),
                    l.name()
                )));
            }
            (Some(l), _) => l.clone(),
            (None, _) if own.is_some() => own.clone().expect("checked"),
            (None, Some(meta)) => darknet_layout(&meta).map_err(|e| bad(e.to_string()))?,
            (None, None) => {
                // Told from one run's output shapes.
                let mut m = model;
                let outs = m.run(vec![0.0; 3 * input_wh[0] * input_wh[1]], input_wh)?;
                let shapes: Vec<Vec<i64>> = outs.iter().map(|o| o.shape.clone()).collect();
                let guessed = Layout::guess(&shapes, (!names.is_empty()).then_some(names.len()))
                    .ok_or_else(|| {
                        bad(format!(
                            "cannot tell the output layout from the outputs' shapes {shapes:?}: name it (layout = darknet, yolov5, yolov8 or yolox)"
                        ))
                    })?;
                return Self::finish(
                    path,
                    Backend::OnnxRuntime(m),
                    guessed,
                    input_wh,
                    names,
                    settings,
                );
            }
        };
        let mut d = Self::finish(
            path,
            Backend::OnnxRuntime(model),
            layout,
            input_wh,
            names,
            settings,
        )?;
        d.trained_gsd_m = trained_gsd_m;
        if settings.nms_contained.is_none() {
            d.nms_contained = own_contained.unwrap_or(1.0);
        }
        Ok(d)
    }

    /// The scales the model was trained at, metres a pixel (`[finest, coarsest]`), when it says.
    pub fn trained_gsd_m(&self) -> Option<[f64; 2]> {
        self.trained_gsd_m
    }

    /// The suppression's containment in use (1: none): [`NeuralSettings::nms_contained`].
    pub fn nms_contained(&self) -> f64 {
        self.nms_contained
    }

    /// How much the frames are scaled before the model sees them, for a model that states the
    /// scales it was trained at ([`model_scale`]); `None` for one fitted to its input size.
    pub fn frame_scale(&self) -> Option<f64> {
        match (self.settings.frame_gsd_m, self.trained_gsd_m) {
            (Some(g), Some(t)) => Some(model_scale(g, t)),
            // Frames of no stated scale are taken to be at the model's own.
            (None, Some(_)) => Some(1.0),
            _ => None,
        }
    }

    fn finish(
        path: &Path,
        model: Backend,
        layout: Layout,
        input_wh: [usize; 2],
        names: Vec<String>,
        settings: &NeuralSettings,
    ) -> Result<NeuralDetector, NeuralError> {
        let mut class_ids = Vec::new();
        for c in &settings.classes {
            if let Ok(id) = c.parse::<usize>() {
                class_ids.push(id);
            } else if let Some(id) = names.iter().position(|n| n == c) {
                class_ids.push(id);
            } else if names.is_empty() {
                return Err(NeuralError::Model {
                    path: path.to_path_buf(),
                    message: format!(
                        "the model names no classes, so '{c}' cannot be found: give class ids (classes = [\"0\"])"
                    ),
                });
            } else {
                return Err(NeuralError::Model {
                    path: path.to_path_buf(),
                    message: format!(
                        "the model has no class '{c}'; its classes: {}",
                        names
                            .iter()
                            .take(12)
                            .cloned()
                            .collect::<Vec<_>>()
                            .join(", ")
                            + if names.len() > 12 { ", ..." } else { "" }
                    ),
                });
            }
        }
        let mut d = NeuralDetector {
            path: path.to_path_buf(),
            model,
            layout,
            input_wh,
            class_ids,
            names,
            settings: settings.clone(),
            trained_gsd_m: None,
            nms_contained: settings.nms_contained.unwrap_or(1.0),
        };
        // The layout against the outputs, once, before any frame.
        let outs = d
            .model
            .run(vec![0.0; 3 * input_wh[0] * input_wh[1]], input_wh)?;
        let outputs: Vec<(Vec<i64>, Vec<f32>)> =
            outs.into_iter().map(|o| (o.shape, o.data)).collect();
        if not_numbers(&outputs) {
            return Err(NeuralError::Model {
                path: path.to_path_buf(),
                message: "its outputs on a blank image are not numbers (NaN or infinite): a broken or wrongly exported model".into(),
            });
        }
        let keep = Keep {
            classes: &d.class_ids,
            min_score: 1.0,
        };
        decode(&d.layout, &outputs, input_wh, &keep).map_err(|m| NeuralError::Model {
            path: path.to_path_buf(),
            message: format!("its outputs do not fit the {} layout: {m}", d.layout.name()),
        })?;
        Ok(d)
    }

    /// Whether the model gives each box's head point (the centre heatmap layout does).
    pub fn gives_heads(&self) -> bool {
        matches!(self.layout, Layout::CentreHeatmap)
    }

    /// The layout in use.
    pub fn layout(&self) -> &Layout {
        &self.layout
    }

    /// The input size in use.
    pub fn input_size(&self) -> [usize; 2] {
        self.input_wh
    }

    /// One region of a frame (`bgr`, `wh`) through the model: its boxes in frame pixels.
    fn run_region(
        &mut self,
        bgr: &[u8],
        wh: [usize; 2],
        region: [usize; 4],
    ) -> Result<Vec<RawBox>, NeuralError> {
        let s = &self.settings;
        let [x0, y0, rw, rh] = region;
        let crop: Vec<u8> = if region == [0, 0, wh[0], wh[1]] {
            bgr.to_vec()
        } else {
            let mut c = Vec::with_capacity(rw * rh * 3);
            for y in y0..y0 + rh {
                c.extend_from_slice(&bgr[(y * wh[0] + x0) * 3..(y * wh[0] + x0 + rw) * 3]);
            }
            c
        };
        let (input, fit, input_wh) = match self.frame_scale() {
            // At the model's own scale: one scale, padded right and below to whole strides.
            Some(f) => {
                let k = (1.0 / f).floor() as usize;
                let (crop, [cw, ch], f) = if k >= 2 {
                    let (c, cwh) = shrink_bgr(&crop, [rw, rh], k);
                    (c, cwh, f * k as f64)
                } else {
                    (crop, [rw, rh], f)
                };
                let side = |v: usize| {
                    ((v as f64 * f).round() as usize)
                        .max(1)
                        .next_multiple_of(32)
                };
                let fit = Fit {
                    scale: [f, f],
                    pad: [0.0, 0.0],
                };
                let input_wh = [side(cw), side(ch)];
                let input = to_input(&crop, [cw, ch], input_wh, &fit, s.mean, s.std, s.bgr);
                let fit = Fit {
                    scale: [f * cw as f64 / rw as f64, f * ch as f64 / rh as f64],
                    pad: [0.0, 0.0],
                };
                (input, fit, input_wh)
            }
            None => {
                let fit = Fit::new([rw, rh], self.input_wh, s.letterbox);
                let input = to_input(&crop, [rw, rh], self.input_wh, &fit, s.mean, s.std, s.bgr);
                (input, fit, self.input_wh)
            }
        };
        let outs = self.model.run(input, input_wh)?;
        let outputs: Vec<(Vec<i64>, Vec<f32>)> =
            outs.into_iter().map(|o| (o.shape, o.data)).collect();
        if not_numbers(&outputs) {
            return Err(NeuralError::Model {
                path: self.path.clone(),
                message: "its outputs are not numbers (NaN or infinite) for this frame: a broken or wrongly exported model".into(),
            });
        }
        let keep = Keep {
            classes: &self.class_ids,
            min_score: s.min_score,
        };
        let boxes = decode(&self.layout, &outputs, input_wh, &keep).map_err(|message| {
            NeuralError::Model {
                path: self.path.clone(),
                message,
            }
        })?;
        Ok(boxes
            .into_iter()
            .map(|b| {
                let m = fit.to_image(&b.xywh);
                let head = b.head.map(|h| {
                    let p = fit.point_to_image(&h);
                    [p[0] + x0 as f64, p[1] + y0 as f64]
                });
                RawBox {
                    xywh: [m[0] + x0 as f64, m[1] + y0 as f64, m[2], m[3]],
                    head,
                    ..b
                }
            })
            .collect())
    }

    /// The detections of one frame (interleaved BGR, `wh`), best first.
    pub fn detect(&mut self, bgr: &[u8], wh: [usize; 2]) -> Result<Vec<Detected>, NeuralError> {
        let region = match self.settings.roi {
            Some([x, y, w, h]) => {
                let x = x.min(wh[0]);
                let y = y.min(wh[1]);
                [x, y, w.min(wh[0] - x), h.min(wh[1] - y)]
            }
            None => [0, 0, wh[0], wh[1]],
        };
        if region[2] == 0 || region[3] == 0 {
            return Err(NeuralError::Settings {
                key: "roi",
                message: format!(
                    "{:?} lies outside the {}x{} frame: nothing would be searched",
                    self.settings.roi.unwrap_or_default(),
                    wh[0],
                    wh[1]
                ),
            });
        }
        // At the model's own scale, what it would see of the region at once is bounded.
        let most = self
            .frame_scale()
            .map(|f| (MODEL_SCALE_SIDE as f64 / f).floor() as usize);
        let parts = if let Some(side) = most
            && self.settings.tile == 0
            && region[2].max(region[3]) > side
        {
            tiles(region, side, self.settings.overlap.min(side / 2))
        } else if self.settings.tile == 0 {
            vec![region]
        } else {
            tiles(region, self.settings.tile, self.settings.overlap)
        };
        if parts.len() > MAX_TILES {
            return Err(NeuralError::Settings {
                key: "tile",
                message: format!(
                    "tiles of {} pixels cut the {}x{} frame into {}: at most {MAX_TILES}; give larger tiles",
                    self.settings.tile,
                    region[2],
                    region[3],
                    parts.len()
                ),
            });
        }
        let mut found = Vec::with_capacity(parts.len());
        for p in &parts {
            found.push((*p, self.run_region(bgr, wh, *p)?));
        }
        let all = if parts.len() > 1 {
            drop_cut_by_tiles(found, region)
        } else {
            found.into_iter().flat_map(|(_, b)| b).collect()
        };
        let mut kept = nms(
            all,
            self.settings.nms_iou,
            self.nms_contained,
            self.settings.max_boxes,
        );
        if parts.len() > 1 {
            kept = merge_cut(kept);
        }
        Ok(kept
            .into_iter()
            .map(|b| Detected {
                xywh: b.xywh,
                score: b.score,
                class: b.class,
                head: b.head,
            })
            .collect())
    }
}

/// Whether some output is all NaN or infinite (the model's numbers are not to be read).
fn not_numbers(outputs: &[(Vec<i64>, Vec<f32>)]) -> bool {
    outputs
        .iter()
        .any(|(_, d)| !d.is_empty() && d.iter().all(|v| !v.is_finite()))
}

/// How near a tile's inner edge a box ends and is cut by it, pixels.
const TILE_CUT_PX: f64 = 2.0;

/// Boxes cut by a tile's inner edge (one that is not the searched region's) where another tile
/// holds the same person whole: dropped before the suppression, which would otherwise keep the
/// cut box when it scores higher (its ends are not the person's: a box's bottom is where the
/// person stands).
fn drop_cut_by_tiles(found: Vec<([usize; 4], Vec<RawBox>)>, region: [usize; 4]) -> Vec<RawBox> {
    let f = |v: usize| v as f64;
    let (rx0, ry0) = (f(region[0]), f(region[1]));
    let (rx1, ry1) = (rx0 + f(region[2]), ry0 + f(region[3]));
    let cut = |t: &[usize; 4], b: &RawBox| {
        let (tx0, ty0) = (f(t[0]), f(t[1]));
        let (tx1, ty1) = (tx0 + f(t[2]), ty0 + f(t[3]));
        let [x, y, w, h] = b.xywh;
        (tx0 > rx0 && x <= tx0 + TILE_CUT_PX)
            || (ty0 > ry0 && y <= ty0 + TILE_CUT_PX)
            || (tx1 < rx1 && x + w >= tx1 - TILE_CUT_PX)
            || (ty1 < ry1 && y + h >= ty1 - TILE_CUT_PX)
    };
    let tagged: Vec<(usize, bool, RawBox)> = found
        .into_iter()
        .enumerate()
        .flat_map(|(i, (t, boxes))| {
            boxes
                .into_iter()
                .map(move |b| (i, cut(&t, &b), b))
                .collect::<Vec<_>>()
        })
        .collect();
    tagged
        .iter()
        .filter(|(i, is_cut, b)| {
            !is_cut
                || !tagged.iter().any(|(j, other_cut, o)| {
                    j != i
                        && !other_cut
                        && o.class == b.class
                        && intersection(&o.xywh, &b.xywh) > 0.5 * b.xywh[2] * b.xywh[3]
                })
        })
        .map(|&(_, _, b)| b)
        .collect()
}

/// Across tiles: a box mostly inside a better one of its class (a person cut by a tile's edge)
/// is the same person.
fn merge_cut(boxes: Vec<RawBox>) -> Vec<RawBox> {
    let mut kept: Vec<RawBox> = Vec::new();
    for b in boxes {
        let inside = kept.iter().any(|k| {
            let shared = intersection(&k.xywh, &b.xywh);
            k.class == b.class
                && shared > 0.0
                && shared > 0.7 * (b.xywh[2] * b.xywh[3]).min(k.xywh[2] * k.xywh[3])
        });
        if !inside {
            kept.push(b);
        }
    }
    kept
}

/// A model's `darknet_yolo` metadata that is not readable: serde's message, clipped (a model's
/// metadata can be megabytes and serde quotes what it could not take).
#[derive(Debug, thiserror::Error)]
#[error("its darknet_yolo metadata is not readable: {0}")]
pub struct DarknetMetadataError(String);

/// The darknet layout from a model's `darknet_yolo` metadata (`scripts/darknet_to_onnx.py`).
pub fn darknet_layout(meta: &str) -> Result<Layout, DarknetMetadataError> {
    #[derive(Deserialize)]
    struct Meta {
        anchors: Vec<[f64; 2]>,
        masks: Vec<Vec<usize>>,
        strides: Vec<f64>,
    }
    let m: Meta = serde_json::from_str(meta)
        .map_err(|e| DarknetMetadataError(crate::io::clip(&e.to_string(), 200)))?;
    Ok(Layout::Darknet {
        anchors: m.anchors,
        masks: m.masks,
        strides: m.strides,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn class_names_read_from_either_metadata_form() {
        assert_eq!(
            parse_names(r#"["person", "bicycle"]"#).unwrap(),
            ["person", "bicycle"]
        );
        assert_eq!(
            parse_names("{0: 'person', 1: 'bicycle'}").unwrap(),
            ["person", "bicycle"]
        );
        assert!(parse_names("{1: 'person'}").is_none());
    }

    #[test]
    fn settings_out_of_range_name_their_key() {
        NeuralSettings::default().check().unwrap();
        let tiled = NeuralSettings {
            tile: 416,
            ..NeuralSettings::default()
        };
        tiled.check().unwrap();
        let cases: Vec<(&str, NeuralSettings)> = vec![
            (
                "tile",
                NeuralSettings {
                    tile: 1,
                    ..tiled.clone()
                },
            ),
            (
                "tile",
                NeuralSettings {
                    tile: 100,
                    overlap: 64,
                    ..tiled.clone()
                },
            ),
            (
                "mean",
                NeuralSettings {
                    mean: [f32::NAN, 0.0, 0.0],
                    ..tiled.clone()
                },
            ),
            (
                "std",
                NeuralSettings {
                    std: [f32::INFINITY, 1.0, 1.0],
                    ..tiled.clone()
                },
            ),
            (
                "std",
                NeuralSettings {
                    std: [0.0, 1.0, 1.0],
                    ..tiled.clone()
                },
            ),
            (
                "input_size",
                NeuralSettings {
                    input_size: Some([0, 0]),
                    ..tiled.clone()
                },
            ),
            (
                "input_size",
                NeuralSettings {
                    input_size: Some([32768, 32768]),
                    ..tiled.clone()
                },
            ),
            (
                "min_score",
                NeuralSettings {
                    min_score: f64::NAN,
                    ..tiled.clone()
                },
            ),
            (
                "nms_iou",
                NeuralSettings {
                    nms_iou: 1.5,
                    ..tiled.clone()
                },
            ),
            (
                "max_boxes",
                NeuralSettings {
                    max_boxes: 0,
                    ..tiled.clone()
                },
            ),
            (
                "classes",
                NeuralSettings {
                    classes: vec![],
                    ..tiled.clone()
                },
            ),
            (
                "roi",
                NeuralSettings {
                    roi: Some([0, 0, 0, 10]),
                    ..tiled.clone()
                },
            ),
            (
                "threads",
                NeuralSettings {
                    threads: 100_000,
                    ..tiled.clone()
                },
            ),
        ];
        for (key, s) in cases {
            assert_eq!(s.check().unwrap_err().0, key, "{s:?}");
        }
    }

    #[test]
    fn frames_are_scaled_to_the_models_trained_scales_only_outside_them() {
        let trained = [0.012, 0.03];
        assert_eq!(model_scale(0.012, trained), 1.0);
        assert_eq!(model_scale(0.02, trained), 1.0);
        assert_eq!(model_scale(0.03, trained), 1.0);
        // Finer: shrunk to the middle (0.019 m a pixel); coarser: enlarged to it.
        let mid = (0.012f64 * 0.03).sqrt();
        assert!((model_scale(0.005, trained) - 0.005 / mid).abs() < 1e-12);
        assert!(model_scale(0.005, trained) < 1.0);
        assert!(model_scale(0.05, trained) > 1.0);
        assert_eq!(parse_trained_gsd("[0.012, 0.03]"), Some(trained));
        for bad in [
            "[0.03, 0.012]",
            "[0.012]",
            "[0, 0.03]",
            "0.02",
            "[\"a\", 1]",
            "[0.01, 50]",
        ] {
            assert_eq!(parse_trained_gsd(bad), None, "{bad}");
        }
    }

    #[test]
    fn a_shrunk_frame_is_the_mean_of_each_block() {
        // 3x2 pixels, shrunk by 2: a 2x1 image; the right block is one column wide.
        let bgr: Vec<u8> = [
            [0, 10, 20],
            [2, 12, 22],
            [100, 0, 0],
            [4, 14, 24],
            [6, 16, 26],
            [50, 0, 0],
        ]
        .concat();
        let (out, wh) = shrink_bgr(&bgr, [3, 2], 2);
        assert_eq!(wh, [2, 1]);
        assert_eq!(out, vec![3, 13, 23, 75, 0, 0]);
    }

    #[test]
    fn tiles_are_chosen_so_that_people_are_not_shrunk_and_are_whole_in_one() {
        let input = [416, 416];
        // PETS's 480x360 frames, people 66 px: two tiles of the frame's height, side by side.
        let (tile, overlap) = auto_tiles([480, 360], input, 66.0);
        assert_eq!((tile, overlap), (360, 66));
        assert_eq!(tiles([0, 0, 480, 360], tile, overlap).len(), 2);
        // A frame within the input: whole.
        assert_eq!(auto_tiles([400, 300], input, 66.0), (0, 0));
        // 1080p, people 100 px: tiles of the input's size.
        let (tile, overlap) = auto_tiles([1920, 1080], input, 100.0);
        assert_eq!((tile, overlap), (416, 100));
        assert!(tiles([0, 0, 1920, 1080], tile, overlap).len() <= MAX_AUTO_TILES);
        // People larger than the frame's tiles allow: whole frames.
        assert_eq!(auto_tiles([480, 360], input, 300.0), (0, 0));
        // 4K: larger tiles, so that there are at most MAX_AUTO_TILES.
        let (tile, overlap) = auto_tiles([3840, 2160], input, 60.0);
        assert!(tile > 416 && overlap == 60, "{tile} {overlap}");
        assert!(tiles([0, 0, 3840, 2160], tile, overlap).len() <= MAX_AUTO_TILES);
        assert_eq!(auto_tiles([480, 360], input, f64::NAN).1, 1);
    }

    #[test]
    fn a_box_cut_by_a_tiles_inner_edge_gives_way_to_the_whole_one() {
        let b = |x: f64, w: f64, s: f64| RawBox {
            xywh: [x, 10.0, w, 40.0],
            score: s,
            class: 0,
            head: None,
        };
        // Two tiles of a 480-wide region overlapping from 120 to 360.
        let (left, right) = ([0, 0, 360, 360], [120, 0, 360, 360]);
        let kept = drop_cut_by_tiles(
            vec![
                // The person at 340-370 is cut by the left tile's inner edge, whole in the
                // right one (which scores lower).
                (left, vec![b(340.0, 19.5, 0.9), b(10.0, 15.0, 0.8)]),
                (right, vec![b(340.0, 30.0, 0.6), b(460.0, 20.0, 0.7)]),
            ],
            [0, 0, 480, 360],
        );
        let xs: Vec<(f64, f64)> = kept.iter().map(|k| (k.xywh[0], k.xywh[2])).collect();
        // The cut box gone; the whole one, and those by the region's own border, kept.
        assert_eq!(xs, [(10.0, 15.0), (340.0, 30.0), (460.0, 20.0)]);
        // A cut box with no whole one elsewhere (a person wider than the overlap) stays.
        let kept = drop_cut_by_tiles(
            vec![(left, vec![b(340.0, 19.5, 0.9)]), (right, vec![])],
            [0, 0, 480, 360],
        );
        assert_eq!(kept.len(), 1);
    }

    #[test]
    fn a_cut_person_merges_into_the_whole_one() {
        let b = |x: f64, w: f64, s: f64| RawBox {
            xywh: [x, 0.0, w, 20.0],
            score: s,
            class: 0,
            head: None,
        };
        let m = merge_cut(vec![
            b(0.0, 10.0, 0.9),
            b(5.0, 5.0, 0.5),
            b(30.0, 10.0, 0.4),
        ]);
        assert_eq!(m.len(), 2);
    }
}
