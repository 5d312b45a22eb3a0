//! Trajectory outputs: CSV, PeTrack/JuPedSim text and MOTChallenge text (pure formatting), and
//! GeoJSON (`geojson`, pure formatting) and GeoPackage through GDAL (`gis`, an adapter).

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
}

impl ExportFormat {
    /// Every format: a run's default list, in this order.
    pub const ALL: [ExportFormat; 6] = [
        ExportFormat::Csv,
        ExportFormat::GeoJson,
        ExportFormat::GeoPackage,
        ExportFormat::PeTrack,
        ExportFormat::Mot,
        ExportFormat::Detections,
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

/// PeTrack's and JuPedSim's trajectory text: comment lines, then `id frame x y z` in metres of
/// the site frame (a local metric frame, as those tools expect).
pub fn petrack_txt(trajectories: &[Trajectory], fps: f64, frame_note: &str) -> String {
    text_of(|w| write_petrack_txt(w, trajectories.iter().map(Ok), fps, frame_note))
}

/// [`petrack_txt`] written to `w` as the trajectories come, like [`write_trajectories_csv`].
pub fn write_petrack_txt<T: std::borrow::Borrow<Trajectory>>(
    w: &mut dyn std::io::Write,
    trajectories: impl IntoIterator<Item = std::io::Result<T>>,
    fps: f64,
    frame_note: &str,
) -> std::io::Result<()> {
    let mut out = Pieces::new(w);
    let s = &mut out.s;
    let _ = writeln!(s, "# geostride trajectories: head positions, smoothed");
    let _ = writeln!(s, "# framerate: {fps}");
    let _ = writeln!(s, "# coordinates: {frame_note}");
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
        let pt = petrack_txt(std::slice::from_ref(&t), 25.0, "site frame");
        assert_eq!(pt.lines().filter(|l| !l.starts_with('#')).count(), 3);
        assert!(pt.contains("7\t10\t1.0000\t2.0000\t8.2000"));
        let it = ImageTrack {
            id: 3,
            points: vec![TrackPoint {
                frame: 0,
                uv: Vector2::new(10.0, 20.0),
                cov: Matrix2::identity(),
                bbox: [4.5, 14.5, 11.0, 11.0],
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
