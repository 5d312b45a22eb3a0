//! Simulated people: who they are (height, speed, gait, colours), where they are at any time
//! (along a deck or a track lane, with lane changes), their head bob, and their bodies as seen
//! from above (pure).

use nalgebra::{Vector2, Vector3};
use rand::{RngExt, SeedableRng};
use rand_distr::{Distribution, Normal};

use super::scene::{Gait, Ground, PeopleSpec};
use super::world::{Rgb, World};

/// Radius of the hat (a flat cap on top of the head), metres.
pub const HAT_RADIUS_M: f64 = 0.12;
/// Radius of the head.
pub const HEAD_RADIUS_M: f64 = 0.105;

/// One person, fixed for the whole scene.
#[derive(Clone, Debug)]
pub struct Person {
    pub id: usize,
    /// Standing height (top of the head), metres.
    pub height_m: f64,
    pub speed_m_s: f64,
    pub gait: Gait,
    /// When the person enters (stream) or starts moving (group), seconds.
    pub start_s: f64,
    /// Progress along the path at `start_s`, metres.
    pub start_along_m: f64,
    /// Lateral position (deck: from the centre line; track: outward from the inner edge).
    pub lateral_m: f64,
    /// Lane changes: (time, new lateral position).
    pub lane_changes: Vec<(f64, f64)>,
    pub step_hz: f64,
    pub bob_m: f64,
    pub phase: f64,
    pub shirt: Rgb,
    pub hair: Rgb,
}

/// A person at one instant.
#[derive(Clone, Debug)]
pub struct Pose {
    /// Feet (centre) on the surface.
    pub foot: Vector3<f64>,
    /// Unit direction of travel (horizontal).
    pub heading: Vector2<f64>,
    /// Top of the head (the hat's centre): the truth that detection aims at.
    pub head_top: Vector3<f64>,
    /// Gait phase, radians.
    pub stride_phase: f64,
}

const SHIRTS: [Rgb; 8] = [
    [0.85, 0.1, 0.1],
    [0.1, 0.3, 0.8],
    [0.95, 0.85, 0.1],
    [0.1, 0.6, 0.25],
    [0.95, 0.95, 0.95],
    [0.08, 0.08, 0.1],
    [0.95, 0.5, 0.1],
    [0.2, 0.7, 0.8],
];

/// The people of a scene, from its seed.
pub fn spawn(spec: &PeopleSpec, world: &World, duration_s: f64, seed: u64) -> Vec<Person> {
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(seed ^ 0x5EED_0F9E_091E);
    let heights = Normal::new(spec.height_m[0], spec.height_m[1].max(1e-9)).expect("height");
    let speeds = Normal::new(spec.speed_m_s[0], spec.speed_m_s[1].max(1e-9)).expect("speed");
    let group = spec.mode == "group";
    let (track, lanes, lane_w, deck_half_w, deck_len) = match world.ground {
        Ground::Track {
            lanes,
            lane_width_m,
            ..
        } => (true, lanes, lane_width_m, 0.0, 0.0),
        Ground::Deck {
            width_m, length_m, ..
        } => (false, 1, 0.0, width_m / 2.0 - 0.45, length_m),
    };
    let lateral = |rng: &mut rand_chacha::ChaCha8Rng| -> f64 {
        if track {
            let lane = rng.random_range(0..lanes.min(6));
            f64::from(lane) * lane_w + 0.3 + rng.random_range(-0.1..0.1)
        } else {
            rng.random_range(-deck_half_w..deck_half_w)
        }
    };
    let mut people = Vec::new();
    let count = if group {
        spec.count as usize
    } else {
        usize::MAX
    };
    // A stream is already flowing when the scene starts: arrivals from one crossing earlier.
    let path_len = if track { 0.0 } else { deck_len };
    let mut t = if group {
        0.0
    } else {
        -path_len / spec.speed_m_s[0].max(0.5)
    };
    while people.len() < count {
        let (start_s, start_along_m) = if group {
            // A pack: a few abreast, rows 1.5 m apart, behind the start.
            let row = people.len() / 4;
            (0.0, -1.5 * row as f64 - rng.random_range(0.0..0.5))
        } else {
            t += -(1.0 - rng.random::<f64>()).ln() / spec.rate_per_s.max(1e-9);
            if t >= duration_s {
                break;
            }
            (t, if track { 0.0 } else { -deck_len / 2.0 })
        };
        let gait = spec.gait;
        let speed = speeds.sample(&mut rng).clamp(0.5, 9.0);
        let (step_hz, bob_m) = match gait {
            Gait::Walk => (1.8 + 0.3 * (speed - 1.4), 0.025),
            Gait::Run => (2.8 + 0.08 * (speed - 3.5), 0.045),
        };
        let per_s = spec.lane_changes_per_min / 60.0;
        // (clearance, start, lateral position, lane changes) of the widest draw so far. Where
        // ten draws find no gap, the runner waits 0.2 s for one, as in a real stream.
        let mut best: Option<Draw> = None;
        for draw in 0..300 {
            // A pack starts together: only a stream's arrival waits for a gap.
            let start_s = if group {
                start_s
            } else {
                start_s + 0.2 * (draw / 10) as f64
            };
            let lat = lateral(&mut rng);
            let mut lane_changes = Vec::new();
            let mut tc = start_s;
            if per_s > 0.0 {
                loop {
                    tc += -(1.0 - rng.random::<f64>()).ln() / per_s;
                    if tc >= duration_s {
                        break;
                    }
                    lane_changes.push((tc, lateral(&mut rng)));
                }
            }
            if spec.min_spacing_m <= 0.0 {
                best = Some((f64::INFINITY, start_s, lat, lane_changes));
                break;
            }
            let path = Path {
                start_s,
                start_along_m,
                speed_m_s: speed,
                lateral_m: lat,
                lane_changes: &lane_changes,
            };
            let gap = people
                .iter()
                .map(|q: &Person| path.closest(&q.path(), duration_s, path_len))
                .fold(f64::INFINITY, f64::min);
            if best.as_ref().is_none_or(|b| gap > b.0) {
                best = Some((gap, start_s, lat, lane_changes));
            }
            if gap >= spec.min_spacing_m {
                break;
            }
        }
        let (_, start_s, lat, lane_changes) = best.expect("at least one draw");
        let mut shirt = SHIRTS[rng.random_range(0..SHIRTS.len())];
        for c in &mut shirt {
            *c = (*c * rng.random_range(0.85..1.1)).clamp(0.0, 1.0);
        }
        let hair_level = rng.random_range(0.05..0.45);
        people.push(Person {
            id: people.len(),
            height_m: heights.sample(&mut rng).clamp(1.4, 2.05),
            speed_m_s: speed,
            gait,
            start_s,
            start_along_m,
            lateral_m: lat,
            lane_changes,
            step_hz,
            bob_m,
            phase: rng.random_range(0.0..std::f64::consts::TAU),
            shirt,
            hair: [hair_level * 0.8, hair_level * 0.6, hair_level * 0.4],
        });
    }
    people
}

/// A draw of an arrival's path: (clearance, start, lateral, lane changes), metres and seconds.
type Draw = (f64, f64, f64, Vec<(f64, f64)>);

/// Where a person runs, in the path's own frame (along, lateral), metres.
struct Path<'a> {
    start_s: f64,
    start_along_m: f64,
    speed_m_s: f64,
    lateral_m: f64,
    lane_changes: &'a [(f64, f64)],
}

impl Path<'_> {
    fn at(&self, t: f64) -> (f64, f64) {
        let mut lat = self.lateral_m;
        for &(tc, target) in self.lane_changes {
            if t <= tc {
                break;
            }
            lat += (target - lat) * ease((t - tc) / 2.0);
        }
        (
            self.start_along_m + self.speed_m_s * (t - self.start_s),
            lat,
        )
    }

    /// The closest two paths come while both are on it (before `end_s`, and before the end of
    /// a path `length_m` long when it is not 0), metres; sampled every 0.05 s.
    fn closest(&self, other: &Path, end_s: f64, length_m: f64) -> f64 {
        let mut t = self.start_s.max(other.start_s);
        let mut least = f64::INFINITY;
        while t <= end_s {
            let (a, b) = (self.at(t), other.at(t));
            if length_m > 0.0 && (a.0 > length_m / 2.0 || b.0 > length_m / 2.0) {
                if a.0 > length_m / 2.0 && b.0 > length_m / 2.0 {
                    break;
                }
            } else {
                least = least.min((a.0 - b.0).hypot(a.1 - b.1));
            }
            t += 0.05;
        }
        least
    }
}

/// Smooth step over 2 s.
fn ease(x: f64) -> f64 {
    let x = x.clamp(0.0, 1.0);
    x * x * (3.0 - 2.0 * x)
}

impl Person {
    fn path(&self) -> Path<'_> {
        Path {
            start_s: self.start_s,
            start_along_m: self.start_along_m,
            speed_m_s: self.speed_m_s,
            lateral_m: self.lateral_m,
            lane_changes: &self.lane_changes,
        }
    }

    /// Lateral position at a time, easing between lanes over 2 s.
    fn lateral_at(&self, t: f64) -> f64 {
        self.path().at(t).1
    }

    /// Where the person is at time `t`, or `None` before entering or after leaving the path.
    pub fn pose(&self, world: &World, t: f64) -> Option<Pose> {
        if t < self.start_s {
            return None;
        }
        let along = self.start_along_m + self.speed_m_s * (t - self.start_s);
        let lat = self.lateral_at(t);
        let (en, heading) = match world.ground {
            Ground::Track { .. } => world.track_point(along, lat),
            Ground::Deck { length_m, .. } => {
                if along > length_m / 2.0 {
                    return None;
                }
                (world.from_local(along, lat), world.along_dir())
            }
        };
        let (z, _) = world.surface_height(&en);
        let stride_phase = self.phase + std::f64::consts::TAU * self.step_hz * (t - self.start_s);
        // The head is highest in mid-stance, twice per stride: once per step.
        let bob = self.bob_m * stride_phase.cos();
        let foot = Vector3::new(en.x, en.y, z);
        Some(Pose {
            foot,
            heading,
            head_top: foot + Vector3::new(0.0, 0.0, self.height_m + bob),
            stride_phase,
        })
    }
}

/// An ellipsoid with axes along (heading, left, up).
#[derive(Clone, Debug)]
pub struct Ellipsoid {
    pub centre: Vector3<f64>,
    pub semi: Vector3<f64>,
    pub colour: Rgb,
}

/// What a person is made of, as seen from above: legs, torso, arms, head, and a hat.
pub struct Body {
    pub parts: Vec<Ellipsoid>,
    pub heading: Vector2<f64>,
    /// Hat: centre (top of the head) and colour, when worn.
    pub hat: Option<(Vector3<f64>, Rgb)>,
    /// An axis-aligned bounding box (min, max) for culling.
    pub bounds: (Vector3<f64>, Vector3<f64>),
}

/// How a body looks: its colours, how far its limbs swing and how broad it is.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct BodyStyle {
    pub shirt: Rgb,
    pub hair: Rgb,
    pub trousers: Rgb,
    /// The limbs' swing against a walker's (0: standing still; a runner's is larger).
    pub swing: f64,
    /// Breadth against the average body's (torso, arms' spread, legs' spread).
    pub girth: f64,
}

impl BodyStyle {
    /// A scene's person: their shirt and hair, dark trousers, a walker's swing.
    pub fn of(person: &Person) -> BodyStyle {
        BodyStyle {
            shirt: person.shirt,
            hair: person.hair,
            trousers: [0.12, 0.12, 0.15],
            swing: 1.0,
            girth: 1.0,
        }
    }
}

impl Body {
    pub fn new(person: &Person, pose: &Pose, hat: Option<Rgb>) -> Body {
        Body::styled(pose, hat, &BodyStyle::of(person))
    }

    /// A body in `pose` dressed and moving as `style` says.
    pub fn styled(pose: &Pose, hat: Option<Rgb>, style: &BodyStyle) -> Body {
        let h = pose.head_top.z - pose.foot.z;
        let f = pose.foot;
        let g = style.girth;
        let fwd = Vector3::new(pose.heading.x, pose.heading.y, 0.0);
        let left = Vector3::new(-pose.heading.y, pose.heading.x, 0.0);
        let swing = style.swing * 0.22 * (h / 1.7) * pose.stride_phase.sin();
        let leg = |side: f64, s: f64| Ellipsoid {
            centre: f + left * (0.1 * g * side) + fwd * s + Vector3::new(0.0, 0.0, 0.24 * h),
            semi: Vector3::new(0.08 * g, 0.07 * g, 0.25 * h),
            colour: style.trousers,
        };
        let arm = |side: f64, s: f64| Ellipsoid {
            centre: f + left * (0.23 * g * side) + fwd * s + Vector3::new(0.0, 0.0, 0.62 * h),
            semi: Vector3::new(0.06 * g, 0.05 * g, 0.15 * h),
            colour: style.shirt,
        };
        let parts = vec![
            leg(1.0, swing),
            leg(-1.0, -swing),
            arm(1.0, -0.6 * swing),
            arm(-1.0, 0.6 * swing),
            Ellipsoid {
                centre: f + Vector3::new(0.0, 0.0, 0.66 * h),
                semi: Vector3::new(0.13 * g, 0.21 * g, 0.17 * h),
                colour: style.shirt,
            },
            Ellipsoid {
                centre: pose.head_top - Vector3::new(0.0, 0.0, HEAD_RADIUS_M + 0.006),
                semi: Vector3::new(HEAD_RADIUS_M, HEAD_RADIUS_M * 0.9, HEAD_RADIUS_M),
                colour: style.hair,
            },
        ];
        Body {
            parts,
            heading: pose.heading,
            hat: hat.map(|c| (pose.head_top, c)),
            bounds: (
                f - Vector3::new(0.5, 0.5, 0.01),
                f + Vector3::new(0.5, 0.5, h + 0.02),
            ),
        }
    }

    /// Points on the body's outline as seen from `eye` (world, metres): each part's contour
    /// generator (the ellipsoid's points whose tangent plane holds the eye) and the hat's rim,
    /// `per_part` points each. Their image box is the box a perfect detector draws around the
    /// person's silhouette, in any view.
    pub fn outline(&self, eye: &Vector3<f64>, per_part: usize) -> Vec<Vector3<f64>> {
        let fwd = Vector3::new(self.heading.x, self.heading.y, 0.0);
        let left = Vector3::new(-self.heading.y, self.heading.x, 0.0);
        let up = Vector3::z();
        let mut points = Vec::with_capacity(per_part * (self.parts.len() + 1));
        for e in &self.parts {
            // In the frame where the part is the unit sphere, the eye at `o` sees the circle of
            // points u with u·o = 1.
            let d = eye - e.centre;
            let o = Vector3::new(
                d.dot(&fwd) / e.semi.x,
                d.dot(&left) / e.semi.y,
                d.dot(&up) / e.semi.z,
            );
            let r2 = o.norm_squared();
            if r2 <= 1.0 {
                continue;
            }
            let centre = o / r2;
            let radius = (1.0 - 1.0 / r2).sqrt();
            let n = o / r2.sqrt();
            let a = if n.x.abs() < 0.9 {
                Vector3::x()
            } else {
                Vector3::y()
            };
            let a = (a - n * n.dot(&a)).normalize();
            let b = n.cross(&a);
            for k in 0..per_part {
                let phi = std::f64::consts::TAU * k as f64 / per_part as f64;
                let u = centre + (a * phi.cos() + b * phi.sin()) * radius;
                points.push(
                    e.centre
                        + fwd * (u.x * e.semi.x)
                        + left * (u.y * e.semi.y)
                        + up * (u.z * e.semi.z),
                );
            }
        }
        if let Some((centre, _)) = &self.hat {
            for k in 0..per_part {
                let phi = std::f64::consts::TAU * k as f64 / per_part as f64;
                points.push(centre + Vector3::new(phi.cos(), phi.sin(), 0.0) * HAT_RADIUS_M);
            }
        }
        points
    }

    /// Whether a ray passes within `margin_m` of the bounding box (slab test).
    pub(crate) fn may_hit(&self, origin: &Vector3<f64>, dir: &Vector3<f64>, margin_m: f64) -> bool {
        let (lo, hi) = (
            self.bounds.0.add_scalar(-margin_m),
            self.bounds.1.add_scalar(margin_m),
        );
        let (mut t0, mut t1) = (0.0f64, f64::INFINITY);
        for k in 0..3 {
            if dir[k].abs() < 1e-12 {
                if origin[k] < lo[k] || origin[k] > hi[k] {
                    return false;
                }
                continue;
            }
            let (a, b) = ((lo[k] - origin[k]) / dir[k], (hi[k] - origin[k]) / dir[k]);
            t0 = t0.max(a.min(b));
            t1 = t1.min(a.max(b));
            if t0 > t1 {
                return false;
            }
        }
        true
    }

    /// The shaded colour of the nearest hit of a ray with the body, if any.
    pub(crate) fn hit(
        &self,
        origin: &Vector3<f64>,
        dir: &Vector3<f64>,
        sun: &Vector3<f64>,
    ) -> Option<Rgb> {
        let shade = |n: &Vector3<f64>, c: &Rgb| -> Rgb {
            let l = (0.45 + 0.55 * n.dot(sun).max(0.0)) as f32;
            [c[0] * l, c[1] * l, c[2] * l]
        };
        let mut best_t = f64::INFINITY;
        let mut hat_hit = false;
        if let Some((centre, _)) = &self.hat {
            // A horizontal disc facing up.
            if dir.z < 0.0 {
                let t = (centre.z - origin.z) / dir.z;
                let p = origin + dir * t;
                if t > 0.0 && (p - centre).xy().norm() <= HAT_RADIUS_M {
                    best_t = t;
                    hat_hit = true;
                }
            }
        }
        let fwd = Vector3::new(self.heading.x, self.heading.y, 0.0);
        let left = Vector3::new(-self.heading.y, self.heading.x, 0.0);
        // Direction in each body frame is the same rotation; only the scale differs.
        let (d_f, d_l) = (dir.dot(&fwd), dir.dot(&left));
        let mut best: Option<(usize, Vector3<f64>)> = None;
        for (i, e) in self.parts.iter().enumerate() {
            let o = origin - e.centre;
            let lo = Vector3::new(
                o.dot(&fwd) / e.semi.x,
                o.dot(&left) / e.semi.y,
                o.z / e.semi.z,
            );
            let ld = Vector3::new(d_f / e.semi.x, d_l / e.semi.y, dir.z / e.semi.z);
            let a = ld.norm_squared();
            let b = lo.dot(&ld);
            let disc = b * b - a * (lo.norm_squared() - 1.0);
            if disc < 0.0 {
                continue;
            }
            let t = (-b - disc.sqrt()) / a;
            if t > 0.0 && t < best_t {
                best_t = t;
                best = Some((i, lo + ld * t));
                hat_hit = false;
            }
        }
        if hat_hit {
            return self.hat.as_ref().map(|(_, c)| shade(&Vector3::z(), c));
        }
        let (i, lp) = best?;
        let e = &self.parts[i];
        // The unit sphere's normal back through the inverse-transpose scale.
        let n_local = Vector3::new(lp.x / e.semi.x, lp.y / e.semi.y, lp.z / e.semi.z);
        let n = (fwd * n_local.x + left * n_local.y + Vector3::z() * n_local.z).normalize();
        Some(shade(&n, &e.colour))
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::simulate::scene::Ground;

    fn deck_world() -> World {
        World::new(
            &Ground::Deck {
                centre: [0.0, 0.0],
                heading_deg: 0.0,
                width_m: 4.0,
                length_m: 60.0,
                height_m: 6.0,
                camber_m: 0.0,
            },
            &[],
            3,
        )
    }

    /// The outline's image box is the box of the whole body's surface, seen from the side and
    /// from above: nothing of the body sticks out of it and it is no larger.
    #[test]
    fn the_outline_bounds_the_body_as_a_camera_sees_it() {
        let world = deck_world();
        let people = spawn(&PeopleSpec::default(), &world, 30.0, 11);
        let p = &people[0];
        let pose = p.pose(&world, p.start_s + 1.3).unwrap();
        let body = Body::new(p, &pose, None);
        let fwd = Vector3::new(body.heading.x, body.heading.y, 0.0);
        let left = Vector3::new(-body.heading.y, body.heading.x, 0.0);
        for eye_offset in [Vector3::new(12.0, -5.0, 3.0), Vector3::new(3.0, 2.0, 25.0)] {
            let eye = pose.foot + eye_offset;
            // A pinhole looking at the body's middle: image box in the camera's tangent plane.
            let z = (pose.foot + Vector3::new(0.0, 0.0, 0.9) - eye).normalize();
            let x = z.cross(&Vector3::z()).normalize();
            let y = z.cross(&x);
            let image = |q: &Vector3<f64>| {
                let d = q - eye;
                [d.dot(&x) / d.dot(&z), d.dot(&y) / d.dot(&z)]
            };
            let bbox = |pts: &mut dyn Iterator<Item = [f64; 2]>| {
                pts.fold([f64::MAX, f64::MAX, f64::MIN, f64::MIN], |b, q| {
                    [
                        b[0].min(q[0]),
                        b[1].min(q[1]),
                        b[2].max(q[0]),
                        b[3].max(q[1]),
                    ]
                })
            };
            let outline = bbox(&mut body.outline(&eye, 96).iter().map(image));
            let mut surface = Vec::new();
            for e in &body.parts {
                for i in 0..60 {
                    for j in 0..120 {
                        let (th, ph) = (
                            std::f64::consts::PI * (i as f64 + 0.5) / 60.0,
                            std::f64::consts::TAU * j as f64 / 120.0,
                        );
                        let u = [th.sin() * ph.cos(), th.sin() * ph.sin(), th.cos()];
                        surface.push(image(
                            &(e.centre
                                + fwd * (u[0] * e.semi.x)
                                + left * (u[1] * e.semi.y)
                                + Vector3::z() * (u[2] * e.semi.z)),
                        ));
                    }
                }
            }
            let dense = bbox(&mut surface.into_iter());
            let scale = (dense[2] - dense[0]).max(dense[3] - dense[1]);
            for k in 0..4 {
                assert!(
                    (outline[k] - dense[k]).abs() < 0.01 * scale,
                    "side {k}: outline {outline:?} surface {dense:?}"
                );
            }
        }
    }

    #[test]
    fn streams_arrive_at_the_rate_and_cross_the_deck() {
        let world = deck_world();
        let spec = PeopleSpec {
            rate_per_s: 2.0,
            ..PeopleSpec::default()
        };
        let people = spawn(&spec, &world, 100.0, 7);
        // Arrivals over the 100 s and one crossing before (60 m at 3.5 m/s): Poisson, σ = √n.
        let expected = 2.0 * (100.0 + 60.0 / 3.5);
        assert!(
            (people.len() as f64 - expected).abs() < 4.0 * expected.sqrt(),
            "{} vs {expected}",
            people.len()
        );
        let p = &people[3];
        assert!(p.pose(&world, p.start_s - 0.1).is_none());
        let pose = p.pose(&world, p.start_s + 2.0).unwrap();
        assert!((pose.foot.z - 6.0).abs() < 1e-9, "on the deck");
        let h = pose.head_top.z - pose.foot.z;
        assert!((h - p.height_m).abs() <= p.bob_m + 1e-12);
        assert!(pose.foot.y < -30.0 + p.speed_m_s * 2.0 + 1e-9);
        assert!(
            p.pose(&world, p.start_s + 60.0 / p.speed_m_s + 1.0)
                .is_none(),
            "off the far end"
        );
        // Deterministic.
        let again = spawn(&spec, &world, 100.0, 7);
        assert_eq!(again[10].height_m, people[10].height_m);
        let heights: Vec<f64> = people.iter().map(|p| p.height_m).collect();
        let m = heights.iter().sum::<f64>() / heights.len() as f64;
        assert!((m - 1.7).abs() < 0.03, "{m}");
    }

    /// The closest two people's feet come, horizontally, over `steps` of 0.1 s.
    fn closest_feet(people: &[Person], world: &World, steps: usize) -> f64 {
        let mut least = f64::INFINITY;
        for k in 0..steps {
            let at: Vec<Vector3<f64>> = people
                .iter()
                .filter_map(|p| p.pose(world, k as f64 * 0.1))
                .map(|q| q.foot)
                .collect();
            for i in 0..at.len() {
                for j in 0..i {
                    least = least.min((at[i] - at[j]).xy().norm());
                }
            }
        }
        least
    }

    #[test]
    fn stream_arrivals_keep_their_distance() {
        let world = deck_world();
        let closest = |spacing: f64| {
            let spec = PeopleSpec {
                rate_per_s: 1.5,
                lane_changes_per_min: 1.0,
                min_spacing_m: spacing,
                ..PeopleSpec::default()
            };
            closest_feet(&spawn(&spec, &world, 30.0, 5), &world, 300)
        };
        // Without the rule people pass through each other; with it they keep 0.6 m.
        assert!(closest(0.0) < 0.3, "{}", closest(0.0));
        assert!(closest(0.6) >= 0.6 - 1e-6, "{}", closest(0.6));
    }

    #[test]
    fn a_pack_keeps_its_distance_too() {
        let world = World::new(
            &Ground::Track {
                centre: [0.0, 0.0],
                heading_deg: 0.0,
                lanes: 8,
                lane_width_m: 1.22,
                straight_m: 84.4,
                radius_m: 36.5,
            },
            &[],
            3,
        );
        let closest = |spacing: f64| {
            let spec = PeopleSpec {
                mode: "group".into(),
                count: 16,
                speed_m_s: [3.8, 0.15],
                lane_changes_per_min: 1.0,
                min_spacing_m: spacing,
                ..PeopleSpec::default()
            };
            closest_feet(&spawn(&spec, &world, 10.0, 7), &world, 100)
        };
        // Overtaking runners pass through each other without the rule, not with it.
        assert!(closest(0.0) < 0.3, "{}", closest(0.0));
        assert!(closest(0.8) >= 0.8 - 1e-3, "{}", closest(0.8));
    }

    #[test]
    fn a_ray_straight_down_hits_the_hat_at_the_head_top() {
        let world = deck_world();
        let spec = PeopleSpec {
            mode: "group".into(),
            count: 1,
            ..PeopleSpec::default()
        };
        let people = spawn(&spec, &world, 10.0, 1);
        let pose = people[0].pose(&world, 1.0).unwrap();
        let body = Body::new(&people[0], &pose, Some([1.0, 0.0, 1.0]));
        let origin = pose.head_top + Vector3::new(0.0, 0.0, 20.0);
        let c = body
            .hit(&origin, &-Vector3::z(), &Vector3::new(0.0, 0.0, 1.0))
            .unwrap();
        assert_eq!(c, [1.0, 0.0, 1.0]);
        assert!(body.may_hit(&origin, &-Vector3::z(), 0.0));
        // Beside the hat but over the shoulder: the shirt.
        let c = body
            .hit(
                &(pose.foot + Vector3::new(0.18, 0.0, 20.0)),
                &-Vector3::z(),
                &Vector3::z(),
            )
            .unwrap();
        let shirt = people[0].shirt;
        let ratio: Vec<f32> = (0..3)
            .filter(|&k| shirt[k] > 0.05)
            .map(|k| c[k] / shirt[k])
            .collect();
        assert!(
            ratio.windows(2).all(|w| (w[0] - w[1]).abs() < 1e-5) && ratio[0] < 1.0,
            "the shirt, shaded: {c:?} vs {shirt:?}"
        );
        assert!(
            body.hit(
                &(pose.foot + Vector3::new(0.6, 0.0, 20.0)),
                &-Vector3::z(),
                &Vector3::z()
            )
            .is_none()
        );
    }
}
