//! The rectified site image: frames projected onto the ground at a chosen ground sample
//! distance, on a grid of the output CRS (a GeoTIFF that lies under the GeoPackage in QGIS),
//! the median of several frames so that people walking through leave no trace; and PNGs with
//! the trajectories, GCPs, a scale bar and a north arrow.

use nalgebra::{Matrix3, Vector2, Vector3};
use opencv::core::{CV_32FC1, Mat, Scalar};
use opencv::prelude::*;
use rayon::prelude::*;

use super::{ViewError, Views, colour_scale, id_colour};
use crate::draw::Canvas;
use crate::projection::intersect;

impl From<opencv::Error> for ViewError {
    fn from(e: opencv::Error) -> ViewError {
        ViewError::Failed(e.to_string())
    }
}

/// The largest side of the site image, pixels: a coarser GSD is taken beyond it.
const MAX_SIDE: usize = 8000;
/// Frames whose median is the site image.
const FRAMES: usize = 7;

/// The site frame to the output CRS near the site: an affine map fitted to exact conversions
/// on a grid over the site (a projected CRS departs from it by well under a millimetre over
/// a few hundred metres).
#[derive(Clone, Copy, Debug)]
pub struct SiteAffine {
    /// `[x, y] = a · [e, n, 1]`.
    a: Matrix3<f64>,
    inv: Matrix3<f64>,
    /// The largest departure of an exact conversion from the fit, metres.
    pub max_residual_m: f64,
}

impl SiteAffine {
    pub fn identity() -> SiteAffine {
        SiteAffine {
            a: Matrix3::identity(),
            inv: Matrix3::identity(),
            max_residual_m: 0.0,
        }
    }

    /// Fitted to `exact` over the box `lo`–`hi` (a 5 × 5 grid).
    pub fn fit(
        exact: &dyn Fn(&Vector2<f64>) -> Option<Vector2<f64>>,
        lo: &Vector2<f64>,
        hi: &Vector2<f64>,
    ) -> Option<SiteAffine> {
        let mut pairs = Vec::new();
        for i in 0..5 {
            for j in 0..5 {
                let p = Vector2::new(
                    lo.x + (hi.x - lo.x) * f64::from(i) / 4.0,
                    lo.y + (hi.y - lo.y) * f64::from(j) / 4.0,
                );
                pairs.push((p, exact(&p)?));
            }
        }
        // Least squares, centred for conditioning.
        let c_in = pairs.iter().map(|p| p.0).sum::<Vector2<f64>>() / pairs.len() as f64;
        let c_out = pairs.iter().map(|p| p.1).sum::<Vector2<f64>>() / pairs.len() as f64;
        let (mut ata, mut atb) = (nalgebra::Matrix2::zeros(), nalgebra::Matrix2::zeros());
        for (p, q) in &pairs {
            let (dp, dq) = (p - c_in, q - c_out);
            ata += dp * dp.transpose();
            atb += dp * dq.transpose();
        }
        // Degenerate box (one point): translation only.
        let lin = ata
            .try_inverse()
            .map_or(nalgebra::Matrix2::identity(), |inv| (inv * atb).transpose());
        let t = c_out - lin * c_in;
        let a = Matrix3::new(
            lin[(0, 0)],
            lin[(0, 1)],
            t.x,
            lin[(1, 0)],
            lin[(1, 1)],
            t.y,
            0.0,
            0.0,
            1.0,
        );
        let inv = a.try_inverse()?;
        let mut fitted = SiteAffine {
            a,
            inv,
            max_residual_m: 0.0,
        };
        fitted.max_residual_m = pairs
            .iter()
            .map(|(p, q)| (fitted.to_crs(p) - q).norm())
            .fold(0.0, f64::max);
        Some(fitted)
    }

    pub fn to_crs(&self, en: &Vector2<f64>) -> Vector2<f64> {
        (self.a * en.push(1.0)).xy()
    }

    pub(crate) fn to_site(&self, xy: &Vector2<f64>) -> Vector2<f64> {
        (self.inv * xy.push(1.0)).xy()
    }

    /// The rotation from site north to grid north, degrees (positive: grid north is clockwise
    /// of the site frame's north).
    #[cfg(test)]
    pub(crate) fn grid_rotation_deg(&self) -> f64 {
        let n = self.a.fixed_view::<2, 2>(0, 0) * Vector2::new(0.0, 1.0);
        n.x.atan2(n.y).to_degrees()
    }
}

/// The grid of the site image in the output CRS: top-left corner, GSD and size.
#[derive(Clone, Copy, Debug)]
pub struct Grid {
    pub x0: f64,
    pub y_top: f64,
    pub gsd: f64,
    pub width: usize,
    pub height: usize,
}

impl Grid {
    /// A CRS position's pixel (sub-pixel; (0, 0) the centre of the top-left pixel).
    pub fn pixel(&self, xy: &Vector2<f64>) -> Vector2<f64> {
        Vector2::new(
            (xy.x - self.x0) / self.gsd - 0.5,
            (self.y_top - xy.y) / self.gsd - 0.5,
        )
    }

    /// GDAL's geotransform.
    pub fn geo_transform(&self) -> [f64; 6] {
        [self.x0, self.gsd, 0.0, self.y_top, 0.0, -self.gsd]
    }
}

/// A round number (1, 1.5, 2, 2.5, 3, 4, 5, 6 or 8 times a power of ten), at least `v`.
fn nice_up(v: f64) -> f64 {
    let p = 10f64.powf(v.log10().floor());
    [1.0, 1.5, 2.0, 2.5, 3.0, 4.0, 5.0, 6.0, 8.0, 10.0]
        .iter()
        .map(|m| m * p)
        .find(|s| *s >= v * (1.0 - 1e-9))
        .unwrap_or(10.0 * p)
}

/// Frames spread over the run that have a pose: the key frames first.
fn chosen_frames(v: &Views) -> Vec<usize> {
    let posed: Vec<usize> = (0..v.frames.min(v.poses.len()))
        .filter(|&f| v.poses[f].is_some())
        .collect();
    if posed.is_empty() {
        return Vec::new();
    }
    // Centred in equal parts of the run: not the last frame, which OpenCV's seeking misses
    // (the whole video is then read to reach it).
    let mut out: Vec<usize> = (0..FRAMES)
        .map(|k| posed[((2 * k + 1) * posed.len() / (2 * FRAMES)).min(posed.len() - 1)])
        .collect();
    if let Some(k) = v.key_frames.first()
        && posed.contains(k)
    {
        out[0] = *k;
    }
    out.sort_unstable();
    out.dedup();
    out
}

/// Makes `site.tif`, `site.png` and `site_speed.png`; the files and warnings.
pub fn site_image(v: &Views) -> Result<(Vec<(String, String)>, Vec<String>), ViewError> {
    let mut warnings = Vec::new();
    let frames = chosen_frames(v);
    let Some(&first) = frames.first() else {
        return Ok((
            Vec::new(),
            vec!["no site image: no frame has a pose".into()],
        ));
    };
    let (lo, hi) = ground_extent(v, &frames);
    if !(lo.x.is_finite() && hi.x > lo.x && hi.y > lo.y) {
        return Ok((
            Vec::new(),
            vec!["no site image: the image does not reach the ground".into()],
        ));
    }
    let affine = match v.to_crs {
        Some(f) => SiteAffine::fit(f, &lo, &hi).ok_or_else(|| {
            ViewError::Failed("the site's corners have no output-CRS position".into())
        })?,
        None => SiteAffine::identity(),
    };
    let (grid, gsd) = site_grid(v, first, &lo, &hi, &affine, &mut warnings);
    // The ground under each pixel (once: the same for every frame).
    let heights = ground_points(v.ground, &grid, &affine);
    // Each frame on the grid (read by checked seeks), then the median.
    let mut layers = Vec::new();
    let mut failed = None;
    crate::video::source::FrameReader::visit_frames(v.video, &frames, |f, bytes, fw, fh| {
        if failed.is_some() {
            return;
        }
        let pose = v.poses[f].as_ref().expect("chosen frames have poses");
        let layer = Mat::new_rows_cols_with_data(fh as i32, (fw * 3) as i32, bytes)
            .and_then(|m| m.reshape(3, fh as i32).and_then(|m| m.try_clone()))
            .map_err(ViewError::from)
            .and_then(|bgr| rectify(v.camera, pose, v.size, &bgr, &grid, &heights));
        match layer {
            Ok(l) => layers.push(l),
            Err(e) => failed = Some(e),
        }
    })?;
    if let Some(e) = failed {
        return Err(e);
    }
    let (bgr, alpha) = median(&layers, grid.width * grid.height);
    let rgba: Vec<u8> = bgr
        .chunks_exact(3)
        .zip(&alpha)
        .flat_map(|(p, a)| [p[2], p[1], p[0], *a])
        .collect();
    crate::gis::write_geotiff(
        &v.out.join("site.tif"),
        &rgba,
        (grid.width, grid.height),
        grid.geo_transform(),
        &v.crs_wkt,
    )?;
    let mut files = vec![(
        format!(
            "Site image, {} m a pixel, {} ({} frames' median)",
            gsd,
            v.crs_label,
            frames.len()
        ),
        "site.tif".to_string(),
    )];
    // The PNGs: no image where the video did not reach, white.
    let white: Vec<u8> = bgr
        .chunks_exact(3)
        .zip(&alpha)
        .flat_map(|(p, a)| {
            if *a == 0 {
                [255, 255, 255]
            } else {
                [p[0], p[1], p[2]]
            }
        })
        .collect();
    // By identity, then by speed over the speeds' range.
    for speeds in [None, Some(super::speed_range(v.trajs)?)] {
        let mut image = Canvas::from_bgr_bytes(&white, grid.width as u32, grid.height as u32)
            .map_err(|e| ViewError::Image("site".into(), e))?;
        overlay(v, &mut image, &grid, &affine, speeds)?;
        let c = framed(v, image, &grid, speeds)?;
        let (name, title) = match speeds {
            None => ("site.png", "Trajectories on the site, coloured by identity"),
            Some(_) => (
                "site_speed.png",
                "Trajectories on the site, coloured by speed",
            ),
        };
        c.save(&v.out.join(name))
            .map_err(|e| ViewError::Image(name.into(), e))?;
        files.push((title.into(), name.into()));
    }
    Ok((files, warnings))
}

/// The ground seen, as the site frame's box (`lo`, `hi`): the image border unprojected in each
/// chosen frame (an empty box when none reaches the ground).
fn ground_extent(v: &Views, frames: &[usize]) -> (Vector2<f64>, Vector2<f64>) {
    let (w, h) = (f64::from(v.size.0), f64::from(v.size.1));
    let mut border = Vec::new();
    for k in 0..=20 {
        let t = f64::from(k) / 20.0;
        border.extend([
            Vector2::new(t * (w - 1.0), 0.0),
            Vector2::new(t * (w - 1.0), h - 1.0),
            Vector2::new(0.0, t * (h - 1.0)),
            Vector2::new(w - 1.0, t * (h - 1.0)),
        ]);
    }
    let (mut lo, mut hi) = (
        Vector2::repeat(f64::INFINITY),
        Vector2::repeat(f64::NEG_INFINITY),
    );
    for &f in frames {
        let pose = v.poses[f].as_ref().expect("chosen frames have poses");
        for uv in &border {
            if let Some(p) = intersect(v.camera, pose, v.ground, 0.0, uv) {
                lo = lo.inf(&p.xy());
                hi = hi.sup(&p.xy());
            }
        }
    }
    (lo, hi)
}

/// The site image's grid in the output CRS: at the video's ground sample distance at the image
/// centre (rounded up to a nice number) or the project's, coarser when the image would be over
/// `MAX_SIDE` pixels a side; and the GSD taken.
fn site_grid(
    v: &Views,
    first: usize,
    lo: &Vector2<f64>,
    hi: &Vector2<f64>,
    affine: &SiteAffine,
    warnings: &mut Vec<String>,
) -> (Grid, f64) {
    let (w, h) = (f64::from(v.size.0), f64::from(v.size.1));
    // The GSD: the video's at the image centre on the ground, or the project's.
    let pose = v.poses[first].as_ref().expect("has a pose");
    let centre = Vector2::new(w / 2.0, h / 2.0);
    let video_gsd = match (
        intersect(v.camera, pose, v.ground, 0.0, &centre),
        intersect(
            v.camera,
            pose,
            v.ground,
            0.0,
            &(centre + Vector2::new(1.0, 0.0)),
        ),
    ) {
        (Some(a), Some(b)) => (a - b).xy().norm(),
        _ => 0.05,
    };
    let mut gsd = v.settings.site_gsd_m.unwrap_or_else(|| nice_up(video_gsd));
    // The box in the CRS.
    let corners =
        [*lo, Vector2::new(hi.x, lo.y), *hi, Vector2::new(lo.x, hi.y)].map(|p| affine.to_crs(&p));
    let (cx0, cx1) = corners
        .iter()
        .fold((f64::INFINITY, f64::NEG_INFINITY), |a, p| {
            (a.0.min(p.x), a.1.max(p.x))
        });
    let (cy0, cy1) = corners
        .iter()
        .fold((f64::INFINITY, f64::NEG_INFINITY), |a, p| {
            (a.0.min(p.y), a.1.max(p.y))
        });
    let side = ((cx1 - cx0).max(cy1 - cy0)) / gsd;
    if side > MAX_SIDE as f64 {
        let coarser = nice_up((cx1 - cx0).max(cy1 - cy0) / MAX_SIDE as f64);
        warnings.push(format!(
            "site image: {gsd} m would make {side:.0} px; {coarser} m taken (at most {MAX_SIDE} px a side)"
        ));
        gsd = coarser;
    }
    let x0 = (cx0 / gsd).floor() * gsd;
    let y_top = (cy1 / gsd).ceil() * gsd;
    let grid = Grid {
        x0,
        y_top,
        gsd,
        width: ((cx1 - x0) / gsd).ceil() as usize,
        height: ((y_top - cy0) / gsd).ceil() as usize,
    };
    if affine.max_residual_m > gsd / 10.0 {
        warnings.push(format!(
            "site image: the output CRS departs from the site frame's affine map by up to {:.3} m over the site",
            affine.max_residual_m
        ));
    }
    (grid, gsd)
}

/// Pixels between the ground heights computed exactly: a local plane is a robust fit to the
/// model's points around it (16 s for the group demo's 4 Mpix pixel by pixel); in between,
/// bilinear, which is exact for a plane and within a millimetre for the deck's camber and the
/// local planes over 8 pixels (20 cm at the demos' GSD).
const HEIGHT_STEP: usize = 8;

/// Each pixel's point on the ground (site frame), none where the ground model ends.
fn ground_points(
    ground: &dyn crate::terrain::HeightSurface,
    grid: &Grid,
    affine: &SiteAffine,
) -> Vec<Option<Vector3<f64>>> {
    let site = |c: usize, r: usize| {
        affine.to_site(&Vector2::new(
            grid.x0 + (c as f64 + 0.5) * grid.gsd,
            grid.y_top - (r as f64 + 0.5) * grid.gsd,
        ))
    };
    let (nc, nr) = (
        grid.width.div_ceil(HEIGHT_STEP) + 1,
        grid.height.div_ceil(HEIGHT_STEP) + 1,
    );
    let node = |i: usize, j: usize| {
        (
            (i * HEIGHT_STEP).min(grid.width - 1),
            (j * HEIGHT_STEP).min(grid.height - 1),
        )
    };
    let nodes: Vec<Option<f64>> = (0..nc * nr)
        .map(|k| {
            let (c, r) = node(k % nc, k / nc);
            ground.height(&site(c, r))
        })
        .collect();
    (0..grid.width * grid.height)
        .map(|k| {
            let (c, r) = (k % grid.width, k / grid.width);
            let en = site(c, r);
            let (i, j) = (c / HEIGHT_STEP, r / HEIGHT_STEP);
            let corners = [
                nodes[j * nc + i],
                nodes[j * nc + i + 1],
                nodes[(j + 1) * nc + i],
                nodes[(j + 1) * nc + i + 1],
            ];
            let z = match corners {
                [Some(a), Some(b), Some(cz), Some(d)] => {
                    let ((c0, r0), (c1, r1)) = (node(i, j), node(i + 1, j + 1));
                    let tx = if c1 > c0 {
                        (c - c0) as f64 / (c1 - c0) as f64
                    } else {
                        0.0
                    };
                    let ty = if r1 > r0 {
                        (r - r0) as f64 / (r1 - r0) as f64
                    } else {
                        0.0
                    };
                    Some((a * (1.0 - tx) + b * tx) * (1.0 - ty) + (cz * (1.0 - tx) + d * tx) * ty)
                }
                // Near the ground model's edge: exact.
                _ => ground.height(&en),
            };
            z.map(|z| Vector3::new(en.x, en.y, z))
        })
        .collect()
}

/// One frame on the grid (`ground`: each pixel's point on the ground): BGR bytes and whether
/// each pixel was seen.
fn rectify(
    camera: &crate::camera::Camera,
    pose: &crate::geom::Rigid3,
    size: (u32, u32),
    bgr: &Mat,
    grid: &Grid,
    ground: &[Option<Vector3<f64>>],
) -> Result<(Vec<u8>, Vec<bool>), ViewError> {
    let (w, h) = (f64::from(size.0), f64::from(size.1));
    let mut maps = vec![(-1.0f32, -1.0f32); ground.len()];
    maps.par_chunks_mut(grid.width)
        .zip(ground.par_chunks(grid.width))
        .for_each(|(row, points)| {
            for (m, g) in row.iter_mut().zip(points) {
                let Some(g) = g else { continue };
                let p = pose.apply(g);
                if p.z <= 0.0 {
                    continue;
                }
                if let Ok(uv) = camera.project(&p)
                    && uv.x >= 0.0
                    && uv.y >= 0.0
                    && uv.x <= w - 1.0
                    && uv.y <= h - 1.0
                {
                    *m = (uv.x as f32, uv.y as f32);
                }
            }
        });
    let rows = grid.height as i32;
    let cols = grid.width as i32;
    let mut map_x = Mat::new_rows_cols_with_default(rows, cols, CV_32FC1, Scalar::all(-1.0))?;
    let mut map_y = Mat::new_rows_cols_with_default(rows, cols, CV_32FC1, Scalar::all(-1.0))?;
    {
        let mx: &mut [f32] = map_x.data_typed_mut()?;
        let my: &mut [f32] = map_y.data_typed_mut()?;
        for (k, (x, y)) in maps.iter().enumerate() {
            mx[k] = *x;
            my[k] = *y;
        }
    }
    let mut out = Mat::default();
    opencv::imgproc::remap(
        bgr,
        &mut out,
        &map_x,
        &map_y,
        opencv::imgproc::INTER_LINEAR,
        opencv::core::BORDER_CONSTANT,
        Scalar::all(0.0),
    )?;
    let seen = maps.iter().map(|m| m.0 >= 0.0).collect();
    Ok((out.data_bytes()?.to_vec(), seen))
}

/// The per-pixel median of the frames that saw each pixel; alpha 255 where any did.
fn median(layers: &[(Vec<u8>, Vec<bool>)], n: usize) -> (Vec<u8>, Vec<u8>) {
    let mut bgr = vec![0u8; n * 3];
    let mut alpha = vec![0u8; n];
    bgr.par_chunks_mut(3)
        .zip(alpha.par_iter_mut())
        .enumerate()
        .for_each(|(k, (px, a))| {
            let mut vals: [Vec<u8>; 3] = Default::default();
            for (img, seen) in layers {
                if seen[k] {
                    for ch in 0..3 {
                        vals[ch].push(img[3 * k + ch]);
                    }
                }
            }
            if vals[0].is_empty() {
                return;
            }
            *a = 255;
            for ch in 0..3 {
                vals[ch].sort_unstable();
                px[ch] = vals[ch][(vals[ch].len() - 1) / 2];
            }
        });
    (bgr, alpha)
}

/// Trajectories (by identity, or by speed over `speeds`: slowest and fastest, m/s) and GCPs.
fn overlay(
    v: &Views,
    c: &mut Canvas,
    grid: &Grid,
    affine: &SiteAffine,
    speeds: Option<(f64, f64)>,
) -> Result<(), ViewError> {
    let im = |e| ViewError::Image("site".into(), e);
    let px = |local: &Vector3<f64>| grid.pixel(&affine.to_crs(&local.xy()));
    let thick = ((grid.width.max(grid.height) as f64 / 1000.0).round() as i32).max(1);
    v.trajs.each(&mut |t| {
        if let Some((slow, fast)) = speeds {
            for w in t.points.windows(2) {
                let s = (w[1].velocity.norm() - slow) / (fast - slow);
                c.line(&px(&w[0].local), &px(&w[1].local), colour_scale(s), thick)
                    .map_err(im)?;
            }
        } else {
            let pts: Vec<Vector2<f64>> = t.points.iter().map(|p| px(&p.local)).collect();
            c.polyline(&pts, id_colour(t.id), thick).map_err(im)?;
            if let Some(end) = pts.last() {
                c.text(
                    &(end + Vector2::new(4.0, -4.0)),
                    &t.id.to_string(),
                    0.4 * f64::from(thick),
                    id_colour(t.id),
                    1,
                )
                .map_err(im)?;
            }
        }
        Ok(())
    })?;
    for g in &v.gcps {
        let p = px(&g.local);
        let rgb = if g.control {
            [40, 220, 40]
        } else {
            [255, 150, 0]
        };
        let r = (0.5 / grid.gsd).max(6.0);
        c.circle(&p, r, rgb, thick).map_err(im)?;
        c.cross(&p, r * 0.6, rgb, 1).map_err(im)?;
        c.text(
            &(p + Vector2::new(r + 3.0, -3.0)),
            &g.name,
            0.45 * f64::from(thick),
            rgb,
            1,
        )
        .map_err(im)?;
    }
    Ok(())
}

/// The image with a title above it and a scale bar and north arrow below it (outside the
/// image, which a narrow deck would not leave room for).
fn framed(
    v: &Views,
    image: Canvas,
    grid: &Grid,
    speeds: Option<(f64, f64)>,
) -> Result<Canvas, ViewError> {
    let im = |e| ViewError::Image("site".into(), e);
    let (top, bottom) = (34, 70);
    let width = grid.width.max(700) as u32;
    let mut c =
        Canvas::blank(width, grid.height as u32 + top + bottom, [255, 255, 255]).map_err(im)?;
    c.paste(&image, 0, top as i32).map_err(im)?;
    let title = format!(
        "{}: {} trajectories on the ground, {} m a pixel",
        v.title,
        v.trajs.count(),
        grid.gsd
    );
    c.text(&Vector2::new(8.0, 22.0), &title, 0.55, [0, 0, 0], 1)
        .map_err(im)?;
    // Scale bar: a round length near a fifth of the image's width, bottom left.
    let y = f64::from(top) + grid.height as f64 + 30.0;
    let width_m = grid.width as f64 * grid.gsd;
    let mut bar_m = nice_up(width_m / 5.0);
    if bar_m > width_m / 3.0 {
        bar_m /= 2.0;
    }
    let bar_px = bar_m / grid.gsd;
    c.fill_rect(10, y as i32 - 6, (bar_px / 2.0) as i32, 8, [0, 0, 0])
        .map_err(im)?;
    c.fill_rect(
        10 + (bar_px / 2.0) as i32,
        y as i32 - 6,
        (bar_px / 2.0) as i32,
        8,
        [160, 160, 160],
    )
    .map_err(im)?;
    c.text(
        &Vector2::new(16.0 + bar_px, y + 2.0),
        &format!("{bar_m} m"),
        0.5,
        [0, 0, 0],
        1,
    )
    .map_err(im)?;
    // North arrow (the grid's north is up) and the CRS.
    let x = f64::from(width) - 40.0;
    c.arrow(
        &Vector2::new(x, y + 28.0),
        &Vector2::new(x, y - 18.0),
        [0, 0, 0],
        2,
    )
    .map_err(im)?;
    c.text(&Vector2::new(x + 8.0, y - 2.0), "N", 0.6, [0, 0, 0], 2)
        .map_err(im)?;
    let note = if let Some((slow, fast)) = speeds {
        format!(
            "speed: {slow:.1} m/s (dark) to {fast:.1} m/s (red); grid north of {}",
            v.crs_label
        )
    } else {
        format!(
            "colour: identity; green: control GCPs, orange: check; grid north of {}",
            v.crs_label
        )
    };
    let note_x = 30.0 + bar_px + 60.0;
    c.text(&Vector2::new(note_x, y + 2.0), &note, 0.42, [0, 0, 0], 1)
        .map_err(im)?;
    Ok(c)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn an_affine_map_is_recovered_and_inverted() {
        let exact = |p: &Vector2<f64>| {
            Some(Vector2::new(
                1000.0 + 0.9996 * (p.x * 0.99 - p.y * 0.14),
                5000.0 + 0.9996 * (p.x * 0.14 + p.y * 0.99),
            ))
        };
        let a = SiteAffine::fit(
            &exact,
            &Vector2::new(-50.0, -20.0),
            &Vector2::new(50.0, 20.0),
        )
        .unwrap();
        assert!(a.max_residual_m < 1e-9);
        let p = Vector2::new(12.0, -7.0);
        assert!((a.to_crs(&p) - exact(&p).unwrap()).norm() < 1e-9);
        assert!((a.to_site(&a.to_crs(&p)) - p).norm() < 1e-9);
        assert!((a.grid_rotation_deg() + 0.14f64.atan2(0.99).to_degrees()).abs() < 1e-6);
    }

    /// A gently curved ground that ends at e = 3.3 m.
    struct Curved;

    impl crate::terrain::HeightSurface for Curved {
        fn height(&self, en: &Vector2<f64>) -> Option<f64> {
            (en.x < 3.3).then(|| 0.01 * en.x + 0.02 * en.y + 0.001 * en.x * en.y)
        }
    }

    #[test]
    fn ground_heights_between_nodes_match_the_surface_and_its_edge() {
        let grid = Grid {
            x0: -1.0,
            y_top: 2.0,
            gsd: 0.05,
            width: 101,
            height: 37,
        };
        let affine = SiteAffine::identity();
        let points = ground_points(&Curved, &grid, &affine);
        for (k, p) in points.iter().enumerate() {
            let (c, r) = (k % grid.width, k / grid.width);
            let en = Vector2::new(
                -1.0 + (c as f64 + 0.5) * 0.05,
                2.0 - (r as f64 + 0.5) * 0.05,
            );
            match (p, crate::terrain::HeightSurface::height(&Curved, &en)) {
                (Some(p), Some(z)) => {
                    assert!((p.xy() - en).norm() < 1e-12);
                    // Bilinear over 0.4 m of a surface with a 0.001 m/m² twist: exact.
                    assert!((p.z - z).abs() < 1e-9, "{c},{r}: {} against {z}", p.z);
                }
                (None, None) => {}
                other => panic!("{c},{r}: {other:?}"),
            }
        }
    }

    #[test]
    fn grid_pixels_and_nice_steps() {
        let g = Grid {
            x0: 100.0,
            y_top: 50.0,
            gsd: 0.5,
            width: 10,
            height: 8,
        };
        // The centre of the top-left pixel.
        assert_eq!(
            g.pixel(&Vector2::new(100.25, 49.75)),
            Vector2::new(0.0, 0.0)
        );
        assert_eq!(g.geo_transform(), [100.0, 0.5, 0.0, 50.0, 0.0, -0.5]);
        assert_eq!(nice_up(0.0193), 0.02);
        assert_eq!(nice_up(0.02), 0.02);
        assert_eq!(nice_up(0.031), 0.04);
        assert_eq!(nice_up(0.0215), 0.025);
    }
}
