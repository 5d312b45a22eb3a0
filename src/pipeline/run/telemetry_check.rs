//! The drone's telemetry against the poses (`[video] telemetry`): each posed frame's camera
//! centre beside the position DJI's subtitles give for its time, their common offset (the
//! receiver's bias and the datum) removed, and the frames beyond 4 σ flagged
//! (`pose/telemetry.csv`, the two telemetry charts, a warning, the `telemetry` stage's numbers).
//! Heights are compared where the project says what `abs_alt` is above.

use std::collections::BTreeMap;
use std::fmt::Write as _;
use std::path::Path;
use std::time::Instant;

use nalgebra::{Vector2, Vector3};

use super::telemetry_site::SiteTelemetry;
use super::{Env, PoseData, RunError, RunInputs, StageRecord, StageStatus};
use crate::draw::{Chart, Series, Style, line_chart};

/// A frame is flagged when its residual is beyond this many σ (a 2D normal passes it once in
/// about 3000 frames).
const FLAG_SIGMAS: f64 = 4.0;

/// One posed frame beside its telemetry: frame, SRT block, the telemetry's and the pose's
/// east, north and up (up NaN where heights are not compared), metres.
struct Pair {
    frame: usize,
    block: u64,
    telemetry: Vector3<f64>,
    pose: Vector3<f64>,
}

/// The median of `v` (the mean of the middle two for an even count); `None` when empty.
fn median(mut v: Vec<f64>) -> Option<f64> {
    v.sort_by(f64::total_cmp);
    let n = v.len();
    match n {
        0 => None,
        _ if n % 2 == 1 => Some(v[n / 2]),
        _ => Some(0.5 * (v[n / 2 - 1] + v[n / 2])),
    }
}

/// The residuals about the common offset, and which frames are beyond 4 σ.
struct Checked {
    offset: Vector2<f64>,
    /// The heights' common offset; `None` without heights.
    offset_u: Option<f64>,
    /// Per pair: east-north residual, up residual (NaN without heights), flagged.
    residuals: Vec<(Vector2<f64>, f64, bool)>,
}

impl Checked {
    fn of(pairs: &[Pair], sigma_m: f64, sigma_vertical_m: f64) -> Checked {
        let axis = |f: &dyn Fn(&Pair) -> f64| median(pairs.iter().map(f).collect());
        let offset = Vector2::new(
            axis(&|p| p.telemetry.x - p.pose.x).unwrap_or(0.0),
            axis(&|p| p.telemetry.y - p.pose.y).unwrap_or(0.0),
        );
        let offset_u = median(
            pairs
                .iter()
                .map(|p| p.telemetry.z - p.pose.z)
                .filter(|d| d.is_finite())
                .collect(),
        );
        let residuals = pairs
            .iter()
            .map(|p| {
                let r = (p.telemetry - p.pose).xy() - offset;
                let ru = offset_u.map_or(f64::NAN, |o| p.telemetry.z - p.pose.z - o);
                let far =
                    r.norm() > FLAG_SIGMAS * sigma_m || ru.abs() > FLAG_SIGMAS * sigma_vertical_m;
                (r, ru, far)
            })
            .collect();
        Checked {
            offset,
            offset_u,
            residuals,
        }
    }
}

/// `pose/telemetry.csv`: one row a posed frame with telemetry.
fn telemetry_csv(pairs: &[Pair], c: &Checked) -> String {
    let mut csv = String::from(
        "frame,srt_block,e_telemetry_m,n_telemetry_m,u_telemetry_m,e_pose_m,n_pose_m,u_pose_m,residual_e_m,residual_n_m,residual_u_m,residual_m,flagged\n",
    );
    let num = |v: f64| {
        if v.is_finite() {
            format!("{v:.3}")
        } else {
            String::new()
        }
    };
    for (p, (r, ru, far)) in pairs.iter().zip(&c.residuals) {
        let _ = writeln!(
            csv,
            "{},{},{:.3},{:.3},{},{:.3},{:.3},{},{:.3},{:.3},{},{:.3},{}",
            p.frame,
            p.block,
            p.telemetry.x,
            p.telemetry.y,
            num(p.telemetry.z),
            p.pose.x,
            p.pose.y,
            num(if p.telemetry.z.is_finite() {
                p.pose.z
            } else {
                f64::NAN
            }),
            r.x,
            r.y,
            num(*ru),
            r.norm(),
            u8::from(*far)
        );
    }
    csv
}

/// The telemetry beside the estimated pose: `telemetry_track.png` (east, north and up of both
/// about the pose's mean, the telemetry moved by its common offset) and `telemetry_residual.png` (the residuals and
/// the 4 σ limits); the flagged frames ticked on both.
fn telemetry_charts(
    pose_dir: &Path,
    pairs: &[Pair],
    c: &Checked,
    fps: f64,
    (sigma_m, sigma_vertical_m): (f64, f64),
) -> std::io::Result<()> {
    let t = |p: &Pair| p.frame as f64 / fps;
    let series = |label: &str, rgb: [u8; 3], style: Style, v: &dyn Fn(usize) -> f64| Series {
        label: label.into(),
        xy: pairs
            .iter()
            .enumerate()
            .map(|(i, p)| (t(p), v(i)))
            .filter(|(_, y)| y.is_finite())
            .collect(),
        rgb,
        style,
    };
    let (blue, orange, green) = ([31, 119, 180], [255, 127, 14], [44, 160, 44]);
    // Each axis about the pose's mean on it, so that metres of wander show beside tens of
    // metres of position.
    let mean = |v: &dyn Fn(&Pair) -> f64| {
        let vals: Vec<f64> = pairs.iter().map(v).filter(|x| x.is_finite()).collect();
        vals.iter().sum::<f64>() / vals.len().max(1) as f64
    };
    let (me, mn) = (mean(&|p| p.pose.x), mean(&|p| p.pose.y));
    let mu = mean(&|p| {
        if p.telemetry.z.is_finite() {
            p.pose.z
        } else {
            f64::NAN
        }
    });
    let ou = c.offset_u.unwrap_or(f64::NAN);
    let about = |axis: &str, m: f64| {
        format!(
            "{axis} {} {:.1} m, pose",
            if m < 0.0 { '+' } else { '-' },
            m.abs()
        )
    };
    let mut track = vec![
        series(&about("east", me), blue, Style::Line, &|i| {
            pairs[i].pose.x - me
        }),
        series("telemetry", blue, Style::Dots, &|i| {
            pairs[i].telemetry.x - c.offset.x - me
        }),
        series(&about("north", mn), orange, Style::Line, &|i| {
            pairs[i].pose.y - mn
        }),
        series("telemetry", orange, Style::Dots, &|i| {
            pairs[i].telemetry.y - c.offset.y - mn
        }),
    ];
    let mut residual = vec![
        series("east-north", blue, Style::Line, &|i| {
            c.residuals[i].0.norm()
        }),
        series(
            &format!("{FLAG_SIGMAS} sigma east-north"),
            blue,
            Style::Dashed,
            &|_| FLAG_SIGMAS * sigma_m,
        ),
    ];
    if c.offset_u.is_some() {
        track.push(series(&about("up", mu), green, Style::Line, &|i| {
            if pairs[i].telemetry.z.is_finite() {
                pairs[i].pose.z - mu
            } else {
                f64::NAN
            }
        }));
        track.push(series("telemetry", green, Style::Dots, &|i| {
            pairs[i].telemetry.z - ou - mu
        }));
        residual.push(series("|up|", green, Style::Line, &|i| {
            c.residuals[i].1.abs()
        }));
        residual.push(series(
            &format!("{FLAG_SIGMAS} sigma up"),
            green,
            Style::Dashed,
            &|_| FLAG_SIGMAS * sigma_vertical_m,
        ));
    }
    let flagged: Vec<f64> = pairs
        .iter()
        .zip(&c.residuals)
        .filter(|(_, r)| r.2)
        .map(|(p, _)| t(p))
        .collect();
    for (file, title, y_label, series, y_from_data) in [
        (
            "telemetry_track.png",
            "Camera centre about its mean: pose and telemetry (common offset removed)",
            "m",
            track,
            true,
        ),
        (
            "telemetry_residual.png",
            "Telemetry minus pose, common offset removed",
            "m",
            residual,
            false,
        ),
    ] {
        let chart = Chart {
            title: title.into(),
            x_label: "time, s".into(),
            y_label: y_label.into(),
            series,
            ticks: flagged.clone(),
            ticks_label: "flagged".into(),
            y_from_data,
            x_from_zero: false,
        };
        line_chart(&chart, 900, 360)
            .and_then(|img| img.save(&pose_dir.join(file)))
            .map_err(std::io::Error::other)?;
    }
    Ok(())
}

/// Checks the poses against the telemetry; `None` without telemetry.
pub(super) fn telemetry_check(
    env: &Env,
    x: &RunInputs,
    pose_data: &PoseData,
    warnings: &mut Vec<String>,
) -> Result<Option<StageRecord>, RunError> {
    let Some(telemetry) = &x.telemetry else {
        return Ok(None);
    };
    let t0 = Instant::now();
    let site = match SiteTelemetry::new(telemetry, &x.framed, x.fps, true)? {
        Ok(s) => s,
        Err(why) => {
            warnings.push(format!("telemetry not checked: {why}"));
            return Ok(None);
        }
    };
    if telemetry.datum.is_some() && !site.has_heights() {
        warnings.push(format!("telemetry: {}", site.heights_note));
    }
    let mut pairs = Vec::new();
    for f in &pose_data.frames {
        if let Some(fix) = site.at(f.frame)? {
            pairs.push(Pair {
                frame: f.frame,
                block: fix.block,
                telemetry: fix.site,
                pose: f.pose().centre(),
            });
        }
    }
    if pairs.is_empty() {
        warnings.push("telemetry not checked: no posed frame has a telemetry position".into());
        return Ok(None);
    }
    let sigmas = (telemetry.sigma_m, telemetry.sigma_vertical_m);
    let c = Checked::of(&pairs, sigmas.0, sigmas.1);
    let pose_dir = env.out.join("pose");
    let path = pose_dir.join("telemetry.csv");
    crate::io::write_atomic(&path, telemetry_csv(&pairs, &c).as_bytes()).map_err(|source| {
        RunError::Io {
            path: path.clone(),
            source,
        }
    })?;
    telemetry_charts(&pose_dir, &pairs, &c, x.fps, sigmas).map_err(|source| RunError::Io {
        path: pose_dir.join("telemetry_track.png"),
        source,
    })?;
    let flagged: Vec<usize> = pairs
        .iter()
        .zip(&c.residuals)
        .filter(|(_, r)| r.2)
        .map(|(p, _)| p.frame)
        .collect();
    let n = pairs.len() as f64;
    let rms = (c.residuals.iter().map(|r| r.0.norm_squared()).sum::<f64>() / n).sqrt();
    let heights: Vec<f64> = c
        .residuals
        .iter()
        .map(|r| r.1)
        .filter(|v| v.is_finite())
        .collect();
    if !flagged.is_empty() {
        let shown: Vec<String> = flagged.iter().take(20).map(|f| f.to_string()).collect();
        warnings.push(format!(
            "telemetry: {} frame(s) whose camera centre is more than {:.1} m east-north{} ({FLAG_SIGMAS} σ) from the drone's position, after their common offset of ({:.2}, {:.2}{}) m east, north{}: frames {}{} (pose/telemetry.csv)",
            flagged.len(),
            FLAG_SIGMAS * sigmas.0,
            if heights.is_empty() {
                String::new()
            } else {
                format!(" or {:.1} m up", FLAG_SIGMAS * sigmas.1)
            },
            c.offset.x,
            c.offset.y,
            c.offset_u.map_or(String::new(), |u| format!(", {u:.2}")),
            if heights.is_empty() { "" } else { ", up" },
            shown.join(", "),
            if flagged.len() > 20 { ", …" } else { "" }
        ));
    }
    let mut counts = BTreeMap::from([
        ("frames_checked".into(), n),
        ("frames_flagged".into(), flagged.len() as f64),
        ("offset_e_m".into(), c.offset.x),
        ("offset_n_m".into(), c.offset.y),
        ("residual_rms_m".into(), rms),
        (
            "heights_compared".into(),
            f64::from(u8::from(!heights.is_empty())),
        ),
    ]);
    if let Some(u) = c.offset_u {
        counts.insert("offset_u_m".into(), u);
        counts.insert(
            "residual_rms_u_m".into(),
            (heights.iter().map(|v| v * v).sum::<f64>() / heights.len() as f64).sqrt(),
        );
    }
    Ok(Some(StageRecord {
        name: "telemetry".into(),
        status: StageStatus::Computed,
        seconds: t0.elapsed().as_secs_f64(),
        counts,
    }))
}
