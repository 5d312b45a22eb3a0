//! DEM loading through GDAL (adapter): any single-band raster GDAL reads, into a plain
//! [`RasterGrid`] and the raster's CRS as WKT.

use std::path::Path;

use gdal::Dataset;

use super::dem::RasterGrid;

/// Reads band 1 of a raster. Returns the grid and the CRS WKT (empty when the raster has none).
pub fn load(path: &Path) -> Result<(RasterGrid, String), String> {
    let ds = Dataset::open(path)
        .map_err(|e| format!("{}: GDAL cannot open it as a raster: {e}", path.display()))?;
    let gt = ds.geo_transform().map_err(|e| {
        format!(
            "{}: no geotransform, so its cells have no positions: {e}",
            path.display()
        )
    })?;
    let band = ds
        .rasterband(1)
        .map_err(|e| format!("{}: no band 1: {e}", path.display()))?;
    let (w, h) = band.size();
    let buf = band
        .read_as::<f64>((0, 0), (w, h), (w, h), None)
        .map_err(|e| format!("{}: cannot read band 1: {e}", path.display()))?;
    let wkt = ds
        .spatial_ref()
        .and_then(|s| s.to_wkt())
        .unwrap_or_default();
    Ok((
        RasterGrid {
            width: w,
            height: h,
            geotransform: gt,
            data: buf.data().to_vec(),
            nodata: band.no_data_value(),
        },
        wkt,
    ))
}
