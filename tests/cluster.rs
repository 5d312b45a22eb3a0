//! `geostride split` + `segment` × N + `merge` against `geostride run` on simulated hovering
//! videos (hats with the association tracker; boxes with KLT): the same bytes for N = 2, 3 and 5,
//! whatever order the segments run in; a missing segment named by `merge`, and a re-run that
//! redoes only what is missing.

#![cfg(all(feature = "opencv", feature = "gdal", feature = "onnx"))]

mod common;

use std::path::{Path, PathBuf};

use common::{assert_success, geostride};

/// The outputs that must not depend on how the run was cut.
const SAME: [&str; 5] = [
    "trajectories.csv",
    "tracks_mot.txt",
    "trajectories.txt",
    "pose/poses.csv",
    "detections.csv",
];

/// Simulates the drifting hover scene (60 frames at 15 fps) into `dir`.
fn simulate(dir: &Path) {
    common::simulate_scene("hover-drift", dir);
}

/// A project of the simulated scene cut into chunks of 0.6 s (9 frames, 7 chunks) tracked from
/// 0.3 s before: `detect` and `track` sections as given.
fn project(dir: &Path, name: &str, detect_track: &str) -> PathBuf {
    common::chunked_deck_project(
        dir,
        &format!("{name}.toml"),
        name,
        "[\"csv\", \"petrack\", \"mot\", \"detections\"]",
        detect_track,
    )
}

fn run(project: &Path, out: &Path) {
    assert_success(&common::run_project(project, out));
}

fn split(project: &Path, n: usize, out: &Path) -> std::process::Output {
    geostride()
        .arg("split")
        .arg(project)
        .args(["--segments", &n.to_string(), "--out"])
        .arg(out)
        .arg("-q")
        .output()
        .unwrap()
}

fn segment(dir: &Path, i: usize) -> std::process::Output {
    geostride()
        .arg("segment")
        .arg(dir)
        .args(["--index", &i.to_string(), "-q"])
        .output()
        .unwrap()
}

fn merge(dir: &Path) -> std::process::Output {
    geostride()
        .arg("merge")
        .arg(dir)
        .arg("-q")
        .output()
        .unwrap()
}

fn assert_same(a: &Path, b: &Path) {
    for f in SAME {
        let (x, y) = (
            std::fs::read(a.join(f)).unwrap(),
            std::fs::read(b.join(f)).unwrap(),
        );
        assert!(
            x == y,
            "{f} differs between {} and {}",
            a.display(),
            b.display()
        );
    }
}

/// Split into 2, 3 and 5, segments in a shuffled order, merged: the bytes of `run`.
fn same_as_run(dir: &Path, project: &Path) {
    let one = dir.join(format!(
        "run-{}",
        project.file_stem().unwrap().to_string_lossy()
    ));
    run(project, &one);
    let tracks = std::fs::read_to_string(one.join("tracks_mot.txt")).unwrap();
    assert!(tracks.lines().count() > 100, "the run tracked too little");
    for (n, order) in [
        (2, vec![1, 0]),
        (3, vec![2, 0, 1]),
        (5, vec![3, 1, 4, 0, 2]),
    ] {
        let d = dir.join(format!(
            "split-{}-{n}",
            project.file_stem().unwrap().to_string_lossy()
        ));
        assert_success(&split(project, n, &d));
        for i in order {
            assert_success(&segment(&d, i));
        }
        assert_success(&merge(&d));
        assert_same(&one, &d);
    }
}

#[test]
fn split_segments_and_merge_give_the_bytes_of_run() {
    let tmp = tempfile::tempdir().unwrap();
    let dir = tmp.path();
    simulate(dir);
    // Hats: the palette learnt once by split, the association tracker.
    let hats = project(
        dir,
        "hats",
        "[detect]\nkind = \"colour\"\ncolour = [255, 0, 255]\n",
    );
    same_as_run(dir, &hats);

    // Boxes (the simulator's true body boxes as a MOTChallenge file) and the KLT tracker.
    let truth = common::read_csv(&dir.join("truth/boxes.csv"));
    let mut mot = String::new();
    for r in truth.iter().filter(|r| r["kind"] == "body") {
        let f: usize = r["frame"].parse().unwrap();
        mot.push_str(&format!(
            "{},-1,{},{},{},{},0.9,-1,-1,-1\n",
            f + 1,
            r["x"],
            r["y"],
            r["w"],
            r["h"]
        ));
    }
    std::fs::write(dir.join("boxes.txt"), mot).unwrap();
    let crowd = project(
        dir,
        "crowd",
        "[detect]\nkind = \"boxes\"\nboxes = \"boxes.txt\"\n[track]\nkind = \"klt\"\n",
    );
    same_as_run(dir, &crowd);
}

/// The frame in `lo..hi` where two people in view come closest in the image, from the truth.
fn crossing(dir: &Path, lo: usize, hi: usize) -> (usize, f64) {
    let rows = common::read_csv(&dir.join("truth/heads.csv"));
    let mut by_frame: std::collections::BTreeMap<usize, Vec<(f64, f64)>> = Default::default();
    for r in rows.iter().filter(|r| r["in_view"] == "1") {
        let f: usize = r["frame"].parse().unwrap();
        by_frame
            .entry(f)
            .or_default()
            .push((common::num(r, "px"), common::num(r, "py")));
    }
    let mut best = (0, f64::INFINITY);
    for (f, ps) in by_frame.range(lo..hi) {
        for i in 0..ps.len() {
            for j in i + 1..ps.len() {
                let d = (ps[i].0 - ps[j].0).hypot(ps[i].1 - ps[j].1);
                if d < best.1 {
                    best = (*f, d);
                }
            }
        }
    }
    best
}

fn id_switches(dir: &Path, run: &Path) -> u64 {
    let v = common::evaluate_json(
        &dir.join("truth/heads.csv"),
        &run.join("trajectories.csv"),
        &[],
    );
    v["id_switches"]
        .as_u64()
        .unwrap_or_else(|| panic!("no id_switches in {v}"))
}

#[test]
fn a_segment_border_inside_a_crossing_keeps_both_people() {
    let tmp = tempfile::tempdir().unwrap();
    let dir = tmp.path();
    simulate(dir);
    // The closest pass of two people between frames 20 and 48, and chunks of 16 frames or
    // more that end there: one segment per chunk puts a segment border inside the crossing.
    let (f, px) = crossing(dir, 20, 48);
    let len = (16..=24).rev().find(|d| f % d == 0).unwrap_or(f);
    let hats = "[detect]\nkind = \"colour\"\ncolour = [255, 0, 255]\n";
    let p = project(dir, "crossing", hats);
    let text = std::fs::read_to_string(&p)
        .unwrap()
        .replace(
            "chunk_s = 0.6\n",
            &format!("chunk_s = {}\n", len as f64 / 15.0),
        )
        // The default overlap, a second: the chunk's tracker knows the people's velocities
        // before the crossing.
        .replace("overlap_s = 0.3\n", "overlap_s = 1.0\n");
    std::fs::write(&p, text).unwrap();
    let chunks = 60usize.div_ceil(len);
    eprintln!(
        "two people {px:.0} px apart at frame {f}: chunks of {len} frames, {chunks} segments"
    );
    let one = dir.join("run-crossing");
    run(&p, &one);
    let d = dir.join("split-crossing");
    assert_success(&split(&p, chunks, &d));
    for i in (0..chunks).rev() {
        assert_success(&segment(&d, i));
    }
    assert_success(&merge(&d));
    assert_same(&one, &d);
    // The border in the crossing swaps no one: as many identity switches as a run in one piece.
    let whole = project(dir, "whole", hats);
    let text = std::fs::read_to_string(&whole)
        .unwrap()
        .replace("chunk_s = 0.6\n", "chunk_s = 10\n");
    std::fs::write(&whole, text).unwrap();
    let w = dir.join("run-whole");
    run(&whole, &w);
    assert_eq!(id_switches(dir, &d), id_switches(dir, &w));
}

#[test]
fn merge_names_a_missing_segment_and_a_rerun_redoes_only_it() {
    let tmp = tempfile::tempdir().unwrap();
    let dir = tmp.path();
    simulate(dir);
    let p = project(
        dir,
        "hats",
        "[detect]\nkind = \"colour\"\ncolour = [255, 0, 255]\n",
    );
    let d = dir.join("split");
    assert_success(&split(&p, 3, &d));
    assert_success(&segment(&d, 0));
    assert_success(&segment(&d, 2));
    let o = merge(&d);
    assert!(!o.status.success());
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(err.contains("segment(s) 1 not done"), "{err}");
    assert!(!d.join("trajectories.csv").exists());

    // The index from a batch engine's variable; a segment done already is not redone.
    let o = geostride()
        .arg("segment")
        .arg(&d)
        .arg("-q")
        .env("SLURM_ARRAY_TASK_ID", "1")
        .output()
        .unwrap();
    assert_success(&o);
    assert!(String::from_utf8_lossy(&o.stdout).contains("Segment 1 of 3"));
    let o = segment(&d, 0);
    assert_success(&o);
    let said = String::from_utf8_lossy(&o.stdout);
    assert!(said.contains(" 0 computed"), "{said}");
    assert_success(&merge(&d));
    assert!(d.join("trajectories.csv").is_file());

    // More segments than chunks, an index beyond them, no index at all: clear errors.
    let o = split(&p, 50, &dir.join("too-many"));
    assert_eq!(o.status.code(), Some(2));
    assert!(String::from_utf8_lossy(&o.stderr).contains("at most 7"));
    let o = segment(&d, 3);
    assert_eq!(o.status.code(), Some(2));
    let o = geostride()
        .arg("segment")
        .arg(&d)
        .env_remove("SLURM_ARRAY_TASK_ID")
        .env_remove("JOB_COMPLETION_INDEX")
        .env_remove("AWS_BATCH_JOB_ARRAY_INDEX")
        .output()
        .unwrap();
    assert_eq!(o.status.code(), Some(2));
    assert!(String::from_utf8_lossy(&o.stderr).contains("SLURM_ARRAY_TASK_ID"));
}
