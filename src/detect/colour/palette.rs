//! The palette: colours in CIELAB, k-means clusters, the hat colours and their 32 KiB table.

use super::*;

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
pub(super) fn index_bgr(b: u8, g: u8, r: u8) -> usize {
    ((b as usize >> 2) << 12) | ((g as usize >> 2) << 6) | (r as usize >> 2)
}

/// The colour at the centre of a 6-bit bin.
pub(super) fn bin_rgb(i: usize) -> [u8; 3] {
    let c = |v: usize| (v * 4 + 2) as u8;
    [c(i & 63), c((i >> 6) & 63), c(i >> 12)]
}

/// A learnt palette: cluster centres in CIELAB and which are hat colours.
#[derive(Clone, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
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

pub(super) fn hue_chroma(lab: &Vector3<f64>) -> (f64, f64) {
    (lab.z.atan2(lab.y).to_degrees(), lab.y.hypot(lab.z))
}

pub(super) fn hue_difference(a: f64, b: f64) -> f64 {
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
pub(super) fn kmeans(points: &[Vector3<f64>], k: usize, seed: u64) -> Vec<Vector3<f64>> {
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
