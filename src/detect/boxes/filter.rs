//! The per-frame box filters: score, region, duplicates, groups, overlap, shape, size, shadows.

use super::*;

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

pub(super) fn retain_counting(
    bs: &mut Vec<RawBox>,
    count: &mut usize,
    keep: impl FnMut(&RawBox) -> bool,
) {
    let before = bs.len();
    bs.retain(keep);
    *count += before - bs.len();
}

/// Merges, into each box in turn (best score first), the later boxes that overlap it by at
/// least `min_iou`: the score-weighted mean box with the best score.
pub(super) fn merge_duplicates(bs: Vec<RawBox>, min_iou: f64) -> Vec<RawBox> {
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
pub(super) fn split_group(b: RawBox, f: &BoxFilter) -> Vec<RawBox> {
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
            // The group's head point is one person's at most.
            p.head = None;
            p.bbox = if w >= h {
                [x + i * w / n, y, w / n, h]
            } else {
                [x, y + i * h / n, w, h / n]
            };
            p
        })
        .collect()
}
