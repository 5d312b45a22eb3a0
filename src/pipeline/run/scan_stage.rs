//! Stage 1, `scan`.

use super::*;

/// Stage 1: one decode pass, stabilisation and detection.
pub(super) fn scan_stage(
    ctx: &Ctx,
    detector: Box<dyn crate::detect::Detector>,
) -> Result<(ScanData, String, StageRecord), RunError> {
    let l = ctx.l;
    let progress = ctx.progress;
    let video = &ctx.video;
    let fps = ctx.fps;
    let max_frames = ctx.max_frames;
    let pick_frame = ctx.pick_frame;
    let control = &ctx.control;
    let check = &ctx.check;
    let px_per_m = ctx.px_per_m;
    let sums: Vec<&str> = ctx.sums.iter().map(String::as_str).collect();
    let p = &ctx.l.project;
    let scan_key = stage_key(
        "scan",
        &sums,
        &(
            &p.camera,
            &p.survey,
            &p.video,
            &p.pose,
            &p.detect,
            &p.projection.head_height_m,
            &p.ground,
        ),
    );
    let t0 = Instant::now();
    let (scan_data, status) = cached(&ctx.cache, ctx.progress, "scan", &scan_key, true, || {
        let detector = detector;
        let (min_features, key_fraction, key_every_s) = p.pose.key_frames();
        let stabilise = StabiliseSettings {
            min_features,
            min_fraction: key_fraction,
            max_interval: key_every_s.map(|s| (s * fps).round().max(1.0) as usize),
            ..StabiliseSettings::default()
        };
        let picks = control.iter().chain(check).map(|o| o.uv).collect();
        let bar = progress.stage("scan");
        let s = scan(
            ScanJob {
                video,
                max_frames,
                stabilise: Some((stabilise, pick_frame, picks)),
                detector: Some(detector),
            },
            bar.as_ref(),
        )
        .map_err(|e| match e {
            ScanError::Detector(e) => RunError::Input(l.error("detect", p.detect.failure_key(), e)),
            ScanError::Other(e) => RunError::Failed(e),
        })?;
        let d = ScanData {
            fps: s.fps,
            width: s.width,
            height: s.height,
            frames: s.frames,
            px_per_m,
            detector_summary: s.detector_summary,
            tracks: s.tracks,
            detections: s.detections,
            times: s.times,
        };
        Ok(d)
    })?;
    let n_det: usize = scan_data.detections.iter().map(Vec::len).sum();
    let record = StageRecord {
        name: "scan".into(),
        status: status.into(),
        seconds: t0.elapsed().as_secs_f64(),
        counts: BTreeMap::from([
            ("frames".into(), scan_data.frames as f64),
            ("width_px".into(), scan_data.width as f64),
            ("height_px".into(), scan_data.height as f64),
            ("detections".into(), n_det as f64),
            (
                "key_frames".into(),
                scan_data.tracks.iter().filter(|t| t.key.is_some()).count() as f64,
            ),
            ("decode_s".into(), scan_data.times.decode_s),
            ("stabilise_s".into(), scan_data.times.stabilise_s),
            ("detect_s".into(), scan_data.times.detect_s),
        ])
        .into_iter()
        .chain(scan_data.detector_summary.iter().cloned())
        .collect(),
    };

    Ok((scan_data, scan_key, record))
}
