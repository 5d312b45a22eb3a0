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
//!    against `run`'s; every step its own `geostride` process, as on a cluster;
//! 3. each segment's peak memory against its length (target: bounded by a chunk, not by the
//!    video);
//! 4. the merge's peak memory for the video's first minute and for both: what a trajectory
//!    point costs it.
//!
//! `GEOSTRIDE_BENCH_DIR=DIR` keeps the simulated scenes in DIR and reuses them on the next run.

use std::path::{Path, PathBuf};
use std::time::Instant;

mod common;
use common::simulated;

use geostride::detect::simulated::{SimulatedDetector, mot_text, read_truth_boxes};
use geostride::pipeline::project::load;
use geostride::pipeline::run::{RunReport, Silent, run};
use geostride::simulate::project::{crowd_project, project_text};

const MERGE_SHARE_TARGET: f64 = 0.05;

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
    let mut p =
        crowd_project(&scene, &scene.camera.calibration, "boxes.txt", &[]).expect("project");
    // The merge's share is of the work that gives the data files: the views (plots, site image;
    // optional outputs) are timed by pipeline_throughput.
    p.output.plots = false;
    p.output.site_image = false;
    let path = dir.join("project.toml");
    std::fs::write(&path, project_text(&p, "the crowd").expect("text")).expect("project file");
    (path, in_view(dir))
}

fn stage<'a>(r: &'a RunReport, name: &str) -> &'a geostride::pipeline::run::StageRecord {
    r.stages.iter().find(|s| s.name == name).expect("stage")
}

/// A process's peak resident memory since its `exec` (`VmHWM`), in MiB; None once it has ended.
fn peak_mib(pid: u32) -> Option<f64> {
    let status = std::fs::read_to_string(format!("/proc/{pid}/status")).ok()?;
    let line = status.lines().find(|l| l.starts_with("VmHWM:"))?;
    let kib: f64 = line.split_whitespace().nth(1)?.parse().ok()?;
    Some(kib / 1024.0)
}

/// Runs `geostride ARGS` as its own process: (wall seconds, peak resident memory in MiB).
///
/// The peak is the child's `VmHWM`, read every 10 ms until it ends (a high-water mark: the last
/// reading holds all but its last few milliseconds). Not `wait4`'s `ru_maxrss`: `exec` carries
/// the parent's peak into it, and this bench's own (977 MiB after part 1's runs in-process) was
/// reported as the merge's.
fn process(args: &[&std::ffi::OsStr]) -> (f64, f64) {
    let t = Instant::now();
    let mut child = std::process::Command::new(env!("CARGO_BIN_EXE_geostride"))
        .args(args)
        .stdout(std::process::Stdio::null())
        .stderr(std::process::Stdio::null())
        .spawn()
        .expect("geostride");
    let mut peak = 0.0f64;
    let status = loop {
        if let Some(m) = peak_mib(child.id()) {
            peak = peak.max(m);
        }
        if let Some(status) = child.try_wait().expect("waiting for geostride") {
            break status;
        }
        std::thread::sleep(std::time::Duration::from_millis(10));
    };
    assert!(status.success(), "geostride {args:?} failed");
    (t.elapsed().as_secs_f64(), peak)
}

/// Runs `project` split into `n` segments in `dir`, each step its own process (as on a
/// cluster); prints and checks against `one` (its folder and seconds) when given. Returns the
/// merge's peak memory in MiB and the trajectory points it held.
fn split_run(project: &Path, dir: &Path, n: usize, one: Option<(&Path, f64)>) -> (f64, f64) {
    let _ = std::fs::remove_dir_all(dir);
    let os = |s: &str| std::ffi::OsString::from(s);
    let (split_s, _) = process(&[
        &os("split"),
        project.as_os_str(),
        &os("--segments"),
        &os(&n.to_string()),
        &os("--out"),
        dir.as_os_str(),
        &os("-q"),
    ]);
    let chunks: Vec<usize> = geostride::pipeline::cluster::Manifest::read(dir)
        .expect("manifest")
        .segments
        .iter()
        .map(|r| r.len())
        .collect();
    let mut seg_s = Vec::new();
    let mut seg_mib = Vec::new();
    for i in 0..n {
        let (s, m) = process(&[
            &os("segment"),
            dir.as_os_str(),
            &os("--index"),
            &os(&i.to_string()),
            &os("-q"),
        ]);
        seg_s.push(s);
        seg_mib.push(m);
    }
    let (merge_s, merge_mib) = process(&[&os("merge"), dir.as_os_str(), &os("-q")]);
    let report: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(dir.join("report.json")).expect("report"))
            .expect("report");
    let points = report["stages"]
        .as_array()
        .expect("stages")
        .iter()
        .find(|s| s["name"] == "project")
        .and_then(|s| s["counts"]["points"].as_f64())
        .expect("points");
    let max = seg_s.iter().copied().fold(0.0, f64::max);
    let sum: f64 = seg_s.iter().sum();
    let wall = split_s + max + merge_s;
    let share = merge_s / (split_s + sum + merge_s);
    println!(
        "  {n} segments of {} chunk(s): split {split_s:.1} s, segments {} s (peak {} MiB), merge {merge_s:.1} s (peak {merge_mib:.0} MiB)",
        chunks
            .iter()
            .map(|c| c.to_string())
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
    let Some((one, one_s)) = one else {
        return (merge_mib, points);
    };
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
    (merge_mib, points)
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
    let one = dir.join("run");
    let _ = std::fs::remove_dir_all(&one);
    let (one_s, one_mib) = process(&[
        std::ffi::OsStr::new("run"),
        project.as_os_str(),
        std::ffi::OsStr::new("--out"),
        one.as_os_str(),
        std::ffi::OsStr::new("-q"),
    ]);
    let report: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(one.join("report.json")).expect("report"))
            .expect("report");
    let stages = report["stages"].as_array().expect("stages");
    let scan = &stages[0]["counts"];
    println!(
        "  2 minutes, {people} people in view: {} frames in {} chunks; run on one machine {one_s:.1} s, peak {one_mib:.0} MiB; stages: {}",
        scan["frames"],
        scan["chunks"],
        stages
            .iter()
            .map(|s| format!(
                "{} {:.1} s",
                s["name"].as_str().unwrap_or("?"),
                s["seconds"].as_f64().unwrap_or(f64::NAN)
            ))
            .collect::<Vec<_>>()
            .join(", ")
    );
    let mut merges = Vec::new();
    for n in [2, 4] {
        merges.push(split_run(
            &project,
            &base.join(format!("crowd-2min-split-{n}")),
            n,
            Some((&one, one_s)),
        ));
    }

    // 4. The merge's memory against the video's length: its first minute alone; then both
    // lengths again with the views (plots, site image) that the projects above leave out.
    let mut lengths = Vec::new();
    for views in [false, true] {
        for minutes in [1, 2] {
            if minutes == 2 && !views {
                lengths.push(merges[0]);
                continue;
            }
            let mut p = load(&project).expect("project").project;
            if minutes == 1 {
                p.video.duration_s = Some(60.0);
            }
            p.output.plots = views;
            p.output.site_image = views;
            let name = format!("{minutes}min{}", if views { "-views" } else { "" });
            let file = dir.join(format!("project-{name}.toml"));
            std::fs::write(
                &file,
                project_text(&p, &format!("the crowd's first {minutes} min")).expect("text"),
            )
            .expect("project file");
            lengths.push(split_run(
                &file,
                &base.join(format!("crowd-{name}-split-2")),
                2,
                None,
            ));
        }
    }
    // What may still grow: SQLite's page cache for the GeoPackage (capped at 8 MiB) and the
    // per-frame and per-track records (under 1 KB a frame, tens of bytes a track).
    for (k, what) in ["", ", with plots and site image"].iter().enumerate() {
        let ((mib_1, points_1), (mib_2, points_2)) = (lengths[2 * k], lengths[2 * k + 1]);
        println!(
            "  the merge against the video's length{what}: 1 min {mib_1:.0} MiB ({points_1} trajectory points), 2 min {mib_2:.0} MiB ({points_2}): {:+.0} MiB for twice the video ({:.0} bytes a point)",
            mib_2 - mib_1,
            (mib_2 - mib_1) * (1 << 20) as f64 / (points_2 - points_1)
        );
    }
}
