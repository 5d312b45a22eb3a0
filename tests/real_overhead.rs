//! The committed overhead person detector on REAL nadir drone photos: the Brighton Beach flight
//! (`$GEOSTRIDE_DATA/brighton-drone`, a DJI Phantom 3 about 40 m up, 1.71 cm a pixel, BSD-2),
//! photos DJI_0026 to DJI_0035, which no model was trained on (the experimental backdrop
//! training in docs/detector.md laid only DJI_0018 to DJI_0024 under simulated people; DJI_0025
//! is left out between the two, as consecutive photos overlap). The people in them, three
//! cyclists and one person on the shore rocks, were boxed by hand at full resolution
//! (`tests/real/brighton-people.csv`, 16 boxes in 7 photos); what could not be told for sure
//! (a bag, a shape in deep shade) is marked `unsure` and counts neither way. Three photos hold
//! nobody: every box there is a false one.
//!
//! Matching as on simulated tiles: a box's centre within half a shoulder width (0.25 m) of a
//! person's box centre, or IoU 0.3 or more.
//!
//! This test records a FAILURE of the committed model (measured 2026-11-28): it finds 14 of the
//! 16 people but also about 240 false boxes in every photo (precision 0.006), on the dappled
//! shade of trees, tree crowns, rocks and cars, which the simulator's grounds never showed it
//! (the count is near the 300 boxes a frame `geostride detect` keeps, so the true number may be
//! higher). The bounds below only keep it from getting worse; docs/detector.md says what has
//! been tried. Tighten them when a model that works on real photos ships.

#![cfg(all(feature = "opencv", feature = "gdal", feature = "onnx"))]

mod common;

use std::collections::HashMap;

const GSD_CM: f64 = 1.71;

/// Recall at least, and false boxes per photo at most (measured 0.875 and 240.1, see above).
const RECALL_FLOOR: f64 = 0.8;
const FALSE_PER_PHOTO_CEILING: f64 = 250.0;

struct Truth {
    xywh: [f64; 4],
    person: bool,
}

fn truth() -> HashMap<String, Vec<Truth>> {
    let text = std::fs::read_to_string(
        std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/real/brighton-people.csv"),
    )
    .unwrap();
    let mut all: HashMap<String, Vec<Truth>> = HashMap::new();
    for line in text.lines().skip(1) {
        let f: Vec<&str> = line.splitn(7, ',').collect();
        let v: Vec<f64> = f[1..5].iter().map(|c| c.parse().unwrap()).collect();
        assert!(f[5] == "person" || f[5] == "unsure", "{line}");
        all.entry(f[0].to_string()).or_default().push(Truth {
            xywh: [v[0], v[1], v[2], v[3]],
            person: f[5] == "person",
        });
    }
    all
}

fn iou(a: &[f64; 4], b: &[f64; 4]) -> f64 {
    let iw = ((a[0] + a[2]).min(b[0] + b[2]) - a[0].max(b[0])).max(0.0);
    let ih = ((a[1] + a[3]).min(b[1] + b[3]) - a[1].max(b[1])).max(0.0);
    let i = iw * ih;
    i / (a[2] * a[3] + b[2] * b[3] - i + 1e-9)
}

/// True, false and missed people of one photo's boxes (best score first, greedy).
fn score(truth: &[Truth], mut boxes: Vec<(f64, [f64; 4])>) -> (usize, usize, usize) {
    let radius_px = 25.0 / GSD_CM;
    boxes.sort_by(|a, b| b.0.total_cmp(&a.0));
    let mut used = vec![false; truth.len()];
    let (mut tp, mut fp) = (0, 0);
    for (_, b) in &boxes {
        let (cx, cy) = (b[0] + b[2] / 2.0, b[1] + b[3] / 2.0);
        let mut best: Option<(f64, usize)> = None;
        for (j, t) in truth.iter().enumerate() {
            if used[j] && t.person {
                continue;
            }
            let d = (cx - t.xywh[0] - t.xywh[2] / 2.0).hypot(cy - t.xywh[1] - t.xywh[3] / 2.0);
            if (d <= radius_px || iou(b, &t.xywh) >= 0.3) && best.is_none_or(|(bd, _)| d < bd) {
                best = Some((d, j));
            }
        }
        match best {
            Some((_, j)) if truth[j].person => {
                used[j] = true;
                tp += 1;
            }
            Some(_) => {}
            None => fp += 1,
        }
    }
    let missed = truth
        .iter()
        .zip(&used)
        .filter(|(t, u)| t.person && !**u)
        .count();
    (tp, fp, missed)
}

#[test]
fn the_overhead_model_on_real_drone_photos_it_never_saw() {
    let Some(dir) = common::data_dir("brighton-drone") else {
        return;
    };
    let photos: Vec<String> = (26..=35).map(|i| format!("DJI_00{i}.JPG")).collect();
    let tmp = tempfile::tempdir().unwrap();
    let out = tmp.path().join("boxes.txt");
    let o = common::geostride()
        .arg("detect")
        .args(photos.iter().map(|p| dir.join("images").join(p)))
        .args(["--gsd-cm", &GSD_CM.to_string(), "-q", "--out"])
        .arg(&out)
        .output()
        .unwrap();
    common::assert_success(&o);
    let mut found: HashMap<usize, Vec<(f64, [f64; 4])>> = HashMap::new();
    for line in std::fs::read_to_string(&out).unwrap().lines() {
        let v: Vec<f64> = line.split(',').map(|c| c.parse().unwrap()).collect();
        found
            .entry(v[0] as usize - 1)
            .or_default()
            .push((v[6], [v[2], v[3], v[4], v[5]]));
    }
    let truth = truth();
    let (mut tp, mut fp, mut missed) = (0, 0, 0);
    for (k, photo) in photos.iter().enumerate() {
        let t = truth.get(photo).map_or(&[][..], |v| &v[..]);
        let (a, b, c) = score(t, found.remove(&k).unwrap_or_default());
        eprintln!("{photo}: {a} found, {b} false, {c} missed");
        tp += a;
        fp += b;
        missed += c;
    }
    let recall = tp as f64 / (tp + missed) as f64;
    let false_per_photo = fp as f64 / photos.len() as f64;
    eprintln!(
        "real photos: recall {recall:.3} ({tp} of {}), {fp} false boxes ({false_per_photo:.1} a photo), precision {:.3}",
        tp + missed,
        tp as f64 / (tp + fp).max(1) as f64
    );
    assert_eq!(tp + missed, 16, "the truth file's people");
    assert!(
        recall >= RECALL_FLOOR,
        "recall {recall:.3} < {RECALL_FLOOR}"
    );
    assert!(
        false_per_photo <= FALSE_PER_PHOTO_CEILING,
        "{false_per_photo:.1} false boxes a photo > {FALSE_PER_PHOTO_CEILING}"
    );
}
