//! Georeferencing a reconstruction (pure): control points triangulated from their picks, a
//! robust similarity onto their surveyed positions (or onto camera centres from RTK), then a
//! bundle adjustment in which the control points are observed points with their survey σ as
//! priors and the camera centres, when given, priors with theirs. Check points stay out of every
//! fit: they are triangulated afterwards from their picks and reported in metres and pixels.

use nalgebra::{Matrix2x3, Matrix3, Vector2, Vector3};
use serde::Serialize;

use super::reconstruct::{Reconstruction, triangulate};
use crate::camera::{Camera, param};
use crate::geom::Rigid3;
use crate::geom::similarity::{ScaleMode, Similarity, fit_weighted};
use crate::optim::RobustLoss;
use crate::optim::ba::{
    BaSettings, CameraCovariance, CentrePrior, Observation, PointPrior, Priors, Problem, adjust,
    covariance,
};
use crate::optim::ba_camera::{BrownConrady, pose_params, rigid_pose};

/// Whether a surveyed point constrains the model or only checks it.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum PointRole {
    Control,
    Check,
}

/// A pixel pick of a surveyed point in one image of the reconstruction.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Pick {
    pub image: usize,
    pub uv: Vector2<f64>,
    pub sigma_px: f64,
}

/// A surveyed point (a GCP or check point) in the site frame, with its picks.
#[derive(Clone, Debug, PartialEq)]
pub struct GroundPoint {
    pub name: String,
    pub role: PointRole,
    /// Metres east, north, up in the site frame.
    pub position: Vector3<f64>,
    /// σ east, north, up, metres.
    pub sigma_m: Vector3<f64>,
    pub picks: Vec<Pick>,
}

/// A measured camera centre (RTK, a flight log) in the site frame.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct CentreMeasurement {
    pub image: usize,
    pub position: Vector3<f64>,
    pub sigma_m: Vector3<f64>,
}

#[derive(Clone, Debug)]
pub struct GeorefSettings {
    /// A control point further than this from the similarity fitted to the others is left out
    /// (a wrong name, pick or coordinate), metres.
    pub outlier_m: f64,
    /// Refine the focal lengths and `k1`, `k2` in the adjustment.
    pub refine_intrinsics: bool,
}

impl Default for GeorefSettings {
    fn default() -> Self {
        GeorefSettings {
            outlier_m: 0.5,
            refine_intrinsics: false,
        }
    }
}

/// One surveyed point's agreement with the georeferenced model.
#[derive(Clone, Debug, Serialize)]
pub struct PointResidual {
    pub name: String,
    pub role: PointRole,
    /// Surveyed position, site frame, metres.
    pub position_m: [f64; 3],
    /// Registered images it is picked in.
    pub images: usize,
    /// Model minus survey, east, north, up (metres): for a control point its adjusted position,
    /// for a check point its position triangulated from the picks (two images at least).
    pub residual_m: Option<[f64; 3]>,
    /// RMS distance of its picks from the projections of its surveyed position, pixels.
    pub rms_px: Option<f64>,
    /// Mean distance of its picks from the projections of the model's estimate of it (as
    /// Metashape reports a marker's error), pixels.
    pub estimate_mean_px: Option<f64>,
    pub sigma_m: [f64; 3],
}

/// RMS horizontal and vertical residuals of a set of points, metres.
#[derive(Clone, Copy, Debug, Serialize, PartialEq)]
pub struct Rms {
    pub points: usize,
    pub horizontal_m: f64,
    pub vertical_m: f64,
}

/// What georeferencing did and how well the survey agrees.
#[derive(Clone, Debug, Serialize)]
pub struct GeorefReport {
    /// What the first similarity was fitted to: `control points` or `camera centres`.
    pub placed_by: String,
    /// Points left out, with why.
    pub left_out: Vec<(String, String)>,
    pub points: Vec<PointResidual>,
    pub control_rms: Option<Rms>,
    pub check_rms: Option<Rms>,
    pub control_rms_px: Option<f64>,
    pub check_rms_px: Option<f64>,
    /// Mean distance of the control points' picks from the projections of their adjusted
    /// positions, over every pick, pixels (the paper's and Metashape's marker error).
    pub control_mean_px: Option<f64>,
    /// Adjusted camera centres against their measurements.
    pub centres_rms: Option<Rms>,
    /// The model's scale change: site metres per model unit.
    pub scale: f64,
    /// Per image (registered or not), the σ of its adjusted camera from the adjustment's
    /// covariance (every observation at its σ; a Monte Carlo spread agrees, see the tests),
    /// scaled by `sigma_scale`.
    pub camera_sigma: Vec<Option<CameraSigma>>,
    /// The factor the cameras' σ were scaled by so that they are never smaller than the
    /// surveyed points' and centres' residuals support: the RMS of those residuals in units of
    /// their σ, when above 1; else 1.
    pub sigma_scale: f64,
}

/// One camera's standard deviations after georeferencing.
#[derive(Clone, Copy, Debug, Serialize, PartialEq)]
pub struct CameraSigma {
    /// Of the centre, east, north, up, metres.
    pub centre_m: [f64; 3],
    /// Of the attitude: the largest σ of its rotation about any axis, degrees.
    pub rotation_deg: f64,
}

/// A camera's centre and rotation σ from the engine's covariance of its `[w, t]` parameters,
/// by a numerical Jacobian of the centre `−R(w)ᵀt` and of the rotation's change.
fn camera_sigma(q: &[f64; 6], cov: &nalgebra::Matrix6<f64>) -> CameraSigma {
    let at = |v: &[f64; 6]| -> (Vector3<f64>, nalgebra::Rotation3<f64>) {
        let p = rigid_pose(v);
        (p.centre(), p.rotation)
    };
    let (c0, r0) = at(q);
    let mut j = nalgebra::Matrix6::<f64>::zeros();
    for k in 0..6 {
        let h = 1e-6 * q[k].abs().max(1.0);
        let mut v = *q;
        v[k] += h;
        let (c, r) = at(&v);
        let dc = (c - c0) / h;
        let dr = crate::geom::so3::log(&(r * r0.inverse())) / h;
        for row in 0..3 {
            j[(row, k)] = dc[row];
            j[(row + 3, k)] = dr[row];
        }
    }
    let s = j * cov * j.transpose();
    let rot = s.fixed_view::<3, 3>(3, 3).into_owned().symmetric_eigen();
    CameraSigma {
        centre_m: [0, 1, 2].map(|k| s[(k, k)].max(0.0).sqrt()),
        rotation_deg: rot.eigenvalues.max().max(0.0).sqrt().to_degrees(),
    }
}

#[derive(Debug, thiserror::Error)]
pub enum GeorefError {
    #[error(
        "cannot place the model: {control} control point(s) are picked in two or more registered images (3 needed){centres}; pick more GCPs or give the camera centres"
    )]
    NotEnough { control: usize, centres: String },
    #[error("the georeferencing adjustment failed: {0}")]
    Adjustment(String),
    #[error(
        "the measured camera centres disagree with the control points: {left_out} of {centres} lie more than {threshold_m:.2} m (median {median_m:.1} m) from where the control points place their cameras ({names}); check that both files are in one CRS with one kind of height, and that the centres are named after their images"
    )]
    CentresDisagree {
        left_out: usize,
        centres: usize,
        threshold_m: f64,
        median_m: f64,
        names: String,
    },
}

/// Normalised image coordinates of a pixel.
fn normalised(camera: &Camera, uv: &Vector2<f64>) -> Option<Vector2<f64>> {
    let ray = camera.unproject(uv).ok()?;
    (ray.z > 1e-9).then(|| Vector2::new(ray.x / ray.z, ray.y / ray.z))
}

/// A point from its picks in registered images: linear triangulation, then Gauss–Newton on the
/// normalised reprojection errors. `None` with fewer than two usable picks.
pub fn triangulate_picks(
    camera: &Camera,
    poses: &[Option<Rigid3>],
    picks: &[Pick],
) -> Option<Vector3<f64>> {
    let rays: Vec<(Rigid3, Vector2<f64>)> = picks
        .iter()
        .filter_map(|p| Some((poses[p.image]?, normalised(camera, &p.uv)?)))
        .collect();
    let mut x = triangulate(&rays, 0.5)?;
    for _ in 0..10 {
        let mut h = Matrix3::zeros();
        let mut g = Vector3::zeros();
        for (pose, xy) in &rays {
            let p = pose.apply(&x);
            let j = Matrix2x3::new(1.0, 0.0, -p.x / p.z, 0.0, 1.0, -p.y / p.z) / p.z
                * pose.rotation.matrix();
            let r = Vector2::new(p.x / p.z, p.y / p.z) - xy;
            h += j.transpose() * j;
            g += j.transpose() * r;
        }
        let step = h.cholesky()?.solve(&g);
        x -= step;
        if step.norm() < 1e-12 * x.norm().max(1.0) {
            break;
        }
    }
    Some(x)
}

/// Moves a reconstruction by a similarity (points `X' = s R X + t`), poses with it.
pub fn transform(r: &mut Reconstruction, sim: &Similarity) {
    let rs = sim.rotation.to_rotation_matrix();
    for pose in r.poses.iter_mut().flatten() {
        // x_cam ∝ R_c X + t_c = R_c Rsᵀ (X' − t)/s + t_c.
        let rotation = pose.rotation * rs.inverse();
        let translation = sim.scale * pose.translation - rotation * sim.translation;
        *pose = Rigid3::new(rotation, translation);
    }
    for p in &mut r.points {
        p.xyz = sim.apply(&p.xyz);
    }
}

/// The similarity from the model onto the site with the most control points within
/// `outlier_m` (MSAC over triples), refitted on those; and which points it kept.
pub(crate) fn robust_similarity(
    model: &[Vector3<f64>],
    site: &[Vector3<f64>],
    outlier_m: f64,
) -> Option<(Similarity, Vec<bool>)> {
    let n = model.len();
    let score = |s: &Similarity| -> f64 {
        model
            .iter()
            .zip(site)
            .map(|(m, x)| (s.apply(m) - x).norm_squared().min(outlier_m * outlier_m))
            .sum()
    };
    let mut best: Option<(f64, Similarity)> = None;
    // Every triple while they are few (30 points: 4060), then a fixed stride through them.
    let total = n * (n - 1) * (n - 2) / 6;
    let stride = total.div_ceil(5000).max(1);
    let mut k = 0usize;
    for a in 0..n {
        for b in a + 1..n {
            for c in b + 1..n {
                k += 1;
                if !k.is_multiple_of(stride) {
                    continue;
                }
                let src = [model[a], model[b], model[c]];
                let dst = [site[a], site[b], site[c]];
                let Ok(s) = fit_weighted(&src, &dst, &[1.0; 3], ScaleMode::Free) else {
                    continue;
                };
                let cost = score(&s);
                if best.as_ref().is_none_or(|(c, _)| cost < *c) {
                    best = Some((cost, s));
                }
            }
        }
    }
    let (_, mut sim) = best?;
    let mut keep = vec![false; n];
    for _ in 0..3 {
        keep = (0..n)
            .map(|i| (sim.apply(&model[i]) - site[i]).norm() <= outlier_m)
            .collect();
        let (src, dst): (Vec<_>, Vec<_>) = (0..n)
            .filter(|&i| keep[i])
            .map(|i| (model[i], site[i]))
            .unzip();
        sim = fit_weighted(&src, &dst, &vec![1.0; src.len()], ScaleMode::Free).ok()?;
    }
    Some((sim, keep))
}

fn rms_of(residuals: &[[f64; 3]]) -> Option<Rms> {
    if residuals.is_empty() {
        return None;
    }
    let n = residuals.len() as f64;
    Some(Rms {
        points: residuals.len(),
        horizontal_m: (residuals
            .iter()
            .map(|r| r[0] * r[0] + r[1] * r[1])
            .sum::<f64>()
            / n)
            .sqrt(),
        vertical_m: (residuals.iter().map(|r| r[2] * r[2]).sum::<f64>() / n).sqrt(),
    })
}

/// Each pick's offset from the projection of `x` in its image, pixels (picks in images without
/// a pose, or where `x` does not project, left out).
fn pick_offsets<'a>(
    camera: &'a Camera,
    poses: &'a [Option<Rigid3>],
    picks: &'a [Pick],
    x: &'a Vector3<f64>,
) -> impl Iterator<Item = Vector2<f64>> + 'a {
    picks.iter().filter_map(|p| {
        let uv = camera.project(&poses[p.image]?.apply(x)).ok()?;
        Some(uv - p.uv)
    })
}

/// The picks' distances from the projections of `x`, pixels.
fn pick_errors_px(
    camera: &Camera,
    poses: &[Option<Rigid3>],
    picks: &[Pick],
    x: &Vector3<f64>,
) -> Vec<f64> {
    pick_offsets(camera, poses, picks, x)
        .map(|d| d.norm())
        .collect()
}

/// RMS of the picks' distances from the projections of `x`.
fn pick_rms_px(
    camera: &Camera,
    poses: &[Option<Rigid3>],
    picks: &[Pick],
    x: &Vector3<f64>,
) -> Option<f64> {
    let d: Vec<f64> = pick_offsets(camera, poses, picks, x)
        .map(|d| d.norm_squared())
        .collect();
    (!d.is_empty()).then(|| (d.iter().sum::<f64>() / d.len() as f64).sqrt())
}

/// How far a measured camera centre may lie from where the placement puts its camera before it
/// is left out, metres: the control points' outlier distance, or five of its σ if larger.
fn centre_threshold_m(c: &CentreMeasurement, s: &GeorefSettings) -> f64 {
    s.outlier_m.max(5.0 * c.sigma_m.norm())
}

/// Places `r` (features `pixels`, their relative σ `sigmas`) in the site frame of `points` and adjusts it with them and
/// the camera-centre measurements `centres` (`names`: the images', for the report); `r` is
/// changed only when this succeeds. A control point or a centre that disagrees with the others is
/// left out and listed; centres that disagree with the control points as a whole are an error.
pub fn georeference(
    r: &mut Reconstruction,
    pixels: &[Vec<Vector2<f64>>],
    sigmas: Option<&[Vec<f64>]>,
    points: &[GroundPoint],
    centres: &[CentreMeasurement],
    names: &[String],
    s: &GeorefSettings,
) -> Result<GeorefReport, GeorefError> {
    let mut left_out = Vec::new();
    let registered = |i: usize| r.poses.get(i).is_some_and(Option::is_some);
    // Picks in registered images only.
    let points: Vec<GroundPoint> = points
        .iter()
        .map(|p| GroundPoint {
            picks: p
                .picks
                .iter()
                .copied()
                .filter(|k| registered(k.image))
                .collect(),
            ..p.clone()
        })
        .collect();
    let centres: Vec<CentreMeasurement> = centres
        .iter()
        .copied()
        .filter(|c| registered(c.image))
        .collect();
    let name_of = |i: usize| {
        names
            .get(i)
            .cloned()
            .unwrap_or_else(|| format!("image {i}"))
    };

    // 1. The first placement.
    let placement = first_placement(r, &points, &centres, s, &mut left_out)?;
    let mut model = r.clone();
    transform(&mut model, &placement.sim);
    let centres = agreeing_centres(
        &model,
        centres,
        placement.placed_by,
        s,
        &name_of,
        &mut left_out,
    )?;

    // 2. The adjustment.
    let images: Vec<usize> = (0..model.poses.len()).filter(|&i| registered(i)).collect();
    let adjusted = adjust_placed(
        &mut model,
        &AdjustmentInputs {
            pixels,
            sigmas,
            points: &points,
            rejected: &placement.rejected,
            centres: &centres,
            images: &images,
        },
        s,
        &mut left_out,
    )?;

    // 3. Residuals.
    let residuals = point_residuals(
        &model,
        &adjusted.problem,
        &points,
        &placement.rejected,
        &adjusted.gcp_slot,
        &mut left_out,
    );
    let centre_residuals: Vec<[f64; 3]> = centres
        .iter()
        .map(|c| (model.poses[c.image].expect("registered").centre() - c.position).into())
        .collect();
    let report = GeorefReport {
        placed_by: placement.placed_by.into(),
        left_out,
        control_rms: rms_of(&residuals_of_role(&residuals, PointRole::Control)),
        check_rms: rms_of(&residuals_of_role(&residuals, PointRole::Check)),
        control_rms_px: px_of_role(&residuals, PointRole::Control),
        check_rms_px: px_of_role(&residuals, PointRole::Check),
        control_mean_px: control_mean_px(&residuals),
        centres_rms: rms_of(&centre_residuals),
        points: residuals,
        scale: placement.sim.scale,
        camera_sigma: adjusted.camera_sigma,
        sigma_scale: adjusted.sigma_scale,
    };
    *r = model;
    Ok(report)
}

/// The first placement of a model in the site frame, and which control points it left out.
struct Placement {
    sim: Similarity,
    /// "control points" or "camera centres".
    placed_by: &'static str,
    /// Per surveyed point: left out by the placement.
    rejected: Vec<bool>,
}

/// A robust similarity from the triangulated control points (three or more), else from the
/// measured camera centres; control points it leaves out are listed in `left_out`.
fn first_placement(
    r: &Reconstruction,
    points: &[GroundPoint],
    centres: &[CentreMeasurement],
    s: &GeorefSettings,
    left_out: &mut Vec<(String, String)>,
) -> Result<Placement, GeorefError> {
    let mut control_model = Vec::new();
    let mut control_site = Vec::new();
    let mut control_index = Vec::new();
    for (k, p) in points.iter().enumerate() {
        if p.role != PointRole::Control {
            continue;
        }
        if let Some(x) = triangulate_picks(&r.camera, &r.poses, &p.picks) {
            control_model.push(x);
            control_site.push(p.position);
            control_index.push(k);
        }
    }
    let mut rejected = vec![false; points.len()];
    if control_model.len() >= 3 {
        let (sim, keep) = robust_similarity(&control_model, &control_site, s.outlier_m)
            .ok_or_else(|| GeorefError::NotEnough {
                control: control_model.len(),
                centres: " (and they are collinear)".into(),
            })?;
        for (j, &k) in control_index.iter().enumerate() {
            if !keep[j] {
                rejected[k] = true;
                left_out.push((
                    points[k].name.clone(),
                    format!(
                        "{:.2} m from where the other control points place it: a wrong name, pick or coordinate?",
                        (sim.apply(&control_model[j]) - control_site[j]).norm()
                    ),
                ));
            }
        }
        return Ok(Placement {
            sim,
            placed_by: "control points",
            rejected,
        });
    }
    if centres.len() < 3 {
        return Err(GeorefError::NotEnough {
            control: control_model.len(),
            centres: format!(
                " and {} registered image(s) have a measured centre",
                centres.len()
            ),
        });
    }
    let src: Vec<Vector3<f64>> = centres
        .iter()
        .map(|c| r.poses[c.image].expect("registered").centre())
        .collect();
    let dst: Vec<Vector3<f64>> = centres.iter().map(|c| c.position).collect();
    let collinear = || GeorefError::NotEnough {
        control: control_model.len(),
        centres: format!(", and the {} camera centres are collinear", centres.len()),
    };
    let mut thresholds: Vec<f64> = centres.iter().map(|c| centre_threshold_m(c, s)).collect();
    thresholds.sort_by(f64::total_cmp);
    let (sim, keep) =
        robust_similarity(&src, &dst, thresholds[thresholds.len() / 2]).ok_or_else(collinear)?;
    if keep.iter().filter(|k| **k).count() < 3 {
        return Err(collinear());
    }
    Ok(Placement {
        sim,
        placed_by: "camera centres",
        rejected,
    })
}

/// The measured centres against the placed `model`: one far off is left out (and listed);
/// most of them far off means the centres and the control points are not of one frame.
fn agreeing_centres(
    model: &Reconstruction,
    centres: Vec<CentreMeasurement>,
    placed_by: &str,
    s: &GeorefSettings,
    name_of: &dyn Fn(usize) -> String,
    left_out: &mut Vec<(String, String)>,
) -> Result<Vec<CentreMeasurement>, GeorefError> {
    let far: Vec<(usize, f64)> = centres
        .iter()
        .enumerate()
        .filter_map(|(k, c)| {
            let d = (model.poses[c.image].expect("registered").centre() - c.position).norm();
            (!(d <= centre_threshold_m(c, s))).then_some((k, d))
        })
        .collect();
    if placed_by == "control points" && centres.len() >= 2 && 2 * far.len() > centres.len() {
        let mut d: Vec<f64> = far.iter().map(|f| f.1).collect();
        d.sort_by(f64::total_cmp);
        let shown: Vec<String> = far
            .iter()
            .take(5)
            .map(|&(k, _)| name_of(centres[k].image))
            .collect();
        return Err(GeorefError::CentresDisagree {
            left_out: far.len(),
            centres: centres.len(),
            threshold_m: centre_threshold_m(&centres[far[0].0], s),
            median_m: d[d.len() / 2],
            names: shown.join(", ") + if far.len() > 5 { ", ..." } else { "" },
        });
    }
    for &(k, d) in &far {
        left_out.push((
            name_of(centres[k].image),
            format!(
                "its measured centre is {d:.2} m from where the {placed_by} place its camera: a wrong name or position?"
            ),
        ));
    }
    let far_set: Vec<usize> = far.iter().map(|f| f.0).collect();
    Ok(centres
        .into_iter()
        .enumerate()
        .filter(|(k, _)| !far_set.contains(k))
        .map(|(_, c)| c)
        .collect())
}

/// The adjusted problem, where each control point went in it, and the cameras' σ.
struct Adjusted {
    problem: Problem<{ crate::camera::N_PARAMS }>,
    /// Per surveyed point: its index among the problem's points, for a control point in it.
    gcp_slot: Vec<Option<usize>>,
    camera_sigma: Vec<Option<CameraSigma>>,
    sigma_scale: f64,
}

/// What the adjustment of a placed model observes.
struct AdjustmentInputs<'a> {
    /// Per image, its features' pixels and (when known) their relative σ.
    pixels: &'a [Vec<Vector2<f64>>],
    sigmas: Option<&'a [Vec<f64>]>,
    /// The surveyed points, and which of them the placement left out.
    points: &'a [GroundPoint],
    rejected: &'a [bool],
    /// The measured centres that agree with the placement.
    centres: &'a [CentreMeasurement],
    /// The registered images.
    images: &'a [usize],
}

/// Adjusts the placed `model` with the control points and the centres of `inputs` as priors
/// and writes the result back into it.
fn adjust_placed(
    model: &mut Reconstruction,
    inputs: &AdjustmentInputs,
    s: &GeorefSettings,
    left_out: &mut Vec<(String, String)>,
) -> Result<Adjusted, GeorefError> {
    let (mut problem, priors, gcp_slot) = adjustment_problem(model, inputs, left_out);
    problem.fixed_intrinsics = vec![[true; crate::camera::N_PARAMS]];
    if s.refine_intrinsics {
        for k in [param::FX, param::FY, param::K1, param::K2] {
            problem.fixed_intrinsics[0][k] = false;
        }
    }
    for loss in [RobustLoss::Huber(2.0), RobustLoss::Squared] {
        let settings = BaSettings {
            loss,
            max_iterations: 100,
            max_memory_bytes: super::adjustment_memory_limit(),
            ..BaSettings::default()
        };
        adjust(&mut problem, &BrownConrady, &priors, &settings)
            .map_err(|e| GeorefError::Adjustment(e.to_string()))?;
    }
    // σ as stated: each observation's σ is its own (the features' from their residuals).
    let cov: Option<CameraCovariance> = covariance(
        &problem,
        &BrownConrady,
        &priors,
        RobustLoss::Squared,
        Some(1.0),
    )
    .ok();
    let sigma_scale = prior_sigma_scale(&problem, &priors);
    let mut sigmas_out = vec![None; model.poses.len()];
    for (k, &i) in inputs.images.iter().enumerate() {
        model.poses[i] = Some(rigid_pose(&problem.poses[k]));
        if let Some(c) = &cov {
            let block = nalgebra::Matrix6::from_iterator(c.pose(k).iter().copied());
            let mut sigma = camera_sigma(&problem.poses[k], &block);
            sigma.centre_m = sigma.centre_m.map(|v| v * sigma_scale);
            sigma.rotation_deg *= sigma_scale;
            sigmas_out[i] = Some(sigma);
        }
    }
    model.camera.set_params(&problem.intrinsics[0]);
    for (k, p) in model.points.iter_mut().enumerate() {
        p.xyz = Vector3::from(problem.points[k]);
    }
    model.mean_reprojection_px = model.mean_reprojection(inputs.pixels);
    Ok(Adjusted {
        problem,
        gcp_slot,
        camera_sigma: sigmas_out,
        sigma_scale,
    })
}

/// The adjustment as a problem: the model's points, then the control points picked in a
/// registered image (one pick is enough: the survey holds the point), with priors; the control
/// points' slots among the problem's points.
fn adjustment_problem(
    model: &Reconstruction,
    inputs: &AdjustmentInputs,
    left_out: &mut Vec<(String, String)>,
) -> (
    Problem<{ crate::camera::N_PARAMS }>,
    Priors,
    Vec<Option<usize>>,
) {
    let AdjustmentInputs {
        pixels,
        sigmas,
        points,
        rejected,
        centres,
        images,
    } = *inputs;
    let mut slot = vec![usize::MAX; model.poses.len()];
    for (k, &i) in images.iter().enumerate() {
        slot[i] = k;
    }
    let mut observations = Vec::new();
    let mut sigma_px = Vec::new();
    // The features' σ per coordinate: their relative σ times a unit from their RMS
    // standardised reprojection error (at least 0.1 px).
    let relative = |i: usize, kp: usize| sigmas.map_or(1.0, |s| s[i][kp]);
    let (mut sum2, mut count) = (0.0, 0usize);
    for p in &model.points {
        for &(i, kp) in &p.observations {
            let pose = model.poses[i].expect("registered");
            if let Ok(uv) = model.camera.project(&pose.apply(&p.xyz)) {
                sum2 += (uv - pixels[i][kp]).norm_squared() / relative(i, kp).powi(2);
                count += 1;
            }
        }
    }
    let unit_sigma = (sum2 / (2 * count.max(1)) as f64).sqrt();
    for (k, p) in model.points.iter().enumerate() {
        for &(i, kp) in &p.observations {
            let xy = pixels[i][kp];
            observations.push(Observation {
                camera: slot[i],
                point: k,
                xy: [xy.x, xy.y],
            });
            sigma_px.push((unit_sigma * relative(i, kp)).max(0.1));
        }
    }
    let mut ba_points: Vec<[f64; 3]> = model.points.iter().map(|p| p.xyz.into()).collect();
    let mut priors = Priors::default();
    let mut gcp_slot = vec![None; points.len()];
    for (k, p) in points.iter().enumerate() {
        if p.role != PointRole::Control || rejected[k] {
            continue;
        }
        if p.picks.is_empty() {
            left_out.push((p.name.clone(), "not picked in any registered image".into()));
            continue;
        }
        let at = ba_points.len();
        gcp_slot[k] = Some(at);
        ba_points.push(p.position.into());
        for pick in &p.picks {
            observations.push(Observation {
                camera: slot[pick.image],
                point: at,
                xy: [pick.uv.x, pick.uv.y],
            });
            sigma_px.push(pick.sigma_px);
        }
        priors
            .points
            .push(PointPrior::new(at, p.position.into(), p.sigma_m.into()));
    }
    for c in centres {
        priors.centres.push(CentrePrior {
            camera: slot[c.image],
            position: c.position.into(),
            sigma: c.sigma_m.into(),
        });
    }
    let mut problem = Problem::new(
        images
            .iter()
            .map(|&i| pose_params(&model.poses[i].expect("registered")))
            .collect(),
        vec![model.camera.params()],
        vec![0; images.len()],
        ba_points,
        observations,
    );
    problem.sigma_px = sigma_px;
    (problem, priors, gcp_slot)
}

/// The surveyed points' and the centres' residuals in units of their σ, as an RMS of at least
/// one: when they spread more than their σ say, so do the cameras.
fn prior_sigma_scale(problem: &Problem<{ crate::camera::N_PARAMS }>, priors: &Priors) -> f64 {
    let (mut z2, mut nz) = (0.0, 0usize);
    for p in &priors.points {
        let x = Vector3::from(problem.points[p.point]);
        let d = x - Vector3::from(p.position);
        z2 += (p.sqrt_information * d).norm_squared();
        nz += 3;
    }
    for c in &priors.centres {
        let centre = rigid_pose(&problem.poses[c.camera]).centre();
        let d = centre - Vector3::from(c.position);
        z2 += d.component_div(&Vector3::from(c.sigma)).norm_squared();
        nz += 3;
    }
    if nz > 0 {
        (z2 / nz as f64).sqrt().max(1.0)
    } else {
        1.0
    }
}

/// Every surveyed point's residual after the adjustment: a control point's from its adjusted
/// position, a check point's triangulated from its picks; an unpicked check point is listed in
/// `left_out`.
fn point_residuals(
    model: &Reconstruction,
    problem: &Problem<{ crate::camera::N_PARAMS }>,
    points: &[GroundPoint],
    rejected: &[bool],
    gcp_slot: &[Option<usize>],
    left_out: &mut Vec<(String, String)>,
) -> Vec<PointResidual> {
    let mut residuals = Vec::new();
    for (k, p) in points.iter().enumerate() {
        if rejected[k] {
            continue;
        }
        let estimate = match (p.role, gcp_slot[k]) {
            (PointRole::Control, Some(at)) => Some(Vector3::from(problem.points[at])),
            (PointRole::Control, None) => None,
            (PointRole::Check, _) => triangulate_picks(&model.camera, &model.poses, &p.picks),
        };
        if p.role == PointRole::Check && p.picks.is_empty() {
            left_out.push((p.name.clone(), "not picked in any registered image".into()));
            continue;
        }
        if p.role == PointRole::Control && estimate.is_none() {
            continue;
        }
        residuals.push(PointResidual {
            name: p.name.clone(),
            role: p.role,
            position_m: p.position.into(),
            images: p.picks.len(),
            residual_m: estimate.map(|x| (x - p.position).into()),
            rms_px: pick_rms_px(&model.camera, &model.poses, &p.picks, &p.position),
            estimate_mean_px: estimate.and_then(|x| {
                let e = pick_errors_px(&model.camera, &model.poses, &p.picks, &x);
                (!e.is_empty()).then(|| e.iter().sum::<f64>() / e.len() as f64)
            }),
            sigma_m: p.sigma_m.into(),
        });
    }
    residuals
}

/// The residuals, metres, of the points of one role that have one.
fn residuals_of_role(residuals: &[PointResidual], role: PointRole) -> Vec<[f64; 3]> {
    residuals
        .iter()
        .filter(|x| x.role == role)
        .filter_map(|x| x.residual_m)
        .collect()
}

/// RMS, pixels, of the picks of the points of one role against their surveyed positions.
fn px_of_role(residuals: &[PointResidual], role: PointRole) -> Option<f64> {
    let (mut s2, mut m) = (0.0, 0usize);
    for x in residuals.iter().filter(|x| x.role == role) {
        if let Some(px) = x.rms_px {
            s2 += px * px * x.images as f64;
            m += x.images;
        }
    }
    (m > 0).then(|| (s2 / m as f64).sqrt())
}

/// Mean distance, pixels, of the control points' picks from their adjusted positions.
fn control_mean_px(residuals: &[PointResidual]) -> Option<f64> {
    let (mut sum, mut m) = (0.0, 0usize);
    for x in residuals.iter().filter(|x| x.role == PointRole::Control) {
        if let Some(px) = x.estimate_mean_px {
            sum += px * x.images as f64;
            m += x.images;
        }
    }
    (m > 0).then(|| sum / m as f64)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::sfm::reconstruct::ModelPoint;
    use crate::testing::Uniform;
    use nalgebra::{Rotation3, UnitQuaternion};

    /// Georeferencing with the default settings, every keypoint alike.
    fn place(
        model: &mut Reconstruction,
        pixels: &[Vec<Vector2<f64>>],
        points: &[GroundPoint],
        centres: &[CentreMeasurement],
    ) -> Result<GeorefReport, GeorefError> {
        georeference(
            model,
            pixels,
            None,
            points,
            centres,
            &[],
            &GeorefSettings::default(),
        )
    }

    /// A nadir block of 3 × 3 cameras 30 m over rough ground (1.25 cm per pixel), its points and observations, in
    /// the site frame; and the same reconstruction moved by a similarity (the model frame).
    fn block(
        noise_px: f64,
        rng: &mut Uniform,
    ) -> (Reconstruction, Reconstruction, Vec<Vec<Vector2<f64>>>) {
        let camera = Camera::pinhole(2400.0, 2400.0, 1600.0, 1200.0).with_image_size(3200, 2400);
        let down = Rotation3::from_matrix_unchecked(Matrix3::new(
            1.0, 0.0, 0.0, 0.0, -1.0, 0.0, 0.0, 0.0, -1.0,
        ));
        let mut poses = Vec::new();
        for a in 0..3 {
            for b in 0..3 {
                let c = Vector3::new(10.0 * f64::from(a), 8.0 * f64::from(b), 30.0);
                poses.push(Some(Rigid3::new(down, -(down * c))));
            }
        }
        let mut pixels = vec![Vec::new(); poses.len()];
        let mut pts = Vec::new();
        for _ in 0..600 {
            let x = Vector3::new(
                rng.range(-10.0, 30.0),
                rng.range(-10.0, 26.0),
                rng.range(-1.0, 1.0),
            );
            let mut observations = Vec::new();
            for (i, pose) in poses.iter().enumerate() {
                if let Ok(uv) = camera.project(&pose.expect("set").apply(&x))
                    && uv.x > 0.0
                    && uv.y > 0.0
                    && uv.x < 3199.0
                    && uv.y < 2399.0
                {
                    let noisy = uv + Vector2::new(rng.normal(), rng.normal()) * noise_px;
                    observations.push((i, pixels[i].len()));
                    pixels[i].push(noisy);
                }
            }
            if observations.len() >= 2 {
                pts.push(ModelPoint {
                    xyz: x,
                    observations,
                });
            }
        }
        let truth = Reconstruction {
            poses,
            points: pts,
            mean_reprojection_px: 0.0,
            camera,
            initial_pair: (0, 1),
            start: Default::default(),
            principal_point: None,
            other_models: Vec::new(),
            adjustments: Default::default(),
        };
        let mut model = truth.clone();
        let sim = Similarity {
            scale: 0.05,
            rotation: UnitQuaternion::from_euler_angles(0.3, -0.2, 1.1),
            translation: Vector3::new(1.0, 2.0, -3.0),
        };
        transform(&mut model, &sim);
        (truth, model, pixels)
    }

    fn picks_of(
        truth: &Reconstruction,
        x: &Vector3<f64>,
        noise_px: f64,
        rng: &mut Uniform,
    ) -> Vec<Pick> {
        truth
            .poses
            .iter()
            .enumerate()
            .filter_map(|(i, p)| {
                let uv = truth.camera.project(&p.expect("set").apply(x)).ok()?;
                (uv.x > 0.0 && uv.y > 0.0 && uv.x < 3199.0 && uv.y < 2399.0).then(|| Pick {
                    image: i,
                    uv: uv + Vector2::new(rng.normal(), rng.normal()) * noise_px,
                    sigma_px: noise_px.max(0.1),
                })
            })
            .collect()
    }

    #[test]
    fn control_points_place_the_model_and_a_wrong_one_is_left_out() {
        let mut rng = Uniform::new(2);
        let (truth, mut model, pixels) = block(0.3, &mut rng);
        let sites = [
            (-5.0, -5.0),
            (25.0, -5.0),
            (-5.0, 21.0),
            (25.0, 21.0),
            (10.0, 8.0),
            (0.0, 15.0),
            (10.0, -6.0),
            (10.0, 22.0),
        ];
        let mut points: Vec<GroundPoint> = sites
            .iter()
            .enumerate()
            .map(|(k, &(e, n))| {
                let x = Vector3::new(e, n, 0.2);
                GroundPoint {
                    name: format!("G{k}"),
                    role: if k == 5 {
                        PointRole::Check
                    } else {
                        PointRole::Control
                    },
                    position: x,
                    sigma_m: Vector3::new(0.01, 0.01, 0.02),
                    picks: picks_of(&truth, &x, 0.5, &mut rng),
                }
            })
            .collect();
        // G4's coordinate is 3 m off (a typing error).
        points[4].position.x += 3.0;
        let report = place(&mut model, &pixels, &points, &[]).unwrap();
        assert_eq!(report.placed_by, "control points");
        assert_eq!(report.left_out.len(), 1, "{:?}", report.left_out);
        assert_eq!(report.left_out[0].0, "G4");
        for (m, t) in model.poses.iter().zip(&truth.poses) {
            let (m, t) = (m.unwrap(), t.unwrap());
            assert!(
                (m.centre() - t.centre()).norm() < 0.03,
                "{} vs {}",
                m.centre(),
                t.centre()
            );
            let angle = (m.rotation * t.rotation.inverse()).angle().to_degrees();
            assert!(angle < 0.05, "{angle}°");
        }
        let check = report.check_rms.unwrap();
        assert_eq!(check.points, 1);
        assert!(
            check.horizontal_m < 0.03 && check.vertical_m < 0.06,
            "{check:?}"
        );
        assert!(report.check_rms_px.unwrap() < 2.0);
        assert!(report.control_rms.unwrap().horizontal_m < 0.02);
    }

    /// The σ of the cameras from the adjustment's covariance against the spread of 150
    /// georeferencings with fresh feature, pick and survey noise.
    #[test]
    fn camera_sigma_agrees_with_a_monte_carlo_spread() {
        let sites = [
            (-5.0, -5.0),
            (25.0, -5.0),
            (-5.0, 21.0),
            (25.0, 21.0),
            (10.0, 8.0),
        ];
        let sigma = Vector3::new(0.01, 0.01, 0.02);
        let trials = 150;
        let mut centres: Vec<Vector3<f64>> = Vec::new();
        let mut predicted = Vec::new();
        let mut rotations: Vec<Vector3<f64>> = Vec::new();
        // One scene (the same points), fresh noise each trial.
        let mut scene_rng = Uniform::new(21);
        let (truth, _, _) = block(0.0, &mut scene_rng);
        let mut rng = Uniform::new(99);
        for _ in 0..trials {
            let mut pixels = vec![Vec::new(); truth.poses.len()];
            let mut pts = Vec::new();
            for p in &truth.points {
                let mut observations = Vec::new();
                for &(i, _) in &p.observations {
                    let uv = truth
                        .camera
                        .project(&truth.poses[i].unwrap().apply(&p.xyz))
                        .unwrap();
                    observations.push((i, pixels[i].len()));
                    pixels[i].push(uv + Vector2::new(rng.normal(), rng.normal()) * 0.3);
                }
                pts.push(ModelPoint {
                    xyz: p.xyz,
                    observations,
                });
            }
            let mut model = Reconstruction {
                points: pts,
                ..truth.clone()
            };
            let points: Vec<GroundPoint> = sites
                .iter()
                .enumerate()
                .map(|(k, &(e, n))| {
                    let x = Vector3::new(e, n, 0.2);
                    GroundPoint {
                        name: format!("G{k}"),
                        role: PointRole::Control,
                        position: x + Vector3::new(rng.normal(), rng.normal(), rng.normal())
                            .component_mul(&sigma),
                        sigma_m: sigma,
                        picks: picks_of(&truth, &x, 0.5, &mut rng),
                    }
                })
                .collect();
            let report = place(&mut model, &pixels, &points, &[]).unwrap();
            centres.push(model.poses[4].unwrap().centre());
            rotations.push(crate::geom::so3::log(
                &(model.poses[4].unwrap().rotation * truth.poses[4].unwrap().rotation.inverse()),
            ));
            predicted.push(report.camera_sigma[4].unwrap());
        }
        let n = trials as f64;
        let mean = centres.iter().sum::<Vector3<f64>>() / n;
        for k in 0..3 {
            let sd = (centres
                .iter()
                .map(|c| (c[k] - mean[k]).powi(2))
                .sum::<f64>()
                / (n - 1.0))
                .sqrt();
            let want = predicted.iter().map(|p| p.centre_m[k]).sum::<f64>() / n;
            // 150 trials: the sample σ within ±18 % (3σ) of the true one.
            assert!(
                (sd / want - 1.0).abs() < 0.18,
                "axis {k}: Monte Carlo {sd:.4} m, predicted {want:.4} m"
            );
        }
        // The attitude: the largest σ of the rotation errors' spread.
        let mean_r = rotations.iter().sum::<Vector3<f64>>() / n;
        let cov_r = rotations
            .iter()
            .map(|r| (r - mean_r) * (r - mean_r).transpose())
            .sum::<Matrix3<f64>>()
            / (n - 1.0);
        let sd = cov_r
            .symmetric_eigen()
            .eigenvalues
            .max()
            .sqrt()
            .to_degrees();
        let want = predicted.iter().map(|p| p.rotation_deg).sum::<f64>() / n;
        assert!(
            (sd / want - 1.0).abs() < 0.25,
            "rotation: Monte Carlo {sd:.5}°, predicted {want:.5}°"
        );
    }

    #[test]
    fn camera_centres_alone_place_the_model() {
        let mut rng = Uniform::new(9);
        let (truth, mut model, pixels) = block(0.3, &mut rng);
        let centres: Vec<CentreMeasurement> = truth
            .poses
            .iter()
            .enumerate()
            .map(|(i, p)| CentreMeasurement {
                image: i,
                position: p.unwrap().centre()
                    + Vector3::new(rng.normal(), rng.normal(), 2.0 * rng.normal()) * 0.01,
                sigma_m: Vector3::new(0.01, 0.01, 0.02),
            })
            .collect();
        let report = place(&mut model, &pixels, &[], &centres).unwrap();
        assert_eq!(report.placed_by, "camera centres");
        let c = report.centres_rms.unwrap();
        assert_eq!(c.points, 9);
        for (m, t) in model.poses.iter().zip(&truth.poses) {
            assert!((m.unwrap().centre() - t.unwrap().centre()).norm() < 0.04);
        }
        assert!(report.check_rms.is_none());
    }

    #[test]
    fn too_few_points_is_an_error_and_leaves_the_model_unchanged() {
        let mut rng = Uniform::new(3);
        let (truth, mut model, pixels) = block(0.3, &mut rng);
        let before = model.clone();
        let x = Vector3::new(0.0, 0.0, 0.0);
        let points = vec![GroundPoint {
            name: "G1".into(),
            role: PointRole::Control,
            position: x,
            sigma_m: Vector3::new(0.01, 0.01, 0.02),
            picks: picks_of(&truth, &x, 0.5, &mut rng),
        }];
        let e = place(&mut model, &pixels, &points, &[]).unwrap_err();
        assert!(e.to_string().contains("1 control point(s)"), "{e}");
        assert_eq!(model.poses, before.poses);
    }
}
