//! The pedestrian-dynamics archives (adapter): the Pedestrian Dynamics Data Archive's HDF5
//! through libhdf5, and JuPedSim's SQLite trajectory database through libsqlite3. PedPy reads
//! both (`load_trajectory_from_ped_data_archive_hdf5`, `load_trajectory_from_jupedsim_sqlite`
//! and their walkable-area loaders); JuPedSim's `Recording` opens the SQLite.

use std::path::{Path, PathBuf};

use hdf5_metno as hdf5;
use hdf5_metno::types::VarLenUnicode;

use super::{SiteFrameNote, Trajectory, TrajectoryPoint};

/// What the archives hold besides the trajectories.
pub struct ArchiveInfo<'a> {
    pub fps: f64,
    /// The walkable area's vertices, site frame, metres (none: no geometry written).
    pub walkable: &'a [nalgebra::Vector2<f64>],
    /// Where the walkable area came from (the project, the deck, the trajectories' extent).
    pub walkable_source: &'a str,
    pub frame: &'a SiteFrameNote,
    /// geostride's build, for the files' provenance.
    pub producer_version: &'a str,
}

/// Writing an archive failed: the file and why (no file is left behind).
#[derive(Debug, thiserror::Error)]
#[error("cannot write {}: {reason}", path.display())]
pub struct ArchiveError {
    pub path: PathBuf,
    pub reason: String,
}

/// One row of the HDF5 `trajectory` dataset: the archive's `id`, `frame`, `x`, `y`, `z` (site
/// frame, metres; z the head's height) and geostride's per-point extras.
#[derive(hdf5::H5Type, Clone, Copy, Debug, PartialEq)]
#[repr(C)]
pub struct ArchiveRow {
    pub id: i64,
    pub frame: i64,
    pub x: f64,
    pub y: f64,
    pub z: f64,
    pub sigma_x: f64,
    pub sigma_y: f64,
    pub head_height: f64,
    pub score: f64,
    pub observed: u8,
}

impl ArchiveRow {
    fn of(t: &Trajectory, p: &TrajectoryPoint) -> ArchiveRow {
        ArchiveRow {
            id: t.id as i64,
            frame: p.frame as i64,
            x: p.local.x,
            y: p.local.y,
            z: p.local.z,
            sigma_x: p.sigma_m.x,
            sigma_y: p.sigma_m.y,
            head_height: t.height_m,
            score: p.score.unwrap_or(f64::NAN),
            observed: u8::from(p.observed),
        }
    }
}

/// The columns' units and meanings, as JSON (the dataset's `column_units` and
/// `column_descriptions` attributes, as JuPedSim's HDF5 writer gives them).
const COLUMN_UNITS: &str = r#"{"id": "-", "frame": "-", "x": "m", "y": "m", "z": "m", "sigma_x": "m", "sigma_y": "m", "head_height": "m", "score": "-", "observed": "-"}"#;
const COLUMN_DESCRIPTIONS: &str = r#"{"id": "person", "frame": "video frame index", "x": "head position east, site frame", "y": "head position north, site frame", "z": "head height, site frame", "sigma_x": "1-sigma uncertainty of x (random, height and pose together)", "sigma_y": "1-sigma uncertainty of y", "head_height": "the person's head height above the ground used for the projection", "score": "the detector's score; NaN where the tracker bridged a frame", "observed": "1 where the frame had a detection, 0 where the smoother bridged a gap"}"#;

/// Rows written to the HDF5 file at a time.
const CHUNK_ROWS: usize = 16384;

/// Writes `path` through a temporary beside it, renamed into place only when `fill` succeeds.
fn atomic(
    path: &Path,
    ext: &str,
    fill: impl FnOnce(&Path) -> Result<(), String>,
) -> Result<(), ArchiveError> {
    crate::io::write_atomic_by_name(path, ext, fill, |e| e.to_string()).map_err(|reason| {
        ArchiveError {
            path: path.to_path_buf(),
            reason,
        }
    })
}

fn unicode(s: &str) -> Result<VarLenUnicode, String> {
    s.parse::<VarLenUnicode>()
        .map_err(|e| format!("a text attribute: {e}"))
}

/// Writes a string attribute on `loc` (the file or a dataset).
fn text_attr(loc: &hdf5::Location, name: &str, value: &str) -> Result<(), String> {
    loc.new_attr::<VarLenUnicode>()
        .create(name)
        .and_then(|a| a.write_scalar(&unicode(value).map_err(hdf5::Error::from)?))
        .map_err(|e| format!("attribute {name}: {e}"))
}

fn number_attr(loc: &hdf5::Location, name: &str, value: f64) -> Result<(), String> {
    loc.new_attr::<f64>()
        .create(name)
        .and_then(|a| a.write_scalar(&value))
        .map_err(|e| format!("attribute {name}: {e}"))
}

/// The Pedestrian Dynamics Data Archive's HDF5: a `trajectory` dataset of [`ArchiveRow`]s with
/// its `fps`, the walkable area as the root's `wkt_geometry`, and how the site frame lies in
/// the survey's CRS. Written a trajectory at a time (a long video's never stand in memory).
pub fn write_hdf5<T: std::borrow::Borrow<Trajectory>>(
    path: &Path,
    info: &ArchiveInfo,
    trajectories: impl IntoIterator<Item = std::io::Result<T>>,
) -> Result<(), ArchiveError> {
    atomic(path, ".h5", |tmp| {
        let err = |e: hdf5::Error| e.to_string();
        // No time stamps: the same run gives the same bytes.
        let file = hdf5::File::with_options()
            .with_fcpl(|p| p.obj_track_times(false))
            .create(tmp)
            .map_err(err)?;
        let mut builder = file.new_dataset::<ArchiveRow>().obj_track_times(false);
        if hdf5::filters::deflate_available() {
            builder = builder.deflate(4);
        }
        let ds = builder
            .chunk((CHUNK_ROWS,))
            .shape(hdf5::Extent::resizable(0))
            .create("trajectory")
            .map_err(err)?;
        let mut rows: Vec<ArchiveRow> = Vec::with_capacity(CHUNK_ROWS);
        let mut written = 0usize;
        let mut flush = |rows: &mut Vec<ArchiveRow>| -> Result<(), String> {
            if rows.is_empty() {
                return Ok(());
            }
            let end = written + rows.len();
            ds.resize((end,)).map_err(err)?;
            ds.write_slice(rows.as_slice(), written..end).map_err(err)?;
            written = end;
            rows.clear();
            Ok(())
        };
        for t in trajectories {
            let t = t.map_err(|e| e.to_string())?;
            let t = t.borrow();
            for p in &t.points {
                rows.push(ArchiveRow::of(t, p));
                if rows.len() == CHUNK_ROWS {
                    flush(&mut rows)?;
                }
            }
        }
        flush(&mut rows)?;
        number_attr(&ds, "fps", info.fps)?;
        text_attr(&ds, "column_units", COLUMN_UNITS)?;
        text_attr(&ds, "column_descriptions", COLUMN_DESCRIPTIONS)?;
        number_attr(&file, "fps", info.fps)?;
        if !info.walkable.is_empty() {
            text_attr(&file, "wkt_geometry", &super::polygon_wkt(info.walkable))?;
        }
        text_attr(&file, "walkable_area_source", info.walkable_source)?;
        text_attr(&file, "producer", "geostride")?;
        text_attr(&file, "producer_version", info.producer_version)?;
        for (key, value) in info.frame.fields() {
            text_attr(&file, &format!("site_frame_{key}"), &value)?;
        }
        file.close().map_err(err)
    })
}

/// JuPedSim's trajectory database (version 2): `trajectory_data` (frame, id, pos_x, pos_y,
/// ori_x, ori_y; the orientation is the walking direction), `metadata` (version, fps, the
/// bounds), `geometry` (the walkable area's WKT) and `frame_data`, as JuPedSim writes them; and
/// geostride's per-point extras in `geostride_points` and its provenance in `metadata`.
pub fn write_sqlite<T: std::borrow::Borrow<Trajectory>>(
    path: &Path,
    info: &ArchiveInfo,
    trajectories: impl IntoIterator<Item = std::io::Result<T>>,
) -> Result<(), ArchiveError> {
    atomic(path, ".sqlite", |tmp| {
        let err = |e: rusqlite::Error| e.to_string();
        let mut con = rusqlite::Connection::open(tmp).map_err(err)?;
        let tx = con.transaction().map_err(err)?;
        tx.execute_batch(
            "CREATE TABLE trajectory_data (frame INTEGER NOT NULL, id INTEGER NOT NULL, \
                 pos_x REAL NOT NULL, pos_y REAL NOT NULL, ori_x REAL NOT NULL, ori_y REAL NOT NULL);
             CREATE TABLE metadata(key TEXT NOT NULL UNIQUE PRIMARY KEY, value TEXT NOT NULL);
             CREATE TABLE geometry(hash INTEGER NOT NULL, wkt TEXT NOT NULL);
             CREATE UNIQUE INDEX geometry_hash ON geometry(hash);
             CREATE TABLE frame_data(frame INTEGER NOT NULL, geometry_hash INTEGER NOT NULL);
             CREATE TABLE geostride_points (frame INTEGER NOT NULL, id INTEGER NOT NULL, \
                 z REAL NOT NULL, sigma_x REAL NOT NULL, sigma_y REAL NOT NULL, \
                 head_height REAL NOT NULL, score REAL, observed INTEGER NOT NULL);",
        )
        .map_err(err)?;
        let mut last_frame: Option<usize> = None;
        let mut seen = bounds(&[]);
        {
            let mut traj = tx
                .prepare("INSERT INTO trajectory_data VALUES (?1, ?2, ?3, ?4, ?5, ?6)")
                .map_err(err)?;
            let mut extra = tx
                .prepare("INSERT INTO geostride_points VALUES (?1, ?2, ?3, ?4, ?5, ?6, ?7, ?8)")
                .map_err(err)?;
            for t in trajectories {
                let t = t.map_err(|e| e.to_string())?;
                let t = t.borrow();
                // JuPedSim's orientation is a unit vector: the walking direction, kept through
                // stops (east before the person first moves).
                let mut heading = nalgebra::Vector2::new(1.0, 0.0);
                for p in &t.points {
                    let v = p.velocity;
                    if v.norm() > 1e-3 && v.iter().all(|c| c.is_finite()) {
                        heading = v.normalize();
                    }
                    let (frame, id) = (p.frame as i64, t.id as i64);
                    traj.execute(rusqlite::params![
                        frame, id, p.local.x, p.local.y, heading.x, heading.y
                    ])
                    .map_err(err)?;
                    extra
                        .execute(rusqlite::params![
                            frame,
                            id,
                            p.local.z,
                            p.sigma_m.x,
                            p.sigma_m.y,
                            t.height_m,
                            p.score,
                            i64::from(p.observed)
                        ])
                        .map_err(err)?;
                    last_frame = last_frame.max(Some(p.frame));
                    seen = union(seen, bounds(&[p.local.xy()]));
                }
            }
        }
        let wkt = super::polygon_wkt(info.walkable);
        let geometry_hash = wkt_hash(&wkt);
        if !info.walkable.is_empty() {
            tx.execute(
                "INSERT INTO geometry VALUES (?1, ?2)",
                rusqlite::params![geometry_hash, wkt],
            )
            .map_err(err)?;
        }
        // One row per frame from 0, as JuPedSim's recording counts its frames.
        {
            let mut fd = tx
                .prepare("INSERT INTO frame_data VALUES (?1, ?2)")
                .map_err(err)?;
            for f in 0..last_frame.map_or(0, |f| f + 1) {
                fd.execute(rusqlite::params![f as i64, geometry_hash])
                    .map_err(err)?;
            }
        }
        // JuPedSim's bounds: the geometry's, and here the people's too (an empty run: zeros).
        let bounds =
            union(bounds(info.walkable), seen).map(|b| if b.is_finite() { b } else { 0.0 });
        let mut meta: Vec<(String, String)> = vec![
            ("version".into(), "2".into()),
            ("fps".into(), info.fps.to_string()),
            ("xmin".into(), bounds[0].to_string()),
            ("xmax".into(), bounds[2].to_string()),
            ("ymin".into(), bounds[1].to_string()),
            ("ymax".into(), bounds[3].to_string()),
            ("producer".into(), "geostride".into()),
            ("producer_version".into(), info.producer_version.into()),
            ("walkable_area_source".into(), info.walkable_source.into()),
        ];
        meta.extend(
            info.frame
                .fields()
                .into_iter()
                .map(|(k, v)| (format!("site_frame_{k}"), v)),
        );
        for (k, v) in &meta {
            tx.execute("INSERT INTO metadata VALUES (?1, ?2)", [k, v])
                .map_err(err)?;
        }
        tx.execute_batch("CREATE INDEX frame_id_idx ON trajectory_data(frame, id);")
            .map_err(err)?;
        tx.commit().map_err(err)?;
        con.close().map_err(|(_, e)| err(e))
    })
}

/// A stable 63-bit hash of the geometry's WKT (FNV-1a; the same text always gives the same key).
fn wkt_hash(wkt: &str) -> i64 {
    let mut h: u64 = 0xcbf2_9ce4_8422_2325;
    for b in wkt.bytes() {
        h ^= u64::from(b);
        h = h.wrapping_mul(0x0100_0000_01b3);
    }
    (h >> 1) as i64
}

fn union(a: [f64; 4], b: [f64; 4]) -> [f64; 4] {
    [
        a[0].min(b[0]),
        a[1].min(b[1]),
        a[2].max(b[2]),
        a[3].max(b[3]),
    ]
}

/// The bounding box `[xmin, ymin, xmax, ymax]` of the vertices.
fn bounds(vertices: &[nalgebra::Vector2<f64>]) -> [f64; 4] {
    let mut b = [
        f64::INFINITY,
        f64::INFINITY,
        f64::NEG_INFINITY,
        f64::NEG_INFINITY,
    ];
    for v in vertices {
        b = [b[0].min(v.x), b[1].min(v.y), b[2].max(v.x), b[3].max(v.y)];
    }
    b
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::export::PointCov;
    use nalgebra::{Vector2, Vector3};

    fn trajectories() -> Vec<Trajectory> {
        (0..2)
            .map(|id| Trajectory {
                id: id + 4,
                height_m: 1.7 + 0.1 * id as f64,
                height_source: "boxes".into(),
                points: (0..5)
                    .map(|k| TrajectoryPoint {
                        frame: 10 + k,
                        time_s: (10 + k) as f64 / 25.0,
                        local: Vector3::new(k as f64, id as f64, 1.7),
                        crs: Vector3::zeros(),
                        velocity: Vector2::new(if k == 2 { 0.0 } else { 0.5 }, 0.5),
                        sigma_m: Vector2::new(0.03, 0.04),
                        cov: PointCov::default(),
                        observed: k != 3,
                        score: (k != 3).then_some(0.8),
                    })
                    .collect(),
            })
            .collect()
    }

    fn info<'a>(walkable: &'a [Vector2<f64>], frame: &'a SiteFrameNote) -> ArchiveInfo<'a> {
        ArchiveInfo {
            fps: 25.0,
            walkable,
            walkable_source: "[analysis] walkable_area",
            frame,
            producer_version: "test",
        }
    }

    fn square() -> Vec<Vector2<f64>> {
        vec![
            Vector2::new(-1.0, -1.0),
            Vector2::new(6.0, -1.0),
            Vector2::new(6.0, 3.0),
            Vector2::new(-1.0, 3.0),
        ]
    }

    #[test]
    fn the_hdf5_archive_holds_every_point_its_fps_and_the_walkable_area() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("t.h5");
        let (walkable, frame) = (square(), SiteFrameNote::default());
        let trajs = trajectories();
        write_hdf5(&path, &info(&walkable, &frame), trajs.iter().map(Ok)).unwrap();
        let file = hdf5::File::open(&path).unwrap();
        let ds = file.dataset("trajectory").unwrap();
        let rows: Vec<ArchiveRow> = ds.read_raw().unwrap();
        assert_eq!(rows.len(), 10);
        assert_eq!(rows[7].id, 5);
        assert_eq!(rows[7].frame, 12);
        assert_eq!((rows[7].x, rows[7].y, rows[7].z), (2.0, 1.0, 1.7));
        assert_eq!((rows[7].sigma_x, rows[7].sigma_y), (0.03, 0.04));
        assert!((rows[7].head_height - 1.8).abs() < 1e-12);
        assert_eq!((rows[7].score, rows[7].observed), (0.8, 1));
        assert!(rows[8].score.is_nan() && rows[8].observed == 0);
        let fps: f64 = ds.attr("fps").unwrap().read_scalar().unwrap();
        assert_eq!(fps, 25.0);
        let wkt: VarLenUnicode = file.attr("wkt_geometry").unwrap().read_scalar().unwrap();
        assert_eq!(
            wkt.as_str(),
            "POLYGON ((-1.0000 -1.0000, 6.0000 -1.0000, 6.0000 3.0000, -1.0000 3.0000, -1.0000 -1.0000))"
        );
        let names: Vec<String> = file.attr_names().unwrap();
        assert!(names.contains(&"site_frame_axes".to_string()), "{names:?}");
        // Nothing is left beside the file.
        assert_eq!(std::fs::read_dir(dir.path()).unwrap().count(), 1);
    }

    #[test]
    fn the_sqlite_database_is_jupedsims_with_geostrides_extras_beside() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("t.sqlite");
        let (walkable, frame) = (square(), SiteFrameNote::default());
        write_sqlite(
            &path,
            &info(&walkable, &frame),
            trajectories().into_iter().map(Ok),
        )
        .unwrap();
        let con = rusqlite::Connection::open(&path).unwrap();
        let one = |sql: &str| -> String {
            con.query_row(sql, [], |r| r.get::<_, rusqlite::types::Value>(0))
                .map(|v| format!("{v:?}"))
                .unwrap()
        };
        assert_eq!(one("SELECT count(*) FROM trajectory_data"), "Integer(10)");
        assert_eq!(
            one("SELECT value FROM metadata WHERE key = 'version'"),
            "Text(\"2\")"
        );
        assert_eq!(
            one("SELECT value FROM metadata WHERE key = 'fps'"),
            "Text(\"25\")"
        );
        assert_eq!(
            one("SELECT value FROM metadata WHERE key = 'xmax'"),
            "Text(\"6\")"
        );
        // Frames 0 to 14, as JuPedSim's recording counts them.
        assert_eq!(one("SELECT count(*) FROM frame_data"), "Integer(15)");
        assert!(one("SELECT wkt FROM geometry").starts_with("Text(\"POLYGON ((-1.0000 -1.0000"));
        // The orientation: the walking direction, kept where the person stops.
        let (ox, oy): (f64, f64) = con
            .query_row(
                "SELECT ori_x, ori_y FROM trajectory_data WHERE id = 4 AND frame = 12",
                [],
                |r| Ok((r.get(0)?, r.get(1)?)),
            )
            .unwrap();
        assert!(
            (ox - 0.0).abs() < 1e-12 && (oy - 1.0).abs() < 1e-12,
            "{ox} {oy}"
        );
        let (ox, _): (f64, f64) = con
            .query_row(
                "SELECT ori_x, ori_y FROM trajectory_data WHERE id = 4 AND frame = 11",
                [],
                |r| Ok((r.get(0)?, r.get(1)?)),
            )
            .unwrap();
        assert!((ox - 0.5f64.sqrt()).abs() < 1e-12);
        assert_eq!(
            one("SELECT score FROM geostride_points WHERE id = 5 AND frame = 13"),
            "Null"
        );
        assert_eq!(
            one("SELECT head_height FROM geostride_points WHERE id = 4 AND frame = 13"),
            "Real(1.7)"
        );
    }

    #[test]
    fn a_failed_write_leaves_no_file() {
        let dir = tempfile::tempdir().unwrap();
        let (walkable, frame) = (square(), SiteFrameNote::default());
        let broken = || {
            vec![
                Ok(trajectories().remove(0)),
                Err(std::io::Error::other("cache gone")),
            ]
        };
        for (name, r) in [
            (
                "t.h5",
                write_hdf5(&dir.path().join("t.h5"), &info(&walkable, &frame), broken()),
            ),
            (
                "t.sqlite",
                write_sqlite(
                    &dir.path().join("t.sqlite"),
                    &info(&walkable, &frame),
                    broken(),
                ),
            ),
        ] {
            let e = r.unwrap_err();
            assert!(
                e.to_string().contains("cache gone") && e.to_string().contains(name),
                "{e}"
            );
        }
        assert_eq!(std::fs::read_dir(dir.path()).unwrap().count(), 0);
    }
}
