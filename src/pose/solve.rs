//! The pose of one image from ground control points: checks, P3P + MSAC, refinement with
//! weights that carry both the pick's and the survey's uncertainty, outlier flags, covariance
//! and per-GCP residuals in pixels and on the ground.

use nalgebra::{Matrix2, Matrix3, Matrix6, SymmetricEigen, Vector2, Vector3};

use super::PoseError;
use super::refine::{PointObs, RefinedPose, project_pose, refine_pose, world_covariance};
use crate::camera::Camera;
use crate::estimate::epnp::epnp;
use crate::estimate::pnp::PnpEstimator;
use crate::estimate::ransac::{RansacSettings, msac};
use crate::geom::Rigid3;
use crate::optim::{LmSettings, RobustLoss, Termination};

/// χ² with 2 degrees of freedom at 99.9 %: the outlier test on a normalised pixel residual.
pub const CHI2_2DOF_999: f64 = 13.815510557964274;

/// A GCP seen in the image.
#[derive(Clone, Debug)]
pub struct GcpObservation {
    pub name: String,
    /// Position in the local frame, metres.
    pub world: Vector3<f64>,
    /// Covariance of the surveyed position (m²); zero for exact points.
    pub world_cov: Matrix3<f64>,
    /// The pick, pixels.
    pub uv: Vector2<f64>,
    /// σ of the pick, pixels.
    pub sigma_px: f64,
}

/// How to solve.
#[derive(Clone, Debug)]
pub struct PoseSettings {
    /// MSAC inlier threshold in pixels; by default `max(4, 3.72 σ)` of the largest pick σ.
    pub threshold_px: Option<f64>,
    pub confidence: f64,
    pub max_iterations: usize,
    pub seed: u64,
    pub loss: RobustLoss,
    /// Outlier test on the squared normalised residual after refinement.
    pub outlier_chi2: f64,
    /// Fewest GCPs, as a fraction of all, that must agree on the pose: a handful agreeing among
    /// many is a coincidence, not a pose.
    pub min_inlier_fraction: f64,
}

impl Default for PoseSettings {
    fn default() -> Self {
        PoseSettings {
            threshold_px: None,
            confidence: 0.9999,
            max_iterations: 10_000,
            seed: 0,
            loss: RobustLoss::Squared,
            outlier_chi2: CHI2_2DOF_999,
            min_inlier_fraction: 0.5,
        }
    }
}

/// One GCP's fit.
#[derive(Clone, Debug)]
pub struct GcpResidual {
    pub name: String,
    pub uv: Vector2<f64>,
    /// The GCP projected with the solved pose; `None` behind the camera.
    pub projected: Option<Vector2<f64>>,
    /// Pick minus projection, pixels.
    pub residual_px: Option<Vector2<f64>>,
    /// Where the pick's ray meets the horizontal plane through the GCP, minus the GCP: east and
    /// north, metres.
    pub ground_m: Option<Vector2<f64>>,
    /// `√(rᵀ Σ⁻¹ r)` with Σ the pick's and the projected survey covariance.
    pub normalised: Option<f64>,
    pub depth_m: Option<f64>,
    pub outlier: bool,
}

/// A solved pose.
#[derive(Clone, Debug)]
pub struct PoseSolution {
    pub cam_from_world: Rigid3,
    /// Covariance of `(δφ_e, δφ_n, δφ_u, C_e, C_n, C_u)`: rotation errors about the world axes
    /// (radians) and the camera centre (metres).
    pub covariance: Matrix6<f64>,
    pub centre: Vector3<f64>,
    pub centre_sigma_m: Vector3<f64>,
    pub residuals: Vec<GcpResidual>,
    pub inliers: usize,
    /// RMS of the inliers' pixel residuals.
    pub rms_px: f64,
    /// A-posteriori σ₀ = √(χ² / (2m − 6)): near 1 when the stated σ are right.
    pub sigma0: f64,
    pub threshold_px: f64,
    pub ransac_iterations: usize,
    pub termination: Termination,
}

/// RMS distances of points (rows of `pts`) from their centroid along the principal axes,
/// largest first.
fn axes_rms(pts: &nalgebra::DMatrix<f64>) -> Vec<f64> {
    let n = pts.nrows() as f64;
    let c = pts.row_mean();
    let centred = pts - nalgebra::DMatrix::from_fn(pts.nrows(), pts.ncols(), |_, j| c[j]);
    let s = centred.transpose() * &centred;
    let mut e: Vec<f64> = SymmetricEigen::new(s)
        .eigenvalues
        .iter()
        .map(|l| (l.max(0.0) / n).sqrt())
        .collect();
    e.sort_by(|a, b| b.total_cmp(a));
    e
}

/// How far from a line points must spread, as a fraction of their extent along it: closer,
/// the rotation about that line is not determined.
const MIN_LINE_OFFSET: f64 = 0.01;

/// Rejects inputs no pose can come from: too few points, coincident GCPs or picks, or GCPs or
/// picks on one line, within their noise (3 σ) or 1 % of their extent.
pub fn check_geometry(obs: &[GcpObservation]) -> Result<(), PoseError> {
    if obs.len() < 4 {
        return Err(PoseError::TooFewPoints { got: obs.len() });
    }
    let world = nalgebra::DMatrix::from_fn(obs.len(), 3, |i, j| obs[i].world[j]);
    let uv = nalgebra::DMatrix::from_fn(obs.len(), 2, |i, j| obs[i].uv[j]);
    let ws = axes_rms(&world);
    if ws[0] == 0.0 {
        return Err(PoseError::Degenerate(
            "all GCPs are at the same position".into(),
        ));
    }
    let sigma_world = obs
        .iter()
        .map(|o| (o.world_cov.trace().max(0.0) / 3.0).sqrt())
        .fold(0.0, f64::max);
    if ws[1] < (3.0 * sigma_world).max(MIN_LINE_OFFSET * ws[0]) {
        return Err(PoseError::Degenerate(format!(
            "the GCPs lie on one line (within {:.3} m RMS over {:.1} m): a pose needs GCPs spread over an area",
            ws[1], ws[0]
        )));
    }
    let ps = axes_rms(&uv);
    if ps[0] == 0.0 {
        return Err(PoseError::Degenerate(
            "all picks are at the same pixel".into(),
        ));
    }
    let sigma_px = obs.iter().map(|o| o.sigma_px).fold(0.0, f64::max);
    if ps[1] < (3.0 * sigma_px).max(MIN_LINE_OFFSET * ps[0]) {
        return Err(PoseError::Degenerate(format!(
            "the picks lie on one image line (within {:.2} px RMS over {:.0} px)",
            ps[1], ps[0]
        )));
    }
    for (i, a) in obs.iter().enumerate() {
        if let Some(b) = obs[..i].iter().find(|b| (b.uv - a.uv).norm() < 1e-6) {
            return Err(PoseError::Degenerate(format!(
                "GCPs '{}' and '{}' are picked at the same pixel",
                b.name, a.name
            )));
        }
    }
    Ok(())
}

/// Pixel covariance of a residual: the pick's, plus the survey's projected through the pose.
pub fn residual_covariance(jx: &nalgebra::Matrix2x3<f64>, o: &GcpObservation) -> Matrix2<f64> {
    Matrix2::identity() * (o.sigma_px * o.sigma_px) + jx * o.world_cov * jx.transpose()
}

fn point_obs(
    camera: &Camera,
    pose: &Rigid3,
    o: &GcpObservation,
) -> Option<(PointObs, Matrix2<f64>)> {
    let (_, _, jx) = project_pose(camera, pose, &o.world)?;
    let cov = residual_covariance(&jx, o);
    Some((
        PointObs {
            world: o.world,
            uv: o.uv,
            info: cov.try_inverse()?,
        },
        cov,
    ))
}

/// The MSAC threshold: the 99.9 % radius of the largest pick σ combined with the typical survey σ
/// seen at the typical depth, at least 4 px. The depth comes from the median ratio of world to
/// normalised image distances, which needs no pose.
fn default_threshold(obs: &[GcpObservation], xy: &[Vector2<f64>], focal: f64) -> f64 {
    let mut ratios = Vec::new();
    for i in 0..obs.len() {
        for j in 0..i {
            let d_img = (xy[i] - xy[j]).norm();
            if d_img > 0.0 {
                ratios.push((obs[i].world - obs[j].world).norm() / d_img);
            }
        }
    }
    let median = |v: &mut Vec<f64>| -> f64 {
        if v.is_empty() {
            return 0.0;
        }
        v.sort_by(f64::total_cmp);
        v[v.len() / 2]
    };
    let depth = median(&mut ratios);
    let mut survey: Vec<f64> = obs
        .iter()
        .map(|o| {
            (0.5 * (o.world_cov[(0, 0)] + o.world_cov[(1, 1)]))
                .max(0.0)
                .sqrt()
        })
        .collect();
    let survey_px = if depth > 0.0 {
        focal * median(&mut survey) / depth
    } else {
        0.0
    };
    let pick = obs.iter().map(|o| o.sigma_px).fold(0.0, f64::max);
    (CHI2_2DOF_999.sqrt() * (pick * pick + survey_px * survey_px).sqrt()).max(4.0)
}

/// Squared normalised residual of one GCP under `pose`; `None` behind the camera.
fn normalised_sq(camera: &Camera, pose: &Rigid3, o: &GcpObservation) -> Option<f64> {
    let (uv, _, jx) = project_pose(camera, pose, &o.world)?;
    let r = o.uv - uv;
    let info = residual_covariance(&jx, o).try_inverse()?;
    Some(r.dot(&(info * r)))
}

fn refine_on(
    camera: &Camera,
    start: &Rigid3,
    obs: &[GcpObservation],
    inliers: &[bool],
    loss: RobustLoss,
) -> Result<RefinedPose, PoseError> {
    let mut pts = Vec::new();
    let mut behind = Vec::new();
    for (i, o) in obs.iter().enumerate().filter(|(i, _)| inliers[*i]) {
        match point_obs(camera, start, o) {
            Some((p, _)) => pts.push(p),
            None => behind.push(i),
        }
    }
    if !behind.is_empty() {
        return Err(PoseError::BehindCamera { points: behind });
    }
    let lm = LmSettings::default();
    let first = refine_pose(camera, start, &pts, loss, &lm)?;
    // The survey term of the weights depends on the pose: re-weight once at the solution.
    let mut pts = Vec::new();
    for o in obs
        .iter()
        .enumerate()
        .filter(|(i, _)| inliers[*i])
        .map(|(_, o)| o)
    {
        pts.push(
            point_obs(camera, &first.cam_from_world, o)
                .ok_or_else(|| {
                    PoseError::Degenerate("a GCP went behind the camera during refinement".into())
                })?
                .0,
        );
    }
    refine_pose(camera, &first.cam_from_world, &pts, loss, &lm)
}

/// How one GCP fits a pose: pixel residual, its normalised size, and where the pick's ray meets
/// the horizontal plane through the GCP.
pub fn gcp_residual(
    camera: &Camera,
    pose: &Rigid3,
    o: &GcpObservation,
    outlier: bool,
) -> GcpResidual {
    let centre = pose.centre();
    let proj = project_pose(camera, pose, &o.world);
    let ground_m = camera.unproject(&o.uv).ok().and_then(|b| {
        let d = pose.rotation.inverse() * b.into_inner();
        let s = (o.world.z - centre.z) / d.z;
        (s > 0.0 && s.is_finite()).then(|| (centre + d * s).xy() - o.world.xy())
    });
    GcpResidual {
        name: o.name.clone(),
        uv: o.uv,
        projected: proj.as_ref().map(|p| p.0),
        residual_px: proj.as_ref().map(|(uv, _, _)| o.uv - uv),
        ground_m,
        normalised: normalised_sq(camera, pose, o).map(f64::sqrt),
        depth_m: Some(pose.apply(&o.world).z).filter(|z| *z > 0.0),
        outlier,
    }
}

/// Solves the pose of one image from its GCP observations.
pub fn solve_pose(
    camera: &Camera,
    obs: &[GcpObservation],
    settings: &PoseSettings,
) -> Result<PoseSolution, PoseError> {
    check_geometry(obs)?;
    let n = obs.len();
    let world: Vec<Vector3<f64>> = obs.iter().map(|o| o.world).collect();
    let mut xy = Vec::with_capacity(n);
    for o in obs {
        xy.push(
            camera
                .pixel_to_normalized(&o.uv)
                .map_err(|e| PoseError::BadPick {
                    name: o.name.clone(),
                    message: e.to_string(),
                })?,
        );
    }
    let focal = 0.5 * (camera.fx + camera.fy);
    let threshold = settings
        .threshold_px
        .unwrap_or_else(|| default_threshold(obs, &xy, focal));
    let est = PnpEstimator::new(&world, &xy, focal);
    let ransac = msac(
        &est,
        &RansacSettings {
            threshold,
            confidence: settings.confidence,
            max_iterations: settings.max_iterations,
            min_iterations: 10,
            local_optimisation: true,
            // P3P models from noisy picks are often poor: optimise every promising one.
            lo_count_fraction: 0.5,
            seed: settings.seed,
        },
    )
    .map_err(|e| PoseError::Degenerate(e.to_string()))?;
    let no_consensus = |count: usize| PoseError::NoConsensus {
        agreeing: count,
        total: n,
        threshold_px: threshold,
    };
    let min_inliers = ((settings.min_inlier_fraction * n as f64).ceil() as usize).max(4);
    if ransac.inlier_count < min_inliers {
        return Err(no_consensus(ransac.inlier_count));
    }
    let mut inliers = ransac.inliers.clone();
    let mut start = ransac.model;
    let mut refined = None;
    // Refine, re-test every GCP on its normalised residual, repeat until the set is stable.
    for _ in 0..10 {
        let count = inliers.iter().filter(|&&b| b).count();
        let subset: Vec<GcpObservation> = obs
            .iter()
            .zip(&inliers)
            .filter(|(_, b)| **b)
            .map(|(o, _)| o.clone())
            .collect();
        if count < min_inliers {
            return Err(no_consensus(count));
        }
        check_geometry(&subset).map_err(|e| {
            PoseError::Degenerate(format!("the GCPs that agree on a pose are degenerate: {e}"))
        })?;
        let mut best = refine_on(camera, &start, obs, &inliers, settings.loss)?;
        // A second start from EPnP on the inliers guards against a poor local minimum.
        let (w, m): (Vec<_>, Vec<_>) = (0..n)
            .filter(|&i| inliers[i])
            .map(|i| (world[i], xy[i]))
            .unzip();
        if let Ok(alt) = epnp(&w, &m)
            && let Ok(r) = refine_on(camera, &alt, obs, &inliers, settings.loss)
            && r.chi2 < best.chi2 * (1.0 - 1e-9)
        {
            best = r;
        }
        let next: Vec<bool> = obs
            .iter()
            .map(|o| {
                normalised_sq(camera, &best.cam_from_world, o)
                    .is_some_and(|s| s < settings.outlier_chi2)
            })
            .collect();
        start = best.cam_from_world;
        let stable = next == inliers;
        refined = Some(best);
        if stable {
            break;
        }
        inliers = next;
    }
    let refined = refined.expect("at least one refinement");
    let count = inliers.iter().filter(|&&b| b).count();
    if count < min_inliers {
        return Err(no_consensus(count));
    }
    let pose = refined.cam_from_world;
    let covariance = world_covariance(&pose, &refined.covariance);
    let centre = pose.centre();
    let residuals: Vec<GcpResidual> = obs
        .iter()
        .zip(&inliers)
        .map(|(o, &inlier)| gcp_residual(camera, &pose, o, !inlier))
        .collect();
    let sum_sq: f64 = residuals
        .iter()
        .filter(|r| !r.outlier)
        .filter_map(|r| r.residual_px)
        .map(|r| r.norm_squared())
        .sum();
    let dof = (2 * count).saturating_sub(6).max(1) as f64;
    Ok(PoseSolution {
        cam_from_world: pose,
        centre,
        centre_sigma_m: Vector3::new(
            covariance[(3, 3)].sqrt(),
            covariance[(4, 4)].sqrt(),
            covariance[(5, 5)].sqrt(),
        ),
        covariance,
        residuals,
        inliers: count,
        rms_px: (sum_sq / count as f64).sqrt(),
        sigma0: (refined.chi2 / dof).sqrt(),
        threshold_px: threshold,
        ransac_iterations: ransac.iterations,
        termination: refined.termination,
    })
}
