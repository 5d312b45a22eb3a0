//! Geodetic coordinates, Earth-centred Earth-fixed (ECEF) coordinates and local east-north-up
//! (ENU) frames on an ellipsoid (pure).
//!
//! Angles are radians here; degrees appear only at the CRS boundary.

use nalgebra::{Matrix3, Vector3};

/// A reference ellipsoid.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Ellipsoid {
    /// Semi-major axis, metres.
    pub a: f64,
    /// Flattening `(a − b) / a`.
    pub f: f64,
}

impl Ellipsoid {
    pub const WGS84: Ellipsoid = Ellipsoid {
        a: 6_378_137.0,
        f: 1.0 / 298.257_223_563,
    };
    pub const GRS80: Ellipsoid = Ellipsoid {
        a: 6_378_137.0,
        f: 1.0 / 298.257_222_101,
    };

    pub fn from_axes(a: f64, b: f64) -> Self {
        Ellipsoid { a, f: (a - b) / a }
    }

    pub fn b(&self) -> f64 {
        self.a * (1.0 - self.f)
    }

    /// First eccentricity squared.
    pub fn e2(&self) -> f64 {
        self.f * (2.0 - self.f)
    }
}

/// Latitude and longitude (radians) and height above the ellipsoid (metres).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Geodetic {
    pub lat: f64,
    pub lon: f64,
    pub h: f64,
}

impl Geodetic {
    pub fn from_degrees(lat_deg: f64, lon_deg: f64, h: f64) -> Self {
        Geodetic {
            lat: lat_deg.to_radians(),
            lon: lon_deg.to_radians(),
            h,
        }
    }
}

/// Geodetic to ECEF.
pub fn ecef_from_geodetic(ell: &Ellipsoid, g: &Geodetic) -> Vector3<f64> {
    let e2 = ell.e2();
    let (sl, cl) = g.lat.sin_cos();
    let n = ell.a / (1.0 - e2 * sl * sl).sqrt();
    let (so, co) = g.lon.sin_cos();
    Vector3::new(
        (n + g.h) * cl * co,
        (n + g.h) * cl * so,
        (n * (1.0 - e2) + g.h) * sl,
    )
}

/// ECEF to geodetic, by Newton iteration on the latitude (converges to 1e-12 rad in a few steps
/// for any point outside the Earth's core).
pub fn geodetic_from_ecef(ell: &Ellipsoid, p: &Vector3<f64>) -> Geodetic {
    let e2 = ell.e2();
    let lon = p.y.atan2(p.x);
    let rho = p.x.hypot(p.y);
    // Bowring's initial value, then fixed-point refinement.
    let b = ell.b();
    let ep2 = e2 / (1.0 - e2);
    let theta = (p.z * ell.a).atan2(rho * b);
    let (st, ct) = theta.sin_cos();
    let mut lat = (p.z + ep2 * b * st * st * st).atan2(rho - e2 * ell.a * ct * ct * ct);
    let mut h = 0.0;
    for _ in 0..5 {
        let sl = lat.sin();
        let n = ell.a / (1.0 - e2 * sl * sl).sqrt();
        h = if lat.cos().abs() > 1e-10 {
            rho / lat.cos() - n
        } else {
            p.z.abs() - n * (1.0 - e2)
        };
        let next = p.z.atan2(rho * (1.0 - e2 * n / (n + h)));
        if (next - lat).abs() < 1e-15 {
            lat = next;
            break;
        }
        lat = next;
    }
    let sl = lat.sin();
    let n = ell.a / (1.0 - e2 * sl * sl).sqrt();
    if lat.cos().abs() > 1e-10 {
        h = rho / lat.cos() - n;
    }
    Geodetic { lat, lon, h }
}

/// A local east-north-up frame with its origin on a geodetic point: `p_enu = R (p_ecef − o)`.
#[derive(Clone, Debug, PartialEq)]
pub struct LocalTangentFrame {
    pub ellipsoid: Ellipsoid,
    pub origin: Geodetic,
    origin_ecef: Vector3<f64>,
    /// Rows: east, north and up unit vectors in ECEF.
    enu_from_ecef: Matrix3<f64>,
}

impl LocalTangentFrame {
    pub fn new(ellipsoid: Ellipsoid, origin: Geodetic) -> Self {
        let (sl, cl) = origin.lat.sin_cos();
        let (so, co) = origin.lon.sin_cos();
        #[rustfmt::skip]
        let enu_from_ecef = Matrix3::new(
            -so,       co,       0.0,
            -sl * co, -sl * so,  cl,
             cl * co,  cl * so,  sl,
        );
        LocalTangentFrame {
            ellipsoid,
            origin,
            origin_ecef: ecef_from_geodetic(&ellipsoid, &origin),
            enu_from_ecef,
        }
    }

    /// The frame whose origin is the centroid of points, given as geodetic coordinates: the
    /// ECEF mean, with its height the mean of the heights.
    pub fn at_centroid(ellipsoid: Ellipsoid, points: &[Geodetic]) -> Option<Self> {
        if points.is_empty() {
            return None;
        }
        let n = points.len() as f64;
        let mean = points.iter().fold(Vector3::zeros(), |acc, g| {
            acc + ecef_from_geodetic(&ellipsoid, g)
        }) / n;
        let mut origin = geodetic_from_ecef(&ellipsoid, &mean);
        origin.h = points.iter().map(|g| g.h).sum::<f64>() / n;
        Some(Self::new(ellipsoid, origin))
    }

    pub fn enu_from_geodetic(&self, g: &Geodetic) -> Vector3<f64> {
        self.enu_from_ecef * (ecef_from_geodetic(&self.ellipsoid, g) - self.origin_ecef)
    }

    pub fn geodetic_from_enu(&self, enu: &Vector3<f64>) -> Geodetic {
        geodetic_from_ecef(
            &self.ellipsoid,
            &(self.enu_from_ecef.transpose() * enu + self.origin_ecef),
        )
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn ecef_round_trip_is_exact_to_a_micrometre() {
        let ell = Ellipsoid::GRS80;
        for &(lat, lon, h) in &[
            (50.79, 4.36, 100.0),
            (-35.3, 149.1, -30.0),
            (89.9999, 10.0, 2000.0),
            (0.0, -179.9, 0.0),
            (-89.99, 0.0, 5.0),
        ] {
            let g = Geodetic::from_degrees(lat, lon, h);
            let back = geodetic_from_ecef(&ell, &ecef_from_geodetic(&ell, &g));
            let again = ecef_from_geodetic(&ell, &back);
            assert!(
                (again - ecef_from_geodetic(&ell, &g)).norm() < 1e-6,
                "{lat} {lon}"
            );
            assert!((back.h - h).abs() < 1e-6);
        }
    }

    #[test]
    fn known_ecef_value() {
        // On the equator at the prime meridian the ECEF x is a + h.
        let p = ecef_from_geodetic(&Ellipsoid::WGS84, &Geodetic::from_degrees(0.0, 0.0, 10.0));
        assert!((p - Vector3::new(6_378_147.0, 0.0, 0.0)).norm() < 1e-9);
        // At the pole z is b + h.
        let p = ecef_from_geodetic(&Ellipsoid::WGS84, &Geodetic::from_degrees(90.0, 0.0, 0.0));
        assert!((p.z - Ellipsoid::WGS84.b()).abs() < 1e-6);
    }

    #[test]
    fn enu_axes_point_east_north_up() {
        let ell = Ellipsoid::GRS80;
        let o = Geodetic::from_degrees(51.0, 4.0, 50.0);
        let f = LocalTangentFrame::new(ell, o);
        let north = f.enu_from_geodetic(&Geodetic::from_degrees(51.0 + 1e-5, 4.0, 50.0));
        let east = f.enu_from_geodetic(&Geodetic::from_degrees(51.0, 4.0 + 1e-5, 50.0));
        let up = f.enu_from_geodetic(&Geodetic::from_degrees(51.0, 4.0, 60.0));
        assert!(north.y > 1.0 && north.x.abs() < 1e-6, "{north}");
        assert!(east.x > 0.5 && east.y.abs() < 1e-3, "{east}");
        assert!((up - Vector3::new(0.0, 0.0, 10.0)).norm() < 1e-9);
        let p = Vector3::new(123.4, -56.7, 8.9);
        assert!((f.enu_from_geodetic(&f.geodetic_from_enu(&p)) - p).norm() < 1e-8);
    }
}
