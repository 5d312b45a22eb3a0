//! `geostride evaluate`: trajectories against the truth.

use std::path::{Path, PathBuf};

use anyhow::anyhow;
use nalgebra::Vector2;

use super::bad_input;
use crate::evaluate::{Sample, evaluate, ignore_brief};
use crate::io::FileCtx;

#[derive(clap::Args)]
pub struct Args {
    /// Truth positions: CSV with a header (the simulator's truth/heads.csv by default columns)
    #[arg(long, value_name = "CSV")]
    truth: PathBuf,
    /// Estimated trajectories: CSV with a header (geostride's trajectories.csv by default columns)
    #[arg(long, value_name = "CSV")]
    tracks: PathBuf,
    /// Distance within which an estimate matches a truth position, metres
    #[arg(long, default_value = "0.5", value_parser = super::parse_positive, value_name = "M")]
    threshold: f64,
    /// Truth columns: frame, id, x, y (where a column 'in_view' is 0, the row is a position that
    /// counts neither way)
    #[arg(long, default_value = "frame,person,e_m,n_m", value_name = "F,ID,X,Y")]
    truth_columns: String,
    /// Estimate columns: frame, id, x, y
    #[arg(long, default_value = "frame,id,e_m,n_m", value_name = "F,ID,X,Y")]
    tracks_columns: String,
    /// People in view in fewer frames than this count neither way (someone crossing a corner
    /// of the image, or cut off by the video's start or end, for less than the shortest track
    /// the pipeline keeps)
    #[arg(long, default_value = "1", value_name = "N")]
    min_frames: usize,
    /// Print JSON instead of the table
    #[arg(long)]
    json: bool,
}

/// Reads `frame, id, x, y` samples from a CSV with a header; rows whose `in_view` column is 0
/// are returned apart (ignored: neither to be found nor false alarms).
fn read_samples(
    path: &Path,
    columns: &str,
    what: &str,
) -> anyhow::Result<(Vec<Sample>, Vec<Sample>)> {
    let ctx = FileCtx { path };
    let text = ctx.read_text(what).map_err(bad_input)?;
    let mut lines = text.lines();
    let header: Vec<&str> = lines
        .next()
        .unwrap_or("")
        .split(',')
        .map(str::trim)
        .collect();
    let want: Vec<&str> = columns.split(',').map(str::trim).collect();
    if want.len() != 4 {
        return Err(bad_input(anyhow!(
            "columns '{columns}': expected four names: frame, id, x, y"
        )));
    }
    let idx: Vec<usize> = want
        .iter()
        .map(|w| {
            header.iter().position(|h| h == w).ok_or_else(|| {
                bad_input(ctx.at(
                    1,
                    format!("no column '{w}' in the header ({})", header.join(",")),
                ))
            })
        })
        .collect::<anyhow::Result<_>>()?;
    let in_view = header.iter().position(|h| *h == "in_view");
    let (mut out, mut ignored) = (Vec::new(), Vec::new());
    for (i, line) in lines.enumerate() {
        if line.trim().is_empty() {
            continue;
        }
        let f: Vec<&str> = line.split(',').collect();
        let get = |k: usize, name: &str| -> anyhow::Result<f64> {
            ctx.number(f.get(idx[k]).copied().unwrap_or(""), i + 2, name)
                .map_err(bad_input)
        };
        let sample = Sample {
            frame: get(0, want[0])? as usize,
            id: get(1, want[1])? as usize,
            position: Vector2::new(get(2, want[2])?, get(3, want[3])?),
        };
        if in_view.is_some_and(|c| f.get(c).map(|v| v.trim()) == Some("0")) {
            ignored.push(sample);
        } else {
            out.push(sample);
        }
    }
    Ok((out, ignored))
}

pub fn run(args: Args) -> anyhow::Result<()> {
    let (mut truth, mut ignored) =
        read_samples(&args.truth, &args.truth_columns, "a CSV of truth positions")?;
    let brief = ignore_brief(&mut truth, &mut ignored, args.min_frames);
    let (est, _) = read_samples(&args.tracks, &args.tracks_columns, "a CSV of trajectories")?;
    let e = evaluate(&truth, &est, &ignored, args.threshold);
    if args.json {
        let mut v = serde_json::to_value(&e)?;
        v["brief_people_not_counted"] = brief.into();
        println!("{}", serde_json::to_string_pretty(&v)?);
        return Ok(());
    }
    println!(
        "Against {} ({} positions of {} people), threshold {} m:",
        args.truth.display(),
        e.truth_positions,
        e.truth_tracks,
        e.threshold_m
    );
    if brief > 0 {
        println!(
            "  ({brief} people in view in fewer than {} frames not counted)",
            args.min_frames
        );
    }
    println!(
        "  position error   RMSE {:.4} m, mean {:.4} m, 95th percentile {:.4} m, largest {:.4} m ({} matches)",
        e.rmse_m, e.mean_error_m, e.p95_error_m, e.max_error_m, e.matches
    );
    println!(
        "  MOTA {:.4}, MOTP {:.4} m, IDF1 {:.4}",
        e.mota, e.motp_m, e.idf1
    );
    println!(
        "  misses {}, false positives {}, ID switches {} ({:.2} % of the people), fragmentations {}",
        e.misses,
        e.false_positives,
        e.id_switches,
        100.0 * e.id_switch_rate,
        e.fragmentations
    );
    println!(
        "  people: {} tracked over ≥ 90 % of their frames ({:.1} %), {} mostly tracked, {} mostly lost; {} estimated tracks",
        e.tracked_90,
        100.0 * e.tracked_90_fraction,
        e.mostly_tracked,
        e.mostly_lost,
        e.estimated_tracks
    );
    Ok(())
}
