//! Throughput of `geostride run` on a simulated 3840x2160 video (`benches/scenes/stream-4k.toml`:
//! 4 s, a dense stream of runners with hats, about 100 in view), beside the plain decode rate of
//! the same video in the same run: frames per second of every stage and end to end, for two
//! paths, each with a target of no less than half the decode rate: hats (colour detector,
//! association tracker) and crowds without hats (an external detector's boxes, simulated from
//! the truth as in `geostride demo --crowd --detector simulated`, and the KLT tracker, in the same decoding pass).
//!
//! `GEOSTRIDE_BENCH_DIR=DIR` keeps the simulated scene in DIR and reuses it on the next run.

use std::path::{Path, PathBuf};
use std::time::Instant;

mod common;
use common::{cpu_s, simulated};

use geostride::detect::simulated::{SimulatedDetector, mot_text, read_truth_boxes};
use geostride::pipeline::project::load;
use geostride::pipeline::run::RunReport;
use geostride::pipeline::run::{Silent, run};
use geostride::simulate::project::{crowd_project, hats_project, project_text};
use geostride::video::source::FrameReader;

const TARGET_RATIO: f64 = 0.5;

/// Decodes every frame once into BGR, as fast as the reader can (one frame's memory reused):
/// (frames, wall s, CPU s).
fn decode(video: &Path) -> (usize, f64, f64) {
    let (t, c) = (Instant::now(), cpu_s());
    let mut reader = FrameReader::open(video).expect("video");
    let mut frame = opencv::core::Mat::default();
    let mut n = 0;
    while reader.read_bgr_into(&mut frame).expect("decode").is_some() {
        std::hint::black_box(&frame);
        n += 1;
    }
    (n, t.elapsed().as_secs_f64(), cpu_s() - c)
}

fn main() {
    let root = Path::new(env!("CARGO_MANIFEST_DIR"));
    let scene_path = root.join("benches/scenes/stream-4k.toml");
    let temp;
    let dir: PathBuf = match std::env::var_os("GEOSTRIDE_BENCH_DIR") {
        Some(d) => PathBuf::from(d),
        None => {
            temp = tempfile::tempdir().expect("temporary folder");
            temp.path().to_path_buf()
        }
    };
    std::fs::create_dir_all(&dir).expect("bench folder");
    let scene = simulated(&scene_path, &dir);
    let project = dir.join("project.toml");
    let mut hats = hats_project(&scene, &scene.camera.calibration, None).expect("project");
    // The pipeline's rate without the views (optional outputs, timed on their own below).
    hats.output.plots = false;
    hats.output.site_image = false;
    let text = project_text(&hats, "the hats").expect("project text");
    std::fs::write(&project, text).expect("project file");
    let video = dir.join("video.mp4");

    // The crowd path's input: detector boxes simulated from the truth.
    let truth_boxes = read_truth_boxes(&dir.join("truth/boxes.csv")).expect("truth boxes");
    let boxes = SimulatedDetector {
        seed: scene.seed,
        ..SimulatedDetector::default()
    }
    .detect(&truth_boxes, (3840.0, 2160.0));
    std::fs::write(dir.join("boxes.txt"), mot_text(&boxes)).expect("boxes file");
    let crowd = dir.join("project-klt.toml");
    let mut klt =
        crowd_project(&scene, &scene.camera.calibration, "boxes.txt", &[]).expect("crowd project");
    klt.output = hats.output.clone();
    let text = project_text(&klt, "the crowd").expect("project text");
    std::fs::write(&crowd, text).expect("crowd project file");

    // Warm the file cache, then decode alone, run each pipeline between two plain decodes.
    let _ = decode(&video);
    let (frames, dec1, dec1_cpu) = decode(&video);
    let mut decodes = vec![(dec1, dec1_cpu)];
    let mut runs = Vec::new();
    for (label, project, out) in [
        ("hats: colour + association", &project, "run"),
        ("no hats: boxes + KLT", &crowd, "run-klt"),
    ] {
        let out = dir.join(out);
        let _ = std::fs::remove_dir_all(&out);
        let loaded = load(project).expect("project loads");
        let (t, c) = (Instant::now(), cpu_s());
        let report = run(&loaded, &out, &Silent).expect("pipeline");
        runs.push((label, report, t.elapsed().as_secs_f64(), cpu_s() - c));
        let (_, d, dc) = decode(&video);
        decodes.push((d, dc));
    }
    let decode_s = decodes.iter().map(|d| d.0).sum::<f64>() / decodes.len() as f64;
    let decode_fps = frames as f64 / decode_s;
    println!(
        "pipeline_throughput: {} ({} frames of 3840x2160, {} threads)",
        scene.name,
        frames,
        std::thread::available_parallelism().map_or(1, |n| n.get())
    );
    println!(
        "  plain decode: {:.1} frames/s (mean of {} passes around the runs: {})",
        decode_fps,
        decodes.len(),
        decodes
            .iter()
            .map(|(d, c)| format!("{d:.2} s / {c:.2} CPU s"))
            .collect::<Vec<_>>()
            .join(", ")
    );
    // The views of the hat run: every stage reused, only the plots, site image and annotated
    // video made.
    let mut with_views = load(&project).expect("project loads");
    with_views.project.output.plots = true;
    with_views.project.output.site_image = true;
    with_views.project.output.video = true;
    let t = Instant::now();
    let report = run(&with_views, &dir.join("run"), &Silent).expect("views");
    let views_s = t.elapsed().as_secs_f64();
    let views = report.stages.iter().find(|s| s.name == "views");
    for (label, report, wall, cpu) in &runs {
        let ratio = print_run(label, report, frames, decode_fps, *wall, *cpu);
        {
            println!(
                "    target >= {TARGET_RATIO} of the decode rate: {}",
                if ratio >= TARGET_RATIO {
                    "met"
                } else {
                    "NOT met"
                }
            );
        }
    }
    println!(
        "  views of the hat run (plots, site image, annotated video of {frames} frames at {} px wide): {:.2} s ({views_s:.2} s with the reused stages), {:.1} frames/s of video",
        with_views.project.output.video_width,
        views.map_or(f64::NAN, |v| v.seconds),
        frames as f64 / views.map_or(f64::NAN, |v| v.seconds)
    );
}

/// Prints one run's stages; returns its end-to-end rate as a fraction of the decode rate.
fn print_run(
    label: &str,
    report: &RunReport,
    frames: usize,
    decode_fps: f64,
    wall: f64,
    wall_cpu: f64,
) -> f64 {
    println!("  {label}");
    println!(
        "  stage           seconds   frames/s   (the scan's decoder, stabiliser and detector run side by side: busy seconds of each)"
    );
    let fps = |s: f64| {
        if s > 0.0 {
            frames as f64 / s
        } else {
            f64::INFINITY
        }
    };
    for st in &report.stages {
        println!(
            "  {:<14} {:>8.3} {:>10.1}",
            st.name,
            st.seconds,
            fps(st.seconds)
        );
        if st.name == "scan" {
            for k in ["decode_s", "stabilise_s", "detect_s", "track_s"] {
                if let Some(&v) = st.counts.get(k) {
                    println!(
                        "    {:<12} {:>8.3} {:>10.1}",
                        k.trim_end_matches("_s"),
                        v,
                        fps(v)
                    );
                }
            }
        }
    }
    let count = |stage: &str, key: &str| {
        report
            .stages
            .iter()
            .find(|s| s.name == stage)
            .and_then(|s| s.counts.get(key))
            .copied()
            .unwrap_or(0.0)
    };
    println!(
        "  {} detections, {} tracks",
        count("scan", "detections"),
        count("track", "tracks")
    );
    let e2e = frames as f64 / wall;
    let ratio = e2e / decode_fps;
    println!(
        "  end to end: {wall:.2} s ({wall_cpu:.2} CPU s), {e2e:.1} frames/s = {ratio:.3} of the decode rate"
    );
    ratio
}
