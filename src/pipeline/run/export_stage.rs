//! Stage 6, `export`.

use super::*;

/// Stage 6: the output files (always written: cheap, and the files must be there). Returns
/// the files written and the WGS 84 transformations used.
pub(super) fn export_stage(
    ctx: &Ctx,
    smoothed: &SmoothData,
    tracks: &[ImageTrack],
    scan_data: &ScanData,
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
    let put = |name: &str, text: &str, outputs: &mut Vec<String>| -> Result<(), RunError> {
        let path = out.join(name);
        write_atomic(&path, text.as_bytes()).map_err(|source| RunError::Io {
            path: path.clone(),
            source,
        })?;
        outputs.push(name.to_string());
        Ok(())
    };
    let trajs = &smoothed.trajectories;
    // The formats are independent files: written side by side.
    use rayon::prelude::*;
    let origin_note = &framed.frame.origin_note;
    let out_crs_spec = out_crs
        .as_ref()
        .or(framed.frame.crs.as_ref())
        .map(|c| c.spec.clone());
    let height_kind = &framed.frame.height;
    let write = |f: &String| -> Result<Written, RunError> {
        let mut w = Written::default();
        let outputs = &mut w.outputs;
        match f.as_str() {
            "csv" => put("trajectories.csv", &trajectories_csv(trajs), outputs)?,
            "petrack" => put(
                "trajectories.txt",
                &petrack_txt(trajs, fps, &format!("site frame ({origin_note}), metres")),
                outputs,
            )?,
            "mot" => put("tracks_mot.txt", &mot_txt(tracks), outputs)?,
            "detections" => put(
                "detections.csv",
                &crate::detect::error_fit::detections_csv(&scan_data.detections),
                outputs,
            )?,
            "gpkg" => {
                write_geopackage(&out.join("trajectories.gpkg"), &crs_wkt, trajs)?;
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
                // (its own handles: this runs on a worker thread).
                let wgs = wgs84_trajectories(spec, height_kind, trajs)?;
                put(
                    "trajectories.geojson",
                    &crate::export::geojson::lines(&wgs.trajectories),
                    outputs,
                )?;
                put(
                    "positions.geojson",
                    &crate::export::geojson::points(&wgs.trajectories),
                    outputs,
                )?;
                w.warnings.extend(wgs.notes);
                w.transformations = wgs.operations;
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
        status: "computed".into(),
        seconds: t0.elapsed().as_secs_f64(),
        counts: BTreeMap::from([("files".into(), outputs.len() as f64)]),
    };

    Ok((outputs, transformations, record))
}
