//! Digital elevation models as regular grids with a GDAL-style geotransform, sampled bilinearly
//! (pure). Loading is in `terrain::raster` (GDAL).

use nalgebra::Vector2;

use super::HeightSurface;

/// A single-band raster. `geotransform` follows GDAL: the corner of pixel (col, row) is at
/// `x = g0 + col·g1 + row·g2`, `y = g3 + col·g4 + row·g5`; pixel centres are at +0.5.
#[derive(Clone, Debug, PartialEq)]
pub struct RasterGrid {
    pub width: usize,
    pub height: usize,
    pub geotransform: [f64; 6],
    /// Row-major values.
    pub data: Vec<f64>,
    pub nodata: Option<f64>,
}

impl RasterGrid {
    fn value(&self, col: usize, row: usize) -> Option<f64> {
        let v = *self.data.get(row * self.width + col)?;
        (v.is_finite() && self.nodata != Some(v)).then_some(v)
    }

    /// Fractional pixel-centre coordinates (col, row) of a position in the raster's CRS.
    pub fn pixel_of(&self, x: f64, y: f64) -> Option<(f64, f64)> {
        let g = &self.geotransform;
        let det = g[1] * g[5] - g[2] * g[4];
        if det == 0.0 {
            return None;
        }
        let (dx, dy) = (x - g[0], y - g[3]);
        let col = (g[5] * dx - g[2] * dy) / det;
        let row = (-g[4] * dx + g[1] * dy) / det;
        Some((col - 0.5, row - 0.5))
    }

    /// Bilinear interpolation between the four surrounding pixel centres; `None` outside the
    /// grid or next to a no-data cell.
    pub fn sample(&self, x: f64, y: f64) -> Option<f64> {
        let (c, r) = self.pixel_of(x, y)?;
        if c < 0.0 || r < 0.0 || c > (self.width - 1) as f64 || r > (self.height - 1) as f64 {
            return None;
        }
        let (c0, r0) = (c.floor() as usize, r.floor() as usize);
        let (c1, r1) = ((c0 + 1).min(self.width - 1), (r0 + 1).min(self.height - 1));
        let (fc, fr) = (c - c0 as f64, r - r0 as f64);
        let top = self.value(c0, r0)? * (1.0 - fc) + self.value(c1, r0)? * fc;
        let bottom = self.value(c0, r1)? * (1.0 - fc) + self.value(c1, r1)? * fc;
        Some(top * (1.0 - fr) + bottom * fr)
    }
}

/// Maps a site position (E, N) to the raster's CRS.
pub type ToRaster = Box<dyn Fn(&Vector2<f64>) -> Option<(f64, f64)>>;
/// Maps a raster height at a site position to the site frame's `U`.
pub type ToLocalHeight = Box<dyn Fn(&Vector2<f64>, f64) -> Option<f64>>;

/// A DEM as a height surface in the site frame.
pub struct DemSurface {
    pub grid: RasterGrid,
    pub to_raster: ToRaster,
    pub to_local_height: ToLocalHeight,
}

impl HeightSurface for DemSurface {
    fn height(&self, en: &Vector2<f64>) -> Option<f64> {
        let (x, y) = (self.to_raster)(en)?;
        let z = self.grid.sample(x, y)?;
        (self.to_local_height)(en, z)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn bilinear_reproduces_a_plane_and_respects_nodata() {
        // 1 m pixels, north-up, top-left corner at (1000, 2000); value = 0.1·x + 0.2·y.
        let (w, h) = (20, 10);
        let gt = [1000.0, 1.0, 0.0, 2000.0, 0.0, -1.0];
        let mut data = Vec::new();
        for r in 0..h {
            for c in 0..w {
                let (x, y) = (1000.0 + c as f64 + 0.5, 2000.0 - r as f64 - 0.5);
                data.push(0.1 * x + 0.2 * y);
            }
        }
        data[5 * w + 5] = -9999.0;
        let g = RasterGrid {
            width: w,
            height: h,
            geotransform: gt,
            data,
            nodata: Some(-9999.0),
        };
        let (x, y) = (1003.3, 1997.1);
        assert!((g.sample(x, y).unwrap() - (0.1 * x + 0.2 * y)).abs() < 1e-9);
        assert!(
            g.sample(1005.7, 1994.2).is_none(),
            "next to the no-data cell"
        );
        assert!(g.sample(999.0, 1995.0).is_none(), "outside");
    }
}
