//! Coloured-hat detection (pure), after the paper's section 3.1.1.
//!
//! A palette is learnt from pixels of randomly chosen frames: their colours, quantised to 6 bits
//! per channel, each distinct colour counted once (as a colour map is, so that a rare hat colour
//! is not outvoted by the ground), are clustered in CIELAB by k-means (15 clusters by default).
//! The clusters whose hue is that of the target colour and whose chroma is strong enough are the
//! hat colours. Every 6-bit colour is then labelled by its nearest cluster once, into a 256 KiB
//! lookup table: classifying a frame is one table look-up per pixel, no floating point.
//!
//! Foreground pixels are gathered into runs per row and grouped into blobs (runs a few pixels
//! apart join); each blob is cleaned in its own small window — holes filled, closed, opened to
//! drop thin lines and specks — and kept when its area and elongation fit a hat of the given
//! diameter at the frame's scale. A blob too big or too elongated for one hat (runners side by
//! side) is split into as many hats by k-means on its pixels. The centroid of each is a head.

use nalgebra::{Matrix2, Vector2, Vector3};
use rand::{RngExt, SeedableRng};

use super::morph::Mask;
use super::{Detection, Detector, FrameView};

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
        let mut changed = false;
        for (a, p) in assign.iter_mut().zip(points) {
            let best = (0..centres.len())
                .min_by(|&i, &j| {
                    (p - centres[i])
                        .norm_squared()
                        .total_cmp(&(p - centres[j]).norm_squared())
                })
                .expect("k ≥ 1");
            if *a != best {
                *a = best;
                changed = true;
            }
        }
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
    table: Vec<bool>,
    settings: ColourSettings,
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

impl ColourDetector {
    pub fn new(palette: &Palette, settings: ColourSettings) -> ColourDetector {
        ColourDetector {
            table: palette.table(),
            settings,
        }
    }

    /// Hat radius in pixels.
    fn hat_radius_px(&self) -> f64 {
        0.5 * self.settings.hat_diameter_m * self.settings.px_per_m
    }

    /// Foreground runs of a frame, row by row.
    fn runs(&self, f: &FrameView) -> Vec<Run> {
        let mut runs = Vec::new();
        for y in 0..f.height {
            let row = &f.bgr[3 * y * f.width..3 * (y + 1) * f.width];
            let mut start: Option<usize> = None;
            for (x, px) in row.chunks_exact(3).enumerate() {
                let fg = self.table[index_bgr(px[0], px[1], px[2])];
                match (fg, start) {
                    (true, None) => start = Some(x),
                    (false, Some(s)) => {
                        runs.push(Run { y, x0: s, x1: x });
                        start = None;
                    }
                    _ => {}
                }
            }
            if let Some(s) = start {
                runs.push(Run {
                    y,
                    x0: s,
                    x1: f.width,
                });
            }
        }
        runs
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
    fn detect(&mut self, f: &FrameView) -> Vec<Detection> {
        let r_hat = self.hat_radius_px().max(1.0);
        let gap = (0.25 * r_hat).round().max(1.0) as usize;
        let r_close = (0.25 * r_hat).round().max(1.0) as usize;
        let r_open = (0.15 * r_hat).round() as usize;
        let area_hat = std::f64::consts::PI * r_hat * r_hat;
        let s = &self.settings;
        let runs = self.runs(f);
        let mut out = Vec::new();
        for group in Self::group(&runs, gap) {
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
        let pixels: Vec<[u8; 3]> = (0..w * h)
            .step_by(3)
            .map(|i| frame.pixel(i % w, i / w))
            .collect();
        let s = ColourSettings {
            px_per_m: 50.0,
            ..ColourSettings::default()
        };
        let palette = Palette::learn(&pixels, &s).unwrap();
        let mut det = ColourDetector::new(&palette, s);
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
    fn a_scene_without_the_colour_is_an_error() {
        let pixels = vec![[100, 120, 90], [30, 30, 30], [200, 200, 200]];
        assert!(matches!(
            Palette::learn(&pixels, &ColourSettings::default()),
            Err(ColourError::NoHatColour { .. })
        ));
    }
}
