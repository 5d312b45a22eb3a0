//! Blobs from runs: grouped, cleaned in their own window, kept or split by their size and shape.

use super::*;

impl ColourDetector {
    /// The heads in a frame.
    pub fn detect(&self, f: &FrameView) -> Vec<Detection> {
        self.detections_from_runs(&self.runs(f), f.width, f.height)
    }

    /// The heads from a frame's hat-coloured runs (in row order).
    pub(super) fn detections_from_runs(
        &self,
        runs: &[Run],
        width: usize,
        height: usize,
    ) -> Vec<Detection> {
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
                    model_head: None,
                });
            }
            merge_fragments(&mut blobs, area_hat, r_hat);
            for pixels in blobs {
                let whole = crate::detect::morph::split(&pixels, 1).remove(0);
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
                    crate::detect::morph::split(&pixels, k)
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
                        model_head: None,
                    });
                }
            }
        }
        out
    }
}

/// Fragments of one hat (cut by an arm, say): small pieces (under 0.6 of a hat's area) whose
/// centroids are within two hat radii are one blob.
fn merge_fragments(blobs: &mut Vec<Vec<(usize, usize)>>, area_hat: f64, r_hat: f64) {
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
}
