//! geostride's pose solver (P3P + MSAC + refinement, with covariance and residual report)
//! against OpenCV's cv::solvePnPRansac (which also refines on its inliers) on the very same
//! correspondences, timed in one run: a nadir 4K camera 30 m above 20 GCPs, 1 px pick noise,
//! 30 % gross outliers, 200 seeded views.

use std::time::{Duration, Instant};

use geostride::pose::oracle::OpenCvPnpInput;
use geostride::pose::{PoseSettings, solve_pose};
use geostride::simulate::gcp_view::{GcpViewSpec, drone_camera_4k, gcp_view};

fn median(mut t: Vec<Duration>) -> Duration {
    t.sort();
    t[t.len() / 2]
}

fn main() {
    let camera = drone_camera_4k();
    let views: Vec<_> = (0..200)
        .map(|s| gcp_view(&camera, &GcpViewSpec::default(), s))
        .collect();
    let inputs: Vec<OpenCvPnpInput> = views
        .iter()
        .map(|v| {
            let world: Vec<_> = v.observations.iter().map(|o| o.world).collect();
            let uv: Vec<_> = v.observations.iter().map(|o| o.uv).collect();
            OpenCvPnpInput::new(&camera, &world, &uv).expect("OpenCV input")
        })
        .collect();
    println!(
        "PnP from 20 GCPs (30 % outliers, 1 px noise), geostride vs OpenCV {} cv::solvePnPRansac",
        opencv::core::get_version_string().unwrap_or_default()
    );
    let settings = PoseSettings::default();
    let run_ours = || {
        for v in &views {
            std::hint::black_box(
                solve_pose(&camera, &v.observations, &settings).expect("geostride"),
            );
        }
    };
    // OpenCV's defaults: 8 px, 99 % confidence, at most 100 iterations, iterative refinement.
    let run_cv = || {
        for i in &inputs {
            std::hint::black_box(i.solve_ransac(8.0, 0.99, 100).expect("OpenCV"));
        }
    };
    // Correctness on the timed data: both flag exactly the gross outliers?
    let (mut ours_ok, mut cv_ok) = (0, 0);
    for (v, i) in views.iter().zip(&inputs) {
        let truth: Vec<bool> = v.outlier.iter().map(|o| !o).collect();
        let s = solve_pose(&camera, &v.observations, &settings).expect("geostride");
        ours_ok += usize::from(s.residuals.iter().map(|r| !r.outlier).collect::<Vec<_>>() == truth);
        cv_ok += usize::from(
            i.solve_ransac(8.0, 0.99, 100)
                .expect("OpenCV")
                .is_some_and(|(_, f)| f == truth),
        );
    }
    run_ours();
    run_cv();
    let (mut t_ours, mut t_cv) = (Vec::new(), Vec::new());
    for _ in 0..15 {
        let t = Instant::now();
        run_ours();
        t_ours.push(t.elapsed());
        let t = Instant::now();
        run_cv();
        t_cv.push(t.elapsed());
    }
    let per_view = |d: Duration| d.as_secs_f64() * 1e6 / views.len() as f64;
    let (a, b) = (per_view(median(t_ours)), per_view(median(t_cv)));
    println!("{:<34} {:>12} {:>14}", "", "µs per view", "exact inliers");
    println!(
        "{:<34} {:>12.1} {:>10}/{}",
        "geostride P3P+MSAC+LM+covariance",
        a,
        ours_ok,
        views.len()
    );
    println!(
        "{:<34} {:>12.1} {:>10}/{}",
        "OpenCV solvePnPRansac (iterative)",
        b,
        cv_ok,
        views.len()
    );
    println!(
        "ratio geostride / OpenCV: {:.3} ({})",
        a / b,
        if a < b {
            "geostride faster"
        } else {
            "OpenCV faster"
        }
    );
}
