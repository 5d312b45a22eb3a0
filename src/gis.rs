//! Vector files through GDAL (adapter): a GeoPackage or GeoJSON dataset written to a temporary
//! file beside the target and renamed when complete, like every output.

use std::path::{Path, PathBuf};

use gdal::spatial_ref::{AxisMappingStrategy, SpatialRef};
use gdal::vector::{Feature, LayerAccess, OGRFieldType};
use gdal::{Dataset, DriverManager};

/// Why a vector file could not be written.
#[derive(Debug, thiserror::Error)]
pub enum GisError {
    /// GDAL cannot use the output's CRS.
    #[error("GDAL cannot use the CRS: {0}")]
    Crs(#[source] gdal::errors::GdalError),
    /// GDAL was built without the format's driver.
    #[error("GDAL has no {driver} driver: {source}")]
    NoDriver {
        driver: &'static str,
        #[source]
        source: gdal::errors::GdalError,
    },
    /// Creating, writing or finishing the file failed.
    #[error("cannot {what} {}: {reason}", path.display())]
    File {
        what: &'static str,
        path: PathBuf,
        reason: String,
    },
    /// A feature's field could not be set.
    #[error(transparent)]
    Gdal(#[from] gdal::errors::GdalError),
    /// What the caller's layers reported.
    #[error("{0}")]
    Layers(String),
    /// QGIS's style table could not be added.
    #[error("cannot write the QGIS styles: {0}")]
    Styles(#[source] gdal::errors::GdalError),
}

impl From<String> for GisError {
    fn from(e: String) -> GisError {
        GisError::Layers(e)
    }
}

/// The GIS formats.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum GisFormat {
    GeoPackage,
    /// RFC 7946 GeoJSON: WGS 84 longitude/latitude, which the caller supplies as positions.
    GeoJson,
}

impl GisFormat {
    /// Layer creation options.
    pub(crate) fn layer_options(self) -> &'static [&'static str] {
        match self {
            // The spatial index is built once the features are in (`write_dataset`): inserting
            // into it feature by feature took 5.5 s of 6.2 s for 246 000 points, in bulk 1.7 s.
            GisFormat::GeoPackage => &["SPATIAL_INDEX=NO"],
            // 9 decimals of a degree: 0.1 mm (RFC 7946 mode's default of 7 is up to 5 mm off).
            GisFormat::GeoJson => &["RFC7946=YES", "WRITE_NAME=NO", "COORDINATE_PRECISION=9"],
        }
    }
}

/// Builds each GeoPackage layer's spatial index (R-tree) in one pass, as GDAL would have built
/// it feature by feature (QGIS uses it to draw only what is in view).
fn spatial_indexes(ds: &Dataset) -> Result<(), String> {
    let layers: Vec<(String, String)> = ds
        .layers()
        .filter_map(|l| {
            // SAFETY: `l` is a live layer of the open dataset `ds`; GDAL returns its own string, never null.
            let geom = unsafe { gdal_sys::OGR_L_GetGeometryColumn(l.c_layer()) };
            // SAFETY: a NUL-terminated string the layer owns (an empty one without a geometry column), copied at once.
            let geom = unsafe { std::ffi::CStr::from_ptr(geom) }
                .to_string_lossy()
                .into_owned();
            (!geom.is_empty()).then(|| (l.name(), geom))
        })
        .collect();
    for (layer, geom) in layers {
        let quote = |s: &str| s.replace('\'', "''");
        ds.execute_sql(
            format!(
                "SELECT CreateSpatialIndex('{}', '{}')",
                quote(&layer),
                quote(&geom)
            ),
            None,
            gdal::vector::sql::Dialect::DEFAULT,
        )
        .map_err(|e| format!("cannot index layer {layer}: {e}"))?;
    }
    Ok(())
}

/// Adds QGIS's `layer_styles` table to a GeoPackage being written: each `(layer, QML)` the
/// style QGIS applies when the layer is opened. Registered as an attributes table; its time
/// stamps fixed like the GeoPackage's.
pub(crate) fn add_qgis_styles(ds: &Dataset, styles: &[(&str, String)]) -> Result<(), GisError> {
    let q = |s: &str| s.replace('\'', "''");
    let mut sql = vec![
        "CREATE TABLE layer_styles (id INTEGER PRIMARY KEY AUTOINCREMENT, f_table_catalog TEXT(256), \
         f_table_schema TEXT(256), f_table_name TEXT(256), f_geometry_column TEXT(256), \
         styleName TEXT(30), styleQML TEXT, styleSLD TEXT, useAsDefault BOOLEAN, description TEXT, \
         owner TEXT(30), ui TEXT(30), update_time DATETIME)"
            .to_string(),
        format!(
            "INSERT INTO gpkg_contents (table_name, data_type, identifier, description, last_change) \
             VALUES ('layer_styles', 'attributes', 'layer_styles', 'QGIS layer styles', '{FIXED_DATE}')"
        ),
    ];
    for (layer, qml) in styles {
        sql.push(format!(
            "INSERT INTO layer_styles (f_table_catalog, f_table_schema, f_table_name, f_geometry_column, \
             styleName, styleQML, styleSLD, useAsDefault, description, owner, ui, update_time) \
             VALUES ('', '', '{}', 'geom', '{}', '{}', '', 1, 'geostride', '', NULL, '{FIXED_DATE}')",
            q(layer),
            q(layer),
            q(qml)
        ));
    }
    for s in sql {
        ds.execute_sql(&s, None, gdal::vector::sql::Dialect::DEFAULT)
            .map_err(GisError::Styles)?;
    }
    Ok(())
}

/// The spatial reference for a layer: `crs_wkt` for a GeoPackage (none when empty), WGS 84 for
/// GeoJSON; axes in GIS order (easting/longitude first).
pub(crate) fn layer_srs(format: GisFormat, crs_wkt: &str) -> Result<Option<SpatialRef>, GisError> {
    let srs = match format {
        GisFormat::GeoJson => Some(SpatialRef::from_epsg(4326)),
        GisFormat::GeoPackage if crs_wkt.is_empty() => None,
        GisFormat::GeoPackage => Some(SpatialRef::from_wkt(crs_wkt)),
    }
    .transpose()
    .map_err(GisError::Crs)?;
    Ok(srs.map(|mut s| {
        s.set_axis_mapping_strategy(AxisMappingStrategy::TraditionalGisOrder);
        s
    }))
}

/// Creates the dataset at a temporary path, lets `fill` write its layers, closes it and moves it
/// into place; on any failure nothing is left behind.
pub(crate) fn write_dataset(
    path: &Path,
    format: GisFormat,
    fill: impl FnOnce(&mut Dataset) -> Result<(), GisError>,
) -> Result<(), GisError> {
    let driver_name = match format {
        GisFormat::GeoPackage => "GPKG",
        GisFormat::GeoJson => "GeoJSON",
    };
    let driver =
        DriverManager::get_driver_by_name(driver_name).map_err(|source| GisError::NoDriver {
            driver: driver_name,
            source,
        })?;
    let ext = path
        .extension()
        .map(|e| format!(".{}", e.to_string_lossy()))
        .unwrap_or_default();
    let cannot = |what: &'static str, e: &dyn std::fmt::Display| GisError::File {
        what,
        path: path.to_path_buf(),
        reason: e.to_string(),
    };
    let fill = |tmp: &Path| -> Result<(), GisError> {
        if format == GisFormat::GeoPackage {
            // GeoPackage stamps its tables with the time of writing: a fixed one makes two
            // identical runs give identical files.
            gdal::config::set_config_option("OGR_CURRENT_DATE", FIXED_DATE)
                .map_err(|e| cannot("write", &e))?;
            // SQLite's page cache, MB (its default, 2 MB, made building the spatial index of
            // 246 000 points 2.2 s instead of 1.75 s while other outputs were being written;
            // 8 MB was as fast as 128, and is all a long video's GeoPackage adds to memory).
            gdal::config::set_config_option("OGR_SQLITE_CACHE", "8")
                .map_err(|e| cannot("write", &e))?;
        }
        // SAFETY: resets this thread's GDAL error state; takes nothing.
        unsafe { gdal_sys::CPLErrorReset() };
        let mut ds = driver
            .create_vector_only(tmp)
            .map_err(|e| cannot("create", &e))?;
        if format == GisFormat::GeoPackage {
            // One transaction: SQLite otherwise commits (and syncs) every feature.
            let mut txn = ds.start_transaction().map_err(|e| cannot("write", &e))?;
            fill(&mut txn)?;
            spatial_indexes(&txn).map_err(|e| cannot("index", &e))?;
            txn.commit().map_err(|e| cannot("write", &e))?;
        } else {
            fill(&mut ds)?;
        }
        ds.close().map_err(|e| cannot("finish", &e))?;
        // GDAL 3.6 does not return errors from closing (a full disk while GeoJSON's last bytes
        // are written): its error state and the file's end say whether it is whole.
        // SAFETY: reads this thread's GDAL error state; takes nothing.
        if unsafe { gdal_sys::CPLGetLastErrorType() } >= gdal_sys::CPLErr::CE_Failure {
            // SAFETY: GDAL's last message on this thread, an empty string when none: never null, copied at once.
            let msg = unsafe { std::ffi::CStr::from_ptr(gdal_sys::CPLGetLastErrorMsg()) };
            return Err(cannot("write", &msg.to_string_lossy()));
        }
        if format == GisFormat::GeoJson && !ends_with_json_close(tmp) {
            return Err(cannot(
                "write",
                &"the file was cut short (is the disk full?)",
            ));
        }
        Ok(())
    };
    crate::io::write_atomic_by_name(path, &ext, fill, |e| cannot("write", &e))
}

/// Writes an 8-bit RGBA image as a GeoTIFF (deflate, tiled; the alpha band marks where there
/// is no image): `geo_transform` GDAL's `[x0, dx, 0, y0, 0, -dy]` of the top-left corner,
/// `crs_wkt` empty for a local frame. Written to a temporary file and moved into place.
pub(crate) fn write_geotiff(
    path: &Path,
    rgba: &[u8],
    (width, height): (usize, usize),
    geo_transform: [f64; 6],
    crs_wkt: &str,
) -> Result<(), GisError> {
    use gdal::raster::{Buffer, ColorInterpretation, RasterCreationOptions};
    let cannot = |what: &'static str, e: &dyn std::fmt::Display| GisError::File {
        what,
        path: path.to_path_buf(),
        reason: e.to_string(),
    };
    if rgba.len() != width * height * 4 {
        return Err(cannot(
            "write",
            &"the image is not width × height RGBA pixels",
        ));
    }
    let driver =
        DriverManager::get_driver_by_name("GTiff").map_err(|source| GisError::NoDriver {
            driver: "GTiff",
            source,
        })?;
    let fill = |tmp: &Path| -> Result<(), GisError> {
        let options = RasterCreationOptions::from_iter([
            "COMPRESS=DEFLATE",
            "TILED=YES",
            "PHOTOMETRIC=RGB",
            "ALPHA=YES",
        ]);
        let mut ds = driver
            .create_with_band_type_with_options::<u8, _>(tmp, width, height, 4, &options)
            .map_err(|e| cannot("create", &e))?;
        ds.set_geo_transform(&geo_transform)
            .map_err(|e| cannot("write", &e))?;
        if !crs_wkt.is_empty() {
            let srs = SpatialRef::from_wkt(crs_wkt).map_err(GisError::Crs)?;
            ds.set_spatial_ref(&srs).map_err(|e| cannot("write", &e))?;
        }
        let interp = [
            ColorInterpretation::RedBand,
            ColorInterpretation::GreenBand,
            ColorInterpretation::BlueBand,
            ColorInterpretation::AlphaBand,
        ];
        for (k, ci) in interp.into_iter().enumerate() {
            let plane: Vec<u8> = rgba.iter().skip(k).step_by(4).copied().collect();
            let mut band = ds.rasterband(k + 1).map_err(|e| cannot("write", &e))?;
            band.set_color_interpretation(ci)
                .map_err(|e| cannot("write", &e))?;
            let mut buf = Buffer::new((width, height), plane);
            band.write((0, 0), (width, height), &mut buf)
                .map_err(|e| cannot("write", &e))?;
        }
        // SAFETY: resets this thread's GDAL error state; takes nothing.
        unsafe { gdal_sys::CPLErrorReset() };
        ds.close().map_err(|e| cannot("finish", &e))?;
        // GDAL 3.6 does not return errors from closing (a full disk while the last tiles are
        // flushed): its error state, and reading every pixel back, say whether it is whole.
        // SAFETY: reads this thread's GDAL error state; takes nothing.
        if unsafe { gdal_sys::CPLGetLastErrorType() } >= gdal_sys::CPLErr::CE_Failure {
            // SAFETY: GDAL's last message on this thread, an empty string when none: never null, copied at once.
            let msg = unsafe { std::ffi::CStr::from_ptr(gdal_sys::CPLGetLastErrorMsg()) };
            return Err(cannot("write", &msg.to_string_lossy()));
        }
        let back = Dataset::open(tmp).map_err(|e| cannot("read back", &e))?;
        for k in 1..=4 {
            let band = back.rasterband(k).map_err(|e| cannot("read back", &e))?;
            let data = band
                .read_as::<u8>((0, 0), (width, height), (width, height), None)
                .map_err(|e| cannot("read back", &e))?;
            if data
                .data()
                .iter()
                .step_by(97)
                .zip(rgba.iter().skip(k - 1).step_by(4 * 97))
                .any(|(a, b)| a != b)
            {
                return Err(cannot(
                    "write",
                    &"the file reads back other pixels (is the disk full?)",
                ));
            }
        }
        drop(back);
        Ok(())
    };
    crate::io::write_atomic_by_name(path, ".tif", fill, |e| cannot("write", &e))
}

/// The time stamp written into GeoPackages (see [`write_dataset`]).
pub const FIXED_DATE: &str = "2000-01-01T00:00:00.000Z";

/// Whether a GeoJSON file ends with its closing brace (whitespace aside).
fn ends_with_json_close(path: &Path) -> bool {
    use std::io::{Read, Seek, SeekFrom};
    let Ok(mut f) = std::fs::File::open(path) else {
        return false;
    };
    let len = f.metadata().map(|m| m.len()).unwrap_or(0);
    let mut tail = Vec::new();
    f.seek(SeekFrom::Start(len.saturating_sub(64))).is_ok()
        && f.read_to_end(&mut tail).is_ok()
        && tail.trim_ascii_end().ends_with(b"}")
}

/// Sets a string field by name.
pub(crate) fn set_string(f: &mut Feature, name: &str, v: &str) -> Result<(), GisError> {
    let i = f.field_index(name)?;
    Ok(f.set_field_string(i, v)?)
}

/// Sets a real field by name; `None` or a non-finite value is null.
pub(crate) fn set_real(f: &mut Feature, name: &str, v: Option<f64>) -> Result<(), GisError> {
    let i = f.field_index(name)?;
    match v.filter(|x| x.is_finite()) {
        Some(x) => f.set_field_double(i, x)?,
        None => f.set_field_null(i)?,
    }
    Ok(())
}

/// Sets a real field by index (a NaN or infinite value as null).
pub(crate) fn set_real_at(f: &mut Feature, i: usize, v: f64) -> Result<(), GisError> {
    if v.is_finite() {
        f.set_field_double(i, v)?;
    } else {
        f.set_field_null(i)?;
    }
    Ok(())
}

/// Sets an integer field by name.
pub(crate) fn set_integer(f: &mut Feature, name: &str, v: i32) -> Result<(), GisError> {
    let i = f.field_index(name)?;
    Ok(f.set_field_integer(i, v)?)
}

/// A field definition.
pub type FieldDef = (&'static str, OGRFieldType::Type);
