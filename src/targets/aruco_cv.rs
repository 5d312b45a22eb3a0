//! Adapter: ArUco and AprilTag markers found and decoded by OpenCV's aruco module (the marker's
//! centre is then refined by [`super::codes::refine`]), and a marker's cells for the simulator.

use nalgebra::Vector2;
use opencv::core::{Mat, Point2f, Ptr, Vector};
use opencv::prelude::*;

use super::Gray;
use super::codes::{CodeError, Dictionary, Marker, MarkerCells};

fn dictionary(d: &Dictionary) -> opencv::Result<Ptr<opencv::aruco::Dictionary>> {
    let name = opencv::aruco::PREDEFINED_DICTIONARY_NAME::try_from(d.opencv_id)?;
    opencv::aruco::get_predefined_dictionary(name)
}

/// The markers of `d` in the image, each with its outer corners (clockwise from the marker's
/// top-left). Markers down to `min_side_px` across are looked for.
pub fn detect_markers(img: &Gray, d: &Dictionary, min_side_px: f64) -> opencv::Result<Vec<Marker>> {
    let bytes: Vec<u8> = img
        .pixels
        .iter()
        .map(|v| v.round().clamp(0.0, 255.0) as u8)
        .collect();
    let mat = Mat::new_rows_cols_with_data(img.height as i32, img.width as i32, &bytes)?;
    let dict = dictionary(d)?;
    let mut params = opencv::aruco::DetectorParameters::create()?;
    // OpenCV's rates are of the image's larger side: small markers in a large photo.
    let larger = img.width.max(img.height) as f64;
    params.set_min_marker_perimeter_rate((4.0 * min_side_px / larger).min(0.03));
    params.set_corner_refinement_method(opencv::aruco::CORNER_REFINE_SUBPIX);
    let mut corners: Vector<Vector<Point2f>> = Vector::new();
    let mut ids: Vector<i32> = Vector::new();
    let mut rejected: Vector<Vector<Point2f>> = Vector::new();
    opencv::aruco::detect_markers(&mat, &dict, &mut corners, &mut ids, &params, &mut rejected)?;
    let mut out = Vec::with_capacity(ids.len());
    for (id, c) in ids.iter().zip(corners.iter()) {
        if c.len() != 4 || id < 0 {
            continue;
        }
        let p = |k: usize| -> opencv::Result<Vector2<f64>> {
            let q = c.get(k)?;
            Ok(Vector2::new(q.x as f64, q.y as f64))
        };
        out.push(Marker {
            id: id as u32,
            corners: [p(0)?, p(1)?, p(2)?, p(3)?],
        });
    }
    Ok(out)
}

/// Marker `id`'s cells (black as 1), as OpenCV draws it.
pub fn marker_cells(d: &Dictionary, id: u32) -> Result<MarkerCells, CodeError> {
    if id >= d.ids {
        return Err(CodeError::NotInDictionary {
            id,
            dictionary: d.name,
            last: d.ids - 1,
        });
    }
    let draw = || -> opencv::Result<MarkerCells> {
        let dict = dictionary(d)?;
        let n = d.cells as i32;
        // One pixel a cell, with the one-cell black border.
        let mut img = Mat::default();
        opencv::aruco::draw_marker(&dict, id as i32, n + 2, &mut img, 1)?;
        let mut bits = 0u64;
        for r in 0..n {
            for c in 0..n {
                if *img.at_2d::<u8>(r + 1, c + 1)? < 128 {
                    bits |= 1 << (r * n + c);
                }
            }
        }
        Ok(MarkerCells {
            cells: d.cells,
            bits,
        })
    };
    draw().map_err(|e| CodeError::Draw {
        id,
        dictionary: d.name,
        message: e.to_string(),
    })
}
