//! Joint refinement of several poses of one camera and the GCP positions they see, the GCPs
//! held to their survey by priors: a configuration of the bundle adjuster ([`crate::optim::ba`])
//! with the intrinsics fixed, each pick weighted by its own σ and each GCP by its survey's full
//! covariance.

use nalgebra::{Matrix3, Matrix6, Vector3};

use super::PoseError;
use crate::camera::{Camera, N_PARAMS};
use crate::geom::Rigid3;
use crate::optim::ba::{
    BaError, BaSettings, Observation, PointPrior, Priors, Problem, adjust_with_covariance,
    total_cost,
};
use crate::optim::ba_camera::{BrownConrady, pose_params, pose_with_covariance};
use crate::optim::{LmSettings, RobustLoss, Termination};

/// A pick of GCP `point` in the image of pose `pose`.
#[derive(Clone, Debug)]
pub struct JointObs {
    pub pose: usize,
    pub point: usize,
    pub uv: nalgebra::Vector2<f64>,
    pub sigma_px: f64,
}

/// The refined poses and GCPs with their covariances.
#[derive(Clone, Debug)]
pub struct JointResult {
    pub poses: Vec<Rigid3>,
    pub points: Vec<Vector3<f64>>,
    /// Covariance of each pose's [`Rigid3::plus`] increment `(δθ, δt)`.
    pub pose_cov: Vec<Matrix6<f64>>,
    pub point_cov: Vec<Matrix3<f64>>,
    /// Σ of the squared whitened residuals, priors included.
    pub chi2: f64,
    pub iterations: usize,
    pub termination: Termination,
}

/// Refines `poses` and `points` on `obs`, with `points` held to `prior` by `prior_cov`.
pub fn refine_jointly(
    camera: &Camera,
    poses: &[Rigid3],
    prior: &[Vector3<f64>],
    prior_cov: &[Matrix3<f64>],
    obs: &[JointObs],
    loss: RobustLoss,
    lm: &LmSettings,
) -> Result<JointResult, PoseError> {
    let mut priors = Priors::default();
    for (j, (x, c)) in prior.iter().zip(prior_cov).enumerate() {
        // A point with a zero σ is held fast by a stiff prior (1 µm).
        let c = c + Matrix3::identity() * 1e-12;
        priors.points.push(
            PointPrior::with_covariance(j, (*x).into(), &c).ok_or_else(|| {
                PoseError::Degenerate(format!(
                    "GCP {j}: survey covariance not symmetric positive definite"
                ))
            })?,
        );
    }
    let mut problem = Problem::new(
        poses.iter().map(pose_params).collect(),
        vec![camera.params()],
        vec![0; poses.len()],
        prior.iter().map(|x| (*x).into()).collect(),
        obs.iter()
            .map(|o| Observation {
                camera: o.pose,
                point: o.point,
                xy: [o.uv.x, o.uv.y],
            })
            .collect(),
    );
    problem.fixed_intrinsics = vec![[true; N_PARAMS]];
    problem.sigma_px = obs.iter().map(|o| o.sigma_px).collect();
    let degenerate = |e: BaError| match e {
        BaError::Projection { image, point, .. } => PoseError::Degenerate(format!(
            "GCP {point} is behind the camera in key frame {image}"
        )),
        BaError::Singular => PoseError::Degenerate(
            "the key frames' poses are not determined by their picks and the GCPs".into(),
        ),
        e => PoseError::Degenerate(e.to_string()),
    };
    let settings = BaSettings {
        loss,
        ..BaSettings::from_lm(lm)
    };
    let (summary, cov) =
        adjust_with_covariance(&mut problem, &BrownConrady, &priors, &settings, Some(1.0))
            .map_err(degenerate)?;
    let (poses, pose_cov) = (0..poses.len())
        .map(|i| pose_with_covariance(&problem, &cov, i))
        .unzip();
    let point_cov = cov
        .points
        .iter()
        .map(|c| c.expect("every GCP has a prior"))
        .collect();
    Ok(JointResult {
        poses,
        points: problem.points.iter().map(|x| Vector3::from(*x)).collect(),
        pose_cov,
        point_cov,
        chi2: 2.0 * total_cost(&problem, &BrownConrady, &priors, RobustLoss::Squared),
        iterations: summary.iterations.len(),
        termination: summary.termination.into(),
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::{Rotation3, Vector2, Vector6};
    use rand::{RngExt, SeedableRng};
    use rand_distr::{Distribution, Normal};

    /// Five key frames 30 m above ten GCPs (picks at 0.5 px, surveys at 3 cm), the start off
    /// by decimetres: (camera, truth, start, survey, survey covariance, picks).
    #[allow(clippy::type_complexity)]
    fn scene(
        seed: u64,
    ) -> (
        Camera,
        Vec<Rigid3>,
        Vec<Rigid3>,
        Vec<Vector3<f64>>,
        Vec<Matrix3<f64>>,
        Vec<JointObs>,
    ) {
        let camera = Camera::pinhole(1400.0, 1400.0, 960.0, 540.0).with_distortion(&[-0.05, 0.02]);
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(seed);
        let truth_pts: Vec<Vector3<f64>> = (0..10)
            .map(|_| {
                Vector3::new(
                    rng.random_range(-15.0..15.0),
                    rng.random_range(-8.0..8.0),
                    rng.random_range(-1.0..1.0),
                )
            })
            .collect();
        let truth_poses: Vec<Rigid3> = (0..5)
            .map(|k| {
                let rotation = Rotation3::from_scaled_axis(Vector3::new(
                    std::f64::consts::PI + 0.01 * k as f64,
                    0.02,
                    0.1,
                ));
                let centre = Vector3::new(0.3 * k as f64, -0.2, 30.0);
                Rigid3 {
                    rotation,
                    translation: -(rotation * centre),
                }
            })
            .collect();
        let noise = Normal::new(0.0, 0.5).unwrap();
        let mut obs = Vec::new();
        for (k, p) in truth_poses.iter().enumerate() {
            for (j, x) in truth_pts.iter().enumerate() {
                let uv = camera.project(&p.apply(x)).unwrap()
                    + Vector2::new(noise.sample(&mut rng), noise.sample(&mut rng));
                obs.push(JointObs {
                    pose: k,
                    point: j,
                    uv,
                    sigma_px: 0.5,
                });
            }
        }
        // Survey errors of 3 cm; start poses off by decimetres.
        let gnoise = Normal::new(0.0, 0.03).unwrap();
        let prior: Vec<Vector3<f64>> = truth_pts
            .iter()
            .map(|p| {
                p + Vector3::new(
                    gnoise.sample(&mut rng),
                    gnoise.sample(&mut rng),
                    gnoise.sample(&mut rng),
                )
            })
            .collect();
        let cov = vec![Matrix3::identity() * 0.0009; prior.len()];
        let start: Vec<Rigid3> = truth_poses
            .iter()
            .map(|p| p.plus(&Vector6::new(0.003, -0.002, 0.004, 0.2, -0.1, 0.3)))
            .collect();
        (camera, truth_poses, start, prior, cov, obs)
    }

    #[test]
    fn recovers_poses_and_pulls_gcps_towards_the_images() {
        let (camera, truth_poses, start, prior, cov, obs) = scene(2);
        let r = refine_jointly(
            &camera,
            &start,
            &prior,
            &cov,
            &obs,
            RobustLoss::Squared,
            &LmSettings::default(),
        )
        .unwrap();
        assert!(r.termination.converged());
        for ((p, t), c) in r.poses.iter().zip(&truth_poses).zip(&r.pose_cov) {
            let cc = super::super::refine::world_covariance(p, c);
            let e = p.centre() - t.centre();
            for k in 0..3 {
                let z = e[k] / cc[(3 + k, 3 + k)].sqrt();
                assert!(z.abs() < 4.0, "centre error {e} is {z} σ");
            }
        }
        // Five images see the GCPs better than the survey alone: relative shape improves and
        // the posterior σ are below the prior's.
        assert!(
            r.point_cov
                .iter()
                .all(|c| c[(0, 0)] < 0.0009 && c[(1, 1)] < 0.0009)
        );
        // χ² near its degrees of freedom: 2·50 observations + 30 prior − 30 − 30 parameters.
        let dof = 2.0 * 50.0 + 30.0 - 30.0 - 30.0;
        assert!(r.chi2 < 2.0 * dof, "χ² {} for {dof} dof", r.chi2);
    }
}
