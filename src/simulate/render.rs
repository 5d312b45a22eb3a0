//! The frame renderer (pure): ground from baked ortho textures with sun shading and people's
//! shadows, then people ray-traced inside their image bounding boxes with 3x3 supersampling,
//! composited far to near, then light changes, sensor noise and gamma. Rows are rendered in
//! parallel; the result does not depend on the thread count.

use nalgebra::{Matrix3, Vector2, Vector3};
use rayon::prelude::*;

use super::noise::gaussian;
use super::people::Body;
use super::world::{Layer, Rgb, World};
use crate::camera::Camera;

/// A camera pose: centre and rotation, world from camera (camera x right, y down, z forward).
#[derive(Clone, Debug, PartialEq)]
pub struct CameraPose {
    pub centre: Vector3<f64>,
    pub world_from_cam: Matrix3<f64>,
}

impl CameraPose {
    /// Projects a world point to pixels, `None` behind the camera.
    pub fn project(&self, camera: &Camera, p: &Vector3<f64>) -> Option<Vector2<f64>> {
        let p_cam = self.world_from_cam.transpose() * (p - self.centre);
        camera.project(&p_cam).ok()
    }
}

/// An ortho texture: RGB albedo on a north-up grid of square texels.
pub struct Texture {
    pub origin: Vector2<f64>,
    pub texel_m: f64,
    pub cols: usize,
    pub rows: usize,
    data: Vec<[u8; 3]>,
}

impl Texture {
    /// Bakes a surface's albedo over a box.
    pub(crate) fn bake(
        world: &World,
        layer: Layer,
        min: Vector2<f64>,
        max: Vector2<f64>,
        texel_m: f64,
    ) -> Texture {
        let cols = (((max.x - min.x) / texel_m).ceil() as usize + 2).max(2);
        let rows = (((max.y - min.y) / texel_m).ceil() as usize + 2).max(2);
        let mut data = vec![[0u8; 3]; cols * rows];
        data.par_chunks_mut(cols).enumerate().for_each(|(r, row)| {
            for (c, px) in row.iter_mut().enumerate() {
                let en = Vector2::new(min.x + c as f64 * texel_m, min.y + r as f64 * texel_m);
                let z = match layer {
                    Layer::Ground => 0.0,
                    Layer::Deck => world.surface_height(&en).0,
                };
                let a = world.albedo(&Vector3::new(en.x, en.y, z), layer);
                *px = a.map(|v| (v * 255.0).round().clamp(0.0, 255.0) as u8);
            }
        });
        Texture {
            origin: min,
            texel_m,
            cols,
            rows,
            data,
        }
    }

    /// Bilinear sample, `None` outside.
    pub fn sample(&self, en: &Vector2<f64>) -> Option<Rgb> {
        let x = (en.x - self.origin.x) / self.texel_m;
        let y = (en.y - self.origin.y) / self.texel_m;
        if x < 0.0 || y < 0.0 || x >= (self.cols - 1) as f64 || y >= (self.rows - 1) as f64 {
            return None;
        }
        let (c, r) = (x as usize, y as usize);
        let (fx, fy) = ((x - c as f64) as f32, (y - r as f64) as f32);
        let at = |r: usize, c: usize| self.data[r * self.cols + c];
        let (a, b, cc, d) = (at(r, c), at(r, c + 1), at(r + 1, c), at(r + 1, c + 1));
        Some(std::array::from_fn(|k| {
            let top = f32::from(a[k]) * (1.0 - fx) + f32::from(b[k]) * fx;
            let bottom = f32::from(cc[k]) * (1.0 - fx) + f32::from(d[k]) * fx;
            (top * (1.0 - fy) + bottom * fy) / 255.0
        }))
    }
}

/// A person's shadow on the surface: an ellipse stretched away from the sun.
#[derive(Clone, Debug)]
pub struct Shadow {
    pub centre: Vector2<f64>,
    /// Unit direction away from the sun.
    pub axis: Vector2<f64>,
    pub semi_major: f64,
    pub semi_minor: f64,
}

impl Shadow {
    pub fn of(foot: &Vector3<f64>, height_m: f64, sun: &Vector3<f64>) -> Shadow {
        let h = sun.xy();
        let axis = if h.norm() > 1e-9 {
            -h.normalize()
        } else {
            Vector2::x()
        };
        let len = height_m * h.norm() / sun.z;
        Shadow {
            centre: foot.xy() + axis * (len / 2.0),
            axis,
            semi_major: len / 2.0 + 0.12,
            semi_minor: 0.22,
        }
    }

    fn contains(&self, p: &Vector2<f64>) -> bool {
        let d = p - self.centre;
        let a = d.dot(&self.axis) / self.semi_major;
        let b = (d.x * -self.axis.y + d.y * self.axis.x) / self.semi_minor;
        a * a + b * b <= 1.0
    }
}

/// People's shadows bucketed on a 1 m grid over the textured area, for per-pixel lookups.
struct ShadowGrid<'a> {
    shadows: &'a [Shadow],
    origin: Vector2<f64>,
    cols: usize,
    rows: usize,
    cells: Vec<Vec<u32>>,
}

impl<'a> ShadowGrid<'a> {
    const CELL_M: f64 = 1.0;

    fn new(shadows: &'a [Shadow], area: &Texture) -> Self {
        let origin = area.origin;
        let cols = ((area.cols as f64 * area.texel_m) / Self::CELL_M).ceil() as usize + 1;
        let rows = ((area.rows as f64 * area.texel_m) / Self::CELL_M).ceil() as usize + 1;
        let mut cells = vec![Vec::new(); cols * rows];
        for (i, s) in shadows.iter().enumerate() {
            let r = s.semi_major;
            let lo = ((s.centre - Vector2::new(r, r) - origin) / Self::CELL_M)
                .map(|x| x.floor().max(0.0) as usize);
            let hi = ((s.centre + Vector2::new(r, r) - origin) / Self::CELL_M)
                .map(|x| x.floor().max(0.0) as usize);
            for y in lo.y..=hi.y.min(rows - 1) {
                for x in lo.x..=hi.x.min(cols - 1) {
                    cells[y * cols + x].push(i as u32);
                }
            }
        }
        ShadowGrid {
            shadows,
            origin,
            cols,
            rows,
            cells,
        }
    }

    fn covers(&self, p: &Vector2<f64>) -> bool {
        let q = (p - self.origin) / Self::CELL_M;
        if q.x < 0.0 || q.y < 0.0 {
            return false;
        }
        let (x, y) = (q.x as usize, q.y as usize);
        if x >= self.cols || y >= self.rows {
            return false;
        }
        self.cells[y * self.cols + x]
            .iter()
            .any(|&i| self.shadows[i as usize].contains(p))
    }
}

/// Sub-samples per pixel side for people (anti-aliased edges keep blob centroids accurate).
const SS: u32 = 2;

/// How a scene is lit and textured.
#[derive(Clone, Copy, Debug)]
pub struct RenderSettings {
    /// Side of a texel of the baked ground textures, metres.
    pub texel_m: f64,
    /// Unit vector towards the sun.
    pub sun: Vector3<f64>,
    /// Sensor noise, grey levels (σ, 0-255).
    pub image_noise: f64,
    pub seed: u64,
}

/// Fixed parts of the renderer for one scene.
pub struct Renderer<'w> {
    pub camera: Camera,
    pub width: usize,
    pub height: usize,
    world: &'w World,
    /// Unit ray of each pixel centre in the camera frame; NaN where undistortion fails.
    rays: Vec<[f32; 3]>,
    ground: Texture,
    deck: Option<Texture>,
    pub sun: Vector3<f64>,
    pub image_noise: f64,
    seed: u64,
    gamma: Vec<u8>,
}

/// Everything that changes from frame to frame.
pub struct FrameInput<'a> {
    pub index: usize,
    pub pose: &'a CameraPose,
    /// Bodies, any order.
    pub bodies: &'a [Body],
    pub shadows: &'a [Shadow],
    /// Overall brightness factor.
    pub light: f64,
}

impl<'w> Renderer<'w> {
    /// Prepares rays and bakes textures covering the box the camera will see.
    pub fn new(
        world: &'w World,
        camera: Camera,
        view: (Vector2<f64>, Vector2<f64>),
        settings: &RenderSettings,
    ) -> Renderer<'w> {
        let (view_min, view_max) = view;
        let RenderSettings {
            texel_m,
            sun,
            image_noise,
            seed,
        } = *settings;
        let size = camera.image_size.expect("camera with an image size");
        let (w, h) = (size.width as usize, size.height as usize);
        let mut rays = vec![[f32::NAN; 3]; w * h];
        rays.par_chunks_mut(w).enumerate().for_each(|(v, row)| {
            for (u, r) in row.iter_mut().enumerate() {
                if let Ok(ray) = camera.unproject(&Vector2::new(u as f64, v as f64)) {
                    *r = [ray.x as f32, ray.y as f32, ray.z as f32];
                }
            }
        });
        let ground = Texture::bake(world, Layer::Ground, view_min, view_max, texel_m);
        let deck = match world.ground {
            super::scene::Ground::Deck { .. } => Some(Texture::bake(
                world,
                Layer::Deck,
                view_min,
                view_max,
                texel_m,
            )),
            _ => None,
        };
        let gamma = (0..4096)
            .map(|i| ((i as f64 / 4095.0).powf(1.0 / 2.2) * 255.0).round() as u8)
            .collect();
        Renderer {
            camera,
            width: w,
            height: h,
            world,
            rays,
            ground,
            deck,
            sun,
            image_noise,
            seed,
            gamma,
        }
    }

    /// Change of the pixel-centre ray per pixel along u (`along_u`) or v, by central
    /// differences (one-sided at the edges).
    fn ray_step(&self, u: usize, v: usize, along_u: bool) -> Vector3<f64> {
        let (a, b, span) = if along_u {
            let (a, b) = (u.saturating_sub(1), (u + 1).min(self.width - 1));
            (self.pixel_ray(a, v), self.pixel_ray(b, v), (b - a) as f64)
        } else {
            let (a, b) = (v.saturating_sub(1), (v + 1).min(self.height - 1));
            (self.pixel_ray(u, a), self.pixel_ray(u, b), (b - a) as f64)
        };
        match (a, b) {
            (Some(a), Some(b)) if span > 0.0 => (b - a) / span,
            _ => Vector3::zeros(),
        }
    }

    /// The ray of a pixel centre.
    fn pixel_ray(&self, u: usize, v: usize) -> Option<Vector3<f64>> {
        let a = self.rays[v * self.width + u];
        a[0].is_finite()
            .then(|| Vector3::new(f64::from(a[0]), f64::from(a[1]), f64::from(a[2])))
    }

    fn ground_colour(
        &self,
        origin: &Vector3<f64>,
        dir: &Vector3<f64>,
        shadows: &ShadowGrid,
    ) -> Rgb {
        let Some((p, layer)) = self.world.intersect(origin, dir) else {
            return [0.5, 0.6, 0.75];
        };
        // A photo backdrop is sampled directly: 8-bit linear texels would band its shade.
        let tex = match layer {
            _ if self.world.backdrop.is_some() => None,
            Layer::Deck => self.deck.as_ref(),
            Layer::Ground => Some(&self.ground),
        };
        let albedo = tex
            .and_then(|t| t.sample(&p.xy()))
            .unwrap_or_else(|| self.world.albedo(&p, layer));
        let mut shade = 0.45 + 0.55 * self.sun.z.max(0.0);
        if layer == Layer::Ground && self.world.in_deck_shadow(&p, &self.sun) {
            shade *= 0.5;
        }
        if shadows.covers(&p.xy()) {
            shade *= 0.55;
        }
        albedo.map(|a| a * shade as f32)
    }

    /// Renders one frame as 8-bit RGB, row-major.
    pub fn render(&self, f: &FrameInput) -> Vec<u8> {
        let (w, h) = (self.width, self.height);
        let r_wc = f.pose.world_from_cam;
        let c = f.pose.centre;
        // People far to near, with their image boxes.
        let mut order: Vec<(f64, &Body, [i64; 4])> = f
            .bodies
            .iter()
            .filter_map(|b| {
                // The image box of the body's bounding box corners.
                let (lo, hi) = b.bounds;
                let mut bx = [i64::MAX, i64::MAX, i64::MIN, i64::MIN];
                for k in 0..8 {
                    let p = Vector3::new(
                        if k & 1 == 0 { lo.x } else { hi.x },
                        if k & 2 == 0 { lo.y } else { hi.y },
                        if k & 4 == 0 { lo.z } else { hi.z },
                    );
                    let uv = self.camera.project(&(r_wc.transpose() * (p - c))).ok()?;
                    bx = [
                        bx[0].min(uv.x.floor() as i64 - 2),
                        bx[1].min(uv.y.floor() as i64 - 2),
                        bx[2].max(uv.x.ceil() as i64 + 2),
                        bx[3].max(uv.y.ceil() as i64 + 2),
                    ];
                }
                if bx[2] < 0 || bx[3] < 0 || bx[0] >= w as i64 || bx[1] >= h as i64 {
                    return None;
                }
                Some((((lo + hi) / 2.0 - c).norm(), b, bx))
            })
            .collect();
        order.sort_by(|a, b| b.0.total_cmp(&a.0));
        let light = f.light as f32;
        let shadows = ShadowGrid::new(f.shadows, &self.ground);
        let mut out = vec![0u8; w * h * 3];
        const BAND: usize = 16;
        out.par_chunks_mut(w * 3 * BAND)
            .enumerate()
            .for_each(|(band, chunk)| {
                let v0 = band * BAND;
                let rows = chunk.len() / (w * 3);
                let mut acc: Vec<Rgb> = Vec::with_capacity(w * rows);
                for dv in 0..rows {
                    let v = v0 + dv;
                    for u in 0..w {
                        let colour = match self.pixel_ray(u, v) {
                            Some(ray) => self.ground_colour(&c, &(r_wc * ray), &shadows),
                            None => [0.0, 0.0, 0.0],
                        };
                        acc.push(colour);
                    }
                }
                for (_, body, bx) in &order {
                    let (y0, y1) = (bx[1].max(v0 as i64), bx[3].min((v0 + rows) as i64 - 1));
                    if y0 > y1 {
                        continue;
                    }
                    let (x0, x1) = (bx[0].max(0), bx[2].min(w as i64 - 1));
                    // A pixel's footprint on the person, for the coarse test of its centre ray.
                    let margin = 1.5 * (((body.bounds.0 + body.bounds.1) / 2.0) - c).norm()
                        / self.camera.fx.min(self.camera.fy);
                    for v in y0..=y1 {
                        for u in x0..=x1 {
                            let (uu, vv) = (u as usize, v as usize);
                            let centre = match self.pixel_ray(uu, vv) {
                                Some(ray) if body.may_hit(&c, &(r_wc * ray), margin) => ray,
                                _ => continue,
                            };
                            // Rays of the 4x4 sub-samples from the pixel's ray gradients.
                            let du = self.ray_step(uu, vv, true);
                            let dv = self.ray_step(uu, vv, false);
                            let (mut sum, mut hits) = ([0f32; 3], 0u32);
                            for sy in 0..SS {
                                for sx in 0..SS {
                                    let ox = (f64::from(sx) + 0.5) / f64::from(SS) - 0.5;
                                    let oy = (f64::from(sy) + 0.5) / f64::from(SS) - 0.5;
                                    let ray = (centre + du * ox + dv * oy).normalize();
                                    if let Some(col) = body.hit(&c, &(r_wc * ray), &self.sun) {
                                        for k in 0..3 {
                                            sum[k] += col[k];
                                        }
                                        hits += 1;
                                    }
                                }
                            }
                            if hits > 0 {
                                let n = (SS * SS) as f32;
                                let cov = hits as f32 / n;
                                let px = &mut acc[(v as usize - v0) * w + u as usize];
                                for k in 0..3 {
                                    px[k] = px[k] * (1.0 - cov) + sum[k] / n;
                                }
                            }
                        }
                    }
                }
                for (i, px) in acc.iter().enumerate() {
                    let global = (v0 * w + i) as u64;
                    let n = if self.image_noise > 0.0 {
                        let key = self.seed
                            ^ (f.index as u64).wrapping_mul(0x9E37_79B9_7F4A_7C15)
                            ^ global.wrapping_mul(0xD1B5_4A32_D192_ED03);
                        (gaussian(key) * self.image_noise / 255.0) as f32
                    } else {
                        0.0
                    };
                    for k in 0..3 {
                        let lin = (px[k] * light + n).clamp(0.0, 1.0);
                        chunk[i * 3 + k] = self.gamma[(lin * 4095.0) as usize];
                    }
                }
            });
        out
    }
}
