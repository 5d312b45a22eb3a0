//! YOLO-family outputs to boxes (pure): the output layouts of darknet (YOLOv3/v4 heads),
//! YOLOv5, anchor-free YOLOv8–v11 and YOLOX, letterboxing, tiling and non-maximum suppression.
//! Boxes are `[x, y, width, height]` in pixels of the image given, (0, 0) the top-left pixel's
//! centre minus half a pixel (the models' own convention: the image's corner).

// The decoding is reached only through the two model runners (ONNX Runtime, OpenCV's dnn).
#![cfg_attr(not(any(feature = "onnx", feature = "opencv")), allow(dead_code))]

use serde::{Deserialize, Serialize};

use super::boxes::iou;

/// How a model's outputs encode boxes.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(tag = "kind", rename_all = "snake_case")]
pub enum Layout {
    /// Darknet heads: one raw output `[1, A·(5+C), H, W]` per scale; sigmoid on x, y,
    /// objectness and classes, `exp(w)·anchor`; `anchors` in input pixels, `masks` the anchors
    /// of each head in output order, `strides` each head's.
    Darknet {
        anchors: Vec<[f64; 2]>,
        masks: Vec<Vec<usize>>,
        strides: Vec<f64>,
    },
    /// YOLOv5/v7: `[1, N, 5+C]`, boxes decoded (centre x, y, w, h in input pixels), objectness
    /// and class scores already through a sigmoid.
    Yolov5,
    /// YOLOv8–v11: `[1, 4+C, N]`, decoded centre boxes, class scores, no objectness.
    Yolov8,
    /// YOLOX: `[1, N, 5+C]` raw grid offsets (strides 8, 16, 32), scores through a sigmoid.
    Yolox,
    /// geostride's overhead detector (`scripts/train_detector.py`, metadata `geostride.layout =
    /// geostride-centre-heatmap-1`): `[1, K, 7]` heatmap peaks decoded in the model, each
    /// score, box centre x, y, width, height and the top of the head x, y in input pixels; one
    /// class.
    CentreHeatmap,
}

/// The `geostride.layout` metadata of a model trained by `scripts/train_detector.py`.
pub const CENTRE_HEATMAP_LAYOUT: &str = "geostride-centre-heatmap-1";

impl Layout {
    /// A layout without parameters by its settings name (`yolov5`, `yolov8`, `yolox`); darknet's
    /// anchors come from the model, so `darknet` is `None` too.
    pub fn from_name(name: &str) -> Option<Layout> {
        match name {
            "yolov5" => Some(Layout::Yolov5),
            "yolov8" => Some(Layout::Yolov8),
            "yolox" => Some(Layout::Yolox),
            "centre_heatmap" => Some(Layout::CentreHeatmap),
            _ => None,
        }
    }

    /// The settings name of a layout.
    pub fn name(&self) -> &'static str {
        match self {
            Layout::Darknet { .. } => "darknet",
            Layout::Yolov5 => "yolov5",
            Layout::Yolov8 => "yolov8",
            Layout::Yolox => "yolox",
            Layout::CentreHeatmap => "centre_heatmap",
        }
    }

    /// The layout of a model from its outputs' shapes (channels-first darknet heads, or one
    /// output), when it can be told; `None` for YOLOX and darknet, which look like others or
    /// need anchors: name them.
    pub fn guess(shapes: &[Vec<i64>], classes: Option<usize>) -> Option<Layout> {
        let [s] = shapes else { return None };
        if s.len() != 3 {
            return None;
        }
        let (a, b) = (s[1], s[2]);
        match classes {
            Some(c) if b == 5 + c as i64 => Some(Layout::Yolov5),
            Some(c) if a == 4 + c as i64 => Some(Layout::Yolov8),
            // Anchor-free outputs have the many candidates last.
            _ if a < b => Some(Layout::Yolov8),
            _ => Some(Layout::Yolov5),
        }
    }
}

/// One raw detection in the model's input pixels.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct RawBox {
    pub xywh: [f64; 4],
    pub score: f64,
    pub class: usize,
    /// The top of the person's head, where the layout gives it (the centre heatmap's).
    pub head: Option<[f64; 2]>,
}

impl RawBox {
    /// A box given by its centre and size.
    fn centred(cx: f64, cy: f64, w: f64, h: f64, score: f64, class: usize) -> RawBox {
        RawBox {
            xywh: [cx - w / 2.0, cy - h / 2.0, w, h],
            score,
            class,
            head: None,
        }
    }
}

fn sigmoid(x: f32) -> f64 {
    1.0 / (1.0 + (-f64::from(x)).exp())
}

/// What to keep.
#[derive(Clone, Debug)]
pub struct Keep<'a> {
    /// Class ids kept (empty: all).
    pub classes: &'a [usize],
    /// Lowest score (objectness × class probability where there is one).
    pub min_score: f64,
}

impl Keep<'_> {
    fn wants(&self, class: usize) -> bool {
        self.classes.is_empty() || self.classes.contains(&class)
    }
}

/// Decodes a model's outputs (shape, values; in the model's output order) for an input of
/// `input_wh` pixels.
pub(crate) fn decode(
    layout: &Layout,
    outputs: &[(Vec<i64>, Vec<f32>)],
    input_wh: [usize; 2],
    keep: &Keep,
) -> Result<Vec<RawBox>, String> {
    let mut out = Vec::new();
    match layout {
        Layout::Darknet {
            anchors,
            masks,
            strides,
        } => decode_darknet(anchors, masks, strides, outputs, keep, &mut out)?,
        Layout::Yolov5 | Layout::Yolox => decode_yolov5(layout, outputs, input_wh, keep, &mut out)?,
        Layout::Yolov8 => decode_yolov8(outputs, keep, &mut out)?,
        Layout::CentreHeatmap => decode_centre(outputs, keep, &mut out)?,
    }
    // A value that is not a number (a broken export) makes no box: NaN passes every `<` test.
    out.retain(|b| {
        b.score.is_finite()
            && b.xywh.iter().all(|v| v.is_finite())
            && b.xywh[2] > 0.0
            && b.xywh[3] > 0.0
    });
    Ok(out)
}

/// [`decode`] of darknet's heads `[1, A·(5+C), H, W]`, one per mask.
fn decode_darknet(
    anchors: &[[f64; 2]],
    masks: &[Vec<usize>],
    strides: &[f64],
    outputs: &[(Vec<i64>, Vec<f32>)],
    keep: &Keep,
    out: &mut Vec<RawBox>,
) -> Result<(), String> {
    if outputs.len() != masks.len() || strides.len() != masks.len() {
        return Err(format!(
            "the model has {} output(s); the darknet layout names {} head(s)",
            outputs.len(),
            masks.len()
        ));
    }
    for ((shape, data), (mask, &stride)) in outputs.iter().zip(masks.iter().zip(strides)) {
        let [1, ch, gh, gw] = shape[..] else {
            return Err(format!(
                "a darknet head of shape {shape:?}, expected [1, C, H, W]"
            ));
        };
        let (ch, gh, gw) = (ch as usize, gh as usize, gw as usize);
        let na = mask.len();
        if na == 0 || ch % na != 0 || ch / na < 6 {
            return Err(format!(
                "a darknet head with {ch} channels for {na} anchors"
            ));
        }
        let per = ch / na;
        let nc = per - 5;
        let at = |a: usize, k: usize, y: usize, x: usize| data[((a * per + k) * gh + y) * gw + x];
        for (a, &m) in mask.iter().enumerate() {
            let anchor = anchors.get(m).ok_or("a mask names a missing anchor")?;
            for y in 0..gh {
                for x in 0..gw {
                    let obj = sigmoid(at(a, 4, y, x));
                    if obj < keep.min_score {
                        continue;
                    }
                    let (mut best, mut best_c) = (0.0, 0);
                    for c in 0..nc {
                        if !keep.wants(c) {
                            continue;
                        }
                        let p = sigmoid(at(a, 5 + c, y, x));
                        if p > best {
                            (best, best_c) = (p, c);
                        }
                    }
                    let score = obj * best;
                    if score < keep.min_score {
                        continue;
                    }
                    let cx = (x as f64 + sigmoid(at(a, 0, y, x))) * stride;
                    let cy = (y as f64 + sigmoid(at(a, 1, y, x))) * stride;
                    let w = f64::from(at(a, 2, y, x)).exp() * anchor[0];
                    let h = f64::from(at(a, 3, y, x)).exp() * anchor[1];
                    out.push(RawBox::centred(cx, cy, w, h, score, best_c));
                }
            }
        }
    }
    Ok(())
}

/// [`decode`] of the centre heatmap's peaks `[1, K, 7]`.
fn decode_centre(
    outputs: &[(Vec<i64>, Vec<f32>)],
    keep: &Keep,
    out: &mut Vec<RawBox>,
) -> Result<(), String> {
    let (data, [n, per]) = single(outputs, "[1, K, 7]", 1)?;
    if per != 7 {
        return Err(format!(
            "{per} values a candidate; the centre heatmap layout has 7 (score, x, y, w, h, head x, y)"
        ));
    }
    if !keep.wants(0) {
        return Ok(());
    }
    for v in data.chunks_exact(7).take(n) {
        let score = f64::from(v[0]);
        if score < keep.min_score {
            continue;
        }
        let (cx, cy, w, h) = (
            f64::from(v[1]),
            f64::from(v[2]),
            f64::from(v[3]),
            f64::from(v[4]),
        );
        out.push(RawBox {
            head: Some([f64::from(v[5]), f64::from(v[6])]),
            ..RawBox::centred(cx, cy, w, h, score, 0)
        });
    }
    Ok(())
}

/// [`decode`] of YOLOv5's or YOLOX's one output `[1, N, 5+C]`.
fn decode_yolov5(
    layout: &Layout,
    outputs: &[(Vec<i64>, Vec<f32>)],
    input_wh: [usize; 2],
    keep: &Keep,
    out: &mut Vec<RawBox>,
) -> Result<(), String> {
    let (data, [n, per]) = single(outputs, "[1, N, 5+C]", 6)?;
    // YOLOX's candidates on the grids of strides 8, 16, 32, in that order.
    let grid = matches!(layout, Layout::Yolox).then(|| yolox_grid(input_wh));
    if let Some(g) = &grid
        && g.len() != n
    {
        return Err(format!(
            "{n} candidates; a YOLOX model at {}x{} has {}",
            input_wh[0],
            input_wh[1],
            g.len()
        ));
    }
    for i in 0..n {
        let v = &data[i * per..(i + 1) * per];
        let obj = f64::from(v[4]);
        if obj < keep.min_score {
            continue;
        }
        let Some((best_c, best)) = (0..per - 5)
            .filter(|&c| keep.wants(c))
            .map(|c| (c, f64::from(v[5 + c])))
            .max_by(|a, b| a.1.total_cmp(&b.1))
        else {
            continue;
        };
        let score = obj * best;
        if score < keep.min_score {
            continue;
        }
        let (cx, cy, w, h) = match &grid {
            Some(g) => {
                let (gx, gy, s) = g[i];
                (
                    (f64::from(v[0]) + gx) * s,
                    (f64::from(v[1]) + gy) * s,
                    f64::from(v[2]).exp() * s,
                    f64::from(v[3]).exp() * s,
                )
            }
            None => (
                f64::from(v[0]),
                f64::from(v[1]),
                f64::from(v[2]),
                f64::from(v[3]),
            ),
        };
        out.push(RawBox::centred(cx, cy, w, h, score, best_c));
    }
    Ok(())
}

/// [`decode`] of YOLOv8's one output `[1, 4+C, N]`.
fn decode_yolov8(
    outputs: &[(Vec<i64>, Vec<f32>)],
    keep: &Keep,
    out: &mut Vec<RawBox>,
) -> Result<(), String> {
    let (data, [per, n]) = single(outputs, "[1, 4+C, N]", 5)?;
    let at = |k: usize, i: usize| f64::from(data[k * n + i]);
    for i in 0..n {
        let Some((best_c, score)) = (0..per - 4)
            .filter(|&c| keep.wants(c))
            .map(|c| (c, at(4 + c, i)))
            .max_by(|a, b| a.1.total_cmp(&b.1))
        else {
            continue;
        };
        if score < keep.min_score {
            continue;
        }
        let (cx, cy, w, h) = (at(0, i), at(1, i), at(2, i), at(3, i));
        out.push(RawBox::centred(cx, cy, w, h, score, best_c));
    }
    Ok(())
}

/// The one output `[1, a, b]` of a single-output layout (`form` for messages): its values and
/// `[a, b]`; the candidates' length (b for `[1, N, 5+C]`, a for `[1, 4+C, N]`) at least `least`.
fn single<'a>(
    outputs: &'a [(Vec<i64>, Vec<f32>)],
    form: &str,
    least: usize,
) -> Result<(&'a [f32], [usize; 2]), String> {
    let [(shape, data)] = outputs else {
        return Err(format!("{} outputs, expected one {form}", outputs.len()));
    };
    let [1, a, b] = shape[..] else {
        return Err(format!("an output of shape {shape:?}, expected {form}"));
    };
    let (a, b) = (a.max(0) as usize, b.max(0) as usize);
    let per = if form.ends_with("N]") { a } else { b };
    if per < least {
        return Err(format!(
            "{per} values per candidate, expected {} + classes",
            least - 1
        ));
    }
    Ok((data, [a, b]))
}

/// YOLOX's candidate cells: (x, y, stride) over strides 8, 16, 32.
fn yolox_grid(input_wh: [usize; 2]) -> Vec<(f64, f64, f64)> {
    let mut g = Vec::new();
    for s in [8usize, 16, 32] {
        for y in 0..input_wh[1] / s {
            for x in 0..input_wh[0] / s {
                g.push((x as f64, y as f64, s as f64));
            }
        }
    }
    g
}

/// Greedy non-maximum suppression per class: the best first, then each box overlapping a kept
/// one of its class by more than `max_iou`, or lying more than `max_contained` of the smaller
/// box's area inside it (1: never), is dropped; ties broken by position, so the result does not
/// depend on the input's order. At most `max_boxes`.
pub fn nms(
    mut boxes: Vec<RawBox>,
    max_iou: f64,
    max_contained: f64,
    max_boxes: usize,
) -> Vec<RawBox> {
    boxes.sort_by(|a, b| {
        b.score
            .total_cmp(&a.score)
            .then(a.xywh[0].total_cmp(&b.xywh[0]))
            .then(a.xywh[1].total_cmp(&b.xywh[1]))
    });
    let mut kept: Vec<RawBox> = Vec::new();
    for b in boxes {
        if kept.len() >= max_boxes {
            break;
        }
        if kept.iter().all(|k| {
            k.class != b.class
                || (iou(&k.xywh, &b.xywh) <= max_iou
                    && (max_contained >= 1.0 || contained(&k.xywh, &b.xywh) <= max_contained))
        }) {
            kept.push(b);
        }
    }
    kept
}

/// The share of the smaller box's area that lies inside the other box: 1 for a box inside
/// another, whatever their IoU (a centre-heatmap model can put a second peak on a large
/// person's body part, whose box lies inside the whole person's).
pub fn contained(a: &[f64; 4], b: &[f64; 4]) -> f64 {
    let iw = ((a[0] + a[2]).min(b[0] + b[2]) - a[0].max(b[0])).max(0.0);
    let ih = ((a[1] + a[3]).min(b[1] + b[3]) - a[1].max(b[1])).max(0.0);
    let smaller = (a[2] * a[3]).min(b[2] * b[3]);
    if smaller > 0.0 {
        iw * ih / smaller
    } else {
        0.0
    }
}

/// How an image is fitted to the model's input: scale, then padding (left, top), input pixels.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Fit {
    pub scale: [f64; 2],
    pub pad: [f64; 2],
}

impl Fit {
    /// Letterbox (one scale, centred, padded) or stretch (each axis its own scale).
    pub fn new(image_wh: [usize; 2], input_wh: [usize; 2], letterbox: bool) -> Fit {
        let sx = input_wh[0] as f64 / image_wh[0] as f64;
        let sy = input_wh[1] as f64 / image_wh[1] as f64;
        if letterbox {
            let s = sx.min(sy);
            Fit {
                scale: [s, s],
                pad: [
                    ((input_wh[0] as f64 - image_wh[0] as f64 * s) / 2.0).floor(),
                    ((input_wh[1] as f64 - image_wh[1] as f64 * s) / 2.0).floor(),
                ],
            }
        } else {
            Fit {
                scale: [sx, sy],
                pad: [0.0, 0.0],
            }
        }
    }

    /// A point in input pixels back to image pixels, (0, 0) the top-left pixel's centre in
    /// both (boxes are by pixel edges: [`Fit::to_image`]).
    pub fn point_to_image(&self, p: &[f64; 2]) -> [f64; 2] {
        [
            (p[0] + 0.5 - self.pad[0]) / self.scale[0] - 0.5,
            (p[1] + 0.5 - self.pad[1]) / self.scale[1] - 0.5,
        ]
    }

    /// A box in input pixels back to image pixels.
    pub fn to_image(&self, b: &[f64; 4]) -> [f64; 4] {
        [
            (b[0] - self.pad[0]) / self.scale[0],
            (b[1] - self.pad[1]) / self.scale[1],
            b[2] / self.scale[0],
            b[3] / self.scale[1],
        ]
    }
}

/// Interleaved 8-bit BGR (a video frame's, `image_wh`) to the model's planar float input
/// (`input_wh`), fitted by `fit` (bilinear, pad value 114 as YOLO's letterbox), each channel
/// `(v/255 − mean)/std`, in RGB order (or BGR with `model_bgr`).
pub fn to_input(
    bgr: &[u8],
    image_wh: [usize; 2],
    input_wh: [usize; 2],
    fit: &Fit,
    mean: [f32; 3],
    std: [f32; 3],
    model_bgr: bool,
) -> Vec<f32> {
    let (w, h) = (image_wh[0], image_wh[1]);
    let (iw, ih) = (input_wh[0], input_wh[1]);
    let plane = iw * ih;
    let mut out = vec![0f32; 3 * plane];
    // The source channel of each of the model's.
    let order: [usize; 3] = if model_bgr { [0, 1, 2] } else { [2, 1, 0] };
    for y in 0..ih {
        // Pixel centres map to pixel centres.
        let sy = (y as f64 + 0.5 - fit.pad[1]) / fit.scale[1] - 0.5;
        for x in 0..iw {
            let sx = (x as f64 + 0.5 - fit.pad[0]) / fit.scale[0] - 0.5;
            let inside = sx > -1.0 && sy > -1.0 && sx < w as f64 && sy < h as f64;
            let mut px = [114.0f32; 3];
            if inside {
                let (x0, y0) = (sx.floor(), sy.floor());
                let (fx, fy) = ((sx - x0) as f32, (sy - y0) as f32);
                let cl = |v: f64, n: usize| (v.max(0.0) as usize).min(n - 1);
                let (xa, xb) = (cl(x0, w), cl(x0 + 1.0, w));
                let (ya, yb) = (cl(y0, h), cl(y0 + 1.0, h));
                for (c, p) in px.iter_mut().enumerate() {
                    let v = |xx: usize, yy: usize| f32::from(bgr[(yy * w + xx) * 3 + c]);
                    *p = (v(xa, ya) * (1.0 - fx) + v(xb, ya) * fx) * (1.0 - fy)
                        + (v(xa, yb) * (1.0 - fx) + v(xb, yb) * fx) * fy;
                }
            }
            for (k, &c) in order.iter().enumerate() {
                out[k * plane + y * iw + x] = (px[c] / 255.0 - mean[k]) / std[k];
            }
        }
    }
    out
}

/// Tiles `[x, y, w, h]` covering `region` with squares of `tile` pixels overlapping by at least
/// `overlap` pixels (one tile when the region is smaller).
pub fn tiles(region: [usize; 4], tile: usize, overlap: usize) -> Vec<[usize; 4]> {
    let axis = |start: usize, len: usize| -> Vec<(usize, usize)> {
        if len <= tile {
            return vec![(start, len)];
        }
        let step = tile.saturating_sub(overlap).max(1);
        let n = (len - tile).div_ceil(step) + 1;
        (0..n)
            .map(|i| {
                // Spread evenly, the last flush with the end.
                let off = if n == 1 {
                    0
                } else {
                    i * (len - tile) / (n - 1)
                };
                (start + off, tile)
            })
            .collect()
    };
    let mut out = Vec::new();
    for (y, h) in axis(region[1], region[3]) {
        for (x, w) in axis(region[0], region[2]) {
            out.push([x, y, w, h]);
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    fn logit(p: f64) -> f32 {
        (p / (1.0 - p)).ln() as f32
    }

    #[test]
    fn centre_heatmap_rows_are_boxes_about_their_centres() {
        let keep = Keep {
            classes: &[],
            min_score: 0.3,
        };
        // Two candidates: one kept, one under the score.
        let rows = vec![
            0.9, 100.0, 50.0, 20.0, 40.0, 100.0, 35.0, //
            0.1, 10.0, 10.0, 5.0, 5.0, 10.0, 8.0,
        ];
        let b = decode(
            &Layout::CentreHeatmap,
            &[(vec![1, 2, 7], rows)],
            [256, 256],
            &keep,
        )
        .unwrap();
        assert_eq!(b.len(), 1);
        assert_eq!(b[0].xywh, [90.0, 30.0, 20.0, 40.0]);
        assert_eq!(b[0].head, Some([100.0, 35.0]));
        assert!((b[0].score - 0.9).abs() < 1e-6);
        let six = vec![0.0f32; 12];
        let e = decode(
            &Layout::CentreHeatmap,
            &[(vec![1, 2, 6], six)],
            [256, 256],
            &keep,
        )
        .unwrap_err();
        assert!(e.contains("has 7"), "{e}");
    }

    #[test]
    fn a_darknet_head_decodes_to_its_box() {
        // One head, stride 32, a 2x2 grid, 1 anchor, 2 classes; a person (class 0) in cell (1, 0).
        let (gh, gw, per) = (2usize, 2usize, 7usize);
        let mut data = vec![-20.0f32; per * gh * gw];
        let set = |d: &mut Vec<f32>, k: usize, v: f32| d[(k * gh) * gw + 1] = v;
        set(&mut data, 0, logit(0.5));
        set(&mut data, 1, logit(0.25));
        set(&mut data, 2, (2.0f64).ln() as f32);
        set(&mut data, 3, 0.0);
        set(&mut data, 4, logit(0.9));
        set(&mut data, 5, logit(0.8));
        let layout = Layout::Darknet {
            anchors: vec![[10.0, 20.0]],
            masks: vec![vec![0]],
            strides: vec![32.0],
        };
        let keep = Keep {
            classes: &[0],
            min_score: 0.3,
        };
        let b = decode(&layout, &[(vec![1, 7, 2, 2], data)], [64, 64], &keep).unwrap();
        assert_eq!(b.len(), 1);
        let b = b[0];
        assert!((b.score - 0.72).abs() < 1e-6);
        // Centre (1.5·32, 0.25·32) = (48, 8), size (20, 20).
        for (g, w) in b.xywh.iter().zip([38.0, -2.0, 20.0, 20.0]) {
            assert!((g - w).abs() < 1e-4, "{:?}", b.xywh);
        }
    }

    #[test]
    fn yolov8_and_yolov5_outputs_decode_and_guess() {
        // Two candidates, 2 classes: [1, 6, 2] and [1, 2, 7].
        let v8 = vec![
            10.0, 50.0, // cx
            20.0, 60.0, // cy
            4.0, 8.0, // w
            6.0, 8.0, // h
            0.9, 0.1, // class 0
            0.05, 0.2, // class 1
        ];
        let keep = Keep {
            classes: &[],
            min_score: 0.5,
        };
        let b = decode(&Layout::Yolov8, &[(vec![1, 6, 2], v8)], [64, 64], &keep).unwrap();
        assert_eq!(b.len(), 1);
        assert_eq!(b[0].xywh, [8.0, 17.0, 4.0, 6.0]);
        let v5 = vec![
            10.0, 20.0, 4.0, 6.0, 0.9, 0.1, 0.95, 50.0, 60.0, 8.0, 8.0, 0.2, 0.9, 0.1,
        ];
        let b = decode(&Layout::Yolov5, &[(vec![1, 2, 7], v5)], [64, 64], &keep).unwrap();
        assert_eq!(b.len(), 1);
        assert_eq!((b[0].class, b[0].xywh), (1, [8.0, 17.0, 4.0, 6.0]));
        assert_eq!(
            Layout::guess(&[vec![1, 84, 8400]], Some(80)),
            Some(Layout::Yolov8)
        );
        assert_eq!(
            Layout::guess(&[vec![1, 25200, 85]], Some(80)),
            Some(Layout::Yolov5)
        );
        assert!(
            decode(
                &Layout::Yolov8,
                &[(vec![1, 6], vec![0.0; 6])],
                [64, 64],
                &keep
            )
            .is_err()
        );
    }

    #[test]
    fn values_that_are_not_numbers_make_no_box() {
        let keep = Keep {
            classes: &[],
            min_score: 0.3,
        };
        let nan = f32::NAN;
        // A NaN score, a NaN centre, an infinite width, a box of no height, then a good one.
        let v5 = vec![
            10.0,
            20.0,
            4.0,
            6.0,
            nan,
            0.9,
            0.1, //
            nan,
            20.0,
            4.0,
            6.0,
            0.9,
            0.9,
            0.1, //
            10.0,
            20.0,
            f32::INFINITY,
            6.0,
            0.9,
            0.9,
            0.1, //
            10.0,
            20.0,
            4.0,
            0.0,
            0.9,
            0.9,
            0.1, //
            10.0,
            20.0,
            4.0,
            6.0,
            0.9,
            0.9,
            0.1,
        ];
        let b = decode(&Layout::Yolov5, &[(vec![1, 5, 7], v5)], [64, 64], &keep).unwrap();
        assert_eq!(b.len(), 1);
        assert_eq!(b[0].xywh, [8.0, 17.0, 4.0, 6.0]);
        let v8 = vec![nan; 12];
        let b = decode(&Layout::Yolov8, &[(vec![1, 6, 2], v8)], [64, 64], &keep).unwrap();
        assert!(b.is_empty());
    }

    #[test]
    fn a_yolox_candidate_decodes_on_its_grid() {
        // A 64x64 input: 64 + 16 + 4 = 84 candidates; the 65th is the first of stride 16.
        let (n, per) = (84usize, 7usize);
        let mut v = vec![0.0f32; n * per];
        let c = 64 * per;
        v[c..c + per].copy_from_slice(&[0.5, 0.25, (2.0f32).ln(), 0.0, 0.9, 0.8, 0.1]);
        let keep = Keep {
            classes: &[],
            min_score: 0.5,
        };
        let b = decode(
            &Layout::Yolox,
            &[(vec![1, n as i64, per as i64], v)],
            [64, 64],
            &keep,
        )
        .unwrap();
        assert_eq!(b.len(), 1);
        // Cell (0, 0) of stride 16: centre (8, 4), size (32, 16).
        for (g, w) in b[0].xywh.iter().zip([-8.0, -4.0, 32.0, 16.0]) {
            assert!((g - w).abs() < 1e-6, "{:?}", b[0].xywh);
        }
        assert!((b[0].score - 0.72).abs() < 1e-6);
        let short = vec![0.0f32; 80 * per];
        assert!(decode(&Layout::Yolox, &[(vec![1, 80, 7], short)], [64, 64], &keep).is_err());
    }

    #[test]
    fn nms_keeps_the_best_of_overlapping_boxes_whatever_their_order() {
        let b = |x: f64, s: f64| RawBox {
            xywh: [x, 0.0, 10.0, 10.0],
            score: s,
            class: 0,
            head: None,
        };
        let boxes = vec![b(0.0, 0.5), b(1.0, 0.9), b(30.0, 0.4)];
        let mut rev = boxes.clone();
        rev.reverse();
        let kept = nms(boxes, 0.45, 1.0, 10);
        assert_eq!(kept, nms(rev, 0.45, 1.0, 10));
        assert_eq!(kept.len(), 2);
        assert_eq!(kept[0].score, 0.9);
    }

    #[test]
    fn a_box_inside_a_better_one_is_dropped_only_when_asked() {
        let b = |xywh: [f64; 4], s: f64| RawBox {
            xywh,
            score: s,
            class: 0,
            head: None,
        };
        // A person's whole box and a part of it (IoU 0.25), and a neighbour touching it.
        let boxes = vec![
            b([0.0, 0.0, 20.0, 40.0], 0.8),
            b([2.0, 2.0, 10.0, 20.0], 0.5),
            b([18.0, 0.0, 20.0, 40.0], 0.7),
        ];
        assert!((contained(&boxes[0].xywh, &boxes[1].xywh) - 1.0).abs() < 1e-12);
        assert!((contained(&boxes[0].xywh, &boxes[2].xywh) - 0.1).abs() < 1e-12);
        assert_eq!(nms(boxes.clone(), 0.45, 1.0, 10).len(), 3);
        let kept = nms(boxes, 0.45, 0.6, 10);
        assert_eq!(kept.len(), 2);
        assert_eq!([kept[0].score, kept[1].score], [0.8, 0.7]);
    }

    #[test]
    fn letterbox_and_tiles_map_back() {
        let fit = Fit::new([1920, 1080], [416, 416], true);
        let b = [100.0, 200.0, 13.0, 26.0];
        let input = [
            b[0] * fit.scale[0] + fit.pad[0],
            b[1] * fit.scale[1] + fit.pad[1],
            b[2] * fit.scale[0],
            b[3] * fit.scale[1],
        ];
        for (g, w) in fit.to_image(&input).iter().zip(b) {
            assert!((g - w).abs() < 1e-9);
        }
        let t = tiles([0, 0, 1920, 1080], 416, 64);
        assert!(t.iter().all(|t| t[0] + t[2] <= 1920 && t[1] + t[3] <= 1080));
        assert_eq!(t.last().unwrap()[0] + 416, 1920);
        // Neighbours overlap by at least 64 px.
        assert!(t[1][0] - t[0][0] <= 416 - 64);
        assert_eq!(tiles([10, 20, 100, 50], 416, 64), vec![[10, 20, 100, 50]]);
    }

    #[test]
    fn a_uniform_image_fills_the_input_and_pads_with_grey() {
        // A blue image (BGR 255, 0, 0): the model's RGB planes put it last.
        let bgr: Vec<u8> = (0..8).flat_map(|_| [255u8, 0, 0]).collect();
        let fit = Fit::new([4, 2], [4, 4], true);
        let x = to_input(&bgr, [4, 2], [4, 4], &fit, [0.0; 3], [1.0; 3], false);
        // Rows 1 and 2 are the image, rows 0 and 3 padding.
        assert!((x[2 * 16 + 4] - 1.0).abs() < 1e-6 && x[4].abs() < 1e-6);
        assert!((x[0] - 114.0 / 255.0).abs() < 1e-6);
    }
}
