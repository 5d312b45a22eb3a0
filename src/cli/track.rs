//! `geostride track VIDEO`: people tracked in the image only, for a fixed camera with no survey
//! (or before the survey is done): background subtraction or an external detector's boxes,
//! then KLT. Tracks in pixels; `geostride run` does the whole job with geolocation.

use std::collections::BTreeMap;
use std::path::PathBuf;
use std::time::Instant;

use anyhow::{Context, anyhow};

use super::bad_input;
use geostride::detect::Detector;
use geostride::detect::background::{BackgroundDetector, Subtractor};
use geostride::detect::boxes::{BoxFilter, BoxFormat, read_boxes};
use geostride::detect::person::BoxesDetector;
use geostride::pipeline::chunk_pass::{ChunkTracker, ScanError};
use geostride::pipeline::klt_pass::klt_tracker;
use geostride::pipeline::scan::{ScanJob, scan};
use geostride::pipeline::settings::KltSection;
use geostride::track::ImageTrack;

#[derive(clap::Args)]
pub struct Args {
    /// The video (a fixed camera)
    video: PathBuf,
    /// Output folder: tracks_mot.txt, tracks.csv, report.json
    #[arg(long, value_name = "DIR")]
    out: PathBuf,
    /// Image scale where the people are, pixels per metre (a person 1.7 m tall and 60 px high
    /// is about 35); sets the size filters, the gates and the KLT window
    #[arg(long, value_name = "PX", value_parser = super::parse_positive)]
    px_per_m: f64,
    /// Detector: 'background' (OpenCV MOG2/KNN) or 'boxes' (an external detector's file)
    #[arg(long, default_value = "background", value_parser = ["background", "boxes"])]
    detect: String,
    /// The boxes file for --detect boxes (MOTChallenge txt, JSON Lines or COCO JSON)
    #[arg(long, value_name = "FILE")]
    boxes: Option<PathBuf>,
    /// With --detect boxes: never split a box into people side by side (an oblique view, where
    /// a tall box is one person standing, not a row of heads seen from above)
    #[arg(long)]
    no_split: bool,
    /// Background subtraction method
    #[arg(long, default_value = "mog2", value_parser = ["mog2", "knn"])]
    method: String,
    /// Foreground components smaller than this are noise, m²
    #[arg(long, default_value = "0.08", value_parser = super::parse_positive, value_name = "M2")]
    min_area_m2: f64,
    /// Foreground components larger than this are not one person, m²
    #[arg(long, default_value = "4.0", value_parser = super::parse_positive, value_name = "M2")]
    max_area_m2: f64,
    /// Only the first N frames
    #[arg(long, value_name = "N")]
    max_frames: Option<usize>,
    /// Print the report as JSON on stdout
    #[arg(long)]
    json: bool,
    /// No progress bars
    #[arg(short, long)]
    quiet: bool,
}

#[derive(serde::Serialize)]
struct Report {
    video: String,
    frames: usize,
    fps: f64,
    width: u32,
    height: u32,
    detector: String,
    detections: usize,
    detector_summary: BTreeMap<String, f64>,
    tracks: usize,
    track_points: usize,
    mean_track_length_s: f64,
    scan_s: f64,
    track_s: f64,
    outputs: Vec<String>,
}

/// The detector the arguments name: an external detector's boxes or background subtraction.
fn detector_of(args: &Args) -> anyhow::Result<Box<dyn Detector>> {
    Ok(match args.detect.as_str() {
        "boxes" => {
            let path = args.boxes.as_ref().ok_or_else(|| {
                bad_input(anyhow!(
                    "--detect boxes needs --boxes FILE (MOTChallenge txt, JSON Lines or COCO JSON)"
                ))
            })?;
            let boxes = read_boxes(path, None::<BoxFormat>).map_err(bad_input)?;
            Box::new(
                BoxesDetector::new(
                    boxes,
                    BoxFilter {
                        max_split: if args.no_split { 1 } else { 4 },
                        ..BoxFilter::new(args.px_per_m)
                    },
                )
                .map_err(|e| bad_input(anyhow!(e)))?,
            )
        }
        _ => {
            let method = if args.method == "knn" {
                Subtractor::Knn
            } else {
                Subtractor::Mog2
            };
            // The same settings a project's `[detect] kind = "background"` gives.
            let section = geostride::pipeline::settings::BackgroundSection {
                method,
                min_area_m2: args.min_area_m2,
                max_area_m2: args.max_area_m2,
                ..Default::default()
            };
            let settings =
                geostride::pipeline::detectors::background_settings(&section, args.px_per_m);
            Box::new(BackgroundDetector::new(settings).map_err(|e| bad_input(anyhow!(e)))?)
        }
    })
}

pub fn run(args: Args) -> anyhow::Result<()> {
    // A head a few pixels across to a thousand: beyond, the tracker's gates mean nothing.
    if !(1.0..=10_000.0).contains(&args.px_per_m) {
        return Err(bad_input(anyhow!(
            "--px-per-m {}: expected 1 to 10000 pixels a metre at head height",
            args.px_per_m
        )));
    }
    if !(args.min_area_m2 < args.max_area_m2) {
        return Err(bad_input(anyhow!(
            "--min-area-m2 {} is not below --max-area-m2 {}: a person's area lies between them",
            args.min_area_m2,
            args.max_area_m2
        )));
    }
    let detector = detector_of(&args)?;
    // A video that cannot be opened is the user's to fix (exit 2).
    let reader = geostride::video::source::FrameReader::open(&args.video)
        .map_err(|e| bad_input(anyhow!(e)))?;
    let (size, fps) = ((reader.width, reader.height), reader.fps);
    drop(reader);
    super::create_output_dir(&args.out, std::iter::once(&args.video).chain(&args.boxes))?;
    let bar = super::progress_bar(
        args.quiet || args.json,
        0,
        "   scan {bar:40} {pos}/{len} [{elapsed_precise}<{eta_precise}]",
    );
    let t0 = Instant::now();
    let track = KltSection::default();
    // One decoding pass: the detector and the KLT tracker beside the decoder, as in a project's
    // run (a fixed camera: no stabiliser).
    let tracker = klt_tracker(&track, size, fps, None, args.px_per_m);
    let scanned = scan(
        ScanJob {
            video: &args.video,
            max_frames: args.max_frames,
            stabilise: None,
            detector: Some(detector),
            tracker: Some(ChunkTracker::Klt(Box::new(tracker))),
        },
        &bar,
    )
    .map_err(|e| match e {
        ScanError::Detector(m) => bad_input(anyhow!(m)),
        ScanError::Other(m) => anyhow!(m),
    })?;
    bar.finish_and_clear();
    let scan_s = t0.elapsed().as_secs_f64();
    let track_s = scanned.times.track_s;
    let tracks = scanned.image_tracks;
    // Short tracks are mostly false alarms, unless the video's start or end cut them.
    let min_frames = (track.min_length_s * scanned.fps).round() as usize;
    let last = scanned.frames.saturating_sub(1);
    let tracks: Vec<ImageTrack> = tracks
        .into_iter()
        .filter(|t| {
            let (a, b) = (t.points[0].frame, t.points[t.points.len() - 1].frame);
            b - a + 1 >= min_frames || a == 0 || b == last
        })
        .enumerate()
        .map(|(i, t)| ImageTrack { id: i + 1, ..t })
        .collect();

    let points: usize = tracks.iter().map(|t| t.points.len()).sum();
    let report = Report {
        video: args.video.display().to_string(),
        frames: scanned.frames,
        fps: scanned.fps,
        width: scanned.width,
        height: scanned.height,
        detector: if args.detect == "boxes" {
            "boxes".into()
        } else {
            format!("background ({})", args.method)
        },
        detections: scanned.detections.iter().map(Vec::len).sum(),
        detector_summary: scanned.detector_summary.iter().cloned().collect(),
        tracks: tracks.len(),
        track_points: points,
        mean_track_length_s: points as f64 / tracks.len().max(1) as f64 / scanned.fps,
        scan_s,
        track_s,
        outputs: vec![
            "tracks_mot.txt".into(),
            "tracks.csv".into(),
            "report.json".into(),
        ],
    };
    let write = |name: &str, text: &str| {
        let path = args.out.join(name);
        geostride::io::write_atomic(&path, text.as_bytes())
            .with_context(|| path.display().to_string())
    };
    write("tracks_mot.txt", &geostride::export::mot_txt(&tracks))?;
    write("tracks.csv", &geostride::export::image_tracks_csv(&tracks))?;
    let json = serde_json::to_string_pretty(&report)?;
    write("report.json", &json)?;
    if args.json {
        println!("{json}");
        return Ok(());
    }
    println!(
        "{}: {} frames of {}x{} at {:.2} fps",
        report.video, report.frames, report.width, report.height, report.fps
    );
    println!(
        "  detect  {:<22} {:>8} detections in {:.1} s",
        report.detector, report.detections, scan_s
    );
    println!(
        "  track   klt {:>19} tracks, {} points, mean {:.1} s long, in {:.1} s",
        report.tracks, points, report.mean_track_length_s, track_s
    );
    println!(
        "  wrote tracks_mot.txt, tracks.csv, report.json in {}",
        args.out.display()
    );
    Ok(())
}
