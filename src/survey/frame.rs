//! The site frame: a local east-north-up frame in metres, tangent to the ellipsoid of the survey's
//! own datum at a reference point, reached through geodetic and ECEF coordinates. No datum change
//! is involved, so the round trip is exact to PROJ's projection accuracy.
//!
//! Heights are carried as the file gives them: `U` is the height of the file's kind relative to
//! the origin's. With orthometric heights the frame is tangent to the ellipsoid at the geoid
//! height of the origin; over a site of a few hundred metres the geoid's slope (typically below
//! 1e-5) changes `U` by millimetres at most.

use std::rc::Rc;

use nalgebra::{Matrix3, Vector2, Vector3};

use super::crs::{Crs, CrsError, HeightKind, Transform};
use super::model::{Role, Survey, SurveyError};
use crate::geom::geodesy::{Geodetic, LocalTangentFrame};
use crate::terrain::{DemSurface, RasterGrid};

/// Where the site frame's origin is.
#[derive(Clone, Debug, PartialEq)]
pub enum Origin {
    /// The centroid of the control points (of all points when there are none).
    Centroid,
    /// A named point of the survey.
    Point(String),
    /// Latitude, longitude (degrees, on the survey's datum) and height (metres, of the survey's kind).
    Geodetic { lat: f64, lon: f64, h: f64 },
}

impl std::str::FromStr for Origin {
    type Err = String;

    /// `centroid`, `point:NAME`, or `LAT,LON,H`.
    fn from_str(s: &str) -> Result<Self, String> {
        if s.eq_ignore_ascii_case("centroid") {
            return Ok(Origin::Centroid);
        }
        if let Some(name) = s.strip_prefix("point:") {
            return Ok(Origin::Point(name.to_string()));
        }
        let v: Vec<f64> = s
            .split(',')
            .map(|x| x.trim().parse::<f64>())
            .collect::<Result<_, _>>()
            .map_err(|_| {
                format!(
                    "expected 'centroid', 'point:NAME' or 'LAT,LON,H', got '{}'",
                    crate::io::clip(s, 40)
                )
            })?;
        match v.as_slice() {
            [lat, lon, h] if lat.abs() <= 90.0 && lon.abs() <= 360.0 => Ok(Origin::Geodetic {
                lat: *lat,
                lon: *lon,
                h: *h,
            }),
            _ => Err(format!(
                "expected 'centroid', 'point:NAME' or 'LAT,LON,H' in degrees and metres, got '{}'",
                crate::io::clip(s, 40)
            )),
        }
    }
}

/// A survey's local metric frame.
pub struct SiteFrame {
    /// `None` for a file in its own local frame, whose coordinates are already local metres.
    pub crs: Option<Crs>,
    pub tangent: Option<LocalTangentFrame>,
    pub height: HeightKind,
    /// How the origin was chosen, for reports.
    pub origin_note: String,
}

impl SiteFrame {
    pub fn new(survey: &Survey, origin: &Origin) -> Result<SiteFrame, SurveyError> {
        let err = |m: String| SurveyError {
            path: survey.source.clone(),
            line: None,
            field: None,
            message: m,
        };
        let Some(spec) = &survey.crs else {
            if *origin != Origin::Centroid {
                return Err(err(
                    "a file in its own local frame keeps its origin; --origin does not apply"
                        .into(),
                ));
            }
            return Ok(SiteFrame {
                crs: None,
                tangent: None,
                height: survey.height.clone(),
                origin_note: "the GCP file's own local frame".into(),
            });
        };
        let crs = Crs::new(spec).map_err(|e| err(e.to_string()))?;
        let geodetic = |x: f64, y: f64, z: f64| -> Result<Geodetic, CrsError> {
            let (lon, lat) = crs.to_lon_lat(x, y)?;
            Ok(Geodetic::from_degrees(lat, lon, z))
        };
        let (origin_geo, note) = match origin {
            Origin::Geodetic { lat, lon, h } => (
                Geodetic::from_degrees(*lat, *lon, *h),
                format!("given: {lat}, {lon}, {h} m"),
            ),
            Origin::Point(name) => {
                let p = survey
                    .point(name)
                    .ok_or_else(|| err(format!("--origin point '{name}' is not in the survey")))?;
                let z = if p.position.z.is_nan() {
                    0.0
                } else {
                    p.position.z
                };
                (
                    geodetic(p.position.x, p.position.y, z).map_err(|e| err(e.to_string()))?,
                    format!("point {name}"),
                )
            }
            Origin::Centroid => {
                let control: Vec<_> = survey
                    .points
                    .iter()
                    .filter(|p| p.role == Role::Control)
                    .collect();
                let (pts, what) = if control.is_empty() {
                    (survey.points.iter().collect::<Vec<_>>(), "all")
                } else {
                    (control, "control")
                };
                if pts.is_empty() {
                    return Err(err("no points to place the frame's origin".into()));
                }
                let with_h: Vec<f64> = pts
                    .iter()
                    .map(|p| p.position.z)
                    .filter(|z| !z.is_nan())
                    .collect();
                let mean_h = if with_h.is_empty() {
                    0.0
                } else {
                    with_h.iter().sum::<f64>() / with_h.len() as f64
                };
                let geos = pts
                    .iter()
                    .map(|p| geodetic(p.position.x, p.position.y, mean_h))
                    .collect::<Result<Vec<_>, _>>()
                    .map_err(|e| err(e.to_string()))?;
                let frame = LocalTangentFrame::at_centroid(crs.ellipsoid, &geos).expect("points");
                (
                    frame.origin,
                    format!("centroid of the {} {what} point(s)", pts.len()),
                )
            }
        };
        Ok(SiteFrame {
            tangent: Some(LocalTangentFrame::new(crs.ellipsoid, origin_geo)),
            height: survey.height.clone(),
            crs: Some(crs),
            origin_note: note,
        })
    }

    /// Source coordinates to local east, north, up (metres). An unknown (NaN) height gives an
    /// unknown `U` and exact `E`, `N`.
    pub fn local_from_source(&self, p: &Vector3<f64>) -> Result<Vector3<f64>, CrsError> {
        let (Some(crs), Some(t)) = (&self.crs, &self.tangent) else {
            return Ok(*p);
        };
        let (lon, lat) = crs.to_lon_lat(p.x, p.y)?;
        let h = if p.z.is_nan() { t.origin.h } else { p.z };
        let mut enu = t.enu_from_geodetic(&Geodetic::from_degrees(lat, lon, h));
        if p.z.is_nan() {
            enu.z = f64::NAN;
        }
        Ok(enu)
    }

    /// Local east, north, up to source coordinates.
    pub fn source_from_local(&self, enu: &Vector3<f64>) -> Result<Vector3<f64>, CrsError> {
        let (Some(crs), Some(t)) = (&self.crs, &self.tangent) else {
            return Ok(*enu);
        };
        let nan_h = enu.z.is_nan();
        let q = if nan_h {
            Vector3::new(enu.x, enu.y, 0.0)
        } else {
            *enu
        };
        let g = t.geodetic_from_enu(&q);
        let (x, y) = crs.from_lon_lat(g.lon.to_degrees(), g.lat.to_degrees())?;
        Ok(Vector3::new(x, y, if nan_h { f64::NAN } else { g.h }))
    }

    /// Local east, north (metres) of a WGS 84 latitude and longitude (degrees) taken as on the
    /// survey's datum (metres apart at most: for telling areas apart, not for surveying). `None`
    /// for a survey in its own local frame.
    pub fn local_from_lat_lon(&self, lat_deg: f64, lon_deg: f64) -> Option<Vector2<f64>> {
        let t = self.tangent.as_ref()?;
        self.crs.as_ref()?;
        let enu = t.enu_from_geodetic(&Geodetic::from_degrees(lat_deg, lon_deg, t.origin.h));
        Some(enu.xy())
    }

    /// Latitude and longitude (degrees) of source coordinates, on the survey's datum.
    pub fn lon_lat(&self, p: &Vector3<f64>) -> Option<Result<(f64, f64), CrsError>> {
        self.crs.as_ref().map(|c| c.to_lon_lat(p.x, p.y))
    }

    /// The local covariance of a point whose source σ are along the grid's east, north and up:
    /// rotated by the grid's convergence and scaled by its scale factor, through the local
    /// Jacobian (central differences of 1 m).
    pub fn local_covariance(
        &self,
        p: &Vector3<f64>,
        sigma_m: &Vector3<f64>,
    ) -> Result<Matrix3<f64>, CrsError> {
        let diagonal = Matrix3::from_diagonal(&sigma_m.component_mul(sigma_m));
        let crs = match &self.crs {
            // Local files, and latitude/longitude, whose σ are already along east and north.
            Some(c) if c.horizontal == super::crs::Horizontal::Projected => c,
            _ => return Ok(diagonal),
        };
        // One metre along each source axis, in source units.
        let step = 1.0 / crs.unit_m;
        let base = Vector3::new(p.x, p.y, if p.z.is_nan() { 0.0 } else { p.z });
        let mut j = Matrix3::zeros();
        for k in 0..3 {
            let h = if k < 2 { step } else { 1.0 };
            let mut a = base;
            let mut b = base;
            a[k] += h;
            b[k] -= h;
            // Per metre of the source axis.
            let col = (self.local_from_source(&a)? - self.local_from_source(&b)?) / 2.0;
            j.set_column(k, &col);
        }
        Ok(j * diagonal * j.transpose())
    }
}

/// A DEM in any CRS as a height surface of the site frame: site positions are taken to the
/// raster's CRS through PROJ (changing datum if they differ), and raster heights, assumed of the
/// survey's kind, become site `U` exactly (the Earth's curvature included). A raster without a
/// CRS must be in the site frame itself.
pub fn dem_surface(
    frame: Rc<SiteFrame>,
    grid: RasterGrid,
    raster_wkt: &str,
) -> Result<DemSurface, CrsError> {
    match (&frame.crs, raster_wkt.trim().is_empty()) {
        (None, true) => Ok(DemSurface {
            grid,
            to_raster: Box::new(|en| Some((en.x, en.y))),
            to_local_height: Box::new(|_, z| Some(z)),
        }),
        (None, false) => Err(CrsError {
            spec: "raster".into(),
            message: "the raster has a CRS but the survey is in its own local frame".into(),
        }),
        (Some(_), true) => Err(CrsError {
            spec: "raster".into(),
            message: "the raster has no CRS; geostride cannot place it in the site frame".into(),
        }),
        (Some(site_crs), false) => {
            let raster_crs = Crs::new(raster_wkt)?;
            let to_raster_t = Transform::new(site_crs, &raster_crs)?;
            let f1 = Rc::clone(&frame);
            let f2 = Rc::clone(&frame);
            Ok(DemSurface {
                grid,
                to_raster: Box::new(move |en: &Vector2<f64>| {
                    let src = f1
                        .source_from_local(&Vector3::new(en.x, en.y, f64::NAN))
                        .ok()?;
                    to_raster_t.apply(src.x, src.y).ok()
                }),
                to_local_height: Box::new(move |en: &Vector2<f64>, z: f64| {
                    let src = f2
                        .source_from_local(&Vector3::new(en.x, en.y, f64::NAN))
                        .ok()?;
                    Some(f2.local_from_source(&Vector3::new(src.x, src.y, z)).ok()?.z)
                }),
            })
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::survey::model::{Gcp, SurveyFormat};

    fn survey(crs: &str, pts: &[(&str, f64, f64, f64)]) -> Survey {
        Survey {
            source: "mem".into(),
            format: SurveyFormat::Csv,
            crs: Some(crs.into()),
            height: HeightKind::Ellipsoidal,
            points: pts
                .iter()
                .enumerate()
                .map(|(i, (n, x, y, z))| Gcp::new(*n, Vector3::new(*x, *y, *z), i + 1))
                .collect(),
            dropped: vec![],
            warnings: vec![],
        }
    }

    #[test]
    fn local_frame_round_trip_is_sub_millimetre_and_metric() {
        let s = survey(
            "EPSG:32631",
            &[
                ("A", 500_000.0, 5_600_000.0, 40.0),
                ("B", 500_100.0, 5_600_000.0, 42.0),
                ("C", 500_000.0, 5_600_100.0, 41.0),
            ],
        );
        let f = SiteFrame::new(&s, &Origin::Centroid).unwrap();
        let locals: Vec<_> = s
            .points
            .iter()
            .map(|p| f.local_from_source(&p.position).unwrap())
            .collect();
        // Centroid at the origin (horizontally), heights relative to the mean.
        let mean = locals.iter().fold(Vector3::zeros(), |a, b| a + b) / 3.0;
        assert!(mean.xy().norm() < 1e-3, "{mean}");
        assert!((locals[1].z - locals[0].z - 2.0).abs() < 1e-3);
        // UTM scale factor near the central meridian is 0.9996: 100 grid metres ≈ 100.04 m.
        let d = (locals[1] - locals[0]).xy().norm();
        assert!((d - 100.0 / 0.9996).abs() < 0.01, "{d}");
        for (p, l) in s.points.iter().zip(&locals) {
            let back = f.source_from_local(l).unwrap();
            assert!(
                (back - p.position).norm() < 1e-4,
                "{back} vs {}",
                p.position
            );
        }
        // A NaN height stays unknown; E and N are still exact.
        let l = f
            .local_from_source(&Vector3::new(500_050.0, 5_600_050.0, f64::NAN))
            .unwrap();
        assert!(l.z.is_nan() && l.x.is_finite());
        let back = f.source_from_local(&l).unwrap();
        assert!((back.xy() - nalgebra::Vector2::new(500_050.0, 5_600_050.0)).norm() < 1e-4);
    }

    #[test]
    fn origins() {
        assert_eq!("point:P1".parse::<Origin>(), Ok(Origin::Point("P1".into())));
        assert_eq!(
            "50.8,4.3,12".parse::<Origin>(),
            Ok(Origin::Geodetic {
                lat: 50.8,
                lon: 4.3,
                h: 12.0
            })
        );
        assert!("91,0,0".parse::<Origin>().is_err());
        let s = survey(
            "EPSG:4326",
            &[("A", 4.3, 50.8, 10.0), ("B", 4.301, 50.8, 10.0)],
        );
        let f = SiteFrame::new(&s, &Origin::Point("A".into())).unwrap();
        assert!(f.local_from_source(&s.points[0].position).unwrap().norm() < 1e-6);
        let e = f.local_from_source(&s.points[1].position).unwrap();
        // 0.001° of longitude at 50.8° N is about 70.5 m.
        assert!((e.x - 70.5).abs() < 0.3 && e.y.abs() < 0.01, "{e}");
        assert!(SiteFrame::new(&s, &Origin::Point("Z".into())).is_err());
    }

    #[test]
    fn local_covariance_is_rotated_by_the_grid_convergence() {
        // Far from the central meridian of UTM 31 (3° E): at 7° E the convergence is about 3°.
        let s = survey("EPSG:32631", &[("A", 780_000.0, 5_650_000.0, 40.0)]);
        let f = SiteFrame::new(&s, &Origin::Centroid).unwrap();
        let c = f
            .local_covariance(&s.points[0].position, &Vector3::new(0.01, 0.03, 0.05))
            .unwrap();
        assert!(c[(0, 1)].abs() > 1e-7, "correlation from the rotation: {c}");
        assert!((c[(2, 2)] - 0.0025).abs() < 1e-8);
        assert!(
            (c.trace() - (0.0001 + 0.0009 + 0.0025)).abs() < 2e-6,
            "scale factor ~1: {}",
            c.trace()
        );
    }
}
