//! The bundled person detector (YOLOv3-tiny, ONNX) on a 1080p frame in 416-pixel tiles
//! (overlap 64: 15 tiles), run by ONNX Runtime and by OpenCV's dnn module on the very same
//! tiles in one run: milliseconds per frame, and the boxes compared. The frame is PETS 2009's
//! vtest frame 100 (from GEOSTRIDE_DATA) enlarged to 1920x1080.

use std::time::{Duration, Instant};

use geostride::detect::neural::{NeuralDetector, NeuralSettings};

fn median(mut t: Vec<Duration>) -> Duration {
    t.sort();
    t[t.len() / 2]
}

fn main() {
    let Some(model) = geostride::detect::onnx::bundled_model() else {
        eprintln!("detect_vs_opencv: no bundled model; run ./scripts/fetch-models.sh");
        return;
    };
    let Some(data) = std::env::var_os("GEOSTRIDE_DATA") else {
        eprintln!("detect_vs_opencv: GEOSTRIDE_DATA is not set (make bench sets it)");
        return;
    };
    let video = std::path::Path::new(&data).join("video/vtest_480x360_h264.avi");
    let (small, w, h) =
        geostride::video::source::FrameReader::frame_bgr_bytes(&video, 100).expect("vtest frame");
    // Nearest-neighbour enlargement to 1080p: the people become 4 times as many pixels.
    let (bw, bh) = (1920usize, 1080usize);
    let mut frame = vec![0u8; bw * bh * 3];
    for y in 0..bh {
        for x in 0..bw {
            let (sx, sy) = (x * w / bw, y * h / bh);
            frame[(y * bw + x) * 3..(y * bw + x) * 3 + 3]
                .copy_from_slice(&small[(sy * w + sx) * 3..(sy * w + sx) * 3 + 3]);
        }
    }
    let settings = NeuralSettings {
        tile: 416,
        overlap: 64,
        ..NeuralSettings::default()
    };
    let mut ort = NeuralDetector::load(&model, &settings).expect("ONNX Runtime");
    let mut cv = ort.on_opencv().expect("OpenCV dnn");
    println!(
        "YOLOv3-tiny, 1080p frame in 416-px tiles (overlap 64), ONNX Runtime {} vs OpenCV {} dnn, {} threads",
        geostride::detect::onnx::ORT_VERSION,
        opencv::core::get_version_string().unwrap_or_default(),
        std::thread::available_parallelism().map_or(1, |n| n.get())
    );
    let time = |d: &mut NeuralDetector| {
        let first = d.detect(&frame, [bw, bh]).expect("detect");
        let mut t = Vec::new();
        for _ in 0..7 {
            let s = Instant::now();
            std::hint::black_box(d.detect(&frame, [bw, bh]).expect("detect"));
            t.push(s.elapsed());
        }
        (median(t), first)
    };
    let (t_ort, b_ort) = time(&mut ort);
    let (t_cv, b_cv) = time(&mut cv);
    let worst = b_ort
        .iter()
        .zip(&b_cv)
        .flat_map(|(a, b)| (0..4).map(move |k| (a.xywh[k] - b.xywh[k]).abs()))
        .fold(0.0f64, f64::max);
    println!(
        "  ONNX Runtime {:.1} ms/frame, OpenCV dnn {:.1} ms/frame (ratio {:.2}); {} vs {} boxes, worst difference {:.1e} px",
        t_ort.as_secs_f64() * 1e3,
        t_cv.as_secs_f64() * 1e3,
        t_ort.as_secs_f64() / t_cv.as_secs_f64(),
        b_ort.len(),
        b_cv.len(),
        worst
    );
}
