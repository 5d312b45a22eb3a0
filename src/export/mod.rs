//! Trajectory outputs: CSV, PeTrack/JuPedSim text and MOTChallenge text (pure formatting),
//! GeoJSON (`geojson`, pure formatting), GeoPackage through GDAL (`gis`, an adapter), and the
//! pedestrian-dynamics archives, HDF5 and SQLite (`archive`, an adapter).

#[cfg(feature = "archives")]
pub mod archive;
pub mod geojson;
#[cfg(feature = "gdal")]
pub mod gis;
pub mod qgis_style;

use std::fmt::Write as _;

use crate::text::Pieces;
use crate::text::fixed::Fixed;
pub use crate::text::text_of;

use nalgebra::{Matrix2, Vector2, Vector3};

use crate::track::ImageTrack;

/// A point's heading, degrees clockwise from north (east is 90).
pub fn heading_deg(p: &TrajectoryPoint) -> f64 {
    p.velocity
        .x
        .atan2(p.velocity.y)
        .to_degrees()
        .rem_euclid(360.0)
}

/// One point of a world trajectory.
#[derive(Clone, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct TrajectoryPoint {
    pub frame: usize,
    pub time_s: f64,
    /// East, north, up in the site frame, metres.
    pub local: Vector3<f64>,
    /// The same point in the output CRS (its units; heights as the survey's).
    pub crs: Vector3<f64>,
    /// East, north velocity, m/s.
    pub velocity: Vector2<f64>,
    /// Total σ east and north (random after smoothing, and systematic), metres.
    pub sigma_m: Vector2<f64>,
    /// The horizontal covariance, split by source.
    pub cov: PointCov,
    /// Whether the frame had a detection (else predicted through a gap).
    pub observed: bool,
    /// The detector's score of the frame's detection; `None` without one.
    pub score: Option<f64>,
}

/// A trajectory point's horizontal covariance (east, north; m²) by source: what is left of the
/// detections' random errors after smoothing, the person's height (the same error in every
/// frame of the person), and the camera pose (shared by everyone in the frame).
#[derive(Clone, Copy, Debug, Default, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct PointCov {
    pub random: Matrix2<f64>,
    pub height: Matrix2<f64>,
    pub pose: Matrix2<f64>,
}

impl PointCov {
    pub fn total(&self) -> Matrix2<f64> {
        self.random + self.height + self.pose
    }
}

/// The σ of a covariance per axis, as one number: the square root of half its trace, metres.
pub fn rms_sigma(cov: &Matrix2<f64>) -> f64 {
    (0.5 * cov.trace()).max(0.0).sqrt()
}

/// A person's trajectory.
#[derive(Clone, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct Trajectory {
    pub id: usize,
    /// The head height used, metres, and where it came from.
    pub height_m: f64,
    pub height_source: String,
    pub points: Vec<TrajectoryPoint>,
}

impl Trajectory {
    /// Path length, metres.
    pub fn length_m(&self) -> f64 {
        self.points
            .windows(2)
            .map(|w| (w[1].local.xy() - w[0].local.xy()).norm())
            .sum()
    }

    /// Mean speed over the trajectory, m/s.
    pub fn mean_speed(&self) -> f64 {
        match (self.points.first(), self.points.last()) {
            (Some(a), Some(b)) if b.time_s > a.time_s => self.length_m() / (b.time_s - a.time_s),
            _ => 0.0,
        }
    }
}

/// Image tracks as CSV: one row per point, pixels (`geostride track`'s `tracks.csv`).
pub fn image_tracks_csv(tracks: &[crate::track::ImageTrack]) -> String {
    let mut s = String::from("id,frame,u_px,v_px,sigma_u_px,sigma_v_px,x,y,w,h\n");
    for t in tracks {
        for q in &t.points {
            let _ = writeln!(
                s,
                "{},{},{},{},{},{},{},{},{},{}",
                t.id,
                q.frame,
                Fixed::<2>(q.uv.x),
                Fixed::<2>(q.uv.y),
                Fixed::<2>(q.cov[(0, 0)].max(0.0).sqrt()),
                Fixed::<2>(q.cov[(1, 1)].max(0.0).sqrt()),
                Fixed::<1>(q.bbox[0]),
                Fixed::<1>(q.bbox[1]),
                Fixed::<1>(q.bbox[2]),
                Fixed::<1>(q.bbox[3]),
            );
        }
    }
    s
}

/// How the site frame's metres lie in the survey's CRS, for the files' headers: a local
/// east-north-up tangent plane at an origin (not a plain offset of the CRS's grid: its axes
/// follow true north and its scale is 1).
#[derive(Clone, Debug, Default, PartialEq)]
pub struct SiteFrameNote {
    /// How the origin was chosen.
    pub origin_note: String,
    /// The survey's CRS (its label); `None` for a survey in its own local frame.
    pub crs: Option<String>,
    /// The origin: latitude, longitude (degrees, on the CRS's datum) and height (metres).
    pub origin_geodetic: Option<[f64; 3]>,
    /// The origin's coordinates in the survey's CRS.
    pub origin_in_crs: Option<[f64; 3]>,
    /// The survey's kind of height.
    pub heights: String,
}

impl SiteFrameNote {
    /// `(key, value)` pairs: the archives' attributes and the text files' header lines.
    pub fn fields(&self) -> Vec<(&'static str, String)> {
        let mut f = vec![
            (
                "axes",
                "x east, y north, z up, metres (a local tangent plane)".to_string(),
            ),
            ("origin", self.origin_note.clone()),
        ];
        if let Some(crs) = &self.crs {
            f.push(("crs", crs.clone()));
        }
        if let Some([lat, lon, h]) = self.origin_geodetic {
            f.push((
                "origin_lat_lon_h",
                format!("{lat:.9} {lon:.9} {h:.4} (degrees, degrees, metres)"),
            ));
        }
        if let Some([x, y, z]) = self.origin_in_crs {
            f.push(("origin_in_crs", format!("{x:.4} {y:.4} {z:.4}")));
        }
        f.push(("heights", self.heights.clone()));
        f
    }
}

/// A polygon as WKT, its ring closed: `POLYGON ((x y, ..., x y))`, 4 decimals.
pub fn polygon_wkt(vertices: &[Vector2<f64>]) -> String {
    let mut s = String::from("POLYGON ((");
    for (i, v) in vertices.iter().chain(vertices.first()).enumerate() {
        if i > 0 {
            s.push_str(", ");
        }
        let _ = write!(s, "{} {}", Fixed::<4>(v.x), Fixed::<4>(v.y));
    }
    s.push_str("))");
    s
}

/// A line as WKT: `LINESTRING (x y, x y)`, 4 decimals.
pub fn linestring_wkt(vertices: &[Vector2<f64>]) -> String {
    let points: Vec<String> = vertices
        .iter()
        .map(|v| format!("{} {}", Fixed::<4>(v.x), Fixed::<4>(v.y)))
        .collect();
    format!("LINESTRING ({})", points.join(", "))
}

/// A run's export formats (`[export] formats`), each written by its own writer.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum ExportFormat {
    /// `trajectories.csv`.
    Csv,
    /// `trajectories.geojson` and `positions.geojson` (WGS 84).
    GeoJson,
    /// `trajectories.gpkg` (the output CRS).
    GeoPackage,
    /// `trajectories.txt`, PeTrack's text.
    PeTrack,
    /// `tracks_mot.txt`, the image tracks as MOTChallenge text.
    Mot,
    /// `detections.csv`.
    Detections,
    /// `trajectories.h5`, the Pedestrian Dynamics Data Archive's HDF5.
    Hdf5,
    /// `trajectories.sqlite`, JuPedSim's trajectory database.
    Sqlite,
}

impl ExportFormat {
    /// Every format: a run's default list, in this order.
    pub const ALL: [ExportFormat; 8] = [
        ExportFormat::Csv,
        ExportFormat::GeoJson,
        ExportFormat::GeoPackage,
        ExportFormat::PeTrack,
        ExportFormat::Mot,
        ExportFormat::Detections,
        ExportFormat::Hdf5,
        ExportFormat::Sqlite,
    ];

    /// The name a project file gives it.
    pub fn name(self) -> &'static str {
        match self {
            ExportFormat::Csv => "csv",
            ExportFormat::GeoJson => "geojson",
            ExportFormat::GeoPackage => "gpkg",
            ExportFormat::PeTrack => "petrack",
            ExportFormat::Mot => "mot",
            ExportFormat::Detections => "detections",
            ExportFormat::Hdf5 => "hdf5",
            ExportFormat::Sqlite => "sqlite",
        }
    }

    /// The format of a name; `None` for any other.
    pub fn parse(name: &str) -> Option<ExportFormat> {
        ExportFormat::ALL.into_iter().find(|f| f.name() == name)
    }
}

/// The trajectories as CSV: one row per point.
pub fn trajectories_csv(trajectories: &[Trajectory]) -> String {
    text_of(|w| write_trajectories_csv(w, trajectories.iter().map(Ok)))
}

/// [`trajectories_csv`] written to `w` as the trajectories come (read back from disk: a long
/// video's are never all in memory); the first that cannot be read stops it.
pub fn write_trajectories_csv<T: std::borrow::Borrow<Trajectory>>(
    w: &mut dyn std::io::Write,
    trajectories: impl IntoIterator<Item = std::io::Result<T>>,
) -> std::io::Result<()> {
    let mut out = Pieces::new(w);
    out.s.push_str(
        "id,frame,time_s,e_m,n_m,u_m,x,y,z,ve_m_s,vn_m_s,speed_m_s,sigma_e_m,sigma_n_m,cov_en_m2,sigma_random_m,sigma_height_m,sigma_pose_m,observed,height_m\n",
    );
    for t in trajectories {
        let t = t?;
        let t = t.borrow();
        let s = &mut out.s;
        for p in &t.points {
            let _ = writeln!(
                s,
                "{},{},{},{},{},{},{},{},{},{},{},{},{},{},{},{},{},{},{},{}",
                t.id,
                p.frame,
                Fixed::<4>(p.time_s),
                Fixed::<4>(p.local.x),
                Fixed::<4>(p.local.y),
                Fixed::<4>(p.local.z),
                Fixed::<4>(p.crs.x),
                Fixed::<4>(p.crs.y),
                Fixed::<4>(p.crs.z),
                Fixed::<4>(p.velocity.x),
                Fixed::<4>(p.velocity.y),
                Fixed::<4>(p.velocity.norm()),
                Fixed::<4>(p.sigma_m.x),
                Fixed::<4>(p.sigma_m.y),
                Fixed::<6>(p.cov.total()[(0, 1)]),
                Fixed::<4>(rms_sigma(&p.cov.random)),
                Fixed::<4>(rms_sigma(&p.cov.height)),
                Fixed::<4>(rms_sigma(&p.cov.pose)),
                u8::from(p.observed),
                Fixed::<3>(t.height_m),
            );
        }
        out.done_piece()?;
    }
    out.finish()
}

/// PeTrack's and JuPedSim's trajectory text: comment lines (the frame rate; how the site frame
/// lies in the survey's CRS), then `id frame x y z` in metres of the site frame (a local metric
/// frame, as those tools expect).
pub fn petrack_txt(trajectories: &[Trajectory], fps: f64, frame: &SiteFrameNote) -> String {
    text_of(|w| write_petrack_txt(w, trajectories.iter().map(Ok), fps, frame))
}

/// [`petrack_txt`] written to `w` as the trajectories come, like [`write_trajectories_csv`].
pub fn write_petrack_txt<T: std::borrow::Borrow<Trajectory>>(
    w: &mut dyn std::io::Write,
    trajectories: impl IntoIterator<Item = std::io::Result<T>>,
    fps: f64,
    frame: &SiteFrameNote,
) -> std::io::Result<()> {
    let mut out = Pieces::new(w);
    let s = &mut out.s;
    let _ = writeln!(s, "# geostride trajectories: head positions, smoothed");
    let _ = writeln!(s, "# framerate: {fps}");
    // PedPy reads the frame rate and the unit from these lines: no other may name either.
    for (key, value) in frame.fields() {
        let _ = writeln!(s, "# site frame {key}: {value}");
    }
    let _ = writeln!(s, "# id\tframe\tx/m\ty/m\tz/m");
    for t in trajectories {
        let t = t?;
        let t = t.borrow();
        let s = &mut out.s;
        for p in &t.points {
            let _ = writeln!(
                s,
                "{}\t{}\t{}\t{}\t{}",
                t.id,
                p.frame,
                Fixed::<4>(p.local.x),
                Fixed::<4>(p.local.y),
                Fixed::<4>(p.local.z)
            );
        }
        out.done_piece()?;
    }
    out.finish()
}

/// MOTChallenge text of the image tracks: `frame,id,left,top,width,height,conf,-1,-1,-1`, frames
/// from 1, boxes in pixels with the first pixel numbered 1.
pub fn mot_txt(tracks: &[ImageTrack]) -> String {
    let mut order: Vec<&ImageTrack> = tracks.iter().collect();
    order.sort_by_key(|t| t.points.first().map_or(0, |p| p.frame));
    text_of(|w| write_mot_in_order(w, order.into_iter().map(Ok)))
}

/// [`mot_txt`] written to `w` from tracks that come in the order of their first frames (a
/// track stage's cache, read a track at a time): rows by frame, then identity, holding only
/// the tracks that have started and not ended. Tracks out of that order are an error.
pub fn write_mot_in_order<T: std::borrow::Borrow<ImageTrack>>(
    w: &mut dyn std::io::Write,
    mut tracks: impl Iterator<Item = std::io::Result<T>>,
) -> std::io::Result<()> {
    use std::cmp::Reverse;
    use std::collections::{BinaryHeap, HashMap};
    // (frame, id, slot, point): the next row of each track taken in.
    let mut next: BinaryHeap<Reverse<(usize, usize, usize, usize)>> = BinaryHeap::new();
    let mut live: HashMap<usize, T> = HashMap::new();
    let (mut slot, mut last_first) = (0, 0);
    let mut pending: Option<T> = None;
    let mut out = Pieces::new(w);
    loop {
        if pending.is_none() {
            pending = tracks.next().transpose()?;
        }
        let row_frame = next.peek().map(|Reverse(r)| r.0);
        // A track starting no later than the next row is taken in first: rows of one frame go
        // by identity across tracks.
        if let Some(t) = pending.take_if(|t| {
            t.borrow()
                .points
                .first()
                .is_none_or(|p| row_frame.is_none_or(|f| p.frame <= f))
        }) {
            let Some(first) = t.borrow().points.first().map(|p| p.frame) else {
                continue;
            };
            if first < last_first {
                return Err(std::io::Error::other(format!(
                    "image track {} starts at frame {first}, before one taken earlier ({last_first}): not in order of first frames",
                    t.borrow().id
                )));
            }
            last_first = first;
            next.push(Reverse((first, t.borrow().id, slot, 0)));
            live.insert(slot, t);
            slot += 1;
            continue;
        }
        let Some(Reverse((frame, id, k, i))) = next.pop() else {
            break;
        };
        let t = live[&k].borrow();
        let b = t.points[i].bbox;
        // geostride's box corner is the left edge of the first pixel (−0.5 from its centre).
        let _ = writeln!(
            out.s,
            "{},{},{},{},{},{},1,-1,-1,-1",
            frame + 1,
            id,
            Fixed::<2>(b[0] + 1.5),
            Fixed::<2>(b[1] + 1.5),
            Fixed::<2>(b[2]),
            Fixed::<2>(b[3]),
        );
        match t.points.get(i + 1) {
            Some(p) => next.push(Reverse((p.frame, id, k, i + 1))),
            None => {
                live.remove(&k);
            }
        }
        out.done_piece()?;
    }
    out.finish()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn export_formats_are_named_once() {
        for f in ExportFormat::ALL {
            assert_eq!(ExportFormat::parse(f.name()), Some(f));
        }
        assert_eq!(ExportFormat::parse("shp"), None);
    }

    use crate::track::TrackPoint;
    use nalgebra::Matrix2;

    fn traj() -> Trajectory {
        let points = (0..3)
            .map(|k| TrajectoryPoint {
                frame: 10 + k,
                time_s: 0.4 + 0.04 * k as f64,
                local: Vector3::new(1.0 + 0.14 * k as f64, 2.0, 8.2),
                crs: Vector3::new(654501.0, 696002.0, 60.2),
                velocity: Vector2::new(3.5, 0.0),
                sigma_m: Vector2::new(0.02, 0.03),
                cov: PointCov {
                    random: Matrix2::new(0.0003, 0.0001, 0.0001, 0.0008),
                    height: Matrix2::new(0.0001, 0.0, 0.0, 0.0001),
                    pose: Matrix2::zeros(),
                },
                observed: k != 1,
                score: (k != 1).then_some(0.9),
            })
            .collect();
        Trajectory {
            id: 7,
            height_m: 1.7,
            height_source: "default".into(),
            points,
        }
    }

    #[test]
    fn formats_have_their_columns() {
        let t = traj();
        assert!((t.length_m() - 0.28).abs() < 1e-12 && (t.mean_speed() - 3.5).abs() < 1e-9);
        let csv = trajectories_csv(std::slice::from_ref(&t));
        assert_eq!(csv.lines().count(), 4);
        assert!(
            csv.lines()
                .nth(2)
                .unwrap()
                .starts_with("7,11,0.4400,1.1400,2.0000,8.2000,")
        );
        let frame = SiteFrameNote {
            origin_note: "point A".into(),
            crs: Some("EPSG:32631 (WGS 84 / UTM zone 31N)".into()),
            origin_geodetic: Some([48.1, 2.5, 120.0]),
            origin_in_crs: Some([500000.0, 5330000.0, 120.0]),
            heights: "ellipsoidal".into(),
        };
        let pt = petrack_txt(std::slice::from_ref(&t), 25.0, &frame);
        assert!(pt.contains("# site frame crs: EPSG:32631"), "{pt}");
        assert!(pt.contains("# site frame origin_in_crs: 500000.0000 5330000.0000 120.0000"));
        // PedPy takes the frame rate from the first number of any line naming it, and the
        // unit from any line with "x/m" or "in cm": only one line may name each.
        let head: Vec<&str> = pt.lines().filter(|l| l.starts_with('#')).collect();
        assert_eq!(head.iter().filter(|l| l.contains("framerate")).count(), 1);
        assert_eq!(
            head.iter()
                .filter(|l| l.to_lowercase().contains("in cm"))
                .count(),
            0
        );
        assert_eq!(head.iter().filter(|l| l.contains("x/m")).count(), 1);
        assert_eq!(pt.lines().filter(|l| !l.starts_with('#')).count(), 3);
        assert!(pt.contains("7\t10\t1.0000\t2.0000\t8.2000"));
        let it = ImageTrack {
            id: 3,
            points: vec![TrackPoint {
                frame: 0,
                uv: Vector2::new(10.0, 20.0),
                cov: Matrix2::identity(),
                bbox: [4.5, 14.5, 11.0, 11.0],
                score: Some(0.9),
            }],
        };
        assert_eq!(
            mot_txt(&[it]).trim(),
            "1,3,6.00,16.00,11.00,11.00,1,-1,-1,-1"
        );
    }

    #[test]
    fn mot_rows_go_by_frame_then_identity_across_tracks() {
        let track = |id: usize, frames: &[usize]| ImageTrack {
            id,
            points: frames
                .iter()
                .map(|&frame| TrackPoint {
                    frame,
                    uv: Vector2::zeros(),
                    cov: Matrix2::identity(),
                    bbox: [0.0; 4],
                    score: Some(1.0),
                })
                .collect(),
        };
        // Tracks out of identity order, overlapping, one with a gap, one empty.
        let tracks = [
            track(9, &[2, 3, 4]),
            track(2, &[0, 1, 3, 6]),
            track(5, &[]),
            track(4, &[1, 2]),
        ];
        let rows: Vec<(usize, usize)> = mot_txt(&tracks)
            .lines()
            .map(|l| {
                let mut f = l.split(',').map(|v| v.parse::<usize>().unwrap());
                (f.next().unwrap(), f.next().unwrap())
            })
            .collect();
        assert_eq!(
            rows,
            [
                (1, 2),
                (2, 2),
                (2, 4),
                (3, 4),
                (3, 9),
                (4, 2),
                (4, 9),
                (5, 9),
                (7, 2)
            ]
        );
    }
}
