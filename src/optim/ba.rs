//! Bundle adjustment (pure): Levenberg–Marquardt over cameras and points with the Schur
//! complement on the points, following Ceres Solver's trust-region strategy so that the two
//! reach the same cost on the same problem:
//!
//! - the Jacobian's columns are scaled by `1 / (1 + ‖column‖)`, computed once at the start;
//! - the step solves `(JᵀJ + D/Δ) y = −Jᵀr` in the scaled variables, `D` the diagonal of `JᵀJ`
//!   clamped to `[1e-6, 1e32]` (kept after a rejected step), `Δ` the trust-region radius;
//! - the points are eliminated (each point's 3×3 block), the reduced camera system is solved by
//!   dense Cholesky or by preconditioned conjugate gradients, and the points follow by
//!   back-substitution;
//! - a step is accepted when the actual over the model's decrease exceeds 1e-3; then
//!   `Δ ← Δ / max(1/3, 1 − (2ρ − 1)³)`, else `Δ ← Δ / ν`, `ν ← 2ν`;
//! - it stops on the function (`|Δcost| ≤ tol·cost`), gradient (`‖g‖∞ ≤ tol`) and parameter
//!   (`‖δ‖ ≤ tol·(‖x‖ + tol)`) tolerances, a radius below 1e-32, or the iteration limit.
//!
//! The camera side of a [`Problem`] is a pose per image (`cam_from_world`, angle-axis and
//! translation) and intrinsics per group of images (one group for a single camera, one per image
//! for self-calibrating every image), any parameter of either held fixed. The camera model is a
//! [`Projection`] with `M` intrinsic parameters: the BAL camera (`M = 3`, in `bal`) or
//! geostride's Brown–Conrady camera (`M = 13`, in `ba_camera`).
//!
//! Residuals and Jacobians are evaluated in parallel (rayon). Robust losses weight each
//! observation by `√ρ'` (exact gradient, Gauss–Newton Hessian of the reweighted problem).

use std::time::Instant;

use nalgebra::{DMatrix, DVector, Matrix3, SMatrix, SVector, Vector2, Vector3};
use rayon::prelude::*;
use serde::Serialize;
use thiserror::Error;

use super::RobustLoss;
use super::bal::{BalIntrinsics, BalObservation, BalProblem, left_jacobian, rotation};

/// One image measurement: image `camera` sees point `point` at `xy` (pixels).
pub type Observation = BalObservation;

type Mat6 = SMatrix<f64, 6, 6>;
type Vec6 = SVector<f64, 6>;
type Mat63 = SMatrix<f64, 6, 3>;
type Mat26 = SMatrix<f64, 2, 6>;
type Mat23 = SMatrix<f64, 2, 3>;
type Mat36 = SMatrix<f64, 3, 6>;
/// An observation's residual and its Jacobians (pose, intrinsics, point).
type Linearised<const M: usize> = (Vector2<f64>, Mat26, SMatrix<f64, 2, M>, Mat23);

/// A camera model's intrinsic part: a point in the camera frame to pixels, with the Jacobians
/// with respect to the point and to the `M` intrinsic parameters.
pub trait Projection<const M: usize>: Sync {
    /// `None` where the model cannot project the point (behind the camera, beyond the fold of
    /// the distortion).
    fn project(&self, intrinsics: &[f64; M], p_cam: &Vector3<f64>) -> Option<Vector2<f64>>;
    fn project_with_jacobians(
        &self,
        intrinsics: &[f64; M],
        p_cam: &Vector3<f64>,
    ) -> Option<(Vector2<f64>, Mat23, SMatrix<f64, 2, M>)>;
}

/// A bundle adjustment problem with `M` intrinsic parameters per camera.
#[derive(Clone, Debug, PartialEq)]
pub struct Problem<const M: usize> {
    /// Per image, `cam_from_world` as `[wx, wy, wz, tx, ty, tz]`: `X_cam = R(w)·X + t`, `w` an
    /// angle-axis vector (radians), `t` in the points' unit.
    pub poses: Vec<[f64; 6]>,
    /// Per camera (group of images sharing intrinsics), its parameters.
    pub intrinsics: Vec<[f64; M]>,
    /// Per image, the index of its intrinsics.
    pub intrinsics_of: Vec<usize>,
    pub points: Vec<[f64; 3]>,
    pub observations: Vec<Observation>,
    /// Per image, which pose parameters are held fixed.
    pub fixed_poses: Vec<[bool; 6]>,
    /// Per camera, which intrinsic parameters are held fixed.
    pub fixed_intrinsics: Vec<[bool; M]>,
}

impl<const M: usize> Problem<M> {
    /// About how many bytes an adjustment of this problem allocates: per observation its
    /// residual and Jacobians (the current and a trial evaluation), its blocks of the normal
    /// equations and its place in the structure; per point and camera their blocks; the reduced
    /// camera system when it is solved densely. Measured within 10 % on BAL problems.
    pub fn memory_estimate(&self, solver: LinearSolver) -> u64 {
        let f = std::mem::size_of::<f64>() as u64;
        let m = M as u64;
        let per_obs = 2 * f * (2 + 12 + 2 * m + 6) + f * (18 + 3 * m) + 64;
        let per_point = f * (9 + 3 + 3 + 9) + 48;
        let cam_dim = 6 * self.poses.len() as u64 + m * self.intrinsics.len() as u64;
        let per_camera = f * (36 + 6 * m + m * m + 12) + 48;
        let dense = match solver {
            LinearSolver::DenseSchur => true,
            LinearSolver::IterativeSchur => false,
            LinearSolver::Auto => self.poses.len() <= DENSE_MAX_IMAGES,
        };
        let reduced = if dense {
            3 * f * cam_dim * cam_dim
        } else {
            8 * f * cam_dim
        };
        // Measured: the formula's parts fall some 30 % short of the peak (allocator slack, the
        // problem's own copy).
        (self.observations.len() as u64 * per_obs
            + self.points.len() as u64 * per_point
            + self.poses.len() as u64 * per_camera
            + reduced)
            * 13
            / 10
    }

    /// A problem with nothing held fixed.
    pub fn new(
        poses: Vec<[f64; 6]>,
        intrinsics: Vec<[f64; M]>,
        intrinsics_of: Vec<usize>,
        points: Vec<[f64; 3]>,
        observations: Vec<Observation>,
    ) -> Self {
        Problem {
            fixed_poses: vec![[false; 6]; poses.len()],
            fixed_intrinsics: vec![[false; M]; intrinsics.len()],
            poses,
            intrinsics,
            intrinsics_of,
            points,
            observations,
        }
    }

    /// The centre of image `i` in the points' frame: `C = −Rᵀt`.
    pub fn centre(&self, i: usize) -> Vector3<f64> {
        let q = &self.poses[i];
        -rotation(&Vector3::new(q[0], q[1], q[2])).transpose() * Vector3::new(q[3], q[4], q[5])
    }

    /// Checks that every index is in range, every list has its length and every number is
    /// finite.
    pub fn check(&self) -> Result<(), BaError> {
        let bad = |m: String| Err(BaError::Invalid(m));
        let (ni, nk, np) = (self.poses.len(), self.intrinsics.len(), self.points.len());
        if self.intrinsics_of.len() != ni {
            return bad(format!(
                "{ni} poses but {} intrinsics indices: give every image its camera",
                self.intrinsics_of.len()
            ));
        }
        if self.fixed_poses.len() != ni || self.fixed_intrinsics.len() != nk {
            return bad(format!(
                "fixed-parameter masks for {} poses and {} cameras, expected {ni} and {nk}",
                self.fixed_poses.len(),
                self.fixed_intrinsics.len()
            ));
        }
        if let Some((i, g)) = self
            .intrinsics_of
            .iter()
            .enumerate()
            .find(|(_, g)| **g >= nk)
        {
            return bad(format!("image {i} uses camera {g}, but there are {nk}"));
        }
        for (k, o) in self.observations.iter().enumerate() {
            if o.camera >= ni || o.point >= np {
                return bad(format!(
                    "observation {k} names image {} and point {} ({ni} images, {np} points)",
                    o.camera, o.point
                ));
            }
            if !o.xy.iter().all(|v| v.is_finite()) {
                return bad(format!("observation {k} is not a finite pixel: {:?}", o.xy));
            }
        }
        let finite = self.poses.iter().flatten().all(|v| v.is_finite())
            && self.intrinsics.iter().flatten().all(|v| v.is_finite())
            && self.points.iter().flatten().all(|v| v.is_finite());
        if !finite {
            return bad("a pose, camera or point parameter is not finite".into());
        }
        Ok(())
    }
}

/// Why a problem cannot be adjusted.
#[derive(Debug, Error, Clone, PartialEq)]
pub enum BaError {
    #[error("invalid bundle adjustment problem: {0}")]
    Invalid(String),
    #[error(
        "the adjustment would take about {:.1} GB of memory, more than its limit of {:.1} GB: allow more (geostride ba --max-memory-gb), or adjust fewer observations",
        *needed as f64 / 1e9,
        *limit as f64 / 1e9
    )]
    TooLarge { needed: u64, limit: u64 },
    #[error(
        "observation {observation} (image {image}, point {point}) cannot be projected at the \
         starting values (the point is behind the camera or beyond the distortion's fold): \
         start from better poses or drop the observation"
    )]
    Projection {
        observation: usize,
        image: usize,
        point: usize,
    },
    #[error(
        "the camera covariance is not defined: the information matrix is singular (without \
         surveyed points or camera-centre priors the frame is free; or a parameter is not \
         observed)"
    )]
    Singular,
}

/// Tolerances and limits (Ceres's defaults).
#[derive(Clone, Debug)]
pub struct BaSettings {
    pub max_iterations: usize,
    pub function_tolerance: f64,
    pub gradient_tolerance: f64,
    pub parameter_tolerance: f64,
    pub initial_radius: f64,
    pub max_radius: f64,
    pub min_radius: f64,
    pub min_relative_decrease: f64,
    pub min_diagonal: f64,
    pub max_diagonal: f64,
    /// Loss on each observation's squared residual, in pixels².
    pub loss: RobustLoss,
    /// How the reduced camera system is solved.
    pub linear_solver: LinearSolver,
    /// Conjugate gradients stop when their residual falls below this fraction of the
    /// right-hand side (Ceres's forcing parameter `eta`, 0.1): an inexact step is still a step
    /// the trust region judges by the cost it actually reaches.
    pub iterative_tolerance: f64,
    /// The most memory the adjustment may take, bytes ([`Problem::memory_estimate`]): a problem
    /// that needs more is refused before anything is allocated.
    pub max_memory_bytes: u64,
}

/// The default memory limit of an adjustment: 2 GiB.
pub const DEFAULT_MAX_MEMORY_BYTES: u64 = 2 << 30;

/// The priors of a problem: on points (surveyed ground control points) and on camera centres
/// (RTK positions of the drone's camera).
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Priors {
    pub points: Vec<PointPrior>,
    pub centres: Vec<CentrePrior>,
}

/// A prior on an image's camera centre `C = −Rᵀt`: `(C − position) / sigma` per coordinate
/// joins the residuals.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct CentrePrior {
    pub camera: usize,
    pub position: [f64; 3],
    pub sigma: [f64; 3],
}

/// A prior on a point's position (a surveyed ground control point): `(X − position) / sigma`
/// per coordinate joins the residuals.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct PointPrior {
    pub point: usize,
    pub position: [f64; 3],
    pub sigma: [f64; 3],
}

impl Default for BaSettings {
    fn default() -> Self {
        BaSettings {
            max_iterations: 50,
            function_tolerance: 1e-6,
            gradient_tolerance: 1e-10,
            parameter_tolerance: 1e-8,
            initial_radius: 1e4,
            max_radius: 1e16,
            min_radius: 1e-32,
            min_relative_decrease: 1e-3,
            min_diagonal: 1e-6,
            max_diagonal: 1e32,
            loss: RobustLoss::Squared,
            linear_solver: LinearSolver::Auto,
            iterative_tolerance: 0.1,
            max_memory_bytes: DEFAULT_MAX_MEMORY_BYTES,
        }
    }
}

/// The solver of the reduced camera system `S y = b` (the camera-side unknowns).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum LinearSolver {
    /// Dense Cholesky up to 200 images, iterative beyond.
    Auto,
    /// `S` formed and factored (Ceres's DENSE_SCHUR): exact, memory and time grow as the square
    /// and the cube of the images.
    DenseSchur,
    /// Conjugate gradients on `S` without forming it, preconditioned by its diagonal blocks
    /// (Ceres's ITERATIVE_SCHUR with SCHUR_JACOBI): memory grows with the observations.
    IterativeSchur,
}

/// Images beyond which `Auto` goes iterative.
const DENSE_MAX_IMAGES: usize = 200;

/// Why the solver stopped.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum BaTermination {
    FunctionTolerance,
    GradientTolerance,
    ParameterTolerance,
    /// The trust region shrank to nothing.
    MinRadius,
    MaxIterations,
    /// Five steps in a row could not be computed (the reduced system was not positive definite).
    Failure,
}

impl BaTermination {
    pub fn converged(self) -> bool {
        !matches!(self, BaTermination::MaxIterations | BaTermination::Failure)
    }
}

impl std::fmt::Display for BaTermination {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(match self {
            BaTermination::FunctionTolerance => "function tolerance reached",
            BaTermination::GradientTolerance => "gradient tolerance reached",
            BaTermination::ParameterTolerance => "parameter tolerance reached",
            BaTermination::MinRadius => "trust region radius below its minimum",
            BaTermination::MaxIterations => "maximum number of iterations reached",
            BaTermination::Failure => "the step could not be computed five times in a row",
        })
    }
}

/// One iteration, as Ceres logs it.
#[derive(Clone, Debug, Serialize)]
pub struct BaIteration {
    pub iteration: usize,
    /// The cost after the iteration (the candidate's when rejected).
    pub cost: f64,
    pub cost_change: f64,
    pub gradient_max_norm: f64,
    pub step_norm: f64,
    /// Actual over predicted decrease.
    pub rho: f64,
    pub radius: f64,
    pub accepted: bool,
    pub seconds: f64,
}

#[derive(Clone, Debug, Serialize)]
pub struct BaSummary {
    /// Images (poses).
    pub cameras: usize,
    pub points: usize,
    pub observations: usize,
    pub initial_cost: f64,
    pub final_cost: f64,
    pub iterations: Vec<BaIteration>,
    pub accepted_steps: usize,
    pub termination: BaTermination,
    pub seconds: f64,
}

/// Where the camera-side parameters sit in the flat vector of the reduced system: each image's
/// pose, followed by its intrinsics when no other image shares them; shared intrinsics last.
/// `units` are the diagonal blocks of the Schur–Jacobi preconditioner (offset, size): a pose
/// with its own intrinsics, a pose alone, shared intrinsics.
struct Layout {
    pose: Vec<usize>,
    intr: Vec<usize>,
    dim: usize,
    units: Vec<(usize, usize)>,
    pose_unit: Vec<usize>,
    intr_unit: Vec<usize>,
}

impl Layout {
    fn new<const M: usize>(p: &Problem<M>) -> Layout {
        let mut users = vec![0usize; p.intrinsics.len()];
        for &g in &p.intrinsics_of {
            users[g] += 1;
        }
        let mut lay = Layout {
            pose: Vec::with_capacity(p.poses.len()),
            intr: vec![usize::MAX; p.intrinsics.len()],
            dim: 0,
            units: Vec::new(),
            pose_unit: Vec::with_capacity(p.poses.len()),
            intr_unit: vec![usize::MAX; p.intrinsics.len()],
        };
        for &g in &p.intrinsics_of {
            lay.pose.push(lay.dim);
            lay.pose_unit.push(lay.units.len());
            if users[g] == 1 {
                lay.intr[g] = lay.dim + 6;
                lay.intr_unit[g] = lay.units.len();
                lay.units.push((lay.dim, 6 + M));
                lay.dim += 6 + M;
            } else {
                lay.units.push((lay.dim, 6));
                lay.dim += 6;
            }
        }
        for g in 0..p.intrinsics.len() {
            if lay.intr[g] == usize::MAX {
                lay.intr[g] = lay.dim;
                lay.intr_unit[g] = lay.units.len();
                lay.units.push((lay.dim, M));
                lay.dim += M;
            }
        }
        lay
    }

    /// Image `i`'s pose offset and its intrinsics' offset.
    fn of<const M: usize>(&self, p: &Problem<M>, i: usize) -> (usize, usize) {
        (self.pose[i], self.intr[p.intrinsics_of[i]])
    }

    /// Per flat index: whether the parameter is estimated (not fixed, and observed).
    fn free<const M: usize>(&self, p: &Problem<M>) -> Vec<bool> {
        let mut free = vec![false; self.dim];
        let mut used = vec![false; p.intrinsics.len()];
        for (i, &g) in p.intrinsics_of.iter().enumerate() {
            used[g] = true;
            for (c, f) in p.fixed_poses[i].iter().enumerate() {
                free[self.pose[i] + c] = !f;
            }
        }
        for (g, fixed) in p.fixed_intrinsics.iter().enumerate() {
            for (c, f) in fixed.iter().enumerate() {
                free[self.intr[g] + c] = used[g] && !f;
            }
        }
        free
    }
}

/// The covariance of the camera-side parameters at the optimum.
#[derive(Clone, Debug)]
pub struct CameraCovariance {
    /// Over every pose and camera parameter, in the solver's order (see [`Self::pose`] and
    /// [`Self::intrinsics`]); fixed parameters have zero rows and columns.
    pub matrix: DMatrix<f64>,
    /// The observations' σ (pixels) the covariance is scaled by: given, or estimated.
    pub sigma_px: f64,
    pose_offsets: Vec<usize>,
    intrinsics_offsets: Vec<usize>,
    intrinsics_len: usize,
}

impl CameraCovariance {
    /// The 6×6 covariance of image `i`'s pose (`w` radians, then `t`).
    pub fn pose(&self, i: usize) -> DMatrix<f64> {
        let o = self.pose_offsets[i];
        self.matrix.view((o, o), (6, 6)).into_owned()
    }

    /// The covariance of camera `g`'s intrinsics.
    pub fn intrinsics(&self, g: usize) -> DMatrix<f64> {
        let (o, m) = (self.intrinsics_offsets[g], self.intrinsics_len);
        self.matrix.view((o, o), (m, m)).into_owned()
    }

    /// The standard deviation of parameter `c` of image `i`'s pose.
    pub fn pose_sigma(&self, i: usize, c: usize) -> f64 {
        let o = self.pose_offsets[i] + c;
        self.matrix[(o, o)].sqrt()
    }

    /// The standard deviation of intrinsic parameter `c` of camera `g`.
    pub fn intrinsics_sigma(&self, g: usize, c: usize) -> f64 {
        let o = self.intrinsics_offsets[g] + c;
        self.matrix[(o, o)].sqrt()
    }
}

/// Residuals and Jacobians at one point of the parameter space (weighted by the loss, fixed
/// parameters' columns zeroed).
struct Evaluation<const M: usize> {
    residuals: Vec<Vector2<f64>>,
    j_pose: Vec<Mat26>,
    j_intr: Vec<SMatrix<f64, 2, M>>,
    j_point: Vec<Mat23>,
    cost: f64,
}

fn robust(loss: RobustLoss, r: Vector2<f64>) -> (f64, f64) {
    let s = r.norm_squared();
    (0.5 * loss.rho(s), loss.weight(s).max(0.0).sqrt())
}

/// Where an image's camera sees a point, minus the measurement.
fn residual<const M: usize>(
    p: &Problem<M>,
    model: &impl Projection<M>,
    o: &Observation,
) -> Option<Vector2<f64>> {
    let q = &p.poses[o.camera];
    let w = Vector3::new(q[0], q[1], q[2]);
    let p_cam = rotation(&w) * Vector3::from(p.points[o.point]) + Vector3::new(q[3], q[4], q[5]);
    let u = model.project(&p.intrinsics[p.intrinsics_of[o.camera]], &p_cam)?;
    Some(u - Vector2::from(o.xy))
}

/// [`residual`] with its Jacobians with respect to the pose (`∂P/∂w = −[R·X]ₓ J(w)`,
/// `∂P/∂t = I`), the intrinsics and the point (`∂P/∂X = R`), `P` the point in the camera frame.
pub(crate) fn linearise<const M: usize>(
    p: &Problem<M>,
    model: &impl Projection<M>,
    o: &Observation,
) -> Option<Linearised<M>> {
    let q = &p.poses[o.camera];
    let w = Vector3::new(q[0], q[1], q[2]);
    let r = rotation(&w);
    let rx = r * Vector3::from(p.points[o.point]);
    let p_cam = rx + Vector3::new(q[3], q[4], q[5]);
    let (u, j_pc, j_intr) =
        model.project_with_jacobians(&p.intrinsics[p.intrinsics_of[o.camera]], &p_cam)?;
    let mut j_pose = Mat26::zeros();
    j_pose
        .fixed_view_mut::<2, 3>(0, 0)
        .copy_from(&(j_pc * (-rx.cross_matrix() * left_jacobian(&w))));
    j_pose.fixed_view_mut::<2, 3>(0, 3).copy_from(&j_pc);
    Some((u - Vector2::from(o.xy), j_pose, j_intr, j_pc * r))
}

/// A matrix with the fixed parameters' columns zeroed.
fn mask_columns<const R: usize, const N: usize>(
    mut j: SMatrix<f64, R, N>,
    fixed: &[bool; N],
) -> SMatrix<f64, R, N> {
    for (k, _) in fixed.iter().enumerate().filter(|f| *f.1) {
        j.column_mut(k).fill(0.0);
    }
    j
}

/// A matrix with its columns scaled.
fn scale_columns<const R: usize, const N: usize>(
    mut j: SMatrix<f64, R, N>,
    s: &SVector<f64, N>,
) -> SMatrix<f64, R, N> {
    for (mut c, v) in j.column_iter_mut().zip(s.iter()) {
        c *= *v;
    }
    j
}

fn prior_residual<const M: usize>(p: &Problem<M>, q: &PointPrior) -> Vector3<f64> {
    (Vector3::from(p.points[q.point]) - Vector3::from(q.position))
        .component_div(&Vector3::from(q.sigma))
}

/// A camera-centre prior's residual and its Jacobian with respect to the image's pose (fixed
/// columns zeroed): `C = −R(w)ᵀ t`, `∂C/∂t = −Rᵀ`, `∂C/∂w = [C]ₓ J(−w)` (J the left Jacobian).
fn centre_residual<const M: usize>(p: &Problem<M>, q: &CentrePrior) -> (Vector3<f64>, Mat36) {
    let pose = &p.poses[q.camera];
    let w = Vector3::new(pose[0], pose[1], pose[2]);
    let rt = rotation(&w).transpose();
    let c = -rt * Vector3::new(pose[3], pose[4], pose[5]);
    let inv = Matrix3::from_diagonal(&Vector3::from(q.sigma).map(|v| 1.0 / v));
    let mut j = Mat36::zeros();
    j.fixed_view_mut::<3, 3>(0, 0)
        .copy_from(&(inv * c.cross_matrix() * left_jacobian(&(-w))));
    j.fixed_view_mut::<3, 3>(0, 3).copy_from(&(inv * -rt));
    (
        inv * (c - Vector3::from(q.position)),
        mask_columns(j, &p.fixed_poses[q.camera]),
    )
}

fn prior_cost<const M: usize>(p: &Problem<M>, priors: &Priors) -> f64 {
    priors
        .points
        .iter()
        .map(|q| 0.5 * prior_residual(p, q).norm_squared())
        .sum::<f64>()
        + priors
            .centres
            .iter()
            .map(|q| 0.5 * centre_residual(p, q).0.norm_squared())
            .sum::<f64>()
}

/// The cost at the problem's parameters (infinite where an observation cannot be projected);
/// summed in observation order, as [`evaluate`] does, so that the two agree to the last bit.
fn cost_of<const M: usize>(
    p: &Problem<M>,
    model: &impl Projection<M>,
    priors: &Priors,
    loss: RobustLoss,
) -> f64 {
    let each: Vec<f64> = p
        .observations
        .par_iter()
        .map(|o| residual(p, model, o).map_or(f64::INFINITY, |r| robust(loss, r).0))
        .collect();
    let cost = each.iter().sum::<f64>() + prior_cost(p, priors);
    if cost.is_finite() {
        cost
    } else {
        f64::INFINITY
    }
}

/// Residuals and Jacobians; `Err(k)` names the first observation that cannot be projected.
fn evaluate<const M: usize>(
    p: &Problem<M>,
    model: &impl Projection<M>,
    priors: &Priors,
    loss: RobustLoss,
) -> Result<Evaluation<M>, usize> {
    let per: Vec<Option<(Linearised<M>, f64)>> = p
        .observations
        .par_iter()
        .map(|o| {
            let (r, jc, ji, jp) = linearise(p, model, o)?;
            let (c, w) = robust(loss, r);
            let ji = mask_columns(ji * w, &p.fixed_intrinsics[p.intrinsics_of[o.camera]]);
            Some((
                (
                    r * w,
                    mask_columns(jc * w, &p.fixed_poses[o.camera]),
                    ji,
                    jp * w,
                ),
                c,
            ))
        })
        .collect();
    let n = per.len();
    let mut e = Evaluation {
        residuals: Vec::with_capacity(n),
        j_pose: Vec::with_capacity(n),
        j_intr: Vec::with_capacity(n),
        j_point: Vec::with_capacity(n),
        cost: 0.0,
    };
    for (k, item) in per.into_iter().enumerate() {
        let ((r, jc, ji, jp), c) = item.ok_or(k)?;
        e.residuals.push(r);
        e.j_pose.push(jc);
        e.j_intr.push(ji);
        e.j_point.push(jp);
        e.cost += c;
    }
    e.cost += prior_cost(p, priors);
    Ok(e)
}

/// The normal equations' blocks in the scaled variables. `JᵀJ` on the camera side has a block
/// per pose, per pose and its intrinsics, and per intrinsics.
struct Normal<const M: usize> {
    u_pose: Vec<Mat6>,
    u_pose_intr: Vec<SMatrix<f64, 6, M>>,
    u_intr: Vec<SMatrix<f64, M, M>>,
    v: Vec<Matrix3<f64>>,
    /// Per observation: `Jposeᵀ Jpoint` and `Jintrᵀ Jpoint`.
    w_pose: Vec<Mat63>,
    w_intr: Vec<SMatrix<f64, M, 3>>,
    /// The camera side's gradient, in [`Layout`] order.
    g_cam: DVector<f64>,
    g_point: Vec<Vector3<f64>>,
}

/// Per group of observations (an image's, a point's): `Σ JᵀJ` and `Σ Jᵀr`, `jac(k)` the
/// observation's Jacobian with respect to the group's parameters.
fn normal_blocks<const N: usize>(
    groups: &[Vec<usize>],
    jac: impl Fn(usize) -> SMatrix<f64, 2, N> + Sync,
    residuals: &[Vector2<f64>],
) -> (Vec<SMatrix<f64, N, N>>, Vec<SVector<f64, N>>) {
    groups
        .par_iter()
        .map(|ks| {
            let mut a = SMatrix::<f64, N, N>::zeros();
            let mut g = SVector::<f64, N>::zeros();
            for &k in ks {
                let j = jac(k);
                a += j.transpose() * j;
                g += j.transpose() * residuals[k];
            }
            (a, g)
        })
        .unzip()
}

/// Per group of observations, the squared norms of its parameters' Jacobian columns.
fn column_norms_sq<const N: usize>(
    groups: &[Vec<usize>],
    jac: &[SMatrix<f64, 2, N>],
) -> Vec<SVector<f64, N>> {
    groups
        .iter()
        .map(|ks| {
            ks.iter().fold(SVector::<f64, N>::zeros(), |acc, &k| {
                acc + jac[k].row_iter().fold(SVector::<f64, N>::zeros(), |a, r| {
                    a + r.transpose().component_mul(&r.transpose())
                })
            })
        })
        .collect()
}

/// Ceres's Jacobi scaling of a column of squared norm `sq`: `1 / (1 + ‖column‖)`.
fn jacobi_scales<const N: usize>(sq: &[SVector<f64, N>]) -> Vec<SVector<f64, N>> {
    sq.iter()
        .map(|v| v.map(|x| 1.0 / (1.0 + x.sqrt())))
        .collect()
}

/// Which observations each image, each camera and each point has.
struct Structure {
    by_image: Vec<Vec<usize>>,
    by_camera: Vec<Vec<usize>>,
    by_point: Vec<Vec<usize>>,
}

impl Structure {
    fn new<const M: usize>(p: &Problem<M>) -> Structure {
        let mut st = Structure {
            by_image: vec![Vec::new(); p.poses.len()],
            by_camera: vec![Vec::new(); p.intrinsics.len()],
            by_point: vec![Vec::new(); p.points.len()],
        };
        for (k, o) in p.observations.iter().enumerate() {
            st.by_image[o.camera].push(k);
            st.by_camera[p.intrinsics_of[o.camera]].push(k);
            st.by_point[o.point].push(k);
        }
        st
    }
}

/// A flat camera-side vector from per-pose and per-camera pieces.
fn flat<const M: usize>(lay: &Layout, poses: &[Vec6], intr: &[SVector<f64, M>]) -> DVector<f64> {
    let mut v = DVector::zeros(lay.dim);
    for (o, x) in lay.pose.iter().zip(poses) {
        v.fixed_rows_mut::<6>(*o).copy_from(x);
    }
    for (o, x) in lay.intr.iter().zip(intr) {
        v.fixed_rows_mut::<M>(*o).copy_from(x);
    }
    v
}

/// The Jacobi scales of every camera-side and point parameter, from the first Jacobian.
fn scales<const M: usize>(
    p: &Problem<M>,
    priors: &Priors,
    st: &Structure,
    lay: &Layout,
    e: &Evaluation<M>,
) -> (DVector<f64>, Vec<Vector3<f64>>) {
    let mut pose_sq = column_norms_sq(&st.by_image, &e.j_pose);
    for q in &priors.centres {
        for r in centre_residual(p, q).1.row_iter() {
            pose_sq[q.camera] += r.transpose().component_mul(&r.transpose());
        }
    }
    let intr_sq = column_norms_sq(&st.by_camera, &e.j_intr);
    let mut point_sq = column_norms_sq(&st.by_point, &e.j_point);
    for q in &priors.points {
        point_sq[q.point] += Vector3::from(q.sigma).map(|v| 1.0 / (v * v));
    }
    (
        flat(lay, &jacobi_scales(&pose_sq), &jacobi_scales(&intr_sq)),
        jacobi_scales(&point_sq),
    )
}

fn scaled_normal<const M: usize>(
    p: &Problem<M>,
    priors: &Priors,
    st: &Structure,
    lay: &Layout,
    e: &Evaluation<M>,
    s_cam: &DVector<f64>,
    s_point: &[Vector3<f64>],
) -> Normal<M> {
    let obs = &p.observations;
    let jc = |k: usize| {
        let s = s_cam.fixed_rows::<6>(lay.pose[obs[k].camera]).into_owned();
        scale_columns(e.j_pose[k], &s)
    };
    let ji = |k: usize| {
        let s = s_cam
            .fixed_rows::<M>(lay.of(p, obs[k].camera).1)
            .into_owned();
        scale_columns(e.j_intr[k], &s)
    };
    let jp = |k: usize| scale_columns(e.j_point[k], &s_point[obs[k].point]);
    let per_image: Vec<(Mat6, SMatrix<f64, 6, M>, Vec6)> = st
        .by_image
        .par_iter()
        .map(|ks| {
            let mut u = Mat6::zeros();
            let mut ui = SMatrix::<f64, 6, M>::zeros();
            let mut g = Vec6::zeros();
            for &k in ks {
                let (a, b) = (jc(k), ji(k));
                u += a.transpose() * a;
                ui += a.transpose() * b;
                g += a.transpose() * e.residuals[k];
            }
            (u, ui, g)
        })
        .collect();
    let mut u_pose: Vec<Mat6> = per_image.iter().map(|x| x.0).collect();
    let u_pose_intr = per_image.iter().map(|x| x.1).collect();
    let mut g_pose: Vec<Vec6> = per_image.iter().map(|x| x.2).collect();
    let (u_intr, g_intr) = normal_blocks(&st.by_camera, ji, &e.residuals);
    let (mut v, mut g_point) = normal_blocks(&st.by_point, jp, &e.residuals);
    // A point prior's Jacobian is diag(1/σ), scaled like the point's columns.
    for q in &priors.points {
        let sp = s_point[q.point];
        let j = Vector3::from(q.sigma).map(|v| 1.0 / v).component_mul(&sp);
        v[q.point] += Matrix3::from_diagonal(&j.component_mul(&j));
        g_point[q.point] += j.component_mul(&prior_residual(p, q));
    }
    for q in &priors.centres {
        let (r, j) = centre_residual(p, q);
        let s = s_cam.fixed_rows::<6>(lay.pose[q.camera]).into_owned();
        let j = scale_columns(j, &s);
        u_pose[q.camera] += j.transpose() * j;
        g_pose[q.camera] += j.transpose() * r;
    }
    let (w_pose, w_intr) = (0..obs.len())
        .into_par_iter()
        .map(|k| {
            let b = jp(k);
            (jc(k).transpose() * b, ji(k).transpose() * b)
        })
        .unzip();
    Normal {
        u_pose,
        u_pose_intr,
        u_intr,
        v,
        w_pose,
        w_intr,
        g_cam: flat(lay, &g_pose, &g_intr),
        g_point,
    }
}

/// The LM diagonal: the diagonals of `JᵀJ` clamped to `[lo, hi]`.
fn clamped_diagonals<const M: usize>(
    lay: &Layout,
    n: &Normal<M>,
    lo: f64,
    hi: f64,
) -> (DVector<f64>, Vec<Vector3<f64>>) {
    let clamp = |x: f64| x.clamp(lo, hi);
    let poses: Vec<Vec6> = n.u_pose.iter().map(|b| b.diagonal().map(clamp)).collect();
    let intr: Vec<SVector<f64, M>> = n.u_intr.iter().map(|b| b.diagonal().map(clamp)).collect();
    (
        flat(lay, &poses, &intr),
        n.v.iter().map(|b| b.diagonal().map(clamp)).collect(),
    )
}

/// `(JᵀJ)_cameras · x` plus the damping `D/Δ · x`, without the points' part.
fn camera_block_product<const M: usize>(
    p: &Problem<M>,
    lay: &Layout,
    n: &Normal<M>,
    damping: &DVector<f64>,
    x: &DVector<f64>,
) -> DVector<f64> {
    let mut y = damping.component_mul(x);
    for i in 0..p.poses.len() {
        let (pi, gi) = lay.of(p, i);
        let (xp, xg) = (
            x.fixed_rows::<6>(pi).into_owned(),
            x.fixed_rows::<M>(gi).into_owned(),
        );
        let mut yp = y.fixed_rows_mut::<6>(pi);
        yp += n.u_pose[i] * xp + n.u_pose_intr[i] * xg;
        let mut yg = y.fixed_rows_mut::<M>(gi);
        yg += n.u_pose_intr[i].transpose() * xp;
    }
    for (g, &o) in lay.intr.iter().enumerate() {
        let xg = x.fixed_rows::<M>(o).into_owned();
        let mut yg = y.fixed_rows_mut::<M>(o);
        yg += n.u_intr[g] * xg;
    }
    y
}

/// The reduced camera system `S y = b` of the damped normal equations, the points eliminated
/// through their inverted damped blocks `v_inv`.
fn reduced_system<const M: usize>(
    p: &Problem<M>,
    st: &Structure,
    lay: &Layout,
    n: &Normal<M>,
    d_cam: &DVector<f64>,
    v_inv: &[Matrix3<f64>],
    radius: f64,
) -> (DMatrix<f64>, DVector<f64>) {
    let obs = &p.observations;
    let dim = lay.dim;
    // Σ W V⁻¹ Wᵀ and Σ W V⁻¹ g, accumulated point by point in parallel.
    let (s_minus, b_plus) = st
        .by_point
        .par_iter()
        .enumerate()
        .fold(
            || (DMatrix::<f64>::zeros(dim, dim), DVector::<f64>::zeros(dim)),
            |(mut s, mut b), (j, ks)| {
                let vi = &v_inv[j];
                let wv: Vec<(Mat63, SMatrix<f64, M, 3>)> = ks
                    .iter()
                    .map(|&k| (n.w_pose[k] * vi, n.w_intr[k] * vi))
                    .collect();
                for (&ka, (wpa, wia)) in ks.iter().zip(&wv) {
                    let (pa, ia) = lay.of(p, obs[ka].camera);
                    let mut rows = b.fixed_rows_mut::<6>(pa);
                    rows += wpa * n.g_point[j];
                    let mut rows = b.fixed_rows_mut::<M>(ia);
                    rows += wia * n.g_point[j];
                    // The lower triangle only (blocks on or below the diagonal): S is
                    // symmetric, mirrored once at the end.
                    for &kb in ks {
                        let (pb, ib) = lay.of(p, obs[kb].camera);
                        let (wp, wi) = (n.w_pose[kb].transpose(), n.w_intr[kb].transpose());
                        if pa >= pb {
                            let mut view = s.fixed_view_mut::<6, 6>(pa, pb);
                            view += wpa * wp;
                        }
                        if pa >= ib {
                            let mut view = s.fixed_view_mut::<6, M>(pa, ib);
                            view += wpa * wi;
                        }
                        if ia >= pb {
                            let mut view = s.fixed_view_mut::<M, 6>(ia, pb);
                            view += wia * wp;
                        }
                        if ia >= ib {
                            let mut view = s.fixed_view_mut::<M, M>(ia, ib);
                            view += wia * wi;
                        }
                    }
                }
                (s, b)
            },
        )
        .reduce(
            || (DMatrix::<f64>::zeros(dim, dim), DVector::<f64>::zeros(dim)),
            |(s1, b1), (s2, b2)| (s1 + s2, b1 + b2),
        );
    let mut s = -s_minus;
    s.fill_upper_triangle_with_lower_triangle();
    for i in 0..p.poses.len() {
        let (pi, gi) = lay.of(p, i);
        let mut view = s.fixed_view_mut::<6, 6>(pi, pi);
        view += n.u_pose[i];
        let mut view = s.fixed_view_mut::<6, M>(pi, gi);
        view += n.u_pose_intr[i];
        let mut view = s.fixed_view_mut::<M, 6>(gi, pi);
        view += n.u_pose_intr[i].transpose();
    }
    for (g, &o) in lay.intr.iter().enumerate() {
        let mut view = s.fixed_view_mut::<M, M>(o, o);
        view += n.u_intr[g];
    }
    for (k, d) in d_cam.iter().enumerate() {
        s[(k, k)] += d / radius;
    }
    (s, b_plus - &n.g_cam)
}

/// The points' damped blocks, inverted; `None` when one is singular.
fn point_inverses<const M: usize>(
    n: &Normal<M>,
    d_point: &[Vector3<f64>],
    radius: f64,
) -> Option<Vec<Matrix3<f64>>> {
    n.v.par_iter()
        .zip(d_point)
        .map(|(v, d)| (v + Matrix3::from_diagonal(&(d / radius))).try_inverse())
        .collect()
}

/// Adds a point's `Σ_a Σ_b W_a V⁻¹ W_bᵀ` to the preconditioner's blocks, restricted to each
/// unit: every pair of its observations whose parameter blocks share a unit (one image's pose
/// and own intrinsics; a shared camera's intrinsics seen from two images) adds its block there.
fn add_unit_blocks<const M: usize>(
    p: &Problem<M>,
    lay: &Layout,
    n: &Normal<M>,
    ks: &[usize],
    vi: &Matrix3<f64>,
    acc: &mut [DMatrix<f64>],
) {
    // Per observation: (unit, offset in it) of its pose and of its intrinsics.
    let at: Vec<((usize, usize), (usize, usize))> = ks
        .iter()
        .map(|&k| {
            let i = p.observations[k].camera;
            let (pi, gi) = lay.of(p, i);
            let (up, ug) = (lay.pose_unit[i], lay.intr_unit[p.intrinsics_of[i]]);
            ((up, pi - lay.units[up].0), (ug, gi - lay.units[ug].0))
        })
        .collect();
    for (&ka, &((upa, lpa), (uga, lga))) in ks.iter().zip(&at) {
        let (wpa, wia) = (n.w_pose[ka] * vi, n.w_intr[ka] * vi);
        for (&kb, &((upb, lpb), (ugb, lgb))) in ks.iter().zip(&at) {
            let (wpb, wib) = (n.w_pose[kb].transpose(), n.w_intr[kb].transpose());
            if upa == upb {
                let mut view = acc[upa].fixed_view_mut::<6, 6>(lpa, lpb);
                view += wpa * wpb;
            }
            if upa == ugb {
                let mut view = acc[upa].fixed_view_mut::<6, M>(lpa, lgb);
                view += wpa * wib;
            }
            if uga == upb {
                let mut view = acc[uga].fixed_view_mut::<M, 6>(lga, lpb);
                view += wia * wpb;
            }
            if uga == ugb {
                let mut view = acc[uga].fixed_view_mut::<M, M>(lga, lgb);
                view += wia * wib;
            }
        }
    }
}

/// Solves `S y = b` by conjugate gradients without forming `S = U − W V⁻¹ Wᵀ`: each product
/// goes through the observations, point by point; the preconditioner is `S`'s diagonal blocks
/// (a pose with its own intrinsics, a pose, shared intrinsics). Stops when the residual falls
/// below `tolerance` of `b` (or after as many steps as unknowns).
fn iterative_reduced_solve<const M: usize>(
    p: &Problem<M>,
    st: &Structure,
    lay: &Layout,
    n: &Normal<M>,
    damping: &DVector<f64>,
    v_inv: &[Matrix3<f64>],
    tolerance: f64,
) -> Option<DVector<f64>> {
    let obs = &p.observations;
    let dim = lay.dim;
    // b = −g_c + Σ W V⁻¹ g_p, and the Schur part of the preconditioner's blocks.
    let zero = || {
        (
            DVector::<f64>::zeros(dim),
            lay.units
                .iter()
                .map(|&(_, m)| DMatrix::<f64>::zeros(m, m))
                .collect::<Vec<_>>(),
        )
    };
    let (b_plus, schur) = st
        .by_point
        .par_iter()
        .enumerate()
        .fold(zero, |(mut b, mut blocks), (j, ks)| {
            let t = v_inv[j] * n.g_point[j];
            for &k in ks {
                let (pk, ik) = lay.of(p, obs[k].camera);
                let mut rows = b.fixed_rows_mut::<6>(pk);
                rows += n.w_pose[k] * t;
                let mut rows = b.fixed_rows_mut::<M>(ik);
                rows += n.w_intr[k] * t;
            }
            add_unit_blocks(p, lay, n, ks, &v_inv[j], &mut blocks);
            (b, blocks)
        })
        .reduce(zero, |(b1, mut m1), (b2, m2)| {
            for (x, y) in m1.iter_mut().zip(m2) {
                *x += y;
            }
            (b1 + b2, m1)
        });
    let b = b_plus - &n.g_cam;
    // The camera blocks' own part of each unit: JᵀJ + D/Δ restricted to it.
    let mut own: Vec<DMatrix<f64>> = lay
        .units
        .iter()
        .map(|&(start, size)| DMatrix::from_diagonal(&damping.rows(start, size)))
        .collect();
    let local = |unit: usize, offset: usize| offset - lay.units[unit].0;
    for i in 0..p.poses.len() {
        let (pi, gi) = lay.of(p, i);
        let (up, ug) = (lay.pose_unit[i], lay.intr_unit[p.intrinsics_of[i]]);
        let lp = local(up, pi);
        let mut view = own[up].fixed_view_mut::<6, 6>(lp, lp);
        view += n.u_pose[i];
        if ug == up {
            let lg = local(up, gi);
            let mut view = own[up].fixed_view_mut::<6, M>(lp, lg);
            view += n.u_pose_intr[i];
            let mut view = own[up].fixed_view_mut::<M, 6>(lg, lp);
            view += n.u_pose_intr[i].transpose();
        }
    }
    for (g, &o) in lay.intr.iter().enumerate() {
        let u = lay.intr_unit[g];
        let lg = local(u, o);
        let mut view = own[u].fixed_view_mut::<M, M>(lg, lg);
        view += n.u_intr[g];
    }
    let precond: Vec<DMatrix<f64>> = own
        .into_par_iter()
        .zip(schur)
        .map(|(a, b)| (a - b).cholesky().map(|c| c.inverse()))
        .collect::<Option<_>>()?;
    let preconditioned = |r: &DVector<f64>| {
        let mut z = DVector::zeros(dim);
        for (&(start, size), m) in lay.units.iter().zip(&precond) {
            z.rows_mut(start, size)
                .copy_from(&(m * r.rows(start, size)));
        }
        z
    };
    let apply = |x: &DVector<f64>| -> DVector<f64> {
        let minus = st
            .by_point
            .par_iter()
            .enumerate()
            .fold(
                || DVector::<f64>::zeros(dim),
                |mut acc, (j, ks)| {
                    let mut t = Vector3::zeros();
                    for &k in ks {
                        let (pk, ik) = lay.of(p, obs[k].camera);
                        t += n.w_pose[k].transpose() * x.fixed_rows::<6>(pk)
                            + n.w_intr[k].transpose() * x.fixed_rows::<M>(ik);
                    }
                    let t = v_inv[j] * t;
                    for &k in ks {
                        let (pk, ik) = lay.of(p, obs[k].camera);
                        let mut rows = acc.fixed_rows_mut::<6>(pk);
                        rows += n.w_pose[k] * t;
                        let mut rows = acc.fixed_rows_mut::<M>(ik);
                        rows += n.w_intr[k] * t;
                    }
                    acc
                },
            )
            .reduce(|| DVector::<f64>::zeros(dim), |a, b| a + b);
        camera_block_product(p, lay, n, damping, x) - minus
    };
    let mut x = DVector::zeros(dim);
    let mut r = b.clone();
    let mut z = preconditioned(&r);
    let mut d = z.clone();
    let mut rz = r.dot(&z);
    let b_norm = b.norm();
    for _ in 0..dim {
        if r.norm() <= tolerance * b_norm {
            break;
        }
        let q = apply(&d);
        let dq = d.dot(&q);
        if !(dq > 0.0) {
            return None;
        }
        let alpha = rz / dq;
        x.axpy(alpha, &d, 1.0);
        r.axpy(-alpha, &q, 1.0);
        z = preconditioned(&r);
        let rz_new = r.dot(&z);
        let beta = rz_new / rz;
        rz = rz_new;
        d = &z + beta * d;
    }
    x.iter().all(|c| c.is_finite()).then_some(x)
}

/// Solves the damped system by eliminating the points; `None` when the reduced camera system is
/// not positive definite. Returns the scaled step (camera side, points).
#[allow(clippy::too_many_arguments)]
fn schur_step<const M: usize>(
    p: &Problem<M>,
    st: &Structure,
    lay: &Layout,
    n: &Normal<M>,
    d_cam: &DVector<f64>,
    d_point: &[Vector3<f64>],
    radius: f64,
    (solver, tolerance): (LinearSolver, f64),
) -> Option<(DVector<f64>, Vec<Vector3<f64>>)> {
    let obs = &p.observations;
    let dense = match solver {
        LinearSolver::Auto => p.poses.len() <= DENSE_MAX_IMAGES,
        LinearSolver::DenseSchur => true,
        LinearSolver::IterativeSchur => false,
    };
    let (y_cam, v_inv) = if dense {
        let v_inv = point_inverses(n, d_point, radius)?;
        let (s, b) = reduced_system(p, st, lay, n, d_cam, &v_inv, radius);
        let y = s.cholesky()?.solve(&b);
        if !y.iter().all(|v| v.is_finite()) {
            return None;
        }
        (y, v_inv)
    } else {
        let v_inv = point_inverses(n, d_point, radius)?;
        (
            iterative_reduced_solve(p, st, lay, n, &(d_cam / radius), &v_inv, tolerance)?,
            v_inv,
        )
    };
    let y_point = st
        .by_point
        .par_iter()
        .enumerate()
        .map(|(j, ks)| {
            let mut r = -n.g_point[j];
            for &k in ks {
                let (pk, ik) = lay.of(p, obs[k].camera);
                r -= n.w_pose[k].transpose() * y_cam.fixed_rows::<6>(pk)
                    + n.w_intr[k].transpose() * y_cam.fixed_rows::<M>(ik);
            }
            v_inv[j] * r
        })
        .collect();
    Some((y_cam, y_point))
}

/// The covariance of the camera-side parameters at the problem's current values: the inverse
/// of the information matrix (observations weighted by `1/σ²`, priors by their own σ) with the
/// points eliminated. `σ` is `sigma_px` or, when `None`, estimated from the observations'
/// residuals as `Σ r²` over the degrees of freedom (`2·observations + 3·priors − free
/// parameters`). With a robust loss the observations are weighted by `√ρ'` as in the solver
/// (an outlier's say shrinks). Fixed parameters get zero rows and columns. Without priors the
/// gauge (a similarity) is free and the covariance is not defined ([`BaError::Singular`]).
pub fn covariance<const M: usize>(
    p: &Problem<M>,
    model: &impl Projection<M>,
    priors: &Priors,
    loss: RobustLoss,
    sigma_px: Option<f64>,
) -> Result<CameraCovariance, BaError> {
    p.check()?;
    check_priors(p, priors)?;
    let st = Structure::new(p);
    let lay = Layout::new(p);
    let mut e = evaluate(p, model, &Priors::default(), loss).map_err(|k| projection_error(p, k))?;
    let free = lay.free(p);
    // A point's observable coordinates: two per image it is seen in and three for a survey.
    let mut point_rank = vec![0; p.points.len()];
    for o in &p.observations {
        point_rank[o.point] += 2;
    }
    for q in &priors.points {
        point_rank[q.point] += 3;
    }
    let n_free =
        free.iter().filter(|f| **f).count() + point_rank.iter().map(|r| (*r).min(3)).sum::<usize>();
    let dof = (2 * p.observations.len() + 3 * (priors.points.len() + priors.centres.len()))
        .saturating_sub(n_free);
    let sigma = match sigma_px {
        Some(v) => v,
        None => {
            let sq: f64 = e.residuals.iter().map(|r| r.norm_squared()).sum();
            (sq / dof.max(1) as f64).sqrt()
        }
    };
    // Whiten the observations; the priors are whitened already.
    for k in 0..e.residuals.len() {
        e.residuals[k] /= sigma;
        e.j_pose[k] /= sigma;
        e.j_intr[k] /= sigma;
        e.j_point[k] /= sigma;
    }
    // In Jacobi-scaled variables (as the solver's): focal lengths in pixels beside distortion
    // coefficients and radians would otherwise defeat the factorisation.
    let (s_cam, s_point) = scales(p, priors, &st, &lay, &e);
    let n = scaled_normal(p, priors, &st, &lay, &e, &s_cam, &s_point);
    // A point seen once (and not surveyed) is free along its ray: the pseudo-inverse of its
    // block gives it no say on the cameras, as it has none.
    let v_inv: Vec<Matrix3<f64>> =
        n.v.iter()
            .map(|v| {
                v.pseudo_inverse(1e-12 * v.norm())
                    .unwrap_or_else(|_| Matrix3::zeros())
            })
            .collect();
    let (mut s, _) = reduced_system(p, &st, &lay, &n, &DVector::zeros(lay.dim), &v_inv, 1.0);
    for (k, _) in free.iter().enumerate().filter(|f| !*f.1) {
        s[(k, k)] = 1.0;
    }
    let scale = DMatrix::from_diagonal(&s_cam);
    let mut matrix = &scale * s.cholesky().ok_or(BaError::Singular)?.inverse() * &scale;
    for (k, _) in free.iter().enumerate().filter(|f| !*f.1) {
        matrix.row_mut(k).fill(0.0);
        matrix.column_mut(k).fill(0.0);
    }
    Ok(CameraCovariance {
        matrix,
        sigma_px: sigma,
        pose_offsets: lay.pose,
        intrinsics_offsets: lay.intr,
        intrinsics_len: M,
    })
}

fn projection_error<const M: usize>(p: &Problem<M>, k: usize) -> BaError {
    let o = &p.observations[k];
    BaError::Projection {
        observation: k,
        image: o.camera,
        point: o.point,
    }
}

/// The decrease of the linearised cost along a step `δ` (the problem's own variables):
/// `−(Jδ)ᵀ(r + Jδ/2)` over the observations and the priors.
fn model_decrease<const M: usize>(
    p: &Problem<M>,
    priors: &Priors,
    lay: &Layout,
    e: &Evaluation<M>,
    delta_cam: &DVector<f64>,
    delta_point: &[Vector3<f64>],
) -> f64 {
    let obs = &p.observations;
    let observed: f64 = (0..obs.len())
        .into_par_iter()
        .map(|k| {
            let (pk, ik) = lay.of(p, obs[k].camera);
            let jd = e.j_pose[k] * delta_cam.fixed_rows::<6>(pk)
                + e.j_intr[k] * delta_cam.fixed_rows::<M>(ik)
                + e.j_point[k] * delta_point[obs[k].point];
            -jd.dot(&(e.residuals[k] + jd * 0.5))
        })
        .sum();
    let centres: f64 = priors
        .centres
        .iter()
        .map(|q| {
            let (r, j) = centre_residual(p, q);
            let jd = j * delta_cam.fixed_rows::<6>(lay.pose[q.camera]);
            -jd.dot(&(r + jd * 0.5))
        })
        .sum();
    let points: f64 = priors
        .points
        .iter()
        .map(|q| {
            let jd = delta_point[q.point].component_div(&Vector3::from(q.sigma));
            -jd.dot(&(prior_residual(p, q) + jd * 0.5))
        })
        .sum();
    observed + centres + points
}

/// The problem moved by a step.
fn stepped<const M: usize>(
    p: &Problem<M>,
    lay: &Layout,
    delta_cam: &DVector<f64>,
    delta_point: &[Vector3<f64>],
) -> Problem<M> {
    let mut q = p.clone();
    for (pose, &o) in q.poses.iter_mut().zip(&lay.pose) {
        for (c, v) in pose.iter_mut().enumerate() {
            *v += delta_cam[o + c];
        }
    }
    for (k, &o) in q.intrinsics.iter_mut().zip(&lay.intr) {
        for (c, v) in k.iter_mut().enumerate() {
            *v += delta_cam[o + c];
        }
    }
    for (x, d) in q.points.iter_mut().zip(delta_point) {
        for (v, dv) in x.iter_mut().zip(d.iter()) {
            *v += dv;
        }
    }
    q
}

/// Every prior names a point or image of the problem and has a finite position and σ > 0.
fn check_priors<const M: usize>(p: &Problem<M>, priors: &Priors) -> Result<(), BaError> {
    // One prior on `kind` number `index` (of `count`), `part` naming what of it ("'s centre").
    let check = |(kind, part): (&str, &str),
                 index: usize,
                 count: usize,
                 x: &[f64; 3],
                 s: &[f64; 3]| {
        if index >= count {
            return Err(BaError::Invalid(format!(
                "a prior names {kind} {index} of {count}"
            )));
        }
        if !(x.iter().all(|v| v.is_finite()) && s.iter().all(|v| v.is_finite() && *v > 0.0)) {
            return Err(BaError::Invalid(format!(
                "the prior on {kind} {index}{part} needs a finite position and σ > 0, got {x:?} ± {s:?}"
            )));
        }
        Ok(())
    };
    for q in &priors.points {
        check(
            ("point", ""),
            q.point,
            p.points.len(),
            &q.position,
            &q.sigma,
        )?;
    }
    for q in &priors.centres {
        check(
            ("image", "'s centre"),
            q.camera,
            p.poses.len(),
            &q.position,
            &q.sigma,
        )?;
    }
    Ok(())
}

/// Adjusts a BAL problem's cameras and points in place.
pub fn bundle_adjust(p: &mut BalProblem, settings: &BaSettings) -> Result<BaSummary, BaError> {
    let mut q = p.to_problem();
    let summary = adjust(&mut q, &BalIntrinsics, &Priors::default(), settings)?;
    p.update_from(&q);
    Ok(summary)
}

/// Adjusts the problem's poses, intrinsics and points in place, with priors on some points
/// and camera centres (which also fix the gauge: without them the solution is defined up to a
/// similarity).
pub fn adjust<const M: usize>(
    p: &mut Problem<M>,
    model: &impl Projection<M>,
    priors: &Priors,
    settings: &BaSettings,
) -> Result<BaSummary, BaError> {
    let start = Instant::now();
    p.check()?;
    check_priors(p, priors)?;
    let needed = p.memory_estimate(settings.linear_solver);
    if needed > settings.max_memory_bytes {
        return Err(BaError::TooLarge {
            needed,
            limit: settings.max_memory_bytes,
        });
    }
    let s = settings;
    let st = Structure::new(p);
    let lay = Layout::new(p);
    let mut e = evaluate(p, model, priors, s.loss).map_err(|k| projection_error(p, k))?;
    let initial_cost = e.cost;
    let (s_cam, s_point) = scales(p, priors, &st, &lay, &e);
    let mut n = scaled_normal(p, priors, &st, &lay, &e, &s_cam, &s_point);
    let diag_of = |n: &Normal<M>| clamped_diagonals(&lay, n, s.min_diagonal, s.max_diagonal);
    let (mut d_cam, mut d_point) = diag_of(&n);
    // The gradient of the unscaled problem, Jᵀr: the scaled one divided by the scales.
    let gradient_max = |n: &Normal<M>| -> f64 {
        n.g_cam.component_div(&s_cam).amax().max(
            n.g_point
                .iter()
                .zip(&s_point)
                .map(|(g, sc)| g.component_div(sc).amax())
                .fold(0.0, f64::max),
        )
    };
    let x_norm = |p: &Problem<M>| -> f64 {
        (p.poses.iter().flatten().map(|v| v * v).sum::<f64>()
            + p.intrinsics.iter().flatten().map(|v| v * v).sum::<f64>()
            + p.points.iter().flatten().map(|v| v * v).sum::<f64>())
        .sqrt()
    };
    let mut radius = s.initial_radius;
    let mut decrease = 2.0;
    let mut iterations = Vec::new();
    let mut accepted_steps = 0;
    let mut invalid = 0;
    let mut termination = BaTermination::MaxIterations;
    if gradient_max(&n) <= s.gradient_tolerance {
        termination = BaTermination::GradientTolerance;
    }
    while termination == BaTermination::MaxIterations && iterations.len() < s.max_iterations {
        let t0 = Instant::now();
        // The step in the problem's own variables, and the model's decrease −(Jδ)ᵀ(r + Jδ/2).
        let step = schur_step(
            p,
            &st,
            &lay,
            &n,
            &d_cam,
            &d_point,
            radius,
            (s.linear_solver, s.iterative_tolerance),
        )
        .map(|(y_cam, y_point)| {
            let delta_cam = y_cam.component_mul(&s_cam);
            let delta_point: Vec<Vector3<f64>> = y_point
                .iter()
                .zip(&s_point)
                .map(|(y, sp)| y.component_mul(sp))
                .collect();
            let model_change = model_decrease(p, priors, &lay, &e, &delta_cam, &delta_point);
            (delta_cam, delta_point, model_change)
        });
        let step_norm = step.as_ref().map_or(0.0, |(dc, dp, _)| {
            (dc.norm_squared() + dp.iter().map(|d| d.norm_squared()).sum::<f64>()).sqrt()
        });
        // A step that could not be computed, or whose model does not decrease, is rejected;
        // five in a row is a failure.
        let Some((delta_cam, delta_point, model_change)) = step.filter(|st| st.2 > 0.0) else {
            invalid += 1;
            radius /= decrease;
            decrease *= 2.0;
            iterations.push(BaIteration {
                iteration: iterations.len() + 1,
                cost: e.cost,
                cost_change: 0.0,
                gradient_max_norm: gradient_max(&n),
                step_norm,
                rho: f64::NAN,
                radius,
                accepted: false,
                seconds: t0.elapsed().as_secs_f64(),
            });
            if invalid >= 5 {
                termination = BaTermination::Failure;
            } else if radius < s.min_radius {
                termination = BaTermination::MinRadius;
            }
            continue;
        };
        invalid = 0;
        let candidate = stepped(p, &lay, &delta_cam, &delta_point);
        let new_cost = cost_of(&candidate, model, priors, s.loss);
        let xn = x_norm(p);
        let mut record = BaIteration {
            iteration: iterations.len() + 1,
            cost: new_cost,
            cost_change: e.cost - new_cost,
            gradient_max_norm: gradient_max(&n),
            step_norm,
            rho: (e.cost - new_cost) / model_change,
            radius,
            accepted: false,
            seconds: 0.0,
        };
        // Where the candidate's Jacobians cannot be evaluated, the step is rejected.
        let accepted = if step_norm <= s.parameter_tolerance * (xn + s.parameter_tolerance) {
            termination = BaTermination::ParameterTolerance;
            None
        } else if (e.cost - new_cost).abs() <= s.function_tolerance * e.cost {
            termination = BaTermination::FunctionTolerance;
            None
        } else if record.rho > s.min_relative_decrease {
            evaluate(&candidate, model, priors, s.loss)
                .ok()
                .map(|e_new| (candidate, e_new))
        } else {
            None
        };
        match accepted {
            Some((candidate, e_new)) => {
                *p = candidate;
                e = e_new;
                radius = (radius / (1.0 - (2.0 * record.rho - 1.0).powi(3)).max(1.0 / 3.0))
                    .min(s.max_radius);
                decrease = 2.0;
                accepted_steps += 1;
                n = scaled_normal(p, priors, &st, &lay, &e, &s_cam, &s_point);
                (d_cam, d_point) = diag_of(&n);
                record.accepted = true;
                record.gradient_max_norm = gradient_max(&n);
                if record.gradient_max_norm <= s.gradient_tolerance {
                    termination = BaTermination::GradientTolerance;
                }
            }
            None if termination == BaTermination::MaxIterations => {
                radius /= decrease;
                decrease *= 2.0;
                if radius < s.min_radius {
                    termination = BaTermination::MinRadius;
                }
            }
            None => {}
        }
        record.radius = radius;
        record.seconds = t0.elapsed().as_secs_f64();
        iterations.push(record);
    }
    Ok(BaSummary {
        cameras: p.poses.len(),
        points: p.points.len(),
        observations: p.observations.len(),
        initial_cost,
        final_cost: e.cost,
        iterations,
        accepted_steps,
        termination,
        seconds: start.elapsed().as_secs_f64(),
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::optim::bal::{BalObservation, project};
    use rand::{RngExt, SeedableRng};
    use rand_distr::{Distribution, Normal};

    /// Cameras on a ring looking at a cloud of points, observed with noise.
    fn scene(seed: u64, noise_px: f64, outliers: f64) -> (BalProblem, BalProblem) {
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(seed);
        let normal = Normal::new(0.0, 1.0).unwrap();
        let points: Vec<[f64; 3]> = (0..300)
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
            .map(|j| PointPrior {
                point: j * 6,
                position: truth.points[j * 6],
                sigma,
            })
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
            let sd = (values.iter().map(|v| (v - mean).powi(2)).sum::<f64>() / (trials - 1) as f64)
                .sqrt();
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
            points: vec![PointPrior {
                point: 3,
                position: [0.1, 0.2, 0.3],
                sigma: [0.05, 0.05, 0.1],
            }],
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
                        j[ik + c] = e.j_intr[k][(r, c)] * s_cam[ik + c];
                        j[lay.dim + 3 * o.point + c] = e.j_point[k][(r, c)] * s_point[o.point][c];
                    }
                    rows.push((j, e.residuals[k][r]));
                }
            }
            for q in &priors.points {
                for c in 0..3 {
                    let mut j = DVector::zeros(dim);
                    j[lay.dim + 3 * q.point + c] = s_point[q.point][c] / q.sigma[c];
                    rows.push((j, prior_residual(&p, q)[c]));
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
                    schur_step(&p, &st, &lay, &n, &d_cam, &d_point, radius, (solver, 1e-12))
                        .unwrap();
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
}
