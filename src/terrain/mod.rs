//! The ground under the people: one height-surface trait, and planes (least squares, RANSAC,
//! local), DEMs, bridge-deck profiles and parallel offset surfaces (pure, but for the GDAL DEM
//! loader in [`raster`]).
//!
//! Surfaces live in the site frame: (E, N) in metres, heights `U` in metres.

pub mod deck;
pub mod dem;
pub mod plane;
#[cfg(feature = "gdal")]
pub mod raster;

use nalgebra::{Vector2, Vector3};

pub use deck::{DeckProfile, VerticalAlignment};
pub use dem::{DemSurface, RasterGrid};
pub use plane::{LocalPlanes, Plane};

/// A surface given as a height over the horizontal plane.
pub trait HeightSurface {
    /// Height at a horizontal position, or `None` outside the surface.
    fn height(&self, en: &Vector2<f64>) -> Option<f64>;

    /// σ of the height at a horizontal position, metres, where the surface knows it (a plane
    /// fitted to points); `None`: taken as exact.
    fn height_sigma(&self, _en: &Vector2<f64>) -> Option<f64> {
        None
    }

    /// The surface as one that threads may share, when it is (a DEM reached through PROJ is
    /// not): the projection then runs side by side.
    fn shareable(&self) -> Option<&(dyn HeightSurface + Sync)> {
        None
    }

    /// The surface's edge as a polygon in the site frame (a deck's outline), where it has one:
    /// the walkable area's default.
    fn outline(&self) -> Option<Vec<Vector2<f64>>> {
        None
    }

    /// Upward unit normal at a horizontal position. The default differentiates `height`
    /// numerically over 5 cm.
    fn normal(&self, en: &Vector2<f64>) -> Option<Vector3<f64>> {
        let h = 0.05;
        let dx = (self.height(&(en + Vector2::new(h, 0.0)))?
            - self.height(&(en - Vector2::new(h, 0.0)))?)
            / (2.0 * h);
        let dy = (self.height(&(en + Vector2::new(0.0, h)))?
            - self.height(&(en - Vector2::new(0.0, h)))?)
            / (2.0 * h);
        Some(Vector3::new(-dx, -dy, 1.0).normalize())
    }
}

/// The surface at a constant distance along the normal from another (heads above a sloping
/// deck, say). For a horizontal position, the base point whose offset lands there is found by
/// fixed-point iteration (the normal's horizontal part is small on walkable ground).
pub struct Offset<S> {
    pub base: S,
    /// Metres along the upward normal; negative goes below.
    pub distance_m: f64,
}

impl<S: HeightSurface> HeightSurface for Offset<S> {
    fn height(&self, en: &Vector2<f64>) -> Option<f64> {
        let (base_en, n) = self.base_point(en)?;
        Some(self.base.height(&base_en)? + self.distance_m * n.z)
    }

    fn normal(&self, en: &Vector2<f64>) -> Option<Vector3<f64>> {
        self.base_point(en).map(|(_, n)| n)
    }

    fn height_sigma(&self, en: &Vector2<f64>) -> Option<f64> {
        self.base.height_sigma(&self.base_point(en)?.0)
    }

    fn outline(&self) -> Option<Vec<Vector2<f64>>> {
        self.base.outline()
    }
}

impl<S: HeightSurface> Offset<S> {
    fn base_point(&self, en: &Vector2<f64>) -> Option<(Vector2<f64>, Vector3<f64>)> {
        let mut b = *en;
        for _ in 0..50 {
            let n = self.base.normal(&b)?;
            let next = en - self.distance_m * n.xy();
            if (next - b).norm() < 1e-9 {
                return Some((next, self.base.normal(&next)?));
            }
            b = next;
        }
        None
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn offset_of_a_tilted_plane_is_the_parallel_plane() {
        // z = 0.1 x + 2 ; normal ∝ (-0.1, 0, 1).
        let p = Plane::from_gradient(0.1, 0.0, 2.0);
        let o = Offset {
            base: p.clone(),
            distance_m: 1.7,
        };
        let en = Vector2::new(10.0, -3.0);
        let h = o.height(&en).unwrap();
        // The parallel plane is z = 0.1 x + 2 + 1.7·√(1 + 0.01).
        let expected = 0.1 * 10.0 + 2.0 + 1.7 * (1.0f64 + 0.01).sqrt();
        assert!((h - expected).abs() < 1e-9, "{h} vs {expected}");
        assert!((o.normal(&en).unwrap() - p.normal(&en).unwrap()).norm() < 1e-12);
    }
}
