//! The drone's telemetry against the poses (`[video] telemetry`): each posed frame's camera
//! centre beside the position DJI's subtitles give for its time, their common offset (the
//! receiver's bias and the datum) removed, and the frames beyond 4 σ flagged
//! (`pose/telemetry.csv`, a warning, the `telemetry` stage's numbers).

use std::collections::BTreeMap;
use std::fmt::Write as _;
use std::time::Instant;

use nalgebra::{Vector2, Vector3};

use super::{Env, PoseData, RunError, RunInputs, StageRecord, StageStatus};
use crate::survey::crs::{Crs, Transform};

/// A frame is flagged when its residual is beyond this many σ (a 2D normal passes it once in
/// about 3000 frames).
const FLAG_SIGMAS: f64 = 4.0;

/// One posed frame beside its telemetry: frame, SRT block, the telemetry's and the pose's
/// east and north, metres.
struct Pair {
    frame: usize,
    block: u64,
    telemetry: Vector2<f64>,
    pose: Vector2<f64>,
}

/// The median of each axis of `d`.
fn median_offset(d: &[Vector2<f64>]) -> Vector2<f64> {
    let med = |mut v: Vec<f64>| {
        v.sort_by(f64::total_cmp);
        let n = v.len();
        if n % 2 == 1 {
            v[n / 2]
        } else {
            0.5 * (v[n / 2 - 1] + v[n / 2])
        }
    };
    Vector2::new(
        med(d.iter().map(|v| v.x).collect()),
        med(d.iter().map(|v| v.y).collect()),
    )
}

/// Checks the poses against the telemetry; `None` without telemetry.
pub(super) fn telemetry_check(
    env: &Env,
    x: &RunInputs,
    pose_data: &PoseData,
    warnings: &mut Vec<String>,
) -> Result<Option<StageRecord>, RunError> {
    let Some((srt, sigma_m)) = &x.telemetry else {
        return Ok(None);
    };
    let t0 = Instant::now();
    let frame = &x.framed.frame;
    let Some(crs) = &frame.crs else {
        warnings.push(
            "telemetry not checked: the survey is in its own local frame, with no CRS to place latitudes and longitudes".into(),
        );
        return Ok(None);
    };
    let wgs84 = Crs::new("EPSG:4326").map_err(RunError::Crs)?;
    let to_survey = Transform::new(&wgs84, crs).map_err(RunError::Crs)?;
    let mut pairs = Vec::new();
    for f in &pose_data.frames {
        let Some(r) = srt.record_of_frame(f.frame, x.fps) else {
            continue;
        };
        let (Some(lat), Some(lon)) = (r.latitude_deg, r.longitude_deg) else {
            continue;
        };
        let (e, n) = to_survey.apply(lon, lat).map_err(RunError::Crs)?;
        let local = frame
            .local_from_source(&Vector3::new(e, n, f64::NAN))
            .map_err(RunError::Crs)?;
        pairs.push(Pair {
            frame: f.frame,
            block: r.index,
            telemetry: local.xy(),
            pose: f.pose().centre().xy(),
        });
    }
    if pairs.is_empty() {
        warnings.push("telemetry not checked: no posed frame has a telemetry position".into());
        return Ok(None);
    }
    let offset = median_offset(
        &pairs
            .iter()
            .map(|p| p.telemetry - p.pose)
            .collect::<Vec<_>>(),
    );
    let limit = FLAG_SIGMAS * sigma_m;
    let mut csv = String::from(
        "frame,srt_block,e_telemetry_m,n_telemetry_m,e_pose_m,n_pose_m,residual_e_m,residual_n_m,residual_m,flagged\n",
    );
    let (mut flagged, mut sum2) = (Vec::new(), 0.0);
    for p in &pairs {
        let r = p.telemetry - p.pose - offset;
        let far = r.norm() > limit;
        if far {
            flagged.push(p.frame);
        }
        sum2 += r.norm_squared();
        let _ = writeln!(
            csv,
            "{},{},{:.3},{:.3},{:.3},{:.3},{:.3},{:.3},{:.3},{}",
            p.frame,
            p.block,
            p.telemetry.x,
            p.telemetry.y,
            p.pose.x,
            p.pose.y,
            r.x,
            r.y,
            r.norm(),
            u8::from(far)
        );
    }
    let path = env.out.join("pose").join("telemetry.csv");
    crate::io::write_atomic(&path, csv.as_bytes()).map_err(|source| RunError::Io {
        path: path.clone(),
        source,
    })?;
    let rms = (sum2 / pairs.len() as f64).sqrt();
    if !flagged.is_empty() {
        let shown: Vec<String> = flagged.iter().take(20).map(|f| f.to_string()).collect();
        warnings.push(format!(
            "telemetry: {} frame(s) whose camera centre is more than {limit:.1} m ({FLAG_SIGMAS} σ) from the drone's position, after their common offset of ({:.2}, {:.2}) m east, north: frames {}{} (pose/telemetry.csv)",
            flagged.len(),
            offset.x,
            offset.y,
            shown.join(", "),
            if flagged.len() > 20 { ", …" } else { "" }
        ));
    }
    Ok(Some(StageRecord {
        name: "telemetry".into(),
        status: StageStatus::Computed,
        seconds: t0.elapsed().as_secs_f64(),
        counts: BTreeMap::from([
            ("frames_checked".into(), pairs.len() as f64),
            ("frames_flagged".into(), flagged.len() as f64),
            ("offset_e_m".into(), offset.x),
            ("offset_n_m".into(), offset.y),
            ("residual_rms_m".into(), rms),
        ]),
    }))
}
