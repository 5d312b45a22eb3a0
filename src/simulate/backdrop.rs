//! Real aerial photos laid on the simulated ground in place of its procedural colours (pure):
//! training tiles then show people on grounds the simulator cannot make (tree canopies, dappled
//! shade, cars, rocks, water), the clutter a detector trained on simulated grounds alone takes for
//! people.

use std::sync::Arc;

use nalgebra::Vector2;

use super::world::Rgb;

/// What is wrong with a backdrop.
#[derive(Debug, thiserror::Error)]
#[error("{0}")]
pub struct BackdropError(pub String);

/// A nadir photo of the ground, 8-bit sRGB, with its ground sample distance.
pub struct Backdrop {
    /// The file name, for the dataset's records.
    pub name: String,
    pub width: usize,
    pub height: usize,
    /// Row-major RGB.
    pub rgb: Vec<u8>,
    /// Metres a pixel on the ground.
    pub gsd_m: f64,
}

impl Backdrop {
    /// Checks the sizes; `Err` says what is wrong.
    pub fn new(
        name: String,
        width: usize,
        height: usize,
        rgb: Vec<u8>,
        gsd_m: f64,
    ) -> Result<Backdrop, BackdropError> {
        if width < 16 || height < 16 || rgb.len() != width * height * 3 {
            return Err(BackdropError(format!(
                "{name}: {width}x{height} with {} bytes: expected an RGB image of at least 16x16",
                rgb.len()
            )));
        }
        if !(gsd_m.is_finite() && gsd_m > 0.0) {
            return Err(BackdropError(format!(
                "{name}: ground sample distance {gsd_m} m: expected > 0"
            )));
        }
        Ok(Backdrop {
            name,
            width,
            height,
            rgb,
            gsd_m,
        })
    }
}

/// Where a backdrop lies: a site point on a photo pixel, turned and possibly mirrored, and the
/// gain that undoes the renderer's shading (the photo is already lit).
#[derive(Clone)]
pub struct BackdropView {
    pub image: Arc<Backdrop>,
    /// The site point (east, north, metres) on `centre_px`.
    pub origin_en: Vector2<f64>,
    pub centre_px: [f64; 2],
    /// The photo's turn on the ground, radians.
    pub turn_rad: f64,
    pub mirror: bool,
    pub gain: f32,
}

/// sRGB byte to linear, as the renderer's gamma inverts it (a 2.2 power); a table, since
/// every rendered pixel on a backdrop reads twelve.
fn linear(v: u8) -> f32 {
    static TABLE: std::sync::LazyLock<[f32; 256]> =
        std::sync::LazyLock::new(|| std::array::from_fn(|i| (i as f32 / 255.0).powf(2.2)));
    TABLE[usize::from(v)]
}

impl BackdropView {
    /// The albedo at a site point: the photo's colour there (bilinear, clamped at its edges),
    /// linear and divided by the shading the renderer will apply.
    pub fn albedo(&self, en: &Vector2<f64>) -> Rgb {
        let img = &self.image;
        let d = (en - self.origin_en) / img.gsd_m;
        let (s, c) = self.turn_rad.sin_cos();
        let east = if self.mirror { -d.x } else { d.x };
        // Image rows run south: north is up.
        let x = self.centre_px[0] + c * east - s * d.y;
        let y = self.centre_px[1] - (s * east + c * d.y);
        let x = x.clamp(0.0, (img.width - 1) as f64);
        let y = y.clamp(0.0, (img.height - 1) as f64);
        let (c0, r0) = (x.floor() as usize, y.floor() as usize);
        let (c1, r1) = ((c0 + 1).min(img.width - 1), (r0 + 1).min(img.height - 1));
        let (fx, fy) = ((x - c0 as f64) as f32, (y - r0 as f64) as f32);
        let at = |r: usize, c: usize, k: usize| linear(img.rgb[(r * img.width + c) * 3 + k]);
        std::array::from_fn(|k| {
            let top = at(r0, c0, k) * (1.0 - fx) + at(r0, c1, k) * fx;
            let bottom = at(r1, c0, k) * (1.0 - fx) + at(r1, c1, k) * fx;
            ((top * (1.0 - fy) + bottom * fy) * self.gain).clamp(0.0, 1.0)
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn gradient() -> Arc<Backdrop> {
        // Red rises to the east (columns), green to the south (rows).
        let (w, h) = (64, 32);
        let mut rgb = vec![0u8; w * h * 3];
        for r in 0..h {
            for c in 0..w {
                rgb[(r * w + c) * 3] = (c * 4) as u8;
                rgb[(r * w + c) * 3 + 1] = (r * 8) as u8;
            }
        }
        Arc::new(Backdrop::new("g".into(), w, h, rgb, 0.02).unwrap())
    }

    #[test]
    fn a_site_point_reads_the_photo_pixel_it_lies_on() {
        let view = BackdropView {
            image: gradient(),
            origin_en: Vector2::new(10.0, 5.0),
            centre_px: [32.0, 16.0],
            turn_rad: 0.0,
            mirror: false,
            gain: 1.0,
        };
        // 0.2 m east and 0.1 m north of the origin: 10 columns right, 5 rows up.
        let a = view.albedo(&Vector2::new(10.2, 5.1));
        assert!((a[0] - linear(42 * 4)).abs() < 1e-6, "{a:?}");
        assert!((a[1] - linear(11 * 8)).abs() < 1e-6, "{a:?}");
        // A quarter turn carries east onto the photo's rows.
        let turned = BackdropView {
            turn_rad: std::f64::consts::FRAC_PI_2,
            ..view.clone()
        };
        let b = turned.albedo(&Vector2::new(10.2, 5.0));
        assert!((b[0] - linear(32 * 4)).abs() < 1e-6, "{b:?}");
        assert!((b[1] - linear(6 * 8)).abs() < 1e-6, "{b:?}");
        // The gain scales the linear colour; outside the photo, its edge.
        let bright = BackdropView { gain: 2.0, ..view };
        let e = bright.albedo(&Vector2::new(100.0, 5.0));
        assert!(
            (e[0] - (2.0 * linear(63 * 4)).min(1.0)).abs() < 1e-6,
            "{e:?}"
        );
    }

    #[test]
    fn a_wrong_size_is_refused() {
        assert!(Backdrop::new("x".into(), 20, 20, vec![0; 10], 0.02).is_err());
        assert!(Backdrop::new("x".into(), 20, 20, vec![0; 1200], 0.0).is_err());
    }
}
