//! Pose from GCPs on synthetic data of known noise: the reported covariance matches the
//! empirical spread, gross outliers are flagged, degenerate inputs are errors.

use geostride::camera::Camera;
use geostride::pose::{GcpObservation, PoseError, PoseSettings, solve_pose};
use geostride::simulate::gcp_view::{GcpView, GcpViewSpec, drone_camera_4k, gcp_view};
use nalgebra::{Matrix3, Vector2, Vector3};
use rand::{RngExt, SeedableRng};
use rand_distr::{Distribution, Normal};

fn camera() -> Camera {
    drone_camera_4k()
}

/// 20 GCPs, 1 px noise, 30 % displaced by `gross_px` to ten times that.
fn case(seed: u64, gross_px: f64) -> GcpView {
    gcp_view(
        &camera(),
        &GcpViewSpec {
            gross_px,
            ..GcpViewSpec::default()
        },
        seed,
    )
}

#[test]
fn covariance_matches_the_spread_and_outliers_are_flagged() {
    let cam = camera();
    let mut normalised: Vec<[f64; 6]> = Vec::new();
    let mut mahalanobis = 0.0;
    let mut false_flags = 0;
    for seed in 0..200 {
        let c = case(seed, 15.0);
        let sol = solve_pose(
            &cam,
            &c.observations,
            &PoseSettings {
                seed,
                ..PoseSettings::default()
            },
        )
        .unwrap();
        for (r, &gross) in sol.residuals.iter().zip(&c.outlier) {
            if gross {
                assert!(
                    r.outlier,
                    "seed {seed}: gross outlier {} not flagged ({:?} px)",
                    r.name, r.residual_px
                );
            } else if r.outlier {
                false_flags += 1;
            }
        }
        // Error in (rotation about the world axes, centre).
        let est = sol.cam_from_world;
        // world_from_cam_est = exp(δφ) world_from_cam_true.
        let dphi = (est.rotation.inverse() * c.cam_from_world.rotation).scaled_axis();
        let dc = est.centre() - c.cam_from_world.centre();
        let e = nalgebra::Vector6::new(dphi.x, dphi.y, dphi.z, dc.x, dc.y, dc.z);
        let info = sol.covariance.try_inverse().unwrap();
        mahalanobis += e.dot(&(info * e));
        normalised.push(std::array::from_fn(|k| {
            e[k] / sol.covariance[(k, k)].sqrt()
        }));
        assert!(sol.rms_px < 2.0, "seed {seed}: rms {}", sol.rms_px);
    }
    let n = normalised.len() as f64;
    for k in 0..6 {
        let mean = normalised.iter().map(|e| e[k]).sum::<f64>() / n;
        let sd = (normalised
            .iter()
            .map(|e| (e[k] - mean).powi(2))
            .sum::<f64>()
            / (n - 1.0))
            .sqrt();
        println!("component {k}: mean {mean:+.3}, sd {sd:.3}");
        assert!(
            (0.8..=1.2).contains(&sd),
            "component {k}: normalised sd {sd}"
        );
        assert!(mean.abs() < 0.25, "component {k}: bias {mean}");
    }
    let m = mahalanobis / n;
    println!("mean Mahalanobis² {m:.2} (expect 6); {false_flags} of 2800 inliers flagged");
    assert!((4.8..=7.2).contains(&m), "mean Mahalanobis² {m}");
    // At χ²(99.9 %) about 3 of 2800 good points are flagged by chance.
    assert!(false_flags <= 12, "{false_flags} good points flagged");
}

#[test]
fn survey_uncertainty_enters_the_covariance() {
    // With 5 cm GCP noise (about 4.6 px here) the spread must follow the survey σ; gross
    // outliers are gross against that.
    let cam = camera();
    let mut z2 = Vec::new();
    for seed in 0..100 {
        let mut c = case(1000 + seed, 60.0);
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(seed);
        let noise = Normal::new(0.0, 0.05).unwrap();
        for o in &mut c.observations {
            o.world += Vector3::new(
                noise.sample(&mut rng),
                noise.sample(&mut rng),
                noise.sample(&mut rng),
            );
            o.world_cov = Matrix3::identity() * 0.0025;
        }
        let sol = solve_pose(
            &cam,
            &c.observations,
            &PoseSettings {
                seed,
                ..PoseSettings::default()
            },
        )
        .unwrap();
        for (r, &g) in sol.residuals.iter().zip(&c.outlier) {
            assert!(
                !g || r.outlier,
                "seed {seed}: {} not flagged: {:?} px, normalised {:?}, threshold {} px, inliers {}",
                r.name,
                r.residual_px.map(|r| r.norm()),
                r.normalised,
                sol.threshold_px,
                sol.inliers
            );
        }
        let dc = sol.cam_from_world.centre() - c.cam_from_world.centre();
        for k in 0..3 {
            z2.push((dc[k] / sol.centre_sigma_m[k]).powi(2));
        }
    }
    let rms = (z2.iter().sum::<f64>() / z2.len() as f64).sqrt();
    println!("normalised centre error RMS {rms:.3}");
    assert!(
        (0.8..=1.2).contains(&rms),
        "normalised centre error RMS {rms}"
    );
}

fn expect_error(obs: &[GcpObservation], what: &str) -> PoseError {
    match solve_pose(&camera(), obs, &PoseSettings::default()) {
        Ok(s) => panic!(
            "{what}: got a pose at {:?} ({} inliers, RMS {} px)",
            s.centre, s.inliers, s.rms_px
        ),
        Err(e) => {
            println!("{what}: {e}");
            e
        }
    }
}

#[test]
fn degenerate_inputs_are_clear_errors() {
    let c = case(7, 15.0);
    let good: Vec<GcpObservation> = c.observations[6..].to_vec();

    let e = expect_error(&good[..3], "three points");
    assert!(matches!(e, PoseError::TooFewPoints { got: 3 }));
    assert!(e.to_string().contains("at least 4"));

    let mut line = good.clone();
    for (i, o) in line.iter_mut().enumerate() {
        o.world = Vector3::new(i as f64, 2.0 * i as f64, 0.5);
    }
    let e = expect_error(&line, "collinear GCPs");
    assert!(e.to_string().contains("one line"), "{e}");

    let mut same = good.clone();
    for o in &mut same {
        o.world = Vector3::new(1.0, 2.0, 0.0);
    }
    assert!(
        expect_error(&same, "coincident GCPs")
            .to_string()
            .contains("same position")
    );

    let mut same_px = good.clone();
    for o in &mut same_px {
        o.uv = Vector2::new(100.0, 200.0);
    }
    assert!(
        expect_error(&same_px, "coincident picks")
            .to_string()
            .contains("same pixel")
    );

    let mut two_same = good.clone();
    two_same[3].uv = two_same[1].uv;
    assert!(
        expect_error(&two_same, "two GCPs at one pixel")
            .to_string()
            .contains("same pixel")
    );

    // Points behind the camera: GCPs reflected through the camera centre keep their pixels
    // (x/z is unchanged) but lie behind it. Over relief (±8 m) no pose puts them in front.
    let cam = camera();
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(11);
    let centre = c.cam_from_world.centre();
    let behind: Vec<GcpObservation> = (0..12)
        .map(|i| {
            let uv = Vector2::new(
                rng.random_range(200.0..3600.0),
                rng.random_range(200.0..1900.0),
            );
            let d = c.cam_from_world.rotation.inverse() * cam.unproject(&uv).unwrap().into_inner();
            let front = centre + d * ((rng.random_range(-8.0..8.0) - centre.z) / d.z);
            GcpObservation {
                name: format!("B{i}"),
                world: centre * 2.0 - front,
                world_cov: Matrix3::zeros(),
                uv,
                sigma_px: 1.0,
            }
        })
        .collect();
    assert!(
        behind
            .iter()
            .all(|o| c.cam_from_world.apply(&o.world).z < 0.0)
    );
    let e = expect_error(&behind, "points behind the camera");
    assert!(
        matches!(
            e,
            PoseError::NoConsensus { .. } | PoseError::BehindCamera { .. }
        ),
        "{e}"
    );
}
