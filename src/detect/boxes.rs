//! Person boxes from an external detector (Grounding DINO, YOLO, ...), pure: readers for
//! MOTChallenge txt, JSON Lines and COCO JSON, and per-frame filters (score, region of interest,
//! duplicates, groups, overlap, shape, size, shadows).
//!
//! Frames are 0-based here. MOT files number frames from 1 and are shifted; JSON Lines `frame`,
//! COCO `image_id`, `frame_index`/`frame_id` and the digits of a COCO `file_name` are taken as
//! 0-based frame indices as written (ffmpeg numbers extracted frames from 1 by default: subtract
//! one in the caller, or write `frame_index`). Boxes are `[x, y, w, h]` pixels, (x, y) the
//! top-left corner, used as the file gives them.

use std::collections::{BTreeMap, HashMap, HashSet};
use std::ops::AddAssign;
use std::path::Path;

use nalgebra::{Matrix3, Vector3};
use serde_json::{Map, Value};

use super::FrameView;
use super::colour::lab;
use crate::io::{FileCtx, FileError};

/// One box as read.
#[derive(Clone, Debug, PartialEq)]
pub struct RawBox {
    /// 0-based frame index.
    pub frame: usize,
    /// `[x, y, w, h]` pixels, (x, y) the top-left corner.
    pub bbox: [f64; 4],
    /// In [0, 1]; 1 when the file gives none (or -1 in MOT).
    pub score: f64,
    pub label: Option<String>,
    /// 1-based line of the file the box came from, for messages (0 if unknown).
    pub line: usize,
}

impl RawBox {
    pub fn centre(&self) -> [f64; 2] {
        let [x, y, w, h] = self.bbox;
        [x + 0.5 * w, y + 0.5 * h]
    }
}

#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum BoxFormat {
    /// MOTChallenge `frame, id, left, top, width, height, conf[, x, y, z]`, frames from 1.
    Mot,
    /// One JSON object per line: a box, or a frame with `boxes`.
    JsonLines,
    /// A COCO results list or a COCO dataset.
    Coco,
}

impl BoxFormat {
    /// `"mot"`, `"jsonl"` or `"coco"` (any case).
    pub fn parse(name: &str) -> Option<BoxFormat> {
        match name.trim().to_ascii_lowercase().as_str() {
            "mot" => Some(BoxFormat::Mot),
            "jsonl" => Some(BoxFormat::JsonLines),
            "coco" => Some(BoxFormat::Coco),
            _ => None,
        }
    }

    /// From the extension, then the text: `.txt`/`.csv` MOT, `.jsonl`/`.ndjson` JSON Lines; a
    /// `.json` (or unknown) file whose every non-empty line is an object with a `frame` key is
    /// JSON Lines (the key check keeps a one-line COCO dataset from passing), other JSON is COCO,
    /// anything else MOT.
    pub fn guess(path: &Path, text: &str) -> BoxFormat {
        let ext = path
            .extension()
            .and_then(|e| e.to_str())
            .map(str::to_ascii_lowercase);
        match ext.as_deref() {
            Some("txt" | "csv") => return BoxFormat::Mot,
            Some("jsonl" | "ndjson") => return BoxFormat::JsonLines,
            _ => {}
        }
        let text = text.strip_prefix('\u{feff}').unwrap_or(text);
        match text.trim_start().chars().next() {
            Some('{') if looks_like_json_lines(text) => BoxFormat::JsonLines,
            Some('{' | '[') => BoxFormat::Coco,
            _ if ext.as_deref() == Some("json") => BoxFormat::Coco,
            _ => BoxFormat::Mot,
        }
    }
}

fn looks_like_json_lines(text: &str) -> bool {
    text.lines().map(str::trim).filter(|l| !l.is_empty()).all(|l| {
        matches!(serde_json::from_str::<Value>(l), Ok(Value::Object(o)) if o.contains_key("frame"))
    })
}

/// Reads a box file; `format` `None` guesses it (see [`BoxFormat::guess`]).
pub fn read_boxes(path: &Path, format: Option<BoxFormat>) -> Result<Vec<RawBox>, FileError> {
    let text = FileCtx { path }.read_text("person boxes (MOT txt, JSON Lines or COCO JSON)")?;
    let format = format.unwrap_or_else(|| BoxFormat::guess(path, &text));
    parse_boxes(path, &text, format)
}

/// Parses box text; `path` only names the file in errors. No boxes at all is an error: a
/// detector run that found nobody in a whole video has almost surely failed.
pub fn parse_boxes(path: &Path, text: &str, format: BoxFormat) -> Result<Vec<RawBox>, FileError> {
    let ctx = FileCtx { path };
    let text = text.strip_prefix('\u{feff}').unwrap_or(text);
    let boxes = match format {
        BoxFormat::Mot => parse_mot(ctx, text)?,
        BoxFormat::JsonLines => parse_json_lines(ctx, text)?,
        BoxFormat::Coco => parse_coco(ctx, text)?,
    };
    if boxes.is_empty() {
        return Err(ctx.err(None, None, "no boxes; expected at least one person box"));
    }
    Ok(boxes)
}

/// Where a value sits, for messages.
#[derive(Clone, Copy)]
struct At<'a> {
    ctx: FileCtx<'a>,
    line: Option<usize>,
}

impl At<'_> {
    fn err(&self, field: &str, message: impl Into<String>) -> FileError {
        self.ctx.err(self.line, Some(field), message)
    }

    fn positive(&self, field: &str, v: f64) -> Result<f64, FileError> {
        if v > 0.0 {
            Ok(v)
        } else {
            Err(self.err(
                field,
                format!("expected a positive size in pixels, found {v}"),
            ))
        }
    }

    fn score(&self, field: &str, v: f64, alternative: &str) -> Result<f64, FileError> {
        if (0.0..=1.0).contains(&v) {
            Ok(v)
        } else {
            Err(self.err(
                field,
                format!("expected a score in [0, 1]{alternative}, found {v}"),
            ))
        }
    }
}

const MOT_FIELDS: [&str; 10] = [
    "frame", "id", "left", "top", "width", "height", "conf", "x", "y", "z",
];

/// The largest COCO file read: it is parsed whole into a JSON tree, some fifteen times its size.
pub const MAX_COCO_BYTES: usize = 64 << 20;

/// A JSON value for a message, cut short.
fn show(v: &serde_json::Value) -> String {
    crate::io::clip(&v.to_string(), 60)
}

/// The largest frame number accepted: a day of video at 100 frames/s is 8.6 million.
const MAX_FRAME: f64 = 1e15;

fn parse_mot(ctx: FileCtx, text: &str) -> Result<Vec<RawBox>, FileError> {
    let mut out = Vec::new();
    let mut first_row = true;
    for (i, raw) in text.lines().enumerate() {
        let line = i + 1;
        let l = raw.trim();
        if l.is_empty() || l.starts_with('#') {
            continue;
        }
        let mut fields: Vec<&str> = if l.contains(',') {
            l.split(',').map(str::trim).collect()
        } else {
            l.split_whitespace().collect()
        };
        if fields.len() > 1 && fields.last() == Some(&"") {
            fields.pop(); // a trailing comma
        }
        // A header row, as spreadsheets and pandas write.
        if std::mem::take(&mut first_row) && fields[0].eq_ignore_ascii_case("frame") {
            continue;
        }
        if l.len() > crate::io::MAX_LINE_BYTES {
            return Err(ctx.at(line, "a line longer than 1 MiB: is it the right file?"));
        }
        ctx.field_count(
            &fields,
            line,
            7,
            10,
            "frame, id, left, top, width, height, conf[, x, y, z]",
        )?;
        let at = At {
            ctx,
            line: Some(line),
        };
        let num = |k: usize| -> Result<f64, FileError> {
            let v = ctx.number(fields[k], line, MOT_FIELDS[k])?;
            if v.is_finite() {
                Ok(v)
            } else {
                Err(at.err(
                    MOT_FIELDS[k],
                    format!("expected a finite number, found '{}'", fields[k]),
                ))
            }
        };
        let frame = num(0)?;
        if frame < 1.0 || frame.fract() != 0.0 || frame > MAX_FRAME {
            return Err(at.err(
                "frame",
                format!(
                    "expected a whole frame number from 1 (MOT frames start at 1), found '{}'",
                    crate::io::clip(fields[0], 40)
                ),
            ));
        }
        num(1)?; // the track id, -1 for detections: unused, but a shifted column shows here
        let (x, y) = (num(2)?, num(3)?);
        let w = at.positive("width", num(4)?)?;
        let h = at.positive("height", num(5)?)?;
        let conf = num(6)?;
        let score = if conf == -1.0 {
            1.0
        } else {
            at.score("conf", conf, " or -1 for unknown")?
        };
        // x, y, z (world coordinates, or class and visibility in ground truth) are not needed.
        out.push(RawBox {
            frame: frame as usize - 1,
            bbox: [x, y, w, h],
            score,
            label: None,
            line,
        });
    }
    Ok(out)
}

/// serde_json's message without its "at line L column C", which the caller words itself.
fn json_message(e: &serde_json::Error) -> String {
    let s = e.to_string();
    match s.rfind(" at line ") {
        Some(i) => s[..i].to_string(),
        None => s,
    }
}

fn json_number(at: At, field: &str, v: &Value) -> Result<f64, FileError> {
    v.as_f64()
        .filter(|x| x.is_finite())
        .ok_or_else(|| at.err(field, format!("expected a number, found {}", show(v))))
}

fn json_frame(at: At, field: &str, v: &Value) -> Result<usize, FileError> {
    match v.as_f64() {
        Some(x) if x >= 0.0 && x.fract() == 0.0 && x < 1e15 => Ok(x as usize),
        _ => Err(at.err(
            field,
            format!(
                "expected a 0-based frame index (a whole number >= 0), found {}",
                show(v)
            ),
        )),
    }
}

/// A box from an object with `bbox` or `xyxy`, optional `score` and `label`; `prefix` leads the
/// field names in messages (`boxes[2].`).
fn json_box(
    at: At,
    obj: &Map<String, Value>,
    prefix: &str,
    frame: usize,
) -> Result<RawBox, FileError> {
    let field = |name: &str| format!("{prefix}{name}");
    let four = |name: &str, v: &Value| -> Result<[f64; 4], FileError> {
        let a = v.as_array().filter(|a| a.len() == 4).ok_or_else(|| {
            at.err(
                &field(name),
                format!("expected 4 numbers, found {}", show(v)),
            )
        })?;
        let mut out = [0.0; 4];
        for (o, x) in out.iter_mut().zip(a) {
            *o = json_number(at, &field(name), x)?;
        }
        Ok(out)
    };
    let bbox = match (obj.get("bbox"), obj.get("xyxy")) {
        (Some(b), None) => {
            let [x, y, w, h] = four("bbox", b)?;
            [
                x,
                y,
                at.positive(&field("bbox"), w)?,
                at.positive(&field("bbox"), h)?,
            ]
        }
        (None, Some(c)) => {
            let [x0, y0, x1, y1] = four("xyxy", c)?;
            if x1 <= x0 || y1 <= y0 {
                return Err(at.err(
                    &field("xyxy"),
                    format!("expected x1 > x0 and y1 > y0, found {c}"),
                ));
            }
            [x0, y0, x1 - x0, y1 - y0]
        }
        (Some(_), Some(_)) => {
            return Err(at.err(&field("bbox"), "expected 'bbox' or 'xyxy', not both"));
        }
        (None, None) => {
            return Err(at.err(
                &field("bbox"),
                "missing; expected 'bbox': [x, y, w, h] or 'xyxy': [x0, y0, x1, y1], pixels",
            ));
        }
    };
    let score = match obj.get("score") {
        None | Some(Value::Null) => 1.0,
        Some(v) => at.score(&field("score"), json_number(at, &field("score"), v)?, "")?,
    };
    let label = match obj.get("label") {
        None | Some(Value::Null) => None,
        Some(Value::String(s)) => Some(s.clone()),
        Some(v) => {
            return Err(at.err(
                &field("label"),
                format!("expected a string, found {}", show(v)),
            ));
        }
    };
    Ok(RawBox {
        frame,
        bbox,
        score,
        label,
        line: at.line.unwrap_or(0),
    })
}

fn parse_json_lines(ctx: FileCtx, text: &str) -> Result<Vec<RawBox>, FileError> {
    let mut out = Vec::new();
    for (i, raw) in text.lines().enumerate() {
        let l = raw.trim();
        if l.is_empty() {
            continue;
        }
        let at = At {
            ctx,
            line: Some(i + 1),
        };
        let v: Value = serde_json::from_str(l).map_err(|e| {
            ctx.at(
                i + 1,
                format!(
                    "invalid JSON at column {}: {}",
                    e.column(),
                    json_message(&e)
                ),
            )
        })?;
        let Value::Object(obj) = v else {
            return Err(ctx.at(
                i + 1,
                "expected one JSON object per line, with 'frame' and 'bbox' or 'boxes'",
            ));
        };
        let frame = match obj.get("frame") {
            Some(f) => json_frame(at, "frame", f)?,
            None => return Err(at.err("frame", "missing; expected the 0-based frame index")),
        };
        match obj.get("boxes") {
            None => out.push(json_box(at, &obj, "", frame)?),
            Some(Value::Array(list)) => {
                for (k, b) in list.iter().enumerate() {
                    let Value::Object(b) = b else {
                        return Err(at.err(
                            &format!("boxes[{k}]"),
                            format!("expected a box object, found {b}"),
                        ));
                    };
                    out.push(json_box(at, b, &format!("boxes[{k}]."), frame)?);
                }
            }
            Some(v) => {
                return Err(at.err(
                    "boxes",
                    format!("expected an array of boxes, found {}", show(v)),
                ));
            }
        }
    }
    Ok(out)
}

/// The line on which each element of the top-level array (key `""`), or of each array under a
/// key of the top-level object, starts. serde_json keeps no positions, so the text, already
/// known to be valid JSON, is scanned for strings and nesting. Counting occurrences of `"bbox"`
/// would be simpler but goes wrong exactly when an annotation lacks its box, or "bbox" appears
/// in a description.
fn element_lines(text: &str) -> HashMap<String, Vec<usize>> {
    let mut out: HashMap<String, Vec<usize>> = HashMap::new();
    let (mut line, mut depth) = (1, 0usize);
    let (mut in_string, mut escaped) = (false, false);
    let mut top = 0u8; // b'[' or b'{' once seen
    let mut string = Vec::new(); // the last string at depth 1: an object's key
    let mut listing: Option<(usize, String)> = None; // the array being listed: its depth and key
    let mut expect = false; // the next token starts an element
    for &c in text.as_bytes() {
        if in_string {
            if escaped {
                escaped = false;
            } else if c == b'\\' {
                escaped = true;
            } else if c == b'"' {
                in_string = false;
            } else if depth == 1 {
                string.push(c);
            }
            continue;
        }
        if c == b'\n' {
            line += 1;
        }
        if c.is_ascii_whitespace() {
            continue;
        }
        if std::mem::take(&mut expect)
            && c != b']'
            && let Some((_, key)) = &listing
        {
            out.entry(key.clone()).or_default().push(line);
        }
        match c {
            b'"' => {
                in_string = true;
                string.clear();
            }
            b'[' | b'{' => {
                depth += 1;
                if top == 0 {
                    top = c;
                }
                let key = match (c, depth, top) {
                    (b'[', 1, _) => Some(String::new()),
                    (b'[', 2, b'{') => Some(String::from_utf8_lossy(&string).into_owned()),
                    _ => None,
                };
                if let Some(key) = key {
                    listing = Some((depth, key));
                    expect = true;
                }
            }
            b']' | b'}' => {
                if matches!(&listing, Some((d, _)) if *d == depth) {
                    listing = None;
                }
                depth = depth.saturating_sub(1);
            }
            b',' => expect = matches!(&listing, Some((d, _)) if *d == depth),
            _ => {}
        }
    }
    out
}

/// The last run of digits in a file name's stem (`frames/frame_000123.jpg` gives 123).
fn frame_from_file_name(name: &str) -> Option<usize> {
    let stem = Path::new(name).file_stem()?.to_str()?;
    let end = stem.rfind(|c: char| c.is_ascii_digit())? + 1;
    // After the last character that is not a digit, whatever its width in bytes.
    let start = stem[..end]
        .char_indices()
        .rfind(|(_, c)| !c.is_ascii_digit())
        .map_or(0, |(i, c)| i + c.len_utf8());
    stem[start..end].parse().ok()
}

/// A results list `[{image_id, category_id, bbox, score}]` (image_id the 0-based frame) or a
/// dataset `{images, annotations, categories}`. Only people are kept: the categories named
/// "person" when categories are given, else category_id 1 (COCO's person) or none.
fn parse_coco(ctx: FileCtx, text: &str) -> Result<Vec<RawBox>, FileError> {
    if text.len() > MAX_COCO_BYTES {
        return Err(ctx.err(
            None,
            None,
            format!(
                "{} MB of COCO JSON: a COCO file is read whole, up to {} MB (about a million boxes); write the boxes as JSON Lines, which is read a line at a time",
                text.len() >> 20,
                MAX_COCO_BYTES >> 20
            ),
        ));
    }
    let doc: Value = serde_json::from_str(text).map_err(|e| {
        ctx.at(
            e.line(),
            format!(
                "invalid JSON at column {}: {}",
                e.column(),
                json_message(&e)
            ),
        )
    })?;
    let lines = element_lines(text);
    let at = |key: &str, i: usize| At {
        ctx,
        line: lines.get(key).and_then(|l| l.get(i)).copied(),
    };
    let (annotations, key, images, categories) = match &doc {
        Value::Array(a) => (a, "", None, None),
        Value::Object(o) => match o.get("annotations") {
            Some(Value::Array(a)) => (a, "annotations", o.get("images"), o.get("categories")),
            _ => {
                return Err(ctx.err(
                    None,
                    Some("annotations"),
                    "missing or not an array; expected a COCO results list [...] or a dataset {\"images\": [...], \"annotations\": [...]}",
                ));
            }
        },
        _ => return Err(ctx.err(None, None, "expected a COCO results list or dataset")),
    };

    // Category ids as JSON text, so that integer and string ids both work.
    let mut person_ids = HashSet::new();
    match categories {
        None => {
            person_ids.insert("1".to_string());
        }
        Some(Value::Array(cats)) => {
            let mut names = Vec::new();
            for (i, c) in cats.iter().enumerate() {
                let name = c.get("name").and_then(Value::as_str).unwrap_or("");
                let Some(id) = c.get("id") else {
                    return Err(at("categories", i)
                        .err("categories.id", "missing; expected the category id"));
                };
                if name.eq_ignore_ascii_case("person") {
                    person_ids.insert(id.to_string());
                }
                names.push(name.to_string());
            }
            if person_ids.is_empty() {
                return Err(ctx.err(
                    None,
                    Some("categories"),
                    format!("no category named 'person' (found: {})", names.join(", ")),
                ));
            }
        }
        Some(v) => {
            return Err(ctx.err(
                None,
                Some("categories"),
                format!("expected an array, found {}", show(v)),
            ));
        }
    }

    // Image id -> frame, when the file lists its images.
    let frames: Option<HashMap<String, usize>> = match images {
        None => None,
        Some(Value::Array(imgs)) => {
            let mut map = HashMap::new();
            for (i, img) in imgs.iter().enumerate() {
                let at = at("images", i);
                let Some(id) = img.get("id") else {
                    return Err(at.err("images.id", "missing; expected the image id"));
                };
                let frame = match img.get("frame_index").or_else(|| img.get("frame_id")) {
                    Some(f) => json_frame(at, "frame_index", f)?,
                    None => {
                        let name = img.get("file_name").and_then(Value::as_str).unwrap_or("");
                        frame_from_file_name(name).ok_or_else(|| {
                            at.err(
                                "images.file_name",
                                format!("no digits in '{}' and no 'frame_index'; expected the frame number in the file name or a 'frame_index'", crate::io::clip(name, 60)),
                            )
                        })?
                    }
                };
                if map.insert(id.to_string(), frame).is_some() {
                    return Err(at.err(
                        "images.id",
                        format!("the image id {} is used twice", show(id)),
                    ));
                }
            }
            Some(map)
        }
        Some(v) => {
            return Err(ctx.err(
                None,
                Some("images"),
                format!("expected an array, found {}", show(v)),
            ));
        }
    };

    let mut out = Vec::new();
    for (i, a) in annotations.iter().enumerate() {
        let at = at(key, i);
        let Value::Object(a) = a else {
            return Err(at.err(
                "annotation",
                format!("expected an object, found {}", show(a)),
            ));
        };
        if let Some(c) = a.get("category_id")
            && !person_ids.contains(&c.to_string())
        {
            continue;
        }
        let Some(image) = a.get("image_id") else {
            return Err(at.err("image_id", "missing; expected the image (frame) id"));
        };
        let frame = match &frames {
            Some(map) => *map.get(&image.to_string()).ok_or_else(|| {
                at.err("image_id", format!("{} is not among 'images'", show(image)))
            })?,
            None => json_frame(at, "image_id", image)?,
        };
        let mut b = json_box(at, a, "", frame)?;
        if b.label.is_none() {
            b.label = Some("person".to_string());
        }
        out.push(b);
    }
    if out.is_empty() && !annotations.is_empty() {
        return Err(ctx.err(
            None,
            None,
            format!(
                "no person boxes: none of the {} annotations is of the person category",
                annotations.len()
            ),
        ));
    }
    Ok(out)
}

/// Boxes grouped by frame, frames in order.
pub fn group_by_frame(boxes: Vec<RawBox>) -> Vec<(usize, Vec<RawBox>)> {
    let mut map: BTreeMap<usize, Vec<RawBox>> = BTreeMap::new();
    for b in boxes {
        map.entry(b.frame).or_default().push(b);
    }
    map.into_iter().collect()
}

/// Intersection over union of two `[x, y, w, h]` boxes.
pub fn iou(a: &[f64; 4], b: &[f64; 4]) -> f64 {
    let iw = (a[0] + a[2]).min(b[0] + b[2]) - a[0].max(b[0]);
    let ih = (a[1] + a[3]).min(b[1] + b[3]) - a[1].max(b[1]);
    if iw <= 0.0 || ih <= 0.0 {
        return 0.0;
    }
    let inter = iw * ih;
    inter / (a[2] * a[3] + b[2] * b[3] - inter)
}

/// Colour of shadows, learnt from patches the user marks. CIELAB rather than BGR: a shadow
/// differs from lit ground mostly in lightness, which Lab keeps on one axis while BGR spreads it
/// over three correlated ones, and Lab distances are close to perceived differences, so one
/// threshold fits dark and bright scenes alike (and the hat detector already works in Lab).
#[derive(Clone, Debug)]
pub struct ShadowModel {
    /// Mean colour, CIELAB.
    pub mean: Vector3<f64>,
    /// Covariance, CIELAB units², with [`SHADOW_COLOUR_FLOOR`] added on the diagonal.
    pub cov: Matrix3<f64>,
    inv: Matrix3<f64>,
}

/// Variance added to the shadow covariance, Lab units²: 8-bit quantisation and sensor noise are
/// about one unit, and a uniform patch would otherwise give a singular covariance.
pub const SHADOW_COLOUR_FLOOR: f64 = 1.0;
/// Fewest patch pixels a shadow model is learnt from.
pub const MIN_SHADOW_PIXELS: usize = 100;
/// About how many pixels of a box are tested.
const SHADOW_SAMPLES: f64 = 1024.0;

impl ShadowModel {
    /// Learns from rectangles `[x, y, w, h]` (pixels, clipped to their frames).
    pub fn from_patches(
        frames_and_rects: &[(FrameView, [usize; 4])],
    ) -> Result<ShadowModel, String> {
        let mut px = Vec::new();
        for (f, r) in frames_and_rects {
            let [x, y, w, h] = *r;
            let (x1, y1) = (
                x.saturating_add(w).min(f.width),
                y.saturating_add(h).min(f.height),
            );
            for v in y..y1 {
                for u in x..x1 {
                    px.push(lab(f.pixel(u, v)));
                }
            }
        }
        if px.len() < MIN_SHADOW_PIXELS {
            return Err(format!(
                "the shadow patches hold {} pixels inside their frames; at least {MIN_SHADOW_PIXELS} are needed (mark larger or more shadow patches)",
                px.len()
            ));
        }
        let n = px.len() as f64;
        let mean = px.iter().sum::<Vector3<f64>>() / n;
        let cov = px
            .iter()
            .map(|p| (p - mean) * (p - mean).transpose())
            .sum::<Matrix3<f64>>()
            / (n - 1.0);
        ShadowModel::new(mean, cov)
    }

    /// From a mean and covariance in CIELAB; the floor is added to `cov`.
    pub fn new(mean: Vector3<f64>, cov: Matrix3<f64>) -> Result<ShadowModel, String> {
        let cov = cov + Matrix3::identity() * SHADOW_COLOUR_FLOOR;
        let inv = cov
            .try_inverse()
            .filter(|m| m.iter().all(|v| v.is_finite()))
            .ok_or("the shadow colour covariance is not invertible")?;
        Ok(ShadowModel { mean, cov, inv })
    }

    /// Whether an sRGB colour is within Mahalanobis distance 3 of the shadow colour.
    pub fn contains(&self, rgb: [u8; 3]) -> bool {
        let d = lab(rgb) - self.mean;
        d.dot(&(self.inv * d)) <= 9.0
    }

    /// Fraction of the box's pixels (clipped to the frame) that look like shadow; about 1000
    /// pixels on a regular grid are tested, so a large box costs no more than a small one.
    pub fn shadow_fraction(&self, frame: &FrameView, bbox: &[f64; 4]) -> f64 {
        // Pixel centres i with lo <= i < lo + len.
        let span = |lo: f64, len: f64, n: usize| {
            let a = lo.ceil().max(0.0) as usize;
            let b = ((lo + len).ceil().max(0.0) as usize).min(n);
            (a, b.max(a))
        };
        let (x0, x1) = span(bbox[0], bbox[2], frame.width);
        let (y0, y1) = span(bbox[1], bbox[3], frame.height);
        let area = (x1 - x0) * (y1 - y0);
        if area == 0 {
            return 0.0;
        }
        let step = ((area as f64 / SHADOW_SAMPLES).sqrt().ceil() as usize).max(1);
        let (mut inside, mut total) = (0usize, 0usize);
        for y in (y0..y1).step_by(step) {
            for x in (x0..x1).step_by(step) {
                total += 1;
                inside += usize::from(self.contains(frame.pixel(x, y)));
            }
        }
        inside as f64 / total as f64
    }
}

/// What [`filter_frame`] keeps. Sizes in metres use `px_per_m`, the image scale at head height.
#[derive(Clone, Debug)]
pub struct BoxFilter {
    /// Lowest score kept (default 0.3).
    pub min_score: f64,
    /// `[x0, y0, x1, y1]` pixels: boxes whose centre lies outside are dropped. The paper's entry
    /// strip along the left edge is `[0, 0, strip, height]`.
    pub roi: Option<[f64; 4]>,
    /// Boxes overlapping the best-scoring one by at least this IoU (two detector passes, say)
    /// merge into their score-weighted mean, keeping the best score (default 0.85).
    pub merge_iou: f64,
    /// Greedy non-maximum suppression: a box overlapping a better one by more than this IoU is
    /// dropped (default 0.5).
    pub nms_iou: f64,
    /// Limits on w/h (default [0.25, 4]).
    pub aspect: [f64; 2],
    /// Image scale at head height, px/m (from the pose); no default.
    pub px_per_m: f64,
    /// Limits on the box's longer side, metres (default [0.25, 1.6]).
    pub size_m: [f64; 2],
    /// One person's extent along a group box (default 0.7 m): a box whose longer side is at least
    /// 1.6 times this, and whose shorter side is within `size_m`, holds round(longer / person_m)
    /// people side by side and is split into as many equal boxes.
    pub person_m: f64,
    /// Boxes that would split into more people than this are left whole (and usually fail the
    /// size limit): a box across half the frame is a detector glitch, not a row of walkers
    /// (default 4).
    pub max_split: usize,
    pub shadow: Option<ShadowModel>,
    /// Boxes with a larger fraction of shadow-coloured pixels are dropped (default 0.6).
    pub max_shadow_fraction: f64,
}

impl BoxFilter {
    /// The defaults, at the given image scale (px/m at head height).
    pub fn new(px_per_m: f64) -> BoxFilter {
        BoxFilter {
            min_score: 0.3,
            roi: None,
            merge_iou: 0.85,
            nms_iou: 0.5,
            aspect: [0.25, 4.0],
            px_per_m,
            size_m: [0.25, 1.6],
            person_m: 0.7,
            max_split: 4,
            shadow: None,
            max_shadow_fraction: 0.6,
        }
    }

    /// Names the first setting that makes no sense.
    pub fn check(&self) -> Result<(), FilterError> {
        let unit = |v: f64| (0.0..=1.0).contains(&v);
        let range = |r: [f64; 2]| r[0] > 0.0 && r[0] <= r[1] && r[1].is_finite();
        let roi_ok = self.roi.is_none_or(|r| {
            r.iter().all(|v| v.is_finite() && *v >= 0.0) && r[0] < r[2] && r[1] < r[3]
        });
        let checks = [
            (
                self.px_per_m.is_finite() && self.px_per_m > 0.0,
                "px_per_m",
                "must be positive",
            ),
            (
                self.person_m.is_finite() && self.person_m > 0.0,
                "person_m",
                "must be positive",
            ),
            (unit(self.min_score), "min_score", "must be in [0, 1]"),
            (unit(self.merge_iou), "merge_iou", "must be in [0, 1]"),
            (unit(self.nms_iou), "nms_iou", "must be in [0, 1]"),
            (
                range(self.aspect),
                "aspect",
                "must be [min, max] with 0 < min <= max",
            ),
            (
                range(self.size_m),
                "size_m",
                "must be [min, max] with 0 < min <= max",
            ),
            (
                unit(self.max_shadow_fraction),
                "max_shadow_fraction",
                "must be in [0, 1]",
            ),
            (
                roi_ok,
                "roi",
                "must be [x0, y0, x1, y1] in pixels with 0 <= x0 < x1 and 0 <= y0 < y1",
            ),
        ];
        match checks.iter().find(|(ok, _, _)| !ok) {
            Some((_, key, message)) => Err(FilterError {
                key,
                message: (*message).to_string(),
            }),
            None => Ok(()),
        }
    }
}

/// A box filter setting out of its range: the setting and what it must be.
#[derive(Clone, Debug, PartialEq, thiserror::Error)]
#[error("box filter: {key} {message}")]
pub struct FilterError {
    pub key: &'static str,
    pub message: String,
}

/// How many boxes each filter removed. Counts add up:
/// `kept = read - low_score - outside_roi - merged + split - suppressed - bad_aspect - bad_size - shadows`.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct FilterCounts {
    pub read: usize,
    pub low_score: usize,
    pub outside_roi: usize,
    /// Boxes absorbed into another (n duplicates merged count n - 1).
    pub merged: usize,
    pub suppressed: usize,
    pub bad_aspect: usize,
    pub bad_size: usize,
    /// Boxes added by splitting (a box split into 3 counts 2).
    pub split: usize,
    pub shadows: usize,
    pub kept: usize,
}

impl AddAssign for FilterCounts {
    fn add_assign(&mut self, o: FilterCounts) {
        self.read += o.read;
        self.low_score += o.low_score;
        self.outside_roi += o.outside_roi;
        self.merged += o.merged;
        self.suppressed += o.suppressed;
        self.bad_aspect += o.bad_aspect;
        self.bad_size += o.bad_size;
        self.split += o.split;
        self.shadows += o.shadows;
        self.kept += o.kept;
    }
}

/// Filters the boxes of one frame: score, region, merge duplicates, split groups, NMS, aspect,
/// size, shadow. Splitting comes before NMS so that the pieces of a group box give way to the
/// detector's own boxes of the same people. Shadows are tested only when both a model and the
/// frame are given. The boxes come back best score first.
pub fn filter_frame(
    boxes: &[RawBox],
    f: &BoxFilter,
    frame: Option<&FrameView>,
) -> (Vec<RawBox>, FilterCounts) {
    let mut n = FilterCounts {
        read: boxes.len(),
        ..FilterCounts::default()
    };
    let mut bs = boxes.to_vec();
    retain_counting(&mut bs, &mut n.low_score, |b| b.score >= f.min_score);
    if let Some(r) = f.roi {
        retain_counting(&mut bs, &mut n.outside_roi, |b| {
            let [cx, cy] = b.centre();
            (r[0]..=r[2]).contains(&cx) && (r[1]..=r[3]).contains(&cy)
        });
    }
    bs.sort_by(|a, b| b.score.total_cmp(&a.score)); // stable: ties keep file order

    let before = bs.len();
    bs = merge_duplicates(bs, f.merge_iou);
    n.merged = before - bs.len();

    let before = bs.len();
    bs = bs.into_iter().flat_map(|b| split_group(b, f)).collect(); // pieces keep the score order
    n.split = bs.len() - before;

    let before = bs.len();
    let mut kept: Vec<RawBox> = Vec::with_capacity(bs.len());
    for b in bs {
        if kept.iter().all(|k| iou(&k.bbox, &b.bbox) <= f.nms_iou) {
            kept.push(b);
        }
    }
    n.suppressed = before - kept.len();
    bs = kept;

    retain_counting(&mut bs, &mut n.bad_aspect, |b| {
        let a = b.bbox[2] / b.bbox[3];
        a >= f.aspect[0] && a <= f.aspect[1]
    });
    retain_counting(&mut bs, &mut n.bad_size, |b| {
        let m = b.bbox[2].max(b.bbox[3]) / f.px_per_m;
        m >= f.size_m[0] && m <= f.size_m[1]
    });
    if let (Some(model), Some(fr)) = (&f.shadow, frame) {
        retain_counting(&mut bs, &mut n.shadows, |b| {
            model.shadow_fraction(fr, &b.bbox) <= f.max_shadow_fraction
        });
    }
    n.kept = bs.len();
    (bs, n)
}

fn retain_counting(bs: &mut Vec<RawBox>, count: &mut usize, keep: impl FnMut(&RawBox) -> bool) {
    let before = bs.len();
    bs.retain(keep);
    *count += before - bs.len();
}

/// Merges, into each box in turn (best score first), the later boxes that overlap it by at
/// least `min_iou`: the score-weighted mean box with the best score.
fn merge_duplicates(bs: Vec<RawBox>, min_iou: f64) -> Vec<RawBox> {
    let mut used = vec![false; bs.len()];
    let mut out = Vec::with_capacity(bs.len());
    for i in 0..bs.len() {
        if used[i] {
            continue;
        }
        let (mut sum, mut wsum, mut count) = ([0.0; 4], 0.0, 0);
        for j in i..bs.len() {
            if used[j] || (j > i && iou(&bs[i].bbox, &bs[j].bbox) < min_iou) {
                continue;
            }
            used[j] = true;
            count += 1;
            let w = bs[j].score.max(1e-9); // zero scores still average, evenly
            for (s, v) in sum.iter_mut().zip(bs[j].bbox) {
                *s += w * v;
            }
            wsum += w;
        }
        let mut m = bs[i].clone();
        if count > 1 {
            // A lone box keeps its exact coordinates rather than a rounded w * x / w.
            m.bbox = sum.map(|s| s / wsum);
        }
        out.push(m);
    }
    out
}

/// A box holding several people side by side along its longer axis, as equal pieces.
fn split_group(b: RawBox, f: &BoxFilter) -> Vec<RawBox> {
    let [x, y, w, h] = b.bbox;
    let (long_m, short_m) = (w.max(h) / f.px_per_m, w.min(h) / f.px_per_m);
    let people = (long_m / f.person_m).round();
    let group = long_m >= 1.6 * f.person_m
        && short_m >= f.size_m[0]
        && short_m <= f.size_m[1]
        && people <= f.max_split as f64;
    if !group {
        return vec![b];
    }
    let n = people as usize;
    (0..n)
        .map(|i| {
            let (i, n) = (i as f64, n as f64);
            let mut p = b.clone();
            p.bbox = if w >= h {
                [x + i * w / n, y, w / n, h]
            } else {
                [x, y + i * h / n, w, h / n]
            };
            p
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    fn parse(name: &str, text: &str, format: BoxFormat) -> Result<Vec<RawBox>, String> {
        parse_boxes(Path::new(name), text, format).map_err(|e| e.to_string())
    }

    fn err(name: &str, text: &str, format: BoxFormat) -> String {
        parse(name, text, format).expect_err("should fail")
    }

    #[test]
    fn mot_det_txt_parses() {
        let text = r"# MOT17-04 det.txt from the detector
1,-1,794.2,47.5,71.2,174.8,0.91,-1,-1,-1
1,-1,1648.1,119.6,66.5,164.2,0.87,-1,-1,-1

2,-1,795.0,48.1,70.9,175.3,-1,-1,-1,-1
3 -1 12.0 40.0 30.5 80.25 0.40
4, -1, 100, 200, 30, 60, 0.5,
";
        let b = parse("det.txt", text, BoxFormat::Mot).unwrap();
        assert_eq!(
            b.iter().map(|b| b.frame).collect::<Vec<_>>(),
            [0, 0, 1, 2, 3]
        );
        assert_eq!(
            b.iter().map(|b| b.line).collect::<Vec<_>>(),
            [2, 3, 5, 6, 7]
        );
        assert_eq!(b[0].bbox, [794.2, 47.5, 71.2, 174.8]);
        assert_eq!(b[0].score, 0.91);
        assert_eq!(b[2].score, 1.0, "conf -1 is unknown");
        assert_eq!(b[3].bbox, [12.0, 40.0, 30.5, 80.25]);
        let header = "frame,id,bb_left,bb_top,bb_width,bb_height,conf\n5,-1,1,2,3,4,0.6\n";
        let b = parse("det.csv", header, BoxFormat::Mot).unwrap();
        assert_eq!((b.len(), b[0].frame, b[0].line), (1, 4, 2));
    }

    #[test]
    fn mot_errors_name_line_and_field() {
        let good = "1,-1,10,10,20,40,0.9,-1,-1,-1\n".repeat(6);
        let cases = [
            (
                "1,-1,10,10,abc,40,0.9,-1,-1,-1",
                "boxes.txt:7: field 'width': expected a number, found 'abc'",
            ),
            (
                "1,-1,10,10,20,-4,0.9,-1,-1,-1",
                "boxes.txt:7: field 'height': expected a positive size",
            ),
            (
                "1,-1,10,10,20,0,0.9",
                "boxes.txt:7: field 'height': expected a positive size",
            ),
            (
                "1,-1,10,10,20,40,1.5",
                "boxes.txt:7: field 'conf': expected a score in [0, 1] or -1",
            ),
            (
                "1,-1,NaN,10,20,40,0.9",
                "boxes.txt:7: field 'left': expected a finite number, found 'NaN'",
            ),
            (
                "0,-1,10,10,20,40,0.9",
                "boxes.txt:7: field 'frame': expected a whole frame number from 1 (MOT frames start at 1)",
            ),
            ("1,-1,10,10,20,40", "boxes.txt:7: expected 7 to 10 fields"),
        ];
        for (bad, want) in cases {
            let e = err("boxes.txt", &format!("{good}{bad}\n{good}"), BoxFormat::Mot);
            assert!(e.starts_with(want), "{bad}: {e}");
        }
        assert!(
            err("boxes.txt", "", BoxFormat::Mot)
                .ends_with("no boxes; expected at least one person box")
        );
        assert!(err("boxes.txt", "# nothing\n\n", BoxFormat::Mot).contains("no boxes"));
    }

    #[test]
    fn json_lines_parse_both_forms() {
        let text = r#"{"frame": 0, "boxes": [{"bbox": [812.4, 233.1, 58.2, 61.0], "score": 0.62, "label": "person"}, {"bbox": [1020.0, 240.5, 55.0, 57.5], "score": 0.48, "label": "person"}]}
{"frame": 1, "boxes": []}

{"frame": 2, "xyxy": [100.0, 200.0, 160.0, 280.0], "score": 0.41, "label": "person"}
{"frame": 3, "bbox": [5, 6, 7, 8]}
"#;
        let b = parse("dino.jsonl", text, BoxFormat::JsonLines).unwrap();
        assert_eq!(
            b.iter().map(|b| (b.frame, b.line)).collect::<Vec<_>>(),
            [(0, 1), (0, 1), (2, 4), (3, 5)]
        );
        assert_eq!(b[1].bbox, [1020.0, 240.5, 55.0, 57.5]);
        assert_eq!(b[2].bbox, [100.0, 200.0, 60.0, 80.0]);
        assert_eq!(b[1].label.as_deref(), Some("person"));
        assert_eq!((b[3].score, b[3].label.clone()), (1.0, None));
    }

    #[test]
    fn json_lines_errors_name_line_and_field() {
        let good = r#"{"frame": 0, "bbox": [1, 2, 3, 4], "score": 0.5}"#;
        let cases = [
            (
                r#"{"frame": 4, "bbox": [1, 2, 3, 4], "score": 0.5"#,
                "b.jsonl:3: invalid JSON at column",
            ),
            (
                r#"{"bbox": [1, 2, 3, 4]}"#,
                "b.jsonl:3: field 'frame': missing",
            ),
            (
                r#"{"frame": -2, "bbox": [1, 2, 3, 4]}"#,
                "b.jsonl:3: field 'frame': expected a 0-based frame index",
            ),
            (
                r#"{"frame": 4, "boxes": [{"bbox": [1, 2, 3, 4]}, {"bbox": [1, 2, 3]}]}"#,
                "b.jsonl:3: field 'boxes[1].bbox': expected 4 numbers",
            ),
            (
                r#"{"frame": 4, "xyxy": [10, 10, 5, 20]}"#,
                "b.jsonl:3: field 'xyxy': expected x1 > x0",
            ),
            (
                r#"{"frame": 4, "bbox": [1, 2, 3, 4], "score": 1.3}"#,
                "b.jsonl:3: field 'score': expected a score in [0, 1]",
            ),
            (
                r#"{"frame": 4, "bbox": [1, 2, "3", 4]}"#,
                "b.jsonl:3: field 'bbox': expected a number, found \"3\"",
            ),
            (r#"{"frame": 4}"#, "b.jsonl:3: field 'bbox': missing"),
        ];
        for (bad, want) in cases {
            let e = err(
                "b.jsonl",
                &format!("{good}\n\n{bad}\n{good}\n"),
                BoxFormat::JsonLines,
            );
            assert!(e.starts_with(want), "{bad}: {e}");
        }
    }

    #[test]
    fn coco_results_list_keeps_people_with_their_lines() {
        let text = r#"[
  {
    "image_id": 0,
    "category_id": 1,
    "bbox": [794.2, 47.5, 71.2, 174.8],
    "score": 0.91
  },
  {
    "image_id": 0,
    "category_id": 3,
    "bbox": [10.0, 20.0, 200.0, 100.0],
    "score": 0.88
  },
  {
    "image_id": 4,
    "category_id": 1,
    "bbox": [1648.1, 119.6, 66.5, 164.2],
    "score": 0.77
  }
]"#;
        let b = parse("results.json", text, BoxFormat::Coco).unwrap();
        assert_eq!(
            b.iter().map(|b| (b.frame, b.line)).collect::<Vec<_>>(),
            [(0, 2), (4, 14)]
        );
        assert_eq!(b[1].bbox, [1648.1, 119.6, 66.5, 164.2]);
        assert_eq!((b[1].score, b[1].label.as_deref()), (0.77, Some("person")));
        let e = err(
            "results.json",
            &text.replace(r#""bbox": [1648.1"#, r#""bbox": [-1, 1648.1"#),
            BoxFormat::Coco,
        );
        assert!(
            e.starts_with("results.json:14: field 'bbox': expected 4 numbers"),
            "{e}"
        );
    }

    const DATASET: &str = r#"{
  "info": {"description": "bbox from Grounding DINO, prompt 'person', bridge_2024-05-14.mp4"},
  "images": [
    {"id": 1, "file_name": "frames/frame_000123.jpg", "width": 3840, "height": 2160},
    {"id": 2, "file_name": "frames/frame_000124.jpg", "width": 3840, "height": 2160},
    {"id": 3, "file_name": "cam2/img.jpg", "frame_index": 900, "width": 3840, "height": 2160}
  ],
  "annotations": [
    {"id": 1, "image_id": 1, "category_id": 2, "bbox": [100.5, 200.0, 60.0, 70.0], "score": 0.8, "area": 4200, "iscrowd": 0},
    {"id": 2, "image_id": 2, "category_id": 1, "bbox": [10.0, 10.0, 30.0, 30.0], "score": 0.9, "area": 900, "iscrowd": 0},
    {"id": 3, "image_id": 3, "category_id": 2, "bbox": [300.0, 400.0, 55.0, 65.0], "area": 3575, "iscrowd": 0}
  ],
  "categories": [{"id": 1, "name": "bicycle"}, {"id": 2, "name": "person"}]
}"#;

    #[test]
    fn coco_dataset_takes_frames_from_file_names() {
        // Digits after a character of two or three bytes (a panic, found by make fuzz).
        assert_eq!(frame_from_file_name("frame_é0001.jpg"), Some(1));
        assert_eq!(frame_from_file_name("frame_\u{feff}0012.png"), Some(12));
        assert_eq!(frame_from_file_name("Դ޹01.jpg"), Some(1));
        assert_eq!(frame_from_file_name("été.jpg"), None);
        let b = parse("dino.json", DATASET, BoxFormat::Coco).unwrap();
        assert_eq!(
            b.iter().map(|b| (b.frame, b.line)).collect::<Vec<_>>(),
            [(123, 9), (900, 11)]
        );
        assert_eq!(b[0].bbox, [100.5, 200.0, 60.0, 70.0]);
        assert_eq!((b[1].score, b[1].label.as_deref()), (1.0, Some("person")));
        // The same file on one line, as pycocotools writes it: still COCO, every line 1.
        let one_line: String = DATASET.lines().map(str::trim).collect();
        assert_eq!(
            BoxFormat::guess(Path::new("dino.json"), &one_line),
            BoxFormat::Coco
        );
        let b = parse("dino.json", &one_line, BoxFormat::Coco).unwrap();
        assert_eq!(
            b.iter().map(|b| (b.frame, b.line)).collect::<Vec<_>>(),
            [(123, 1), (900, 1)]
        );
    }

    #[test]
    fn coco_errors_name_the_line() {
        let no_box = DATASET.replace(r#""bbox": [300.0, 400.0, 55.0, 65.0], "#, "");
        let e = err("d.json", &no_box, BoxFormat::Coco);
        assert!(e.starts_with("d.json:11: field 'bbox': missing"), "{e}");
        let unknown = DATASET.replace(r#""image_id": 3"#, r#""image_id": 7"#);
        let e = err("d.json", &unknown, BoxFormat::Coco);
        assert!(
            e.starts_with("d.json:11: field 'image_id': 7 is not among 'images'"),
            "{e}"
        );
        let no_digits = DATASET.replace(r#""frame_index": 900, "#, "");
        let e = err("d.json", &no_digits, BoxFormat::Coco);
        assert!(
            e.starts_with("d.json:6: field 'images.file_name': no digits in 'cam2/img.jpg'"),
            "{e}"
        );
        let broken = DATASET.replace(r#""height": 2160},"#, r#""height": 2160}"#);
        let e = err("d.json", &broken, BoxFormat::Coco);
        assert!(e.starts_with("d.json:5: invalid JSON at column"), "{e}");
        let no_person = DATASET.replace(r#""name": "person""#, r#""name": "car""#);
        let e = err("d.json", &no_person, BoxFormat::Coco);
        assert!(
            e.ends_with("no category named 'person' (found: bicycle, car)"),
            "{e}"
        );
    }

    #[test]
    fn formats_are_named_and_guessed() {
        assert_eq!(BoxFormat::parse("MOT"), Some(BoxFormat::Mot));
        assert_eq!(BoxFormat::parse("jsonl"), Some(BoxFormat::JsonLines));
        assert_eq!(BoxFormat::parse("coco"), Some(BoxFormat::Coco));
        assert_eq!(BoxFormat::parse("yolo"), None);
        let jsonl =
            "{\"frame\": 0, \"bbox\": [1, 2, 3, 4]}\n{\"frame\": 1, \"bbox\": [1, 2, 3, 4]}\n";
        let g = |name: &str, text: &str| BoxFormat::guess(Path::new(name), text);
        assert_eq!(g("det.txt", "{"), BoxFormat::Mot);
        assert_eq!(g("boxes.ndjson", ""), BoxFormat::JsonLines);
        assert_eq!(g("boxes.json", jsonl), BoxFormat::JsonLines);
        assert_eq!(g("boxes.json", DATASET), BoxFormat::Coco);
        assert_eq!(g("boxes", "[{\"image_id\": 0}]"), BoxFormat::Coco);
        assert_eq!(g("boxes", "1,-1,1,2,3,4,0.5"), BoxFormat::Mot);
    }

    #[test]
    fn read_boxes_from_a_file() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("det.txt");
        std::fs::write(&path, "\u{feff}1,-1,794.2,47.5,71.2,174.8,0.91,-1,-1,-1\n").unwrap();
        let b = read_boxes(&path, None).unwrap();
        assert_eq!((b.len(), b[0].frame, b[0].line), (1, 0, 1));
        let e = read_boxes(&dir.path().join("missing.txt"), None).unwrap_err();
        assert!(e.to_string().contains("cannot read"), "{e}");
    }

    fn bx(x: f64, y: f64, w: f64, h: f64, score: f64) -> RawBox {
        RawBox {
            frame: 0,
            bbox: [x, y, w, h],
            score,
            label: None,
            line: 1,
        }
    }

    /// Runs the filter and checks that the counts add up.
    fn run(
        boxes: &[RawBox],
        f: &BoxFilter,
        frame: Option<&FrameView>,
    ) -> (Vec<RawBox>, FilterCounts) {
        f.check().unwrap();
        let (kept, n) = filter_frame(boxes, f, frame);
        let removed = n.low_score
            + n.outside_roi
            + n.merged
            + n.suppressed
            + n.bad_aspect
            + n.bad_size
            + n.shadows;
        assert_eq!(n.read + n.split - removed, n.kept, "{n:?}");
        assert_eq!(kept.len(), n.kept);
        (kept, n)
    }

    /// 100 px/m: a person's box of 50 x 60 px is 0.6 m.
    fn person(x: f64, score: f64) -> RawBox {
        bx(x, 100.0, 50.0, 60.0, score)
    }

    #[test]
    fn score_and_roi_filters() {
        let mut f = BoxFilter::new(100.0);
        let (kept, n) = run(&[person(0.0, 0.2), person(100.0, 0.5)], &f, None);
        assert_eq!((n.low_score, kept[0].bbox[0]), (1, 100.0));
        f.roi = Some([0.0, 0.0, 100.0, 1080.0]); // an entry strip along the left edge
        let (kept, n) = run(
            &[person(20.0, 0.9), person(90.0, 0.9), person(300.0, 0.9)],
            &f,
            None,
        );
        assert_eq!(n.outside_roi, 2, "centres at 45, 115 and 325 px");
        assert_eq!(kept[0].bbox[0], 20.0);
    }

    #[test]
    fn near_duplicates_merge_and_overlaps_are_suppressed() {
        let f = BoxFilter::new(100.0);
        let (kept, n) = run(
            &[bx(101.0, 100.0, 50.0, 61.0, 0.6), person(100.0, 0.9)],
            &f,
            None,
        );
        assert_eq!((n.merged, kept.len()), (1, 1));
        assert!((kept[0].bbox[0] - 100.4).abs() < 1e-12 && (kept[0].bbox[3] - 60.4).abs() < 1e-12);
        assert_eq!(kept[0].score, 0.9);
        // IoU 0.54 with the best box: suppressed; IoU 0.11: kept.
        let (kept, n) = run(
            &[person(100.0, 0.9), person(115.0, 0.7), person(140.0, 0.8)],
            &f,
            None,
        );
        assert_eq!((n.merged, n.suppressed), (0, 1));
        assert_eq!(
            kept.iter().map(|b| b.bbox[0]).collect::<Vec<_>>(),
            [100.0, 140.0]
        );
    }

    #[test]
    fn aspect_and_size_filters() {
        let f = BoxFilter::new(100.0);
        let boxes = [
            person(0.0, 0.9),
            bx(300.0, 0.0, 12.0, 60.0, 0.9),   // w/h 0.2
            bx(600.0, 0.0, 15.0, 15.0, 0.9),   // 0.15 m
            bx(900.0, 0.0, 180.0, 180.0, 0.9), // 1.8 m, too wide to be a row of people
        ];
        let (kept, n) = run(&boxes, &f, None);
        assert_eq!((n.bad_aspect, n.bad_size, n.split), (1, 2, 0));
        assert_eq!(kept[0].bbox, person(0.0, 0.9).bbox);
    }

    #[test]
    fn group_boxes_split_along_their_longer_side() {
        let f = BoxFilter::new(100.0);
        let boxes = [
            bx(500.0, 100.0, 140.0, 50.0, 0.7),
            bx(800.0, 100.0, 50.0, 210.0, 0.6),
        ];
        let (kept, n) = run(&boxes, &f, None);
        assert_eq!((n.split, n.kept), (3, 5));
        assert_eq!(kept[0].bbox, [500.0, 100.0, 70.0, 50.0]);
        assert_eq!(kept[1].bbox, [570.0, 100.0, 70.0, 50.0]);
        assert_eq!(kept[4].bbox, [800.0, 240.0, 50.0, 70.0]);
        assert!(kept.iter().all(|b| b.score == 0.7 || b.score == 0.6));
        // A piece covering a person the detector also found alone gives way to it.
        let (kept, n) = run(
            &[
                bx(500.0, 100.0, 140.0, 50.0, 0.7),
                bx(502.0, 100.0, 68.0, 50.0, 0.9),
            ],
            &f,
            None,
        );
        assert_eq!((n.split, n.suppressed, kept.len()), (1, 1, 2));
        assert_eq!(kept[0].bbox[0], 502.0);
    }

    /// 200 x 100: the left half dark, nearly uniform ground; the right half bright and textured.
    fn shadow_scene() -> Vec<u8> {
        let (w, h) = (200, 100);
        let mut bgr = vec![0u8; 3 * w * h];
        let bright = [[60, 180, 200], [220, 200, 60], [240, 240, 240]];
        for y in 0..h {
            for x in 0..w {
                let px = if x < 100 {
                    let n = ((7 * x + 13 * y) % 6) as u8;
                    [40 + n, 35 + n, 30 + n]
                } else {
                    bright[(x / 4 + y / 4) % 3]
                };
                bgr[3 * (y * w + x)..3 * (y * w + x) + 3].copy_from_slice(&px);
            }
        }
        bgr
    }

    #[test]
    fn boxes_on_shadow_are_rejected() {
        let bgr = shadow_scene();
        let frame = FrameView {
            index: 0,
            width: 200,
            height: 100,
            bgr: &bgr,
        };
        let model = ShadowModel::from_patches(&[(frame, [10, 10, 40, 40])]).unwrap();
        let (dark, lit) = ([20.0, 50.0, 40.0, 40.0], [130.0, 20.0, 40.0, 50.0]);
        assert!(model.shadow_fraction(&frame, &dark) > 0.99);
        assert!(model.shadow_fraction(&frame, &lit) < 0.01);
        assert_eq!(
            model.shadow_fraction(&frame, &[500.0, 0.0, 10.0, 10.0]),
            0.0
        );
        let mut f = BoxFilter::new(100.0);
        f.shadow = Some(model);
        let boxes = [
            bx(20.0, 50.0, 40.0, 40.0, 0.9),
            bx(130.0, 20.0, 40.0, 50.0, 0.8),
        ];
        let (kept, n) = run(&boxes, &f, Some(&frame));
        assert_eq!((n.shadows, kept[0].bbox), (1, lit));
        // Without the frame the shadow test cannot run.
        assert_eq!(run(&boxes, &f, None).1.shadows, 0);
        let e = ShadowModel::from_patches(&[(frame, [195, 95, 20, 20])]).unwrap_err();
        assert!(e.contains("hold 25 pixels"), "{e}");
    }
}
