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
//!
//! Files: this one the settings and the detector; `palette`; `runs`; `blobs`; `learning`.

use nalgebra::{Matrix2, Vector2, Vector3};
use rand::{RngExt, SeedableRng};
use rayon::prelude::*;

use super::morph::Mask;
use super::{Detection, Detector, FrameDetections, FrameView};

mod blobs;
mod learning;
mod palette;
mod runs;
#[cfg(test)]
mod tests;

pub use learning::LearningColourDetector;
use palette::*;
pub use palette::{ColourError, Palette, lab};
use runs::*;

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

/// The colour detector: a lookup table and the blob limits.
pub struct ColourDetector {
    /// One bit per 6-bit colour (32 KiB, so that it stays in the first-level cache).
    table: Vec<u64>,
    settings: ColourSettings,
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
    fn push(&mut self, f: &FrameView) -> Result<Vec<FrameDetections>, crate::PluginError> {
        Ok(vec![(f.index, self.detect(f))])
    }
}
