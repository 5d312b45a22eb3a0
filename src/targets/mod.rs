//! Ground control targets found in images (pure, but for the OpenCV adapter `aruco_cv`): the
//! checker and X designs found by their saddle point (`detect`), crosses by their symmetry
//! (`cross`), coded markers decoded by OpenCV and refined here (`codes`); which surveyed point
//! each target is, from the layout of the targets alone (`identify`); one image's search
//! (`search`).

#[cfg(feature = "opencv")]
pub mod aruco_cv;
pub mod codes;
pub mod cross;
pub mod detect;
pub mod identify;
pub mod search;

pub use cross::find_crosses;
pub use detect::{Candidate, Rejected, TargetSettings, find_saddles};

/// The targets of every design `s` asks for in `img`, and the places refused with why.
pub fn find_targets(img: &Gray, s: &TargetSettings) -> (Vec<Candidate>, Vec<Rejected>) {
    let (mut found, mut rejected) = if s.saddles {
        find_saddles(img, s)
    } else {
        (Vec::new(), Vec::new())
    };
    if s.crosses {
        let (crosses, refused) = find_crosses(img, s);
        for c in crosses {
            // A place both detectors accept is kept once, as the saddle detector placed it.
            if !found
                .iter()
                .any(|f| (f.uv - c.uv).norm() < 0.35 * f.size_px.min(c.size_px))
            {
                found.push(c);
            }
        }
        rejected.extend(refused);
        rejected.retain(|r| !found.iter().any(|c| (c.uv - r.uv).norm() < 0.7 * c.size_px));
    }
    (found, rejected)
}
pub use identify::{Identification, Identified, LayoutSettings, identify_by_layout};

/// A grey image as floating-point intensities (0–255), row by row.
#[derive(Clone, Debug)]
pub struct Gray {
    pub width: usize,
    pub height: usize,
    pub pixels: Vec<f32>,
}

impl Gray {
    /// From tightly packed BGR bytes (OpenCV's order), with the usual luma weights.
    pub fn from_bgr(bytes: &[u8], width: usize, height: usize) -> Gray {
        let pixels = bytes
            .chunks_exact(3)
            .take(width * height)
            .map(|p| 0.114 * p[0] as f32 + 0.587 * p[1] as f32 + 0.299 * p[2] as f32)
            .collect();
        Gray {
            width,
            height,
            pixels,
        }
    }

    #[inline]
    pub fn at(&self, x: usize, y: usize) -> f32 {
        self.pixels[y * self.width + x]
    }

    /// Bilinear sample at `(x, y)` (pixel centres at integers); clamped to the image.
    pub fn sample(&self, x: f64, y: f64) -> f32 {
        let xm = (self.width - 1) as f64;
        let ym = (self.height - 1) as f64;
        let (x, y) = (x.clamp(0.0, xm), y.clamp(0.0, ym));
        let (x0, y0) = (x.floor() as usize, y.floor() as usize);
        let (x1, y1) = ((x0 + 1).min(self.width - 1), (y0 + 1).min(self.height - 1));
        let (fx, fy) = ((x - x0 as f64) as f32, (y - y0 as f64) as f32);
        let top = self.at(x0, y0) * (1.0 - fx) + self.at(x1, y0) * fx;
        let bottom = self.at(x0, y1) * (1.0 - fx) + self.at(x1, y1) * fx;
        top * (1.0 - fy) + bottom * fy
    }

    /// Half the size, each pixel the mean of a 2×2 block.
    pub fn half(&self) -> Gray {
        let (w, h) = (self.width / 2, self.height / 2);
        let mut pixels = Vec::with_capacity(w * h);
        for y in 0..h {
            for x in 0..w {
                let s = self.at(2 * x, 2 * y)
                    + self.at(2 * x + 1, 2 * y)
                    + self.at(2 * x, 2 * y + 1)
                    + self.at(2 * x + 1, 2 * y + 1);
                pixels.push(0.25 * s);
            }
        }
        Gray {
            width: w,
            height: h,
            pixels,
        }
    }

    /// A separable box blur of radius `r` (a (2r+1)² mean), edges clamped. The vertical pass
    /// runs down the rows with a sum per column, so that memory is read in order.
    pub fn box_blur(&self, r: usize) -> Gray {
        let (w, h) = (self.width, self.height);
        let norm = 1.0 / (2 * r + 1) as f32;
        let ri = r as isize;
        let mut once = vec![0.0f32; w * h];
        for (row, out) in self.pixels.chunks_exact(w).zip(once.chunks_exact_mut(w)) {
            let at = |k: isize| row[k.clamp(0, w as isize - 1) as usize];
            let mut acc: f32 = (-ri..=ri).map(at).sum();
            for (k, o) in out.iter_mut().enumerate() {
                *o = acc * norm;
                acc += at(k as isize + ri + 1) - at(k as isize - ri);
            }
        }
        let row_at = |k: isize| {
            let y = k.clamp(0, h as isize - 1) as usize;
            &once[y * w..(y + 1) * w]
        };
        let mut acc = vec![0.0f32; w];
        for k in -ri..=ri {
            for (a, v) in acc.iter_mut().zip(row_at(k)) {
                *a += v;
            }
        }
        let mut pixels = vec![0.0f32; w * h];
        for (y, out) in pixels.chunks_exact_mut(w).enumerate() {
            for (o, a) in out.iter_mut().zip(&acc) {
                *o = a * norm;
            }
            let (add, sub) = (row_at(y as isize + ri + 1), row_at(y as isize - ri));
            for ((a, p), m) in acc.iter_mut().zip(add).zip(sub) {
                *a += p - m;
            }
        }
        Gray {
            width: w,
            height: h,
            pixels,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::Gray;

    /// The running sums give each pixel the mean of its (2r+1)² neighbours, the image's edge
    /// pixels repeated beyond it.
    #[test]
    fn the_box_blur_is_the_clamped_mean() {
        let (w, h) = (23usize, 17usize);
        let img = Gray {
            width: w,
            height: h,
            pixels: (0..w * h)
                .map(|i| ((i * 7919) % 251) as f32 + 0.25 * (i % 3) as f32)
                .collect(),
        };
        for r in [0usize, 1, 3, 12] {
            let b = img.box_blur(r);
            let ri = r as isize;
            for y in 0..h {
                for x in 0..w {
                    let mut sum = 0.0f64;
                    for dy in -ri..=ri {
                        for dx in -ri..=ri {
                            let xx = (x as isize + dx).clamp(0, w as isize - 1) as usize;
                            let yy = (y as isize + dy).clamp(0, h as isize - 1) as usize;
                            sum += f64::from(img.at(xx, yy));
                        }
                    }
                    let mean = sum / ((2 * r + 1) * (2 * r + 1)) as f64;
                    let got = f64::from(b.at(x, y));
                    assert!(
                        (got - mean).abs() < 1e-3,
                        "r {r} at ({x}, {y}): {got} vs {mean}"
                    );
                }
            }
        }
    }
}
