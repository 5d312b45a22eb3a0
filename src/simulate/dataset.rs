//! Training tiles for an overhead person detector (pure): square images rendered by the
//! simulator's renderer, each with its own random camera (ground sample distance, view off
//! nadir), site (a track or a footbridge and its surroundings), sun (or overcast), people
//! (standing, walking, running, alone and in touching groups, every colour, some in caps) and
//! things that look like people from above but are not (bollards, bins, cones, benches,
//! bicycles, manhole covers, GCP targets, the shadows of people outside the tile), then the
//! camera's faults (exposure, white balance, sensor noise, motion blur, defocus). Each person's
//! exact box, head point and shoulder width in pixels come with it.
//!
//! Tile `i` of a dataset depends only on the seed and `i` (its own random stream), so a
//! dataset is the same on any machine and with any number of threads, and any range of it can
//! be rendered alone.

use std::sync::Arc;

use nalgebra::{Matrix3, Vector2, Vector3};
use rand::{RngExt, SeedableRng};
use rand_chacha::ChaCha8Rng;

use super::backdrop::{Backdrop, BackdropView};
use super::people::{Body, BodyStyle, Ellipsoid, HEAD_RADIUS_M, Pose};
use super::render::{CameraPose, FrameInput, RenderSettings, Renderer, Shadow};
use super::scene::{GcpSpec, Ground};
use super::world::{Rgb, World};
use crate::camera::{Camera, ImageSize};

/// What a dataset draws its tiles from.
#[derive(Clone, Debug, PartialEq, serde::Serialize)]
pub struct DatasetSpec {
    /// Tile side, pixels.
    pub size_px: u32,
    pub seed: u64,
    /// Ground sample distance at the tile's centre, metres a pixel (drawn log-uniformly).
    pub gsd_m: [f64; 2],
    /// The tile centre's view, degrees from straight down (drawn from 0 to this).
    pub max_off_nadir_deg: f64,
    /// The ground's texture (`World::detail`: 1 the simulator's default, 4 the feature-rich
    /// ground a scene gives structure from motion), drawn uniformly.
    pub ground_detail: [f64; 2],
    /// The share of tiles laid on a real photo (when backdrops are given).
    pub backdrop_share: f64,
}

impl Default for DatasetSpec {
    fn default() -> Self {
        DatasetSpec {
            size_px: 256,
            seed: 1,
            gsd_m: [0.004, 0.03],
            max_off_nadir_deg: 40.0,
            ground_detail: [0.6, 2.0],
            backdrop_share: 0.0,
        }
    }
}

/// One person in a tile, pixels.
#[derive(Clone, Debug, PartialEq)]
pub struct TileLabel {
    /// `[x, y, w, h]` of the silhouette, clipped to the tile.
    pub bbox: [f64; 4],
    /// The top of the head (may lie outside the tile when the box is cut).
    pub head: [f64; 2],
    /// The shoulders' width (0.5 m) at the person, pixels: the match radius's scale.
    pub shoulder_px: f64,
    /// The share of the silhouette's box inside the tile.
    pub inside: f64,
}

/// How a tile was made.
#[derive(Clone, Debug, PartialEq, serde::Serialize)]
pub struct TileInfo {
    pub gsd_m: f64,
    pub off_nadir_deg: f64,
    /// None: overcast, no shadows.
    pub sun_elevation_deg: Option<f64>,
    pub ground: &'static str,
    pub people: usize,
    pub objects: usize,
    /// Sensor noise, grey levels (σ).
    pub noise: f64,
    /// Blur: motion (length, px) and defocus (σ, px).
    pub motion_blur_px: f64,
    pub defocus_px: f64,
    /// The JPEG quality the tile is to be stored at (its compression is part of the sample).
    pub jpeg_quality: u8,
    /// The ground's texture ([`DatasetSpec::ground_detail`]).
    pub ground_detail: f64,
    /// The photo the ground shows, if any ([`render_tile`]'s backdrops).
    pub backdrop: Option<String>,
}

/// A rendered tile: 8-bit RGB, row-major.
pub struct Tile {
    pub rgb: Vec<u8>,
    pub labels: Vec<TileLabel>,
    pub info: TileInfo,
}

/// Uniform in `[a, b)`.
fn uniform(rng: &mut ChaCha8Rng, a: f64, b: f64) -> f64 {
    a + (b - a) * rng.random::<f64>()
}

/// A standard normal draw (Box–Muller).
fn normal(rng: &mut ChaCha8Rng) -> f64 {
    let u = rng.random::<f64>().max(1e-12);
    let v = rng.random::<f64>();
    (-2.0 * u.ln()).sqrt() * (std::f64::consts::TAU * v).cos()
}

/// A colour from hue, saturation and value, all in [0, 1].
fn hsv(h: f64, s: f64, v: f64) -> Rgb {
    crate::image::hsv_to_rgb(h, s, v).map(|c| c as f32)
}

/// Clothing: any hue, from washed out to vivid, from black to white.
fn clothing(rng: &mut ChaCha8Rng) -> Rgb {
    match rng.random_range(0..10) {
        // Black, greys and white are common.
        0..=2 => {
            let v = uniform(rng, 0.05, 0.95);
            hsv(0.0, 0.0, v)
        }
        _ => hsv(
            rng.random::<f64>(),
            uniform(rng, 0.2, 1.0),
            uniform(rng, 0.15, 0.95),
        ),
    }
}

fn hair(rng: &mut ChaCha8Rng) -> Rgb {
    const HAIR: [Rgb; 6] = [
        [0.05, 0.04, 0.03],
        [0.18, 0.11, 0.06],
        [0.35, 0.22, 0.12],
        [0.70, 0.58, 0.35],
        [0.55, 0.55, 0.55],
        [0.50, 0.20, 0.08],
    ];
    HAIR[rng.random_range(0..HAIR.len())]
}

/// The tile's camera: pinhole, `size` square, looking at `target` from `off_nadir` degrees
/// off straight down towards azimuth `toward`, `gsd` metres a pixel there.
fn tile_camera(
    size: u32,
    target: &Vector3<f64>,
    height_m: f64,
    off_nadir_deg: f64,
    toward_rad: f64,
    roll_rad: f64,
    gsd_m: f64,
) -> (Camera, CameraPose) {
    let t = off_nadir_deg.to_radians();
    let range = height_m / t.cos();
    let f = range / gsd_m;
    let half = f64::from(size) / 2.0 - 0.5;
    let camera = Camera {
        image_size: Some(ImageSize {
            width: size,
            height: size,
        }),
        fx: f,
        fy: f,
        cx: half,
        cy: half,
        skew: 0.0,
        dist: [0.0; 8],
    };
    // Forward: from the camera down to the target.
    let fwd = Vector3::new(
        t.sin() * toward_rad.cos(),
        t.sin() * toward_rad.sin(),
        -t.cos(),
    );
    let h = Vector3::new(roll_rad.cos(), roll_rad.sin(), 0.0);
    let mut x = h - fwd * h.dot(&fwd);
    if x.norm() < 1e-6 {
        x = Vector3::new(-roll_rad.sin(), roll_rad.cos(), 0.0);
        x -= fwd * x.dot(&fwd);
    }
    let x = x.normalize();
    let y = fwd.cross(&x);
    let pose = CameraPose {
        centre: target - fwd * range,
        world_from_cam: Matrix3::from_columns(&[x, y, fwd]),
    };
    (camera, pose)
}

/// Where the tile's corners' rays meet the level `z`, with `margin_m` around: the ground box
/// the tile sees.
fn footprint(
    camera: &Camera,
    pose: &CameraPose,
    size: u32,
    z: f64,
    margin_m: f64,
) -> (Vector2<f64>, Vector2<f64>) {
    let s = f64::from(size);
    let mut lo = Vector2::repeat(f64::INFINITY);
    let mut hi = Vector2::repeat(f64::NEG_INFINITY);
    for (u, v) in [(0.0, 0.0), (s, 0.0), (0.0, s), (s, s)] {
        let ray = camera
            .unproject(&Vector2::new(u - 0.5, v - 0.5))
            .map_or(Vector3::new(0.0, 0.0, 1.0), |r| r.into_inner());
        let d = pose.world_from_cam * ray;
        let t = if d.z < -1e-6 {
            (z - pose.centre.z) / d.z
        } else {
            0.0
        };
        let p = (pose.centre + d * t).xy();
        lo = lo.inf(&p);
        hi = hi.sup(&p);
    }
    (
        lo - Vector2::repeat(margin_m),
        hi + Vector2::repeat(margin_m),
    )
}

/// Whether `p` is at least `gap` from every placed foot.
fn free(p: &Vector2<f64>, feet: &[(Vector2<f64>, Vector2<f64>)], gap: f64) -> bool {
    feet.iter().all(|(q, _)| (q - p).norm() >= gap)
}

/// A thing that is not a person: one or a few ellipsoids on the ground at `at`.
fn object(rng: &mut ChaCha8Rng, at: &Vector3<f64>) -> Body {
    let a = uniform(rng, 0.0, std::f64::consts::TAU);
    let heading = Vector2::new(a.cos(), a.sin());
    let fwd = Vector3::new(heading.x, heading.y, 0.0);
    let part = |c: Vector3<f64>, semi: [f64; 3], colour: Rgb| Ellipsoid {
        centre: c,
        semi: Vector3::new(semi[0], semi[1], semi[2]),
        colour,
    };
    let z = |h: f64| at + Vector3::new(0.0, 0.0, h);
    let grey = |v: f32| [v, v, v];
    let parts = match rng.random_range(0..7) {
        // A bollard.
        0 => {
            let colour = if rng.random::<bool>() {
                grey(uniform(rng, 0.2, 0.7) as f32)
            } else {
                [0.85, 0.7, 0.1]
            };
            vec![part(z(0.45), [0.1, 0.1, 0.45], colour)]
        }
        // A bin.
        1 => vec![part(z(0.45), [0.28, 0.28, 0.45], clothing(rng))],
        // A cone.
        2 => vec![
            part(z(0.25), [0.14, 0.14, 0.25], [0.95, 0.4, 0.05]),
            part(z(0.02), [0.2, 0.2, 0.02], [0.95, 0.4, 0.05]),
        ],
        // A bench.
        3 => vec![
            part(z(0.45), [0.8, 0.22, 0.05], [0.45, 0.3, 0.15]),
            part(
                z(0.7) - fwd.cross(&Vector3::z()) * 0.2,
                [0.8, 0.04, 0.2],
                [0.45, 0.3, 0.15],
            ),
        ],
        // A bicycle.
        4 => vec![
            part(z(0.35) + fwd * 0.45, [0.33, 0.02, 0.33], grey(0.1)),
            part(z(0.35) - fwd * 0.45, [0.33, 0.02, 0.33], grey(0.1)),
            part(z(0.7), [0.5, 0.03, 0.05], clothing(rng)),
            part(z(0.95) + fwd * 0.4, [0.04, 0.28, 0.02], grey(0.15)),
        ],
        // A manhole cover or a drain: flat and dark.
        5 => vec![part(
            z(0.005),
            [0.32, 0.32, 0.005],
            grey(uniform(rng, 0.08, 0.3) as f32),
        )],
        // A post with a sign: a person's height, thin.
        _ => vec![
            part(z(1.0), [0.04, 0.04, 1.0], grey(0.5)),
            part(z(2.0), [0.03, 0.3, 0.2], clothing(rng)),
        ],
    };
    let (mut lo, mut hi) = (
        Vector3::repeat(f64::INFINITY),
        Vector3::repeat(f64::NEG_INFINITY),
    );
    for p in &parts {
        let r = p.semi.x.max(p.semi.y);
        lo = lo.inf(&(p.centre - Vector3::new(r, r, p.semi.z)));
        hi = hi.sup(&(p.centre + Vector3::new(r, r, p.semi.z)));
    }
    Body {
        parts,
        heading,
        hat: None,
        bounds: (lo, hi),
    }
}

/// A person placed for a tile: their body, shadow and head.
struct Placed {
    body: Body,
    foot: Vector3<f64>,
    head_top: Vector3<f64>,
    height_m: f64,
}

/// The site, and the ground point the tile looks at: the ground, its name, the world's seed,
/// the world without GCP targets and the point.
fn site(rng: &mut ChaCha8Rng) -> (Ground, &'static str, u64, World, Vector3<f64>) {
    let heading_deg = uniform(rng, 0.0, 360.0);
    let (ground, ground_name) = if rng.random::<bool>() {
        (
            Ground::Track {
                centre: [0.0, 0.0],
                heading_deg,
                lanes: rng.random_range(4..=9),
                lane_width_m: 1.22,
                straight_m: 84.39,
                radius_m: 36.5,
            },
            "track",
        )
    } else {
        (
            Ground::Deck {
                centre: [0.0, 0.0],
                heading_deg,
                width_m: uniform(rng, 3.0, 14.0),
                length_m: 120.0,
                height_m: uniform(rng, 0.0, 8.0),
                camber_m: uniform(rng, 0.0, 1.0),
            },
            "deck",
        )
    };
    let world_seed: u64 = rng.random();
    let world0 = World::new(&ground, &[], world_seed);
    let target_en = match ground {
        Ground::Track { lanes, .. } => {
            let s = uniform(rng, 0.0, 400.0);
            let d = uniform(rng, -6.0, f64::from(lanes) * 1.22 + 6.0);
            world0.track_point(s, d).0
        }
        Ground::Deck { width_m, .. } => world0.from_local(
            uniform(rng, -50.0, 50.0),
            uniform(rng, -width_m / 2.0 - 4.0, width_m / 2.0 + 4.0),
        ),
    };
    let target = Vector3::new(
        target_en.x,
        target_en.y,
        world0.surface_height(&target_en).0,
    );
    (ground, ground_name, world_seed, world0, target)
}

/// Where people stand and which way they face, in the ground box `lo`–`hi`: none in some
/// tiles, else alone, in groups that touch, or running in a line.
fn place_feet(
    rng: &mut ChaCha8Rng,
    lo: &Vector2<f64>,
    hi: &Vector2<f64>,
) -> Vec<(Vector2<f64>, Vector2<f64>)> {
    let area = (hi - lo).x * (hi - lo).y;
    let mut feet: Vec<(Vector2<f64>, Vector2<f64>)> = Vec::new();
    if rng.random::<f64>() >= 0.12 {
        let wanted = rng
            .random_range(1..=30usize)
            .min((area / 0.8) as usize)
            .max(1);
        let mut tries = 0;
        while feet.len() < wanted && tries < 400 {
            tries += 1;
            let c = Vector2::new(uniform(rng, lo.x, hi.x), uniform(rng, lo.y, hi.y));
            let a = uniform(rng, 0.0, std::f64::consts::TAU);
            let dir = Vector2::new(a.cos(), a.sin());
            match rng.random_range(0..3) {
                // Alone.
                0 => {
                    if free(&c, &feet, 0.6) {
                        feet.push((c, dir));
                    }
                }
                // A group, shoulder to shoulder or just apart, facing about the same way.
                1 => {
                    let n = rng.random_range(2..=6);
                    for _ in 0..n {
                        let p = c + Vector2::new(uniform(rng, -0.9, 0.9), uniform(rng, -0.9, 0.9));
                        let turn = uniform(rng, -0.4, 0.4);
                        let d = Vector2::new(
                            dir.x * turn.cos() - dir.y * turn.sin(),
                            dir.x * turn.sin() + dir.y * turn.cos(),
                        );
                        if free(&p, &feet, 0.45) {
                            feet.push((p, d));
                        }
                    }
                }
                // A line of runners.
                _ => {
                    let n = rng.random_range(2..=5);
                    for k in 0..n {
                        let p = c + dir * (k as f64 * uniform(rng, 0.9, 2.0));
                        if free(&p, &feet, 0.6) {
                            feet.push((p, dir));
                        }
                    }
                }
            }
        }
    }
    feet
}

/// The people at `feet`: height, gait, clothes and caps.
fn dress(
    rng: &mut ChaCha8Rng,
    feet: &[(Vector2<f64>, Vector2<f64>)],
    world0: &World,
) -> Vec<Placed> {
    let mut placed = Vec::new();
    for (en, dir) in feet {
        let (z, _) = world0.surface_height(en);
        let foot = Vector3::new(en.x, en.y, z);
        let child = rng.random::<f64>() < 0.05;
        let height_m = if child {
            uniform(rng, 1.05, 1.45)
        } else {
            (1.71 + 0.09 * normal(rng)).clamp(1.45, 2.05)
        };
        let gait = rng.random_range(0..4);
        let swing = match gait {
            0 => 0.0,
            1 | 2 => uniform(rng, 0.7, 1.2),
            _ => uniform(rng, 1.3, 1.7),
        };
        let head_top = foot + Vector3::new(0.0, 0.0, height_m);
        let style = BodyStyle {
            shirt: clothing(rng),
            hair: hair(rng),
            trousers: if rng.random::<f64>() < 0.6 {
                hsv(0.6, uniform(rng, 0.0, 0.5), uniform(rng, 0.05, 0.35))
            } else {
                clothing(rng)
            },
            swing,
            girth: uniform(rng, 0.85, 1.25) * if child { 0.8 } else { 1.0 },
        };
        // Caps, never on most: the detector must not need them.
        let cap = (rng.random::<f64>() < 0.12).then(|| clothing(rng));
        let p = Pose {
            foot,
            heading: *dir,
            head_top,
            stride_phase: uniform(rng, 0.0, std::f64::consts::TAU),
        };
        placed.push(Placed {
            body: Body::styled(&p, cap, &style),
            foot,
            head_top,
            height_m,
        });
    }
    placed
}

/// What else the tile holds: things that are not people (their bodies and count), the world
/// with its GCP targets, and the shadows (the people's and those of people just outside).
fn props(
    rng: &mut ChaCha8Rng,
    (ground, world_seed, world0): (&Ground, u64, &World),
    feet: &[(Vector2<f64>, Vector2<f64>)],
    (lo, hi): (Vector2<f64>, Vector2<f64>),
    placed: &[Placed],
    (overcast, sun): (bool, &Vector3<f64>),
    detail: [f64; 2],
) -> (Vec<Body>, usize, World, Vec<Shadow>) {
    let n_objects = rng.random_range(0..=8usize);
    let mut bodies: Vec<Body> = Vec::new();
    let mut objects = 0;
    for _ in 0..n_objects {
        let en = Vector2::new(uniform(rng, lo.x, hi.x), uniform(rng, lo.y, hi.y));
        if !free(&en, feet, 0.7) {
            continue;
        }
        let z = world0.surface_height(&en).0;
        bodies.push(object(rng, &Vector3::new(en.x, en.y, z)));
        objects += 1;
    }
    let gcps: Vec<GcpSpec> = (0..rng.random_range(0..=1u32))
        .map(|k| {
            GcpSpec::new(
                format!("T{k}"),
                [uniform(rng, lo.x, hi.x), uniform(rng, lo.y, hi.y)],
            )
        })
        .collect();
    let mut world = World::new(ground, &gcps, world_seed);
    world.detail = uniform(rng, detail[0], detail[1]);
    let shadows: Vec<Shadow> = if overcast {
        Vec::new()
    } else {
        let mut s: Vec<Shadow> = placed
            .iter()
            .map(|p| Shadow::of(&p.foot, p.height_m, sun))
            .collect();
        // The shadows of people just outside the tile.
        for _ in 0..rng.random_range(0..3) {
            let en = Vector2::new(
                uniform(rng, lo.x - 3.0, hi.x + 3.0),
                uniform(rng, lo.y - 3.0, hi.y + 3.0),
            );
            if en.x < lo.x || en.x > hi.x || en.y < lo.y || en.y > hi.y {
                let z = world0.surface_height(&en).0;
                s.push(Shadow::of(&Vector3::new(en.x, en.y, z), 1.7, sun));
            }
        }
        s
    };
    (bodies, objects, world, shadows)
}

/// The camera's faults, the exposure and the JPEG quality.
fn draw_faults(rng: &mut ChaCha8Rng, seed: u64) -> (Faults, f64, u8) {
    let noise = uniform(rng, 0.0, 6.0);
    let light = uniform(rng, 0.65, 1.35);
    let balance: [f32; 3] = std::array::from_fn(|_| uniform(rng, 0.88, 1.12) as f32);
    let motion_blur_px = if rng.random::<f64>() < 0.3 {
        uniform(rng, 1.0, 4.0)
    } else {
        0.0
    };
    let blur_dir = uniform(rng, 0.0, std::f64::consts::PI);
    let defocus_px = if rng.random::<f64>() < 0.25 {
        uniform(rng, 0.4, 1.3)
    } else {
        0.0
    };
    let jpeg_quality = rng.random_range(45..=95u8);
    (
        Faults {
            balance,
            motion_blur_px,
            blur_dir,
            defocus_px,
            noise,
            seed,
        },
        light,
        jpeg_quality,
    )
}

/// Each placed person's label in the tile seen by `camera` from `pose`.
fn label(
    placed: &[Placed],
    camera: &Camera,
    pose: &CameraPose,
    size: u32,
    gsd_m: f64,
) -> Vec<TileLabel> {
    let s = f64::from(size);
    let mut labels = Vec::new();
    for p in placed {
        let mut b = [
            f64::INFINITY,
            f64::INFINITY,
            f64::NEG_INFINITY,
            f64::NEG_INFINITY,
        ];
        let mut ok = true;
        for q in p.body.outline(&pose.centre, 24) {
            match pose.project(camera, &q) {
                Some(uv) => {
                    b = [
                        b[0].min(uv.x),
                        b[1].min(uv.y),
                        b[2].max(uv.x),
                        b[3].max(uv.y),
                    ];
                }
                None => ok = false,
            }
        }
        let Some(head) = pose.project(camera, &p.head_top) else {
            continue;
        };
        // A box with no extent (or NaN corners) labels nothing.
        if !ok
            || b[2].partial_cmp(&b[0]) != Some(std::cmp::Ordering::Greater)
            || b[3].partial_cmp(&b[1]) != Some(std::cmp::Ordering::Greater)
        {
            continue;
        }
        let full = (b[2] - b[0]) * (b[3] - b[1]);
        let c = [
            b[0].max(-0.5),
            b[1].max(-0.5),
            b[2].min(s - 0.5),
            b[3].min(s - 0.5),
        ];
        if c[2] - c[0] < 1.0 || c[3] - c[1] < 1.0 {
            continue;
        }
        let inside = (c[2] - c[0]) * (c[3] - c[1]) / full;
        // The shoulders, 0.5 m across at their height, seen from the camera.
        let shoulders = p.foot + Vector3::new(0.0, 0.0, 0.82 * p.height_m);
        let side = Vector3::new(-p.body.heading.y, p.body.heading.x, 0.0) * 0.25;
        let shoulder_px = match (
            pose.project(camera, &(shoulders + side)),
            pose.project(camera, &(shoulders - side)),
        ) {
            (Some(a), Some(b)) => (a - b).norm().max(0.5 * HEAD_RADIUS_M / gsd_m),
            _ => 0.5 / gsd_m,
        };
        labels.push(TileLabel {
            bbox: [c[0], c[1], c[2] - c[0], c[3] - c[1]],
            head: [head.x, head.y],
            shoulder_px,
            inside,
        });
    }
    labels
}

/// Lays one of the photos, or none, under a tile looking at `target` over the ground box
/// `lo`–`hi`, from the tile's own stream (apart from the main one, so that a dataset without
/// backdrops is the same as before they existed).
fn pick_backdrop(
    spec: &DatasetSpec,
    index: u64,
    backdrops: &[Arc<Backdrop>],
    target: &Vector3<f64>,
    (lo, hi): (Vector2<f64>, Vector2<f64>),
    sun: &Vector3<f64>,
) -> Option<BackdropView> {
    if backdrops.is_empty() {
        return None;
    }
    let mut rng = ChaCha8Rng::seed_from_u64(spec.seed ^ 0xBAC4_D50F);
    rng.set_stream(index);
    if rng.random::<f64>() >= spec.backdrop_share {
        return None;
    }
    let image = backdrops[rng.random_range(0..backdrops.len())].clone();
    // The footprint's reach from the target, photo pixels: the photo covers the tile where it can.
    let reach = (lo - target.xy())
        .abs()
        .sup(&(hi - target.xy()).abs())
        .norm()
        / image.gsd_m;
    let mut centre = |n: usize| {
        let n = n as f64;
        if 2.0 * reach < n {
            uniform(&mut rng, reach, n - reach)
        } else {
            n / 2.0
        }
    };
    let centre_px = [centre(image.width), centre(image.height)];
    Some(BackdropView {
        image,
        origin_en: target.xy(),
        centre_px,
        turn_rad: uniform(&mut rng, 0.0, std::f64::consts::TAU),
        mirror: rng.random::<bool>(),
        gain: (1.0 / (0.45 + 0.55 * sun.z.max(0.0))) as f32,
    })
}

/// Renders tile `index` of the dataset `spec`, some tiles (`spec.backdrop_share`) on one of
/// the `backdrops`.
pub fn render_tile(spec: &DatasetSpec, index: u64, backdrops: &[Arc<Backdrop>]) -> Tile {
    let mut rng = ChaCha8Rng::seed_from_u64(spec.seed);
    rng.set_stream(index);
    let size = spec.size_px;
    let (ground, ground_name, world_seed, world0, target) = site(&mut rng);

    // The camera.
    let gsd_m =
        (spec.gsd_m[0].ln() + (spec.gsd_m[1] / spec.gsd_m[0]).ln() * rng.random::<f64>()).exp();
    let off_nadir_deg = if rng.random::<f64>() < 0.25 {
        uniform(&mut rng, 0.0, 3.0).min(spec.max_off_nadir_deg)
    } else {
        uniform(&mut rng, 0.0, spec.max_off_nadir_deg)
    };
    let height_m = uniform(&mut rng, 8.0, 60.0);
    let toward = uniform(&mut rng, 0.0, std::f64::consts::TAU);
    let roll = uniform(&mut rng, 0.0, std::f64::consts::TAU);
    let (camera, pose) = tile_camera(size, &target, height_m, off_nadir_deg, toward, roll, gsd_m);

    // The sun.
    let overcast = rng.random::<f64>() < 0.2;
    let (sun, sun_elevation_deg) = if overcast {
        (Vector3::z(), None)
    } else {
        let e = uniform(&mut rng, 15.0, 80.0);
        let a = uniform(&mut rng, 0.0, 360.0);
        {
            let (a, e) = (a.to_radians(), e.to_radians());
            // Azimuth from north, clockwise: east, north, up.
            (
                Vector3::new(a.sin() * e.cos(), a.cos() * e.cos(), e.sin()),
                Some(e.to_degrees()),
            )
        }
    };

    let (lo, hi) = footprint(&camera, &pose, size, target.z, 1.5);
    let feet = place_feet(&mut rng, &lo, &hi);
    let placed = dress(&mut rng, &feet, &world0);
    let (mut bodies, objects, mut world, shadows) = props(
        &mut rng,
        (&ground, world_seed, &world0),
        &feet,
        (lo, hi),
        &placed,
        (overcast, &sun),
        spec.ground_detail,
    );
    let seed = spec.seed ^ index.wrapping_mul(0x9E37_79B9_7F4A_7C15);
    let (faults, light, jpeg_quality) = draw_faults(&mut rng, seed);
    world.backdrop = pick_backdrop(spec, index, backdrops, &target, (lo, hi), &sun);

    let settings = RenderSettings {
        texel_m: (0.7 * gsd_m).clamp(0.003, 0.05),
        sun,
        image_noise: 0.0,
        seed,
    };
    // Textured only where the tile looks (the people's margin would cost texels, not pixels).
    let seen = footprint(&camera, &pose, size, target.z, 0.2);
    let renderer = Renderer::new(&world, camera.clone(), seen, &settings);
    bodies.extend(placed.iter().map(|p| Body {
        parts: p.body.parts.clone(),
        heading: p.body.heading,
        hat: p.body.hat,
        bounds: p.body.bounds,
    }));
    let mut rgb = renderer.render(&FrameInput {
        index: index as usize,
        pose: &pose,
        bodies: &bodies,
        shadows: &shadows,
        light,
    });
    degrade(&mut rgb, size as usize, &faults);
    let labels = label(&placed, &camera, &pose, size, gsd_m);
    Tile {
        rgb,
        labels,
        info: TileInfo {
            gsd_m,
            off_nadir_deg,
            sun_elevation_deg,
            ground: if world.backdrop.is_some() {
                "backdrop"
            } else {
                ground_name
            },
            people: placed.len(),
            objects,
            noise: faults.noise,
            motion_blur_px: faults.motion_blur_px,
            defocus_px: faults.defocus_px,
            jpeg_quality,
            ground_detail: world.detail,
            backdrop: world.backdrop.as_ref().map(|b| b.image.name.clone()),
        },
    }
}

/// A camera's faults applied to a rendered tile.
struct Faults {
    balance: [f32; 3],
    motion_blur_px: f64,
    blur_dir: f64,
    defocus_px: f64,
    noise: f64,
    seed: u64,
}

/// White balance, motion blur along a line, defocus (a Gaussian), then sensor noise, on 8-bit
/// RGB in place.
fn degrade(rgb: &mut [u8], size: usize, f: &Faults) {
    let mut img: Vec<f32> = rgb.iter().map(|&v| f32::from(v)).collect();
    for px in img.chunks_mut(3) {
        for (v, g) in px.iter_mut().zip(f.balance) {
            *v *= g;
        }
    }
    let sample = |img: &[f32], x: f64, y: f64, k: usize| -> f32 {
        let (xi, yi) = (
            x.round().clamp(0.0, (size - 1) as f64) as usize,
            y.round().clamp(0.0, (size - 1) as f64) as usize,
        );
        img[(yi * size + xi) * 3 + k]
    };
    if f.motion_blur_px > 0.0 {
        let taps = (f.motion_blur_px.ceil() as usize * 2 + 1).max(3);
        let (dx, dy) = (f.blur_dir.cos(), f.blur_dir.sin());
        let src = img.clone();
        for y in 0..size {
            for x in 0..size {
                for k in 0..3 {
                    let mut sum = 0.0;
                    for t in 0..taps {
                        let s = (t as f64 / (taps - 1) as f64 - 0.5) * f.motion_blur_px;
                        sum += sample(&src, x as f64 + s * dx, y as f64 + s * dy, k);
                    }
                    img[(y * size + x) * 3 + k] = sum / taps as f32;
                }
            }
        }
    }
    if f.defocus_px > 0.0 {
        let r = (3.0 * f.defocus_px).ceil() as i64;
        let w: Vec<f32> = (-r..=r)
            .map(|i| (-(i * i) as f64 / (2.0 * f.defocus_px * f.defocus_px)).exp() as f32)
            .collect();
        let total: f32 = w.iter().sum();
        for pass in 0..2 {
            let src = img.clone();
            for y in 0..size {
                for x in 0..size {
                    for k in 0..3 {
                        let mut sum = 0.0;
                        for (j, wj) in w.iter().enumerate() {
                            let o = j as i64 - r;
                            let (xx, yy) = if pass == 0 {
                                ((x as i64 + o).clamp(0, size as i64 - 1) as usize, y)
                            } else {
                                (x, (y as i64 + o).clamp(0, size as i64 - 1) as usize)
                            };
                            sum += wj * src[(yy * size + xx) * 3 + k];
                        }
                        img[(y * size + x) * 3 + k] = sum / total;
                    }
                }
            }
        }
    }
    for (i, (out, v)) in rgb.iter_mut().zip(&img).enumerate() {
        let n = if f.noise > 0.0 {
            let key = f.seed ^ (i as u64).wrapping_mul(0xD1B5_4A32_D192_ED03);
            super::noise::gaussian(key) * f.noise
        } else {
            0.0
        };
        *out = (f64::from(*v) + n).round().clamp(0.0, 255.0) as u8;
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_tile_is_the_same_from_its_seed_and_index_alone() {
        let spec = DatasetSpec {
            size_px: 96,
            ..DatasetSpec::default()
        };
        let a = render_tile(&spec, 7, &[]);
        let b = render_tile(&spec, 7, &[]);
        let c = render_tile(&spec, 8, &[]);
        assert_eq!(a.rgb, b.rgb);
        assert_eq!(a.labels, b.labels);
        assert_ne!(a.rgb, c.rgb);
        assert_eq!(a.rgb.len(), 96 * 96 * 3);
    }

    #[test]
    fn labels_box_the_people_and_their_heads_inside_the_tile() {
        let spec = DatasetSpec {
            size_px: 128,
            ..DatasetSpec::default()
        };
        let mut people = 0;
        for i in 0..40 {
            let t = render_tile(&spec, i, &[]);
            assert!(t.info.gsd_m >= 0.004 && t.info.gsd_m <= 0.03);
            assert!(t.info.off_nadir_deg <= 40.0);
            for l in &t.labels {
                people += 1;
                let [x, y, w, h] = l.bbox;
                assert!(x >= -0.5 && y >= -0.5 && x + w <= 127.5 && y + h <= 127.5);
                assert!(l.inside > 0.0 && l.inside <= 1.0 + 1e-9);
                // A whole person's head lies within their box.
                if l.inside > 0.999 {
                    assert!(
                        l.head[0] >= x - 1.0
                            && l.head[0] <= x + w + 1.0
                            && l.head[1] >= y - 1.0
                            && l.head[1] <= y + h + 1.0,
                        "{l:?}"
                    );
                }
                // About 0.5 m at 0.4-3 cm a pixel.
                assert!(l.shoulder_px > 5.0 && l.shoulder_px < 200.0, "{l:?}");
            }
        }
        assert!(people > 40, "{people} people in 40 tiles");
    }

    #[test]
    fn a_backdrop_tile_shows_the_photo_and_the_others_are_unchanged() {
        // A magenta photo: no simulated ground or person is that colour.
        let (w, h) = (200, 150);
        let rgb: Vec<u8> = (0..w * h).flat_map(|_| [200u8, 40, 190]).collect();
        let photo = Arc::new(Backdrop::new("magenta.jpg".into(), w, h, rgb, 0.02).unwrap());
        let plain = DatasetSpec {
            size_px: 96,
            ..DatasetSpec::default()
        };
        let spec = DatasetSpec {
            backdrop_share: 0.5,
            ..plain.clone()
        };
        let mut on_photo = 0;
        for i in 0..12 {
            let t = render_tile(&spec, i, std::slice::from_ref(&photo));
            let magenta = t
                .rgb
                .chunks(3)
                .filter(|p| p[0] > 100 && p[1] < 90 && p[2] > 100 && p[0].abs_diff(p[2]) < 60)
                .count();
            let share = magenta as f64 / (96.0 * 96.0);
            match &t.info.backdrop {
                Some(name) => {
                    on_photo += 1;
                    assert_eq!(name, "magenta.jpg");
                    assert_eq!(t.info.ground, "backdrop");
                    assert!(share > 0.3, "tile {i}: {share} magenta");
                }
                None => {
                    assert!(share < 0.01, "tile {i}: {share} magenta");
                    // The main stream is untouched: the same tile as without backdrops.
                    assert_eq!(t.rgb, render_tile(&plain, i, &[]).rgb);
                }
            }
            // People are labelled on the photo as anywhere.
            assert_eq!(t.labels, render_tile(&plain, i, &[]).labels);
        }
        assert!(
            (2..=10).contains(&on_photo),
            "{on_photo} of 12 on the photo"
        );
    }
}
