//! The box file readers: MOTChallenge txt, JSON Lines and COCO JSON, every bad row an error
//! naming its line and field.

use super::*;

pub(super) fn looks_like_json_lines(text: &str) -> bool {
    text.lines().map(str::trim).filter(|l| !l.is_empty()).all(|l| {
        matches!(serde_json::from_str::<Value>(l), Ok(Value::Object(o)) if o.contains_key("frame"))
    })
}

/// Where a value sits, for messages.
#[derive(Clone, Copy)]
pub(super) struct At<'a> {
    ctx: FileCtx<'a>,
    line: Option<usize>,
}

impl At<'_> {
    pub(super) fn err(&self, field: &str, message: impl Into<String>) -> FileError {
        self.ctx.err(self.line, Some(field), message)
    }

    pub(super) fn positive(&self, field: &str, v: f64) -> Result<f64, FileError> {
        if v > 0.0 {
            Ok(v)
        } else {
            Err(self.err(
                field,
                format!("expected a positive size in pixels, found {v}"),
            ))
        }
    }

    pub(super) fn score(&self, field: &str, v: f64, alternative: &str) -> Result<f64, FileError> {
        if (0.0..=1.0).contains(&v) {
            Ok(v)
        } else {
            Err(self.err(
                field,
                format!(
                    "expected a score in [0, 1]{alternative}, found {v} (a detector whose scores \
                     are not probabilities, such as MOTChallenge's ACF or DPM files, needs them \
                     scaled to [0, 1] first)"
                ),
            ))
        }
    }
}

pub(super) const MOT_FIELDS: [&str; 10] = [
    "frame", "id", "left", "top", "width", "height", "conf", "x", "y", "z",
];

/// A JSON value for a message, cut short.
pub(super) fn show(v: &serde_json::Value) -> String {
    crate::io::clip(&v.to_string(), 60)
}

/// The largest frame number accepted: a day of video at 100 frames/s is 8.6 million.
pub(super) const MAX_FRAME: f64 = 1e15;

pub(super) fn parse_mot(ctx: FileCtx, text: &str) -> Result<Vec<RawBox>, FileError> {
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
            head: None,
        });
    }
    Ok(out)
}

/// serde_json's message without its "at line L column C", which the caller words itself.
pub(super) fn json_message(e: &serde_json::Error) -> String {
    let s = e.to_string();
    match s.rfind(" at line ") {
        Some(i) => s[..i].to_string(),
        None => s,
    }
}

pub(super) fn json_number(at: At, field: &str, v: &Value) -> Result<f64, FileError> {
    v.as_f64()
        .filter(|x| x.is_finite())
        .ok_or_else(|| at.err(field, format!("expected a number, found {}", show(v))))
}

pub(super) fn json_frame(at: At, field: &str, v: &Value) -> Result<usize, FileError> {
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
pub(super) fn json_box(
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
        head: None,
    })
}

pub(super) fn parse_json_lines(ctx: FileCtx, text: &str) -> Result<Vec<RawBox>, FileError> {
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
pub(super) fn element_lines(text: &str) -> HashMap<String, Vec<usize>> {
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
pub(super) fn frame_from_file_name(name: &str) -> Option<usize> {
    let stem = Path::new(name).file_stem()?.to_str()?;
    let end = stem.rfind(|c: char| c.is_ascii_digit())? + 1;
    // After the last character that is not a digit, whatever its width in bytes.
    let start = stem[..end]
        .char_indices()
        .rfind(|(_, c)| !c.is_ascii_digit())
        .map_or(0, |(i, c)| i + c.len_utf8());
    stem[start..end].parse().ok()
}

/// The person categories' ids as JSON text (integer and string ids both work): those named
/// "person", or COCO's 1 without categories.
fn coco_person_ids<'a>(
    ctx: FileCtx<'a>,
    categories: Option<&Value>,
    at: &dyn Fn(&str, usize) -> At<'a>,
) -> Result<HashSet<String>, FileError> {
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
    Ok(person_ids)
}

/// Image id -> frame, when the file lists its images.
fn coco_frames<'a>(
    ctx: FileCtx<'a>,
    images: Option<&Value>,
    at: &dyn Fn(&str, usize) -> At<'a>,
) -> Result<Option<HashMap<String, usize>>, FileError> {
    Ok(match images {
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
    })
}

/// A results list `[{image_id, category_id, bbox, score}]` (image_id the 0-based frame) or a
/// dataset `{images, annotations, categories}`. Only people are kept: the categories named
/// "person" when categories are given, else category_id 1 (COCO's person) or none.
pub(super) fn parse_coco(ctx: FileCtx, text: &str) -> Result<Vec<RawBox>, FileError> {
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

    let person_ids = coco_person_ids(ctx, categories, &at)?;
    let frames = coco_frames(ctx, images, &at)?;

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
