//! Bridge decks: heights along a centre line (stations with heights, or a grade line with a
//! vertical curve), level across the deck.

use nalgebra::{Vector2, Vector3};

use super::HeightSurface;

/// How the deck's height varies with chainage `s` (metres along the centre line).
#[derive(Clone, Debug, PartialEq)]
pub enum VerticalAlignment {
    /// Heights at stations, interpolated linearly; stations sorted by chainage.
    Stations(Vec<(f64, f64)>),
    /// Two grades meeting at the point of vertical intersection (`pvi_s`, `pvi_z`), joined by a
    /// parabolic vertical curve of radius `radius_m` (its length is `radius·|g2 − g1|`); a crest
    /// when `g2 < g1`.
    Grades {
        g1: f64,
        g2: f64,
        pvi_s: f64,
        pvi_z: f64,
        radius_m: f64,
    },
}

impl VerticalAlignment {
    /// Height and its derivative along the chainage.
    pub fn height_slope(&self, s: f64) -> Option<(f64, f64)> {
        match self {
            VerticalAlignment::Stations(st) => {
                if st.len() < 2 || s < st[0].0 || s > st[st.len() - 1].0 {
                    return None;
                }
                let i = st.windows(2).position(|w| s <= w[1].0)?;
                let ((s0, z0), (s1, z1)) = (st[i], st[i + 1]);
                let g = (z1 - z0) / (s1 - s0);
                Some((z0 + g * (s - s0), g))
            }
            VerticalAlignment::Grades {
                g1,
                g2,
                pvi_s,
                pvi_z,
                radius_m,
            } => {
                let len = radius_m * (g2 - g1).abs();
                let start = pvi_s - len / 2.0;
                let z_start = pvi_z - g1 * len / 2.0;
                if s <= start {
                    Some((pvi_z + g1 * (s - pvi_s), *g1))
                } else if s >= pvi_s + len / 2.0 {
                    Some((pvi_z + g2 * (s - pvi_s), *g2))
                } else {
                    let x = s - start;
                    let k = (g2 - g1) / (2.0 * len);
                    Some((z_start + g1 * x + k * x * x, g1 + 2.0 * k * x))
                }
            }
        }
    }
}

/// A deck along a centre line (a polyline in the site frame), of a given width.
#[derive(Clone, Debug)]
pub struct DeckProfile {
    pub centre_line: Vec<Vector2<f64>>,
    /// Chainage of the first vertex.
    pub start_s: f64,
    pub width_m: f64,
    pub alignment: VerticalAlignment,
}

impl DeckProfile {
    /// Chainage, lateral offset (positive to the left) and unit direction at the closest point
    /// of the centre line.
    pub fn station(&self, en: &Vector2<f64>) -> Option<(f64, f64, Vector2<f64>)> {
        let mut best: Option<(f64, f64, f64, Vector2<f64>)> = None;
        let mut s0 = self.start_s;
        for w in self.centre_line.windows(2) {
            let d = w[1] - w[0];
            let len = d.norm();
            if len == 0.0 {
                continue;
            }
            let t = d / len;
            let along = (en - w[0]).dot(&t).clamp(0.0, len);
            let foot = w[0] + t * along;
            let dist = (en - foot).norm();
            if best.is_none_or(|b| dist < b.0) {
                let left = Vector2::new(-t.y, t.x);
                best = Some((dist, s0 + along, (en - foot).dot(&left), t));
            }
            s0 += len;
        }
        best.map(|(_, s, off, t)| (s, off, t))
    }
}

impl HeightSurface for DeckProfile {
    fn height(&self, en: &Vector2<f64>) -> Option<f64> {
        let (s, off, _) = self.station(en)?;
        if off.abs() > self.width_m / 2.0 {
            return None;
        }
        self.alignment.height_slope(s).map(|(z, _)| z)
    }

    fn normal(&self, en: &Vector2<f64>) -> Option<Vector3<f64>> {
        let (s, off, t) = self.station(en)?;
        if off.abs() > self.width_m / 2.0 {
            return None;
        }
        let (_, g) = self.alignment.height_slope(s)?;
        Some(Vector3::new(-g * t.x, -g * t.y, 1.0).normalize())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn deck(alignment: VerticalAlignment) -> DeckProfile {
        DeckProfile {
            // An L-shaped centre line: 60 m east, then 40 m north.
            centre_line: vec![
                Vector2::new(0.0, 0.0),
                Vector2::new(60.0, 0.0),
                Vector2::new(60.0, 40.0),
            ],
            start_s: 100.0,
            width_m: 4.0,
            alignment,
        }
    }

    #[test]
    fn stations_are_interpolated_along_the_centre_line() {
        let d = deck(VerticalAlignment::Stations(vec![
            (100.0, 10.0),
            (160.0, 11.2),
            (200.0, 10.8),
        ]));
        assert!((d.height(&Vector2::new(30.0, 1.5)).unwrap() - 10.6).abs() < 1e-12);
        assert!((d.height(&Vector2::new(61.0, 20.0)).unwrap() - 11.0).abs() < 1e-12);
        assert!(
            d.height(&Vector2::new(30.0, 2.5)).is_none(),
            "beside the deck"
        );
        let n = d.normal(&Vector2::new(30.0, 0.0)).unwrap();
        assert!((n - Vector3::new(-0.02, 0.0, 1.0).normalize()).norm() < 1e-12);
    }

    #[test]
    fn a_crest_curve_is_tangent_to_both_grades() {
        let a = VerticalAlignment::Grades {
            g1: 0.04,
            g2: -0.03,
            pvi_s: 50.0,
            pvi_z: 12.0,
            radius_m: 1000.0,
        };
        // Curve length 70 m: from s = 15 to s = 85.
        let (z15, g15) = a.height_slope(15.0).unwrap();
        assert!((z15 - (12.0 - 0.04 * 35.0)).abs() < 1e-12 && (g15 - 0.04).abs() < 1e-12);
        let (z85, g85) = a.height_slope(85.0).unwrap();
        assert!((z85 - (12.0 - 0.03 * 35.0)).abs() < 1e-9 && (g85 + 0.03).abs() < 1e-12);
        // The summit is where the slope is zero, 1/R curvature: z'' = −1/1000.
        let (_, g_a) = a.height_slope(40.0).unwrap();
        let (_, g_b) = a.height_slope(41.0).unwrap();
        assert!(((g_b - g_a) + 0.001).abs() < 1e-12);
        // Height at the PVI is below it by len²·|Δg| / 8 / len = R·Δg²/8.
        let (z50, _) = a.height_slope(50.0).unwrap();
        assert!((12.0 - z50 - 1000.0 * 0.07 * 0.07 / 8.0).abs() < 1e-9);
    }
}
