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
    /// `z = Σ cₖ xᵏ` with `x = (s − centre) / scale`: a profile fitted through points.
    Polynomial {
        centre: f64,
        scale: f64,
        coeffs: Vec<f64>,
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
            VerticalAlignment::Polynomial {
                centre,
                scale,
                coeffs,
            } => {
                let x = (s - centre) / scale;
                // Horner's scheme for the value and for the derivative (coefficients k·cₖ).
                let z = coeffs.iter().rev().fold(0.0, |acc, c| acc * x + c);
                let d = coeffs
                    .iter()
                    .enumerate()
                    .skip(1)
                    .rev()
                    .fold(0.0, |acc, (k, c)| acc * x + k as f64 * c);
                Some((z, d / scale))
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

#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum DeckError {
    #[error("station chainages must be increasing and at least two")]
    Stations,
    #[error("no deck points between chainages {0} and {1}: the heights there are not determined")]
    Gap(f64, f64),
    #[error("a profile of this degree needs {needed} points on the deck, found {got}")]
    TooFewPoints { needed: usize, got: usize },
}

impl DeckProfile {
    /// Fits heights at the given station chainages to points measured on the deck (GCPs, a
    /// point cloud) by least squares on the piecewise-linear profile; points off the deck's width
    /// or outside the stations are ignored. Returns the profile and the RMS height residual.
    pub fn fit_stations(
        centre_line: Vec<Vector2<f64>>,
        start_s: f64,
        width_m: f64,
        chainages: &[f64],
        points: &[Vector3<f64>],
    ) -> Result<(DeckProfile, f64), DeckError> {
        let n = chainages.len();
        if n < 2 || chainages.windows(2).any(|w| w[1] <= w[0]) {
            return Err(DeckError::Stations);
        }
        let mut deck = DeckProfile {
            centre_line,
            start_s,
            width_m,
            alignment: VerticalAlignment::Stations(chainages.iter().map(|&s| (s, 0.0)).collect()),
        };
        // Normal equations of the hat-function basis (tridiagonal, solved densely: few stations).
        let mut ata = nalgebra::DMatrix::<f64>::zeros(n, n);
        let mut atb = nalgebra::DVector::<f64>::zeros(n);
        let mut used = Vec::new();
        for p in points {
            let Some((s, off, _)) = deck.station(&p.xy()) else {
                continue;
            };
            if off.abs() > width_m / 2.0 || s < chainages[0] || s > chainages[n - 1] {
                continue;
            }
            let i = chainages
                .windows(2)
                .position(|w| s <= w[1])
                .expect("inside the stations");
            let t = (s - chainages[i]) / (chainages[i + 1] - chainages[i]);
            let (wi, wj) = (1.0 - t, t);
            ata[(i, i)] += wi * wi;
            ata[(i, i + 1)] += wi * wj;
            ata[(i + 1, i)] += wi * wj;
            ata[(i + 1, i + 1)] += wj * wj;
            atb[i] += wi * p.z;
            atb[i + 1] += wj * p.z;
            used.push((i, t, p.z));
        }
        for k in 0..n - 1 {
            if !used.iter().any(|(i, _, _)| *i == k) {
                return Err(DeckError::Gap(chainages[k], chainages[k + 1]));
            }
        }
        let z = ata
            .cholesky()
            .ok_or(DeckError::Gap(chainages[0], chainages[n - 1]))?
            .solve(&atb);
        let rms = (used
            .iter()
            .map(|(i, t, h)| (z[*i] * (1.0 - t) + z[*i + 1] * t - h).powi(2))
            .sum::<f64>()
            / used.len() as f64)
            .sqrt();
        deck.alignment =
            VerticalAlignment::Stations(chainages.iter().copied().zip(z.iter().copied()).collect());
        Ok((deck, rms))
    }

    /// Fits a polynomial height profile of `degree` (0 to 3) along the centre line to points
    /// measured on the deck (GCPs); points off the deck's width are ignored. Returns the profile
    /// and the RMS height residual.
    pub fn fit_polynomial(
        centre_line: Vec<Vector2<f64>>,
        start_s: f64,
        width_m: f64,
        degree: usize,
        points: &[Vector3<f64>],
    ) -> Result<(DeckProfile, f64), DeckError> {
        let mut deck = DeckProfile {
            centre_line,
            start_s,
            width_m,
            alignment: VerticalAlignment::Stations(Vec::new()),
        };
        let on: Vec<(f64, f64)> = points
            .iter()
            .filter_map(|p| {
                let (s, off, _) = deck.station(&p.xy())?;
                (off.abs() <= width_m / 2.0).then_some((s, p.z))
            })
            .collect();
        if on.len() <= degree {
            return Err(DeckError::TooFewPoints {
                needed: degree + 1,
                got: on.len(),
            });
        }
        let (lo, hi) = on.iter().fold((f64::INFINITY, f64::NEG_INFINITY), |a, p| {
            (a.0.min(p.0), a.1.max(p.0))
        });
        let centre = 0.5 * (lo + hi);
        let scale = (0.5 * (hi - lo)).max(1.0);
        let a = nalgebra::DMatrix::from_fn(on.len(), degree + 1, |i, k| {
            ((on[i].0 - centre) / scale).powi(k as i32)
        });
        let b = nalgebra::DVector::from_iterator(on.len(), on.iter().map(|p| p.1));
        let c =
            a.clone()
                .svd(true, true)
                .solve(&b, 1e-12)
                .map_err(|_| DeckError::TooFewPoints {
                    needed: degree + 1,
                    got: on.len(),
                })?;
        let r = &a * &c - &b;
        deck.alignment = VerticalAlignment::Polynomial {
            centre,
            scale,
            coeffs: c.iter().copied().collect(),
        };
        Ok((deck, (r.norm_squared() / on.len() as f64).sqrt()))
    }

    /// Chainage, lateral offset (positive to the left) and unit direction at the closest point
    /// of the centre line.
    pub fn station(&self, en: &Vector2<f64>) -> Option<(f64, f64, Vector2<f64>)> {
        let mut best: Option<(f64, f64, f64, Vector2<f64>)> = None;
        let mut s0 = self.start_s;
        for w in self.centre_line.windows(2) {
            let d = w[1] - w[0];
            let len = d.norm();
            // A repeated or non-finite vertex makes no segment (and `clamp` would panic on NaN).
            if !(len > 0.0 && len.is_finite()) {
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
    fn shareable(&self) -> Option<&(dyn HeightSurface + Sync)> {
        Some(self)
    }

    /// The centre line offset by half the width to each side, mitred at its bends: the left
    /// edge forward, then the right edge back (counter-clockwise).
    fn outline(&self) -> Option<Vec<Vector2<f64>>> {
        let mut line: Vec<Vector2<f64>> = Vec::with_capacity(self.centre_line.len());
        for p in &self.centre_line {
            if line.last().is_none_or(|q| (p - q).norm() > 0.0) {
                line.push(*p);
            }
        }
        if line.len() < 2 || line.iter().any(|p| !(p.x.is_finite() && p.y.is_finite())) {
            return None;
        }
        let left = |d: Vector2<f64>| Vector2::new(-d.y, d.x) / d.norm();
        let half = self.width_m / 2.0;
        let n = line.len();
        // Each vertex's offset direction: the mitre of its two segments' normals, scaled so the
        // edges stay half the width from the centre line.
        let offset: Vec<Vector2<f64>> = (0..n)
            .map(|i| {
                let a = left(line[i.max(1)] - line[i.max(1) - 1]);
                let b = left(line[(i + 1).min(n - 1)] - line[i.min(n - 2)]);
                let m = a + b;
                let cos_half = (m.norm() / 2.0).max(0.2);
                m.normalize() * (half / cos_half)
            })
            .collect();
        let mut ring: Vec<Vector2<f64>> = line.iter().zip(&offset).map(|(p, o)| p + o).collect();
        ring.extend(line.iter().zip(&offset).rev().map(|(p, o)| p - o));
        Some(ring)
    }

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
    fn a_parabolic_camber_is_fitted_exactly() {
        let line = vec![Vector2::new(-40.0, 0.0), Vector2::new(40.0, 0.0)];
        let z = |x: f64| 6.0 + 0.5 * (1.0 - (x / 40.0).powi(2));
        let pts: Vec<Vector3<f64>> = [-18.0, -9.0, 0.0, 9.0, 18.0]
            .iter()
            .flat_map(|&x| [Vector3::new(x, 1.9, z(x)), Vector3::new(x, -1.9, z(x))])
            .collect();
        let (d, rms) = DeckProfile::fit_polynomial(line.clone(), 0.0, 5.0, 2, &pts).unwrap();
        assert!(rms < 1e-9);
        for x in [-30.0, -5.0, 25.0] {
            assert!((d.height(&Vector2::new(x, 0.5)).unwrap() - z(x)).abs() < 1e-9);
            let n = d.normal(&Vector2::new(x, 0.0)).unwrap();
            let slope = -0.5 * 2.0 * x / 1600.0;
            assert!((n - Vector3::new(-slope, 0.0, 1.0).normalize()).norm() < 1e-9);
        }
        assert!(DeckProfile::fit_polynomial(line, 0.0, 5.0, 2, &pts[..2]).is_err());
    }

    #[test]
    fn the_outline_is_the_centre_line_widened_and_mitred_at_its_bend() {
        let d = deck(VerticalAlignment::Stations(vec![
            (100.0, 10.0),
            (200.0, 12.0),
        ]));
        let ring = d.outline().unwrap();
        let want = [
            (0.0, 2.0),
            (58.0, 2.0),
            (58.0, 40.0),
            (62.0, 40.0),
            (62.0, -2.0),
            (0.0, -2.0),
        ];
        assert_eq!(ring.len(), want.len());
        for (p, (x, y)) in ring.iter().zip(want) {
            assert!(
                (p - Vector2::new(x, y)).norm() < 1e-9,
                "{p:?} against ({x}, {y})"
            );
        }
        // Every outline vertex is on the deck's edge: half the width off the centre line.
        for p in &ring {
            let (_, off, _) = d.station(p).unwrap();
            assert!((off.abs() - 2.0).abs() < 1e-9, "{p:?}: {off}");
        }
        let mut degenerate = d.clone();
        degenerate.centre_line = vec![Vector2::new(1.0, 1.0); 3];
        assert!(degenerate.outline().is_none());
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
    fn station_heights_fitted_to_noisy_deck_points_recover_the_profile() {
        use rand::{RngExt, SeedableRng};
        use rand_distr::{Distribution, Normal};
        // A crest curve surveyed with 1 cm noise at 500 points on a 4 m wide deck.
        let truth = VerticalAlignment::Grades {
            g1: 0.04,
            g2: -0.03,
            pvi_s: 150.0,
            pvi_z: 12.0,
            radius_m: 1000.0,
        };
        let line = vec![
            Vector2::new(0.0, 0.0),
            Vector2::new(60.0, 0.0),
            Vector2::new(60.0, 40.0),
        ];
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(4);
        let noise = Normal::new(0.0, 0.01).unwrap();
        let probe = DeckProfile {
            centre_line: line.clone(),
            start_s: 100.0,
            width_m: 4.0,
            alignment: truth.clone(),
        };
        let mut pts = Vec::new();
        while pts.len() < 500 {
            let en = Vector2::new(rng.random_range(0.0..62.0), rng.random_range(-2.0..40.0));
            if let Some((s, off, _)) = probe.station(&en)
                && off.abs() <= 2.0
            {
                pts.push(Vector3::new(
                    en.x,
                    en.y,
                    truth.height_slope(s).unwrap().0 + noise.sample(&mut rng),
                ));
            }
        }
        let stations: Vec<f64> = (0..=10).map(|k| 100.0 + 10.0 * k as f64).collect();
        let (deck, rms) =
            DeckProfile::fit_stations(line.clone(), 100.0, 4.0, &stations, &pts).unwrap();
        // The piecewise-linear chord of a 1/1000 curve over 10 m sags by 10²/8/1000 = 1.25 cm.
        assert!(rms < 0.02, "{rms}");
        for &s in &stations {
            let (z, _) = truth.height_slope(s).unwrap();
            let (f, _) = deck.alignment.height_slope(s).unwrap();
            assert!((f - z).abs() < 0.02, "station {s}: {f} vs {z}");
        }
        assert_eq!(
            DeckProfile::fit_stations(line.clone(), 100.0, 4.0, &[100.0], &pts).unwrap_err(),
            DeckError::Stations
        );
        let few: Vec<_> = pts
            .iter()
            .copied()
            .filter(|p| p.x < 20.0 && p.y.abs() < 3.0)
            .collect();
        assert!(matches!(
            DeckProfile::fit_stations(line, 100.0, 4.0, &stations, &few),
            Err(DeckError::Gap(..))
        ));
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
