//! `topview.png`: the sparse points from above, coloured by height, the cameras with their
//! viewing directions, the surveyed points and a scale bar (drawing through `draw`, OpenCV).
//! In a site or east-north-up frame north is up; in the arbitrary frame of an unplaced model the
//! view looks along the points' direction of least spread.

use std::path::Path;

use nalgebra::{Matrix3, Vector2, Vector3};

use super::georef::PointRole;
use super::job::SfmRun;
use crate::draw::Canvas;
use crate::imageio::ImageError;

/// Longer side of the image, pixels.
const SIZE_PX: f64 = 1600.0;
const MARGIN_PX: f64 = 60.0;

/// Axes of the view: rows are right, up (on the page) and towards the viewer.
fn view_axes(run: &SfmRun) -> Matrix3<f64> {
    if run.report.frame != "model" {
        return Matrix3::identity();
    }
    let pts: Vec<Vector3<f64>> = run.reconstruction.points.iter().map(|p| p.xyz).collect();
    if pts.len() < 3 {
        return Matrix3::identity();
    }
    let mean = pts.iter().sum::<Vector3<f64>>() / pts.len() as f64;
    let cov = pts
        .iter()
        .map(|p| (p - mean) * (p - mean).transpose())
        .sum::<Matrix3<f64>>();
    let eig = cov.symmetric_eigen();
    let mut order = [0, 1, 2];
    order.sort_by(|&a, &b| eig.eigenvalues[b].total_cmp(&eig.eigenvalues[a]));
    let x = eig.eigenvectors.column(order[0]).into_owned();
    let mut z = eig.eigenvectors.column(order[2]).into_owned();
    // The viewer on the cameras' side.
    let cams: Vec<Vector3<f64>> = run
        .reconstruction
        .poses
        .iter()
        .flatten()
        .map(|p| p.centre())
        .collect();
    if !cams.is_empty() {
        let c = cams.iter().sum::<Vector3<f64>>() / cams.len() as f64;
        if (c - mean).dot(&z) < 0.0 {
            z = -z;
        }
    }
    let y = z.cross(&x);
    Matrix3::from_rows(&[x.transpose(), y.transpose(), z.transpose()])
}

/// A blue (low) to red (high) ramp.
fn ramp(t: f64) -> [u8; 3] {
    crate::draw::ramp_colour(
        &[
            [49.0, 54.0, 149.0],
            [69.0, 117.0, 180.0],
            [171.0, 217.0, 233.0],
            [254.0, 224.0, 144.0],
            [244.0, 109.0, 67.0],
            [165.0, 0.0, 38.0],
        ],
        t,
    )
}

fn percentile(v: &mut [f64], q: f64) -> f64 {
    v.sort_by(f64::total_cmp);
    v[((v.len() - 1) as f64 * q).round() as usize]
}

/// A round length near `x`: 1, 2 or 5 times a power of ten.
fn round_length(x: f64) -> f64 {
    let p = 10f64.powf(x.log10().floor());
    [5.0, 2.0, 1.0]
        .into_iter()
        .map(|m| m * p)
        .find(|&l| l <= x)
        .unwrap_or(p)
}

/// The view's extent: the points' 1st to 99th percentiles and every camera (a unit square when
/// there is nothing).
fn extent(
    pts: &[Vector3<f64>],
    cams: &[(usize, Vector3<f64>, Vector3<f64>)],
) -> (Vector2<f64>, Vector2<f64>) {
    let (mut lo, mut hi) = (
        Vector2::repeat(f64::INFINITY),
        Vector2::repeat(f64::NEG_INFINITY),
    );
    for d in 0..2 {
        if pts.len() >= 10 {
            let mut v: Vec<f64> = pts.iter().map(|p| p[d]).collect();
            lo[d] = percentile(&mut v, 0.01);
            hi[d] = percentile(&mut v, 0.99);
        }
        for (_, c, _) in cams {
            lo[d] = lo[d].min(c[d]);
            hi[d] = hi[d].max(c[d]);
        }
    }
    if !lo.iter().all(|v| v.is_finite()) {
        lo = Vector2::new(-1.0, -1.0);
        hi = Vector2::new(1.0, 1.0);
    }
    (lo, hi)
}

/// The surveyed points at their surveyed positions (only in the site frame), `to_px` from the
/// site frame to the canvas.
fn draw_surveyed(
    canvas: &mut Canvas,
    run: &SfmRun,
    to_px: &dyn Fn(&Vector3<f64>) -> Vector2<f64>,
) -> Result<(), ImageError> {
    if let Some(g) = &run.report.georef {
        for p in &g.points {
            let q = to_px(&Vector3::from(p.position_m));
            let colour = match p.role {
                PointRole::Control => [255, 60, 60],
                PointRole::Check => [80, 200, 255],
            };
            let a = 8.0;
            let tri = [
                q + Vector2::new(0.0, -a),
                q + Vector2::new(a * 0.87, a * 0.5),
                q + Vector2::new(-a * 0.87, a * 0.5),
            ];
            for k in 0..3 {
                canvas.line(&tri[k], &tri[(k + 1) % 3], colour, 2)?;
            }
            canvas.text(&(q + Vector2::new(10.0, 12.0)), &p.name, 0.45, colour, 1)?;
        }
    }
    Ok(())
}

/// Draws the top view of `run` (with its surveyed points' adjusted positions when
/// georeferenced) into `path`.
pub fn write_topview(path: &Path, run: &SfmRun) -> Result<(), ImageError> {
    let axes = view_axes(run);
    let r = &run.reconstruction;
    let view = |p: &Vector3<f64>| axes * p;
    let pts: Vec<Vector3<f64>> = r.points.iter().map(|p| view(&p.xyz)).collect();
    let cams: Vec<(usize, Vector3<f64>, Vector3<f64>)> = r
        .poses
        .iter()
        .enumerate()
        .filter_map(|(i, p)| {
            let p = (*p)?;
            let axis = p.rotation.inverse() * Vector3::z();
            Some((i, view(&p.centre()), axes * axis))
        })
        .collect();
    let (lo, hi) = extent(&pts, &cams);
    let span = (hi - lo).map(|v| v.max(1e-6));
    let scale = (SIZE_PX - 2.0 * MARGIN_PX) / span.x.max(span.y);
    let w = (span.x * scale + 2.0 * MARGIN_PX).round().max(400.0);
    let h = (span.y * scale + 2.0 * MARGIN_PX + 40.0).round().max(300.0);
    let to_px = |p: &Vector3<f64>| {
        Vector2::new(
            MARGIN_PX + (p.x - lo.x) * scale,
            h - 40.0 - MARGIN_PX - (p.y - lo.y) * scale,
        )
    };
    let mut canvas = Canvas::blank(w as u32, h as u32, [24, 24, 28])?;
    // Points by height, low first so that the high ones stay visible.
    let unit = if run.report.frame == "model" {
        "model units"
    } else {
        "m"
    };
    if !pts.is_empty() {
        let mut zs: Vec<f64> = pts.iter().map(|p| p.z).collect();
        let z_lo = percentile(&mut zs, 0.02);
        let z_hi = percentile(&mut zs, 0.98);
        // The colour bar.
        let x0 = w - 260.0;
        for k in 0..200 {
            let t = f64::from(k) / 199.0;
            canvas.fill_rect(x0 as i32 + k, (h - 40.0) as i32, 1, 12, ramp(t))?;
        }
        let label = format!("height {z_lo:.1} to {z_hi:.1} {unit}");
        canvas.text(
            &Vector2::new(x0, h - 46.0),
            &label,
            0.45,
            [255, 255, 255],
            1,
        )?;
        let mut order: Vec<usize> = (0..pts.len()).collect();
        order.sort_by(|&a, &b| pts[a].z.total_cmp(&pts[b].z));
        let step = (pts.len() / 200_000).max(1);
        for &k in order.iter().step_by(step) {
            let q = to_px(&pts[k]);
            if q.x < 0.0 || q.y < 0.0 || q.x >= w || q.y >= h {
                continue;
            }
            let t = (pts[k].z - z_lo) / (z_hi - z_lo).max(1e-9);
            canvas.fill_rect(q.x as i32 - 1, q.y as i32 - 1, 2, 2, ramp(t))?;
        }
    }
    // Cameras: a dot and the direction they look in, shortened by how steeply they look down.
    let arm = 0.04 * (SIZE_PX - 2.0 * MARGIN_PX);
    for (i, c, axis) in &cams {
        let q = to_px(c);
        let d = Vector2::new(axis.x, -axis.y);
        canvas.line(&q, &(q + d * arm), [255, 255, 255], 1)?;
        canvas.circle(&q, 5.0, [255, 255, 255], -1)?;
        canvas.circle(&q, 5.0, [0, 0, 0], 1)?;
        canvas.text(
            &(q + Vector2::new(7.0, -7.0)),
            &format!("{}", i + 1),
            0.4,
            [255, 255, 255],
            1,
        )?;
    }
    draw_surveyed(&mut canvas, run, &|p| to_px(&view(p)))?;
    // Scale bar, north arrow and a caption.
    let unit = if run.report.frame == "model" {
        "model units"
    } else {
        "m"
    };
    let bar = round_length(span.x.max(span.y) / 5.0);
    let y = h - 30.0;
    let a = Vector2::new(MARGIN_PX, y);
    let b = Vector2::new(MARGIN_PX + bar * scale, y);
    canvas.line(&a, &b, [255, 255, 255], 3)?;
    canvas.text(
        &(a + Vector2::new(0.0, -8.0)),
        &format!("{bar} {unit}"),
        0.5,
        [255, 255, 255],
        1,
    )?;
    if run.report.frame != "model" {
        let base = Vector2::new(w - 40.0, 80.0);
        canvas.arrow(&base, &(base - Vector2::new(0.0, 50.0)), [255, 255, 255], 2)?;
        canvas.text(
            &(base + Vector2::new(-6.0, 22.0)),
            "N",
            0.6,
            [255, 255, 255],
            2,
        )?;
    }
    let rep = &run.report;
    let caption = format!(
        "{} of {} images registered, {} points, frame: {}{}",
        rep.registered,
        rep.images,
        rep.points,
        rep.frame,
        if rep.registered < rep.images {
            " (unregistered images are not drawn)"
        } else {
            ""
        }
    );
    canvas.text(
        &Vector2::new(MARGIN_PX, 30.0),
        &caption,
        0.6,
        [255, 255, 255],
        1,
    )?;
    canvas.save(path)
}
