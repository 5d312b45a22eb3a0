//! Survey file writers for the text formats (pure formatting; the caller supplies coordinates
//! already in the output CRS). GIS formats are in `survey::gis`.

use std::fmt::Write as _;

use nalgebra::Vector3;

use super::crs::HeightKind;
use super::fit::Residual;
use super::model::{Gcp, Role};
use super::read::emlid::COLUMNS_27;
use super::read::opensfm::normalized_from_pixel;

/// Everything a writer needs about one point.
pub struct OutPoint<'a> {
    pub gcp: &'a Gcp,
    /// In the output CRS (or local metres for a local file).
    pub position: Vector3<f64>,
    /// Longitude and latitude (degrees) on the output CRS's datum, when it has one.
    pub lon_lat: Option<(f64, f64)>,
    /// Site-frame east, north, up, metres.
    pub local: Vector3<f64>,
    pub residual: Option<&'a Residual>,
}

/// The output CRS as writers describe it.
pub struct OutCrs {
    /// `EPSG:nnnn` when known, else the specification; `None` for a local frame.
    pub spec: Option<String>,
    pub name: String,
    pub projected: bool,
    pub height: HeightKind,
}

#[derive(Debug, thiserror::Error, PartialEq)]
#[error("{0}")]
pub struct WriteError(pub String);

/// Shortest decimal that reads back to the same double; `NaN` stays `NaN`.
fn num(v: f64) -> String {
    if v.is_nan() {
        "NaN".into()
    } else {
        format!("{v}")
    }
}

pub fn odm(crs: &OutCrs, points: &[OutPoint]) -> Result<String, WriteError> {
    let spec = crs.spec.as_ref().ok_or_else(|| {
        WriteError(
            "an OpenDroneMap gcp_list.txt needs a CRS; this survey is in a local frame".into(),
        )
    })?;
    let mut s = format!("{spec}\n");
    let mut rows = 0;
    for p in points.iter().filter(|p| p.gcp.role != Role::Disabled) {
        for o in &p.gcp.observations {
            let _ = writeln!(
                s,
                "{} {} {} {} {} {} {}",
                num(p.position.x),
                num(p.position.y),
                num(p.position.z),
                num(o.uv.x),
                num(o.uv.y),
                o.image,
                p.gcp.name
            );
            rows += 1;
        }
    }
    if rows == 0 {
        return Err(WriteError(
            "no image observations to write: an OpenDroneMap gcp_list.txt is one row per pick; add picks with --picks".into(),
        ));
    }
    Ok(s)
}

pub fn metashape(crs: &OutCrs, points: &[OutPoint]) -> String {
    let mut s = match (
        &crs.spec,
        crs.spec.as_deref().and_then(|x| x.strip_prefix("EPSG:")),
    ) {
        (_, Some(code)) => format!("#CoordinateSystem: {} (EPSG::{code})\n", crs.name),
        (Some(_), None) => format!("#CoordinateSystem: {}\n", crs.name),
        (None, _) => "#CoordinateSystem: Local Coordinates (m)\n".into(),
    };
    let (x, y) = if crs.projected || crs.spec.is_none() {
        ("X/Easting", "Y/Northing")
    } else {
        ("X/Longitude", "Y/Latitude")
    };
    let _ = writeln!(
        s,
        "#Label,{x},{y},Z/Altitude,X_accuracy,Y_accuracy,Z_accuracy,Enable"
    );
    // Metashape has no disabled state: an unticked marker is a check point.
    for p in points.iter().filter(|p| p.gcp.role != Role::Disabled) {
        let sig = sigma_fields(p.gcp);
        let _ = writeln!(
            s,
            "{},{},{},{},{},{},{},{}",
            csv_field(&p.gcp.name),
            num(p.position.x),
            num(p.position.y),
            num(p.position.z),
            sig[0],
            sig[1],
            sig[2],
            u8::from(p.gcp.role == Role::Control)
        );
    }
    s
}

/// PeTrack `.3dc`: the site frame in centimetres, with the pick of each point when every point
/// has exactly one, in the same image.
pub fn petrack(points: &[OutPoint]) -> Result<String, WriteError> {
    let usable: Vec<&OutPoint> = points
        .iter()
        .filter(|p| p.gcp.role != Role::Disabled)
        .collect();
    if usable
        .iter()
        .any(|p| !p.local.iter().all(|v| v.is_finite()))
    {
        return Err(WriteError(
            "PeTrack needs a height for every point; some have none".into(),
        ));
    }
    let image = usable
        .first()
        .and_then(|p| p.gcp.observations.first())
        .map(|o| &o.image);
    let with_picks = image.is_some()
        && usable
            .iter()
            .all(|p| p.gcp.observations.len() == 1 && Some(&p.gcp.observations[0].image) == image);
    let mut s = format!("{}\n", usable.len());
    for p in usable {
        let cm = p.local * 100.0;
        let _ = write!(s, "{:.3} {:.3} {:.3}", cm.x, cm.y, cm.z);
        if with_picks {
            let uv = p.gcp.observations[0].uv;
            let _ = write!(s, " {} {}", num(uv.x), num(uv.y));
        }
        s.push('\n');
    }
    Ok(s)
}

/// The σ of a point as three fields, empty when unknown.
fn sigma_fields(g: &Gcp) -> [String; 3] {
    g.sigma_m
        .map(|v| [num(v.x), num(v.y), num(v.z)])
        .unwrap_or_default()
}

pub(crate) fn csv_field(s: &str) -> String {
    if s.contains([',', '"', '\n']) {
        format!("\"{}\"", s.replace('"', "\"\""))
    } else {
        s.to_string()
    }
}

/// Emlid's first-generation 27 columns, filled where geostride knows the value.
pub fn emlid(crs: &OutCrs, points: &[OutPoint]) -> Result<String, WriteError> {
    let name = crs.spec.as_ref().map(|_| crs.name.clone()).ok_or_else(|| {
        WriteError("an Emlid CSV needs a CRS; this survey is in a local frame".into())
    })?;
    let mut s = COLUMNS_27.join(",") + "\n";
    for p in points {
        let mut row: Vec<String> = vec![String::new(); COLUMNS_27.len()];
        let mut set = |col: &str, v: String| {
            let i = COLUMNS_27.iter().position(|c| *c == col).expect("column");
            row[i] = v;
        };
        set("Name", csv_field(&p.gcp.name));
        if crs.projected {
            set("Easting", num(p.position.x));
            set("Northing", num(p.position.y));
        }
        if let Some((lon, lat)) = p.lon_lat {
            set("Longitude", num(lon));
            set("Latitude", num(lat));
        }
        match crs.height {
            HeightKind::Ellipsoidal => {
                set("Ellipsoidal height", num(p.position.z));
                set("Elevation", num(p.position.z));
            }
            _ => set("Elevation", num(p.position.z)),
        }
        if let Some(sig) = p.gcp.sigma_m {
            set("Easting RMS", num(sig.x));
            set("Northing RMS", num(sig.y));
            set("Elevation RMS", num(sig.z));
        }
        if let Some(st) = &p.gcp.status {
            set("Solution status", st.to_string());
        }
        if let Some(c) = &p.gcp.code {
            set("Description", csv_field(c));
        }
        set("CS name", csv_field(&name));
        s += &(row.join(",") + "\n");
    }
    Ok(s)
}

/// A plain CSV with everything: source and local coordinates, σ, role, status, residuals.
pub fn csv(points: &[OutPoint]) -> String {
    let mut s = String::from(
        "name,role,x,y,z,sigma_e_m,sigma_n_m,sigma_u_m,status,code,e_m,n_m,u_m,observations",
    );
    let with_res = points.iter().any(|p| p.residual.is_some());
    if with_res {
        s.push_str(",res_e_m,res_n_m,res_u_m,res_m");
    }
    s.push('\n');
    for p in points {
        let g = p.gcp;
        let sig = sigma_fields(g);
        let _ = write!(
            s,
            "{},{},{},{},{},{},{},{},{},{},{},{},{},{}",
            csv_field(&g.name),
            g.role,
            num(p.position.x),
            num(p.position.y),
            num(p.position.z),
            sig[0],
            sig[1],
            sig[2],
            g.status.as_ref().map(|x| x.to_string()).unwrap_or_default(),
            csv_field(g.code.as_deref().unwrap_or("")),
            num(p.local.x),
            num(p.local.y),
            num(p.local.z),
            g.observations.len()
        );
        if with_res {
            match p.residual {
                Some(r) => {
                    let _ = write!(
                        s,
                        ",{},{},{},{}",
                        num(r.residual_m[0]),
                        num(r.residual_m[1]),
                        num(r.residual_m[2]),
                        num(r.norm_m)
                    );
                }
                None => s.push_str(",,,,"),
            }
        }
        s.push('\n');
    }
    s
}

/// OpenSfM `ground_control_points.json`: positions must be WGS 84 longitude/latitude.
pub fn opensfm(points: &[OutPoint], image_size: Option<(u32, u32)>) -> Result<String, WriteError> {
    let mut out = Vec::new();
    for p in points.iter().filter(|p| p.gcp.role != Role::Disabled) {
        let mut obs = Vec::new();
        for o in &p.gcp.observations {
            let (w, h) = image_size.ok_or_else(|| {
                WriteError(
                    "OpenSfM stores picks in normalised image coordinates; pass --image-size WxH"
                        .into(),
                )
            })?;
            obs.push(serde_json::json!({"shot_id": o.image, "projection": normalized_from_pixel(&o.uv, w, h)}));
        }
        let mut pos = serde_json::json!({"latitude": p.position.y, "longitude": p.position.x});
        if p.position.z.is_finite() {
            pos["altitude"] = serde_json::json!(p.position.z);
        }
        out.push(serde_json::json!({"id": p.gcp.name, "position": pos, "observations": obs}));
    }
    let mut s = serde_json::to_string_pretty(&serde_json::json!({ "points": out }))
        .map_err(|e| WriteError(e.to_string()))?;
    s.push('\n');
    Ok(s)
}
