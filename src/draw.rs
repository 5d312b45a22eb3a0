//! Annotated images and simple charts (OpenCV adapter): a canvas to draw on in pixel
//! coordinates (sub-pixel, (0, 0) the centre of the top-left pixel), and a line chart.

use crate::imageio::{ImageError, file_error};
use std::path::Path;

use nalgebra::Vector2;
use opencv::core::{CV_8UC3, Mat, Point, Rect, Scalar, Size};
use opencv::imgproc;
use opencv::prelude::*;

/// Sub-pixel bits for OpenCV's drawing functions.
const SHIFT: i32 = 4;

fn pt(p: &Vector2<f64>) -> Point {
    let s = f64::from(1 << SHIFT);
    Point::new((p.x * s).round() as i32, (p.y * s).round() as i32)
}

fn colour(rgb: [u8; 3]) -> Scalar {
    Scalar::new(f64::from(rgb[2]), f64::from(rgb[1]), f64::from(rgb[0]), 0.0)
}

fn err(e: opencv::Error) -> ImageError {
    ImageError::OpenCv(e)
}

/// An 8-bit colour image to draw on.
pub struct Canvas {
    mat: Mat,
}

impl Canvas {
    /// Reads an image file (any format OpenCV decodes) in colour.
    pub fn read(path: &Path) -> Result<Canvas, ImageError> {
        let name = path
            .to_str()
            .ok_or_else(|| file_error(path, "not a UTF-8 path"))?;
        crate::imageheader::check_file(path).map_err(|e| file_error(path, e))?;
        let mat = opencv::imgcodecs::imread(name, opencv::imgcodecs::IMREAD_COLOR)
            .map_err(|e| file_error(path, e))?;
        if mat.empty() {
            return Err(file_error(path, "not an image OpenCV can read"));
        }
        Ok(Canvas { mat })
    }

    /// A canvas from an OpenCV colour (BGR) image.
    pub(crate) fn from_bgr(mat: Mat) -> Canvas {
        Canvas { mat }
    }

    /// A canvas from tightly packed BGR bytes (a frame as pure code holds it).
    pub fn from_bgr_bytes(bgr: &[u8], width: u32, height: u32) -> Result<Canvas, ImageError> {
        let mut mat = Mat::new_rows_cols_with_default(
            height as i32,
            width as i32,
            CV_8UC3,
            opencv::core::Scalar::all(0.0),
        )
        .map_err(err)?;
        let dst = mat.data_bytes_mut().map_err(err)?;
        if dst.len() != bgr.len() {
            return Err(err(opencv::Error::new(
                opencv::core::StsBadArg,
                format!("{} bytes for a {width}x{height} BGR image", bgr.len()),
            )));
        }
        dst.copy_from_slice(bgr);
        Ok(Canvas { mat })
    }

    /// A plain canvas.
    pub(crate) fn blank(width: u32, height: u32, rgb: [u8; 3]) -> Result<Canvas, ImageError> {
        let mat =
            Mat::new_rows_cols_with_default(height as i32, width as i32, CV_8UC3, colour(rgb))
                .map_err(err)?;
        Ok(Canvas { mat })
    }

    pub fn width(&self) -> u32 {
        self.mat.cols() as u32
    }

    pub fn height(&self) -> u32 {
        self.mat.rows() as u32
    }

    pub fn line(
        &mut self,
        a: &Vector2<f64>,
        b: &Vector2<f64>,
        rgb: [u8; 3],
        thickness: i32,
    ) -> Result<(), ImageError> {
        imgproc::line(
            &mut self.mat,
            pt(a),
            pt(b),
            colour(rgb),
            thickness,
            imgproc::LINE_AA,
            SHIFT,
        )
        .map_err(err)
    }

    /// A dashed line, `dash` pixels on and off.
    pub(crate) fn dashed_line(
        &mut self,
        a: &Vector2<f64>,
        b: &Vector2<f64>,
        rgb: [u8; 3],
        thickness: i32,
        dash: f64,
    ) -> Result<(), ImageError> {
        let len = (b - a).norm();
        let steps = (len / dash).ceil().max(1.0) as usize;
        for k in (0..steps).step_by(2) {
            let t0 = k as f64 / steps as f64;
            let t1 = ((k + 1) as f64 / steps as f64).min(1.0);
            self.line(&(a + (b - a) * t0), &(a + (b - a) * t1), rgb, thickness)?;
        }
        Ok(())
    }

    pub fn circle(
        &mut self,
        c: &Vector2<f64>,
        radius: f64,
        rgb: [u8; 3],
        thickness: i32,
    ) -> Result<(), ImageError> {
        let r = (radius * f64::from(1 << SHIFT)).round() as i32;
        imgproc::circle(
            &mut self.mat,
            pt(c),
            r,
            colour(rgb),
            thickness,
            imgproc::LINE_AA,
            SHIFT,
        )
        .map_err(err)
    }

    /// An upright cross of half-size `half` pixels.
    pub fn cross(
        &mut self,
        c: &Vector2<f64>,
        half: f64,
        rgb: [u8; 3],
        thickness: i32,
    ) -> Result<(), ImageError> {
        self.line(
            &(c - Vector2::new(half, 0.0)),
            &(c + Vector2::new(half, 0.0)),
            rgb,
            thickness,
        )?;
        self.line(
            &(c - Vector2::new(0.0, half)),
            &(c + Vector2::new(0.0, half)),
            rgb,
            thickness,
        )
    }

    pub fn arrow(
        &mut self,
        from: &Vector2<f64>,
        to: &Vector2<f64>,
        rgb: [u8; 3],
        thickness: i32,
    ) -> Result<(), ImageError> {
        let len = (to - from).norm().max(1e-9);
        let tip = (12.0 / len).min(0.4);
        imgproc::arrowed_line(
            &mut self.mat,
            pt(from),
            pt(to),
            colour(rgb),
            thickness,
            imgproc::LINE_AA,
            SHIFT,
            tip,
        )
        .map_err(err)
    }

    /// Text with its baseline starting at `at`, outlined in black so that it reads on any
    /// background. `scale` 1 is about 22 px high.
    pub fn text(
        &mut self,
        at: &Vector2<f64>,
        s: &str,
        scale: f64,
        rgb: [u8; 3],
        thickness: i32,
    ) -> Result<(), ImageError> {
        let p = Point::new(at.x.round() as i32, at.y.round() as i32);
        if rgb != [0, 0, 0] {
            imgproc::put_text(
                &mut self.mat,
                s,
                p,
                imgproc::FONT_HERSHEY_SIMPLEX,
                scale,
                colour([0, 0, 0]),
                thickness + 2,
                imgproc::LINE_AA,
                false,
            )
            .map_err(err)?;
        }
        imgproc::put_text(
            &mut self.mat,
            s,
            p,
            imgproc::FONT_HERSHEY_SIMPLEX,
            scale,
            colour(rgb),
            thickness,
            imgproc::LINE_AA,
            false,
        )
        .map_err(err)
    }

    /// An ellipse: centre, semi-axes and the first axis's angle from +x (degrees, clockwise in
    /// the image); `thickness` −1 fills it.
    pub fn ellipse(
        &mut self,
        centre: &Vector2<f64>,
        semi_axes: (f64, f64),
        angle_deg: f64,
        rgb: [u8; 3],
        thickness: i32,
    ) -> Result<(), ImageError> {
        let s = f64::from(1 << SHIFT);
        imgproc::ellipse(
            &mut self.mat,
            pt(centre),
            Size::new(
                (semi_axes.0 * s).round() as i32,
                (semi_axes.1 * s).round() as i32,
            ),
            angle_deg,
            0.0,
            360.0,
            colour(rgb),
            thickness,
            imgproc::LINE_AA,
            SHIFT,
        )
        .map_err(err)
    }

    /// Connected line segments through `points`.
    pub(crate) fn polyline(
        &mut self,
        points: &[Vector2<f64>],
        rgb: [u8; 3],
        thickness: i32,
    ) -> Result<(), ImageError> {
        if points.len() < 2 {
            return Ok(());
        }
        let pts: opencv::core::Vector<Point> = points.iter().map(pt).collect();
        let mut curves = opencv::core::Vector::<opencv::core::Vector<Point>>::new();
        curves.push(pts);
        imgproc::polylines(
            &mut self.mat,
            &curves,
            false,
            colour(rgb),
            thickness,
            imgproc::LINE_AA,
            SHIFT,
        )
        .map_err(err)
    }

    /// Copies `other` onto this canvas with its top-left pixel at (`x`, `y`) (it must fit).
    pub(crate) fn paste(&mut self, other: &Canvas, x: i32, y: i32) -> Result<(), ImageError> {
        let rect = Rect::new(x, y, other.mat.cols(), other.mat.rows());
        let mut roi = Mat::roi_mut(&mut self.mat, rect).map_err(err)?;
        other.mat.copy_to(&mut roi).map_err(err)
    }

    /// The image (8-bit BGR).
    pub fn mat(&self) -> &Mat {
        &self.mat
    }

    /// A filled rectangle (integer pixels), clipped to the canvas.
    pub(crate) fn fill_rect(
        &mut self,
        x: i32,
        y: i32,
        w: i32,
        h: i32,
        rgb: [u8; 3],
    ) -> Result<(), ImageError> {
        imgproc::rectangle(
            &mut self.mat,
            Rect::new(x, y, w, h),
            colour(rgb),
            -1,
            imgproc::LINE_8,
            0,
        )
        .map_err(err)
    }

    /// A darkened band over the rectangle, to put text on.
    pub fn shade_rect(&mut self, x: i32, y: i32, w: i32, h: i32) -> Result<(), ImageError> {
        let r = Rect::new(
            x.max(0),
            y.max(0),
            w.min(self.mat.cols() - x.max(0)),
            h.min(self.mat.rows() - y.max(0)),
        );
        if r.width <= 0 || r.height <= 0 {
            return Ok(());
        }
        let mut roi = Mat::roi_mut(&mut self.mat, r).map_err(err)?;
        let mut dark = Mat::default();
        roi.convert_to(&mut dark, -1, 0.35, 0.0).map_err(err)?;
        dark.copy_to(&mut roi).map_err(err)
    }

    /// Writes the canvas; the format follows the extension; written atomically.
    pub fn save(&self, path: &Path) -> Result<(), ImageError> {
        crate::imageio::encode_to(path, &self.mat)
    }

    /// Text width in pixels at `scale`.
    pub(crate) fn text_width(s: &str, scale: f64, thickness: i32) -> i32 {
        let mut base = 0;
        imgproc::get_text_size(
            s,
            imgproc::FONT_HERSHEY_SIMPLEX,
            scale,
            thickness,
            &mut base,
        )
        .map_or(0, |sz: Size| sz.width)
    }
}

/// The colour at `t` (0 to 1, clamped; NaN as 0) of a ramp through equally spaced `stops`.
pub(crate) fn ramp_colour(stops: &[[f64; 3]], t: f64) -> [u8; 3] {
    let t = if t.is_finite() {
        t.clamp(0.0, 1.0)
    } else {
        0.0
    };
    let f = t * (stops.len() - 1) as f64;
    let k = (f.floor() as usize).min(stops.len() - 2);
    let w = f - k as f64;
    std::array::from_fn(|c| (stops[k][c] * (1.0 - w) + stops[k + 1][c] * w).round() as u8)
}

/// How a series is drawn.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Style {
    Line,
    Dashed,
    Dots,
    /// A bar from 0 at each x, as wide as the series' closest x values (a histogram).
    Bars,
}

/// One series of a chart.
#[derive(Clone, Debug)]
pub struct Series {
    pub label: String,
    pub xy: Vec<(f64, f64)>,
    pub rgb: [u8; 3],
    pub style: Style,
}

/// A line chart: series over shared axes, and optional vertical ticks (key frames, say).
#[derive(Clone, Debug, Default)]
pub struct Chart {
    pub title: String,
    pub x_label: String,
    pub y_label: String,
    pub series: Vec<Series>,
    /// Short vertical marks along the bottom of the plot area, with their legend label.
    pub ticks: Vec<f64>,
    pub ticks_label: String,
    /// The y axis spans the data only (an altitude near 30 m, say; negative values too), not
    /// from 0.
    pub y_from_data: bool,
    /// The x axis starts at 0 (a density, a speed), not at the smallest x.
    pub x_from_zero: bool,
}

/// A "nice" step (1, 2 or 5 times a power of ten) for about `n` intervals over `span`.
fn nice_step(span: f64, n: f64) -> f64 {
    let raw = (span / n).max(1e-300);
    let p = 10f64.powf(raw.log10().floor());
    [1.0, 2.0, 5.0, 10.0]
        .iter()
        .map(|m| m * p)
        .find(|s| *s >= raw)
        .unwrap_or(10.0 * p)
}

fn label(v: f64, step: f64) -> String {
    let decimals = if step >= 1.0 {
        0
    } else {
        (-step.log10().floor()) as usize
    };
    format!("{v:.decimals$}")
}

/// A chart's axes: x from `x0` to `x1`, y from `y0` to `y1` in steps of `y_step`.
struct ChartRanges {
    x0: f64,
    x1: f64,
    y0: f64,
    y_step: f64,
    y1: f64,
}

impl ChartRanges {
    /// The data's range, the x axis from 0 when asked, y from 0 or from the data, rounded out to
    /// nice steps.
    fn of(chart: &Chart) -> ChartRanges {
        let pts = chart
            .series
            .iter()
            .flat_map(|s| s.xy.iter())
            .filter(|(x, y)| x.is_finite() && y.is_finite());
        let (mut x0, mut x1, mut y_max) = (f64::INFINITY, f64::NEG_INFINITY, f64::NEG_INFINITY);
        let mut y_min = f64::INFINITY;
        for &(x, y) in pts {
            x0 = x0.min(x);
            x1 = x1.max(x);
            y_max = y_max.max(y);
            y_min = y_min.min(y);
        }
        // From 0 the axis reaches at least 0; from the data, the data's top.
        let y1 = if chart.y_from_data && y_max.is_finite() {
            y_max
        } else {
            y_max.max(0.0)
        };
        if !x0.is_finite() {
            (x0, x1) = (0.0, 1.0);
        }
        if chart.x_from_zero {
            x0 = x0.min(0.0);
        }
        if x1 <= x0 {
            x1 = x0 + 1.0;
        }
        let (y0, y_step, y1) = if chart.y_from_data && y_min.is_finite() {
            // At least a few millimetres of span, centred on flat data.
            let span = (y1 - y_min).max(1e-3 * y1.abs()).max(1e-6);
            let step = nice_step(span, 5.0);
            let lo = ((y_min - 0.05 * span) / step).floor() * step;
            (
                lo,
                step,
                ((y1 + 0.05 * span) / step).ceil().max(lo / step + 1.0) * step,
            )
        } else {
            let step = nice_step(if y1 > 0.0 { y1 } else { 1.0 }, 5.0);
            (0.0, step, (y1 / step).ceil().max(1.0) * step)
        };
        ChartRanges {
            x0,
            x1,
            y0,
            y_step,
            y1,
        }
    }
}

/// Draws a chart on a white canvas of `width` × `height` pixels. The y axis starts at 0.
pub(crate) fn line_chart(chart: &Chart, width: u32, height: u32) -> Result<Canvas, ImageError> {
    let mut c = Canvas::blank(width, height, [255, 255, 255])?;
    let (left, right, top, bottom) = (70.0, 20.0, 50.0, 55.0);
    let (w, h) = (
        f64::from(width) - left - right,
        f64::from(height) - top - bottom,
    );
    let ChartRanges {
        x0,
        x1,
        y0,
        y_step,
        y1,
    } = ChartRanges::of(chart);
    let to_px = |x: f64, y: f64| {
        Vector2::new(
            left + (x - x0) / (x1 - x0) * w,
            top + h - (y - y0) / (y1 - y0) * h,
        )
    };
    let grey = [200, 200, 200];
    let black = [0, 0, 0];
    // Grid and labels.
    let mut y = y0;
    while y <= y1 + 1e-9 * y_step {
        let p = to_px(x0, y);
        c.line(&p, &to_px(x1, y), grey, 1)?;
        let s = label(y, y_step);
        c.text(
            &Vector2::new(
                left - 8.0 - f64::from(Canvas::text_width(&s, 0.45, 1)),
                p.y + 5.0,
            ),
            &s,
            0.45,
            black,
            1,
        )?;
        y += y_step;
    }
    let x_step = nice_step(x1 - x0, 8.0);
    let mut x = (x0 / x_step).ceil() * x_step;
    while x <= x1 + 1e-9 * x_step {
        let p = to_px(x, y0);
        c.line(&p, &(p + Vector2::new(0.0, 5.0)), black, 1)?;
        let s = label(x, x_step);
        c.text(
            &Vector2::new(
                p.x - f64::from(Canvas::text_width(&s, 0.45, 1)) / 2.0,
                p.y + 20.0,
            ),
            &s,
            0.45,
            black,
            1,
        )?;
        x += x_step;
    }
    c.line(&to_px(x0, y0), &to_px(x1, y0), black, 1)?;
    c.line(&to_px(x0, y0), &to_px(x0, y1), black, 1)?;
    for &t in &chart.ticks {
        let p = to_px(t, y0);
        c.line(&p, &(p - Vector2::new(0.0, 10.0)), [30, 120, 200], 2)?;
    }
    for s in &chart.series {
        if s.style == Style::Bars {
            let dx =
                s.xy.windows(2)
                    .map(|w| (w[1].0 - w[0].0).abs())
                    .filter(|d| *d > 0.0)
                    .fold(f64::INFINITY, f64::min);
            let dx = if dx.is_finite() { dx } else { (x1 - x0) / 10.0 };
            for &(x, y) in s.xy.iter().filter(|(x, y)| x.is_finite() && y.is_finite()) {
                let (a, b) = (to_px(x - 0.45 * dx, y.max(y0)), to_px(x + 0.45 * dx, y0));
                let (ax, ay) = (a.x.round() as i32, a.y.round() as i32);
                c.fill_rect(
                    ax,
                    ay,
                    (b.x.round() as i32 - ax).max(1),
                    b.y.round() as i32 - ay,
                    s.rgb,
                )?;
            }
            continue;
        }
        let mut prev: Option<Vector2<f64>> = None;
        for &(x, y) in &s.xy {
            if !(x.is_finite() && y.is_finite()) {
                prev = None;
                continue;
            }
            let p = to_px(x, y);
            match s.style {
                Style::Dots => c.circle(&p, 1.5, s.rgb, -1)?,
                Style::Bars => {}
                Style::Line => {
                    if let Some(q) = prev {
                        c.line(&q, &p, s.rgb, 1)?;
                    }
                }
                Style::Dashed => {
                    if let Some(q) = prev {
                        c.dashed_line(&q, &p, s.rgb, 1, 6.0)?;
                    }
                }
            }
            prev = Some(p);
        }
    }
    // Titles and legend.
    c.text(&Vector2::new(left, 28.0), &chart.title, 0.6, black, 1)?;
    let xl = &chart.x_label;
    c.text(
        &Vector2::new(
            left + w / 2.0 - f64::from(Canvas::text_width(xl, 0.5, 1)) / 2.0,
            f64::from(height) - 10.0,
        ),
        xl,
        0.5,
        black,
        1,
    )?;
    c.text(
        &Vector2::new(8.0, top - 10.0),
        &chart.y_label,
        0.45,
        black,
        1,
    )?;
    let mut lx = left + w;
    let mut entries: Vec<(String, [u8; 3])> = chart
        .series
        .iter()
        .map(|s| (s.label.clone(), s.rgb))
        .collect();
    if !chart.ticks.is_empty() {
        entries.push((chart.ticks_label.clone(), [30, 120, 200]));
    }
    for (l, rgb) in entries.iter().rev() {
        lx -= f64::from(Canvas::text_width(l, 0.45, 1)) + 30.0;
        c.line(
            &Vector2::new(lx, top - 14.0),
            &Vector2::new(lx + 18.0, top - 14.0),
            *rgb,
            2,
        )?;
        c.text(&Vector2::new(lx + 22.0, top - 10.0), l, 0.45, black, 1)?;
    }
    Ok(c)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn nice_steps() {
        assert_eq!(nice_step(10.0, 5.0), 2.0);
        assert_eq!(nice_step(0.9, 5.0), 0.2);
        assert_eq!(nice_step(730.0, 8.0), 100.0);
        assert_eq!(label(0.4, 0.2), "0.4");
        assert_eq!(label(300.0, 100.0), "300");
    }

    #[test]
    fn data_ranges_span_negative_values_and_zero_ranges_start_at_zero() {
        let chart = |xy: Vec<(f64, f64)>, y_from_data: bool| Chart {
            series: vec![Series {
                label: "s".into(),
                xy,
                rgb: [0, 0, 0],
                style: Style::Line,
            }],
            y_from_data,
            ..Chart::default()
        };
        // All below 0, from the data: the axis holds them and stops near their top.
        let r = ChartRanges::of(&chart(vec![(0.0, -30.0), (1.0, -20.0)], true));
        assert!(
            r.y0 <= -30.0 && r.y1 >= -20.0 && r.y1 < -15.0,
            "{} {}",
            r.y0,
            r.y1
        );
        // Across 0.
        let r = ChartRanges::of(&chart(vec![(0.0, -0.4), (1.0, 0.6)], true));
        assert!(r.y0 <= -0.4 && r.y1 >= 0.6 && r.y0 > -1.0 && r.y1 < 1.0);
        // From 0, positive data: 0 to the top.
        let r = ChartRanges::of(&chart(vec![(0.0, 3.0), (1.0, 7.0)], false));
        assert!(r.y0 == 0.0 && r.y1 >= 7.0);
        // No data: a unit axis.
        let r = ChartRanges::of(&chart(Vec::new(), true));
        assert!(r.y0 == 0.0 && r.y1 > 0.0);
    }
}
