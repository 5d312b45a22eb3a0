//! Bundle adjustment with geostride's own camera (pure): the Brown–Conrady model in OpenCV's
//! conventions ([`Camera`], 13 parameters in [`crate::camera::PARAM_NAMES`] order, z forward, pixel centres at
//! integers) as the engine's [`Projection`]; the parameter groups a user holds fixed by name;
//! the conversions between a [`Rigid3`] and the engine's pose vector.
//!
//! One camera for every image is `intrinsics_of = [0; images]`; self-calibration of each image
//! is one camera per image; a rig of two cameras is two. Typical drone survey: the skew and the
//! rational terms fixed (`skew`, `rational`), the rest estimated.

use std::str::FromStr;

use nalgebra::{Rotation3, SMatrix, Vector2, Vector3};

use super::ba::Projection;
use crate::camera::{Camera, N_PARAMS, param};
use crate::geom::Rigid3;

/// Geostride's camera model for the engine: `[fx, fy, cx, cy, skew, k1, k2, p1, p2, k3, k4, k5,
/// k6]`.
pub struct BrownConrady;

/// The camera of a parameter vector.
pub fn camera_from_params(k: &[f64; N_PARAMS]) -> Camera {
    let mut c = Camera::pinhole(k[0], k[1], k[2], k[3]);
    c.set_params(k);
    c
}

impl Projection<N_PARAMS> for BrownConrady {
    fn project(&self, k: &[f64; N_PARAMS], p_cam: &Vector3<f64>) -> Option<Vector2<f64>> {
        camera_from_params(k).project(p_cam).ok()
    }

    fn project_with_jacobians(
        &self,
        k: &[f64; N_PARAMS],
        p_cam: &Vector3<f64>,
    ) -> Option<(Vector2<f64>, SMatrix<f64, 2, 3>, SMatrix<f64, 2, N_PARAMS>)> {
        camera_from_params(k).project_with_jacobians(p_cam).ok()
    }
}

/// Groups of intrinsic parameters held fixed or estimated together.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum IntrinsicsGroup {
    /// `fx`, `fy`.
    Focal,
    /// `cx`, `cy`.
    PrincipalPoint,
    Skew,
    /// The polynomial radial terms `k1`, `k2`, `k3`.
    Radial,
    /// `p1`, `p2`.
    Tangential,
    /// The rational model's denominator `k4`, `k5`, `k6`.
    Rational,
}

impl IntrinsicsGroup {
    pub const ALL: [IntrinsicsGroup; 6] = [
        IntrinsicsGroup::Focal,
        IntrinsicsGroup::PrincipalPoint,
        IntrinsicsGroup::Skew,
        IntrinsicsGroup::Radial,
        IntrinsicsGroup::Tangential,
        IntrinsicsGroup::Rational,
    ];

    /// The group's parameters, as indices into [`PARAM_NAMES`].
    pub fn params(self) -> &'static [usize] {
        match self {
            IntrinsicsGroup::Focal => &[param::FX, param::FY],
            IntrinsicsGroup::PrincipalPoint => &[param::CX, param::CY],
            IntrinsicsGroup::Skew => &[param::SKEW],
            IntrinsicsGroup::Radial => &[param::K1, param::K2, param::K3],
            IntrinsicsGroup::Tangential => &[param::P1, param::P2],
            IntrinsicsGroup::Rational => &[param::K4, param::K5, param::K6],
        }
    }

    pub fn name(self) -> &'static str {
        match self {
            IntrinsicsGroup::Focal => "focal",
            IntrinsicsGroup::PrincipalPoint => "principal_point",
            IntrinsicsGroup::Skew => "skew",
            IntrinsicsGroup::Radial => "radial",
            IntrinsicsGroup::Tangential => "tangential",
            IntrinsicsGroup::Rational => "rational",
        }
    }
}

impl FromStr for IntrinsicsGroup {
    type Err = String;

    fn from_str(s: &str) -> Result<Self, String> {
        IntrinsicsGroup::ALL
            .into_iter()
            .find(|g| g.name() == s)
            .ok_or_else(|| {
                let names: Vec<&str> = IntrinsicsGroup::ALL.iter().map(|g| g.name()).collect();
                format!(
                    "unknown intrinsics group '{s}': expected one of {}",
                    names.join(", ")
                )
            })
    }
}

/// The mask of fixed intrinsics for a list of fixed groups.
pub fn fixed_intrinsics(groups: &[IntrinsicsGroup]) -> [bool; N_PARAMS] {
    let mut fixed = [false; N_PARAMS];
    for g in groups {
        for &k in g.params() {
            fixed[k] = true;
        }
    }
    fixed
}

/// Groups of pose parameters held fixed together.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum PoseGroup {
    Rotation,
    Translation,
}

/// The mask of fixed pose parameters for a list of fixed groups.
pub fn fixed_pose(groups: &[PoseGroup]) -> [bool; 6] {
    let mut fixed = [false; 6];
    for g in groups {
        let range = match g {
            PoseGroup::Rotation => 0..3,
            PoseGroup::Translation => 3..6,
        };
        fixed[range].fill(true);
    }
    fixed
}

/// The engine's pose vector `[w, t]` of a `cam_from_world` pose (`w` angle-axis, radians).
pub fn pose_params(cam_from_world: &Rigid3) -> [f64; 6] {
    let w = crate::geom::so3::log(&cam_from_world.rotation);
    let t = cam_from_world.translation;
    [w.x, w.y, w.z, t.x, t.y, t.z]
}

/// The `cam_from_world` pose of an engine pose vector.
pub fn rigid_pose(q: &[f64; 6]) -> Rigid3 {
    Rigid3 {
        rotation: Rotation3::new(Vector3::new(q[0], q[1], q[2])),
        translation: Vector3::new(q[3], q[4], q[5]),
    }
}

/// Image `i`'s `cam_from_world` and the covariance of its [`Rigid3::plus`] increment: the
/// engine's covariance is of additive angle-axis and translation increments, which no other
/// code here reads (`projection` propagates the `Rigid3` increment's).
pub fn pose_with_covariance<const M: usize>(
    p: &super::ba::Problem<M>,
    cov: &super::ba::CameraCovariance,
    i: usize,
) -> (Rigid3, nalgebra::Matrix6<f64>) {
    let q = &p.poses[i];
    let a = crate::geom::rigid::tangent_from_angle_axis(
        &Vector3::new(q[0], q[1], q[2]),
        &Vector3::new(q[3], q[4], q[5]),
    );
    let engine = nalgebra::Matrix6::from_iterator(cov.pose(i).iter().copied());
    (rigid_pose(q), a * engine * a.transpose())
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::camera::PARAM_NAMES;
    use crate::geom::so3::rotation;
    use crate::optim::RobustLoss;
    use crate::optim::ba::{
        BaError, BaSettings, LinearSolver, Observation, PointPrior, Priors, Problem, adjust,
        covariance, linearise,
    };

    /// A pose whose rotation is the identity to rounding but with a trace a few ulps over 3
    /// (the homography start of two near-identical photos gave one): finite parameters, so
    /// the adjustment accepts it. nalgebra's `scaled_axis` made them NaN and every adjustment
    /// refused the problem.
    #[test]
    fn a_near_identity_rotation_gives_finite_pose_parameters() {
        let pose = Rigid3 {
            rotation: Rotation3::from_matrix_unchecked(crate::geom::so3::near_identity_over_trace()),
            translation: Vector3::new(-0.035, -0.015, -0.999),
        };
        let q = pose_params(&pose);
        assert!(q.iter().all(|v| v.is_finite()), "{q:?}");
        assert!(q[..3].iter().all(|v| v.abs() < 1e-13), "{q:?}");
        assert!((rigid_pose(&q).translation - pose.translation).norm() == 0.0);
    }
    use rand::{RngExt, SeedableRng};
    use rand_distr::{Distribution, Normal};

    const WIDTH: f64 = 3840.0;
    const HEIGHT: f64 = 2160.0;

    /// A 4K drone camera with strong distortion.
    fn camera_truth(fx: f64) -> [f64; N_PARAMS] {
        [
            fx,
            fx * 1.0004,
            1921.3,
            1078.6,
            0.0,
            -0.112,
            0.094,
            4e-4,
            -3e-4,
            -0.021,
            0.0,
            0.0,
            0.0,
        ]
    }

    /// Twelve images 30 m above a 60 × 36 m site with 1.5 m of relief, tilted up to 10°; each
    /// image sees the points inside its frame (0.5 px noise). `cameras` intrinsics, the images
    /// split between them in turn.
    fn survey(seed: u64, cameras: &[[f64; N_PARAMS]]) -> Problem<N_PARAMS> {
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(seed);
        let normal = Normal::new(0.0, 1.0).unwrap();
        let points: Vec<[f64; 3]> = (0..400)
            .map(|_| {
                let (e, n): (f64, f64) =
                    (rng.random_range(-30.0..30.0), rng.random_range(-18.0..18.0));
                [e, n, 1.5 * (e / 7.0).sin() * (n / 5.0).cos()]
            })
            .collect();
        // Nadir: x_cam = E, y_cam = −N, z_cam = −U.
        let nadir = Rotation3::from_matrix_unchecked(nalgebra::Matrix3::new(
            1.0, 0.0, 0.0, 0.0, -1.0, 0.0, 0.0, 0.0, -1.0,
        ));
        let mut poses = Vec::new();
        for e in [-15.0, -5.0, 5.0, 15.0] {
            for n in [-6.0, 0.0, 6.0] {
                let tilt = Rotation3::new(Vector3::new(
                    rng.random_range(-0.17..0.17),
                    rng.random_range(-0.17..0.17),
                    rng.random_range(-0.3..0.3),
                ));
                let r = tilt * nadir;
                let c = Vector3::new(e, n, 30.0);
                poses.push(pose_params(&Rigid3 {
                    rotation: r,
                    translation: -(r * c),
                }));
            }
        }
        let intrinsics_of: Vec<usize> = (0..poses.len()).map(|i| i % cameras.len()).collect();
        let mut p = Problem::new(poses, cameras.to_vec(), intrinsics_of, points, Vec::new());
        for i in 0..p.poses.len() {
            for j in 0..p.points.len() {
                let o = Observation {
                    camera: i,
                    point: j,
                    xy: [0.0, 0.0],
                };
                let Some((r, ..)) = linearise(&p, &BrownConrady, &o) else {
                    continue;
                };
                if (0.0..WIDTH).contains(&r.x) && (0.0..HEIGHT).contains(&r.y) {
                    p.observations.push(Observation {
                        xy: [
                            r.x + 0.5 * normal.sample(&mut rng),
                            r.y + 0.5 * normal.sample(&mut rng),
                        ],
                        ..o
                    });
                }
            }
        }
        // As structure from motion would: only points seen twice or more.
        let mut seen = vec![0; p.points.len()];
        for o in &p.observations {
            seen[o.point] += 1;
        }
        p.observations.retain(|o| seen[o.point] >= 2);
        p
    }

    /// Eight surveyed points (2 cm) at the truth plus noise.
    fn gcps(truth: &Problem<N_PARAMS>, seed: u64) -> Priors {
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(seed);
        let normal = Normal::new(0.0, 1.0).unwrap();
        Priors {
            points: (0..8)
                .map(|j| {
                    PointPrior::new(
                        j * 50,
                        truth.points[j * 50].map(|v| v + 0.02 * normal.sample(&mut rng)),
                        [0.02; 3],
                    )
                })
                .collect(),
            centres: Vec::new(),
        }
    }

    /// The start: poses off by ~0.3° and 0.1 m, points by 0.05 m (as triangulated), the
    /// intrinsics a nominal guess (focal 3 % off, principal point 15 px, no distortion).
    fn perturbed(truth: &Problem<N_PARAMS>, seed: u64) -> Problem<N_PARAMS> {
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(seed);
        let normal = Normal::new(0.0, 1.0).unwrap();
        let mut p = truth.clone();
        for q in &mut p.poses {
            for (c, v) in q.iter_mut().enumerate() {
                *v += if c < 3 { 0.005 } else { 0.1 } * normal.sample(&mut rng);
            }
        }
        for x in &mut p.points {
            for v in x.iter_mut() {
                *v += 0.05 * normal.sample(&mut rng);
            }
        }
        for k in &mut p.intrinsics {
            let f = k[0] * 1.03;
            *k = [
                f,
                f,
                k[2] + 15.0,
                k[3] - 10.0,
                0.0,
                0.0,
                0.0,
                0.0,
                0.0,
                0.0,
                0.0,
                0.0,
                0.0,
            ];
        }
        p
    }

    /// The pose covariance `adjust` gives, carried through `projection`, against the spread of
    /// ground points under poses re-estimated from fresh noise (pixels and GCP surveys).
    #[test]
    fn a_pose_covariance_from_the_adjuster_propagates_through_projection() {
        use crate::projection::{intersect, project};
        use crate::terrain::Plane;
        let truth = survey(1, &[camera_truth(2800.0)]);
        let model = BrownConrady;
        let exact: Vec<[f64; 2]> = truth
            .observations
            .iter()
            .map(|o| {
                let r = linearise(&truth, &model, &Observation { xy: [0.0; 2], ..*o })
                    .unwrap()
                    .0;
                [r.x, r.y]
            })
            .collect();
        let mut base = truth.clone();
        base.fixed_intrinsics[0] = [true; N_PARAMS];
        let settings = BaSettings::default();
        let camera = camera_from_params(&truth.intrinsics[0]);
        let ground = Plane::from_gradient(0.0, 0.0, 0.0);
        let pixels = [Vector2::new(1920.0, 1080.0), Vector2::new(300.0, 200.0)];
        let draws = 400;
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(7);
        let normal = Normal::new(0.0, 1.0).unwrap();
        let mut ground_points: Vec<Vec<Vector2<f64>>> = vec![Vec::new(); pixels.len()];
        let mut predicted = None;
        for d in 0..draws {
            let mut p = base.clone();
            for (o, e) in p.observations.iter_mut().zip(&exact) {
                o.xy = [
                    e[0] + 0.5 * normal.sample(&mut rng),
                    e[1] + 0.5 * normal.sample(&mut rng),
                ];
            }
            let priors = gcps(&truth, 1000 + d as u64);
            adjust(&mut p, &model, &priors, &settings).unwrap();
            let pose = if predicted.is_none() {
                let cov = covariance(&p, &model, &priors, RobustLoss::Squared, Some(0.5)).unwrap();
                let (pose, tangent) = pose_with_covariance(&p, &cov, 0);
                let raw = nalgebra::Matrix6::from_iterator(cov.pose(0).iter().copied());
                predicted = Some((tangent, raw));
                pose
            } else {
                rigid_pose(&p.poses[0])
            };
            for (k, uv) in pixels.iter().enumerate() {
                ground_points[k].push(intersect(&camera, &pose, &ground, 0.0, uv).unwrap().xy());
            }
        }
        let (tangent, raw) = predicted.unwrap();
        let pose = rigid_pose(&truth.poses[0]);
        for (k, uv) in pixels.iter().enumerate() {
            let pts = &ground_points[k];
            let mean = pts.iter().sum::<Vector2<f64>>() / pts.len() as f64;
            let emp = pts
                .iter()
                .map(|x| (x - mean) * (x - mean).transpose())
                .sum::<nalgebra::Matrix2<f64>>()
                / (pts.len() - 1) as f64;
            let stated = |c: &nalgebra::Matrix6<f64>| {
                project(
                    &camera,
                    &pose,
                    Some(c),
                    &ground,
                    uv,
                    &nalgebra::Matrix2::zeros(),
                    0.0,
                    0.0,
                )
                .unwrap()
                .cov_pose
            };
            // The empirical spread in the stated covariance's whitened frame: σ ratios along its
            // principal directions of 1 within 10 % (a σ from 400 draws is known to 3.5 %).
            let ratios = |c: &nalgebra::Matrix2<f64>| {
                let w = c.cholesky().unwrap().l().try_inverse().unwrap();
                (w * emp * w.transpose())
                    .symmetric_eigenvalues()
                    .map(f64::sqrt)
            };
            let r = ratios(&stated(&tangent));
            eprintln!(
                "pixel {uv:?}: empirical σ {:.4} / {:.4} m, stated {:.4} / {:.4} m; ratios {:.3}, {:.3}",
                emp[(0, 0)].sqrt(),
                emp[(1, 1)].sqrt(),
                stated(&tangent)[(0, 0)].sqrt(),
                stated(&tangent)[(1, 1)].sqrt(),
                r[0],
                r[1]
            );
            assert!(r.iter().all(|x| (x - 1.0).abs() < 0.1), "{r:?}");
            // The engine's own parameters read as the increment's: far off.
            let wrong = ratios(&stated(&raw));
            eprintln!("  read as the increment's without the conversion: ratios {wrong:?}");
            assert!(wrong.iter().any(|x| (x - 1.0).abs() > 0.3), "{wrong:?}");
        }
    }

    #[test]
    fn whole_chain_jacobians_agree_with_finite_differences() {
        let mut k = camera_truth(2800.0);
        k[param::SKEW] = 0.7;
        k[param::K4] = 0.02;
        let p0 = Problem::new(
            vec![[0.3, -0.2, 2.9, 1.0, -2.0, 30.0]],
            vec![k],
            vec![0],
            vec![[4.0, -3.0, 1.2]],
            vec![Observation {
                camera: 0,
                point: 0,
                xy: [100.0, 200.0],
            }],
        );
        let r = |p: &Problem<N_PARAMS>| linearise(p, &BrownConrady, &p.observations[0]).unwrap().0;
        let (_, j_pose, j_intr, j_point) =
            linearise(&p0, &BrownConrady, &p0.observations[0]).unwrap();
        let check = |analytic: Vector2<f64>, bump: &dyn Fn(&mut Problem<N_PARAMS>, f64), h: f64| {
            let (mut a, mut b) = (p0.clone(), p0.clone());
            bump(&mut a, h);
            bump(&mut b, -h);
            let numeric = (r(&a) - r(&b)) / (2.0 * h);
            assert!(
                (numeric - analytic).norm() <= 1e-5 * (1.0 + numeric.norm()),
                "h {h}: {numeric} vs {analytic}"
            );
        };
        for c in 0..6 {
            check(j_pose.column(c).into(), &|p, h| p.poses[0][c] += h, 1e-6);
        }
        for (c, kc) in k.iter().enumerate() {
            let h = 1e-6 * kc.abs().max(1.0);
            check(j_intr.column(c).into(), &|p, h| p.intrinsics[0][c] += h, h);
        }
        for c in 0..3 {
            check(j_point.column(c).into(), &|p, h| p.points[0][c] += h, 1e-6);
        }
        // The engine's rotation is the pose's.
        let q = rigid_pose(&p0.poses[0]);
        assert!((q.rotation.matrix() - rotation(&Vector3::new(0.3, -0.2, 2.9))).norm() < 1e-14);
        let back = pose_params(&q);
        assert!(
            back.iter()
                .zip(&p0.poses[0])
                .all(|(a, b)| (a - b).abs() < 1e-12)
        );
    }

    #[test]
    fn self_calibrates_one_camera_shared_by_every_image() {
        let truth = survey(1, &[camera_truth(2800.0)]);
        let priors = gcps(&truth, 2);
        let mut p = perturbed(&truth, 3);
        p.fixed_intrinsics[0] =
            fixed_intrinsics(&[IntrinsicsGroup::Skew, IntrinsicsGroup::Rational]);
        // From a nominal guess the radial terms and the focal length creep along a curved
        // valley where Levenberg–Marquardt takes ~100 short steps (Ceres's radius rule too).
        let settings = BaSettings {
            max_iterations: 300,
            ..BaSettings::default()
        };
        let summary = adjust(&mut p, &BrownConrady, &priors, &settings).unwrap();
        assert!(summary.termination.converged(), "{:?}", summary.termination);
        let n = summary.observations as f64;
        // ½ Σ r² of 0.5 px noise: about n/4, less the parameters' share.
        assert!(
            summary.final_cost < 0.3 * n && summary.initial_cost > 100.0 * n,
            "{} -> {} for {n} observations",
            summary.initial_cost,
            summary.final_cost
        );
        let cov = covariance(&p, &BrownConrady, &priors, RobustLoss::Squared, None).unwrap();
        eprintln!(
            "shared camera: {} observations, cost {:.4e} -> {:.4e} in {} iterations ({}), \
             fx {:.2} ± {:.2} (truth {}), k1 {:.4} ± {:.4} (truth {}), σ0 {:.3} px",
            summary.observations,
            summary.initial_cost,
            summary.final_cost,
            summary.iterations.len(),
            summary.termination,
            p.intrinsics[0][0],
            cov.intrinsics_sigma(0, 0),
            truth.intrinsics[0][0],
            p.intrinsics[0][param::K1],
            cov.intrinsics_sigma(0, param::K1),
            truth.intrinsics[0][param::K1],
            cov.sigma_px
        );
        assert!((cov.sigma_px / 0.5 - 1.0).abs() < 0.05, "{}", cov.sigma_px);
        for (c, name) in PARAM_NAMES.iter().enumerate() {
            let (est, want, sd) = (
                p.intrinsics[0][c],
                truth.intrinsics[0][c],
                cov.intrinsics_sigma(0, c),
            );
            if p.fixed_intrinsics[0][c] {
                assert_eq!((est, sd), (0.0, 0.0), "{name}");
                continue;
            }
            // Within 4σ of the truth, σ small.
            assert!(
                (est - want).abs() < 4.0 * sd,
                "{name}: {est} vs {want} ± {sd}"
            );
        }
        assert!(cov.intrinsics_sigma(0, param::FX) < 5.0);
        assert!(cov.intrinsics_sigma(0, param::K1) < 5e-3);
        // The iterative solver reaches the same optimum (its preconditioner's shared block
        // carries the cross terms of every image).
        let mut q = perturbed(&truth, 3);
        q.fixed_intrinsics = p.fixed_intrinsics.clone();
        let iterative = adjust(
            &mut q,
            &BrownConrady,
            &priors,
            &BaSettings {
                linear_solver: LinearSolver::IterativeSchur,
                ..settings
            },
        )
        .unwrap();
        assert!(
            (iterative.final_cost / summary.final_cost - 1.0).abs() < 1e-6,
            "{} vs {}",
            iterative.final_cost,
            summary.final_cost
        );
        assert!(
            (q.intrinsics[0][0] - p.intrinsics[0][0]).abs() < 1e-3 * cov.intrinsics_sigma(0, 0)
        );
    }

    #[test]
    fn per_camera_intrinsics_with_fixed_groups() {
        // Two cameras (e.g. two drones) alternating over the images; the second's distortion is
        // calibrated and held fixed, as is its principal point; the first image's rotation is
        // held too (a pose mask).
        let truth = survey(4, &[camera_truth(2800.0), camera_truth(3300.0)]);
        let priors = gcps(&truth, 5);
        let mut p = perturbed(&truth, 6);
        let b_fixed = [
            IntrinsicsGroup::PrincipalPoint,
            IntrinsicsGroup::Skew,
            IntrinsicsGroup::Radial,
            IntrinsicsGroup::Tangential,
            IntrinsicsGroup::Rational,
        ];
        p.intrinsics[1] = truth.intrinsics[1];
        p.intrinsics[1][param::FX] *= 0.98;
        p.intrinsics[1][param::FY] *= 0.98;
        p.fixed_intrinsics = vec![
            fixed_intrinsics(&[IntrinsicsGroup::Skew, IntrinsicsGroup::Rational]),
            fixed_intrinsics(&b_fixed),
        ];
        p.poses[0] = truth.poses[0];
        p.fixed_poses[0] = fixed_pose(&[PoseGroup::Rotation]);
        let before = p.clone();
        let settings = BaSettings {
            max_iterations: 300,
            ..BaSettings::default()
        };
        let summary = adjust(&mut p, &BrownConrady, &priors, &settings).unwrap();
        assert!(summary.termination.converged(), "{:?}", summary.termination);
        // Fixed values are untouched, bit for bit.
        for (c, f) in p.fixed_intrinsics[1].iter().enumerate() {
            if *f {
                assert_eq!(p.intrinsics[1][c], before.intrinsics[1][c]);
            }
        }
        assert_eq!(p.poses[0][..3], before.poses[0][..3]);
        let cov = covariance(&p, &BrownConrady, &priors, RobustLoss::Squared, None).unwrap();
        assert_eq!(cov.pose(0).view((0, 0), (3, 3)).norm(), 0.0);
        for g in 0..2 {
            for c in [param::FX, param::FY] {
                let (est, want, sd) = (
                    p.intrinsics[g][c],
                    truth.intrinsics[g][c],
                    cov.intrinsics_sigma(g, c),
                );
                assert!(
                    sd > 0.0 && (est - want).abs() < 4.0 * sd,
                    "camera {g} {c}: {est} vs {want} ± {sd}"
                );
            }
        }
        let k1 = p.intrinsics[0][param::K1];
        assert!(
            (k1 - truth.intrinsics[0][param::K1]).abs() < 4.0 * cov.intrinsics_sigma(0, param::K1)
        );
        assert_eq!(cov.intrinsics(1).nrows(), N_PARAMS);
    }

    #[test]
    fn a_point_behind_the_camera_at_the_start_is_an_error() {
        let mut p = survey(7, &[camera_truth(2800.0)]);
        let o = p.observations[10];
        p.points[o.point][2] = 40.0;
        let err = adjust(
            &mut p,
            &BrownConrady,
            &Priors::default(),
            &BaSettings::default(),
        )
        .unwrap_err();
        assert!(
            matches!(
                err,
                BaError::Projection {
                    observation: 10,
                    ..
                }
            ),
            "{err}"
        );
        assert!(err.to_string().contains("behind the camera"));
        assert_eq!(
            "radial".parse::<IntrinsicsGroup>(),
            Ok(IntrinsicsGroup::Radial)
        );
        assert!(
            "focus"
                .parse::<IntrinsicsGroup>()
                .unwrap_err()
                .contains("principal_point")
        );
    }
}
