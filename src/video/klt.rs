//! Corner features and pyramidal Lucas–Kanade tracking (OpenCV adapter), for the stabiliser.

use nalgebra::Vector2;
use opencv::core::{Mat, Point2f, Size, TermCriteria, TermCriteria_Type, Vector};
use opencv::prelude::*;
use opencv::{core, imgproc, video};

use crate::pose::stabilise::FeatureTracker;

/// Tracker settings.
#[derive(Clone, Debug)]
pub struct KltSettings {
    /// Side of the tracking window, pixels.
    pub window: i32,
    /// Pyramid levels above the full image.
    pub levels: i32,
    /// Window side and pyramid levels of the local search around a good prediction.
    pub refine_window: i32,
    pub refine_levels: i32,
    /// A track whose backward track misses its start by more than this is dropped, pixels.
    pub max_fb_error_px: f64,
    pub max_corners: i32,
    /// Corners are found per cell of a grid of this many columns (and rows in the image's
    /// proportion), so that weak ground texture is used next to strong targets and people.
    pub grid_cols: i32,
    /// Corner quality relative to the best corner of its cell.
    pub quality: f64,
    /// Least distance between corners, pixels.
    pub min_distance: f64,
}

impl Default for KltSettings {
    fn default() -> Self {
        KltSettings {
            window: 21,
            levels: 3,
            refine_window: 31,
            refine_levels: 1,
            max_fb_error_px: 0.5,
            max_corners: 1000,
            grid_cols: 8,
            quality: 0.02,
            min_distance: 15.0,
        }
    }
}

/// A greyscale frame with its image pyramid, built once for every track into or out of it.
pub struct GrayFrame {
    pub index: usize,
    image: Mat,
    pyramid: Vector<Mat>,
}

fn e(e: opencv::Error) -> String {
    e.to_string()
}

/// OpenCV's `goodFeaturesToTrack` and `calcOpticalFlowPyrLK` with a forward–backward check.
pub struct Klt {
    pub settings: KltSettings,
}

impl Klt {
    pub fn new(settings: KltSettings) -> Klt {
        Klt { settings }
    }

    pub fn frame(&self, index: usize, gray: Mat) -> Result<GrayFrame, String> {
        let mut pyramid = Vector::<Mat>::new();
        let win = Size::new(self.settings.window, self.settings.window);
        video::build_optical_flow_pyramid(
            &gray,
            &mut pyramid,
            win,
            self.settings.levels,
            true,
            core::BORDER_REFLECT_101,
            core::BORDER_CONSTANT,
            true,
        )
        .map_err(e)?;
        Ok(GrayFrame {
            index,
            image: gray,
            pyramid,
        })
    }

    fn lk(
        &self,
        from: &GrayFrame,
        to: &GrayFrame,
        pts: &Vector<Point2f>,
        guess: Option<&Vector<Point2f>>,
        local: bool,
    ) -> Result<(Vector<Point2f>, Vector<u8>), String> {
        let (window, levels) = if local {
            (self.settings.refine_window, self.settings.refine_levels)
        } else {
            (self.settings.window, self.settings.levels)
        };
        let mut next = guess.cloned().unwrap_or_else(|| pts.clone());
        let mut status = Vector::<u8>::new();
        let mut err = Vector::<f32>::new();
        let criteria = TermCriteria::new(
            TermCriteria_Type::COUNT as i32 + TermCriteria_Type::EPS as i32,
            30,
            0.01,
        )
        .map_err(e)?;
        let flags = if guess.is_some() {
            video::OPTFLOW_USE_INITIAL_FLOW
        } else {
            0
        };
        let size = Size::new(window, window);
        // The pyramids are built for the wide search; the local one works on the images.
        if local {
            video::calc_optical_flow_pyr_lk(
                &from.image,
                &to.image,
                pts,
                &mut next,
                &mut status,
                &mut err,
                size,
                levels,
                criteria,
                flags,
                1e-4,
            )
            .map_err(e)?;
        } else {
            video::calc_optical_flow_pyr_lk(
                &from.pyramid,
                &to.pyramid,
                pts,
                &mut next,
                &mut status,
                &mut err,
                size,
                levels,
                criteria,
                flags,
                1e-4,
            )
            .map_err(e)?;
        }
        Ok((next, status))
    }
}

fn to_cv(pts: &[Vector2<f64>]) -> Vector<Point2f> {
    pts.iter()
        .map(|p| Point2f::new(p.x as f32, p.y as f32))
        .collect()
}

impl FeatureTracker for Klt {
    type Frame = GrayFrame;

    fn detect(&mut self, frame: &GrayFrame) -> Result<Vec<Vector2<f64>>, String> {
        let s = &self.settings;
        let (w, h) = (frame.image.cols(), frame.image.rows());
        let cols = s.grid_cols.max(1);
        let rows = ((f64::from(cols) * f64::from(h) / f64::from(w)).round() as i32).max(1);
        let per_cell = (s.max_corners / (cols * rows)).max(1);
        let mut out = Vec::new();
        for r in 0..rows {
            for c in 0..cols {
                let (x0, y0) = (w * c / cols, h * r / rows);
                let (x1, y1) = (w * (c + 1) / cols, h * (r + 1) / rows);
                let cell =
                    Mat::roi(&frame.image, core::Rect::new(x0, y0, x1 - x0, y1 - y0)).map_err(e)?;
                let mut corners = Vector::<Point2f>::new();
                imgproc::good_features_to_track(
                    &cell,
                    &mut corners,
                    per_cell,
                    s.quality,
                    s.min_distance,
                    &core::no_array(),
                    3,
                    false,
                    0.04,
                )
                .map_err(e)?;
                out.extend(corners.iter().map(|p| {
                    Vector2::new(
                        f64::from(p.x) + f64::from(x0),
                        f64::from(p.y) + f64::from(y0),
                    )
                }));
            }
        }
        Ok(out)
    }

    fn track(
        &mut self,
        from: &GrayFrame,
        to: &GrayFrame,
        pts: &[Vector2<f64>],
        guess: Option<&[Vector2<f64>]>,
    ) -> Result<Vec<Option<Vector2<f64>>>, String> {
        self.checked(from, to, pts, guess, false)
    }

    fn refine(
        &mut self,
        from: &GrayFrame,
        to: &GrayFrame,
        pts: &[Vector2<f64>],
        guess: &[Vector2<f64>],
    ) -> Result<Vec<Option<Vector2<f64>>>, String> {
        self.checked(from, to, pts, Some(guess), true)
    }
}

impl Klt {
    /// Lucas–Kanade forward, then back from where the points landed: a good track returns to
    /// its start.
    fn checked(
        &self,
        from: &GrayFrame,
        to: &GrayFrame,
        pts: &[Vector2<f64>],
        guess: Option<&[Vector2<f64>]>,
        local: bool,
    ) -> Result<Vec<Option<Vector2<f64>>>, String> {
        if pts.is_empty() {
            return Ok(Vec::new());
        }
        let start = to_cv(pts);
        let guess = guess.map(to_cv);
        let (fwd, st_f) = self.lk(from, to, &start, guess.as_ref(), local)?;
        let (back, st_b) = self.lk(to, from, &fwd, Some(&start), local)?;
        let (w, h) = (to.image.cols() as f32, to.image.rows() as f32);
        let max_fb = self.settings.max_fb_error_px as f32;
        Ok((0..pts.len())
            .map(|i| {
                let (f, b, s) = (fwd.get(i).ok()?, back.get(i).ok()?, start.get(i).ok()?);
                let ok = st_f.get(i).ok()? == 1
                    && st_b.get(i).ok()? == 1
                    && (b.x - s.x).hypot(b.y - s.y) <= max_fb
                    && f.x >= 0.0
                    && f.y >= 0.0
                    && f.x <= w - 1.0
                    && f.y <= h - 1.0;
                ok.then(|| Vector2::new(f64::from(f.x), f64::from(f.y)))
            })
            .collect())
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use opencv::core::CV_8UC1;

    /// A smooth random-ish texture shifted by (dx, dy).
    fn texture(dx: f64, dy: f64) -> Mat {
        let (w, h) = (640, 480);
        let mut px = vec![0u8; w * h];
        for y in 0..h {
            for x in 0..w {
                let (u, v) = (x as f64 - dx, y as f64 - dy);
                // Band-limited: a few plane waves, the finest of 20 px wavelength.
                let s = (u * 0.3 + v * 0.1).sin()
                    + (u * -0.12 + v * 0.27 + 1.0).sin()
                    + (u * 0.05 + v * 0.08 + 2.0).sin()
                    + (u * 0.21 - v * 0.19 + 0.5).sin();
                px[y * w + x] = (128.0 + 40.0 * s).clamp(0.0, 255.0) as u8;
            }
        }
        let m = Mat::new_rows_cols_with_data(h as i32, w as i32, &px)
            .unwrap()
            .try_clone()
            .unwrap();
        assert_eq!(m.typ(), CV_8UC1);
        m
    }

    #[test]
    fn tracks_a_shift_and_finds_features() {
        let mut klt = Klt::new(KltSettings::default());
        let a = klt.frame(0, texture(0.0, 0.0)).unwrap();
        let b = klt.frame(1, texture(2.3, -1.7)).unwrap();
        let pts = klt.detect(&a).unwrap();
        assert!(pts.len() > 50, "{} features", pts.len());
        let moved = klt.track(&a, &b, &pts, None).unwrap();
        let ok: Vec<_> = pts
            .iter()
            .zip(&moved)
            .filter_map(|(p, m)| m.map(|m| m - p))
            .collect();
        assert!(
            ok.len() > pts.len() * 8 / 10,
            "{} of {} tracked",
            ok.len(),
            pts.len()
        );
        let mut err: Vec<f64> = ok
            .iter()
            .map(|d| (d - Vector2::new(2.3, -1.7)).norm())
            .collect();
        err.sort_by(f64::total_cmp);
        assert!(
            err[err.len() / 2] < 0.05 && err[err.len() * 9 / 10] < 0.2,
            "median {} p90 {}",
            err[err.len() / 2],
            err[err.len() * 9 / 10]
        );
    }
}
