//! GeoPackage and GeoJSON output of survey points through GDAL (adapter).

use std::path::Path;

use gdal::vector::{
    Feature, Geometry, LayerAccess, LayerOptions, OGRFieldType, OGRwkbGeometryType,
};

use super::write::OutPoint;
pub use crate::gis::GisFormat;
use crate::gis::{layer_srs, set_integer, set_real, set_string, write_dataset};

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
) -> Result<(), crate::gis::GisError> {
    let srs = layer_srs(format, crs_wkt)?;
    write_dataset(path, format, |ds| {
        let with_res = points.iter().any(|p| p.residual.is_some());
        let layer = ds
            .create_layer(LayerOptions {
                name: "gcps",
                srs: srs.as_ref(),
                ty: OGRwkbGeometryType::wkbPoint25D,
                options: Some(format.layer_options()),
            })
            .map_err(|e| format!("cannot create the layer: {e}"))?;
        layer
            .create_defn_fields(&field_list(with_res))
            .map_err(|e| e.to_string())?;
        for p in points {
            let mut f = Feature::new(layer.defn()).map_err(|e| e.to_string())?;
            let g = p.gcp;
            set_string(&mut f, "name", &g.name)?;
            set_string(&mut f, "role", &g.role.to_string())?;
            set_string(
                &mut f,
                "status",
                &g.status.as_ref().map(|s| s.to_string()).unwrap_or_default(),
            )?;
            set_string(&mut f, "code", g.code.as_deref().unwrap_or(""))?;
            set_string(&mut f, "height_kind", height_kind)?;
            set_real(&mut f, "height_m", Some(p.position.z))?;
            set_real(&mut f, "sigma_e_m", g.sigma_m.map(|s| s.x))?;
            set_real(&mut f, "sigma_n_m", g.sigma_m.map(|s| s.y))?;
            set_real(&mut f, "sigma_u_m", g.sigma_m.map(|s| s.z))?;
            set_real(&mut f, "e_m", Some(p.local.x))?;
            set_real(&mut f, "n_m", Some(p.local.y))?;
            set_real(&mut f, "u_m", Some(p.local.z))?;
            if with_res {
                set_real(&mut f, "res_e_m", p.residual.map(|r| r.residual_m[0]))?;
                set_real(&mut f, "res_n_m", p.residual.map(|r| r.residual_m[1]))?;
                set_real(&mut f, "res_u_m", p.residual.map(|r| r.residual_m[2]))?;
                set_real(&mut f, "res_m", p.residual.map(|r| r.norm_m))?;
            }
            set_integer(&mut f, "observations", g.observations.len() as i32)?;
            let geom = if p.position.z.is_finite() {
                let mut g =
                    Geometry::empty(OGRwkbGeometryType::wkbPoint25D).map_err(|e| e.to_string())?;
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
        Ok(())
    })
}

/// A camera for [`write_cameras`]: its centre in the layer's CRS and its attitude.
pub struct CameraPoint<'a> {
    pub image: &'a str,
    /// Easting or longitude, northing or latitude, height.
    pub position: [f64; 3],
    /// `cam_from_world` in the site's east-north-up frame, as a unit quaternion.
    pub quaternion: [f64; 4],
    /// The site frame's east, north, up, metres.
    pub local: [f64; 3],
}

/// Writes camera centres as a point layer `cameras` with `crs_wkt` as its SRS (none when
/// empty).
pub fn write_cameras(
    path: &Path,
    crs_wkt: &str,
    height_kind: &str,
    cameras: &[CameraPoint],
) -> Result<(), crate::gis::GisError> {
    let format = GisFormat::GeoPackage;
    let srs = layer_srs(format, crs_wkt)?;
    write_dataset(path, format, |ds| {
        let layer = ds
            .create_layer(LayerOptions {
                name: "cameras",
                srs: srs.as_ref(),
                ty: OGRwkbGeometryType::wkbPoint25D,
                options: Some(format.layer_options()),
            })
            .map_err(|e| format!("cannot create the layer: {e}"))?;
        let fields = [
            ("image", OGRFieldType::OFTString),
            ("height_m", OGRFieldType::OFTReal),
            ("height_kind", OGRFieldType::OFTString),
            ("e_m", OGRFieldType::OFTReal),
            ("n_m", OGRFieldType::OFTReal),
            ("u_m", OGRFieldType::OFTReal),
            ("qw", OGRFieldType::OFTReal),
            ("qx", OGRFieldType::OFTReal),
            ("qy", OGRFieldType::OFTReal),
            ("qz", OGRFieldType::OFTReal),
        ];
        layer
            .create_defn_fields(&fields)
            .map_err(|e| e.to_string())?;
        for c in cameras {
            let mut f = Feature::new(layer.defn()).map_err(|e| e.to_string())?;
            set_string(&mut f, "image", c.image)?;
            set_real(&mut f, "height_m", Some(c.position[2]))?;
            set_string(&mut f, "height_kind", height_kind)?;
            for (name, v) in ["e_m", "n_m", "u_m"].iter().zip(c.local) {
                set_real(&mut f, name, Some(v))?;
            }
            for (name, v) in ["qw", "qx", "qy", "qz"].iter().zip(c.quaternion) {
                set_real(&mut f, name, Some(v))?;
            }
            let mut g =
                Geometry::empty(OGRwkbGeometryType::wkbPoint25D).map_err(|e| e.to_string())?;
            g.add_point((c.position[0], c.position[1], c.position[2]));
            f.set_geometry(g).map_err(|e| e.to_string())?;
            f.create(&layer).map_err(|e| e.to_string())?;
        }
        Ok(())
    })
}
