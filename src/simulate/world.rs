//! The simulated site: ground geometry (an athletics track or a footbridge deck over lower
//! surroundings), its procedural colours with fine texture for feature matching, GCP targets, and
//! ray intersection (pure).

use crate::targets::codes::MarkerCells;
use nalgebra::{Vector2, Vector3};

use super::noise::fbm;
use super::scene::{GcpSpec, Ground, TargetDesign};

/// Which surface a ray hits.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Layer {
    /// The ground (z from the track plane or the surroundings at 0).
    Ground,
    /// A footbridge deck.
    Deck,
}

/// Linear RGB in [0, 1].
pub type Rgb = [f32; 3];

/// The site in the site frame.
pub struct World {
    pub ground: Ground,
    pub gcps: Vec<(String, Vector3<f64>)>,
    /// Each GCP's target: its pattern and side (metres).
    designs: Vec<(TargetDesign, f64, Option<MarkerCells>)>,
    seed: u64,
    /// Contrast of the fine texture (1 the default).
    pub detail: f64,
    /// A real photo in place of the procedural colours (training tiles only).
    pub backdrop: Option<super::backdrop::BackdropView>,
    /// Unit vector along the deck or the track's straights, and its left normal.
    along: Vector2<f64>,
    left: Vector2<f64>,
    centre: Vector2<f64>,
}

/// Side of a square GCP target, metres.
pub const GCP_TARGET_M: f64 = 0.6;

fn heading_vec(deg: f64) -> Vector2<f64> {
    let a = deg.to_radians();
    Vector2::new(a.sin(), a.cos())
}

impl World {
    pub fn new(ground: &Ground, gcps: &[GcpSpec], seed: u64) -> World {
        let (centre, heading) = match ground {
            Ground::Track {
                centre,
                heading_deg,
                ..
            }
            | Ground::Deck {
                centre,
                heading_deg,
                ..
            } => (Vector2::new(centre[0], centre[1]), *heading_deg),
        };
        let along = heading_vec(heading);
        let mut w = World {
            ground: ground.clone(),
            gcps: Vec::new(),
            designs: gcps.iter().map(|g| (g.design, g.size_m, g.cells)).collect(),
            seed,
            detail: 1.0,
            backdrop: None,
            along,
            left: Vector2::new(-along.y, along.x),
            centre,
        };
        w.gcps = gcps
            .iter()
            .map(|g| {
                let en = Vector2::new(g.position[0], g.position[1]);
                (
                    g.name.clone(),
                    Vector3::new(en.x, en.y, w.surface_height(&en).0),
                )
            })
            .collect();
        w
    }

    /// Along-track and lateral coordinates of a site position.
    pub fn local(&self, en: &Vector2<f64>) -> (f64, f64) {
        let d = en - self.centre;
        (d.dot(&self.along), d.dot(&self.left))
    }

    pub(crate) fn from_local(&self, along: f64, lateral: f64) -> Vector2<f64> {
        self.centre + self.along * along + self.left * lateral
    }

    pub(crate) fn along_dir(&self) -> Vector2<f64> {
        self.along
    }

    /// Height of the deck at an along-deck coordinate (ends at `height_m`, a parabolic camber).
    fn deck_z(&self, u: f64) -> f64 {
        match self.ground {
            Ground::Deck {
                length_m,
                height_m,
                camber_m,
                ..
            } => {
                let x = (2.0 * u / length_m).clamp(-1.0, 1.0);
                height_m + camber_m * (1.0 - x * x)
            }
            Ground::Track { .. } => 0.0,
        }
    }

    fn on_deck(&self, u: f64, v: f64) -> bool {
        match self.ground {
            Ground::Deck {
                width_m, length_m, ..
            } => u.abs() <= length_m / 2.0 && v.abs() <= width_m / 2.0,
            Ground::Track { .. } => false,
        }
    }

    /// The surface height under a position and which surface it is (the deck wins over the
    /// surroundings below it).
    pub(crate) fn surface_height(&self, en: &Vector2<f64>) -> (f64, Layer) {
        let (u, v) = self.local(en);
        if self.on_deck(u, v) {
            (self.deck_z(u), Layer::Deck)
        } else {
            (0.0, Layer::Ground)
        }
    }

    /// Where a ray from `origin` along `dir` (pointing down) first meets the site's surfaces.
    pub(crate) fn intersect(
        &self,
        origin: &Vector3<f64>,
        dir: &Vector3<f64>,
    ) -> Option<(Vector3<f64>, Layer)> {
        if dir.z >= 0.0 {
            return None;
        }
        if let Ground::Deck {
            height_m,
            camber_m,
            width_m,
            length_m,
            ..
        } = self.ground
        {
            // The deck top, by fixed-point iteration on its gentle profile; rays that miss the
            // deck's box by a margin go straight to the ground.
            let mut z = height_m + camber_m / 2.0;
            let t = (z - origin.z) / dir.z;
            let (u, v) = self.local(&(origin + dir * t).xy());
            let slack = camber_m.abs() + 1.0;
            if u.abs() > length_m / 2.0 + slack || v.abs() > width_m / 2.0 + slack {
                return Self::ground_hit(origin, dir);
            }
            let mut hit = None;
            for _ in 0..4 {
                let t = (z - origin.z) / dir.z;
                if t <= 0.0 {
                    break;
                }
                let p = origin + dir * t;
                let (u, v) = self.local(&p.xy());
                if !self.on_deck(u, v) {
                    hit = None;
                    break;
                }
                z = self.deck_z(u);
                hit = Some(origin + dir * ((z - origin.z) / dir.z));
            }
            if let Some(p) = hit {
                let (u, v) = self.local(&p.xy());
                if self.on_deck(u, v) {
                    return Some((p, Layer::Deck));
                }
            }
        }
        Self::ground_hit(origin, dir)
    }

    /// The hit on the ground plane z = 0 (exactly 0).
    fn ground_hit(origin: &Vector3<f64>, dir: &Vector3<f64>) -> Option<(Vector3<f64>, Layer)> {
        let t = -origin.z / dir.z;
        (t > 0.0).then(|| {
            let mut p = origin + dir * t;
            p.z = 0.0;
            (p, Layer::Ground)
        })
    }

    /// Signed distance outside the inner edge of lane 1 of a track (negative in the infield).
    fn track_distance(&self, en: &Vector2<f64>) -> f64 {
        let Ground::Track {
            straight_m,
            radius_m,
            ..
        } = self.ground
        else {
            return f64::INFINITY;
        };
        let (u, v) = self.local(en);
        let half = straight_m / 2.0;
        if u.abs() <= half {
            v.abs() - radius_m
        } else {
            Vector2::new(u.abs() - half, v).norm() - radius_m
        }
    }

    /// A position on a track lane line: `s` metres along from the start of the right-hand
    /// straight, `d` metres outward from the inner edge; runs anticlockwise. Returns the position
    /// and the unit direction of running.
    pub(crate) fn track_point(&self, s: f64, d: f64) -> (Vector2<f64>, Vector2<f64>) {
        let Ground::Track {
            straight_m: l,
            radius_m,
            ..
        } = self.ground
        else {
            return (self.from_local(s, d), self.along);
        };
        let r = radius_m + d;
        let per = 2.0 * l + 2.0 * std::f64::consts::PI * r;
        let s = s.rem_euclid(per);
        let arc = std::f64::consts::PI * r;
        // Local (along, lateral) with the straights along `along`; the right straight at lateral −r.
        let (u, v, du, dv) = if s < l {
            (-l / 2.0 + s, -r, 1.0, 0.0)
        } else if s < l + arc {
            let a = (s - l) / r; // from −π/2 to π/2 around (l/2, 0)
            let ang = -std::f64::consts::FRAC_PI_2 + a;
            (
                l / 2.0 + r * ang.cos(),
                r * ang.sin(),
                -ang.sin(),
                ang.cos(),
            )
        } else if s < 2.0 * l + arc {
            (l / 2.0 - (s - l - arc), r, -1.0, 0.0)
        } else {
            let a = (s - 2.0 * l - arc) / r;
            let ang = std::f64::consts::FRAC_PI_2 + a;
            (
                -l / 2.0 + r * ang.cos(),
                r * ang.sin(),
                -ang.sin(),
                ang.cos(),
            )
        };
        (
            self.from_local(u, v),
            (self.along * du + self.left * dv).normalize(),
        )
    }

    /// Colour of a GCP target at a position, if one is there (its design on a square of its
    /// side, aligned with north).
    fn gcp_colour(&self, en: &Vector2<f64>) -> Option<Rgb> {
        const BLACK: Rgb = [0.04, 0.04, 0.04];
        const WHITE: Rgb = [0.93, 0.93, 0.93];
        for ((_, g), (design, size, cells)) in self.gcps.iter().zip(&self.designs) {
            let d = en - g.xy();
            if let (TargetDesign::Coded, Some(m)) = (design, cells) {
                // Cells across: the marker's own, its black border, a white margin.
                let cell = size / (m.cells as f64 + 2.0);
                let half = size / 2.0 + cell;
                if d.x.abs() > half || d.y.abs() > half {
                    continue;
                }
                let col = ((d.x + half) / cell).floor() as isize - 2;
                let row = ((half - d.y) / cell).floor() as isize - 2;
                let n = m.cells as isize;
                let black = if col < -1 || row < -1 || col > n || row > n {
                    false
                } else if col == -1 || row == -1 || col == n || row == n {
                    true
                } else {
                    m.black(row as usize, col as usize)
                };
                return Some(if black { BLACK } else { WHITE });
            }
            let half = size / 2.0;
            if d.x.abs() > half || d.y.abs() > half {
                continue;
            }
            let black = match design {
                TargetDesign::Checker => (d.x >= 0.0) == (d.y >= 0.0),
                TargetDesign::X => d.y.abs() > d.x.abs(),
                TargetDesign::Cross => d.x.abs() > 0.1 * size && d.y.abs() > 0.1 * size,
                // Without its cells (a pure build): a black square.
                TargetDesign::Coded => true,
            };
            return Some(if black { BLACK } else { WHITE });
        }
        None
    }

    /// Albedo of a surface point.
    pub(crate) fn albedo(&self, p: &Vector3<f64>, layer: Layer) -> Rgb {
        let en = p.xy();
        if let Some(c) = self.gcp_colour(&en) {
            return c;
        }
        if let Some(b) = &self.backdrop {
            return b.albedo(&en);
        }
        let (x, y) = (p.x, p.y);
        let d = self.detail as f32;
        let fine = (fbm(self.seed ^ 11, x, y, 0.06, 3) as f32 - 0.5) * d;
        let coarse = fbm(self.seed ^ 23, x, y, 4.0, 3) as f32 - 0.5;
        // Beyond the default detail, blotches of 10 to 40 cm too (exactly 0 at detail 1).
        let mid = if d == 1.0 {
            0.0
        } else {
            0.4 * (d - 1.0) * (fbm(self.seed ^ 37, x, y, 0.3, 2) as f32 - 0.5)
        };
        let tint = |base: Rgb, f: f32, c: f32| -> Rgb {
            std::array::from_fn(|k| (base[k] * (1.0 + f + c + mid)).clamp(0.0, 1.0))
        };
        match (&self.ground, layer) {
            (
                Ground::Track {
                    lanes,
                    lane_width_m,
                    ..
                },
                _,
            ) => {
                let d = self.track_distance(&en);
                let outer = f64::from(*lanes) * lane_width_m;
                if d < -0.05 {
                    tint([0.20, 0.42, 0.14], 0.5 * fine, 0.4 * coarse)
                } else if d <= outer + 1.0 {
                    let k = (d / lane_width_m).round();
                    let on_line = (d - k * lane_width_m).abs() < 0.025
                        && (0.0..=f64::from(*lanes)).contains(&k);
                    if on_line {
                        tint([0.92, 0.92, 0.9], 0.1 * fine, 0.0)
                    } else {
                        tint([0.64, 0.24, 0.17], 0.35 * fine, 0.12 * coarse)
                    }
                } else {
                    tint([0.42, 0.42, 0.40], 0.4 * fine, 0.3 * coarse)
                }
            }
            (Ground::Deck { width_m, .. }, Layer::Deck) => {
                let (u, v) = self.local(&en);
                if (v.abs() - width_m / 2.0).abs() < 0.12 {
                    // Railing plinths along the edges.
                    tint([0.30, 0.30, 0.32], 0.2 * fine, 0.0)
                } else if (u.rem_euclid(10.0) - 5.0).abs() < 0.015 {
                    tint([0.18, 0.18, 0.18], 0.0, 0.0)
                } else {
                    tint([0.60, 0.60, 0.57], 0.3 * fine, 0.2 * coarse)
                }
            }
            (Ground::Deck { .. }, Layer::Ground) => {
                let (_, v) = self.local(&en);
                // A river under the bridge, grass and a path beside it.
                if v.abs() < 12.0 {
                    tint([0.12, 0.22, 0.26], 0.15 * fine, 0.3 * coarse)
                } else if (v.abs() - 15.0).abs() < 1.5 {
                    tint([0.45, 0.43, 0.40], 0.4 * fine, 0.2 * coarse)
                } else {
                    tint([0.22, 0.40, 0.15], 0.5 * fine, 0.4 * coarse)
                }
            }
        }
    }

    /// Whether a ground point (the surroundings) lies in the deck's shadow, with the sun at
    /// azimuth/elevation (radians).
    pub(crate) fn in_deck_shadow(&self, p: &Vector3<f64>, sun: &Vector3<f64>) -> bool {
        match self.ground {
            Ground::Deck { height_m, .. } if p.z < height_m * 0.5 && sun.z > 0.0 => {
                // Walk towards the sun to the deck's height.
                let q = p + sun * ((height_m - p.z) / sun.z);
                let (u, v) = self.local(&q.xy());
                self.on_deck(u, v)
            }
            _ => false,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn deck() -> World {
        let g = Ground::Deck {
            centre: [10.0, 0.0],
            heading_deg: 90.0,
            width_m: 4.0,
            length_m: 60.0,
            height_m: 6.0,
            camber_m: 0.6,
        };
        World::new(&g, &[GcpSpec::new("G1", [10.0, 1.0])], 1)
    }

    #[test]
    fn deck_geometry_and_rays() {
        let w = deck();
        // Heading 90°: the deck runs east; its middle is 6.6 m up, its ends 6 m.
        assert_eq!(
            w.surface_height(&Vector2::new(10.0, 0.0)),
            (6.6, Layer::Deck)
        );
        assert!((w.surface_height(&Vector2::new(39.9, 0.0)).0 - 6.0).abs() < 0.01);
        assert_eq!(
            w.surface_height(&Vector2::new(10.0, 3.0)),
            (0.0, Layer::Ground)
        );
        assert!((w.gcps[0].1.z - 6.6).abs() < 1e-12);
        let c = Vector3::new(15.0, 0.5, 30.0);
        let (p, l) = w
            .intersect(&c, &Vector3::new(0.1, -0.05, -1.0).normalize())
            .unwrap();
        assert_eq!(l, Layer::Deck);
        assert!((p.z - w.surface_height(&p.xy()).0).abs() < 1e-6);
        let (p, l) = w
            .intersect(&c, &Vector3::new(0.0, 0.5, -1.0).normalize())
            .unwrap();
        assert_eq!((l, p.z), (Layer::Ground, 0.0));
        let sun = Vector3::new(0.0, -0.6, 0.8).normalize();
        assert!(
            w.in_deck_shadow(&Vector3::new(10.0, 5.0, 0.0), &sun),
            "north of a deck lit from the south"
        );
        assert!(!w.in_deck_shadow(&Vector3::new(10.0, -8.0, 0.0), &sun));
    }

    #[test]
    fn track_lanes_are_400_m_and_continuous() {
        let g = Ground::Track {
            centre: [0.0, 0.0],
            heading_deg: 0.0,
            lanes: 8,
            lane_width_m: 1.22,
            straight_m: 84.39,
            radius_m: 36.5,
        };
        let w = World::new(&g, &[], 1);
        // The running line of lane 1 is 0.30 m outside the inner edge: 400 m.
        let per = 2.0 * 84.39 + 2.0 * std::f64::consts::PI * 36.8;
        assert!((per - 400.0).abs() < 0.1, "{per}");
        let mut prev = w.track_point(0.0, 0.3).0;
        for k in 1..=4000 {
            let (p, dir) = w.track_point(k as f64 * 0.1, 0.3);
            assert!(
                ((p - prev).norm() - 0.1).abs() < 1e-3,
                "jump at s = {}",
                k as f64 * 0.1
            );
            assert!((dir.norm() - 1.0).abs() < 1e-9);
            assert!((w.track_distance(&p) - 0.3).abs() < 1e-6);
            prev = p;
        }
        // Anticlockwise: on the first straight the infield is on the left.
        let (p, dir) = w.track_point(10.0, 0.3);
        let left = Vector2::new(-dir.y, dir.x);
        assert!(w.track_distance(&(p + left * 1.0)) < 0.0);
    }
}
