//! Published reference coordinates reproduced through geostride's PROJ adapter, to < 1 cm in
//! both directions.
//!
//! Sources:
//! - IOGP Geospatial Integrity of Geoscience Software (GIGS) test dataset v2.1 (EPSG data
//!   v10.019), conversion tests 5101 part 2 (Transverse Mercator, JHS formulas, WGS 84 / UTM
//!   zone 31N) and 5103 part 1 (Lambert Conic Conformal 2SP, BD72 / Belgian Lambert 72).
//! - Belgian NGI sample data for Lambert 72 (BD72 latitude/longitude to Lambert 72 X, Y,
//!   published to 1 cm).
//! - Belgian NGI definition of Lambert 2008: the geographic position of its false origin, and
//!   an independent implementation of the EPSG Guidance Note 7-2 LCC (2SP) formulas checked
//!   against PROJ across Belgium (no published non-origin point for Lambert 2008 was found).

#![cfg(all(feature = "opencv", feature = "gdal", feature = "onnx"))]

use geostride::survey::crs::Crs;

/// Metres per degree of latitude and longitude near `lat`, to express angular differences.
fn metres_per_degree(lat: f64) -> (f64, f64) {
    (111_320.0 * lat.to_radians().cos(), 110_574.0)
}

fn dms(d: f64, m: f64, s: f64) -> f64 {
    d + m / 60.0 + s / 3600.0
}

fn check(crs: &Crs, lat: f64, lon: f64, e: f64, n: f64, tol_m: f64, what: &str) {
    let (x, y) = crs.from_lon_lat(lon, lat).unwrap();
    assert!(
        (x - e).abs() < tol_m && (y - n).abs() < tol_m,
        "{what}: forward ({x:.4}, {y:.4}) vs ({e}, {n})"
    );
    let (lon2, lat2) = crs.to_lon_lat(e, n).unwrap();
    let (mx, my) = metres_per_degree(lat);
    let (de, dn) = ((lon2 - lon) * mx, (lat2 - lat) * my);
    assert!(
        de.abs() < tol_m && dn.abs() < tol_m,
        "{what}: reverse off by ({de:.4}, {dn:.4}) m"
    );
}

#[test]
fn gigs_5101_utm_zone_31n() {
    let crs = Crs::new("EPSG:32631").unwrap();
    for &(lat, lon, e, n) in &[
        (60.0, 3.0, 500000.0, 6651411.19),
        (60.0, 5.0, 611544.042, 6653097.435),
        (60.0, 8.0, 778711.23, 6661953.041),
        (60.0, -2.0, 221288.77, 6661953.041),
        (40.0, -2.0, 73106.698, 4439746.917),
        (80.0, -2.0, 403186.945, 8885748.708),
        (0.0, -2.0, -57087.12, 0.0),
        (-40.0, -2.0, 73106.698, -4439746.917),
    ] {
        check(&crs, lat, lon, e, n, 0.01, &format!("UTM 31N {lat} {lon}"));
    }
}

#[test]
fn gigs_5103_belgian_lambert_72() {
    let crs = Crs::new("EPSG:31370").unwrap();
    assert!(
        crs.geodetic_name.contains("Belge 1972"),
        "{}",
        crs.geodetic_name
    );
    let mut points = vec![
        (58.0, 5.0, 187742.7, 969521.653),
        (57.0, 5.0, 188698.877, 857277.135),
        (56.0, 5.0, 189652.853, 745291.184),
        (55.0, 5.0, 190604.967, 633523.672),
        (54.0, 5.0, 191555.55, 521935.9),
        (53.0, 5.0, 192504.921, 410490.433),
        (52.15616056, 5.387638889, 219843.841, 316827.604),
        (51.0, 4.0, 124202.936, 187756.876),
        (50.0, 4.0, 123652.406, 76521.628),
        (49.0, 4.0, 123101.889, -34711.068),
        (47.97526111, 3.31372806, 71254.553, -148236.592),
    ];
    let eastings = [
        58108.966, 125304.704, 192504.921, 259697.429, 326870.04, 394010.571, 461106.844,
        528146.69, 595117.95,
    ];
    let northings = [
        411155.591, 410370.504, 410490.433, 411515.356, 413445.087, 416279.276, 420017.408,
        424658.807, 430202.63,
    ];
    for (i, (e, n)) in eastings.iter().zip(northings).enumerate() {
        points.push((53.0, 3.0 + i as f64, *e, n));
    }
    for (lat, lon, e, n) in points {
        check(
            &crs,
            lat,
            lon,
            e,
            n,
            0.01,
            &format!("Lambert 72 {lat} {lon}"),
        );
    }
}

#[test]
fn ngi_lambert_72_sample_points() {
    let crs = Crs::new("EPSG:31370").unwrap();
    for &(lat, lon, x, y) in &[
        (
            dms(51.0, 18.0, 39.48882),
            dms(3.0, 10.0, 3.41519),
            66333.00,
            222966.00,
        ),
        (
            dms(51.0, 8.0, 10.75864),
            dms(5.0, 27.0, 47.75844),
            226696.00,
            203425.00,
        ),
        (
            dms(50.0, 29.0, 57.14179),
            dms(4.0, 3.0, 1.99697),
            127514.00,
            132032.00,
        ),
    ] {
        check(&crs, lat, lon, x, y, 0.01, &format!("NGI {lat} {lon}"));
    }
}

/// EPSG Guidance Note 7-2, Lambert Conic Conformal (2SP), forward formulas, written
/// independently of PROJ. Angles in degrees.
struct Lcc2sp {
    a: f64,
    f: f64,
    lat1: f64,
    lat2: f64,
    lat_f: f64,
    lon_f: f64,
    e_f: f64,
    n_f: f64,
}

impl Lcc2sp {
    fn forward(&self, lat: f64, lon: f64) -> (f64, f64) {
        let e2 = self.f * (2.0 - self.f);
        let e = e2.sqrt();
        let m = |p: f64| p.cos() / (1.0 - e2 * p.sin().powi(2)).sqrt();
        let t = |p: f64| {
            (std::f64::consts::FRAC_PI_4 - p / 2.0).tan()
                / ((1.0 - e * p.sin()) / (1.0 + e * p.sin())).powf(e / 2.0)
        };
        let (lat1, lat2) = (self.lat1.to_radians(), self.lat2.to_radians());
        let n = (m(lat1).ln() - m(lat2).ln()) / (t(lat1).ln() - t(lat2).ln());
        let big_f = m(lat1) / (n * t(lat1).powf(n));
        let r_f = self.a * big_f * t(self.lat_f.to_radians()).powf(n);
        let r = self.a * big_f * t(lat.to_radians()).powf(n);
        let theta = n * (lon - self.lon_f).to_radians();
        (self.e_f + r * theta.sin(), self.n_f + r_f - r * theta.cos())
    }
}

#[test]
fn belgian_lambert_2008() {
    let crs = Crs::new("EPSG:3812").unwrap();
    // NGI: the false origin, 50°47'52.134"N 4°21'33.177"E, is X 649328.0, Y 665262.0.
    check(
        &crs,
        dms(50.0, 47.0, 52.134),
        dms(4.0, 21.0, 33.177),
        649_328.0,
        665_262.0,
        0.01,
        "Lambert 2008 origin",
    );
    // Across Belgium, PROJ agrees with the GN7-2 formulas and NGI's parameters (GRS 1980,
    // standard parallels 49°50' and 51°10', false origin above) to < 1 mm.
    let lambert_2008 = Lcc2sp {
        a: 6_378_137.0,
        f: 1.0 / 298.257_222_101,
        lat1: dms(49.0, 50.0, 0.0),
        lat2: dms(51.0, 10.0, 0.0),
        lat_f: dms(50.0, 47.0, 52.134),
        lon_f: dms(4.0, 21.0, 33.177),
        e_f: 649_328.0,
        n_f: 665_262.0,
    };
    for lat in [49.5, 50.0, 50.5, 51.0, 51.5] {
        for lon in [2.5, 3.5, 4.5, 5.5, 6.4] {
            let (e, n) = lambert_2008.forward(lat, lon);
            check(
                &crs,
                lat,
                lon,
                e,
                n,
                0.001,
                &format!("Lambert 2008 {lat} {lon}"),
            );
        }
    }
}

#[test]
fn snyder_transverse_mercator_example_to_its_published_precision() {
    // USGS Professional Paper 1395, pp. 269-270: Clarke 1866, 40°30'N 73°30'W, zone 18
    // (k0 0.9996): x = 127 106.5 m (+500 000 false easting), y = 4 484 124.4 m, printed to 0.1 m.
    let crs = Crs::new("EPSG:26718").unwrap();
    check(
        &crs,
        40.5,
        -73.5,
        627_106.5,
        4_484_124.4,
        0.05,
        "Snyder UTM",
    );
}
