//! OpenCV as an oracle for PnP: on the same correspondences geostride's refined pose reprojects
//! at least as well as `cv::solvePnPRansac` / `cv::solvePnP` (to 1e-6 px), and flags the same
//! outliers.

#![cfg(all(feature = "opencv", feature = "gdal", feature = "onnx"))]

use geostride::camera::Camera;
use geostride::geom::Rigid3;
use geostride::pose::oracle::OpenCvPnpInput;
use geostride::pose::{PoseSettings, solve_pose};
use geostride::simulate::gcp_view::{GcpView, GcpViewSpec, drone_camera_4k, gcp_view};

/// RMS pixel residual of `pose` over the flagged observations, on geostride's camera model
/// (the same formula as OpenCV's projectPoints).
fn rms(view: &GcpView, pose: &Rigid3, subset: &[bool]) -> f64 {
    let (mut sum, mut n) = (0.0, 0);
    for (o, _) in view.observations.iter().zip(subset).filter(|(_, s)| **s) {
        let uv = view.camera.project(&pose.apply(&o.world)).unwrap();
        sum += (uv - o.uv).norm_squared();
        n += 1;
    }
    (sum / n as f64).sqrt()
}

fn input(camera: &Camera, view: &GcpView) -> OpenCvPnpInput {
    let world: Vec<_> = view.observations.iter().map(|o| o.world).collect();
    let uv: Vec<_> = view.observations.iter().map(|o| o.uv).collect();
    OpenCvPnpInput::new(camera, &world, &uv).unwrap()
}

#[test]
fn refined_rms_is_no_worse_than_solve_pnp_on_clean_data() {
    let camera = drone_camera_4k();
    let spec = GcpViewSpec {
        outlier_fraction: 0.0,
        ..GcpViewSpec::default()
    };
    let mut worst: f64 = f64::NEG_INFINITY;
    for seed in 0..50 {
        let view = gcp_view(&camera, &spec, seed);
        let all = vec![true; view.observations.len()];
        let cv = input(&camera, &view)
            .solve(&all)
            .unwrap()
            .expect("OpenCV solves");
        let ours = solve_pose(
            &camera,
            &view.observations,
            &PoseSettings {
                seed,
                ..PoseSettings::default()
            },
        )
        .unwrap();
        assert_eq!(
            ours.inliers,
            view.observations.len(),
            "seed {seed}: a good point was flagged"
        );
        let (a, b) = (
            rms(&view, &ours.cam_from_world, &all),
            rms(&view, &cv, &all),
        );
        worst = worst.max(a - b);
        assert!(
            a <= b + 1e-6,
            "seed {seed}: geostride {a} px, OpenCV {b} px"
        );
    }
    println!("largest (geostride − OpenCV) RMS over 50 clean views: {worst:+.3e} px");
}

#[test]
fn refined_rms_is_no_worse_than_solve_pnp_ransac_with_outliers() {
    let camera = drone_camera_4k();
    let spec = GcpViewSpec::default();
    let (mut compared, mut worst) = (0, f64::NEG_INFINITY);
    for seed in 0..50 {
        let view = gcp_view(&camera, &spec, seed);
        let (cv_pose, cv_inliers) = input(&camera, &view)
            .solve_ransac(8.0, 0.99, 100)
            .unwrap()
            .expect("OpenCV solves");
        let ours = solve_pose(
            &camera,
            &view.observations,
            &PoseSettings {
                seed,
                ..PoseSettings::default()
            },
        )
        .unwrap();
        let our_inliers: Vec<bool> = ours.residuals.iter().map(|r| !r.outlier).collect();
        // Both must reject exactly the gross outliers, then the fits are comparable.
        let truth: Vec<bool> = view.outlier.iter().map(|o| !o).collect();
        assert_eq!(our_inliers, truth, "seed {seed}: geostride's inliers");
        if cv_inliers != truth {
            println!(
                "seed {seed}: OpenCV's inliers differ from the truth; compared on geostride's"
            );
        }
        let (a, b) = (
            rms(&view, &ours.cam_from_world, &truth),
            rms(&view, &cv_pose, &truth),
        );
        worst = worst.max(a - b);
        assert!(
            a <= b + 1e-6,
            "seed {seed}: geostride {a} px, OpenCV {b} px"
        );
        compared += 1;
    }
    println!(
        "largest (geostride − OpenCV) RMS over {compared} views with 30 % outliers: {worst:+.3e} px"
    );
}
