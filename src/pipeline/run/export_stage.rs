//! Stage 6, `export`.

use std::collections::BTreeMap;
use std::path::Path;
use std::time::Instant;

use nalgebra::{Vector2, Vector3};

use super::{Env, RunError, RunInputs, StageRecord, StageStatus};
use crate::analysis::ConvexPolygon;
use crate::cache::{StageCache, cache_gone};
use crate::export::gis::write_geopackage;
use crate::export::{ExportFormat, SiteFrameNote, Trajectory};
use crate::pipeline::project::AnalysisSection;
use crate::pipeline::views::{Walkable, walkable_area};
use crate::survey::crs::{Crs, HeightKind, Transform, UsedOperations};
use crate::track::ImageTrack;

/// What writing one export format gave: files, warnings, and the WGS 84 transformations used.
#[derive(Default)]
struct Written {
    outputs: Vec<String>,
    warnings: Vec<String>,
    transformations: Vec<String>,
}

/// Trajectories to WGS 84 for GeoJSON, one at a time, and what the report should say about them.
struct Wgs84 {
    crs: Crs,
    to_wgs84: Transform,
    used: UsedOperations,
    heights_ellipsoidal: bool,
    /// The survey's kind of height, for the report.
    heights: String,
}

impl Wgs84 {
    /// Converts output-CRS coordinates (`crs`, in the CRS `spec`) to WGS 84 with the
    /// transformation PROJ picks for each point (datum change included; the one `cs2cs` uses).
    /// Heights are kept, as WGS 84 ellipsoidal heights, only when the survey's are ellipsoidal:
    /// RFC 7946 allows no other kind.
    fn new(spec: &str, heights: &HeightKind) -> Result<Wgs84, RunError> {
        let failed = RunError::Crs;
        let crs = Crs::new(spec).map_err(failed)?;
        let to_wgs84 =
            Transform::new(&crs, &Crs::new("EPSG:4326").map_err(failed)?).map_err(failed)?;
        Ok(Wgs84 {
            crs,
            to_wgs84,
            used: UsedOperations::default(),
            heights_ellipsoidal: *heights == HeightKind::Ellipsoidal,
            heights: heights.to_string(),
        })
    }

    /// The trajectory's points as (longitude, latitude, ellipsoidal height or NaN).
    fn convert(&mut self, t: &Trajectory) -> Result<Vec<Vector3<f64>>, RunError> {
        let crs: Vec<Vector3<f64>> = t.points.iter().map(|q| q.crs).collect();
        self.convert_points(&crs)
    }

    /// Output-CRS points as (longitude, latitude, ellipsoidal height or NaN).
    fn convert_points(&mut self, crs: &[Vector3<f64>]) -> Result<Vec<Vector3<f64>>, RunError> {
        crs.iter()
            .map(|q| {
                let (lon, lat, h) = self
                    .to_wgs84
                    .apply_3d_noting(q.x, q.y, q.z, &mut self.used)
                    .map_err(RunError::Crs)?;
                Ok(Vector3::new(
                    lon,
                    lat,
                    if self.heights_ellipsoidal {
                        h
                    } else {
                        f64::NAN
                    },
                ))
            })
            .collect()
    }

    /// PROJ's operations used, with their accuracy, and the notes for the report.
    fn report(&self) -> (Vec<String>, Vec<String>) {
        let operations = self
            .used
            .infos()
            .iter()
            .map(|op| {
                let acc = op.accuracy_m.map_or("accuracy unknown".to_string(), |a| {
                    format!("accuracy {a} m")
                });
                format!(
                    "{} to WGS 84: PROJ's '{}' ({acc})",
                    self.crs.label(),
                    op.name
                )
            })
            .collect();
        let mut notes = Vec::new();
        if !self.heights_ellipsoidal {
            notes.push(format!(
                "GeoJSON positions are 2D: RFC 7946 heights are ellipsoidal on WGS 84 and the survey's are {}; the heights are in trajectories.csv and the GeoPackage",
                self.heights
            ));
        }
        (operations, notes)
    }
}

/// An area for `areas.geojson`: its role, where it came from, its site-frame WKT and area, and
/// its vertices in the output CRS.
struct AreaOut {
    role: &'static str,
    source: &'static str,
    wkt: String,
    shape: crate::export::geojson::Shape,
    crs: Vec<Vector3<f64>>,
}

/// The run's areas with their vertices in the output CRS; none without a CRS.
fn areas_out(
    inputs: &RunInputs,
    measurement: Option<&ConvexPolygon>,
    walkable: Option<&Walkable>,
    lines: &[[Vector2<f64>; 2]],
) -> Result<Vec<AreaOut>, RunError> {
    use crate::export::geojson::Shape;
    let frame = &inputs.framed.frame;
    if frame.crs.is_none() {
        return Ok(Vec::new());
    }
    let mut areas = Vec::new();
    let polygon = |p: &ConvexPolygon| {
        (
            p.vertices().to_vec(),
            crate::export::polygon_wkt(p.vertices()),
            Shape::Polygon { area_m2: p.area() },
        )
    };
    let shapes = walkable
        .map(|w| ("walkable", w.source, polygon(&w.polygon)))
        .into_iter()
        .chain(measurement.map(|m| ("measurement", "[analysis] measurement_area", polygon(m))))
        .chain(lines.iter().map(|l| {
            (
                "measurement_line",
                "[analysis] measurement_lines",
                (
                    l.to_vec(),
                    crate::export::linestring_wkt(l),
                    Shape::Line {
                        length_m: (l[1] - l[0]).norm(),
                    },
                ),
            )
        }));
    for (role, source, (vertices, wkt, shape)) in shapes {
        let crs = vertices
            .iter()
            .map(|v| {
                let src = frame
                    .source_from_local(&Vector3::new(v.x, v.y, 0.0))
                    .map_err(RunError::Crs)?;
                Ok(match &inputs.transform {
                    Some(t) => {
                        let (x, y) = t.apply(src.x, src.y).map_err(RunError::Crs)?;
                        Vector3::new(x, y, src.z)
                    }
                    None => src,
                })
            })
            .collect::<Result<Vec<_>, RunError>>()?;
        areas.push(AreaOut {
            role,
            source,
            wkt,
            shape,
            crs,
        });
    }
    Ok(areas)
}

/// [`cache_gone`] as an I/O error, for the writers.
fn gone(cache: &StageCache, stage: &str) -> std::io::Error {
    std::io::Error::other(cache_gone(cache, stage).to_string())
}

/// What every format's writer reads: the output folder, the run's facts and the stage caches
/// (the context is not shared by threads).
struct ExportInputs<'a> {
    out: &'a Path,
    fps: f64,
    origin_note: &'a str,
    /// How the site frame lies in the survey's CRS, for the files' headers.
    frame: SiteFrameNote,
    /// The walkable area the analysis uses too (none when nobody was tracked and none given).
    walkable: Option<Walkable>,
    /// The walkable and measurement areas with their vertices in the output CRS, for
    /// `areas.geojson` (none without a CRS).
    areas: Vec<AreaOut>,
    crs_wkt: String,
    out_crs_spec: Option<String>,
    height_kind: &'a HeightKind,
    cache: &'a StageCache,
    smooth_key: &'a str,
    track_key: &'a str,
    /// The scan's chunks: (stage, key).
    chunks: Vec<(String, String)>,
}

impl ExportInputs<'_> {
    /// The trajectories read back from the smooth stage's cache, one at a time.
    fn trajectories(&self) -> std::io::Result<crate::cache::CachedSeq<Trajectory>> {
        self.cache
            .read_seq::<Trajectory>("smooth", self.smooth_key)
            .map_err(|e| std::io::Error::other(e.to_string()))
    }

    /// The scan's chunks read back from their caches, one at a time.
    fn chunk_data(
        &self,
    ) -> impl Iterator<Item = std::io::Result<crate::pipeline::chunk_pass::ChunkData>> + '_ {
        self.chunks.iter().map(|(stage, key)| {
            self.cache
                .load::<crate::pipeline::chunk_pass::ChunkData>(stage, key)
                .ok_or_else(|| gone(self.cache, stage))
        })
    }

    /// The file `name` written piece by piece into its temporary (an hour's outputs never stand
    /// whole in memory); a failed write leaves no file.
    fn put(
        &self,
        name: &str,
        fill: &mut dyn FnMut(&mut dyn std::io::Write) -> std::io::Result<()>,
        w: &mut Written,
    ) -> Result<(), RunError> {
        let path = self.out.join(name);
        crate::io::write_atomic_with(&path, |w| fill(w)).map_err(|source| RunError::Io {
            path: path.clone(),
            source,
        })?;
        w.outputs.push(name.to_string());
        Ok(())
    }
}

/// One format's files: one writer per [`ExportFormat`].
fn write_format(f: ExportFormat, x: &ExportInputs) -> Result<Written, RunError> {
    let mut w = Written::default();
    match f {
        ExportFormat::Csv => x.put(
            "trajectories.csv",
            &mut |o| crate::export::write_trajectories_csv(o, x.trajectories()?),
            &mut w,
        )?,
        ExportFormat::PeTrack => x.put(
            "trajectories.txt",
            &mut |o| crate::export::write_petrack_txt(o, x.trajectories()?, x.fps, &x.frame),
            &mut w,
        )?,
        ExportFormat::Hdf5 | ExportFormat::Sqlite => write_archive(f, x, &mut w)?,
        // The image tracks and the detections are read back from the stage caches a track and
        // a chunk at a time: a long video's are not held in memory for these files.
        ExportFormat::Mot => x.put(
            "tracks_mot.txt",
            &mut |o| {
                let tracks = x
                    .cache
                    .read_seq::<ImageTrack>("track", x.track_key)
                    .map_err(|e| std::io::Error::other(e.to_string()))?;
                crate::export::write_mot_in_order(o, tracks)
            },
            &mut w,
        )?,
        ExportFormat::Detections => {
            x.put("detections.csv", &mut |o| write_detections(o, x), &mut w)?
        }
        ExportFormat::GeoPackage => {
            // Two passes: the lines, then the positions.
            let each = || -> Box<dyn Iterator<Item = std::io::Result<Trajectory>>> {
                match x.trajectories() {
                    Ok(seq) => Box::new(seq),
                    Err(e) => Box::new(std::iter::once(Err(e))),
                }
            };
            write_geopackage(&x.out.join("trajectories.gpkg"), &x.crs_wkt, each)?;
            w.outputs.push("trajectories.gpkg".into());
        }
        ExportFormat::GeoJson => write_geojson(x, &mut w)?,
    }
    Ok(w)
}

/// `trajectories.h5` or `trajectories.sqlite` (`archive`), with the walkable area.
#[cfg(feature = "archives")]
fn write_archive(f: ExportFormat, x: &ExportInputs, w: &mut Written) -> Result<(), RunError> {
    use crate::export::archive::{ArchiveInfo, write_hdf5, write_sqlite};
    let info = ArchiveInfo {
        fps: x.fps,
        walkable: x.walkable.as_ref().map_or(&[], |w| w.polygon.vertices()),
        walkable_source: x.walkable.as_ref().map_or("none", |w| w.source),
        frame: &x.frame,
        producer_version: crate::cache::build_id(),
    };
    let trajectories = x.trajectories().map_err(|source| RunError::Io {
        path: x.out.to_path_buf(),
        source,
    })?;
    let name = if f == ExportFormat::Hdf5 {
        "trajectories.h5"
    } else {
        "trajectories.sqlite"
    };
    let path = x.out.join(name);
    match f {
        ExportFormat::Hdf5 => write_hdf5(&path, &info, trajectories),
        _ => write_sqlite(&path, &info, trajectories),
    }
    .map_err(|e| RunError::Failed(e.to_string()))?;
    w.outputs.push(name.into());
    Ok(())
}

#[cfg(not(feature = "archives"))]
fn write_archive(f: ExportFormat, _: &ExportInputs, _: &mut Written) -> Result<(), RunError> {
    Err(RunError::Failed(format!(
        "[export] formats: '{}' needs geostride built with its 'archives' feature (HDF5 and SQLite)",
        f.name()
    )))
}

/// `detections.csv`: every chunk's detections, read back a chunk at a time.
fn write_detections(o: &mut dyn std::io::Write, x: &ExportInputs) -> std::io::Result<()> {
    use crate::detect::error_fit::{DETECTIONS_HEADER, write_detection_rows};
    writeln!(o, "{DETECTIONS_HEADER}")?;
    for chunk in x.chunk_data() {
        let chunk = chunk?;
        if chunk.end > chunk.start {
            write_detection_rows(o, chunk.start, &chunk.detections)?;
        }
    }
    Ok(())
}

/// `motion-check.csv`: what the motion check found that the detector missed, every chunk's
/// read back in turn; the count of blobs and of frames.
fn write_missed(x: &ExportInputs, w: &mut Written) -> Result<(usize, usize), RunError> {
    let (mut blobs, mut frames) = (0, 0);
    x.put(
        "motion-check.csv",
        &mut |o| {
            writeln!(o, "frame,x,y,width,height")?;
            for chunk in x.chunk_data() {
                let chunk = chunk?;
                let mut last = None;
                for (f, b) in &chunk.missed {
                    writeln!(o, "{f},{:.1},{:.1},{:.1},{:.1}", b[0], b[1], b[2], b[3])?;
                    blobs += 1;
                    frames += usize::from(last != Some(*f));
                    last = Some(*f);
                }
            }
            Ok(())
        },
        w,
    )?;
    Ok((blobs, frames))
}

/// `trajectories.geojson` and `positions.geojson`: RFC 7946, WGS 84 longitude, latitude and
/// ellipsoidal height, through PROJ (its own handles: this runs on a worker thread). Both files
/// are written together, a trajectory at a time, each converted once.
fn write_geojson(x: &ExportInputs, w: &mut Written) -> Result<(), RunError> {
    let Some(spec) = &x.out_crs_spec else {
        w.warnings.push(format!(
            "GeoJSON needs WGS 84: the site frame ({}) has no CRS, so it is not written",
            x.origin_note
        ));
        return Ok(());
    };
    let mut wgs = Wgs84::new(spec, x.height_kind)?;
    let mut failed: Option<RunError> = None;
    let mut both =
        |lines: &mut dyn std::io::Write, points: &mut dyn std::io::Write| -> std::io::Result<()> {
            let mut l = crate::export::geojson::Features::new(lines);
            let mut p = crate::export::geojson::Features::new(points);
            for t in x.trajectories()? {
                let t = &t?;
                let c = match wgs.convert(t) {
                    Ok(c) => c,
                    Err(e) => {
                        failed = Some(e);
                        return Err(std::io::Error::other("conversion to WGS 84"));
                    }
                };
                l.line(t, &c)?;
                p.points(t, &c)?;
            }
            l.finish()?;
            p.finish()
        };
    let lines_path = x.out.join("trajectories.geojson");
    let points_path = x.out.join("positions.geojson");
    let written = crate::io::write_atomic_with(&lines_path, |lw| {
        // The message names the file at fault.
        crate::io::write_atomic_with(&points_path, |pw| both(lw, pw))
            .map_err(|e| std::io::Error::new(e.kind(), format!("{}: {e}", points_path.display())))
    });
    if let Some(e) = failed {
        return Err(e);
    }
    written.map_err(|source| RunError::Io {
        path: lines_path.clone(),
        source,
    })?;
    w.outputs.push("trajectories.geojson".into());
    w.outputs.push("positions.geojson".into());
    if !x.areas.is_empty() {
        let path = x.out.join("areas.geojson");
        let mut rings = Vec::new();
        for a in &x.areas {
            rings.push(wgs.convert_points(&a.crs)?);
        }
        crate::io::write_atomic_with(&path, |o| {
            let mut f = crate::export::geojson::Features::new(o);
            for (a, ring) in x.areas.iter().zip(&rings) {
                f.area((a.role, a.source, &a.wkt, a.shape), ring)?;
            }
            f.finish()
        })
        .map_err(|source| RunError::Io { path, source })?;
        w.outputs.push("areas.geojson".into());
    }
    let (operations, notes) = wgs.report();
    w.warnings.extend(notes);
    w.transformations = operations;
    Ok(())
}

/// How the site frame lies in the survey's CRS.
fn site_frame_note(frame: &crate::survey::frame::SiteFrame) -> SiteFrameNote {
    SiteFrameNote {
        origin_note: frame.origin_note.clone(),
        crs: frame.crs.as_ref().map(|c| c.label()),
        origin_geodetic: frame.tangent.as_ref().map(|t| {
            [
                t.origin.lat.to_degrees(),
                t.origin.lon.to_degrees(),
                t.origin.h,
            ]
        }),
        origin_in_crs: frame
            .crs
            .as_ref()
            .and_then(|_| frame.source_from_local(&Vector3::zeros()).ok())
            .map(|v| [v.x, v.y, v.z]),
        heights: frame.height.to_string(),
    }
}

/// `walkable_area.wkt` (and `measurement_area.wkt`, `measurement_lines.wkt` (a line each) when
/// `[analysis]` gives them): the areas and lines in the site frame, as PedPy's
/// `WalkableArea`, `MeasurementArea` and `MeasurementLine` read WKT.
fn write_areas(
    out: &Path,
    measurement: Option<&ConvexPolygon>,
    walkable: Option<&Walkable>,
    lines: &[[Vector2<f64>; 2]],
) -> Result<Vec<String>, RunError> {
    let mut files: Vec<(&str, String)> = walkable
        .iter()
        .map(|w| {
            (
                "walkable_area.wkt",
                crate::export::polygon_wkt(w.polygon.vertices()),
            )
        })
        .collect();
    if let Some(m) = measurement {
        files.push((
            "measurement_area.wkt",
            crate::export::polygon_wkt(m.vertices()),
        ));
    }
    if !lines.is_empty() {
        let wkt: Vec<String> = lines
            .iter()
            .map(|l| crate::export::linestring_wkt(l))
            .collect();
        files.push(("measurement_lines.wkt", wkt.join("\n")));
    }
    let mut names = Vec::new();
    for (name, wkt) in files {
        let path = out.join(name);
        crate::io::write_atomic(&path, format!("{wkt}\n").as_bytes())
            .map_err(|source| RunError::Io { path, source })?;
        names.push(name.to_string());
    }
    Ok(names)
}

/// Stage 6: the output files (always written: cheap, and the files must be there). Returns
/// the files written and the WGS 84 transformations used.
pub(super) fn export_stage(
    env: &Env,
    inputs: &RunInputs,
    analysis: &AnalysisSection,
    (smooth_key, track_key, count): (&str, &str, usize),
    warnings: &mut Vec<String>,
) -> Result<(Vec<String>, Vec<String>, StageRecord), RunError> {
    use rayon::prelude::*;
    let framed = &inputs.framed;
    let t0 = Instant::now();
    let mut outputs = Vec::new();
    let crs = inputs.out_crs.as_ref().or(framed.frame.crs.as_ref());
    let cached = super::views_stage::Cached {
        cache: &env.cache,
        key: smooth_key,
        count,
    };
    // None when nobody was tracked and no area is given: there is nothing to bound.
    let walkable = match walkable_area(analysis, inputs.surface.as_ref(), &cached) {
        Ok(w) => Some(w),
        Err(e) => {
            warnings.push(format!("no walkable area written: {e}"));
            None
        }
    };
    let (measurement, _) = analysis
        .polygons()
        .map_err(|(k, m)| RunError::Failed(format!("[analysis] {k}: {m}")))?;
    let lines = analysis
        .lines()
        .map_err(|(k, m)| RunError::Failed(format!("[analysis] {k}: {m}")))?;
    outputs.extend(write_areas(
        env.out,
        measurement.as_ref(),
        walkable.as_ref(),
        &lines,
    )?);
    let areas = areas_out(inputs, measurement.as_ref(), walkable.as_ref(), &lines)?;
    let x = ExportInputs {
        out: env.out,
        fps: inputs.fps,
        origin_note: &framed.frame.origin_note,
        frame: site_frame_note(&framed.frame),
        walkable,
        areas,
        crs_wkt: crs.map(|c| c.wkt.clone()).unwrap_or_default(),
        out_crs_spec: crs.map(|c| c.spec.clone()),
        height_kind: &framed.frame.height,
        cache: &env.cache,
        smooth_key,
        track_key,
        chunks: (0..inputs.grid.chunks())
            .map(|c| {
                (
                    super::scan_stage::chunk_stage(c),
                    super::scan_stage::chunk_key(&inputs.scan_key, c),
                )
            })
            .collect(),
    };
    let formats = &inputs.formats;
    let x = &x;
    let write = |f: &ExportFormat| write_format(*f, x);
    // The GeoPackage takes longest (SQLite and its spatial index): it starts at once on a
    // thread of its own; the results keep the formats' order.
    let write = &write;
    let written: Vec<Result<Written, RunError>> = std::thread::scope(|scope| {
        let gpkg = formats
            .iter()
            .position(|f| *f == ExportFormat::GeoPackage)
            .map(|k| (k, scope.spawn(move || write(&formats[k]))));
        // The others on the threads left beside the GeoPackage's (three threads on two cores
        // slowed the GeoPackage, the longest).
        let on_own = gpkg.as_ref().map(|(k, _)| *k);
        let others = || -> Vec<Result<Written, RunError>> {
            formats
                .par_iter()
                .enumerate()
                .filter(|(k, _)| on_own != Some(*k))
                .map(|(_, f)| write(f))
                .collect()
        };
        let threads = rayon::current_num_threads().saturating_sub(1).max(1);
        let mut rest = match (
            &gpkg,
            rayon::ThreadPoolBuilder::new().num_threads(threads).build(),
        ) {
            (Some(_), Ok(pool)) => pool.install(others),
            _ => others(),
        };
        if let Some((k, handle)) = gpkg {
            let w = handle
                .join()
                .unwrap_or_else(|_| Err(RunError::Failed("the GeoPackage writer failed".into())));
            rest.insert(k, w);
        }
        rest
    });
    let mut transformations = Vec::new();
    for w in written {
        let w = w?;
        outputs.extend(w.outputs);
        warnings.extend(w.warnings);
        transformations.extend(w.transformations);
    }
    if inputs.motion_check {
        let mut w = Written::default();
        let (blobs, frames) = write_missed(x, &mut w)?;
        outputs.extend(w.outputs);
        if blobs > 0 {
            warnings.push(format!(
                "the motion check found {blobs} moving blob(s) in {frames} frame(s) that no detection lies on: motion-check.csv lists them"
            ));
        }
    }
    let record = StageRecord {
        name: "export".into(),
        status: StageStatus::Computed,
        seconds: t0.elapsed().as_secs_f64(),
        counts: BTreeMap::from([("files".into(), outputs.len() as f64)]),
    };

    Ok((outputs, transformations, record))
}
