//! A split run against one machine, and the crowd tracker against crowd density, on simulated
//! 3840x2160 crowds without hats (an external detector's boxes simulated from the truth, the
//! KLT tracker):
//!
//! 1. the KLT tracker's time per frame with about 200 and about 1,000 people in view
//!    (`benches/scenes/crowd-4k-200.toml`, `crowd-4k-1000.toml`; target: growing no faster than
//!    the number of people);
//! 2. 2 minutes of video with about 220 people in view (`crowd-4k-2min.toml`, at 10 fps): `run`
//!    on one machine, then split into 2 and 4 segments run one after another here, each timed on
//!    its own (the wall time of N machines is the split, the slowest segment and the merge), the
//!    merge's share of the work (target: at most 5 %), the outputs checked byte for byte
//!    against `run`'s;
//! 3. each segment's peak memory against its length (target: bounded by a chunk, not by the
//!    video).
//!
//! `GEOSTRIDE_BENCH_DIR=DIR` keeps the simulated scenes in DIR and reuses them on the next run.

use std::path::{Path, PathBuf};
use std::time::Instant;

mod common;
use common::simulated;

use geostride::detect::simulated::{SimulatedDetector, mot_text, read_truth_boxes};
use geostride::pipeline::cluster::segments;
use geostride::pipeline::project::{Loaded, load};
use geostride::pipeline::run::{
    ChunkMode, RunReport, Silent, plan_chunks, run, run_segment, run_with,
};
use geostride::simulate::project::{crowd_project, project_text};

const MERGE_SHARE_TARGET: f64 = 0.05;

/// Forgets this process's peak resident memory (Linux), so the next peak is the next work's.
fn reset_peak() {
    let _ = std::fs::write("/proc/self/clear_refs", "5");
}

/// This process's peak resident memory since the last reset, MiB (Linux).
fn peak_mib() -> f64 {
    std::fs::read_to_string("/proc/self/status")
        .ok()
        .and_then(|s| {
            s.lines()
                .find(|l| l.starts_with("VmHWM:"))
                .and_then(|l| l.split_whitespace().nth(1)?.parse::<f64>().ok())
        })
        .map_or(f64::NAN, |kib| kib / 1024.0)
}

/// The median number of people in view per frame, from the truth.
fn in_view(dir: &Path) -> usize {
    let text = std::fs::read_to_string(dir.join("truth/heads.csv")).expect("truth heads");
    let mut lines = text.lines();
    let header: Vec<&str> = lines.next().expect("header").split(',').collect();
    let (fi, vi) = (
        header.iter().position(|h| *h == "frame").expect("frame"),
        header
            .iter()
            .position(|h| *h == "in_view")
            .expect("in_view"),
    );
    let mut counts: std::collections::BTreeMap<usize, usize> = Default::default();
    for l in lines {
        let f: Vec<&str> = l.split(',').collect();
        if f[vi] == "1" {
            *counts.entry(f[fi].parse().expect("frame")).or_default() += 1;
        }
    }
    let mut v: Vec<usize> = counts.into_values().collect();
    v.sort_unstable();
    v.get(v.len() / 2).copied().unwrap_or(0)
}

/// Simulates (or reuses) a crowd scene in `dir`, its detector boxes and its project file.
fn crowd(scene_file: &str, dir: &Path) -> (PathBuf, usize) {
    let root = Path::new(env!("CARGO_MANIFEST_DIR"));
    std::fs::create_dir_all(dir).expect("bench folder");
    let scene = simulated(&root.join("benches/scenes").join(scene_file), dir);
    let truth = read_truth_boxes(&dir.join("truth/boxes.csv")).expect("truth boxes");
    let size = scene.camera.video_mode.expect("video mode");
    let boxes = SimulatedDetector {
        seed: scene.seed,
        ..SimulatedDetector::default()
    }
    .detect(&truth, (f64::from(size[0]), f64::from(size[1])));
    std::fs::write(dir.join("boxes.txt"), mot_text(&boxes)).expect("boxes file");
    let p = crowd_project(&scene, &scene.camera.calibration, "boxes.txt", &[]).expect("project");
    let path = dir.join("project.toml");
    std::fs::write(&path, project_text(&p, "the crowd").expect("text")).expect("project file");
    (path, in_view(dir))
}

fn stage<'a>(r: &'a RunReport, name: &str) -> &'a geostride::pipeline::run::StageRecord {
    r.stages.iter().find(|s| s.name == name).expect("stage")
}

fn timed<T>(f: impl FnOnce() -> T) -> (T, f64) {
    let t = Instant::now();
    let v = f();
    (v, t.elapsed().as_secs_f64())
}

/// Runs `loaded` split into `n` segments in `dir`; prints and checks against `one`.
fn split_run(loaded: &Loaded, dir: &Path, n: usize, one: &Path, one_s: f64) {
    let _ = std::fs::remove_dir_all(dir);
    let (plan, split_s) = timed(|| plan_chunks(loaded, dir, &Silent).expect("split"));
    let segs = segments(plan.grid.chunks(), n).expect("enough chunks");
    let mut seg_s = Vec::new();
    let mut seg_mib = Vec::new();
    for r in &segs {
        reset_peak();
        let (_, s) = timed(|| run_segment(loaded, dir, &Silent, r.clone()).expect("segment"));
        seg_s.push(s);
        seg_mib.push(peak_mib());
    }
    reset_peak();
    let (_, merge_s) = timed(|| run_with(loaded, dir, &Silent, &ChunkMode::None).expect("merge"));
    let merge_mib = peak_mib();
    let max = seg_s.iter().copied().fold(0.0, f64::max);
    let sum: f64 = seg_s.iter().sum();
    let wall = split_s + max + merge_s;
    let share = merge_s / (split_s + sum + merge_s);
    println!(
        "  {n} segments of {} chunk(s): split {split_s:.1} s, segments {} s (peak {} MiB), merge {merge_s:.1} s (peak {merge_mib:.0} MiB)",
        segs.iter()
            .map(|r| r.len().to_string())
            .collect::<Vec<_>>()
            .join("/"),
        seg_s
            .iter()
            .map(|s| format!("{s:.1}"))
            .collect::<Vec<_>>()
            .join(" + "),
        seg_mib
            .iter()
            .map(|m| format!("{m:.0}"))
            .collect::<Vec<_>>()
            .join("/")
    );
    println!(
        "    on {n} machines: {wall:.1} s against {one_s:.1} s on one ({:.2}x); work {:.1} s ({:.2} of one machine's); merge {:.1} % of the work: target <= {:.0} %: {}",
        one_s / wall,
        split_s + sum + merge_s,
        (split_s + sum + merge_s) / one_s,
        100.0 * share,
        100.0 * MERGE_SHARE_TARGET,
        if share <= MERGE_SHARE_TARGET {
            "met"
        } else {
            "NOT met"
        }
    );
    for f in [
        "trajectories.csv",
        "tracks_mot.txt",
        "trajectories.txt",
        "pose/poses.csv",
    ] {
        let same = std::fs::read(one.join(f)).ok() == std::fs::read(dir.join(f)).ok();
        assert!(same, "{f} differs between run and the split run");
    }
    println!(
        "    trajectories.csv, tracks_mot.txt, trajectories.txt, pose/poses.csv: the bytes of run"
    );
}

fn main() {
    let temp;
    let base: PathBuf = match std::env::var_os("GEOSTRIDE_BENCH_DIR") {
        Some(d) => PathBuf::from(d),
        None => {
            temp = tempfile::tempdir().expect("temporary folder");
            temp.path().to_path_buf()
        }
    };
    println!("cluster_scaling: 3840x2160 crowds, boxes + KLT, 2 threads");

    // 1. The tracker against density.
    let mut per_frame = Vec::new();
    for (file, sub) in [
        ("crowd-4k-200.toml", "crowd-200"),
        ("crowd-4k-1000.toml", "crowd-1000"),
    ] {
        let dir = base.join(sub);
        let (project, people) = crowd(file, &dir);
        let loaded = load(&project).expect("project");
        let out = dir.join("run");
        let _ = std::fs::remove_dir_all(&out);
        let report = run(&loaded, &out, &Silent).expect("run");
        let scan = stage(&report, "scan");
        let frames = scan.counts["frames"];
        let ms = 1000.0 * scan.counts["track_s"] / frames;
        println!(
            "  {people} people in view ({file}): tracker {ms:.1} ms per frame ({:.3} ms per person), {} tracks",
            ms / people as f64,
            stage(&report, "track").counts["tracks"]
        );
        per_frame.push((people as f64, ms));
    }
    let growth = (per_frame[1].1 / per_frame[0].1) / (per_frame[1].0 / per_frame[0].0);
    println!(
        "  tracker time grows {:.2}x for {:.1}x the people: {} (target: no faster than linearly)",
        per_frame[1].1 / per_frame[0].1,
        per_frame[1].0 / per_frame[0].0,
        if growth <= 1.0 { "met" } else { "NOT met" }
    );

    // 2. and 3. Two minutes, one machine against segments.
    let dir = base.join("crowd-2min");
    let (project, people) = crowd("crowd-4k-2min.toml", &dir);
    let loaded = load(&project).expect("project");
    let one = dir.join("run");
    let _ = std::fs::remove_dir_all(&one);
    reset_peak();
    let (report, one_s) = timed(|| run(&loaded, &one, &Silent).expect("run"));
    let one_mib = peak_mib();
    let scan = stage(&report, "scan");
    let global: f64 = report
        .stages
        .iter()
        .filter(|s| s.name != "scan")
        .map(|s| s.seconds)
        .sum();
    println!(
        "  2 minutes, {people} people in view: {} frames in {} chunks; run on one machine {one_s:.1} s (scan {:.1} s, the rest {global:.1} s), peak {one_mib:.0} MiB",
        scan.counts["frames"], scan.counts["chunks"], scan.seconds
    );
    for n in [2, 4] {
        split_run(
            &loaded,
            &base.join(format!("crowd-2min-split-{n}")),
            n,
            &one,
            one_s,
        );
    }
}
