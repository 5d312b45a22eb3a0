//! Vector files through GDAL (adapter): a GeoPackage or GeoJSON dataset written to a temporary
//! file beside the target and renamed when complete, like every output.

use std::path::Path;

use gdal::spatial_ref::{AxisMappingStrategy, SpatialRef};
use gdal::vector::{Feature, OGRFieldType};
use gdal::{Dataset, DriverManager};

/// The GIS formats.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum GisFormat {
    GeoPackage,
    /// RFC 7946 GeoJSON: WGS 84 longitude/latitude, which the caller supplies as positions.
    GeoJson,
}

impl GisFormat {
    /// Layer creation options.
    pub fn layer_options(self) -> &'static [&'static str] {
        match self {
            GisFormat::GeoPackage => &[],
            // 9 decimals of a degree: 0.1 mm (RFC 7946 mode's default of 7 is up to 5 mm off).
            GisFormat::GeoJson => &["RFC7946=YES", "WRITE_NAME=NO", "COORDINATE_PRECISION=9"],
        }
    }
}

/// The spatial reference for a layer: `crs_wkt` for a GeoPackage (none when empty), WGS 84 for
/// GeoJSON; axes in GIS order (easting/longitude first).
pub fn layer_srs(format: GisFormat, crs_wkt: &str) -> Result<Option<SpatialRef>, String> {
    let srs = match format {
        GisFormat::GeoJson => Some(SpatialRef::from_epsg(4326)),
        GisFormat::GeoPackage if crs_wkt.is_empty() => None,
        GisFormat::GeoPackage => Some(SpatialRef::from_wkt(crs_wkt)),
    }
    .transpose()
    .map_err(|e| format!("GDAL cannot use the CRS: {e}"))?;
    Ok(srs.map(|mut s| {
        s.set_axis_mapping_strategy(AxisMappingStrategy::TraditionalGisOrder);
        s
    }))
}

/// Creates the dataset at a temporary path, lets `fill` write its layers, closes it and moves it
/// into place; on any failure nothing is left behind.
pub fn write_dataset(
    path: &Path,
    format: GisFormat,
    fill: impl FnOnce(&mut Dataset) -> Result<(), String>,
) -> Result<(), String> {
    let driver_name = match format {
        GisFormat::GeoPackage => "GPKG",
        GisFormat::GeoJson => "GeoJSON",
    };
    let driver = DriverManager::get_driver_by_name(driver_name)
        .map_err(|e| format!("GDAL has no {driver_name} driver: {e}"))?;
    let dir = match path.parent() {
        Some(p) if !p.as_os_str().is_empty() => p.to_path_buf(),
        _ => std::path::PathBuf::from("."),
    };
    let file_name = path
        .file_name()
        .ok_or("no file name")?
        .to_string_lossy()
        .into_owned();
    let ext = path
        .extension()
        .map(|e| format!(".{}", e.to_string_lossy()))
        .unwrap_or_default();
    let tmp = dir.join(format!(".{file_name}.tmp-{}{ext}", std::process::id()));
    let _ = std::fs::remove_file(&tmp);
    let result = (|| -> Result<(), String> {
        let mut ds = driver
            .create_vector_only(&tmp)
            .map_err(|e| format!("cannot create {}: {e}", path.display()))?;
        if format == GisFormat::GeoPackage {
            // One transaction: SQLite otherwise commits (and syncs) every feature.
            let mut txn = ds
                .start_transaction()
                .map_err(|e| format!("cannot write {}: {e}", path.display()))?;
            fill(&mut txn)?;
            txn.commit()
                .map_err(|e| format!("cannot write {}: {e}", path.display()))?;
        } else {
            fill(&mut ds)?;
        }
        ds.close()
            .map_err(|e| format!("cannot finish {}: {e}", path.display()))?;
        std::fs::rename(&tmp, path).map_err(|e| format!("cannot write {}: {e}", path.display()))
    })();
    if result.is_err() {
        let _ = std::fs::remove_file(&tmp);
    }
    result
}

/// Sets a string field by name.
pub fn set_string(f: &mut Feature, name: &str, v: &str) -> Result<(), String> {
    let i = f.field_index(name).map_err(|e| e.to_string())?;
    f.set_field_string(i, v).map_err(|e| e.to_string())
}

/// Sets a real field by name; `None` or a non-finite value is null.
pub fn set_real(f: &mut Feature, name: &str, v: Option<f64>) -> Result<(), String> {
    let i = f.field_index(name).map_err(|e| e.to_string())?;
    match v.filter(|x| x.is_finite()) {
        Some(x) => f.set_field_double(i, x),
        None => f.set_field_null(i),
    }
    .map_err(|e| e.to_string())
}

/// Sets an integer field by name.
pub fn set_integer(f: &mut Feature, name: &str, v: i32) -> Result<(), String> {
    let i = f.field_index(name).map_err(|e| e.to_string())?;
    f.set_field_integer(i, v).map_err(|e| e.to_string())
}

/// A field definition.
pub type FieldDef = (&'static str, OGRFieldType::Type);
