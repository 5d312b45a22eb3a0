//! geostride's calibration solver against cv::calibrateCamera on the very same corners, timed in
//! one run. Both start from the corners alone (closed-form initialisation included) and use the
//! same flags; geostride also computes the covariance and the per-view report.
//!
//! Corners come from `$GEOSTRIDE_DATA/opencv-chessboard-left` when present, else from a
//! synthetic 13-view scene (said in the output).

use std::path::PathBuf;
use std::time::{Duration, Instant};

use geostride::calibration::inputs::{CollectSettings, collect};
use geostride::calibration::oracle::{OpenCvInput, calibrate_camera};
use geostride::calibration::{Options, View, calibrate};
use geostride::camera::{BoardSpec, Camera, ImageSize};
use geostride::progress::NoProgress;
use geostride::simulate::board::{add_noise, project_corners, random_board_poses};
use rand::SeedableRng;

fn views() -> (Vec<View>, BoardSpec, ImageSize, String) {
    let board = BoardSpec {
        cols: 9,
        rows: 6,
        square_m: 0.025,
    };
    if let Some(dir) =
        std::env::var_os("GEOSTRIDE_DATA").map(|d| PathBuf::from(d).join("opencv-chessboard-left"))
        && dir.is_dir()
    {
        let c = collect(
            std::slice::from_ref(&dir),
            &board,
            &CollectSettings::default(),
            &NoProgress,
        )
        .expect("corners");
        return (
            c.views,
            board,
            c.image_size.expect("size"),
            format!("{} ({} views)", dir.display(), 13),
        );
    }
    let cam = Camera::pinhole(536.0, 536.0, 342.0, 235.0)
        .with_distortion(&[-0.27, -0.04, 0.0018, -0.0003, 0.24])
        .with_image_size(640, 480);
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(1);
    let views = random_board_poses(&cam, &board, 13, &mut rng)
        .iter()
        .enumerate()
        .map(|(i, p)| {
            let mut corners = project_corners(&cam, &board, p);
            add_noise(&mut corners, 0.3, &mut rng);
            View {
                name: format!("{i}"),
                corners,
            }
        })
        .collect();
    (
        views,
        board,
        ImageSize {
            width: 640,
            height: 480,
        },
        "synthetic scene, 13 views (GEOSTRIDE_DATA not set)".into(),
    )
}

fn median(mut t: Vec<Duration>) -> Duration {
    t.sort();
    t[t.len() / 2]
}

fn main() {
    // `cargo bench` passes --bench; nothing else to parse.
    let (views, board, size, source) = views();
    let input = OpenCvInput::new(&views, &board, size);
    println!(
        "calibration solve, geostride vs OpenCV {} cv::calibrateCamera",
        opencv::core::get_version_string().unwrap_or_default()
    );
    println!("corners: {source}");
    println!(
        "{:<22} {:>14} {:>14} {:>10} {:>12} {:>12}",
        "flags", "geostride ms", "OpenCV ms", "ratio", "RMS ours", "RMS OpenCV"
    );
    let reps = 30;
    for (label, opts) in [
        ("default", Options::default()),
        (
            "fix-aspect",
            Options {
                fix_aspect: Some(1.0),
                ..Options::default()
            },
        ),
        (
            "rational",
            Options {
                rational: true,
                ..Options::default()
            },
        ),
    ] {
        // Warm-up, and the results to print.
        let ours = calibrate(&views, &board, size, &opts, false).expect("geostride");
        let cv = calibrate_camera(&input, &opts, false).expect("opencv");
        let (mut t_ours, mut t_cv) = (Vec::new(), Vec::new());
        for _ in 0..reps {
            let t = Instant::now();
            std::hint::black_box(calibrate(&views, &board, size, &opts, false).expect("geostride"));
            t_ours.push(t.elapsed());
            let t = Instant::now();
            std::hint::black_box(calibrate_camera(&input, &opts, false).expect("opencv"));
            t_cv.push(t.elapsed());
        }
        let (a, b) = (median(t_ours), median(t_cv));
        println!(
            "{label:<22} {:>14.3} {:>14.3} {:>10.3} {:>12.5} {:>12.5}",
            a.as_secs_f64() * 1e3,
            b.as_secs_f64() * 1e3,
            a.as_secs_f64() / b.as_secs_f64(),
            ours.rms_px,
            cv.rms_px
        );
    }
    println!(
        "ratio = geostride time / OpenCV time (median of {reps} runs each, interleaved); target ≤ 1.0"
    );
}
