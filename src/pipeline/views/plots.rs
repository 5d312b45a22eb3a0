//! The run report's plots: speeds, people in view, σ over the image, the fundamental diagram.

use std::path::Path;

use nalgebra::Vector2;

use super::{ViewError, Views, colour_scale};
use crate::analysis::{self, FrameMeasures};
use crate::draw::{Canvas, Chart, Series, Style, line_chart};
use crate::export::rms_sigma;

const BLUE: [u8; 3] = [40, 100, 180];
const ORANGE: [u8; 3] = [230, 120, 30];
const GREY: [u8; 3] = [120, 120, 120];

fn save(c: &Canvas, out: &Path, name: &str) -> Result<String, ViewError> {
    let rel = format!("plots/{name}");
    c.save(&out.join(&rel))
        .map_err(|e| ViewError::Image(rel.clone(), e))?;
    Ok(rel)
}

/// Histogram of the speed of every trajectory point (the smoother's), 0.1 m/s bins.
pub(crate) fn speed_plot(v: &Views) -> Result<(String, String), ViewError> {
    // The quantiles in a few passes, then the counts in one: the speeds are not all held.
    let (q, n) = super::speed_quantiles(v.trajs, &[0.5, 0.995])?;
    // No person runs 50 m/s: the scale ends there whatever a wild point says.
    let (median, top) = (q[0], q[1].clamp(0.5, 50.0));
    let bin = if top > 6.0 { 0.2 } else { 0.1 };
    let bins = ((top / bin).ceil() as usize).max(1);
    let mut counts = vec![0usize; bins];
    v.trajs.each(&mut |t| {
        let speeds = t.points.iter().map(|p| p.velocity.norm());
        let c = analysis::histogram(speeds, 0.0, bins as f64 * bin, bins);
        counts.iter_mut().zip(c).for_each(|(a, b)| *a += b);
        Ok(())
    })?;
    let chart = Chart {
        title: format!("Speeds ({n} points, median {median:.2} m/s)"),
        x_label: "speed, m/s".into(),
        y_label: "points".into(),
        series: vec![Series {
            label: format!("{bin} m/s bins"),
            xy: counts
                .iter()
                .enumerate()
                .map(|(k, c)| ((k as f64 + 0.5) * bin, *c as f64))
                .collect(),
            rgb: BLUE,
            style: Style::Bars,
        }],
        x_from_zero: true,
        ..Chart::default()
    };
    let c = line_chart(&chart, 900, 450).map_err(|e| ViewError::Image("speed".into(), e))?;
    Ok(("Speed distribution".into(), save(&c, v.out, "speed.png")?))
}

/// People in view frame by frame: with a trajectory point, and with a detection.
pub(crate) fn people_plot(v: &Views) -> Result<(String, String), ViewError> {
    let frames = v.frames.max(1);
    let (mut all, mut seen) = (vec![0usize; frames], vec![0usize; frames]);
    v.trajs.each(&mut |t| {
        for p in &t.points {
            if p.frame < frames {
                all[p.frame] += 1;
                seen[p.frame] += usize::from(p.observed);
            }
        }
        Ok(())
    })?;
    let series = |counts: &[usize], label: &str, rgb, style| Series {
        label: label.into(),
        xy: counts
            .iter()
            .enumerate()
            .map(|(f, c)| (f as f64 / v.fps, *c as f64))
            .collect(),
        rgb,
        style,
    };
    let most = all.iter().copied().max().unwrap_or(0);
    let chart = Chart {
        title: format!(
            "People in view ({} tracks, at most {most} at once)",
            v.trajs.count()
        ),
        x_label: "time, s".into(),
        y_label: "people".into(),
        series: vec![
            series(&all, "trajectories", [30, 30, 30], Style::Line),
            series(&seen, "detected", ORANGE, Style::Dashed),
        ],
        ticks: v.key_frames.iter().map(|f| *f as f64 / v.fps).collect(),
        ticks_label: "key frames".into(),
        ..Chart::default()
    };
    let c = line_chart(&chart, 900, 400).map_err(|e| ViewError::Image("people".into(), e))?;
    Ok(("People in view".into(), save(&c, v.out, "people.png")?))
}

/// Median σ (total, per axis) of the points in each cell of a grid over the image: where in
/// the frame the positions are least sure.
pub(crate) fn sigma_plot(v: &Views) -> Result<(String, String), ViewError> {
    let (w, h) = (f64::from(v.size.0), f64::from(v.size.1));
    let cols = 16usize;
    let rows = ((cols as f64 * h / w).round() as usize).max(1);
    // Each cell's median in a few passes over the points (not every σ held).
    let cell_of = |frame: usize, local: &nalgebra::Vector3<f64>| -> Option<usize> {
        let uv = v.image_point(frame, local)?;
        if !(uv.x >= 0.0 && uv.y >= 0.0 && uv.x < w && uv.y < h) {
            return None;
        }
        let (c, r) = (
            (uv.x / w * cols as f64) as usize,
            (uv.y / h * rows as f64) as usize,
        );
        Some(r.min(rows - 1) * cols + c.min(cols - 1))
    };
    let queries: Vec<(usize, f64)> = (0..cols * rows).map(|c| (c, 0.5)).collect();
    let (medians, counts) = analysis::quantiles_by_passes(cols * rows, &queries, &mut |f| {
        v.trajs.each(&mut |t| {
            for p in &t.points {
                if let Some(c) = cell_of(p.frame, &p.local) {
                    f(c, rms_sigma(&p.cov.total()));
                }
            }
            Ok(())
        })
    })?;
    let medians: Vec<f64> = medians
        .into_iter()
        .zip(&counts)
        .map(|(m, &n)| if n < 5 { f64::NAN } else { m })
        .collect();
    let finite: Vec<f64> = medians.iter().copied().filter(|m| m.is_finite()).collect();
    let lo = finite.iter().copied().fold(f64::INFINITY, f64::min);
    let hi = finite.iter().copied().fold(0.0, f64::max);
    let (lo, hi) = if lo.is_finite() && hi > lo {
        (lo, hi)
    } else {
        (0.0, hi.max(0.01))
    };
    // The image at 960 px wide, a colour bar beside it.
    let pw = 960.0;
    let ph = (pw * h / w).round();
    let (left, top) = (20.0, 50.0);
    let mut c = Canvas::blank(
        (left + pw + 140.0) as u32,
        (top + ph + 40.0) as u32,
        [255; 3],
    )
    .map_err(|e| ViewError::Image("sigma".into(), e))?;
    let im = |e| ViewError::Image("sigma".into(), e);
    let (cw, ch) = (pw / cols as f64, ph / rows as f64);
    for r in 0..rows {
        for k in 0..cols {
            let m = medians[r * cols + k];
            let (x, y) = (left + k as f64 * cw, top + r as f64 * ch);
            let rgb = if m.is_finite() {
                colour_scale((m - lo) / (hi - lo))
            } else {
                [235, 235, 235]
            };
            c.fill_rect(
                x.round() as i32,
                y.round() as i32,
                ((x + cw).round() - x.round()) as i32,
                ((y + ch).round() - y.round()) as i32,
                rgb,
            )
            .map_err(im)?;
            if m.is_finite() {
                let s = format!("{:.1}", m * 100.0);
                c.text(
                    &Vector2::new(x + 6.0, y + ch / 2.0 + 5.0),
                    &s,
                    0.4,
                    [255, 255, 255],
                    1,
                )
                .map_err(im)?;
            }
        }
    }
    let bx = left + pw + 30.0;
    for k in 0..100 {
        let t = 1.0 - k as f64 / 99.0;
        let y = top + k as f64 / 100.0 * ph;
        c.fill_rect(
            bx as i32,
            y as i32,
            20,
            (ph / 100.0).ceil() as i32 + 1,
            colour_scale(t),
        )
        .map_err(im)?;
    }
    for (t, y) in [(hi, top + 10.0), (lo, top + ph)] {
        c.text(
            &Vector2::new(bx + 26.0, y),
            &format!("{:.1} cm", t * 100.0),
            0.45,
            [0, 0, 0],
            1,
        )
        .map_err(im)?;
    }
    c.text(
        &Vector2::new(left, 30.0),
        &format!(
            "Median sigma per axis (cm) of the points seen in each part of the image ({cols} x {rows} cells; grey: under 5 points)"
        ),
        0.5,
        [0, 0, 0],
        1,
    )
    .map_err(im)?;
    Ok((
        "Sigma over the image".into(),
        save(&c, v.out, "sigma_image.png")?,
    ))
}

/// The fundamental diagram: Voronoi density against Voronoi speed in the measurement area,
/// one dot a frame (the classic density beside it in grey).
pub(crate) fn fundamental_plot(
    v: &Views,
    measures: &[FrameMeasures],
    area_m2: f64,
) -> Result<(String, String), ViewError> {
    let dots = |f: &dyn Fn(&FrameMeasures) -> (f64, f64)| -> Vec<(f64, f64)> {
        measures.iter().filter(|m| m.inside > 0).map(f).collect()
    };
    let chart = Chart {
        title: format!(
            "Fundamental diagram ({area_m2:.1} m2, {} frames)",
            measures.iter().filter(|m| m.inside > 0).count()
        ),
        x_label: "density, 1/m2".into(),
        y_label: "speed, m/s".into(),
        series: vec![
            Series {
                label: "classic density, mean speed".into(),
                xy: dots(&|m| (m.classic_density, m.mean_speed)),
                rgb: GREY,
                style: Style::Dots,
            },
            Series {
                label: "Voronoi density and speed".into(),
                xy: dots(&|m| (m.voronoi_density, m.voronoi_speed)),
                rgb: BLUE,
                style: Style::Dots,
            },
        ],
        x_from_zero: true,
        ..Chart::default()
    };
    let c = line_chart(&chart, 800, 520).map_err(|e| ViewError::Image("fundamental".into(), e))?;
    Ok((
        "Fundamental diagram".into(),
        save(&c, v.out, "fundamental.png")?,
    ))
}

/// The measures frame by frame as CSV.
pub(crate) fn measures_csv(measures: &[FrameMeasures]) -> String {
    use std::fmt::Write as _;
    let mut s = String::from(
        "frame,time_s,people,inside,classic_density_1_m2,voronoi_density_1_m2,mean_speed_m_s,voronoi_speed_m_s\n",
    );
    for m in measures {
        let _ = writeln!(
            s,
            "{},{:.4},{},{},{:.6},{:.6},{},{:.6}",
            m.frame,
            m.time_s,
            m.people,
            m.inside,
            m.classic_density,
            m.voronoi_density,
            if m.mean_speed.is_finite() {
                format!("{:.6}", m.mean_speed)
            } else {
                String::new()
            },
            m.voronoi_speed
        );
    }
    s
}
