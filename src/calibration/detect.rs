//! Chessboard corner detection (OpenCV adapter). Returns plain nalgebra pixels in OpenCV's
//! convention (pixel (0, 0) is the centre of the top-left pixel), which is geostride's.

use nalgebra::Vector2;
use opencv::core::{Mat, Point2f, Size, TermCriteria, TermCriteria_Type, Vector};
use opencv::prelude::*;
use opencv::{calib3d, imgproc};

use crate::camera::BoardSpec;

/// Which OpenCV detector finds the corners.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Detector {
    /// `findChessboardCorners` + `cornerSubPix`, as OpenCV's calibration sample does.
    Classic,
    /// `findChessboardCornersSB` (sector-based, more robust to blur and noise).
    SectorBased,
}

/// Corner detection settings.
#[derive(Clone, Copy, Debug)]
pub struct DetectSettings {
    pub detector: Detector,
    /// Half-size of the `cornerSubPix` search window, pixels (OpenCV sample: 11).
    pub subpix_window: i32,
    /// Cap the window at the largest size that stays inside one square of the detected board.
    pub cap_window: bool,
    /// `cornerSubPix` stops when a corner moves less than this, pixels.
    pub subpix_eps: f64,
    /// Quick rejection of frames without a board (`CALIB_CB_FAST_CHECK`), for videos.
    pub fast_check: bool,
}

impl Default for DetectSettings {
    fn default() -> Self {
        DetectSettings {
            detector: Detector::Classic,
            subpix_window: 11,
            cap_window: false,
            subpix_eps: 0.001,
            fast_check: false,
        }
    }
}

/// Finds the inner corners of `board` in a greyscale 8-bit image, in OpenCV's row-major order.
/// `Ok(None)` when the board is not found.
pub fn find_corners(
    gray: &Mat,
    board: &BoardSpec,
    settings: &DetectSettings,
) -> opencv::Result<Option<Vec<Vector2<f64>>>> {
    let pattern = Size::new(board.cols as i32, board.rows as i32);
    let mut corners = Vector::<Point2f>::new();
    let found = match settings.detector {
        Detector::Classic => {
            let mut flags = calib3d::CALIB_CB_ADAPTIVE_THRESH | calib3d::CALIB_CB_NORMALIZE_IMAGE;
            if settings.fast_check {
                flags |= calib3d::CALIB_CB_FAST_CHECK;
            }
            let found = calib3d::find_chessboard_corners(gray, pattern, &mut corners, flags)?;
            if found {
                let half = if settings.cap_window {
                    settings.subpix_window.min(max_window(&corners, board))
                } else {
                    settings.subpix_window
                };
                let criteria = TermCriteria::new(
                    TermCriteria_Type::EPS as i32 + TermCriteria_Type::COUNT as i32,
                    30,
                    settings.subpix_eps,
                )?;
                imgproc::corner_sub_pix(
                    gray,
                    &mut corners,
                    Size::new(half, half),
                    Size::new(-1, -1),
                    criteria,
                )?;
            }
            found
        }
        Detector::SectorBased => {
            let flags = calib3d::CALIB_CB_NORMALIZE_IMAGE
                | calib3d::CALIB_CB_EXHAUSTIVE
                | calib3d::CALIB_CB_ACCURACY;
            calib3d::find_chessboard_corners_sb(gray, pattern, &mut corners, flags)?
        }
    };
    if !found || corners.len() != (board.cols * board.rows) as usize {
        return Ok(None);
    }
    Ok(Some(
        corners
            .iter()
            .map(|p| Vector2::new(f64::from(p.x), f64::from(p.y)))
            .collect(),
    ))
}

/// The largest sub-pixel half-window that stays inside one square: beyond it the search window
/// reaches the neighbouring corners and pulls the estimate.
fn max_window(corners: &Vector<Point2f>, board: &BoardSpec) -> i32 {
    let cols = board.cols as usize;
    let mut min_spacing = f32::INFINITY;
    for (i, p) in corners.iter().enumerate() {
        if (i + 1) % cols != 0
            && let Ok(q) = corners.get(i + 1)
        {
            min_spacing = min_spacing.min(((p.x - q.x).powi(2) + (p.y - q.y).powi(2)).sqrt());
        }
        if let Ok(q) = corners.get(i + cols) {
            min_spacing = min_spacing.min(((p.x - q.x).powi(2) + (p.y - q.y).powi(2)).sqrt());
        }
    }
    ((min_spacing / 2.0).floor() as i32 - 1).max(2)
}

/// Variance of the Laplacian: a focus measure, higher when sharper.
pub fn sharpness(gray: &Mat) -> opencv::Result<f64> {
    let mut lap = Mat::default();
    imgproc::laplacian(
        gray,
        &mut lap,
        opencv::core::CV_64F,
        1,
        1.0,
        0.0,
        opencv::core::BORDER_DEFAULT,
    )?;
    let mut mean = Mat::default();
    let mut stddev = Mat::default();
    opencv::core::mean_std_dev(&lap, &mut mean, &mut stddev, &opencv::core::no_array())?;
    let s = *stddev.at::<f64>(0)?;
    Ok(s * s)
}
