//! GeoPackage and GeoJSON output of survey points through GDAL (adapter). Written to a temporary
//! file beside the target and renamed, like every output.

use std::path::Path;

use gdal::DriverManager;
use gdal::spatial_ref::{AxisMappingStrategy, SpatialRef};
use gdal::vector::{
    Feature, Geometry, LayerAccess, LayerOptions, OGRFieldType, OGRwkbGeometryType,
};

use super::write::OutPoint;

/// The GIS formats.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum GisFormat {
    GeoPackage,
    /// RFC 7946 GeoJSON: WGS 84 longitude/latitude, which the caller supplies as positions.
    GeoJson,
}

fn field_list(with_residuals: bool) -> Vec<(&'static str, OGRFieldType::Type)> {
    let mut f = vec![
        ("name", OGRFieldType::OFTString),
        ("role", OGRFieldType::OFTString),
        ("status", OGRFieldType::OFTString),
        ("code", OGRFieldType::OFTString),
        ("height_m", OGRFieldType::OFTReal),
        ("height_kind", OGRFieldType::OFTString),
        ("sigma_e_m", OGRFieldType::OFTReal),
        ("sigma_n_m", OGRFieldType::OFTReal),
        ("sigma_u_m", OGRFieldType::OFTReal),
        ("e_m", OGRFieldType::OFTReal),
        ("n_m", OGRFieldType::OFTReal),
        ("u_m", OGRFieldType::OFTReal),
        ("observations", OGRFieldType::OFTInteger),
    ];
    if with_residuals {
        f.extend([
            ("res_e_m", OGRFieldType::OFTReal),
            ("res_n_m", OGRFieldType::OFTReal),
            ("res_u_m", OGRFieldType::OFTReal),
            ("res_m", OGRFieldType::OFTReal),
        ]);
    }
    f
}

/// Writes points with `crs_wkt` as the layer's SRS (none when empty; GeoJSON: EPSG:4326 regardless).
pub fn write_points(
    path: &Path,
    format: GisFormat,
    crs_wkt: &str,
    height_kind: &str,
    points: &[OutPoint],
) -> Result<(), String> {
    let (driver_name, options): (&str, &[&str]) = match format {
        GisFormat::GeoPackage => ("GPKG", &[]),
        GisFormat::GeoJson => ("GeoJSON", &["RFC7946=YES", "WRITE_NAME=NO"]),
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
        let srs = match format {
            GisFormat::GeoJson => Some(SpatialRef::from_epsg(4326)),
            GisFormat::GeoPackage if crs_wkt.is_empty() => None,
            GisFormat::GeoPackage => Some(SpatialRef::from_wkt(crs_wkt)),
        }
        .transpose()
        .map_err(|e| format!("GDAL cannot use the CRS: {e}"))?
        .map(|mut s| {
            s.set_axis_mapping_strategy(AxisMappingStrategy::TraditionalGisOrder);
            s
        });
        let mut ds = driver
            .create_vector_only(&tmp)
            .map_err(|e| format!("cannot create {}: {e}", path.display()))?;
        let with_res = points.iter().any(|p| p.residual.is_some());
        // The layer borrows the dataset: write in a scope, then close the dataset.
        {
            let layer = ds
                .create_layer(LayerOptions {
                    name: "gcps",
                    srs: srs.as_ref(),
                    ty: OGRwkbGeometryType::wkbPoint25D,
                    options: Some(options),
                })
                .map_err(|e| format!("cannot create the layer: {e}"))?;
            layer
                .create_defn_fields(&field_list(with_res))
                .map_err(|e| e.to_string())?;
            for p in points {
                let mut f = Feature::new(layer.defn()).map_err(|e| e.to_string())?;
                let g = p.gcp;
                let mut set_s = |name: &str, v: &str| -> Result<(), String> {
                    let i = f.field_index(name).map_err(|e| e.to_string())?;
                    f.set_field_string(i, v).map_err(|e| e.to_string())
                };
                set_s("name", &g.name)?;
                set_s("role", &g.role.to_string())?;
                set_s(
                    "status",
                    &g.status.as_ref().map(|s| s.to_string()).unwrap_or_default(),
                )?;
                set_s("code", g.code.as_deref().unwrap_or(""))?;
                set_s("height_kind", height_kind)?;
                let mut set_r = |name: &str, v: Option<f64>| -> Result<(), String> {
                    let i = f.field_index(name).map_err(|e| e.to_string())?;
                    match v.filter(|x| x.is_finite()) {
                        Some(x) => f.set_field_double(i, x),
                        None => f.set_field_null(i),
                    }
                    .map_err(|e| e.to_string())
                };
                set_r("height_m", Some(p.position.z))?;
                set_r("sigma_e_m", g.sigma_m.map(|s| s.x))?;
                set_r("sigma_n_m", g.sigma_m.map(|s| s.y))?;
                set_r("sigma_u_m", g.sigma_m.map(|s| s.z))?;
                set_r("e_m", Some(p.local.x))?;
                set_r("n_m", Some(p.local.y))?;
                set_r("u_m", Some(p.local.z))?;
                if with_res {
                    set_r("res_e_m", p.residual.map(|r| r.residual_m[0]))?;
                    set_r("res_n_m", p.residual.map(|r| r.residual_m[1]))?;
                    set_r("res_u_m", p.residual.map(|r| r.residual_m[2]))?;
                    set_r("res_m", p.residual.map(|r| r.norm_m))?;
                }
                let i = f.field_index("observations").map_err(|e| e.to_string())?;
                f.set_field_integer(i, g.observations.len() as i32)
                    .map_err(|e| e.to_string())?;
                let geom = if p.position.z.is_finite() {
                    let mut g = Geometry::empty(OGRwkbGeometryType::wkbPoint25D)
                        .map_err(|e| e.to_string())?;
                    g.add_point((p.position.x, p.position.y, p.position.z));
                    g
                } else {
                    let mut g =
                        Geometry::empty(OGRwkbGeometryType::wkbPoint).map_err(|e| e.to_string())?;
                    g.add_point_2d((p.position.x, p.position.y));
                    g
                };
                f.set_geometry(geom).map_err(|e| e.to_string())?;
                f.create(&layer)
                    .map_err(|e| format!("cannot write point {}: {e}", g.name))?;
            }
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
