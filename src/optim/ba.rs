//! Bundle adjustment (pure): Levenberg–Marquardt over cameras and points with the Schur
//! complement on the points, following Ceres Solver's trust-region strategy so that the two
//! reach the same cost on the same problem:
//!
//! - the Jacobian's columns are scaled by `1 / (1 + ‖column‖)`, computed once at the start;
//! - the step solves `(JᵀJ + D/Δ) y = −Jᵀr` in the scaled variables, `D` the diagonal of `JᵀJ`
//!   clamped to `[1e-6, 1e32]` (kept after a rejected step), `Δ` the trust-region radius;
//! - the points are eliminated (each point's 3×3 block), the reduced camera system is solved by
//!   dense Cholesky, and the points follow by back-substitution;
//! - a step is accepted when the actual over the model's decrease exceeds 1e-3; then
//!   `Δ ← Δ / max(1/3, 1 − (2ρ − 1)³)`, else `Δ ← Δ / ν`, `ν ← 2ν`;
//! - it stops on the function (`|Δcost| ≤ tol·cost`), gradient (`‖g‖∞ ≤ tol`) and parameter
//!   (`‖δ‖ ≤ tol·(‖x‖ + tol)`) tolerances, a radius below 1e-32, or the iteration limit.
//!
//! Residuals and Jacobians are evaluated in parallel (rayon). Robust losses weight each
//! observation by `√ρ'` (exact gradient, Gauss–Newton Hessian of the reweighted problem).

use std::time::Instant;

use nalgebra::{DMatrix, DVector, Matrix3, SMatrix, SVector, Vector2, Vector3};
use rayon::prelude::*;
use serde::Serialize;

use super::RobustLoss;
use super::bal::{BalProblem, project, project_with_jacobians};

type Mat93 = SMatrix<f64, 9, 3>;
type Mat99 = SMatrix<f64, 9, 9>;
type Vec9 = SMatrix<f64, 9, 1>;
/// The reduced camera system `S`, its right-hand side, and the points' inverted blocks.
type Reduced = (DMatrix<f64>, DVector<f64>, Vec<Matrix3<f64>>);
type JacCam = SMatrix<f64, 2, 9>;
type JacPoint = SMatrix<f64, 2, 3>;

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
    /// Camera parameters held fixed in every camera (e.g. `f`, `k1`, `k2` of a calibrated
    /// camera), by index into the nine.
    pub fixed_camera_params: [bool; 9],
}

/// The priors of a problem: on points (surveyed ground control points) and on camera centres
/// (RTK positions of the drone's camera).
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Priors {
    pub points: Vec<PointPrior>,
    pub centres: Vec<CentrePrior>,
}

/// A prior on a camera's centre `C = −Rᵀt`: `(C − position) / sigma` per coordinate joins the
/// residuals.
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
            fixed_camera_params: [false; 9],
            linear_solver: LinearSolver::Auto,
        }
    }
}

/// The solver of the reduced camera system `S y = b` (`9·cameras` unknowns).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum LinearSolver {
    /// Dense Cholesky up to 200 cameras, iterative beyond.
    Auto,
    /// `S` formed and factored (Ceres's DENSE_SCHUR): exact, memory and time grow as the square
    /// and the cube of the cameras.
    DenseSchur,
    /// Conjugate gradients on `S` without forming it, preconditioned by its 9×9 diagonal blocks
    /// (Ceres's ITERATIVE_SCHUR with SCHUR_JACOBI): memory grows with the observations.
    IterativeSchur,
}

/// Cameras beyond which `Auto` goes iterative.
const DENSE_MAX_CAMERAS: usize = 200;

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

/// Residuals and Jacobians at one point of the parameter space (weighted by the loss).
struct Evaluation {
    residuals: Vec<Vector2<f64>>,
    j_cam: Vec<JacCam>,
    j_point: Vec<JacPoint>,
    cost: f64,
}

fn robust(loss: RobustLoss, r: Vector2<f64>) -> (f64, f64) {
    let s = r.norm_squared();
    (0.5 * loss.rho(s), loss.weight(s).max(0.0).sqrt())
}

/// The cost at the problem's parameters; summed in observation order, as [`evaluate`] does, so
/// that the two agree to the last bit.
fn prior_residual(p: &BalProblem, q: &PointPrior) -> Vector3<f64> {
    (Vector3::from(p.points[q.point]) - Vector3::from(q.position))
        .component_div(&Vector3::from(q.sigma))
}

/// A camera-centre prior's residual and its Jacobian with respect to the camera's nine
/// parameters: `C = −R(w)ᵀ t`, `∂C/∂t = −Rᵀ`, `∂C/∂w = [C]ₓ J(−w)` (J the left Jacobian).
fn centre_residual(p: &BalProblem, q: &CentrePrior) -> (Vector3<f64>, SMatrix<f64, 3, 9>) {
    let cam = &p.cameras[q.camera];
    let w = Vector3::new(cam[0], cam[1], cam[2]);
    let rt = super::bal::rotation(&w).transpose();
    let c = -rt * Vector3::new(cam[3], cam[4], cam[5]);
    let inv = Matrix3::from_diagonal(&Vector3::from(q.sigma).map(|v| 1.0 / v));
    let mut j = SMatrix::<f64, 3, 9>::zeros();
    j.fixed_view_mut::<3, 3>(0, 0)
        .copy_from(&(inv * c.cross_matrix() * super::bal::left_jacobian(&(-w))));
    j.fixed_view_mut::<3, 3>(0, 3).copy_from(&(inv * -rt));
    (inv * (c - Vector3::from(q.position)), j)
}

/// A Jacobian with the fixed camera parameters' columns zeroed.
fn fixed_columns<const R: usize>(
    mut j: SMatrix<f64, R, 9>,
    fixed: [bool; 9],
) -> SMatrix<f64, R, 9> {
    for (k, _) in fixed.iter().enumerate().filter(|f| *f.1) {
        j.column_mut(k).fill(0.0);
    }
    j
}

fn prior_cost(p: &BalProblem, priors: &Priors) -> f64 {
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

fn cost_of(p: &BalProblem, priors: &Priors, loss: RobustLoss) -> f64 {
    let each: Vec<f64> = p
        .observations
        .par_iter()
        .map(|o| {
            let r = project(&p.cameras[o.camera], &p.points[o.point]) - Vector2::from(o.xy);
            robust(loss, r).0
        })
        .collect();
    each.iter().sum::<f64>() + prior_cost(p, priors)
}

fn evaluate(p: &BalProblem, priors: &Priors, s: &BaSettings) -> Evaluation {
    let loss = s.loss;
    let fixed = s.fixed_camera_params;
    let per: Vec<(Vector2<f64>, JacCam, JacPoint, f64)> = p
        .observations
        .par_iter()
        .map(|o| {
            let (u, jc, jp) = project_with_jacobians(&p.cameras[o.camera], &p.points[o.point]);
            let r = u - Vector2::from(o.xy);
            let (c, w) = robust(loss, r);
            (r * w, fixed_columns(jc * w, fixed), jp * w, c)
        })
        .collect();
    let mut e = Evaluation {
        residuals: Vec::with_capacity(per.len()),
        j_cam: Vec::with_capacity(per.len()),
        j_point: Vec::with_capacity(per.len()),
        cost: 0.0,
    };
    for (r, jc, jp, c) in per {
        e.residuals.push(r);
        e.j_cam.push(jc);
        e.j_point.push(jp);
        e.cost += c;
    }
    e.cost += prior_cost(p, priors);
    e
}

/// The normal equations' blocks in the scaled variables.
struct Normal {
    u: Vec<Mat99>,
    v: Vec<Matrix3<f64>>,
    /// Per observation: `Jcᵀ Jp`.
    w: Vec<Mat93>,
    g_cam: Vec<Vec9>,
    g_point: Vec<Vector3<f64>>,
}

/// Per group of observations (a camera's, a point's): `Σ JᵀJ` and `Σ Jᵀr`, `jac(k)` the
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

/// The LM diagonal: each block's diagonal clamped to `[lo, hi]`.
fn clamped_diagonals<const N: usize>(
    blocks: &[SMatrix<f64, N, N>],
    lo: f64,
    hi: f64,
) -> Vec<SVector<f64, N>> {
    blocks
        .iter()
        .map(|b| b.diagonal().map(|v| v.clamp(lo, hi)))
        .collect()
}

/// The largest entry of an unscaled gradient, from the scaled one and its scales.
fn unscaled_max<const N: usize>(scaled: &[SVector<f64, N>], scales: &[SVector<f64, N>]) -> f64 {
    scaled
        .iter()
        .zip(scales)
        .map(|(g, sc)| g.component_div(sc).amax())
        .fold(0.0, f64::max)
}

/// Which observations each camera and each point has.
struct Structure {
    by_camera: Vec<Vec<usize>>,
    by_point: Vec<Vec<usize>>,
}

impl Structure {
    fn new(p: &BalProblem) -> Structure {
        let mut st = Structure {
            by_camera: vec![Vec::new(); p.cameras.len()],
            by_point: vec![Vec::new(); p.points.len()],
        };
        for (k, o) in p.observations.iter().enumerate() {
            st.by_camera[o.camera].push(k);
            st.by_point[o.point].push(k);
        }
        st
    }
}

fn scaled_normal(
    p: &BalProblem,
    priors: &Priors,
    st: &Structure,
    e: &Evaluation,
    s_cam: &[Vec9],
    s_point: &[Vector3<f64>],
    fixed: [bool; 9],
) -> Normal {
    let obs = &p.observations;
    let jc = |k: usize| e.j_cam[k] * Mat99::from_diagonal(&s_cam[obs[k].camera]);
    let jp = |k: usize| e.j_point[k] * Matrix3::from_diagonal(&s_point[obs[k].point]);
    let (mut u, mut g_cam) = normal_blocks(&st.by_camera, jc, &e.residuals);
    let (mut v, mut g_point) = normal_blocks(&st.by_point, jp, &e.residuals);
    // A prior's Jacobian is diag(1/σ), scaled like the point's columns.
    for q in &priors.points {
        let sp = s_point[q.point];
        let j = Vector3::from(q.sigma).map(|v| 1.0 / v).component_mul(&sp);
        v[q.point] += Matrix3::from_diagonal(&j.component_mul(&j));
        g_point[q.point] += j.component_mul(&prior_residual(p, q));
    }
    for q in &priors.centres {
        let (r, j) = centre_residual(p, q);
        let j = fixed_columns(j, fixed) * Mat99::from_diagonal(&s_cam[q.camera]);
        u[q.camera] += j.transpose() * j;
        g_cam[q.camera] += j.transpose() * r;
    }
    let w = (0..obs.len())
        .into_par_iter()
        .map(|k| jc(k).transpose() * jp(k))
        .collect();
    Normal {
        u,
        v,
        w,
        g_cam,
        g_point,
    }
}

/// The reduced camera system `S y = b` of the damped normal equations (the points eliminated)
/// and the points' inverted damped blocks; `None` when a point's block is singular.
fn reduced_system(
    p: &BalProblem,
    st: &Structure,
    n: &Normal,
    d_cam: &[Vec9],
    d_point: &[Vector3<f64>],
    radius: f64,
) -> Option<Reduced> {
    let nc = p.cameras.len();
    let obs = &p.observations;
    let v_inv = point_inverses(n, d_point, radius)?;
    // The reduced camera system S y = b, accumulated point by point in parallel.
    let dim = 9 * nc;
    let (s_minus, b_plus) = st
        .by_point
        .par_iter()
        .enumerate()
        .fold(
            || (DMatrix::<f64>::zeros(dim, dim), DVector::<f64>::zeros(dim)),
            |(mut s, mut b), (j, ks)| {
                let vi = &v_inv[j];
                let wv: Vec<Mat93> = ks.iter().map(|&k| n.w[k] * vi).collect();
                for (a, &ka) in ks.iter().enumerate() {
                    let ca = obs[ka].camera;
                    let bv = wv[a] * n.g_point[j];
                    let mut rows = b.fixed_rows_mut::<9>(9 * ca);
                    rows += bv;
                    for &kb in ks {
                        let cb = obs[kb].camera;
                        let blk = wv[a] * n.w[kb].transpose();
                        let mut view = s.fixed_view_mut::<9, 9>(9 * ca, 9 * cb);
                        view += blk;
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
    let mut b = b_plus;
    for (i, ((u, d), g)) in n.u.iter().zip(d_cam).zip(&n.g_cam).enumerate() {
        let mut view = s.fixed_view_mut::<9, 9>(9 * i, 9 * i);
        view += u + Mat99::from_diagonal(&(d / radius));
        let mut rows = b.fixed_rows_mut::<9>(9 * i);
        rows -= g;
    }
    Some((s, b, v_inv))
}

/// The points' damped blocks, inverted; `None` when one is singular.
fn point_inverses(n: &Normal, d_point: &[Vector3<f64>], radius: f64) -> Option<Vec<Matrix3<f64>>> {
    n.v.par_iter()
        .zip(d_point)
        .map(|(v, d)| (v + Matrix3::from_diagonal(&(d / radius))).try_inverse())
        .collect()
}

/// Solves `S y = b` by conjugate gradients without forming `S = U − W V⁻¹ Wᵀ`: each product
/// goes through the observations, point by point; the preconditioner is `S`'s 9×9 diagonal
/// blocks. Stops when the residual falls below 1e-10 of `b` (or after `9·cameras` steps).
fn iterative_reduced_solve(
    p: &BalProblem,
    st: &Structure,
    n: &Normal,
    d_cam: &[Vec9],
    v_inv: &[Matrix3<f64>],
    radius: f64,
) -> Option<Vec<Vec9>> {
    let nc = p.cameras.len();
    let obs = &p.observations;
    let u_damped: Vec<Mat99> =
        n.u.iter()
            .zip(d_cam)
            .map(|(u, d)| u + Mat99::from_diagonal(&(d / radius)))
            .collect();
    // Right-hand side b = −g_c + Σ W V⁻¹ g_p, and the preconditioner's blocks.
    let zero = || (vec![Vec9::zeros(); nc], vec![Mat99::zeros(); nc]);
    let (b_plus, s_diag) = st
        .by_point
        .par_iter()
        .enumerate()
        .fold(zero, |(mut b, mut d), (j, ks)| {
            for &k in ks {
                let c = obs[k].camera;
                let wv = n.w[k] * v_inv[j];
                b[c] += wv * n.g_point[j];
                d[c] += wv * n.w[k].transpose();
            }
            (b, d)
        })
        .reduce(zero, |(mut b1, mut d1), (b2, d2)| {
            for (x, y) in b1.iter_mut().zip(b2) {
                *x += y;
            }
            for (x, y) in d1.iter_mut().zip(d2) {
                *x += y;
            }
            (b1, d1)
        });
    let b: Vec<Vec9> = b_plus.iter().zip(&n.g_cam).map(|(a, g)| a - g).collect();
    let precond: Vec<Mat99> = u_damped
        .iter()
        .zip(&s_diag)
        .map(|(u, d)| (u - d).cholesky().map(|c| c.inverse()))
        .collect::<Option<_>>()?;
    let apply = |x: &[Vec9]| -> Vec<Vec9> {
        let minus = st
            .by_point
            .par_iter()
            .enumerate()
            .fold(
                || vec![Vec9::zeros(); nc],
                |mut acc, (j, ks)| {
                    let mut t = Vector3::zeros();
                    for &k in ks {
                        t += n.w[k].transpose() * x[obs[k].camera];
                    }
                    let t = v_inv[j] * t;
                    for &k in ks {
                        acc[obs[k].camera] += n.w[k] * t;
                    }
                    acc
                },
            )
            .reduce(
                || vec![Vec9::zeros(); nc],
                |mut a, b| {
                    for (x, y) in a.iter_mut().zip(b) {
                        *x += y;
                    }
                    a
                },
            );
        u_damped
            .iter()
            .zip(x)
            .zip(minus)
            .map(|((u, xi), m)| u * xi - m)
            .collect()
    };
    let dot = |a: &[Vec9], b: &[Vec9]| a.iter().zip(b).map(|(x, y)| x.dot(y)).sum::<f64>();
    let mut x = vec![Vec9::zeros(); nc];
    let mut r = b.clone();
    let mut z: Vec<Vec9> = precond.iter().zip(&r).map(|(m, v)| m * v).collect();
    let mut d = z.clone();
    let mut rz = dot(&r, &z);
    let b_norm = dot(&b, &b).sqrt();
    for _ in 0..9 * nc {
        if dot(&r, &r).sqrt() <= 1e-10 * b_norm {
            break;
        }
        let q = apply(&d);
        let dq = dot(&d, &q);
        if !(dq > 0.0) {
            return None;
        }
        let alpha = rz / dq;
        for ((xi, ri), (di, qi)) in x.iter_mut().zip(r.iter_mut()).zip(d.iter().zip(&q)) {
            *xi += alpha * di;
            *ri -= alpha * qi;
        }
        z = precond.iter().zip(&r).map(|(m, v)| m * v).collect();
        let rz_new = dot(&r, &z);
        let beta = rz_new / rz;
        rz = rz_new;
        for (di, zi) in d.iter_mut().zip(&z) {
            *di = zi + beta * *di;
        }
    }
    x.iter()
        .all(|v| v.iter().all(|c| c.is_finite()))
        .then_some(x)
}

/// Solves the damped system by eliminating the points; `None` when the reduced camera system is
/// not positive definite. Returns the scaled step (cameras, points).
fn schur_step(
    p: &BalProblem,
    st: &Structure,
    n: &Normal,
    d_cam: &[Vec9],
    d_point: &[Vector3<f64>],
    radius: f64,
    solver: LinearSolver,
) -> Option<(Vec<Vec9>, Vec<Vector3<f64>>)> {
    let nc = p.cameras.len();
    let obs = &p.observations;
    let dense = match solver {
        LinearSolver::Auto => nc <= DENSE_MAX_CAMERAS,
        LinearSolver::DenseSchur => true,
        LinearSolver::IterativeSchur => false,
    };
    let (y_cam, v_inv) = if dense {
        let (s, b, v_inv) = reduced_system(p, st, n, d_cam, d_point, radius)?;
        let y = s.cholesky()?.solve(&b);
        if !y.iter().all(|v| v.is_finite()) {
            return None;
        }
        let y_cam: Vec<Vec9> = (0..nc)
            .map(|i| Vec9::from_iterator(y.rows(9 * i, 9).iter().copied()))
            .collect();
        (y_cam, v_inv)
    } else {
        let v_inv = point_inverses(n, d_point, radius)?;
        (
            iterative_reduced_solve(p, st, n, d_cam, &v_inv, radius)?,
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
                r -= n.w[k].transpose() * y_cam[obs[k].camera];
            }
            v_inv[j] * r
        })
        .collect();
    Some((y_cam, y_point))
}

/// The covariance of the cameras' parameters at the problem's current values: `9·cameras`
/// square, camera after camera: the inverse of the information matrix (observations weighted by
/// `1/σ²`, priors by their own σ) with the points eliminated. `σ` is `sigma_px` or, when `None`,
/// estimated from the observations' residuals as `Σ r²` over the degrees of freedom
/// (`2·observations + 3·priors − free parameters`); it is returned beside. Fixed parameters get zero rows and columns. `None` when
/// the reduced matrix is singular: without priors the gauge (a similarity) is free and the
/// covariance is not defined.
pub fn camera_covariance(
    p: &BalProblem,
    priors: &Priors,
    settings: &BaSettings,
    sigma_px: Option<f64>,
) -> Option<(DMatrix<f64>, f64)> {
    let (nc, np) = (p.cameras.len(), p.points.len());
    let st = Structure::new(p);
    let mut e = evaluate(p, &Priors::default(), settings);
    let fixed = settings.fixed_camera_params;
    let free = 9 * nc - fixed.iter().filter(|f| **f).count() * nc + 3 * np;
    let dof = (2 * p.observations.len() + 3 * (priors.points.len() + priors.centres.len()))
        .saturating_sub(free);
    let sigma = match sigma_px {
        Some(v) => v,
        None => {
            let sq: f64 = e.residuals.iter().map(|r| r.norm_squared()).sum();
            (sq / dof.max(1) as f64).sqrt()
        }
    };
    // Whiten the observations; the priors are whitened already.
    for ((r, jc), jp) in e.residuals.iter_mut().zip(&mut e.j_cam).zip(&mut e.j_point) {
        *r /= sigma;
        *jc /= sigma;
        *jp /= sigma;
    }
    let ones_c = vec![Vec9::repeat(1.0); nc];
    let ones_p = vec![Vector3::repeat(1.0); np];
    let n = scaled_normal(p, priors, &st, &e, &ones_c, &ones_p, fixed);
    let zeros_c = vec![Vec9::zeros(); nc];
    let zeros_p = vec![Vector3::zeros(); np];
    let (mut s, _, _) = reduced_system(p, &st, &n, &zeros_c, &zeros_p, 1.0)?;
    for i in 0..nc {
        for (k, _) in fixed.iter().enumerate().filter(|f| *f.1) {
            s[(9 * i + k, 9 * i + k)] = 1.0;
        }
    }
    let mut cov = s.cholesky()?.inverse();
    for i in 0..nc {
        for (k, _) in fixed.iter().enumerate().filter(|f| *f.1) {
            cov.row_mut(9 * i + k).fill(0.0);
            cov.column_mut(9 * i + k).fill(0.0);
        }
    }
    Some((cov, sigma))
}

/// The decrease of the linearised cost along a step `δ` (the problem's own variables):
/// `−(Jδ)ᵀ(r + Jδ/2)` over the observations and the priors.
fn model_decrease(
    p: &BalProblem,
    priors: &Priors,
    e: &Evaluation,
    delta_cam: &[Vec9],
    delta_point: &[Vector3<f64>],
    fixed: [bool; 9],
) -> f64 {
    let obs = &p.observations;
    let observed: f64 = (0..obs.len())
        .into_par_iter()
        .map(|k| {
            let jd =
                e.j_cam[k] * delta_cam[obs[k].camera] + e.j_point[k] * delta_point[obs[k].point];
            -jd.dot(&(e.residuals[k] + jd * 0.5))
        })
        .sum();
    let centres: f64 = priors
        .centres
        .iter()
        .map(|q| {
            let (r, j) = centre_residual(p, q);
            let jd = fixed_columns(j, fixed) * delta_cam[q.camera];
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

/// Adjusts the problem's cameras and points in place.
pub fn bundle_adjust(p: &mut BalProblem, settings: &BaSettings) -> BaSummary {
    bundle_adjust_with_priors(p, &Priors::default(), settings)
}

/// Adjusts the problem's cameras and points in place, with priors on some points (which also
/// fix the gauge: without them the solution is defined up to a similarity).
pub fn bundle_adjust_with_priors(
    p: &mut BalProblem,
    priors: &Priors,
    settings: &BaSettings,
) -> BaSummary {
    let start = Instant::now();
    let s = settings;
    let (nc, np) = (p.cameras.len(), p.points.len());
    let st = Structure::new(p);
    let mut e = evaluate(p, priors, s);
    let initial_cost = e.cost;
    // Jacobi scaling from the first Jacobian's column norms.
    let mut cam_sq = column_norms_sq(&st.by_camera, &e.j_cam);
    for q in &priors.centres {
        let j = fixed_columns(centre_residual(p, q).1, s.fixed_camera_params);
        for r in j.row_iter() {
            cam_sq[q.camera] += r.transpose().component_mul(&r.transpose());
        }
    }
    let s_cam = jacobi_scales(&cam_sq);
    let mut point_sq = column_norms_sq(&st.by_point, &e.j_point);
    for q in &priors.points {
        point_sq[q.point] += Vector3::from(q.sigma).map(|v| 1.0 / (v * v));
    }
    let s_point = jacobi_scales(&point_sq);
    let mut n = scaled_normal(p, priors, &st, &e, &s_cam, &s_point, s.fixed_camera_params);
    let diag_of = |n: &Normal| {
        (
            clamped_diagonals(&n.u, s.min_diagonal, s.max_diagonal),
            clamped_diagonals(&n.v, s.min_diagonal, s.max_diagonal),
        )
    };
    let (mut d_cam, mut d_point) = diag_of(&n);
    // The gradient of the unscaled problem, Jᵀr: the scaled one divided by the scales.
    let gradient_max = |n: &Normal| -> f64 {
        unscaled_max(&n.g_cam, &s_cam).max(unscaled_max(&n.g_point, &s_point))
    };
    let x_norm = |p: &BalProblem| -> f64 {
        (p.cameras.iter().flatten().map(|v| v * v).sum::<f64>()
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
        let step = schur_step(p, &st, &n, &d_cam, &d_point, radius, s.linear_solver).map(
            |(y_cam, y_point)| {
                let delta_cam: Vec<Vec9> = y_cam
                    .iter()
                    .zip(&s_cam)
                    .map(|(y, sc)| y.component_mul(sc))
                    .collect();
                let delta_point: Vec<Vector3<f64>> = y_point
                    .iter()
                    .zip(&s_point)
                    .map(|(y, sp)| y.component_mul(sp))
                    .collect();
                let model_change = model_decrease(
                    p,
                    priors,
                    &e,
                    &delta_cam,
                    &delta_point,
                    s.fixed_camera_params,
                );
                (delta_cam, delta_point, model_change)
            },
        );
        let step_norm = step.as_ref().map_or(0.0, |(dc, dp, _)| {
            (dc.iter().map(|d| d.norm_squared()).sum::<f64>()
                + dp.iter().map(|d| d.norm_squared()).sum::<f64>())
            .sqrt()
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
        let mut candidate = p.clone();
        for (c, d) in candidate.cameras.iter_mut().zip(&delta_cam) {
            for (v, dv) in c.iter_mut().zip(d.iter()) {
                *v += dv;
            }
        }
        for (x, d) in candidate.points.iter_mut().zip(&delta_point) {
            for (v, dv) in x.iter_mut().zip(d.iter()) {
                *v += dv;
            }
        }
        let new_cost = cost_of(&candidate, priors, s.loss);
        let new_cost = if new_cost.is_finite() {
            new_cost
        } else {
            f64::INFINITY
        };
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
        if step_norm <= s.parameter_tolerance * (xn + s.parameter_tolerance) {
            termination = BaTermination::ParameterTolerance;
        } else if (e.cost - new_cost).abs() <= s.function_tolerance * e.cost {
            termination = BaTermination::FunctionTolerance;
        } else if record.rho > s.min_relative_decrease {
            *p = candidate;
            radius = (radius / (1.0 - (2.0 * record.rho - 1.0).powi(3)).max(1.0 / 3.0))
                .min(s.max_radius);
            decrease = 2.0;
            accepted_steps += 1;
            e = evaluate(p, priors, s);
            n = scaled_normal(p, priors, &st, &e, &s_cam, &s_point, s.fixed_camera_params);
            (d_cam, d_point) = diag_of(&n);
            record.accepted = true;
            record.gradient_max_norm = gradient_max(&n);
            if record.gradient_max_norm <= s.gradient_tolerance {
                termination = BaTermination::GradientTolerance;
            }
        } else {
            radius /= decrease;
            decrease *= 2.0;
            if radius < s.min_radius {
                termination = BaTermination::MinRadius;
            }
        }
        record.radius = radius;
        record.seconds = t0.elapsed().as_secs_f64();
        iterations.push(record);
    }
    BaSummary {
        cameras: nc,
        points: np,
        observations: p.observations.len(),
        initial_cost,
        final_cost: e.cost,
        iterations,
        accepted_steps,
        termination,
        seconds: start.elapsed().as_secs_f64(),
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::optim::bal::BalObservation;
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
        let summary = bundle_adjust(&mut start, &BaSettings::default());
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
        let settings = BaSettings {
            fixed_camera_params: [false, false, false, false, false, false, false, true, true],
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
        let (predicted, s) =
            camera_covariance(&truth, &exact_priors, &settings, Some(0.5)).unwrap();
        assert_eq!(s, 0.5);
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(7);
        let normal = Normal::new(0.0, 1.0).unwrap();
        let trials = 300;
        let mut samples: Vec<Vec<f64>> = Vec::new();
        let mut sigma_hat = Vec::new();
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
            let summary = bundle_adjust_with_priors(&mut p, &priors, &settings);
            assert!(summary.termination.converged(), "{:?}", summary.termination);
            sigma_hat.push(camera_covariance(&p, &priors, &settings, None).unwrap().1);
            samples.push(
                p.cameras
                    .iter()
                    .zip(&truth.cameras)
                    .flat_map(|(a, b)| (0..9).map(move |k| a[k] - b[k]))
                    .collect(),
            );
        }
        let mut checked = 0;
        for k in 0..36 {
            let want = predicted[(k, k)].sqrt();
            let values: Vec<f64> = samples.iter().map(|v| v[k]).collect();
            if settings.fixed_camera_params[k % 9] {
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
        assert!(camera_covariance(&truth, &Priors::default(), &settings, Some(0.5)).is_none());
    }

    #[test]
    fn centre_prior_jacobian_agrees_with_finite_differences() {
        let (truth, _) = scene(2, 0.0, 0.0);
        let q = CentrePrior {
            camera: 3,
            position: [0.5, -0.2, 9.0],
            sigma: [0.02, 0.03, 0.05],
        };
        let (_, j) = centre_residual(&truth, &q);
        for k in 0..9 {
            let (mut a, mut b) = (truth.clone(), truth.clone());
            a.cameras[3][k] += 1e-6;
            b.cameras[3][k] -= 1e-6;
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
        let (truth, mut start) = scene(9, 0.5, 0.0);
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(1);
        let normal = Normal::new(0.0, 1.0).unwrap();
        let centre = |p: &BalProblem, i: usize| {
            let c = &p.cameras[i];
            -super::super::bal::rotation(&Vector3::new(c[0], c[1], c[2])).transpose()
                * Vector3::new(c[3], c[4], c[5])
        };
        let priors = Priors {
            points: Vec::new(),
            centres: (0..truth.cameras.len())
                .map(|i| {
                    let c = centre(&truth, i);
                    CentrePrior {
                        camera: i,
                        position: [0, 1, 2].map(|k| c[k] + 0.02 * normal.sample(&mut rng)),
                        sigma: [0.02; 3],
                    }
                })
                .collect(),
        };
        // A calibrated camera: f, k1, k2 fixed (at the truth: the start perturbed only f).
        for (c, t) in start.cameras.iter_mut().zip(&truth.cameras) {
            c[6..].copy_from_slice(&t[6..]);
        }
        let settings = BaSettings {
            fixed_camera_params: [false, false, false, false, false, false, true, true, true],
            ..BaSettings::default()
        };
        let summary = bundle_adjust_with_priors(&mut start, &priors, &settings);
        assert!(summary.termination.converged(), "{:?}", summary.termination);
        for i in 0..truth.cameras.len() {
            let err = (centre(&start, i) - centre(&truth, i)).norm();
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
        assert!(camera_covariance(&start, &priors, &settings, None).is_some());
    }

    #[test]
    fn iterative_schur_reaches_the_dense_solution() {
        let (_, start) = scene(4, 0.5, 0.0);
        let run = |solver| {
            let mut p = start.clone();
            let s = bundle_adjust(
                &mut p,
                &BaSettings {
                    linear_solver: solver,
                    ..BaSettings::default()
                },
            );
            (s, p)
        };
        let (dense, a) = run(LinearSolver::DenseSchur);
        let (iterative, b) = run(LinearSolver::IterativeSchur);
        assert!(dense.termination.converged() && iterative.termination.converged());
        assert!(
            (iterative.final_cost / dense.final_cost - 1.0).abs() < 1e-9,
            "{} vs {}",
            iterative.final_cost,
            dense.final_cost
        );
        let worst = a
            .points
            .iter()
            .zip(&b.points)
            .map(|(x, y)| (Vector3::from(*x) - Vector3::from(*y)).norm())
            .fold(0.0, f64::max);
        assert!(worst < 1e-6, "{worst}");
    }

    #[test]
    fn huber_loss_converges_through_gross_outliers() {
        let (truth, start) = scene(5, 0.5, 0.05);
        let mut plain = start.clone();
        bundle_adjust(&mut plain, &BaSettings::default());
        let mut robust = start;
        let summary = bundle_adjust(
            &mut robust,
            &BaSettings {
                loss: RobustLoss::Huber(1.0),
                ..BaSettings::default()
            },
        );
        assert!(summary.termination.converged(), "{:?}", summary.termination);
        let (a, b) = (rms_to_truth(&truth, &plain), rms_to_truth(&truth, &robust));
        assert!(b < 0.45 && b < 0.1 * a, "plain {a}, Huber {b}");
    }
}
