//! Coloured-hat detection (pure), after the paper's section 3.1.1.
//!
//! A palette is learnt from pixels of randomly chosen frames: their colours, quantised to 6 bits
//! per channel, each distinct colour counted once (as a colour map is, so that a rare hat colour
//! is not outvoted by the ground), are clustered in CIELAB by k-means (15 clusters by default).
//! The clusters whose hue is that of the target colour and whose chroma is strong enough are the
//! hat colours. Every 6-bit colour is then labelled by its nearest cluster once, into a 32 KiB
//! lookup table (one bit per colour): classifying a frame is one table look-up per pixel, no floating point.
//!
//! Foreground pixels are gathered into runs per row and grouped into blobs (runs a few pixels
//! apart join); each blob is cleaned in its own small window — holes filled, closed, opened to
//! drop thin lines and specks — and kept when its area and elongation fit a hat of the given
//! diameter at the frame's scale. A blob too big or too elongated for one hat (runners side by
//! side) is split into as many hats by k-means on its pixels. The centroid of each is a head.

use nalgebra::{Matrix2, Vector2, Vector3};
use rand::{RngExt, SeedableRng};
use rayon::prelude::*;

use super::morph::Mask;
use super::{Detection, Detector, FrameDetections, FrameView};

/// sRGB (8 bits) to CIELAB (D65).
pub fn lab(rgb: [u8; 3]) -> Vector3<f64> {
    let lin = |c: u8| {
        let c = f64::from(c) / 255.0;
        if c <= 0.04045 {
            c / 12.92
        } else {
            ((c + 0.055) / 1.055).powf(2.4)
        }
    };
    let (r, g, b) = (lin(rgb[0]), lin(rgb[1]), lin(rgb[2]));
    let x = (0.4124564 * r + 0.3575761 * g + 0.1804375 * b) / 0.95047;
    let y = 0.2126729 * r + 0.7151522 * g + 0.0721750 * b;
    let z = (0.0193339 * r + 0.1191920 * g + 0.9503041 * b) / 1.08883;
    let f = |t: f64| {
        let d: f64 = 6.0 / 29.0;
        if t > d * d * d {
            t.cbrt()
        } else {
            t / (3.0 * d * d) + 4.0 / 29.0
        }
    };
    let (fx, fy, fz) = (f(x), f(y), f(z));
    Vector3::new(116.0 * fy - 16.0, 500.0 * (fx - fy), 200.0 * (fy - fz))
}

/// The 6-bit table index of a BGR pixel.
#[inline]
fn index_bgr(b: u8, g: u8, r: u8) -> usize {
    ((b as usize >> 2) << 12) | ((g as usize >> 2) << 6) | (r as usize >> 2)
}

/// The colour at the centre of a 6-bit bin.
fn bin_rgb(i: usize) -> [u8; 3] {
    let c = |v: usize| (v * 4 + 2) as u8;
    [c(i & 63), c((i >> 6) & 63), c(i >> 12)]
}

/// How to learn the hat colour and what a hat looks like.
#[derive(Clone, Debug)]
pub struct ColourSettings {
    /// The hats' colour, sRGB.
    pub target_rgb: [u8; 3],
    /// k-means clusters.
    pub clusters: usize,
    /// A cluster is a hat colour when its hue is within this many degrees of the target's...
    pub max_hue_difference_deg: f64,
    /// ... and its chroma at least this fraction of the target's.
    pub min_chroma_fraction: f64,
    pub seed: u64,
    /// Hat diameter, metres.
    pub hat_diameter_m: f64,
    /// Pixels per metre at head height (from the pose); sets the size limits.
    pub px_per_m: f64,
    /// Accepted blob area, as a fraction of a whole hat's.
    pub min_area_fraction: f64,
    pub max_area_fraction: f64,
    /// Largest ratio of a blob's principal axes.
    pub max_elongation: f64,
    /// σ of a centroid, pixels.
    pub centroid_sigma_px: f64,
}

impl Default for ColourSettings {
    fn default() -> Self {
        ColourSettings {
            target_rgb: [255, 0, 255],
            clusters: 15,
            max_hue_difference_deg: 30.0,
            min_chroma_fraction: 0.35,
            seed: 0,
            hat_diameter_m: 0.24,
            px_per_m: 46.0,
            min_area_fraction: 0.3,
            max_area_fraction: 2.5,
            max_elongation: 2.5,
            centroid_sigma_px: 0.5,
        }
    }
}

/// A learnt palette: cluster centres in CIELAB and which are hat colours.
#[derive(Clone, Debug)]
pub struct Palette {
    pub centres: Vec<Vector3<f64>>,
    pub hat: Vec<bool>,
    /// Distinct 6-bit colours the palette was learnt from.
    pub colours: usize,
}

#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum ColourError {
    #[error("no pixels to learn the palette from")]
    NoSamples,
    #[error(
        "no colour in the sampled frames looks like the target {target:?} (the nearest cluster is at a hue {hue_deg:.0}° away, chroma {chroma:.0} of {target_chroma:.0}): check the hat colour, or widen the hue tolerance"
    )]
    NoHatColour {
        target: [u8; 3],
        hue_deg: f64,
        chroma: f64,
        target_chroma: f64,
    },
}

fn hue_chroma(lab: &Vector3<f64>) -> (f64, f64) {
    (lab.z.atan2(lab.y).to_degrees(), lab.y.hypot(lab.z))
}

fn hue_difference(a: f64, b: f64) -> f64 {
    ((a - b + 540.0).rem_euclid(360.0) - 180.0).abs()
}

impl Palette {
    /// Learns the palette from sample pixels (sRGB).
    pub fn learn(pixels: &[[u8; 3]], s: &ColourSettings) -> Result<Palette, ColourError> {
        let mut seen = vec![false; 1 << 18];
        let mut colours = Vec::new();
        for p in pixels {
            let i = index_bgr(p[2], p[1], p[0]);
            if !seen[i] {
                seen[i] = true;
                colours.push(lab(bin_rgb(i)));
            }
        }
        if colours.is_empty() {
            return Err(ColourError::NoSamples);
        }
        let centres = kmeans(&colours, s.clusters.max(1), s.seed);
        let target = lab(s.target_rgb);
        let (th, tc) = hue_chroma(&target);
        let hat: Vec<bool> = centres
            .iter()
            .map(|c| {
                let (h, ch) = hue_chroma(c);
                hue_difference(h, th) <= s.max_hue_difference_deg
                    && ch >= s.min_chroma_fraction * tc
            })
            .collect();
        if !hat.iter().any(|&b| b) {
            let nearest = centres
                .iter()
                .map(hue_chroma)
                .min_by(|a, b| hue_difference(a.0, th).total_cmp(&hue_difference(b.0, th)))
                .expect("clusters");
            return Err(ColourError::NoHatColour {
                target: s.target_rgb,
                hue_deg: hue_difference(nearest.0, th),
                chroma: nearest.1,
                target_chroma: tc,
            });
        }
        Ok(Palette {
            centres,
            hat,
            colours: colours.len(),
        })
    }

    /// The lookup table: for every 6-bit BGR colour, whether its nearest cluster is a hat colour.
    pub fn table(&self) -> Vec<bool> {
        (0..1 << 18)
            .into_par_iter()
            .map(|i| {
                let l = lab(bin_rgb(i));
                let nearest = self
                    .centres
                    .iter()
                    .enumerate()
                    .min_by(|a, b| {
                        (a.1 - l)
                            .norm_squared()
                            .total_cmp(&(b.1 - l).norm_squared())
                    })
                    .map(|(k, _)| k)
                    .expect("clusters");
                self.hat[nearest]
            })
            .collect()
    }
}

/// k-means++ seeding, then Lloyd's iterations until no point changes cluster.
fn kmeans(points: &[Vector3<f64>], k: usize, seed: u64) -> Vec<Vector3<f64>> {
    let k = k.min(points.len());
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(seed);
    let mut centres = vec![points[rng.random_range(0..points.len())]];
    let mut d2: Vec<f64> = points
        .iter()
        .map(|p| (p - centres[0]).norm_squared())
        .collect();
    while centres.len() < k {
        let total: f64 = d2.iter().sum();
        if total <= 0.0 {
            break;
        }
        let mut t = rng.random_range(0.0..total);
        let mut pick = points.len() - 1;
        for (i, d) in d2.iter().enumerate() {
            if t < *d {
                pick = i;
                break;
            }
            t -= d;
        }
        centres.push(points[pick]);
        for (d, p) in d2.iter_mut().zip(points) {
            *d = d.min((p - points[pick]).norm_squared());
        }
    }
    let mut assign = vec![usize::MAX; points.len()];
    for _ in 0..300 {
        let changed = assign
            .par_iter_mut()
            .zip(points)
            .map(|(a, p)| {
                let best = (0..centres.len())
                    .min_by(|&i, &j| {
                        (p - centres[i])
                            .norm_squared()
                            .total_cmp(&(p - centres[j]).norm_squared())
                    })
                    .expect("k ≥ 1");
                let moved = *a != best;
                *a = best;
                moved
            })
            .reduce(|| false, |a, b| a || b);
        let mut sums = vec![(Vector3::zeros(), 0usize); centres.len()];
        for (a, p) in assign.iter().zip(points) {
            sums[*a].0 += p;
            sums[*a].1 += 1;
        }
        for (c, (s, n)) in centres.iter_mut().zip(sums) {
            if n > 0 {
                *c = s / n as f64;
            }
        }
        if !changed {
            break;
        }
    }
    centres
}

/// The colour detector: a lookup table and the blob limits.
pub struct ColourDetector {
    /// One bit per 6-bit colour (32 KiB, so that it stays in the first-level cache).
    table: Vec<u64>,
    settings: ColourSettings,
}

/// A frame's size, pixels.
struct Size {
    width: usize,
    height: usize,
}

/// A horizontal run of foreground pixels `[x0, x1)` in row `y`.
#[derive(Clone, Copy, Debug)]
struct Run {
    y: usize,
    x0: usize,
    x1: usize,
}

fn find(parent: &mut [usize], mut i: usize) -> usize {
    while parent[i] != i {
        parent[i] = parent[parent[i]];
        i = parent[i];
    }
    i
}

/// The colours that could be a hat whatever the palette: a hue within the tolerance plus 30°
/// of the target's and at least 15 % of its chroma (shaded and blurred hat edges included). A
/// hat colour must also be in this set, so that frames can be screened before the palette is
/// learnt.
fn permissive_table(s: &ColourSettings) -> Vec<u64> {
    let (th, tc) = hue_chroma(&lab(s.target_rgb));
    let mut table = vec![0u64; (1 << 18) / 64];
    table.par_iter_mut().enumerate().for_each(|(i, word)| {
        for bit in 0..64 {
            let (h, c) = hue_chroma(&lab(bin_rgb(i * 64 + bit)));
            if hue_difference(h, th) <= s.max_hue_difference_deg + 30.0 && c >= 0.15 * tc {
                *word |= 1 << bit;
            }
        }
    });
    table
}

/// Whether the 6-bit colour `i` is in a bit table.
#[inline]
fn has_colour(table: &[u64], i: usize) -> bool {
    table[i >> 6] >> (i & 63) & 1 == 1
}

#[inline]
fn in_table(table: &[u64], px: &[u8]) -> bool {
    has_colour(table, index_bgr(px[0], px[1], px[2]))
}

/// Hat radius in pixels.
fn hat_radius_px(s: &ColourSettings) -> f64 {
    0.5 * s.hat_diameter_m * s.px_per_m
}

/// Runs of the rows `ys` whose colours are in `table`, each row scanned over the column ranges
/// `[x0, x1)` that `ranges` gives for it (ascending, apart).
fn runs_in<I: Iterator<Item = (usize, usize)>>(
    f: &FrameView,
    table: &[u64],
    ys: std::ops::Range<usize>,
    ranges: impl Fn(usize) -> I,
) -> Vec<Run> {
    let mut runs = Vec::new();
    for y in ys {
        let row = &f.bgr[3 * y * f.width..3 * (y + 1) * f.width];
        for (x0, x1) in ranges(y) {
            let mut start: Option<usize> = None;
            for x in x0..x1 {
                match (in_table(table, &row[3 * x..3 * x + 3]), start) {
                    (true, None) => start = Some(x),
                    (false, Some(s)) => {
                        runs.push(Run { y, x0: s, x1: x });
                        start = None;
                    }
                    _ => {}
                }
            }
            if let Some(s) = start {
                runs.push(Run { y, x0: s, x1 });
            }
        }
    }
    runs
}

/// Runs of a frame's colours in `table`, row by row. When hats span many pixels, a grid of every
/// `step`-th pixel of every `step`-th row (half the hat's radius: a whole hat holds a dozen grid
/// points, an edge-cut or half-hidden one several) is classified first, and only tiles near a
/// hit (and their neighbours, which hold any fringe of the same blob) are scanned in full: a 4K
/// frame of a few dozen hats costs a fraction of a full pass, with the same runs.
fn table_runs(f: &FrameView, table: &[u64], r_hat_px: f64) -> Vec<Run> {
    let step = (r_hat_px / 2.0).floor().max(1.0) as usize;
    if step == 1 {
        return runs_in(f, table, 0..f.height, |_| std::iter::once((0, f.width)));
    }
    let tile = (2 * step).max(16);
    let (tw, th) = (f.width.div_ceil(tile), f.height.div_ceil(tile));
    let mut hit = vec![false; tw * th];
    for y in (step / 2..f.height).step_by(step) {
        let row = &f.bgr[3 * y * f.width..3 * (y + 1) * f.width];
        for x in (step / 2..f.width).step_by(step) {
            if in_table(table, &row[3 * x..3 * x + 3]) {
                hit[(y / tile) * tw + x / tile] = true;
            }
        }
    }
    // Flagged: a hit in the tile or in one of its eight neighbours.
    let mut spans: Vec<Vec<(usize, usize)>> = vec![Vec::new(); th];
    for (ty, row_spans) in spans.iter_mut().enumerate() {
        let mut open: Option<usize> = None;
        for tx in 0..=tw {
            let flagged = tx < tw
                && (ty.saturating_sub(1)..(ty + 2).min(th))
                    .any(|yy| (tx.saturating_sub(1)..(tx + 2).min(tw)).any(|xx| hit[yy * tw + xx]));
            match (flagged, open) {
                (true, None) => open = Some(tx),
                (false, Some(t0)) => {
                    row_spans.push((t0 * tile, (tx * tile).min(f.width)));
                    open = None;
                }
                _ => {}
            }
        }
    }
    runs_in(f, table, 0..f.height, |y| spans[y / tile].iter().copied())
}

impl ColourDetector {
    pub fn new(palette: &Palette, settings: ColourSettings) -> ColourDetector {
        let mut table = permissive_table(&settings);
        Self::restrict(&mut table, palette);
        ColourDetector { table, settings }
    }

    /// Keeps in `table` the colours whose nearest cluster is a hat colour.
    fn restrict(table: &mut [u64], palette: &Palette) {
        for (i, hat) in palette.table().into_iter().enumerate() {
            if !hat {
                table[i >> 6] &= !(1 << (i & 63));
            }
        }
    }

    /// Hat radius in pixels.
    fn hat_radius_px(&self) -> f64 {
        hat_radius_px(&self.settings)
    }

    /// Foreground runs of a frame.
    fn runs(&self, f: &FrameView) -> Vec<Run> {
        table_runs(f, &self.table, self.hat_radius_px())
    }

    /// Groups runs that lie within `gap` pixels of each other into blobs.
    fn group(runs: &[Run], gap: usize) -> Vec<Vec<usize>> {
        let mut parent: Vec<usize> = (0..runs.len()).collect();
        // Runs are in row order; compare each with the runs of the `gap` rows above.
        let mut row_start = 0;
        for i in 0..runs.len() {
            while runs[row_start].y + gap < runs[i].y {
                row_start += 1;
            }
            for j in row_start..i {
                let (a, b) = (&runs[i], &runs[j]);
                if b.x0 <= a.x1 + gap && a.x0 <= b.x1 + gap {
                    let (ra, rb) = (find(&mut parent, i), find(&mut parent, j));
                    if ra != rb {
                        parent[ra] = rb;
                    }
                }
            }
        }
        let mut groups: std::collections::HashMap<usize, Vec<usize>> =
            std::collections::HashMap::new();
        for i in 0..runs.len() {
            let r = find(&mut parent, i);
            groups.entry(r).or_default().push(i);
        }
        let mut out: Vec<Vec<usize>> = groups.into_values().collect();
        out.sort_by_key(|g| g[0]);
        out
    }
}

impl Detector for ColourDetector {
    fn push(&mut self, f: &FrameView) -> Result<Vec<FrameDetections>, String> {
        Ok(vec![(f.index, self.detect(f))])
    }
}

/// The colour detector as one pass over a video runs it: it learns its palette from pixels of
/// randomly chosen frames as they go by, and meanwhile keeps, for every frame, only the runs of
/// colours that could be a hat whatever the palette (with their colours); once the last chosen
/// frame has been seen it learns the palette and finishes the kept frames. The video is
/// decoded once. Should the kept runs outgrow `budget_bytes` first (a long video with many hat
/// colours about), the palette is learnt from the chosen frames seen so far.
pub struct LearningColourDetector {
    settings: ColourSettings,
    screen: Vec<u64>,
    /// Frames to sample (ascending) and every how many pixels.
    sample_frames: Vec<usize>,
    step: usize,
    samples: Vec<[u8; 3]>,
    kept: Vec<Kept>,
    kept_bytes: usize,
    budget_bytes: usize,
    ready: Option<(ColourDetector, Palette)>,
}

/// A frame held back: its candidate runs and the 6-bit colour of each of their pixels.
struct Kept {
    index: usize,
    width: usize,
    height: usize,
    runs: Vec<Run>,
    colours: Vec<u32>,
}

impl LearningColourDetector {
    /// `frames`: how many frames the video has (to spread `sample_count` frames over, by a draw
    /// seeded with `settings.seed`); `None`: the first `sample_count` frames. Every `step`-th
    /// pixel of a chosen frame is sampled.
    pub fn new(
        settings: ColourSettings,
        frames: Option<usize>,
        sample_count: usize,
        step: usize,
        budget_bytes: usize,
    ) -> LearningColourDetector {
        let mut sample_frames: Vec<usize> = match frames {
            Some(n) if sample_count < n => {
                let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(settings.seed);
                (0..sample_count).map(|_| rng.random_range(0..n)).collect()
            }
            Some(n) => (0..n).collect(),
            None => (0..sample_count.max(1)).collect(),
        };
        sample_frames.sort_unstable();
        sample_frames.dedup();
        LearningColourDetector {
            screen: permissive_table(&settings),
            settings,
            sample_frames,
            step: step.max(1),
            samples: Vec::new(),
            kept: Vec::new(),
            kept_bytes: 0,
            budget_bytes,
            ready: None,
        }
    }

    /// The palette, once learnt.
    pub fn palette(&self) -> Option<&Palette> {
        self.ready.as_ref().map(|r| &r.1)
    }

    /// Learns the palette and finishes the frames held back.
    fn learn(&mut self) -> Result<Vec<FrameDetections>, String> {
        let palette = Palette::learn(&self.samples, &self.settings).map_err(|e| e.to_string())?;
        let mut table = self.screen.clone();
        ColourDetector::restrict(&mut table, &palette);
        let det = ColourDetector {
            table,
            settings: self.settings.clone(),
        };
        // The frames held back are independent: finish them in parallel (this happens once,
        // often when the rest of the pass is done and the cores are free).
        let out: Vec<FrameDetections> = std::mem::take(&mut self.kept)
            .into_par_iter()
            .map(|k| {
                // Split each candidate run where its colours are not hat colours.
                let mut runs = Vec::new();
                let mut c = 0;
                for r in &k.runs {
                    let mut start: Option<usize> = None;
                    for x in r.x0..r.x1 {
                        let hat = has_colour(&det.table, k.colours[c] as usize);
                        c += 1;
                        match (hat, start) {
                            (true, None) => start = Some(x),
                            (false, Some(s)) => {
                                runs.push(Run {
                                    y: r.y,
                                    x0: s,
                                    x1: x,
                                });
                                start = None;
                            }
                            _ => {}
                        }
                    }
                    if let Some(s) = start {
                        runs.push(Run {
                            y: r.y,
                            x0: s,
                            x1: r.x1,
                        });
                    }
                }
                (k.index, det.detections_from_runs(&runs, k.width, k.height))
            })
            .collect();
        self.samples = Vec::new();
        self.kept_bytes = 0;
        self.ready = Some((det, palette));
        Ok(out)
    }
}

impl Detector for LearningColourDetector {
    fn push(&mut self, f: &FrameView) -> Result<Vec<FrameDetections>, String> {
        if let Some((det, _)) = &self.ready {
            return Ok(vec![(f.index, det.detect(f))]);
        }
        if self.sample_frames.binary_search(&f.index).is_ok() {
            // The same pixels whichever way the frames are read: an offset from the index.
            let mut k = (f.index * 7919) % self.step;
            while k < f.width * f.height {
                self.samples.push(f.pixel(k % f.width, k / f.width));
                k += self.step;
            }
        }
        let runs = table_runs(f, &self.screen, hat_radius_px(&self.settings));
        let mut colours = Vec::new();
        for r in &runs {
            let row = &f.bgr[3 * r.y * f.width..];
            for x in r.x0..r.x1 {
                colours.push(index_bgr(row[3 * x], row[3 * x + 1], row[3 * x + 2]) as u32);
            }
        }
        self.kept_bytes += runs.len() * std::mem::size_of::<Run>() + 4 * colours.len() + 64;
        self.kept.push(Kept {
            index: f.index,
            width: f.width,
            height: f.height,
            runs,
            colours,
        });
        let last = self.sample_frames.last().copied().unwrap_or(0);
        if f.index >= last || (self.kept_bytes > self.budget_bytes && !self.samples.is_empty()) {
            self.learn()
        } else {
            Ok(Vec::new())
        }
    }

    fn finish(&mut self) -> Result<Vec<FrameDetections>, String> {
        if self.ready.is_some() || self.kept.is_empty() {
            return Ok(Vec::new());
        }
        self.learn()
    }

    fn summary(&self) -> Vec<(String, f64)> {
        match self.palette() {
            Some(p) => vec![
                (
                    "hat_colours".into(),
                    p.hat.iter().filter(|h| **h).count() as f64,
                ),
                ("palette_colours".into(), p.colours as f64),
            ],
            None => Vec::new(),
        }
    }
}

impl ColourDetector {
    /// The heads in a frame.
    pub fn detect(&self, f: &FrameView) -> Vec<Detection> {
        self.detections_from_runs(&self.runs(f), f.width, f.height)
    }

    /// The heads from a frame's hat-coloured runs (in row order).
    fn detections_from_runs(&self, runs: &[Run], width: usize, height: usize) -> Vec<Detection> {
        let f = Size { width, height };
        let r_hat = self.hat_radius_px().max(1.0);
        let gap = (0.25 * r_hat).round().max(1.0) as usize;
        let r_close = (0.25 * r_hat).round().max(1.0) as usize;
        let r_open = (0.15 * r_hat).round() as usize;
        let area_hat = std::f64::consts::PI * r_hat * r_hat;
        let s = &self.settings;
        let mut out = Vec::new();
        for group in Self::group(runs, gap) {
            let count: usize = group.iter().map(|&i| runs[i].x1 - runs[i].x0).sum();
            if (count as f64) < 0.25 * s.min_area_fraction * area_hat {
                continue;
            }
            // The blob's window, with a margin for the morphology.
            let m = r_close + 2;
            let x0 = group
                .iter()
                .map(|&i| runs[i].x0)
                .min()
                .expect("runs")
                .saturating_sub(m);
            let y0 = group
                .iter()
                .map(|&i| runs[i].y)
                .min()
                .expect("runs")
                .saturating_sub(m);
            let x1 = (group.iter().map(|&i| runs[i].x1).max().expect("runs") + m).min(f.width);
            let y1 = (group.iter().map(|&i| runs[i].y).max().expect("runs") + 1 + m).min(f.height);
            let mut mask = Mask::new(x1 - x0, y1 - y0);
            for &i in &group {
                let r = runs[i];
                for x in r.x0..r.x1 {
                    mask.set(x - x0, r.y - y0, true);
                }
            }
            let clean = mask.close(r_close).fill_holes().open(r_open);
            // A hat cut by the frame's edge: its centre lies one hat radius in from the far side
            // of what is visible (the other axis is unbiased by symmetry).
            let mut blobs: Vec<Vec<(usize, usize)>> = Vec::new();
            for (c, pixels) in clean.components_with_pixels() {
                let (bx0, by0, bx1, by1) = (
                    c.bounds.0 + x0,
                    c.bounds.1 + y0,
                    c.bounds.2 + x0,
                    c.bounds.3 + y0,
                );
                let (left, top, right, bottom) =
                    (bx0 == 0, by0 == 0, bx1 + 1 >= f.width, by1 + 1 >= f.height);
                let cut = [left, top, right, bottom].iter().filter(|&&b| b).count();
                if cut == 0 {
                    blobs.push(pixels);
                    continue;
                }
                let (w, h) = ((bx1 - bx0 + 1) as f64, (by1 - by0 + 1) as f64);
                // Only one edge, and enough of the hat in view to place it.
                if cut > 1
                    || (left || right) && (w < 0.5 * r_hat || h < 1.4 * r_hat)
                    || (top || bottom) && (h < 0.5 * r_hat || w < 1.4 * r_hat)
                {
                    continue;
                }
                let (mut u, mut v) = (c.centroid.0 + x0 as f64, c.centroid.1 + y0 as f64);
                let mut cov = Matrix2::identity() * (s.centroid_sigma_px * s.centroid_sigma_px);
                let along = (0.25 * r_hat).powi(2);
                if left {
                    u = bx1 as f64 + 0.5 - r_hat;
                    cov[(0, 0)] += along;
                } else if right {
                    u = bx0 as f64 - 0.5 + r_hat;
                    cov[(0, 0)] += along;
                } else if top {
                    v = by1 as f64 + 0.5 - r_hat;
                    cov[(1, 1)] += along;
                } else {
                    v = by0 as f64 - 0.5 + r_hat;
                    cov[(1, 1)] += along;
                }
                out.push(Detection {
                    uv: Vector2::new(u, v),
                    cov,
                    bbox: [bx0 as f64 - 0.5, by0 as f64 - 0.5, w, h],
                    area_px: c.area as f64,
                    score: 0.5,
                });
            }
            // Fragments of one hat (cut by an arm, say): small pieces close together are one.
            let centroid = |p: &[(usize, usize)]| {
                let n = p.len() as f64;
                p.iter().fold((0.0, 0.0), |a, q| {
                    (a.0 + q.0 as f64 / n, a.1 + q.1 as f64 / n)
                })
            };
            let small = |p: &[(usize, usize)]| (p.len() as f64) < 0.6 * area_hat;
            let mut merged = true;
            while merged {
                merged = false;
                'outer: for i in 0..blobs.len() {
                    for j in i + 1..blobs.len() {
                        let (a, b) = (centroid(&blobs[i]), centroid(&blobs[j]));
                        if small(&blobs[i])
                            && small(&blobs[j])
                            && (a.0 - b.0).hypot(a.1 - b.1) < 2.0 * r_hat
                        {
                            let other = blobs.swap_remove(j);
                            blobs[i].extend(other);
                            merged = true;
                            break 'outer;
                        }
                    }
                }
            }
            for pixels in blobs {
                let whole = super::morph::split(&pixels, 1).remove(0);
                let area = whole.area as f64;
                if area < s.min_area_fraction * area_hat {
                    continue;
                }
                // Touching hats make one oversized blob (elongated when two): split it into as
                // many hats. A single, partly hidden hat is small, and never split.
                let k = if area > 1.6 * area_hat {
                    ((area / area_hat).round() as usize).clamp(2, 4)
                } else if area > 1.25 * area_hat && whole.elongation() > 1.6 {
                    2
                } else {
                    1
                };
                let parts = if k > 1 {
                    super::morph::split(&pixels, k)
                } else {
                    vec![whole]
                };
                for c in parts {
                    let area = c.area as f64;
                    let min = if k > 1 { 0.5 } else { s.min_area_fraction };
                    if area < min * area_hat
                        || area > s.max_area_fraction * area_hat
                        || c.elongation() > s.max_elongation
                    {
                        continue;
                    }
                    let (bx0, by0, bx1, by1) = c.bounds;
                    out.push(Detection {
                        uv: Vector2::new(c.centroid.0 + x0 as f64, c.centroid.1 + y0 as f64),
                        cov: Matrix2::identity() * (s.centroid_sigma_px * s.centroid_sigma_px),
                        bbox: [
                            (bx0 + x0) as f64 - 0.5,
                            (by0 + y0) as f64 - 0.5,
                            (bx1 - bx0 + 1) as f64,
                            (by1 - by0 + 1) as f64,
                        ],
                        area_px: area,
                        score: (area / area_hat).min(1.0),
                    });
                }
            }
        }
        out
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn lab_of_known_colours() {
        let w = lab([255, 255, 255]);
        assert!((w - Vector3::new(100.0, 0.0, 0.0)).norm() < 0.01, "{w}");
        let m = lab([255, 0, 255]);
        assert!(
            (m - Vector3::new(60.32, 98.23, -60.82)).norm() < 0.05,
            "{m}"
        );
    }

    /// A grey-green scene with shaded magenta discs and a magenta line.
    fn scene(w: usize, h: usize, hats: &[(f64, f64)], r: f64) -> Vec<u8> {
        let mut bgr = vec![0u8; 3 * w * h];
        for y in 0..h {
            for x in 0..w {
                let i = 3 * (y * w + x);
                let t = ((x * 7 + y * 13) % 23) as u8;
                let (mut b, mut g, mut rr) = (90 + t, 120 + t, 100 + t);
                for &(cx, cy) in hats {
                    let d = ((x as f64 - cx).powi(2) + (y as f64 - cy).powi(2)).sqrt();
                    if d <= r {
                        // Shaded: darker towards one side.
                        let s = 0.7 + 0.3 * ((x as f64 - cx) / r);
                        (b, g, rr) = ((220.0 * s) as u8, (30.0 * s) as u8, (210.0 * s) as u8);
                    }
                }
                if y == 5 {
                    (b, g, rr) = (230, 20, 220);
                }
                bgr[i] = b;
                bgr[i + 1] = g;
                bgr[i + 2] = rr;
            }
        }
        bgr
    }

    /// Every third pixel of a frame, RGB: the palette's sample.
    fn every_third_pixel(frame: &FrameView) -> Vec<[u8; 3]> {
        let w = frame.width;
        (0..w * frame.height)
            .step_by(3)
            .map(|i| frame.pixel(i % w, i / w))
            .collect()
    }

    #[test]
    fn finds_shaded_hats_and_ignores_a_line() {
        let (w, h) = (320, 200);
        let hats = [(60.3, 80.6), (200.0, 120.0), (250.5, 40.2)];
        let bgr = scene(w, h, &hats, 6.0);
        let frame = FrameView {
            index: 0,
            width: w,
            height: h,
            bgr: &bgr,
        };
        let pixels = every_third_pixel(&frame);
        let s = ColourSettings {
            px_per_m: 50.0,
            ..ColourSettings::default()
        };
        let palette = Palette::learn(&pixels, &s).unwrap();
        let det = ColourDetector::new(&palette, s);
        let found = det.detect(&frame);
        assert_eq!(found.len(), 3, "{found:?}");
        for (cx, cy) in hats {
            let d = found
                .iter()
                .map(|d| (d.uv - Vector2::new(cx, cy)).norm())
                .fold(f64::INFINITY, f64::min);
            assert!(d < 0.5, "hat at ({cx}, {cy}) found {d} px off");
        }
    }

    #[test]
    fn the_coarse_scan_finds_the_same_hat_runs_as_a_full_scan() {
        let (w, h) = (400, 240);
        let hats = [(60.3, 80.6), (200.0, 120.0), (251.5, 40.2), (390.0, 230.0)];
        let bgr = scene(w, h, &hats, 13.0);
        let frame = FrameView {
            index: 0,
            width: w,
            height: h,
            bgr: &bgr,
        };
        let pixels = every_third_pixel(&frame);
        let s = ColourSettings {
            px_per_m: 100.0,
            ..ColourSettings::default()
        };
        let palette = Palette::learn(&pixels, &s).unwrap();
        let det = ColourDetector::new(&palette, s);
        assert!(det.hat_radius_px() >= 6.0, "the coarse path is exercised");
        let key = |r: &Run| (r.y, r.x0, r.x1);
        let coarse: Vec<_> = det.runs(&frame).iter().map(key).collect();
        let full: Vec<_> = runs_in(&frame, &det.table, 0..h, |_| std::iter::once((0, w)))
            .iter()
            .map(key)
            .collect();
        // The one-pixel line is between the grid's rows: only it may be missed.
        let hat_runs: Vec<_> = full.iter().copied().filter(|r| r.0 != 5).collect();
        assert!(hat_runs.len() > 80, "{}", hat_runs.len());
        assert_eq!(
            coarse
                .iter()
                .copied()
                .filter(|r| r.0 != 5)
                .collect::<Vec<_>>(),
            hat_runs
        );
    }

    #[test]
    fn learning_on_the_way_gives_what_a_palette_learnt_first_gives() {
        let (w, h) = (320, 200);
        let frames: Vec<Vec<u8>> = (0..6)
            .map(|i| {
                let x = 40.0 + 30.0 * i as f64;
                scene(w, h, &[(x, 80.6), (200.0, 120.0 - 5.0 * i as f64)], 6.0)
            })
            .collect();
        let view = |i: usize| FrameView {
            index: i,
            width: w,
            height: h,
            bgr: &frames[i],
        };
        let s = ColourSettings {
            px_per_m: 50.0,
            ..ColourSettings::default()
        };
        let mut learning = LearningColourDetector::new(s.clone(), Some(6), 3, 7, usize::MAX);
        let mut got = Vec::new();
        for i in 0..6 {
            got.extend(learning.push(&view(i)).unwrap());
        }
        got.extend(learning.finish().unwrap());
        assert_eq!(
            got.iter().map(|g| g.0).collect::<Vec<_>>(),
            (0..6).collect::<Vec<_>>()
        );
        // The same frames and pixels, sampled beforehand.
        let mut pixels = Vec::new();
        for &i in &learning.sample_frames {
            let mut k = (i * 7919) % 7;
            while k < w * h {
                pixels.push(view(i).pixel(k % w, k / w));
                k += 7;
            }
        }
        let first = ColourDetector::new(&Palette::learn(&pixels, &s).unwrap(), s.clone());
        for (i, d) in &got {
            assert_eq!(d.len(), 2, "frame {i}: {d:?}");
            assert_eq!(*d, first.detect(&view(*i)), "frame {i}");
        }
        // A budget too small to hold a frame: learnt from the first sampled frame on.
        let mut early = LearningColourDetector::new(s.clone(), Some(6), 3, 7, 1);
        let mut n = 0;
        for i in 0..6 {
            n += early.push(&view(i)).unwrap().len();
        }
        n += early.finish().unwrap().len();
        assert_eq!(n, 6);
        assert!(early.palette().is_some());
    }

    #[test]
    fn a_scene_without_the_colour_is_an_error() {
        let pixels = vec![[100, 120, 90], [30, 30, 30], [200, 200, 200]];
        assert!(matches!(
            Palette::learn(&pixels, &ColourSettings::default()),
            Err(ColourError::NoHatColour { .. })
        ));
    }
}
