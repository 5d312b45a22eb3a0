//! `geostride evaluate`: trajectories against the truth.

use std::path::{Path, PathBuf};

use anyhow::anyhow;

use super::bad_input;
use geostride::evaluate::{
    SampleTable, consistency, evaluate, evaluate_matches, ignore_brief, parse_mot_truth,
    read_covariances, read_samples,
};

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
    /// `csv` (a CSV with a header, --truth-columns) or `mot`: MOTChallenge 3D ground truth
    /// (frame from 1, id, box, flag, world x, y, z; flag 0 counts neither way), as PETS 2009 has
    #[arg(long, default_value = "csv", value_name = "FORMAT")]
    truth_format: String,
    /// Every estimated row on its own, identities ignored: how well positions are placed frame
    /// by frame (as a detector is scored), not how well people are followed
    #[arg(long)]
    ignore_ids: bool,
    /// The truth's own σ per axis, metres (hand-marked truth is not exact): added to each stated
    /// covariance before the stated σ are checked against the errors
    #[arg(long, default_value = "0", value_name = "M")]
    truth_sd: f64,
    /// Print JSON instead of the table
    #[arg(long)]
    json: bool,
}

/// `F,ID,X,Y` column names.
fn columns(text: &str, flag: &str) -> anyhow::Result<[String; 4]> {
    let v: Vec<String> = text.split(',').map(|s| s.trim().to_string()).collect();
    <[String; 4]>::try_from(v).map_err(|_| {
        bad_input(anyhow!(
            "{flag} '{text}': expected four column names: frame, id, x, y"
        ))
    })
}

fn read(path: &Path, cols: &[String; 4]) -> anyhow::Result<SampleTable> {
    read_samples(
        path,
        [&cols[0], &cols[1], &cols[2], &cols[3]].map(String::as_str),
    )
    .map_err(bad_input)
}

pub fn run(args: Args) -> anyhow::Result<()> {
    let truth_cols = columns(&args.truth_columns, "--truth-columns")?;
    let tracks_cols = columns(&args.tracks_columns, "--tracks-columns")?;
    if !(args.truth_sd >= 0.0 && args.truth_sd.is_finite()) {
        return Err(bad_input(anyhow!(
            "--truth-sd {}: expected metres, 0 or more",
            args.truth_sd
        )));
    }
    let SampleTable {
        samples: mut truth,
        mut ignored,
    } = match args.truth_format.as_str() {
        "csv" => read(&args.truth, &truth_cols)?,
        "mot" => {
            let text = geostride::io::FileCtx { path: &args.truth }
                .read_text("MOTChallenge 3D ground truth")
                .map_err(bad_input)?;
            parse_mot_truth(&args.truth, &text).map_err(bad_input)?
        }
        other => {
            return Err(bad_input(anyhow!(
                "--truth-format '{other}': expected 'csv' or 'mot'"
            )));
        }
    };
    if truth.is_empty() {
        return Err(bad_input(anyhow!(
            "{}: no position counts (every row is out of view)",
            args.truth.display()
        )));
    }
    let brief = ignore_brief(&mut truth, &mut ignored, args.min_frames);
    let mut est = read(&args.tracks, &tracks_cols)?.samples;
    // Each row its own track: the matching is then frame by frame, by distance alone.
    let own_ids: Vec<usize> = est.iter().map(|s| s.id).collect();
    if args.ignore_ids {
        for (k, s) in est.iter_mut().enumerate() {
            s.id = k + 1;
        }
    }
    // The stated uncertainties against the errors, when the tracks carry them (geostride's
    // trajectories.csv, read by its own frame and id columns); the matches are kept only then.
    let covariances = if tracks_cols[..2] == ["frame", "id"] {
        match read_covariances(&args.tracks) {
            Ok(c) => Some(c),
            Err(err) if err.message.starts_with("no column") => None,
            Err(err) => return Err(bad_input(anyhow!(err))),
        }
    } else {
        None
    };
    let (e, uncertainty) = match &covariances {
        Some(c) => {
            let (e, mut matches) = evaluate_matches(&truth, &est, &ignored, args.threshold);
            if args.ignore_ids {
                for (_, m) in &mut matches {
                    m.id = own_ids[m.id - 1];
                }
            }
            let mut c = c.clone();
            let truth_var = args.truth_sd * args.truth_sd;
            for p in c.values_mut() {
                p.random += nalgebra::Matrix2::identity() * truth_var;
            }
            (
                e,
                Some(consistency(&matches, &c).0).filter(|c| c.points > 0),
            )
        }
        None => (evaluate(&truth, &est, &ignored, args.threshold), None),
    };
    if args.json {
        let mut v = serde_json::to_value(&e)?;
        v["brief_people_not_counted"] = brief.into();
        if let Some(u) = &uncertainty {
            v["uncertainty"] = serde_json::to_value(u)?;
        }
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
    if let Some(u) = uncertainty {
        println!(
            "  stated σ: the 95 % ellipse holds the truth for {:.1} % of {} points; error / σ median {:.2}, mean of squares {:.2}; mean error / σ east {:+.2}, north {:+.2}; median σ random {:.3}, height {:.3}, pose {:.3} m",
            100.0 * u.inside_95,
            u.points,
            u.median_normalised_error,
            u.mean_nees_per_axis,
            u.mean_normalised_e,
            u.mean_normalised_n,
            u.median_sigma_random_m,
            u.median_sigma_height_m,
            u.median_sigma_pose_m
        );
    }
    Ok(())
}
