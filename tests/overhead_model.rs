//! The committed overhead person detector (`models/overhead-person.onnx`) measured through
//! `geostride detect` on 256-px simulated tiles of a seed it was neither trained nor validated on
//! (training 1 and 5, validation 2, here 3): at the scales it was trained at, on finer frames
//! that geostride scales to them, and on feature-rich grounds (texture detail 3-5). Measured with
//! the committed model (2026-11-28): precision 0.937 / recall 0.936 at its scales, 0.928 / 0.822
//! on 0.5-0.6 cm frames, 0.930 / 0.927 on textured grounds (a quarter of a 256-px tile's people
//! are cut by its border: on 1024-px tiles it does better, `models/overhead-person.md`). The
//! floors are a little under, so that a worse model or a broken scaling fails.

#![cfg(all(feature = "opencv", feature = "gdal", feature = "onnx"))]

mod common;

use std::collections::HashMap;
use std::path::Path;

/// One label: `[x, y, w, h]`, the shoulder width (pixels) and the share inside the tile.
struct Label {
    xywh: [f64; 4],
    shoulder_px: f64,
    inside: f64,
}

fn dataset(out: &Path, gsd_cm: &str, detail: &str) -> Vec<(String, Vec<Label>)> {
    let o = common::geostride()
        .args([
            "dataset",
            "--tiles",
            "200",
            "--seed",
            "3",
            "--gsd-cm",
            gsd_cm,
            "--ground-detail",
            detail,
            "-q",
            "--out",
        ])
        .arg(out)
        .output()
        .unwrap();
    common::assert_success(&o);
    let mut labels: HashMap<usize, Vec<Label>> = HashMap::new();
    let text = std::fs::read_to_string(out.join("labels.csv")).unwrap();
    for line in text.lines().skip(1) {
        let v: Vec<f64> = line.split(',').map(|c| c.parse().unwrap()).collect();
        labels.entry(v[0] as usize).or_default().push(Label {
            xywh: [v[1], v[2], v[3], v[4]],
            shoulder_px: v[7],
            inside: v[8],
        });
    }
    (0..200)
        .map(|i| {
            (
                format!("images/{i:07}.jpg"),
                labels.remove(&i).unwrap_or_default(),
            )
        })
        .collect()
}

fn iou(a: &[f64; 4], b: &[f64; 4]) -> f64 {
    let iw = ((a[0] + a[2]).min(b[0] + b[2]) - a[0].max(b[0])).max(0.0);
    let ih = ((a[1] + a[3]).min(b[1] + b[3]) - a[1].max(b[1])).max(0.0);
    let i = iw * ih;
    i / (a[2] * a[3] + b[2] * b[3] - i + 1e-9)
}

/// Precision and recall as scripts/train_detector.py counts them: a box matches a person when
/// its centre lies within half the shoulder width of the person's box centre, or their IoU is
/// 0.3 or more (greedy, best score first); people mostly outside the tile count neither way.
fn score(tiles: &[(String, Vec<Label>)], mot: &str) -> (f64, f64, usize) {
    let mut found: HashMap<usize, Vec<(f64, [f64; 4])>> = HashMap::new();
    for line in mot.lines() {
        let v: Vec<f64> = line.split(',').map(|c| c.parse().unwrap()).collect();
        found
            .entry(v[0] as usize - 1)
            .or_default()
            .push((v[6], [v[2], v[3], v[4], v[5]]));
    }
    let (mut tp, mut fp, mut fn_) = (0, 0, 0);
    for (k, (_, labels)) in tiles.iter().enumerate() {
        let mut boxes = found.remove(&k).unwrap_or_default();
        boxes.sort_by(|a, b| b.0.total_cmp(&a.0));
        let mut used = vec![false; labels.len()];
        for (_, b) in &boxes {
            let (cx, cy) = (b[0] + b[2] / 2.0, b[1] + b[3] / 2.0);
            let mut best: Option<(f64, usize)> = None;
            for (j, l) in labels.iter().enumerate() {
                if used[j] {
                    continue;
                }
                let (lx, ly) = (l.xywh[0] + l.xywh[2] / 2.0, l.xywh[1] + l.xywh[3] / 2.0);
                let d = (cx - lx).hypot(cy - ly);
                let ok = d <= l.shoulder_px / 2.0 || iou(b, &l.xywh) >= 0.3;
                if ok && best.is_none_or(|(bd, _)| d < bd) {
                    best = Some((d, j));
                }
            }
            match best {
                Some((_, j)) => {
                    used[j] = true;
                    if labels[j].inside >= 0.5 {
                        tp += 1;
                    }
                }
                None => fp += 1,
            }
        }
        fn_ += labels
            .iter()
            .zip(&used)
            .filter(|(l, u)| !**u && l.inside >= 0.5)
            .count();
    }
    let p = tp as f64 / (tp + fp).max(1) as f64;
    let r = tp as f64 / (tp + fn_).max(1) as f64;
    (p, r, tp + fn_)
}

fn detect(dir: &Path, tiles: &[(String, Vec<Label>)], extra: &[&str]) -> String {
    let out = dir.join("boxes.txt");
    let o = common::geostride()
        .current_dir(dir)
        .arg("detect")
        .args(tiles.iter().map(|(f, _)| f.as_str()))
        .args(extra)
        .arg("--out")
        .arg(&out)
        .arg("-q")
        .output()
        .unwrap();
    common::assert_success(&o);
    std::fs::read_to_string(&out).unwrap()
}

#[test]
fn the_overhead_model_finds_people_at_its_scales_on_finer_frames_and_on_textured_ground() {
    let tmp = tempfile::tempdir().unwrap();
    // At the trained scales: the frames as they are.
    let at = tmp.path().join("at");
    let tiles = dataset(&at, "1.2,3", "0.6,2");
    let (p, r, n) = score(&tiles, &detect(&at, &tiles, &[]));
    eprintln!("trained scales: precision {p:.3} recall {r:.3} ({n} people)");
    assert!(n > 500, "{n} people");
    assert!(
        p >= AT_SCALES[0] && r >= AT_SCALES[1],
        "precision {p:.3} recall {r:.3}: under {AT_SCALES:?}"
    );
    // Four times finer (0.5-0.6 cm a pixel): shrunk to the model's scale by geostride.
    let fine = tmp.path().join("fine");
    let tiles = dataset(&fine, "0.5,0.6", "0.6,2");
    let (p, r, n) = score(&tiles, &detect(&fine, &tiles, &["--gsd-cm", "0.55"]));
    eprintln!("0.5-0.6 cm, scaled: precision {p:.3} recall {r:.3} ({n} people)");
    assert!(n > 100, "{n} people");
    assert!(
        p >= FINER[0] && r >= FINER[1],
        "precision {p:.3} recall {r:.3}: under {FINER:?}"
    );
    // On the feature-rich grounds scenes give structure from motion (texture detail 3-5: an
    // earlier model took their blotches for people, precision 0.03).
    let textured = tmp.path().join("textured");
    let tiles = dataset(&textured, "1.2,3", "3,5");
    let (p, r, n) = score(&tiles, &detect(&textured, &tiles, &[]));
    eprintln!("textured grounds: precision {p:.3} recall {r:.3} ({n} people)");
    assert!(n > 500, "{n} people");
    assert!(
        p >= TEXTURED[0] && r >= TEXTURED[1],
        "precision {p:.3} recall {r:.3}: under {TEXTURED:?}"
    );
}

/// Precision and recall the committed model must reach at its scales, and on the finer frames
/// and on textured grounds (a little under what it measured: 0.937 / 0.936, 0.928 / 0.822 and
/// 0.930 / 0.927).
const AT_SCALES: [f64; 2] = [0.90, 0.90];
const FINER: [f64; 2] = [0.89, 0.78];
const TEXTURED: [f64; 2] = [0.90, 0.89];
