//! OpenCV as the oracle of the five-point solver: on the same five correspondences,
//! `cv::findEssentialMat` (which returns every solution of its five-point solver when given five
//! points) and `estimate::essential::five_point` give the same set of essential matrices, on
//! random scenes and on near-planar ones (every point within 1 % of the depth of a plane).

#![cfg(all(feature = "opencv", feature = "gdal", feature = "onnx"))]

use geostride::estimate::essential::{essential_of, five_point};
use geostride::geom::Rigid3;
use nalgebra::{Matrix3, Rotation3, Vector2, Vector3};
use opencv::core::{Mat, Point2d, Vector, no_array};
use opencv::prelude::*;
use rand::{RngExt, SeedableRng};
use rand_chacha::ChaCha8Rng;

/// Five points seen by two cameras: a random volume, or a tilted plane with 1 % depth noise.
fn scene(rng: &mut ChaCha8Rng, planar: bool) -> (Rigid3, [Vector2<f64>; 5], [Vector2<f64>; 5]) {
    let pose = Rigid3::new(
        Rotation3::from_scaled_axis(
            Vector3::new(
                rng.random_range(-1.0..1.0),
                rng.random_range(-1.0..1.0),
                rng.random_range(-1.0..1.0),
            ) * 0.3,
        ),
        Vector3::new(
            rng.random_range(-1.0..1.0),
            rng.random_range(-1.0..1.0),
            0.3 * rng.random_range(-1.0..1.0),
        ),
    );
    let tilt = Vector3::new(
        0.3 * rng.random_range(-1.0..1.0),
        0.3 * rng.random_range(-1.0..1.0),
        1.0,
    );
    let (mut a, mut b) = (Vec::new(), Vec::new());
    while a.len() < 5 {
        let (x, y) = (
            2.0 * rng.random_range(-1.0..1.0),
            2.0 * rng.random_range(-1.0..1.0),
        );
        let z = if planar {
            // On the plane tilt·p = 5, then 1 % off it.
            (5.0 - tilt.x * x - tilt.y * y) * (1.0 + 0.01 * rng.random_range(-1.0..1.0))
        } else {
            5.0 + 3.0 * rng.random_range(-1.0..1.0)
        };
        let p = Vector3::new(x, y, z);
        let q = pose.apply(&p);
        if p.z <= 0.1 || q.z <= 0.1 {
            continue;
        }
        a.push(Vector2::new(p.x / p.z, p.y / p.z));
        b.push(Vector2::new(q.x / q.z, q.y / q.z));
    }
    (
        pose,
        std::array::from_fn(|k| a[k]),
        std::array::from_fn(|k| b[k]),
    )
}

fn opencv_solutions(a: &[Vector2<f64>; 5], b: &[Vector2<f64>; 5]) -> Vec<Matrix3<f64>> {
    let to_cv = |p: &[Vector2<f64>; 5]| -> Vector<Point2d> {
        p.iter().map(|v| Point2d::new(v.x, v.y)).collect()
    };
    let k = Mat::from_slice_2d(&[[1.0f64, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]]).unwrap();
    let e = opencv::calib3d::find_essential_mat(
        &to_cv(a),
        &to_cv(b),
        &k,
        opencv::calib3d::RANSAC,
        0.999,
        1e-3,
        1000,
        &mut no_array(),
    )
    .unwrap();
    (0..e.rows() / 3)
        .map(|s| Matrix3::from_fn(|i, j| *e.at_2d::<f64>(3 * s + i as i32, j as i32).unwrap()))
        .collect()
}

fn distance(a: &Matrix3<f64>, b: &Matrix3<f64>) -> f64 {
    let (a, b) = (a / a.norm(), b / b.norm());
    (a - b).norm().min((a + b).norm())
}

/// Matrices (unit norm, up to sign) closer than this are the same solution. Most roots agree to
/// 1e-5; the few that differ by more than this are, each time, further from essential in
/// OpenCV's solution than in any of geostride's (checked below).
const TOL: f64 = 1e-4;

/// How far a unit-norm matrix is from essential: the smallest singular value and the gap
/// between the other two.
fn not_essential(m: &Matrix3<f64>) -> f64 {
    let mut s: Vec<f64> = (m / m.norm()).singular_values().iter().copied().collect();
    s.sort_by(f64::total_cmp);
    s[0].max(s[2] - s[1])
}

#[test]
fn five_point_solutions_are_opencvs() {
    let mut rng = ChaCha8Rng::seed_from_u64(42);
    for planar in [false, true] {
        let (mut theirs, mut ours) = (0, 0);
        let (mut theirs_unmatched, mut ours_unmatched, mut truth_missed) = (0, 0, 0);
        let mut worst: f64 = 0.0;
        for _ in 0..300 {
            let (pose, a, b) = scene(&mut rng, planar);
            let cv = opencv_solutions(&a, &b);
            let mine = five_point(&a, &b);
            theirs += cv.len();
            ours += mine.len();
            let near = |e: &Matrix3<f64>, set: &[Matrix3<f64>]| {
                set.iter()
                    .map(|m| distance(e, m))
                    .fold(f64::INFINITY, f64::min)
            };
            theirs_unmatched += cv.iter().filter(|e| near(e, &mine) > TOL).count();
            ours_unmatched += mine.iter().filter(|e| near(e, &cv) > TOL).count();
            for e in &cv {
                worst = worst.max(near(e, &mine));
                // Where the two disagree, OpenCV's is the less exact: further from essential
                // than every one of ours.
                if near(e, &mine) > TOL {
                    let ours_worst = mine.iter().map(not_essential).fold(0.0, f64::max);
                    assert!(
                        not_essential(e) > ours_worst,
                        "OpenCV's unmatched solution {:e} from essential, ours {ours_worst:e}",
                        not_essential(e)
                    );
                }
            }
            for e in &mine {
                assert!(not_essential(e) < 1e-6, "{}", not_essential(e));
            }
            truth_missed += usize::from(near(&essential_of(&pose), &mine) > TOL);
        }
        eprintln!(
            "planar {planar}: OpenCV {theirs} solutions ({theirs_unmatched} not among ours), \
             geostride {ours} ({ours_unmatched} not among OpenCV's), farthest {worst:.1e}, \
             truth missed {truth_missed} of 300"
        );
        // The two eigen-solvers differ on a few ill-conditioned roots (two roots close
        // together): measured over seeds 1 to 4 and 42, up to 0.2 % of the random sets' roots
        // and 1.9 % of the near-planar ones, each time OpenCV's the less exact.
        let allowed = theirs * if planar { 3 } else { 1 } / 100;
        assert!(
            theirs_unmatched <= allowed && ours_unmatched <= allowed,
            "planar {planar}: {theirs_unmatched} / {ours_unmatched} unmatched (allowed {allowed})"
        );
        assert_eq!(truth_missed, 0, "planar {planar}");
    }
}
