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

    /// A separable box blur of radius `r` (a (2r+1)² mean), edges clamped.
    pub fn box_blur(&self, r: usize) -> Gray {
        let (w, h) = (self.width, self.height);
        let pass = |src: &[f32], horizontal: bool| -> Vec<f32> {
            let mut out = vec![0.0f32; w * h];
            let (n, m) = if horizontal { (h, w) } else { (w, h) };
            let idx = |line: usize, k: usize| {
                if horizontal {
                    line * w + k
                } else {
                    k * w + line
                }
            };
            let norm = 1.0 / (2 * r + 1) as f32;
            for line in 0..n {
                let at = |k: isize| src[idx(line, k.clamp(0, m as isize - 1) as usize)];
                let mut acc: f32 = (-(r as isize)..=r as isize).map(at).sum();
                for k in 0..m {
                    out[idx(line, k)] = acc * norm;
                    acc += at(k as isize + r as isize + 1) - at(k as isize - r as isize);
                }
            }
            out
        };
        let once = pass(&self.pixels, true);
        Gray {
            width: w,
            height: h,
            pixels: pass(&once, false),
        }
    }
}
