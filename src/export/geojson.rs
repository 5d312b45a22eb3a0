//! Trajectories as GeoJSON (RFC 7946), pure formatting: a line per person
//! (`trajectories.geojson`) and a point per position (`positions.geojson`), positions in WGS 84
//! longitude, latitude and ellipsoidal height, taken from each point's `crs` (2D where the
//! height is unknown, NaN).
//!
//! Written here rather than through GDAL: GDAL's writer took 3 s for 246 000 points, most of the
//! merge of a split run.

use std::fmt::Write as _;

use nalgebra::Vector3;

use super::Trajectory;

/// Decimals of a degree: 9 is 0.1 mm (RFC 7946 suggests 6 to 7, up to 5 cm and 5 mm off).
const DECIMALS: usize = 9;

/// A coordinate to `DECIMALS` decimals, without trailing zeros.
fn coordinate(s: &mut String, v: f64) {
    let start = s.len();
    let _ = write!(s, "{}", crate::text::fixed::Fixed::<DECIMALS>(v));
    if s[start..].contains('.') {
        let trimmed = s.trim_end_matches('0').trim_end_matches('.').len();
        s.truncate(trimmed);
    }
    if &s[start..] == "-0" {
        s.truncate(start);
        s.push('0');
    }
}

/// `[lon, lat, h]`, or `[lon, lat]` when `flat`.
fn position(s: &mut String, c: &Vector3<f64>, flat: bool) {
    s.push('[');
    coordinate(s, c.x);
    s.push(',');
    coordinate(s, c.y);
    if !flat {
        s.push(',');
        coordinate(s, c.z);
    }
    s.push(']');
}

/// A property value: the shortest decimal that reads back as the same number; null when not
/// finite (JSON has no NaN).
fn real(s: &mut String, name: &str, v: f64) {
    if v.is_finite() {
        let _ = write!(s, "\"{name}\":{v:?}");
    } else {
        let _ = write!(s, "\"{name}\":null");
    }
}

fn integer(s: &mut String, name: &str, v: i64) {
    let _ = write!(s, "\"{name}\":{v}");
}

const HEAD: &str = "{\"type\":\"FeatureCollection\",\"features\":[\n";
const TAIL: &str = "\n]}\n";

/// What an area feature is: a polygon and its area, or a line and its length.
#[derive(Clone, Copy, Debug)]
pub enum Shape {
    Polygon { area_m2: f64 },
    Line { length_m: f64 },
}

/// A FeatureCollection written to `w` one trajectory at a time (an hour's positions never stand
/// whole in memory); `wgs` gives each trajectory's positions in WGS 84, point by point.
pub struct Features<'w> {
    out: crate::text::Pieces<'w>,
    first: bool,
}

impl<'w> Features<'w> {
    pub fn new(w: &'w mut dyn std::io::Write) -> Features<'w> {
        let mut out = crate::text::Pieces::new(w);
        out.s.push_str(HEAD);
        Features { out, first: true }
    }

    /// The text of the next feature, after its separator.
    fn next(&mut self) -> &mut String {
        if !self.first {
            self.out.s.push_str(",\n");
        }
        self.first = false;
        &mut self.out.s
    }

    /// The trajectory as a LineString feature (none under two points) with its id, frames,
    /// duration, length, mean speed and head height.
    pub fn line(&mut self, t: &Trajectory, wgs: &[Vector3<f64>]) -> std::io::Result<()> {
        if t.points.len() < 2 {
            return Ok(());
        }
        let s = self.next();
        let (a, b) = (&t.points[0], &t.points[t.points.len() - 1]);
        s.push_str("{\"type\":\"Feature\",\"properties\":{");
        integer(s, "id", t.id as i64);
        s.push(',');
        integer(s, "first_frame", a.frame as i64);
        s.push(',');
        integer(s, "last_frame", b.frame as i64);
        s.push(',');
        real(s, "duration_s", b.time_s - a.time_s);
        s.push(',');
        real(s, "length_m", t.length_m());
        s.push(',');
        real(s, "mean_speed_m_s", t.mean_speed());
        s.push(',');
        real(s, "height_m", t.height_m);
        s.push_str("},\"geometry\":{\"type\":\"LineString\",\"coordinates\":[");
        let flat = wgs.iter().any(|c| c.z.is_nan());
        for (k, c) in wgs.iter().enumerate() {
            if k > 0 {
                s.push(',');
            }
            position(s, c, flat);
        }
        s.push_str("]}}");
        self.out.done_piece()
    }

    /// One Point feature per trajectory point, with the fields of the GeoPackage's `positions`
    /// layer.
    pub fn points(&mut self, t: &Trajectory, wgs: &[Vector3<f64>]) -> std::io::Result<()> {
        for (p, c) in t.points.iter().zip(wgs) {
            let s = self.next();
            s.push_str("{\"type\":\"Feature\",\"properties\":{");
            integer(s, "id", t.id as i64);
            s.push(',');
            integer(s, "frame", p.frame as i64);
            s.push(',');
            real(s, "time_s", p.time_s);
            s.push(',');
            real(s, "e_m", p.local.x);
            s.push(',');
            real(s, "n_m", p.local.y);
            s.push(',');
            real(s, "u_m", p.local.z);
            s.push(',');
            real(s, "speed_m_s", p.velocity.norm());
            s.push(',');
            real(s, "heading_deg", super::heading_deg(p));
            s.push(',');
            real(s, "sigma_e_m", p.sigma_m.x);
            s.push(',');
            real(s, "sigma_n_m", p.sigma_m.y);
            s.push(',');
            integer(s, "observed", i64::from(p.observed));
            s.push_str("},\"geometry\":{\"type\":\"Point\",\"coordinates\":");
            position(s, c, c.z.is_nan());
            s.push_str("}}");
        }
        self.out.done_piece()
    }

    /// An area as a Polygon feature (its ring closed, 2D), or a measurement line as a
    /// LineString, with its `role` (`walkable`, `measurement`, `measurement_line`), where it
    /// came from, its site-frame WKT and its area or length.
    pub fn area(
        &mut self,
        (role, source, wkt, shape): (&str, &str, &str, Shape),
        wgs: &[Vector3<f64>],
    ) -> std::io::Result<()> {
        let s = self.next();
        s.push_str("{\"type\":\"Feature\",\"properties\":{");
        for (k, (name, value)) in [("role", role), ("source", source), ("site_frame_wkt", wkt)]
            .into_iter()
            .enumerate()
        {
            if k > 0 {
                s.push(',');
            }
            let _ = write!(s, "\"{name}\":{}", serde_json::Value::from(value));
        }
        s.push(',');
        let closed = match shape {
            Shape::Polygon { area_m2 } => {
                real(s, "area_m2", area_m2);
                s.push_str("},\"geometry\":{\"type\":\"Polygon\",\"coordinates\":[[");
                true
            }
            Shape::Line { length_m } => {
                real(s, "length_m", length_m);
                s.push_str("},\"geometry\":{\"type\":\"LineString\",\"coordinates\":[");
                false
            }
        };
        for (k, c) in wgs.iter().chain(wgs.first().filter(|_| closed)).enumerate() {
            if k > 0 {
                s.push(',');
            }
            position(s, c, true);
        }
        s.push_str(if closed { "]]}}" } else { "]}}" });
        self.out.done_piece()
    }

    /// Closes the collection.
    pub fn finish(mut self) -> std::io::Result<()> {
        self.out.s.push_str(TAIL);
        self.out.finish()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The collections of `trajectories`, their `crs` taken as WGS 84.
    fn collection(trajectories: &[Trajectory], lines: bool) -> String {
        let mut v = Vec::new();
        let mut f = Features::new(&mut v);
        for t in trajectories {
            let wgs: Vec<Vector3<f64>> = t.points.iter().map(|q| q.crs).collect();
            if lines {
                f.line(t, &wgs).unwrap();
            } else {
                f.points(t, &wgs).unwrap();
            }
        }
        f.finish().unwrap();
        String::from_utf8(v).unwrap()
    }

    fn lines(trajectories: &[Trajectory]) -> String {
        collection(trajectories, true)
    }

    fn points(trajectories: &[Trajectory]) -> String {
        collection(trajectories, false)
    }
    use crate::export::{PointCov, TrajectoryPoint};
    use nalgebra::Vector2;

    fn trajectory(id: usize, h: f64) -> Trajectory {
        Trajectory {
            id,
            height_m: 1.7,
            height_source: "default".into(),
            points: (0..3)
                .map(|k| TrajectoryPoint {
                    frame: k,
                    time_s: k as f64 * 0.04,
                    local: Vector3::new(k as f64, 0.0, 1.7),
                    crs: Vector3::new(4.4327381981234 + k as f64 * 1e-5, -51.0740933, h),
                    velocity: Vector2::new(1.0, 0.0),
                    sigma_m: Vector2::new(0.02, f64::NAN),
                    cov: PointCov::default(),
                    observed: k != 1,
                    score: (k != 1).then_some(0.9),
                })
                .collect(),
        }
    }

    #[test]
    fn an_area_is_a_closed_2d_polygon_with_its_role_and_site_frame_wkt() {
        let mut v = Vec::new();
        let mut f = Features::new(&mut v);
        let ring = [
            Vector3::new(4.1, 51.0, 10.0),
            Vector3::new(4.2, 51.0, 10.0),
            Vector3::new(4.2, 51.1, f64::NAN),
        ];
        let wkt = "POLYGON ((0 0, 1 0, 1 1, 0 0))";
        f.area(
            (
                "walkable",
                "the deck's \"outline\"",
                wkt,
                Shape::Polygon { area_m2: 0.5 },
            ),
            &ring,
        )
        .unwrap();
        f.finish().unwrap();
        let j: serde_json::Value = serde_json::from_slice(&v).unwrap();
        let a = &j["features"][0];
        assert_eq!(a["properties"]["role"], "walkable");
        assert_eq!(a["properties"]["source"], "the deck's \"outline\"");
        assert_eq!(a["properties"]["site_frame_wkt"], wkt);
        assert_eq!(a["properties"]["area_m2"].as_f64(), Some(0.5));
        assert_eq!(a["geometry"]["type"], "Polygon");
        let r = a["geometry"]["coordinates"][0].as_array().unwrap();
        assert_eq!(r.len(), 4);
        assert_eq!(r[0], r[3]);
        assert!(r.iter().all(|c| c.as_array().unwrap().len() == 2));
    }

    #[test]
    fn reads_back_as_the_same_numbers() {
        let ts = [trajectory(3, 60.5), trajectory(4, f64::NAN)];
        let pts: serde_json::Value = serde_json::from_str(&points(&ts)).unwrap();
        let f = pts["features"].as_array().unwrap();
        assert_eq!(f.len(), 6);
        assert_eq!(pts["type"], "FeatureCollection");
        let p = &f[1]["properties"];
        assert_eq!(p["id"], 3);
        assert_eq!(p["frame"], 1);
        assert_eq!(p["time_s"].as_f64(), Some(0.04));
        assert_eq!(p["heading_deg"].as_f64(), Some(90.0));
        assert_eq!(p["observed"], 0);
        assert!(p["sigma_n_m"].is_null());
        let c = f[1]["geometry"]["coordinates"].as_array().unwrap();
        assert_eq!(c.len(), 3);
        assert_eq!(c[0].as_f64(), Some(4.432748198));
        assert_eq!(c[1].as_f64(), Some(-51.0740933));
        assert_eq!(c[2].as_f64(), Some(60.5));
        // Unknown heights: 2D positions.
        assert_eq!(f[4]["geometry"]["coordinates"].as_array().unwrap().len(), 2);

        let lines: serde_json::Value = serde_json::from_str(&lines(&ts)).unwrap();
        let f = lines["features"].as_array().unwrap();
        assert_eq!(f.len(), 2);
        assert_eq!(f[0]["properties"]["last_frame"], 2);
        assert_eq!(f[0]["geometry"]["type"], "LineString");
        assert_eq!(f[0]["geometry"]["coordinates"].as_array().unwrap().len(), 3);
        assert_eq!(
            f[1]["geometry"]["coordinates"][0].as_array().unwrap().len(),
            2
        );
    }

    #[test]
    fn coordinates_are_trimmed_and_never_negative_zero() {
        let mut s = String::new();
        coordinate(&mut s, 60.0);
        s.push(' ');
        coordinate(&mut s, -0.0000000001);
        s.push(' ');
        coordinate(&mut s, 1.25);
        assert_eq!(s, "60 0 1.25");
    }

    #[test]
    fn no_trajectories_is_an_empty_collection() {
        let v: serde_json::Value = serde_json::from_str(&points(&[])).unwrap();
        assert_eq!(v["features"].as_array().unwrap().len(), 0);
    }
}
