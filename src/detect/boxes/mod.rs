//! Person boxes from an external detector (Grounding DINO, YOLO, ...), pure: readers for
//! MOTChallenge txt, JSON Lines and COCO JSON, and per-frame filters (score, region of interest,
//! duplicates, groups, overlap, shape, size, shadows).
//!
//! Frames are 0-based here. MOT files number frames from 1 and are shifted; JSON Lines `frame`,
//! COCO `image_id`, `frame_index`/`frame_id` and the digits of a COCO `file_name` are taken as
//! 0-based frame indices as written (ffmpeg numbers extracted frames from 1 by default: subtract
//! one in the caller, or write `frame_index`). Boxes are `[x, y, w, h]` pixels, (x, y) the
//! top-left corner, used as the file gives them.
//!
//! Files: this one the box and the format; `read` the readers; `filter` the filters;
//! `shadow` the shadow model.

use std::collections::{BTreeMap, HashMap, HashSet};
use std::ops::AddAssign;
use std::path::Path;

use nalgebra::{Matrix3, Vector3};
use serde_json::{Map, Value};

use super::FrameView;
use super::colour::lab;
use crate::io::{FileCtx, FileError};

mod filter;
mod read;
mod shadow;
#[cfg(test)]
mod tests;

pub use filter::{BoxFilter, FilterCounts, FilterError, filter_frame};
use read::*;
pub use shadow::{MIN_SHADOW_PIXELS, SHADOW_COLOUR_FLOOR, ShadowError, ShadowModel};

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
    /// The top of the head, pixels ((0, 0) the top-left pixel's centre), where the detector
    /// gives it (geostride's overhead model); a file's boxes have none.
    pub head: Option<[f64; 2]>,
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

/// The largest COCO file read: it is parsed whole into a JSON tree, some fifteen times its size.
pub const MAX_COCO_BYTES: usize = 64 << 20;

/// Boxes grouped by frame, frames in order.
pub fn group_by_frame(boxes: Vec<RawBox>) -> Vec<(usize, Vec<RawBox>)> {
    let mut map: BTreeMap<usize, Vec<RawBox>> = BTreeMap::new();
    for b in boxes {
        map.entry(b.frame).or_default().push(b);
    }
    map.into_iter().collect()
}

/// The area two `[x, y, w, h]` boxes share, px² (0 when apart).
pub fn intersection(a: &[f64; 4], b: &[f64; 4]) -> f64 {
    let iw = (a[0] + a[2]).min(b[0] + b[2]) - a[0].max(b[0]);
    let ih = (a[1] + a[3]).min(b[1] + b[3]) - a[1].max(b[1]);
    if iw <= 0.0 || ih <= 0.0 {
        return 0.0;
    }
    iw * ih
}

/// Intersection over union of two `[x, y, w, h]` boxes.
pub fn iou(a: &[f64; 4], b: &[f64; 4]) -> f64 {
    let inter = intersection(a, b);
    if inter <= 0.0 {
        return 0.0;
    }
    inter / (a[2] * a[3] + b[2] * b[3] - inter)
}
