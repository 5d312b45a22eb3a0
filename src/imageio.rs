//! Image file output (OpenCV adapter).

use std::path::Path;

use opencv::core::{CV_8UC1, Mat, Vector};
use opencv::imgcodecs;
use opencv::prelude::*;

use crate::simulate::board::GrayImage;

/// Writes a greyscale image; the format follows the extension. Written to a temporary name and
/// renamed, like every output.
pub fn write_gray(path: &Path, image: &GrayImage) -> Result<(), String> {
    let mat = Mat::new_rows_cols_with_data(image.height as i32, image.width as i32, &image.pixels)
        .map_err(|e| e.to_string())?;
    debug_assert_eq!(mat.typ(), CV_8UC1);
    let ext = path
        .extension()
        .and_then(|e| e.to_str())
        .map(|e| format!(".{e}"))
        .ok_or_else(|| {
            format!(
                "{}: no file extension to choose the image format",
                path.display()
            )
        })?;
    let mut buf = Vector::<u8>::new();
    let ok =
        imgcodecs::imencode(&ext, &mat, &mut buf, &Vector::new()).map_err(|e| e.to_string())?;
    if !ok {
        return Err(format!(
            "{}: OpenCV cannot encode '{ext}' images",
            path.display()
        ));
    }
    crate::io::write_atomic(path, buf.as_slice()).map_err(|e| format!("{}: {e}", path.display()))
}
