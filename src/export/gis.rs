//! Trajectories as a GeoPackage through GDAL (adapter): a line per person and a point per
//! position, in the output CRS. (GeoJSON is written by `export::geojson`.)

use std::path::Path;

use gdal::vector::{
    Feature, Geometry, LayerAccess, LayerOptions, OGRFieldType, OGRwkbGeometryType,
};
use nalgebra::Vector3;

use super::Trajectory;
use crate::gis::{
    FieldDef, GisFormat, layer_srs, set_integer, set_real, set_real_at, write_dataset,
};

const LINE_FIELDS: [FieldDef; 7] = [
    ("id", OGRFieldType::OFTInteger),
    ("first_frame", OGRFieldType::OFTInteger),
    ("last_frame", OGRFieldType::OFTInteger),
    ("duration_s", OGRFieldType::OFTReal),
    ("length_m", OGRFieldType::OFTReal),
    ("mean_speed_m_s", OGRFieldType::OFTReal),
    ("height_m", OGRFieldType::OFTReal),
];

const POINT_FIELDS: [FieldDef; 11] = [
    ("id", OGRFieldType::OFTInteger),
    ("frame", OGRFieldType::OFTInteger),
    ("time_s", OGRFieldType::OFTReal),
    ("e_m", OGRFieldType::OFTReal),
    ("n_m", OGRFieldType::OFTReal),
    ("u_m", OGRFieldType::OFTReal),
    ("speed_m_s", OGRFieldType::OFTReal),
    ("heading_deg", OGRFieldType::OFTReal),
    ("sigma_e_m", OGRFieldType::OFTReal),
    ("sigma_n_m", OGRFieldType::OFTReal),
    ("observed", OGRFieldType::OFTInteger),
];

/// A vertex with its height, or without one (`flat`: the height is unknown, NaN).
fn add_point(g: &mut Geometry, c: &Vector3<f64>, flat: bool) {
    if flat {
        g.add_point_2d((c.x, c.y));
    } else {
        g.add_point((c.x, c.y, c.z));
    }
}

/// Writes the trajectories as a GeoPackage in the CRS `crs_wkt` (none when empty): each point
/// at its `crs` coordinates (a NaN height makes the geometry 2D). `trajectories` gives them
/// afresh for each of the two layers (a long video's are read back from disk, never all in
/// memory).
pub fn write_geopackage<I, T>(
    path: &Path,
    crs_wkt: &str,
    trajectories: impl Fn() -> I,
) -> Result<(), crate::gis::GisError>
where
    I: IntoIterator<Item = std::io::Result<T>>,
    T: std::borrow::Borrow<Trajectory>,
{
    let format = GisFormat::GeoPackage;
    let srs = layer_srs(format, crs_wkt)?;
    write_dataset(path, format, |ds| {
        // A line per person.
        {
            let layer = ds
                .create_layer(LayerOptions {
                    name: "trajectories",
                    srs: srs.as_ref(),
                    ty: OGRwkbGeometryType::wkbLineString25D,
                    options: Some(format.layer_options()),
                })
                .map_err(|e| format!("cannot create the layer: {e}"))?;
            layer
                .create_defn_fields(&LINE_FIELDS)
                .map_err(|e| e.to_string())?;
            for t in trajectories() {
                let t = t.map_err(|e| e.to_string())?;
                let t = t.borrow();
                if t.points.len() < 2 {
                    continue;
                }
                let mut f = Feature::new(layer.defn()).map_err(|e| e.to_string())?;
                let (a, b) = (&t.points[0], &t.points[t.points.len() - 1]);
                set_integer(&mut f, "id", t.id as i32)?;
                set_integer(&mut f, "first_frame", a.frame as i32)?;
                set_integer(&mut f, "last_frame", b.frame as i32)?;
                set_real(&mut f, "duration_s", Some(b.time_s - a.time_s))?;
                set_real(&mut f, "length_m", Some(t.length_m()))?;
                set_real(&mut f, "mean_speed_m_s", Some(t.mean_speed()))?;
                set_real(&mut f, "height_m", Some(t.height_m))?;
                let cs: Vec<Vector3<f64>> = t.points.iter().map(|q| q.crs).collect();
                let flat = cs.iter().any(|c| c.z.is_nan());
                let mut g = Geometry::empty(if flat {
                    OGRwkbGeometryType::wkbLineString
                } else {
                    OGRwkbGeometryType::wkbLineString25D
                })
                .map_err(|e| e.to_string())?;
                for c in &cs {
                    add_point(&mut g, c, flat);
                }
                f.set_geometry(g).map_err(|e| e.to_string())?;
                f.create(&layer)
                    .map_err(|e| format!("cannot write trajectory {}: {e}", t.id))?;
            }
        }
        // A point per position; the times' range for the style.
        let (mut t0, mut t1) = (f64::INFINITY, f64::NEG_INFINITY);
        {
            let layer = ds
                .create_layer(LayerOptions {
                    name: "positions",
                    srs: srs.as_ref(),
                    ty: OGRwkbGeometryType::wkbPoint25D,
                    options: Some(format.layer_options()),
                })
                .map_err(|e| format!("cannot create the layer: {e}"))?;
            layer
                .create_defn_fields(&POINT_FIELDS)
                .map_err(|e| e.to_string())?;
            // Fields by index, looked up once (by name per feature it was a tenth of the time).
            let defn = layer.defn();
            let ix = |name: &str| defn.field_index(name).map_err(|e| e.to_string());
            let [
                id,
                frame,
                time,
                e,
                n,
                u,
                speed,
                heading,
                sigma_e,
                sigma_n,
                observed,
            ] = [
                ix("id")?,
                ix("frame")?,
                ix("time_s")?,
                ix("e_m")?,
                ix("n_m")?,
                ix("u_m")?,
                ix("speed_m_s")?,
                ix("heading_deg")?,
                ix("sigma_e_m")?,
                ix("sigma_n_m")?,
                ix("observed")?,
            ];
            for t in trajectories() {
                let t = t.map_err(|e| e.to_string())?;
                let t = t.borrow();
                for p in &t.points {
                    (t0, t1) = (t0.min(p.time_s), t1.max(p.time_s));
                    let mut f = Feature::new(defn).map_err(|e| e.to_string())?;
                    f.set_field_integer(id, t.id as i32)?;
                    f.set_field_integer(frame, p.frame as i32)?;
                    set_real_at(&mut f, time, p.time_s)?;
                    set_real_at(&mut f, e, p.local.x)?;
                    set_real_at(&mut f, n, p.local.y)?;
                    set_real_at(&mut f, u, p.local.z)?;
                    set_real_at(&mut f, speed, p.velocity.norm())?;
                    set_real_at(&mut f, heading, super::heading_deg(p))?;
                    set_real_at(&mut f, sigma_e, p.sigma_m.x)?;
                    set_real_at(&mut f, sigma_n, p.sigma_m.y)?;
                    f.set_field_integer(observed, i32::from(p.observed))?;
                    let c = p.crs;
                    let flat = c.z.is_nan();
                    let mut g = Geometry::empty(if flat {
                        OGRwkbGeometryType::wkbPoint
                    } else {
                        OGRwkbGeometryType::wkbPoint25D
                    })
                    .map_err(|e| e.to_string())?;
                    add_point(&mut g, &c, flat);
                    f.set_geometry(g).map_err(|e| e.to_string())?;
                    f.create(&layer)
                        .map_err(|e| format!("cannot write a position of {}: {e}", t.id))?;
                }
            }
        }
        // QGIS's styles: lines by identity, points by time.
        let (t0, t1) = if t0.is_finite() { (t0, t1) } else { (0.0, 1.0) };
        crate::gis::add_qgis_styles(
            ds,
            &[
                ("trajectories", super::qgis_style::lines_by_identity()),
                ("positions", super::qgis_style::points_by_time(t0, t1)),
            ],
        )?;
        Ok(())
    })
}
