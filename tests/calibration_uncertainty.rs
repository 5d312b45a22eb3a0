//! The reported uncertainty is honest: over many seeded synthetic calibrations, the error of
//! every intrinsic divided by its reported standard deviation has a standard deviation of 1.

use geostride::calibration::{Options, View, calibrate};
use geostride::camera::{BoardSpec, Camera, N_PARAMS, PARAM_NAMES};
use geostride::simulate::board::{add_noise, project_corners, random_board_poses};
use rand::SeedableRng;

const SEEDS: u64 = 200;
const VIEWS: usize = 15;
const NOISE_PX: f64 = 0.2;

#[test]
fn normalised_errors_have_unit_spread() {
    let truth = Camera::pinhole(1000.0, 1004.0, 642.0, 478.0)
        .with_distortion(&[-0.21, 0.12, 0.0011, -0.0006, -0.03])
        .with_image_size(1280, 960);
    let board = BoardSpec {
        cols: 9,
        rows: 6,
        square_m: 0.03,
    };
    let mut z: Vec<Vec<f64>> = vec![Vec::new(); N_PARAMS];
    let mut sigma_px = Vec::new();
    for seed in 0..SEEDS {
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(seed);
        let views: Vec<View> = random_board_poses(&truth, &board, VIEWS, &mut rng)
            .iter()
            .enumerate()
            .map(|(i, pose)| {
                let mut corners = project_corners(&truth, &board, pose);
                add_noise(&mut corners, NOISE_PX, &mut rng);
                View {
                    name: format!("{i}"),
                    corners,
                }
            })
            .collect();
        let r = calibrate(
            &views,
            &board,
            truth.image_size.unwrap(),
            &Options::default(),
            false,
        )
        .unwrap_or_else(|e| panic!("seed {seed}: {e}"));
        assert!(
            r.termination.converged(),
            "seed {seed}: {:?}",
            r.termination
        );
        let (est, tru, sd) = (r.camera.params(), truth.params(), r.std_devs());
        for i in 0..N_PARAMS {
            if sd[i] > 0.0 {
                z[i].push((est[i] - tru[i]) / sd[i]);
            }
        }
        sigma_px.push(r.sigma_px);
    }
    let free = ["fx", "fy", "cx", "cy", "k1", "k2", "p1", "p2", "k3"];
    for (i, name) in PARAM_NAMES.iter().enumerate() {
        if !free.contains(name) {
            assert!(z[i].is_empty(), "{name} should be fixed");
            continue;
        }
        assert_eq!(z[i].len(), SEEDS as usize, "{name}");
        let n = z[i].len() as f64;
        let mean = z[i].iter().sum::<f64>() / n;
        let sd = (z[i].iter().map(|v| (v - mean).powi(2)).sum::<f64>() / (n - 1.0)).sqrt();
        println!("{name:>3}: std of normalised error {sd:.3}, mean {mean:+.3}");
        assert!(
            (0.8..=1.2).contains(&sd),
            "{name}: std of (estimate − truth)/σ is {sd:.3}"
        );
        // Bias below a third of σ (the mean of 200 unit normals has σ 0.07).
        assert!(mean.abs() < 0.33, "{name}: mean normalised error {mean:.3}");
    }
    let mean_sigma = sigma_px.iter().sum::<f64>() / sigma_px.len() as f64;
    println!("mean estimated corner sigma {mean_sigma:.4} px (true {NOISE_PX})");
    assert!((mean_sigma - NOISE_PX).abs() < 0.01 * NOISE_PX * 5.0);
}
