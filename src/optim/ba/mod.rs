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
//!
//! Files: this one the problem and its settings; `evaluation` residuals and Jacobians; `schur`
//! the normal equations, scaling and the Schur complement; `pcg` the iterative solver; `lm` the
//! trust-region loop; `covariance` the cameras' covariances.

use std::time::Instant;

use nalgebra::{DMatrix, DVector, Matrix3, SMatrix, SVector, Vector2, Vector3};
use rayon::prelude::*;
use serde::Serialize;
use thiserror::Error;

use super::RobustLoss;
use crate::geom::so3::{left_jacobian, rotation};

mod covariance;
mod evaluation;
mod lm;
mod pcg;
mod schur;
#[cfg(test)]
mod tests;

pub use covariance::{CameraCovariance, covariance};
use evaluation::*;
use lm::*;
pub use lm::{adjust, adjust_with_covariance};
use pcg::*;
use schur::*;

/// One image measurement: image `camera` sees point `point` at `xy` (pixels).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Observation {
    pub camera: usize,
    pub point: usize,
    pub xy: [f64; 2],
}

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
    /// Per point, whether it is held fixed (a calibration board's corners).
    pub fixed_points: Vec<bool>,
    /// Per observation, its standard deviation (pixels): residuals are divided by it, so that
    /// costs and losses are in σ units. Empty: every observation 1 px (residuals in pixels).
    pub sigma_px: Vec<f64>,
}

impl<const M: usize> Problem<M> {
    /// About how many bytes an adjustment of this problem allocates: per observation its
    /// residual and Jacobians (the current and a trial evaluation), its blocks of the normal
    /// equations and its place in the structure; per point and camera their blocks; the reduced
    /// camera system when it is solved densely. Measured within 10 % on BAL problems. The
    /// intrinsics' Jacobians and couplings count only when some intrinsic parameter is free
    /// (else they are not stored).
    pub fn memory_estimate(&self, solver: LinearSolver) -> u64 {
        let f = std::mem::size_of::<f64>() as u64;
        let m = M as u64;
        let mi = if evaluation::intrinsics_free(self) {
            m
        } else {
            0
        };
        let per_obs = 2 * f * (2 + 12 + 2 * mi + 6) + f * (18 + 3 * mi) + 64;
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
            fixed_points: vec![false; points.len()],
            sigma_px: Vec::new(),
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
        if self.fixed_points.len() != np {
            return bad(format!(
                "fixed-point mask for {} points, expected {np}",
                self.fixed_points.len()
            ));
        }
        if !self.sigma_px.is_empty() && self.sigma_px.len() != self.observations.len() {
            return bad(format!(
                "{} observation σ for {} observations: give one per observation or none",
                self.sigma_px.len(),
                self.observations.len()
            ));
        }
        if let Some((k, s)) = self
            .sigma_px
            .iter()
            .enumerate()
            .find(|(_, s)| !(s.is_finite() && **s > 0.0))
        {
            return bad(format!("observation {k} has σ = {s} px, expected > 0"));
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

/// A prior on a point's position (a surveyed ground control point): `W (X − position)` joins
/// the residuals, `W` the square root of the survey's information (`WᵀW = Σ⁻¹`).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct PointPrior {
    pub point: usize,
    pub position: [f64; 3],
    /// `W`, lower triangular: `diag(1/σ)` for independent coordinates.
    pub sqrt_information: Matrix3<f64>,
}

impl PointPrior {
    /// Independent coordinates with standard deviations `sigma`.
    pub fn new(point: usize, position: [f64; 3], sigma: [f64; 3]) -> Self {
        PointPrior {
            point,
            position,
            sqrt_information: Matrix3::from_diagonal(&Vector3::from(sigma).map(|s| 1.0 / s)),
        }
    }

    /// A full covariance (a survey's correlated east, north and up); `None` unless it is
    /// symmetric positive definite.
    pub fn with_covariance(point: usize, position: [f64; 3], cov: &Matrix3<f64>) -> Option<Self> {
        if (cov - cov.transpose()).amax() > 1e-12 * cov.amax() {
            return None;
        }
        // Σ = L Lᵀ ⇒ W = L⁻¹ gives WᵀW = Σ⁻¹.
        let w = cov.cholesky()?.l().try_inverse()?;
        w.iter().all(|v| v.is_finite()).then_some(PointPrior {
            point,
            position,
            sqrt_information: w,
        })
    }
}

impl BaSettings {
    /// The tolerances and limits of a Levenberg–Marquardt run (`initial_mu` the inverse of the
    /// initial radius), the rest at their defaults.
    pub fn from_lm(lm: &super::LmSettings) -> Self {
        BaSettings {
            max_iterations: lm.max_iterations,
            function_tolerance: lm.function_tolerance,
            gradient_tolerance: lm.gradient_tolerance,
            parameter_tolerance: lm.parameter_tolerance,
            initial_radius: 1.0 / lm.initial_mu,
            min_diagonal: lm.min_diagonal,
            max_diagonal: lm.max_diagonal,
            min_relative_decrease: lm.min_relative_decrease,
            ..BaSettings::default()
        }
    }
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

/// About how many observations' work one parallel task gets: a loop over fewer runs on the
/// thread it is on, as waking another costs more than a small problem's whole loop (measured:
/// a 13-view calibration took 4x longer split into tasks).
const GRAIN: usize = 1024;

/// The least number of `items` (sharing `observations` between them) per parallel task.
fn grain(items: usize, observations: usize) -> usize {
    (items.saturating_mul(GRAIN) / observations.max(1)).max(1)
}

/// `fold` over `items` (with their indices) in fixed chunks of `chunk` run side by side, the
/// chunks' results combined in order from `zero`: the same bits on any number of threads, however
/// the work is stolen (rayon's `fold`/`reduce` sums in pieces that depend on who steals what, so a
/// large problem's sums differed in the last bits from run to run). A problem of one chunk is one
/// fold, as rayon did for a problem too small to split.
pub(super) fn fold_in_order<T: Sync, A: Send>(
    items: &[T],
    chunk: usize,
    zero: impl Fn() -> A + Sync + Send,
    fold: impl Fn(A, (usize, &T)) -> A + Sync + Send,
    combine: impl Fn(A, A) -> A,
) -> A {
    let chunk = chunk.max(1);
    let parts: Vec<A> = items
        .par_chunks(chunk)
        .enumerate()
        .map(|(c, xs)| {
            xs.iter()
                .enumerate()
                .fold(zero(), |a, (k, x)| fold(a, (c * chunk + k, x)))
        })
        .collect();
    parts.into_iter().fold(zero(), combine)
}

/// The chunk of [`fold_in_order`] over a problem's points: two grains, the least rayon split,
/// and at most [`MAX_POINT_PARTS`] chunks, as each starts its own camera-sized accumulator.
fn point_chunk(points: usize, observations: usize) -> usize {
    (2 * grain(points, observations)).max(points.div_ceil(MAX_POINT_PARTS))
}

/// The most chunks a fold over the points is cut into (a fixed number: the sums must not
/// depend on the threads). Every chunk zeroes and then adds a copy of the camera system: a
/// 118-image model with 174 000 points had 350 copies of its 4 MB Schur complement an
/// iteration, more work than its points.
const MAX_POINT_PARTS: usize = 16;

/// Images beyond which `Auto` goes iterative.
const DENSE_MAX_IMAGES: usize = 200;

/// The cost `½ Σ ρ(‖r/σ‖²)` of the observations plus `½ Σ ‖W (X − X₀)‖²` and the centre
/// priors' at the problem's parameters (infinite where an observation cannot be projected).
pub fn total_cost<const M: usize>(
    p: &Problem<M>,
    model: &impl Projection<M>,
    priors: &Priors,
    loss: RobustLoss,
) -> f64 {
    cost_of(p, model, priors, loss)
}

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

impl From<BaTermination> for super::Termination {
    fn from(t: BaTermination) -> Self {
        use super::Termination as T;
        match t {
            BaTermination::FunctionTolerance => T::FunctionTolerance,
            BaTermination::GradientTolerance => T::GradientTolerance,
            BaTermination::ParameterTolerance => T::ParameterTolerance,
            BaTermination::MaxIterations => T::MaxIterations,
            BaTermination::MinRadius | BaTermination::Failure => T::NoFurtherProgress,
        }
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
    /// Where the intrinsics shared by several images begin (`dim` when none are).
    shared_start: usize,
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
            shared_start: 0,
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
        lay.shared_start = lay.dim;
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

/// [`residual`] with its Jacobians with respect to the pose (`∂P/∂w = −[R·X]ₓ J(w)`,
/// `∂P/∂t = I`), the intrinsics and the point (`∂P/∂X = R`), `P` the point in the camera frame.
#[cfg(test)]
pub(crate) fn linearise<const M: usize>(
    p: &Problem<M>,
    model: &impl Projection<M>,
    o: &Observation,
) -> Option<Linearised<M>> {
    linearise_at(p, model, o, &PoseFrame::of(&p.poses[o.camera]))
}

/// A pose's rotation matrix and the left Jacobian of its angle-axis vector, computed once for
/// all of its observations.
pub(super) struct PoseFrame {
    rotation: Matrix3<f64>,
    left_jacobian: Matrix3<f64>,
}

impl PoseFrame {
    pub(super) fn of(q: &[f64; 6]) -> PoseFrame {
        let w = Vector3::new(q[0], q[1], q[2]);
        PoseFrame {
            rotation: rotation(&w),
            left_jacobian: left_jacobian(&w),
        }
    }

    /// Every pose's frame.
    pub(super) fn all<const M: usize>(p: &Problem<M>) -> Vec<PoseFrame> {
        p.poses.iter().map(PoseFrame::of).collect()
    }
}

/// [`linearise`] with the pose's frame given.
pub(super) fn linearise_at<const M: usize>(
    p: &Problem<M>,
    model: &impl Projection<M>,
    o: &Observation,
    frame: &PoseFrame,
) -> Option<Linearised<M>> {
    let q = &p.poses[o.camera];
    let r = &frame.rotation;
    let rx = r * Vector3::from(p.points[o.point]);
    let p_cam = rx + Vector3::new(q[3], q[4], q[5]);
    let (u, j_pc, j_intr) =
        model.project_with_jacobians(&p.intrinsics[p.intrinsics_of[o.camera]], &p_cam)?;
    let mut j_pose = Mat26::zeros();
    j_pose
        .fixed_view_mut::<2, 3>(0, 0)
        .copy_from(&(j_pc * (-rx.cross_matrix() * frame.left_jacobian)));
    j_pose.fixed_view_mut::<2, 3>(0, 3).copy_from(&j_pc);
    Some((u - Vector2::from(o.xy), j_pose, j_intr, j_pc * r))
}
