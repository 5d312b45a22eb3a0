//! Image file output (OpenCV adapter).

use std::path::{Path, PathBuf};

use opencv::core::{CV_8UC1, Mat, Vector};
use opencv::imgcodecs;
use opencv::prelude::*;

use crate::image::GrayImage;

/// Why an image could not be read, made or written.
#[derive(Debug, thiserror::Error)]
pub enum ImageError {
    /// The file, or its name, cannot be used as an image: the reason.
    #[error("{}: {reason}", path.display())]
    File { path: PathBuf, reason: String },
    /// Writing the encoded image failed.
    #[error("{}: {source}", path.display())]
    Write {
        path: PathBuf,
        #[source]
        source: std::io::Error,
    },
    /// OpenCV failed while drawing or converting.
    #[error(transparent)]
    OpenCv(#[from] opencv::Error),
}

/// An error about the file `path`.
pub fn file_error(path: &Path, reason: impl std::fmt::Display) -> ImageError {
    ImageError::File {
        path: path.to_path_buf(),
        reason: reason.to_string(),
    }
}

/// Whether OpenCV can write an image named `path` (its extension names a format it encodes).
pub fn check_writable(path: &Path) -> Result<(), ImageError> {
    let known = path
        .extension()
        .and_then(|e| e.to_str())
        .is_some_and(|e| imgcodecs::have_image_writer(format!("x.{e}").as_str()).unwrap_or(false));
    if known {
        Ok(())
    } else {
        Err(file_error(
            path,
            "cannot tell the image format from the extension; use .jpg, .png or .tif",
        ))
    }
}

/// Encodes a Mat in the format of `path`'s extension and writes it atomically.
pub(crate) fn encode_to(
    path: &Path,
    mat: &impl opencv::core::ToInputArray,
) -> Result<(), ImageError> {
    let ext = path
        .extension()
        .and_then(|e| e.to_str())
        .map(|e| format!(".{e}"))
        .ok_or_else(|| file_error(path, "no file extension to choose the image format"))?;
    let mut buf = Vector::<u8>::new();
    let ok = imgcodecs::imencode(&ext, mat, &mut buf, &Vector::new())
        .map_err(|e| file_error(path, e))?;
    if !ok {
        return Err(file_error(
            path,
            format!("OpenCV cannot encode '{ext}' images"),
        ));
    }
    crate::io::write_atomic(path, buf.as_slice()).map_err(|source| ImageError::Write {
        path: path.to_path_buf(),
        source,
    })
}

/// Writes a greyscale image; the format follows the extension. Written to a temporary name and
/// renamed, like every output.
pub fn write_gray(path: &Path, image: &GrayImage) -> Result<(), ImageError> {
    let mat = Mat::new_rows_cols_with_data(image.height as i32, image.width as i32, &image.pixels)?;
    debug_assert_eq!(mat.typ(), CV_8UC1);
    encode_to(path, &mat)
}

/// Writes an 8-bit RGB image (row-major); the format follows the extension.
pub fn write_rgb(path: &Path, width: u32, height: u32, rgb: &[u8]) -> Result<(), ImageError> {
    let err = |e: opencv::Error| file_error(path, e);
    let mat = Mat::new_rows_cols_with_data(height as i32, width as i32 * 3, rgb).map_err(err)?;
    let mat = mat.reshape(3, height as i32).map_err(err)?;
    let mut bgr = Mat::default();
    opencv::imgproc::cvt_color_def(&mat, &mut bgr, opencv::imgproc::COLOR_RGB2BGR).map_err(err)?;
    encode_to(path, &bgr)
}

/// 8-bit RGB (row-major) encoded as JPEG at `quality` (1-100).
pub fn encode_rgb_jpeg(
    width: u32,
    height: u32,
    rgb: &[u8],
    quality: u8,
) -> Result<Vec<u8>, ImageError> {
    let path = Path::new("(jpeg)");
    let err = |e: opencv::Error| file_error(path, e);
    let mat = Mat::new_rows_cols_with_data(height as i32, width as i32 * 3, rgb).map_err(err)?;
    let mat = mat.reshape(3, height as i32).map_err(err)?;
    let mut bgr = Mat::default();
    opencv::imgproc::cvt_color_def(&mat, &mut bgr, opencv::imgproc::COLOR_RGB2BGR).map_err(err)?;
    let mut buf = Vector::<u8>::new();
    let params = Vector::from_slice(&[
        imgcodecs::IMWRITE_JPEG_QUALITY,
        i32::from(quality.clamp(1, 100)),
    ]);
    if !imgcodecs::imencode(".jpg", &bgr, &mut buf, &params).map_err(err)? {
        return Err(file_error(path, "OpenCV cannot encode JPEG"));
    }
    Ok(buf.to_vec())
}

/// Tightly packed 8-bit BGR encoded as PNG (lossless: what a page shows is what was searched).
pub fn encode_bgr_png(bgr: &[u8], width: usize, height: usize) -> Result<Vec<u8>, ImageError> {
    let path = Path::new("(png)");
    let err = |e: opencv::Error| file_error(path, e);
    let mat = Mat::new_rows_cols_with_data(height as i32, width as i32 * 3, bgr).map_err(err)?;
    let mat = mat.reshape(3, height as i32).map_err(err)?;
    let mut buf = Vector::<u8>::new();
    // Level 1: a 4K frame in a fraction of a second; the size matters little on 127.0.0.1.
    let params = Vector::from_slice(&[imgcodecs::IMWRITE_PNG_COMPRESSION, 1]);
    if !imgcodecs::imencode(".png", &mat, &mut buf, &params).map_err(err)? {
        return Err(file_error(path, "OpenCV cannot encode PNG"));
    }
    Ok(buf.to_vec())
}

/// A scalar map for [`write_heatmap`]: row-major values, a title, and the unit of the labels
/// (values are multiplied by `scale` for them, e.g. 100 for centimetres).
pub struct HeatMap<'a> {
    pub cols: usize,
    pub rows: usize,
    pub values: &'a [f64],
    pub title: String,
    pub unit: &'a str,
    pub scale: f64,
}

/// Writes a scalar map as a PNG heat map (viridis) with a colour bar and a title. NaN cells are
/// black. The map is scaled up to about `width_px` wide.
pub fn write_heatmap(path: &Path, map: &HeatMap, width_px: i32) -> Result<(), ImageError> {
    let HeatMap {
        cols,
        rows,
        values,
        title,
        unit,
        scale,
    } = map;
    let (cols, rows, scale) = (*cols, *rows, *scale);
    use opencv::core::{CV_8UC3, Point, Rect, Scalar, Size};
    use opencv::imgproc;
    let err = |e: opencv::Error| file_error(path, e);
    let vmax = values
        .iter()
        .copied()
        .filter(|v| v.is_finite())
        .fold(0.0, f64::max);
    let grey: Vec<u8> = values
        .iter()
        .map(|v| {
            if v.is_finite() && vmax > 0.0 {
                (v / vmax * 255.0).round().clamp(0.0, 255.0) as u8
            } else {
                0
            }
        })
        .collect();
    let small = Mat::new_rows_cols_with_data(rows as i32, cols as i32, &grey).map_err(err)?;
    let mut coloured = Mat::default();
    imgproc::apply_color_map(&small, &mut coloured, imgproc::COLORMAP_VIRIDIS).map_err(err)?;
    // NaN cells black.
    for (i, v) in values.iter().enumerate() {
        if !v.is_finite() {
            let (r, c) = ((i / cols) as i32, (i % cols) as i32);
            *coloured
                .at_2d_mut::<opencv::core::Vec3b>(r, c)
                .map_err(err)? = opencv::core::Vec3b::from([0, 0, 0]);
        }
    }
    let map_w = width_px.max(64);
    let map_h = ((map_w as f64) * rows as f64 / cols as f64)
        .round()
        .max(1.0) as i32;
    let mut big = Mat::default();
    imgproc::resize(
        &coloured,
        &mut big,
        Size::new(map_w, map_h),
        0.0,
        0.0,
        imgproc::INTER_LINEAR,
    )
    .map_err(err)?;

    // Canvas: title band on top, colour bar and labels on the right.
    let (top, bar_w, right) = (40, 24, 110);
    let mut canvas = Mat::new_rows_cols_with_default(
        map_h + top + 20,
        map_w + right + 20,
        CV_8UC3,
        Scalar::all(255.0),
    )
    .map_err(err)?;
    let mut roi = Mat::roi_mut(&mut canvas, Rect::new(10, top, map_w, map_h)).map_err(err)?;
    big.copy_to(&mut roi).map_err(err)?;
    let ramp: Vec<u8> = (0..map_h)
        .map(|y| (255.0 * (1.0 - y as f64 / (map_h - 1).max(1) as f64)).round() as u8)
        .collect();
    let ramp = Mat::new_rows_cols_with_data(map_h, 1, &ramp).map_err(err)?;
    let mut ramp_c = Mat::default();
    imgproc::apply_color_map(&ramp, &mut ramp_c, imgproc::COLORMAP_VIRIDIS).map_err(err)?;
    let mut bar = Mat::default();
    imgproc::resize(
        &ramp_c,
        &mut bar,
        Size::new(bar_w, map_h),
        0.0,
        0.0,
        imgproc::INTER_NEAREST,
    )
    .map_err(err)?;
    let x_bar = 10 + map_w + 15;
    let mut roi = Mat::roi_mut(&mut canvas, Rect::new(x_bar, top, bar_w, map_h)).map_err(err)?;
    bar.copy_to(&mut roi).map_err(err)?;
    let black = Scalar::new(0.0, 0.0, 0.0, 0.0);
    for k in 0..=4 {
        let f = f64::from(k) / 4.0;
        let y = top + ((1.0 - f) * f64::from(map_h - 1)).round() as i32;
        let label = format!("{:.1} {unit}", vmax * f * scale);
        imgproc::put_text(
            &mut canvas,
            &label,
            Point::new(x_bar + bar_w + 5, y + 5),
            imgproc::FONT_HERSHEY_SIMPLEX,
            0.4,
            black,
            1,
            imgproc::LINE_AA,
            false,
        )
        .map_err(err)?;
    }
    imgproc::put_text(
        &mut canvas,
        title,
        Point::new(10, 25),
        imgproc::FONT_HERSHEY_SIMPLEX,
        0.55,
        black,
        1,
        imgproc::LINE_AA,
        false,
    )
    .map_err(err)?;
    encode_to(path, &canvas)
}

/// An image file in colour as tightly packed BGR bytes, width and height (pure code's frame).
pub fn read_bgr_bytes(path: &Path) -> Result<(Vec<u8>, usize, usize), ImageError> {
    let name = path
        .to_str()
        .ok_or_else(|| file_error(path, "the file name is not valid UTF-8"))?;
    if !path.is_file() {
        return Err(file_error(path, "no such file"));
    }
    crate::imageheader::check_file(path).map_err(|e| file_error(path, e))?;
    let m = opencv::imgcodecs::imread(name, opencv::imgcodecs::IMREAD_COLOR)
        .map_err(|e| file_error(path, e))?;
    if m.empty() {
        return Err(file_error(path, "not an image OpenCV can read"));
    }
    let m = if m.is_continuous() {
        m
    } else {
        m.try_clone().map_err(|e| file_error(path, e))?
    };
    let bytes = m.data_bytes().map_err(|e| file_error(path, e))?.to_vec();
    Ok((bytes, m.cols() as usize, m.rows() as usize))
}
