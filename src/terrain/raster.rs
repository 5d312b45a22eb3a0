//! DEM loading through GDAL (adapter): any single-band raster GDAL reads, into a plain
//! [`RasterGrid`] and the raster's CRS as WKT.

use std::path::Path;

use gdal::Dataset;

use super::dem::RasterGrid;
use crate::io::{FileCtx, FileError};

/// The most cells read from a DEM (8 bytes each: 800 MB at most).
pub const MAX_CELLS: u64 = 100_000_000;

/// Reads band 1 of a raster. Returns the grid and the CRS WKT (empty when the raster has none).
pub fn load(path: &Path) -> Result<(RasterGrid, String), FileError> {
    let fail = |m: String| FileCtx { path }.err(None, None, m);
    let ds =
        Dataset::open(path).map_err(|e| fail(format!("GDAL cannot open it as a raster: {e}")))?;
    let gt = ds.geo_transform().map_err(|e| {
        fail(format!(
            "no geotransform, so its cells have no positions: {e}"
        ))
    })?;
    let band = ds
        .rasterband(1)
        .map_err(|e| fail(format!("no band 1: {e}")))?;
    let (w, h) = band.size();
    if w == 0 || h == 0 || (w as u64) * (h as u64) > MAX_CELLS {
        return Err(fail(format!(
            "{w}x{h} cells; a DEM is read whole, up to {MAX_CELLS} cells (crop it to the site, e.g. with gdal_translate -projwin)"
        )));
    }
    if !(gt.iter().all(|v| v.is_finite()) && gt[1] != 0.0 && gt[5] != 0.0) {
        return Err(fail(format!(
            "its geotransform {gt:?} gives the cells no size"
        )));
    }
    let buf = band
        .read_as::<f64>((0, 0), (w, h), (w, h), None)
        .map_err(|e| fail(format!("cannot read band 1: {e}")))?;
    let wkt = ds
        .spatial_ref()
        .and_then(|s| s.to_wkt())
        .unwrap_or_default();
    Ok((
        RasterGrid {
            width: w,
            height: h,
            geotransform: gt,
            data: buf.into_shape_and_vec().1,
            nodata: band.no_data_value(),
        },
        wkt,
    ))
}
