//! Shadows' colour, learnt from patches the user marks, and the test of a box against it.

use super::*;

/// Colour of shadows, learnt from patches the user marks. CIELAB rather than BGR: a shadow
/// differs from lit ground mostly in lightness, which Lab keeps on one axis while BGR spreads it
/// over three correlated ones, and Lab distances are close to perceived differences, so one
/// threshold fits dark and bright scenes alike (and the hat detector already works in Lab).
#[derive(Clone, Debug)]
pub struct ShadowModel {
    /// Mean colour, CIELAB.
    pub mean: Vector3<f64>,
    /// Covariance, CIELAB units², with [`SHADOW_COLOUR_FLOOR`] added on the diagonal.
    pub cov: Matrix3<f64>,
    inv: Matrix3<f64>,
}

/// Variance added to the shadow covariance, Lab units²: 8-bit quantisation and sensor noise are
/// about one unit, and a uniform patch would otherwise give a singular covariance.
pub const SHADOW_COLOUR_FLOOR: f64 = 1.0;

/// Fewest patch pixels a shadow model is learnt from.
pub const MIN_SHADOW_PIXELS: usize = 100;

/// About how many pixels of a box are tested.
pub(super) const SHADOW_SAMPLES: f64 = 1024.0;

/// Why no shadow model could be learnt.
#[derive(Clone, Debug, PartialEq, thiserror::Error)]
pub enum ShadowError {
    #[error(
        "the shadow patches hold {pixels} pixels inside their frames; at least {MIN_SHADOW_PIXELS} are needed (mark larger or more shadow patches)"
    )]
    TooFewPixels { pixels: usize },
    #[error("the shadow colour covariance is not invertible")]
    Singular,
}

impl ShadowModel {
    /// Learns from rectangles `[x, y, w, h]` (pixels, clipped to their frames).
    pub fn from_patches(
        frames_and_rects: &[(FrameView, [usize; 4])],
    ) -> Result<ShadowModel, ShadowError> {
        let mut px = Vec::new();
        for (f, r) in frames_and_rects {
            let [x, y, w, h] = *r;
            let (x1, y1) = (
                x.saturating_add(w).min(f.width),
                y.saturating_add(h).min(f.height),
            );
            for v in y..y1 {
                for u in x..x1 {
                    px.push(lab(f.pixel(u, v)));
                }
            }
        }
        if px.len() < MIN_SHADOW_PIXELS {
            return Err(ShadowError::TooFewPixels { pixels: px.len() });
        }
        let n = px.len() as f64;
        let mean = px.iter().sum::<Vector3<f64>>() / n;
        let cov = px
            .iter()
            .map(|p| (p - mean) * (p - mean).transpose())
            .sum::<Matrix3<f64>>()
            / (n - 1.0);
        ShadowModel::new(mean, cov)
    }

    /// From a mean and covariance in CIELAB; the floor is added to `cov`.
    pub fn new(mean: Vector3<f64>, cov: Matrix3<f64>) -> Result<ShadowModel, ShadowError> {
        let cov = cov + Matrix3::identity() * SHADOW_COLOUR_FLOOR;
        let inv = cov
            .try_inverse()
            .filter(|m| m.iter().all(|v| v.is_finite()))
            .ok_or(ShadowError::Singular)?;
        Ok(ShadowModel { mean, cov, inv })
    }

    /// Whether an sRGB colour is within Mahalanobis distance 3 of the shadow colour.
    pub fn contains(&self, rgb: [u8; 3]) -> bool {
        let d = lab(rgb) - self.mean;
        d.dot(&(self.inv * d)) <= 9.0
    }

    /// Fraction of the box's pixels (clipped to the frame) that look like shadow; about 1000
    /// pixels on a regular grid are tested, so a large box costs no more than a small one.
    pub fn shadow_fraction(&self, frame: &FrameView, bbox: &[f64; 4]) -> f64 {
        // Pixel centres i with lo <= i < lo + len.
        let span = |lo: f64, len: f64, n: usize| {
            let a = lo.ceil().max(0.0) as usize;
            let b = ((lo + len).ceil().max(0.0) as usize).min(n);
            (a, b.max(a))
        };
        let (x0, x1) = span(bbox[0], bbox[2], frame.width);
        let (y0, y1) = span(bbox[1], bbox[3], frame.height);
        let area = (x1 - x0) * (y1 - y0);
        if area == 0 {
            return 0.0;
        }
        let step = ((area as f64 / SHADOW_SAMPLES).sqrt().ceil() as usize).max(1);
        let (mut inside, mut total) = (0usize, 0usize);
        for y in (y0..y1).step_by(step) {
            for x in (x0..x1).step_by(step) {
                total += 1;
                inside += usize::from(self.contains(frame.pixel(x, y)));
            }
        }
        inside as f64 / total as f64
    }
}
