//! Stage 6, `export`.

use super::*;

/// [`cache_gone`] as an I/O error, for the writers.
fn gone(cache: &StageCache, stage: &str) -> std::io::Error {
    std::io::Error::other(cache_gone(cache, stage).to_string())
}

/// Stage 6: the output files (always written: cheap, and the files must be there). Returns
/// the files written and the WGS 84 transformations used.
pub(super) fn export_stage(
    ctx: &Ctx,
    smooth_key: &str,
    track_key: &str,
    warnings: &mut Vec<String>,
) -> Result<(Vec<String>, Vec<String>, StageRecord), RunError> {
    let out = ctx.out;
    let p = &ctx.l.project;
    let fps = ctx.fps;
    let framed = &ctx.framed;
    let out_crs = &ctx.out_crs;
    let t0 = Instant::now();
    let mut outputs = Vec::new();
    let crs_wkt = out_crs
        .as_ref()
        .or(framed.frame.crs.as_ref())
        .map(|c| c.wkt.clone())
        .unwrap_or_default();
    // Each file written piece by piece into its temporary (an hour's outputs never stand whole
    // in memory); a failed write leaves no file.
    let put = |name: &str,
               fill: &mut dyn FnMut(&mut dyn std::io::Write) -> std::io::Result<()>,
               outputs: &mut Vec<String>|
     -> Result<(), RunError> {
        let path = out.join(name);
        crate::io::write_atomic_with(&path, |w| fill(w)).map_err(|source| RunError::Io {
            path: path.clone(),
            source,
        })?;
        outputs.push(name.to_string());
        Ok(())
    };
    // Every writer reads the trajectories back from the smooth stage's cache, one at a time.
    let cache = &ctx.cache;
    let trajs = || {
        cache
            .read_seq::<Trajectory>("smooth", smooth_key)
            .map_err(|e| std::io::Error::other(e.to_string()))
    };
    // The formats are independent files: written side by side.
    use rayon::prelude::*;
    let origin_note = &framed.frame.origin_note;
    let out_crs_spec = out_crs
        .as_ref()
        .or(framed.frame.crs.as_ref())
        .map(|c| c.spec.clone());
    let height_kind = &framed.frame.height;
    // What the writers read back from the stage caches (the context is not shared by threads).
    let chunks: Vec<(String, String)> = (0..ctx.grid.chunks())
        .map(|c| {
            (
                super::scan_stage::chunk_stage(c),
                super::scan_stage::chunk_key(ctx, c),
            )
        })
        .collect();
    let write = |f: &String| -> Result<Written, RunError> {
        let mut w = Written::default();
        let outputs = &mut w.outputs;
        match f.as_str() {
            "csv" => put(
                "trajectories.csv",
                &mut |w| crate::export::write_trajectories_csv(w, trajs()?),
                outputs,
            )?,
            "petrack" => {
                let note = format!("site frame ({origin_note}), metres");
                put(
                    "trajectories.txt",
                    &mut |w| crate::export::write_petrack_txt(w, trajs()?, fps, &note),
                    outputs,
                )?
            }
            // The image tracks and the detections are read back from the stage caches a track
            // and a chunk at a time: a long video's are not held in memory for these files.
            "mot" => put(
                "tracks_mot.txt",
                &mut |w| {
                    let tracks = cache
                        .read_seq::<ImageTrack>("track", track_key)
                        .map_err(|e| std::io::Error::other(e.to_string()))?;
                    crate::export::write_mot_in_order(w, tracks)
                },
                outputs,
            )?,
            "detections" => put(
                "detections.csv",
                &mut |w| {
                    use crate::detect::error_fit::{DETECTIONS_HEADER, write_detection_rows};
                    writeln!(w, "{DETECTIONS_HEADER}")?;
                    for (stage, key) in &chunks {
                        let chunk = cache
                            .load::<crate::pipeline::chunk_pass::ChunkData>(stage, key)
                            .ok_or_else(|| gone(cache, stage))?;
                        if chunk.end > chunk.start {
                            write_detection_rows(w, chunk.start, &chunk.detections)?;
                        }
                    }
                    Ok(())
                },
                outputs,
            )?,
            "gpkg" => {
                // Two passes: the lines, then the positions.
                let each = || -> Box<dyn Iterator<Item = std::io::Result<Trajectory>>> {
                    match trajs() {
                        Ok(seq) => Box::new(seq),
                        Err(e) => Box::new(std::iter::once(Err(e))),
                    }
                };
                write_geopackage(&out.join("trajectories.gpkg"), &crs_wkt, each)?;
                outputs.push("trajectories.gpkg".into());
            }
            "geojson" => {
                let Some(spec) = &out_crs_spec else {
                    w.warnings.push(
                        "GeoJSON needs WGS 84: the GCP file has no CRS, so it is not written"
                            .into(),
                    );
                    return Ok(w);
                };
                // RFC 7946: WGS 84 longitude, latitude and ellipsoidal height, through PROJ
                // (its own handles: this runs on a worker thread). Both files are written
                // together, a trajectory at a time, each converted once.
                let mut wgs = Wgs84::new(spec, height_kind)?;
                let mut failed: Option<RunError> = None;
                let mut both = |lines: &mut dyn std::io::Write,
                                points: &mut dyn std::io::Write|
                 -> std::io::Result<()> {
                    let mut l = crate::export::geojson::Features::new(lines);
                    let mut p = crate::export::geojson::Features::new(points);
                    for t in trajs()? {
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
                let lines_path = out.join("trajectories.geojson");
                let points_path = out.join("positions.geojson");
                let written = crate::io::write_atomic_with(&lines_path, |lw| {
                    // The message names the file at fault.
                    crate::io::write_atomic_with(&points_path, |pw| both(lw, pw)).map_err(|e| {
                        std::io::Error::new(e.kind(), format!("{}: {e}", points_path.display()))
                    })
                });
                if let Some(e) = failed {
                    return Err(e);
                }
                written.map_err(|source| RunError::Io {
                    path: lines_path.clone(),
                    source,
                })?;
                outputs.push("trajectories.geojson".into());
                outputs.push("positions.geojson".into());
                let (operations, notes) = wgs.report();
                w.warnings.extend(notes);
                w.transformations = operations;
            }
            _ => unreachable!("checked when the project was read"),
        }
        Ok(w)
    };
    // The GeoPackage takes longest (SQLite and its spatial index): it starts at once on a
    // thread of its own; the results keep the formats' order.
    let formats = &p.export.formats;
    let write = &write;
    let written: Vec<Result<Written, RunError>> = std::thread::scope(|scope| {
        let gpkg = formats
            .iter()
            .position(|f| f == "gpkg")
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
    let record = StageRecord {
        name: "export".into(),
        status: StageStatus::Computed,
        seconds: t0.elapsed().as_secs_f64(),
        counts: BTreeMap::from([("files".into(), outputs.len() as f64)]),
    };

    Ok((outputs, transformations, record))
}
