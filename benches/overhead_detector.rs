//! geostride's overhead person detector (models/overhead-person.onnx) beside the bundled
//! YOLOv3-tiny on the very same frames, in one run, both through ONNX Runtime: milliseconds
//! and frames a second. The frames are rendered by the simulator (`simulate::dataset`, seed 9,
//! a seed no model was trained or validated on): 1080p at 1.9 cm a pixel, 4K at 0.95 cm (a 4K
//! camera 30 m up, the paper's) and 4K at 1.9 cm. The overhead model sees each frame whole at
//! its own scale (as `[detect] kind = "onnx"` runs it from a pose: the 0.95 cm frame shrunk to
//! 1.9 cm); YOLOv3-tiny sees it in 416-pixel tiles overlapping by 64 pixels (`docs/detector.md`).
//! Targets (issue 38): ≥ 5 frames a second at 1080p and ≥ 1.5 at 4K on 2 cores.

use std::time::{Duration, Instant};

use geostride::detect::neural::{NeuralDetector, NeuralSettings};
use geostride::simulate::dataset::{DatasetSpec, render_tile};

fn median(mut t: Vec<Duration>) -> Duration {
    t.sort();
    t[t.len() / 2]
}

/// A `width`×`height` BGR frame at `gsd_m` metres a pixel: the top of a square rendered tile.
fn frame(width: usize, height: usize, gsd_m: f64) -> (Vec<u8>, usize) {
    let spec = DatasetSpec {
        size_px: width as u32,
        seed: 9,
        gsd_m: [gsd_m, gsd_m],
        ..DatasetSpec::default()
    };
    let tile = render_tile(&spec, 0, &[]);
    let mut bgr = vec![0u8; width * height * 3];
    for (o, i) in bgr.chunks_exact_mut(3).zip(tile.rgb.chunks_exact(3)) {
        o.copy_from_slice(&[i[2], i[1], i[0]]);
    }
    let people = tile
        .labels
        .iter()
        .filter(|l| l.bbox[1] + l.bbox[3] / 2.0 < height as f64)
        .count();
    (bgr, people)
}

fn time(d: &mut NeuralDetector, bgr: &[u8], wh: [usize; 2]) -> (Duration, usize) {
    let found = d.detect(bgr, wh).expect("detect").len();
    let t = (0..5)
        .map(|_| {
            let s = Instant::now();
            std::hint::black_box(d.detect(bgr, wh).expect("detect"));
            s.elapsed()
        })
        .collect();
    (median(t), found)
}

fn main() {
    let Some(yolo) = geostride::detect::onnx::bundled_model() else {
        eprintln!("overhead_detector: no bundled YOLOv3-tiny; run ./scripts/fetch-models.sh");
        return;
    };
    let Some(overhead) = geostride::detect::onnx::overhead_model() else {
        eprintln!(
            "overhead_detector: models/overhead-person.onnx is missing (run from the checkout)"
        );
        return;
    };
    println!(
        "Overhead model (whole frames at its own scale) vs YOLOv3-tiny (416-px tiles, overlap 64), ONNX Runtime {}, {} threads",
        geostride::detect::onnx::ORT_VERSION,
        std::thread::available_parallelism().map_or(1, |n| n.get())
    );
    for (name, w, h, gsd_m) in [
        ("1080p at 1.9 cm/px", 1920, 1080, 0.019),
        ("4K at 0.95 cm/px", 3840, 2160, 0.0095),
        ("4K at 1.9 cm/px", 3840, 2160, 0.019),
    ] {
        let (bgr, people) = frame(w, h, gsd_m);
        let mut own = NeuralDetector::load(
            &overhead,
            &NeuralSettings {
                frame_gsd_m: Some(gsd_m),
                ..NeuralSettings::default()
            },
        )
        .expect("the overhead model");
        let mut tiny = NeuralDetector::load(
            &yolo,
            &NeuralSettings {
                tile: 416,
                overlap: 64,
                ..NeuralSettings::default()
            },
        )
        .expect("YOLOv3-tiny");
        let (t_own, n_own) = time(&mut own, &bgr, [w, h]);
        let (t_tiny, n_tiny) = time(&mut tiny, &bgr, [w, h]);
        let ms = |t: Duration| t.as_secs_f64() * 1e3;
        println!(
            "  {name} ({people} people; frames scaled {:.2}×): overhead {:.0} ms ({:.1} frames/s, {n_own} boxes), YOLOv3-tiny {:.0} ms ({:.1} frames/s, {n_tiny} boxes)",
            own.frame_scale().unwrap_or(1.0),
            ms(t_own),
            1e3 / ms(t_own),
            ms(t_tiny),
            1e3 / ms(t_tiny),
        );
    }
}
