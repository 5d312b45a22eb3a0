//! Corner features and pyramidal Lucas–Kanade tracking (OpenCV adapter), for the stabiliser.
//!
//! Features are found and tracked on a working copy of the frame no wider than `max_width`
//! (a 4K frame is halved: the homography needs hundreds of points, not their last tenth of a
//! pixel, and the cost falls fourfold); coordinates are always returned in the frame's own
//! pixels. The local refinement of a few points (GCP picks) works on small windows of the
//! full-resolution frames cut around each point, so its cost does not grow with the image.

use nalgebra::Vector2;
use opencv::core::{Mat, Point2f, Rect, Size, TermCriteria, TermCriteria_Type, Vector};
use opencv::prelude::*;
use opencv::{core, imgproc, video};

use crate::features::FeatureTracker;

/// Tracker settings.
#[derive(Clone, Debug)]
pub struct KltSettings {
    /// Side of the tracking window, pixels (of the working copy). The stabiliser's 11 (from 15)
    /// costs half the Lucas–Kanade time on its corners, with the same key frames and poses.
    pub window: i32,
    /// Pyramid levels above the working copy.
    pub levels: i32,
    /// Levels tried first: enough for a hovering camera's motion between frames; when fewer
    /// than `fast_fraction` of the features pass, all `levels` are used.
    pub fast_levels: i32,
    pub fast_fraction: f64,
    /// The working copy's largest width, pixels.
    pub max_width: i32,
    /// Window side and pyramid levels of the local search around a good prediction (full
    /// resolution). No coarse level by default: the prediction is within a few pixels (a jump
    /// beyond 6 px is refused anyway), and a level triples the area of the windows.
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
    /// Least distance between corners, pixels (of the working copy).
    pub min_distance: f64,
}

impl Default for KltSettings {
    fn default() -> Self {
        KltSettings {
            window: 11,
            levels: 3,
            fast_levels: 1,
            fast_fraction: 0.6,
            max_width: 1920,
            refine_window: 31,
            refine_levels: 0,
            max_fb_error_px: 0.5,
            max_corners: 1000,
            grid_cols: 8,
            quality: 0.02,
            min_distance: 15.0,
        }
    }
}

/// A greyscale frame with the pyramid of its working copy, built once for every track into or
/// out of it.
pub struct GrayFrame {
    pub index: usize,
    /// Full resolution, for the local refinement of picks; none for a tracker that never
    /// refines (a people tracker keeps 25 frames: 200 MB of 4K frames it never reads).
    image: Option<std::sync::Arc<Mat>>,
    /// The working copy's pyramid, and frame pixels per working pixel.
    pyramid: Vector<Mat>,
    scale: f64,
    /// Where the pyramid goes when the frame is dropped. Nothing outside the frame keeps a
    /// header of its pyramid's images (`working` is read and let go at once).
    recycle: Option<PyramidPool>,
}

/// OpenCV's `goodFeaturesToTrack` and `calcOpticalFlowPyrLK` with a forward–backward check.
pub struct Klt {
    pub settings: KltSettings,
    pyramids: PyramidPool,
    /// The working copy before its pyramid is built (the pyramid copies it): one buffer
    /// rewritten for every frame (a fresh 4K-halved image each frame was a third of a crowd
    /// scan's page faults).
    scratch: std::sync::Mutex<Mat>,
}

/// Pixel coordinates between resolutions, pixel centres at integers: `x' = (x + 0.5)·s − 0.5`.
fn rescale(p: &Vector2<f64>, s: f64) -> Vector2<f64> {
    Vector2::new((p.x + 0.5) * s - 0.5, (p.y + 0.5) * s - 0.5)
}

fn to_cv(pts: &[Vector2<f64>]) -> Vector<Point2f> {
    pts.iter()
        .map(|p| Point2f::new(p.x as f32, p.y as f32))
        .collect()
}

/// Iterations and the step (pixels) at which Lucas–Kanade stops.
fn criteria(iterations: i32, eps_px: f64) -> Result<TermCriteria, opencv::Error> {
    TermCriteria::new(
        TermCriteria_Type::COUNT as i32 + TermCriteria_Type::EPS as i32,
        iterations,
        eps_px,
    )
}

/// The stabiliser's hundreds of features: a homography does not need each to a hundredth of a
/// pixel, and these criteria halve their cost.
const FEATURE_CRITERIA: (i32, f64) = (10, 0.03);
/// The few picks: as precise as can be.
const PICK_CRITERIA: (i32, f64) = (30, 0.01);

/// Lucas–Kanade from `a` to `b` (images or pyramids), then back: a good track returns to its
/// start. Returns the landing points and whether each passed.
fn forward_backward(
    a: &impl core::ToInputArray,
    b: &impl core::ToInputArray,
    start: &Vector<Point2f>,
    guess: Option<&Vector<Point2f>>,
    (window, levels): (i32, i32),
    max_fb: f32,
    (iterations, eps_px): (i32, f64),
) -> Result<(Vector<Point2f>, Vec<bool>), opencv::Error> {
    let size = Size::new(window, window);
    let mut fwd = guess.cloned().unwrap_or_else(|| start.clone());
    let (mut st_f, mut err) = (Vector::<u8>::new(), Vector::<f32>::new());
    let flags = if guess.is_some() {
        video::OPTFLOW_USE_INITIAL_FLOW
    } else {
        0
    };
    video::calc_optical_flow_pyr_lk(
        a,
        b,
        start,
        &mut fwd,
        &mut st_f,
        &mut err,
        size,
        levels,
        criteria(iterations, eps_px)?,
        flags,
        1e-4,
    )?;
    let mut back = start.clone();
    let mut st_b = Vector::<u8>::new();
    video::calc_optical_flow_pyr_lk(
        b,
        a,
        &fwd,
        &mut back,
        &mut st_b,
        &mut err,
        size,
        levels,
        criteria(iterations, eps_px)?,
        video::OPTFLOW_USE_INITIAL_FLOW,
        1e-4,
    )?;
    let ok = (0..start.len())
        .map(|i| {
            let (Ok(s), Ok(bk), Ok(sf), Ok(sb)) =
                (start.get(i), back.get(i), st_f.get(i), st_b.get(i))
            else {
                return false;
            };
            sf == 1 && sb == 1 && (bk.x - s.x).hypot(bk.y - s.y) <= max_fb
        })
        .collect();
    Ok((fwd, ok))
}

impl Klt {
    pub fn new(settings: KltSettings) -> Klt {
        Klt {
            settings,
            pyramids: PyramidPool::default(),
            scratch: std::sync::Mutex::new(Mat::default()),
        }
    }

    pub fn frame(&self, index: usize, gray: Mat) -> Result<GrayFrame, opencv::Error> {
        self.frame_shared(index, std::sync::Arc::new(gray))
    }

    /// [`frame`](Self::frame) of a gray image shared with others (the stabiliser and the
    /// people tracker take the same frame): no copy of it is made.
    pub(crate) fn frame_shared(
        &self,
        index: usize,
        gray: std::sync::Arc<Mat>,
    ) -> Result<GrayFrame, opencv::Error> {
        let target = self.working_size(gray.cols(), gray.rows());
        if gray.size()? == target {
            return self.frame_with_working(index, gray.clone(), &gray);
        }
        let mut scratch = self.scratch.lock().unwrap_or_else(|e| e.into_inner());
        super::reduce::area_reduce(&*gray, &mut scratch, target)?;
        self.frame_with_working(index, gray, &scratch)
    }

    /// The size of the working copy of a `w` × `h` frame: reduced by a whole factor to at most
    /// `max_width`.
    pub(crate) fn working_size(&self, w: i32, h: i32) -> Size {
        let factor =
            ((f64::from(w) / f64::from(self.settings.max_width.max(64))).ceil()).max(1.0) as i32;
        Size::new(w / factor, h / factor)
    }

    /// The frame of `gray` with `work`, its working copy made elsewhere (of
    /// [`working_size`](Self::working_size), from another tracker's working copy, say).
    pub(crate) fn frame_with_working(
        &self,
        index: usize,
        gray: std::sync::Arc<Mat>,
        work: &Mat,
    ) -> Result<GrayFrame, opencv::Error> {
        let width = gray.cols();
        self.frame_of(index, Some(gray), width, work)
    }

    /// The frame of a working copy alone, of a frame `full_width` pixels wide: for a tracker
    /// that never refines at full resolution.
    pub(crate) fn frame_of_working(
        &self,
        index: usize,
        full_width: i32,
        work: &Mat,
    ) -> Result<GrayFrame, opencv::Error> {
        self.frame_of(index, None, full_width, work)
    }

    fn frame_of(
        &self,
        index: usize,
        image: Option<std::sync::Arc<Mat>>,
        full_width: i32,
        work: &Mat,
    ) -> Result<GrayFrame, opencv::Error> {
        // A pyramid of a frame no longer used: its memory is rewritten rather than allocated
        // again (fresh pages cost a tenth of a 4K crowd scan).
        let mut pyramid = self
            .pyramids
            .lock()
            .ok()
            .and_then(|mut p| p.pop())
            .unwrap_or_default();
        let win = Size::new(self.settings.window, self.settings.window);
        // Never with the input as its first level: the pyramid is rewritten when reused.
        video::build_optical_flow_pyramid(
            work,
            &mut pyramid,
            win,
            self.settings.levels,
            true,
            core::BORDER_REFLECT_101,
            core::BORDER_CONSTANT,
            false,
        )?;
        let scale = f64::from(full_width) / f64::from(work.cols());
        Ok(GrayFrame {
            index,
            image,
            pyramid,
            scale,
            recycle: Some(self.pyramids.clone()),
        })
    }
}

/// Pyramids of dropped frames, for the next frames (at most `PYRAMIDS_KEPT`).
type PyramidPool = std::sync::Arc<std::sync::Mutex<Vec<Vector<Mat>>>>;

const PYRAMIDS_KEPT: usize = 4;

impl Drop for GrayFrame {
    fn drop(&mut self) {
        if let Some(pool) = &self.recycle
            && let Ok(mut kept) = pool.lock()
            && kept.len() < PYRAMIDS_KEPT
        {
            kept.push(std::mem::take(&mut self.pyramid));
        }
    }
}

impl GrayFrame {
    /// The working copy (the pyramid's first level), sharing its pixels: to be read at once,
    /// not kept (the pyramid is rewritten once the frame is dropped).
    pub fn working(&self) -> Result<Mat, opencv::Error> {
        self.pyramid.get(0)
    }
}

impl FeatureTracker for Klt {
    type Frame = GrayFrame;

    fn detect(&mut self, frame: &GrayFrame) -> Result<Vec<Vector2<f64>>, crate::PluginError> {
        let s = &self.settings;
        let work = frame.pyramid.get(0)?;
        let (w, h) = (work.cols(), work.rows());
        let cols = s.grid_cols.max(1);
        let rows = ((f64::from(cols) * f64::from(h) / f64::from(w)).round() as i32).max(1);
        let per_cell = (s.max_corners / (cols * rows)).max(1);
        let mut out = Vec::new();
        for r in 0..rows {
            for c in 0..cols {
                let (x0, y0) = (w * c / cols, h * r / rows);
                let (x1, y1) = (w * (c + 1) / cols, h * (r + 1) / rows);
                let cell = Mat::roi(&work, Rect::new(x0, y0, x1 - x0, y1 - y0))?;
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
                )?;
                out.extend(corners.iter().map(|p| {
                    rescale(
                        &Vector2::new(
                            f64::from(p.x) + f64::from(x0),
                            f64::from(p.y) + f64::from(y0),
                        ),
                        frame.scale,
                    )
                }));
            }
        }
        Ok(out)
    }

    /// Corners inside a person's box.
    fn detect_in(
        &mut self,
        frame: &GrayFrame,
        bbox: [f64; 4],
        max: usize,
    ) -> Result<Vec<Vector2<f64>>, crate::PluginError> {
        let work = frame.pyramid.get(0)?;
        let inv = 1.0 / frame.scale;
        let a = rescale(&Vector2::new(bbox[0], bbox[1]), inv);
        let b = rescale(&Vector2::new(bbox[0] + bbox[2], bbox[1] + bbox[3]), inv);
        let x0 = (a.x.floor() as i32).clamp(0, work.cols() - 1);
        let y0 = (a.y.floor() as i32).clamp(0, work.rows() - 1);
        let x1 = (b.x.ceil() as i32).clamp(0, work.cols());
        let y1 = (b.y.ceil() as i32).clamp(0, work.rows());
        if x1 - x0 < 4 || y1 - y0 < 4 || max == 0 {
            return Ok(Vec::new());
        }
        let cell = Mat::roi(&work, Rect::new(x0, y0, x1 - x0, y1 - y0))?;
        let mut corners = Vector::<Point2f>::new();
        imgproc::good_features_to_track(
            &cell,
            &mut corners,
            max as i32,
            self.settings.quality,
            self.settings.min_distance,
            &core::no_array(),
            3,
            false,
            0.04,
        )?;
        Ok(corners
            .iter()
            .map(|p| {
                rescale(
                    &Vector2::new(
                        f64::from(p.x) + f64::from(x0),
                        f64::from(p.y) + f64::from(y0),
                    ),
                    frame.scale,
                )
            })
            .collect())
    }

    fn track(
        &mut self,
        from: &GrayFrame,
        to: &GrayFrame,
        pts: &[Vector2<f64>],
        guess: Option<&[Vector2<f64>]>,
    ) -> Result<Vec<Option<Vector2<f64>>>, crate::PluginError> {
        if pts.is_empty() {
            return Ok(Vec::new());
        }
        let inv = 1.0 / from.scale;
        let start: Vec<Vector2<f64>> = pts.iter().map(|p| rescale(p, inv)).collect();
        let guess: Option<Vec<Vector2<f64>>> =
            guess.map(|g| g.iter().map(|p| rescale(p, inv)).collect());
        let max_fb = (self.settings.max_fb_error_px * inv) as f32;
        let s = &self.settings;
        let run = |levels: i32| {
            forward_backward(
                &from.pyramid,
                &to.pyramid,
                &to_cv(&start),
                guess.as_ref().map(|g| to_cv(g)).as_ref(),
                (s.window, levels),
                max_fb,
                FEATURE_CRITERIA,
            )
        };
        let (mut fwd, mut ok) = run(s.fast_levels.min(s.levels))?;
        if s.fast_levels < s.levels
            && (ok.iter().filter(|&&b| b).count() as f64) < s.fast_fraction * pts.len() as f64
        {
            (fwd, ok) = run(s.levels)?;
        }
        let work = to.pyramid.get(0)?;
        let (w, h) = (work.cols() as f32, work.rows() as f32);
        Ok((0..pts.len())
            .map(|i| {
                let f = fwd.get(i).ok()?;
                (ok[i] && f.x >= 0.0 && f.y >= 0.0 && f.x <= w - 1.0 && f.y <= h - 1.0)
                    .then(|| rescale(&Vector2::new(f64::from(f.x), f64::from(f.y)), to.scale))
            })
            .collect())
    }

    fn refine(
        &mut self,
        from: &GrayFrame,
        to: &GrayFrame,
        pts: &[Vector2<f64>],
        guess: &[Vector2<f64>],
    ) -> Result<Vec<Option<Vector2<f64>>>, crate::PluginError> {
        let s = &self.settings;
        // Windows wide enough for the search: the LK window, its pyramid, and slack.
        let half = (s.refine_window * (1 << s.refine_levels)) + 8;
        let (Some(from_image), Some(to_image)) = (&from.image, &to.image) else {
            return Err("KLT refinement needs full-resolution frames".into());
        };
        let (wa, ha) = (from_image.cols(), from_image.rows());
        let (wb, hb) = (to_image.cols(), to_image.rows());
        // Both windows have the same size (Lucas–Kanade compares equal images): near an edge a
        // window slides inwards rather than shrinking.
        let side = 2 * half + 1;
        let window = |p: &Vector2<f64>, w: i32, h: i32| -> Option<Rect> {
            if w < side
                || h < side
                || !(p.x >= 0.0 && p.y >= 0.0 && p.x <= f64::from(w - 1) && p.y <= f64::from(h - 1))
            {
                return None;
            }
            let (cx, cy) = (p.x.round() as i32, p.y.round() as i32);
            Some(Rect::new(
                (cx - half).clamp(0, w - side),
                (cy - half).clamp(0, h - side),
                side,
                side,
            ))
        };
        let mut out = Vec::with_capacity(pts.len());
        for (p, g) in pts.iter().zip(guess) {
            let (Some(ra), Some(rb)) = (window(p, wa, ha), window(g, wb, hb)) else {
                out.push(None);
                continue;
            };
            let a = Mat::roi(&**from_image, ra)?;
            let b = Mat::roi(&**to_image, rb)?;
            let start = to_cv(&[Vector2::new(p.x - f64::from(ra.x), p.y - f64::from(ra.y))]);
            let guess = to_cv(&[Vector2::new(g.x - f64::from(rb.x), g.y - f64::from(rb.y))]);
            let (fwd, ok) = forward_backward(
                &a,
                &b,
                &start,
                Some(&guess),
                (s.refine_window, s.refine_levels),
                s.max_fb_error_px as f32,
                PICK_CRITERIA,
            )?;
            let f = fwd.get(0)?;
            let q = Vector2::new(
                f64::from(f.x) + f64::from(rb.x),
                f64::from(f.y) + f64::from(rb.y),
            );
            out.push(
                (ok[0]
                    && q.x >= 0.0
                    && q.y >= 0.0
                    && q.x <= f64::from(wb - 1)
                    && q.y <= f64::from(hb - 1))
                .then_some(q),
            );
        }
        Ok(out)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use opencv::core::CV_8UC1;

    /// A smooth random-ish texture shifted by (dx, dy).
    fn texture(w: usize, h: usize, dx: f64, dy: f64) -> Mat {
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

    fn check(max_width: i32, size: (usize, usize)) {
        let mut klt = Klt::new(KltSettings {
            max_width,
            ..KltSettings::default()
        });
        let a = klt.frame(0, texture(size.0, size.1, 0.0, 0.0)).unwrap();
        let b = klt.frame(1, texture(size.0, size.1, 2.3, -1.7)).unwrap();
        let pts = klt.detect(&a).unwrap();
        assert!(pts.len() > 50, "{} features", pts.len());
        let moved = klt.track(&a, &b, &pts, None).unwrap();
        let ok: Vec<_> = pts
            .iter()
            .zip(&moved)
            .filter_map(|(p, m)| m.map(|m| m - p))
            .collect();
        assert!(
            ok.len() > pts.len() * 7 / 10,
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
            err[err.len() / 2] < 0.1 && err[err.len() * 9 / 10] < 0.3,
            "median {} p90 {}",
            err[err.len() / 2],
            err[err.len() * 9 / 10]
        );
        // Local refinement at full resolution from a rough guess.
        let picks = vec![Vector2::new(100.0, 120.0), Vector2::new(500.0, 300.0)];
        let guess: Vec<_> = picks.iter().map(|p| p + Vector2::new(3.0, -1.0)).collect();
        for (p, r) in picks
            .iter()
            .zip(klt.refine(&a, &b, &picks, &guess).unwrap())
        {
            assert!((r.unwrap() - p - Vector2::new(2.3, -1.7)).norm() < 0.1);
        }
    }

    #[test]
    fn tracks_a_shift_at_full_and_at_half_resolution() {
        check(1920, (640, 480));
        check(400, (800, 480));
    }
}
