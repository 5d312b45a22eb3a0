use super::*;
use crate::optim::bal::{BalIntrinsics, BalObservation, BalProblem, bundle_adjust, project};
use rand::{RngExt, SeedableRng};
use rand_distr::{Distribution, Normal};

/// Cameras on a ring looking at a cloud of 300 points, observed with noise.
fn scene(seed: u64, noise_px: f64, outliers: f64) -> (BalProblem, BalProblem) {
    scene_of(seed, noise_px, outliers, 300)
}

/// [`scene`] with `n_points` points.
fn scene_of(seed: u64, noise_px: f64, outliers: f64, n_points: usize) -> (BalProblem, BalProblem) {
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(seed);
    let normal = Normal::new(0.0, 1.0).unwrap();
    let points: Vec<[f64; 3]> = (0..n_points)
        .map(|_| {
            [
                rng.random_range(-2.0..2.0),
                rng.random_range(-2.0..2.0),
                rng.random_range(-2.0..2.0),
            ]
        })
        .collect();
    let cameras: Vec<[f64; 9]> = (0..8)
        .map(|i| {
            let a = i as f64 * 0.35;
            // Rotate about y by a; the camera sits 10 m away looking at the origin (−z).
            let w = [0.0, a, 0.0];
            [
                w[0],
                w[1],
                w[2],
                0.1 * i as f64,
                -0.05 * i as f64,
                -10.0,
                600.0,
                1e-3,
                -1e-5,
            ]
        })
        .collect();
    let truth = BalProblem {
        cameras,
        points,
        observations: Vec::new(),
    };
    let mut observations = Vec::new();
    for (c, cam) in truth.cameras.iter().enumerate() {
        for (j, x) in truth.points.iter().enumerate() {
            let u = project(cam, x);
            let mut xy = [
                u.x + noise_px * normal.sample(&mut rng),
                u.y + noise_px * normal.sample(&mut rng),
            ];
            if rng.random::<f64>() < outliers {
                xy[0] += rng.random_range(20.0..80.0);
                xy[1] -= rng.random_range(20.0..80.0);
            }
            observations.push(BalObservation {
                camera: c,
                point: j,
                xy,
            });
        }
    }
    let mut truth = truth;
    truth.observations = observations.clone();
    // The start: every parameter perturbed.
    let mut start = truth.clone();
    for c in &mut start.cameras {
        for v in &mut c[..6] {
            *v += 0.02 * normal.sample(&mut rng);
        }
        c[6] *= 1.0 + 0.01 * normal.sample(&mut rng);
    }
    for x in &mut start.points {
        for v in x.iter_mut() {
            *v += 0.05 * normal.sample(&mut rng);
        }
    }
    (truth, start)
}

/// Reprojection RMS against noise-free projections of the truth (the gauge does not matter).
fn rms_to_truth(truth: &BalProblem, est: &BalProblem) -> f64 {
    let n = est.observations.len() as f64;
    (est.observations
        .iter()
        .map(|o| {
            (project(&est.cameras[o.camera], &est.points[o.point])
                - project(&truth.cameras[o.camera], &truth.points[o.point]))
            .norm_squared()
        })
        .sum::<f64>()
        / n)
        .sqrt()
}

/// A problem large enough for its sums over points to be split between threads gives the same
/// bits on 1, 2, 3 and 4 threads and again on 4, with either linear solver (rayon's fold and
/// reduce gave other bits with other threads: the group demo's model moved by millimetres from
/// run to run).
#[test]
fn the_same_problem_gives_the_same_bits_on_any_number_of_threads() {
    let (_, start) = scene_of(11, 0.5, 0.0, 3000);
    for solver in [LinearSolver::DenseSchur, LinearSolver::IterativeSchur] {
        let settings = BaSettings {
            linear_solver: solver,
            max_iterations: 5,
            ..BaSettings::default()
        };
        let run = |threads: usize| {
            let pool = rayon::ThreadPoolBuilder::new()
                .num_threads(threads)
                .build()
                .unwrap();
            let mut p = start.clone();
            pool.install(|| bundle_adjust(&mut p, &settings)).unwrap();
            let bits: Vec<u64> = p
                .cameras
                .iter()
                .flatten()
                .chain(p.points.iter().flatten())
                .map(|v| v.to_bits())
                .collect();
            bits
        };
        let one = run(1);
        for threads in [2, 3, 4, 4] {
            assert!(
                run(threads) == one,
                "{solver:?}: other bits on {threads} threads"
            );
        }
    }
}

#[test]
fn recovers_a_scene_within_its_noise() {
    let (truth, mut start) = scene(3, 0.5, 0.0);
    let before = rms_to_truth(&truth, &start);
    let summary = bundle_adjust(&mut start, &BaSettings::default()).unwrap();
    assert!(summary.termination.converged(), "{:?}", summary.termination);
    assert!(summary.final_cost < summary.initial_cost);
    // ½ Σ r² of 2 × 2400 residuals of 0.5 px: about 600, less the parameters' share.
    let expected = 0.5 * 0.25 * (2.0 * 2400.0 - (8.0 * 9.0 + 300.0 * 3.0 - 7.0));
    assert!(
        (summary.final_cost / expected - 1.0).abs() < 0.1,
        "{} vs {expected}",
        summary.final_cost
    );
    let after = rms_to_truth(&truth, &start);
    // Noise-free projections are reached within the noise's share of the parameters:
    // 0.5 px · √(p / n) ≈ 0.22 px.
    assert!(before > 3.0 && after < 0.35, "{before} -> {after}");
}

#[test]
fn covariance_agrees_with_a_monte_carlo_spread() {
    // 4 cameras, 60 points, 10 of them surveyed (σ 1 cm: they fix the gauge), 0.5 px noise,
    // the distortion held fixed.
    let (truth, _) = scene(11, 0.0, 0.0);
    let mut truth = truth;
    truth.cameras.truncate(4);
    truth.points.truncate(60);
    truth.observations.retain(|o| o.camera < 4 && o.point < 60);
    let mut truth = truth.to_problem();
    for f in &mut truth.fixed_intrinsics {
        *f = [false, true, true];
    }
    let settings = BaSettings {
        function_tolerance: 1e-12,
        ..BaSettings::default()
    };
    let sigma = [0.01; 3];
    let exact: Vec<PointPrior> = (0..10)
        .map(|j| PointPrior::new(j * 6, truth.points[j * 6], sigma))
        .collect();
    let exact_priors = Priors {
        points: exact.clone(),
        centres: Vec::new(),
    };
    let predicted = covariance(
        &truth,
        &BalIntrinsics,
        &exact_priors,
        RobustLoss::Squared,
        Some(0.5),
    )
    .unwrap();
    assert_eq!(predicted.sigma_px, 0.5);
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(7);
    let normal = Normal::new(0.0, 1.0).unwrap();
    let trials = 300;
    let mut samples: Vec<Vec<f64>> = Vec::new();
    let mut sigma_hat = Vec::new();
    // Per camera: the pose's six, then f, k1, k2.
    let values = |p: &Problem<3>| -> Vec<f64> {
        (0..4)
            .flat_map(|i| p.poses[i].into_iter().chain(p.intrinsics[i]))
            .collect()
    };
    for _ in 0..trials {
        let mut p = truth.clone();
        for o in &mut p.observations {
            o.xy[0] += 0.5 * normal.sample(&mut rng);
            o.xy[1] += 0.5 * normal.sample(&mut rng);
        }
        let priors: Vec<PointPrior> = exact
            .iter()
            .map(|q| PointPrior {
                position: [0, 1, 2].map(|c| q.position[c] + sigma[c] * normal.sample(&mut rng)),
                ..*q
            })
            .collect();
        let priors = Priors {
            points: priors,
            centres: Vec::new(),
        };
        let summary = adjust(&mut p, &BalIntrinsics, &priors, &settings).unwrap();
        assert!(summary.termination.converged(), "{:?}", summary.termination);
        sigma_hat.push(
            covariance(&p, &BalIntrinsics, &priors, RobustLoss::Squared, None)
                .unwrap()
                .sigma_px,
        );
        samples.push(
            values(&p)
                .iter()
                .zip(values(&truth))
                .map(|(a, b)| a - b)
                .collect(),
        );
    }
    let mut checked = 0;
    for k in 0..36 {
        let (i, c) = (k / 9, k % 9);
        let want = if c < 6 {
            predicted.pose_sigma(i, c)
        } else {
            predicted.intrinsics_sigma(i, c - 6)
        };
        let values: Vec<f64> = samples.iter().map(|v| v[k]).collect();
        if c >= 7 {
            assert!(want == 0.0 && values.iter().all(|v| *v == 0.0));
            continue;
        }
        let mean = values.iter().sum::<f64>() / trials as f64;
        let sd =
            (values.iter().map(|v| (v - mean).powi(2)).sum::<f64>() / (trials - 1) as f64).sqrt();
        // 300 trials: the sample sd is within ±12 % (3σ) of the true one.
        assert!(
            (sd / want - 1.0).abs() < 0.12,
            "parameter {k}: Monte Carlo {sd:e}, predicted {want:e}"
        );
        checked += 1;
    }
    assert_eq!(checked, 28);
    // The noise estimated from the cost: 0.5 px on average.
    let mean_hat = sigma_hat.iter().sum::<f64>() / trials as f64;
    assert!((mean_hat / 0.5 - 1.0).abs() < 0.03, "{mean_hat}");
    // Without priors the gauge is free: no covariance.
    assert_eq!(
        covariance(
            &truth,
            &BalIntrinsics,
            &Priors::default(),
            RobustLoss::Squared,
            Some(0.5)
        )
        .unwrap_err(),
        BaError::Singular
    );
}

#[test]
fn centre_prior_jacobian_agrees_with_finite_differences() {
    let truth = scene(2, 0.0, 0.0).0.to_problem();
    let q = CentrePrior {
        camera: 3,
        position: [0.5, -0.2, 9.0],
        sigma: [0.02, 0.03, 0.05],
    };
    let (_, j) = centre_residual(&truth, &q);
    for k in 0..6 {
        let (mut a, mut b) = (truth.clone(), truth.clone());
        a.poses[3][k] += 1e-6;
        b.poses[3][k] -= 1e-6;
        let d = (centre_residual(&a, &q).0 - centre_residual(&b, &q).0) / 2e-6;
        assert!(
            (d - j.column(k)).norm() < 1e-5 * (1.0 + d.norm()),
            "column {k}: {d} vs {}",
            j.column(k)
        );
    }
}

#[test]
fn rtk_centres_fix_the_gauge_and_the_scene_is_recovered() {
    // Every camera's centre known to 2 cm (RTK), no surveyed point.
    let (truth, start) = scene(9, 0.5, 0.0);
    let (truth, mut start) = (truth.to_problem(), start.to_problem());
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(1);
    let normal = Normal::new(0.0, 1.0).unwrap();
    let priors = Priors {
        points: Vec::new(),
        centres: (0..truth.poses.len())
            .map(|i| {
                let c = truth.centre(i);
                CentrePrior {
                    camera: i,
                    position: [0, 1, 2].map(|k| c[k] + 0.02 * normal.sample(&mut rng)),
                    sigma: [0.02; 3],
                }
            })
            .collect(),
    };
    // A calibrated camera: f, k1, k2 fixed (at the truth: the start perturbed only f).
    start.intrinsics.clone_from(&truth.intrinsics);
    for f in &mut start.fixed_intrinsics {
        *f = [true; 3];
    }
    let summary = adjust(&mut start, &BalIntrinsics, &priors, &BaSettings::default()).unwrap();
    assert!(summary.termination.converged(), "{:?}", summary.termination);
    assert_eq!(start.intrinsics, truth.intrinsics);
    for i in 0..truth.poses.len() {
        let err = (start.centre(i) - truth.centre(i)).norm();
        assert!(err < 0.05, "camera {i}: {err} m");
    }
    // The points in the site frame itself, not up to a similarity: the frame known from
    // eight 2 cm centres on a 10 m arc is uncertain by about 1 cm in shift and 1.5 mrad in
    // rotation about the cameras' centroid, 7 m from the points: about 2 cm at the points.
    let rms = (truth
        .points
        .iter()
        .zip(&start.points)
        .map(|(a, b)| (Vector3::from(*a) - Vector3::from(*b)).norm_squared())
        .sum::<f64>()
        / truth.points.len() as f64)
        .sqrt();
    assert!(rms < 0.04, "{rms} m");
    let mut bad = priors.clone();
    bad.centres[0].sigma[2] = 0.0;
    let err = adjust(
        &mut start.clone(),
        &BalIntrinsics,
        &bad,
        &BaSettings::default(),
    );
    assert!(matches!(err, Err(BaError::Invalid(m)) if m.contains("σ > 0")));
    assert!(covariance(&start, &BalIntrinsics, &priors, RobustLoss::Squared, None).is_ok());
}

#[test]
fn iterative_schur_reaches_the_dense_solution() {
    let (truth, start) = scene(4, 0.5, 0.0);
    let run = |solver, iterative_tolerance| {
        let mut p = start.clone();
        let s = bundle_adjust(
            &mut p,
            &BaSettings {
                linear_solver: solver,
                iterative_tolerance,
                ..BaSettings::default()
            },
        )
        .unwrap();
        (s, p)
    };
    let (dense, a) = run(LinearSolver::DenseSchur, 0.1);
    let worst = |b: &BalProblem| {
        a.points
            .iter()
            .zip(&b.points)
            .map(|(x, y)| (Vector3::from(*x) - Vector3::from(*y)).norm())
            .fold(0.0, f64::max)
    };
    // Solved to 1e-10 the steps are the dense ones: the same optimum.
    let (exact, b) = run(LinearSolver::IterativeSchur, 1e-10);
    assert!(dense.termination.converged() && exact.termination.converged());
    assert!(
        (exact.final_cost / dense.final_cost - 1.0).abs() < 1e-9,
        "{} vs {}",
        exact.final_cost,
        dense.final_cost
    );
    assert!(worst(&b) < 1e-6, "{}", worst(&b));
    // Inexact steps (the default, Ceres's 0.1) stop within the function tolerance of it.
    let (inexact, c) = run(LinearSolver::IterativeSchur, 0.1);
    assert!(inexact.termination.converged());
    assert!(
        (inexact.final_cost / dense.final_cost - 1.0).abs() < 1e-5,
        "{} vs {}",
        inexact.final_cost,
        dense.final_cost
    );
    assert!(rms_to_truth(&truth, &c) < 1.01 * rms_to_truth(&truth, &a));
}

/// The Schur step (dense and iterative) against the full damped normal equations solved
/// densely, for a camera shared by every image and for one camera per image, with priors.
#[test]
fn schur_steps_equal_the_full_system_solution() {
    let (_, start) = scene(6, 0.5, 0.0);
    let mut start = start;
    start.cameras.truncate(5);
    start.points.truncate(40);
    start.observations.retain(|o| o.camera < 5 && o.point < 40);
    let per_image = start.to_problem();
    let mut shared = per_image.clone();
    shared.intrinsics.truncate(1);
    shared.fixed_intrinsics.truncate(1);
    shared.intrinsics_of = vec![0; 5];
    shared.fixed_intrinsics[0][2] = true;
    shared.fixed_poses[1] = [false, true, false, false, false, true];
    let priors = Priors {
        // A correlated survey (east and north at ρ = 0.5).
        points: vec![
            PointPrior::with_covariance(
                3,
                [0.1, 0.2, 0.3],
                &Matrix3::new(25e-4, 12.5e-4, 0.0, 12.5e-4, 25e-4, 0.0, 0.0, 0.0, 1e-2),
            )
            .unwrap(),
        ],
        centres: vec![CentrePrior {
            camera: 2,
            position: [1.0, 0.0, 10.0],
            sigma: [0.1; 3],
        }],
    };
    for p in [per_image, shared] {
        let st = Structure::new(&p);
        let lay = Layout::new(&p);
        let e = evaluate(&p, &BalIntrinsics, &priors, RobustLoss::Squared).unwrap();
        let (s_cam, s_point) = scales(&p, &priors, &st, &lay, &e);
        let n = scaled_normal(&p, &priors, &st, &lay, &e, &s_cam, &s_point);
        let (d_cam, d_point) = clamped_diagonals(&lay, &n, 1e-6, 1e32);
        let radius = 1e3;
        // The full scaled Jacobian, row by row, and its residuals.
        let dim = lay.dim + 3 * p.points.len();
        let mut rows: Vec<(DVector<f64>, f64)> = Vec::new();
        for (k, o) in p.observations.iter().enumerate() {
            let (pk, ik) = lay.of(&p, o.camera);
            for r in 0..2 {
                let mut j = DVector::zeros(dim);
                for c in 0..6 {
                    j[pk + c] = e.j_pose[k][(r, c)] * s_cam[pk + c];
                }
                for c in 0..3 {
                    j[ik + c] = e.ji(k)[(r, c)] * s_cam[ik + c];
                    j[lay.dim + 3 * o.point + c] = e.j_point[k][(r, c)] * s_point[o.point][c];
                }
                rows.push((j, e.residuals[k][r]));
            }
        }
        for q in &priors.points {
            for r in 0..3 {
                let mut j = DVector::zeros(dim);
                for c in 0..3 {
                    j[lay.dim + 3 * q.point + c] = q.sqrt_information[(r, c)] * s_point[q.point][c];
                }
                rows.push((j, prior_residual(&p, q)[r]));
            }
        }
        for q in &priors.centres {
            let (r, jq) = centre_residual(&p, q);
            for c in 0..3 {
                let mut j = DVector::zeros(dim);
                for k in 0..6 {
                    j[lay.pose[q.camera] + k] = jq[(c, k)] * s_cam[lay.pose[q.camera] + k];
                }
                rows.push((j, r[c]));
            }
        }
        let mut a = DMatrix::zeros(dim, dim);
        let mut g = DVector::zeros(dim);
        for (j, r) in &rows {
            a += j * j.transpose();
            g += j * *r;
        }
        for k in 0..lay.dim {
            a[(k, k)] += d_cam[k] / radius;
        }
        for (j, d) in d_point.iter().enumerate() {
            for c in 0..3 {
                a[(lay.dim + 3 * j + c, lay.dim + 3 * j + c)] += d[c] / radius;
            }
        }
        let want = a.cholesky().unwrap().solve(&(-g));
        for solver in [LinearSolver::DenseSchur, LinearSolver::IterativeSchur] {
            let (y_cam, y_point) =
                schur_step(&p, &st, &lay, &n, &d_cam, &d_point, radius, (solver, 1e-12)).unwrap();
            let mut got = DVector::zeros(dim);
            got.rows_mut(0, lay.dim).copy_from(&y_cam);
            for (j, y) in y_point.iter().enumerate() {
                got.fixed_rows_mut::<3>(lay.dim + 3 * j).copy_from(y);
            }
            assert!(
                (&got - &want).norm() < 1e-8 * want.norm(),
                "{solver:?}: {} vs {}",
                (&got - &want).norm(),
                want.norm()
            );
        }
    }
}

#[test]
fn huber_loss_converges_through_gross_outliers() {
    let (truth, start) = scene(5, 0.5, 0.05);
    let mut plain = start.clone();
    bundle_adjust(&mut plain, &BaSettings::default()).unwrap();
    let mut robust = start;
    let summary = bundle_adjust(
        &mut robust,
        &BaSettings {
            loss: RobustLoss::Huber(1.0),
            ..BaSettings::default()
        },
    )
    .unwrap();
    assert!(summary.termination.converged(), "{:?}", summary.termination);
    let (a, b) = (rms_to_truth(&truth, &plain), rms_to_truth(&truth, &robust));
    assert!(b < 0.45 && b < 0.1 * a, "plain {a}, Huber {b}");
}

/// A problem of the ring scene with its gauge held by a fixed first pose and a fixed point
/// (the scale), the rest free; per-observation σ when `sigma` is given.
fn gauged(seed: u64, sigma: Option<&dyn Fn(usize) -> f64>) -> Problem<3> {
    let (_, start) = scene(seed, 0.5, 0.0);
    let mut p = start.to_problem();
    p.fixed_poses[0] = [true; 6];
    p.fixed_points[0] = true;
    if let Some(s) = sigma {
        p.sigma_px = (0..p.observations.len()).map(s).collect();
    }
    p
}

/// The cost is `½ Σ ‖r/σ‖²`; scaling every σ by one constant scales the cost and moves nothing;
/// a fixed point stays where it is; with σ varying per observation the result is a minimum of
/// the weighted cost (central differences along the points vanish), not of the plain one.
#[test]
fn observation_sigmas_weigh_and_fixed_points_stay() {
    let settings = BaSettings {
        function_tolerance: 1e-14,
        parameter_tolerance: 1e-14,
        ..BaSettings::default()
    };
    let mut plain = gauged(8, None);
    let fixed_point = plain.points[0];
    let a = adjust(&mut plain, &BalIntrinsics, &Priors::default(), &settings).unwrap();
    let mut doubled = gauged(8, Some(&|_| 2.0));
    let b = adjust(&mut doubled, &BalIntrinsics, &Priors::default(), &settings).unwrap();
    assert!((a.initial_cost / b.initial_cost - 4.0).abs() < 1e-12);
    assert!((a.final_cost / b.final_cost - 4.0).abs() < 1e-8);
    assert_eq!(plain.points[0], fixed_point);
    assert_eq!(doubled.points[0], fixed_point);
    let moved = plain
        .points
        .iter()
        .zip(&doubled.points)
        .map(|(x, y)| (Vector3::from(*x) - Vector3::from(*y)).norm())
        .fold(0.0, f64::max);
    // Two paths to one optimum: the points (±2 m) agree to micrometres.
    assert!(moved < 1e-5, "{moved}");

    // Some observations of each point four times less certain than the others.
    let weights = |k: usize| if k % 7 < 3 { 4.0 } else { 1.0 };
    let mut weighted = gauged(8, Some(&weights));
    adjust(&mut weighted, &BalIntrinsics, &Priors::default(), &settings).unwrap();
    // The largest central difference of a cost along the first coordinates of points 1..20.
    let slope = |p: &Problem<3>, q: &Problem<3>| {
        (1..20)
            .map(|j| {
                let h = 1e-6;
                let (mut up, mut down) = (p.clone(), p.clone());
                up.points[j][0] += h;
                down.points[j][0] -= h;
                let cost = |x: &Problem<3>| {
                    let mut x = x.clone();
                    x.sigma_px.clone_from(&q.sigma_px);
                    cost_of(&x, &BalIntrinsics, &Priors::default(), RobustLoss::Squared)
                };
                ((cost(&up) - cost(&down)) / (2.0 * h)).abs()
            })
            .fold(0.0, f64::max)
    };
    let at_weighted = slope(&weighted, &weighted);
    let plain_under_weights = slope(&plain, &weighted);
    assert!(
        at_weighted < 1e-3 * plain_under_weights,
        "{at_weighted} vs {plain_under_weights}"
    );
}

/// The covariance's camera block and every point's block equal the inverse of the full normal
/// matrix (observations with their own σ, a fixed point, a correlated point prior and a
/// centre prior), formed and inverted densely.
#[test]
fn covariance_blocks_equal_the_full_inverse() {
    covariance_against_the_full_inverse(false);
    // Every point fixed (a calibration): the reduced system is eliminated image by image.
    covariance_against_the_full_inverse(true);
}

fn covariance_against_the_full_inverse(all_fixed: bool) {
    let mut p = gauged(9, Some(&|k| 0.5 + 0.1 * (k % 5) as f64));
    p.observations.retain(|o| o.camera < 5 && o.point < 30);
    p.sigma_px.truncate(p.observations.len());
    p.poses.truncate(5);
    p.intrinsics.truncate(1);
    p.intrinsics_of = vec![0; 5];
    p.fixed_poses.truncate(5);
    p.fixed_poses[0] = [false; 6];
    p.fixed_intrinsics.truncate(1);
    p.fixed_intrinsics[0][2] = true;
    p.points.truncate(30);
    p.fixed_points.truncate(30);
    p.sigma_px = (0..p.observations.len())
        .map(|k| 0.5 + 0.1 * (k % 5) as f64)
        .collect();
    if all_fixed {
        p.fixed_points = vec![true; p.points.len()];
    }
    let priors = Priors {
        points: if all_fixed {
            Vec::new()
        } else {
            vec![
                PointPrior::with_covariance(
                    3,
                    [0.1, 0.2, 0.3],
                    &Matrix3::new(25e-4, 12.5e-4, 0.0, 12.5e-4, 25e-4, 0.0, 0.0, 0.0, 1e-2),
                )
                .unwrap(),
            ]
        },
        centres: (0..3)
            .map(|i| CentrePrior {
                camera: i,
                position: p.centre(i).into(),
                sigma: [0.05; 3],
            })
            .collect(),
    };
    let cov = covariance(&p, &BalIntrinsics, &priors, RobustLoss::Squared, Some(1.0)).unwrap();
    let lay = Layout::new(&p);
    let e = evaluate(&p, &BalIntrinsics, &Priors::default(), RobustLoss::Squared).unwrap();
    let dim = lay.dim + 3 * p.points.len();
    let mut a = DMatrix::<f64>::zeros(dim, dim);
    let mut add = |j: DVector<f64>| a += &j * j.transpose();
    for (k, o) in p.observations.iter().enumerate() {
        let (pk, ik) = lay.of(&p, o.camera);
        for r in 0..2 {
            let mut j = DVector::zeros(dim);
            for c in 0..6 {
                j[pk + c] = e.j_pose[k][(r, c)];
            }
            for c in 0..3 {
                j[ik + c] = e.ji(k)[(r, c)];
                j[lay.dim + 3 * o.point + c] = e.j_point[k][(r, c)];
            }
            add(j);
        }
    }
    for q in &priors.points {
        for r in 0..3 {
            let mut j = DVector::zeros(dim);
            for c in 0..3 {
                j[lay.dim + 3 * q.point + c] = q.sqrt_information[(r, c)];
            }
            add(j);
        }
    }
    for q in &priors.centres {
        let jq = centre_residual(&p, q).1;
        for r in 0..3 {
            let mut j = DVector::zeros(dim);
            for k in 0..6 {
                j[lay.pose[q.camera] + k] = jq[(r, k)];
            }
            add(j);
        }
    }
    // Fixed parameters: unit rows, zeroed after inversion.
    let mut fixed: Vec<usize> = lay
        .free(&p)
        .iter()
        .enumerate()
        .filter(|f| !*f.1)
        .map(|f| f.0)
        .collect();
    let fixed_points = if all_fixed { p.points.len() } else { 1 };
    fixed.extend((0..3 * fixed_points).map(|c| lay.dim + c));
    for &k in &fixed {
        a[(k, k)] = 1.0;
    }
    let inv = a.cholesky().expect("determined").inverse();
    let mut cams = inv.view((0, 0), (lay.dim, lay.dim)).into_owned();
    for &k in fixed.iter().filter(|k| **k < lay.dim) {
        cams.row_mut(k).fill(0.0);
        cams.column_mut(k).fill(0.0);
    }
    assert!(
        (&cams - &cov.matrix).amax() < 1e-8 * cams.amax(),
        "{}",
        (&cams - &cov.matrix).amax()
    );
    assert_eq!(cov.points[0], Some(Matrix3::zeros()));
    for j in fixed_points..p.points.len() {
        let want = inv.fixed_view::<3, 3>(lay.dim + 3 * j, lay.dim + 3 * j);
        let got = cov.points[j].expect("seen five times");
        assert!(
            (got - want).amax() < 1e-8 * want.amax(),
            "point {j}: {got} vs {want}"
        );
    }
}

/// The covariance taken from the solver's last normal equations equals the one linearised again
/// at the optimum: without priors (σ estimated) and with priors (σ given as 1).
#[test]
fn covariance_after_adjusting_equals_covariance_afresh() {
    let mut p = gauged(10, Some(&|k| 0.5 + 0.1 * (k % 3) as f64));
    p.fixed_poses[0] = [false; 6];
    p.fixed_points[0] = false;
    let priors = Priors {
        points: (0..4)
            .map(|j| PointPrior::new(j * 7, p.points[j * 7], [0.02; 3]))
            .collect(),
        centres: Vec::new(),
    };
    let mut gauged_only = gauged(10, None);
    for (problem, priors, sigma) in [
        (&mut p, priors, Some(1.0)),
        (&mut gauged_only, Priors::default(), None),
    ] {
        let mut again = problem.clone();
        let (_, reused) = adjust_with_covariance(
            problem,
            &BalIntrinsics,
            &priors,
            &BaSettings::default(),
            sigma,
        )
        .unwrap();
        adjust(&mut again, &BalIntrinsics, &priors, &BaSettings::default()).unwrap();
        assert_eq!(*problem, again);
        let afresh =
            covariance(&again, &BalIntrinsics, &priors, RobustLoss::Squared, sigma).unwrap();
        let diff = (&reused.matrix - &afresh.matrix).amax() / afresh.matrix.amax();
        assert!(diff < 1e-9, "{diff}");
        assert!((reused.sigma_px / afresh.sigma_px - 1.0).abs() < 1e-12);
        for (a, b) in reused.points.iter().zip(&afresh.points) {
            match (a, b) {
                (Some(a), Some(b)) => assert!((a - b).amax() <= 1e-9 * b.amax()),
                (a, b) => assert_eq!(a.is_some(), b.is_some()),
            }
        }
    }
}

/// A large problem's loops over its points are cut into at most `MAX_POINT_PARTS` chunks, as
/// each chunk sums its own copy of the camera system (350 copies of 4 MB an iteration made a
/// 118-image model's adjustment twice as slow); a small problem's into two grains, as before.
#[test]
fn a_large_problem_sums_its_points_in_few_chunks() {
    let (points, observations): (usize, usize) = (174_000, 720_000);
    assert!(points.div_ceil(point_chunk(points, observations)) <= MAX_POINT_PARTS);
    assert_eq!(point_chunk(5_000, 15_000), 2 * grain(5_000, 15_000));
}

/// With every intrinsic parameter held the adjustment stores no Jacobians by the intrinsics
/// (two evaluations' 2×M) nor their couplings (M×3), and the memory estimate, which refuses a
/// problem before any work, must not count them: it once did, and refused a 242-photo survey.
#[test]
fn a_held_camera_is_estimated_without_the_intrinsics_blocks() {
    let mut p = gauged(1, None);
    let n = p.observations.len() as u64;
    p.fixed_intrinsics.iter_mut().for_each(|f| *f = [false; 3]);
    let free = p.memory_estimate(LinearSolver::DenseSchur);
    p.fixed_intrinsics.iter_mut().for_each(|f| *f = [true; 3]);
    let held = p.memory_estimate(LinearSolver::DenseSchur);
    let per_obs = 2 * 8 * (2 * 3) + 8 * (3 * 3);
    let want = n * per_obs * 13 / 10;
    assert!(
        (free - held).abs_diff(want) <= 1,
        "{free} - {held} against {want}"
    );
    // And the adjustment with the camera held still converges, its evaluation without them.
    let e =
        evaluation::evaluate(&p, &BalIntrinsics, &Priors::default(), RobustLoss::Squared).unwrap();
    assert!(e.j_intr.is_empty());
    let s = adjust(
        &mut p,
        &BalIntrinsics,
        &Priors::default(),
        &BaSettings::default(),
    )
    .unwrap();
    assert!(s.final_cost < s.initial_cost, "{s:?}");
}
