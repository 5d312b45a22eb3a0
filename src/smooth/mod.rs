//! Trajectory refinement (pure): a constant-velocity Kalman filter and Rauch–Tung–Striebel
//! smoother over the horizontal position, with the process noise estimated by
//! expectation–maximisation (the paper's section 3.4; Shumway & Stoffer 1982).
//!
//! The state is `(e, n, v_e, v_n)` at every frame from a track's first observation to its last;
//! frames without an observation are predicted through (gaps). Each observation carries its own
//! 2×2 covariance (from the projection), so the measurement noise is known and only the process
//! noise `Q` (per frame step, shared by all tracks) is estimated: the E-step smooths every track,
//! the M-step sets `Q` to the mean of the smoothed transition residuals' second moments.

use nalgebra::{Matrix2, Matrix2x4, Matrix4, Vector2, Vector4};
use serde::Serialize;

/// One observed position of a track.
#[derive(Clone, Debug, PartialEq)]
pub struct Observation {
    pub frame: usize,
    /// East, north, metres.
    pub position: Vector2<f64>,
    /// Its covariance, m².
    pub cov: Matrix2<f64>,
}

/// A smoothed state.
#[derive(Clone, Debug, PartialEq)]
pub struct State {
    pub frame: usize,
    pub position: Vector2<f64>,
    pub velocity: Vector2<f64>,
    /// Covariance of `(e, n, v_e, v_n)`.
    pub cov: Matrix4<f64>,
    /// Whether this frame had an observation.
    pub observed: bool,
    /// The position block of `Cov(xₖ, xₖ₊₁ | all)` with the next frame's state (zero at a
    /// track's last frame, and where nothing was smoothed).
    pub cov_next: Matrix2<f64>,
}

/// How `Q` is constrained in the M-step.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, serde::Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum NoiseModel {
    /// White acceleration noise per axis (continuous white-noise acceleration, spectral density
    /// `q` per axis: `Q = q [[dt³/3, dt²/2], [dt²/2, dt]]`): two parameters, well determined.
    WhiteAcceleration,
    /// Any symmetric positive definite 4×4 matrix (the paper's closed form). Its position part
    /// is weakly determined when the observations are noisier than the process.
    Full,
    /// Independent position and velocity noise per axis.
    Diagonal,
}

impl std::str::FromStr for NoiseModel {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, String> {
        match s {
            "white_acceleration" => Ok(NoiseModel::WhiteAcceleration),
            "full" => Ok(NoiseModel::Full),
            "diagonal" => Ok(NoiseModel::Diagonal),
            _ => Err(format!(
                "expected 'white_acceleration', 'full' or 'diagonal', got '{s}'"
            )),
        }
    }
}

/// The 2×2 shape of white-acceleration noise over one axis' (position, velocity) for a step `dt`.
fn white_acceleration_shape(dt: f64) -> Matrix2<f64> {
    Matrix2::new(dt * dt * dt / 3.0, dt * dt / 2.0, dt * dt / 2.0, dt)
}

/// `Q` of white acceleration with spectral densities `qe`, `qn` (m²/s³).
pub fn white_acceleration_q(dt: f64, qe: f64, qn: f64) -> Matrix4<f64> {
    let g = white_acceleration_shape(dt);
    let mut q = Matrix4::zeros();
    for (axis, d) in [(0, qe), (1, qn)] {
        for (a, b) in [(0, 0), (0, 1), (1, 0), (1, 1)] {
            q[(axis + 2 * a, axis + 2 * b)] = d * g[(a, b)];
        }
    }
    q
}

/// Settings of the smoother and of EM.
#[derive(Clone, Debug)]
pub struct SmoothSettings {
    /// Frame interval, seconds.
    pub dt: f64,
    /// Initial process noise (the paper's): position and velocity standard deviations per step;
    /// for white acceleration, the velocity one sets the initial spectral density.
    pub q_position_m: f64,
    pub q_velocity_m_s: f64,
    /// Estimate `Q` by EM (else keep the initial one).
    pub em: bool,
    pub model: NoiseModel,
    pub max_iterations: usize,
    /// Stop when `‖Qₖ₊₁ − Qₖ‖ / ‖Qₖ‖` falls below this (over an accelerated step).
    pub tolerance: f64,
    /// Prior standard deviation of a track's initial velocity, m/s.
    pub initial_speed_sd: f64,
}

impl Default for SmoothSettings {
    fn default() -> Self {
        SmoothSettings {
            dt: 0.04,
            q_position_m: 0.5,
            q_velocity_m_s: 0.25,
            em: true,
            model: NoiseModel::WhiteAcceleration,
            max_iterations: 300,
            tolerance: 1e-6,
            initial_speed_sd: 10.0,
        }
    }
}

/// The result of smoothing a set of tracks.
#[derive(Clone, Debug)]
pub struct Smoothed {
    pub tracks: Vec<Vec<State>>,
    /// The process noise used (estimated when EM ran), per frame step.
    pub q: Matrix4<f64>,
    pub em_iterations: usize,
    pub converged: bool,
    /// Log-likelihood of the observations under the final model.
    pub log_likelihood: f64,
}

fn h() -> Matrix2x4<f64> {
    Matrix2x4::new(1.0, 0.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0)
}

/// Sufficient statistics of one track's smoothing for the M-step.
struct Pass {
    states: Vec<State>,
    /// Σ over transitions of E[(xₜ − F xₜ₋₁)(xₜ − F xₜ₋₁)ᵀ].
    residual_moment: Matrix4<f64>,
    transitions: usize,
    log_likelihood: f64,
}

/// `F x` for the constant-velocity transition over `dt` (state: east, north, their velocities).
fn f_x(x: &Vector4<f64>, dt: f64) -> Vector4<f64> {
    Vector4::new(x[0] + dt * x[2], x[1] + dt * x[3], x[2], x[3])
}

/// `F P`: row blocks (top + dt·bottom, bottom).
fn f_p(p: &Matrix4<f64>, dt: f64) -> Matrix4<f64> {
    let mut out = *p;
    for c in 0..4 {
        out[(0, c)] += dt * p[(2, c)];
        out[(1, c)] += dt * p[(3, c)];
    }
    out
}

/// `P Fᵀ`: column blocks (left + dt·right, right).
fn p_ft(p: &Matrix4<f64>, dt: f64) -> Matrix4<f64> {
    let mut out = *p;
    for r in 0..4 {
        out[(r, 0)] += dt * p[(r, 2)];
        out[(r, 1)] += dt * p[(r, 3)];
    }
    out
}

/// Filters and smooths one track (observations sorted by frame, frames distinct). The
/// transition's and the observation's structure (`F = [I dt·I; 0 I]`, `H = [I 0]`) is written
/// out: general 4×4 products made smoothing most of a merge's time.
fn smooth_track(
    obs: &[Observation],
    q: &Matrix4<f64>,
    s: &SmoothSettings,
    keep_states: bool,
) -> Option<Pass> {
    let first = obs.first()?;
    let last = obs.last()?;
    let n = last.frame - first.frame + 1;
    let dt = s.dt;
    let mut by_frame: Vec<Option<&Observation>> = vec![None; n];
    for o in obs {
        by_frame[o.frame - first.frame] = Some(o);
    }
    // Forward: predicted (x⁻, P⁻) and filtered (x, P) at every frame.
    let mut xp = Vec::with_capacity(n);
    let mut pp = Vec::with_capacity(n);
    let mut xf: Vec<Vector4<f64>> = Vec::with_capacity(n);
    let mut pf: Vec<Matrix4<f64>> = Vec::with_capacity(n);
    let mut ll = 0.0;
    let v0 = s.initial_speed_sd * s.initial_speed_sd;
    for k in 0..n {
        let (x_pred, p_pred) = if k == 0 {
            let mut p0 = Matrix4::zeros();
            // A diffuse prior: the first observation sets the position.
            p0.fixed_view_mut::<2, 2>(0, 0)
                .copy_from(&(Matrix2::identity() * 1e4));
            p0[(2, 2)] = v0;
            p0[(3, 3)] = v0;
            (
                Vector4::new(first.position.x, first.position.y, 0.0, 0.0),
                p0,
            )
        } else {
            (f_x(&xf[k - 1], dt), p_ft(&f_p(&pf[k - 1], dt), dt) + q)
        };
        let (x, p) = match by_frame[k] {
            Some(o) => {
                let innov = o.position - x_pred.fixed_rows::<2>(0);
                // H P⁻ Hᵀ + R, and P⁻ Hᵀ (P⁻'s first two columns).
                let s_cov: Matrix2<f64> = p_pred.fixed_view::<2, 2>(0, 0) + o.cov;
                let s_inv = s_cov.try_inverse()?;
                let pht: nalgebra::Matrix4x2<f64> = p_pred.fixed_columns::<2>(0).into();
                let gain = pht * s_inv;
                if k > 0 {
                    ll -= 0.5
                        * (innov.dot(&(s_inv * innov))
                            + s_cov.determinant().ln()
                            + 2.0 * std::f64::consts::TAU.ln());
                }
                // Joseph form, expanded: (I − KH)P(I − KH)ᵀ + KRKᵀ = P − KHP − (KHP)ᵀ + KSKᵀ;
                // symmetric by construction, and positive as long as Joseph's is.
                let ikh = Matrix4::identity() - gain * h();
                let p = ikh * p_pred * ikh.transpose() + gain * o.cov * gain.transpose();
                (x_pred + gain * innov, p)
            }
            None => (x_pred, p_pred),
        };
        xp.push(x_pred);
        pp.push(p_pred);
        xf.push(x);
        pf.push(p);
    }
    // Backward (RTS), in place: xf and pf become the smoothed states; with the lag-one
    // covariances for the M-step.
    let mut moment = Matrix4::zeros();
    let mut cov_next = vec![Matrix2::zeros(); n];
    for k in (0..n.saturating_sub(1)).rev() {
        let pp_inv = pp[k + 1].try_inverse()?;
        let j = p_ft(&pf[k], dt) * pp_inv;
        let x_next = xf[k + 1];
        let p_next = pf[k + 1];
        let x = xf[k] + j * (x_next - xp[k + 1]);
        let mut p = pf[k] + j * (p_next - pp[k + 1]) * j.transpose();
        p = (p + p.transpose()) * 0.5;
        // Cov(xₖ₊₁, xₖ | all) = Pₖ₊₁ Jₖᵀ.
        let cross = p_next * j.transpose();
        cov_next[k] = cross.fixed_view::<2, 2>(0, 0).transpose();
        let d = x_next - f_x(&x, dt);
        let f_cross_t = f_p(&cross.transpose(), dt);
        moment +=
            d * d.transpose() + p_next - f_cross_t.transpose() - f_cross_t + p_ft(&f_p(&p, dt), dt);
        xf[k] = x;
        pf[k] = p;
    }
    let states = if keep_states {
        (0..n)
            .map(|k| State {
                frame: first.frame + k,
                position: Vector2::new(xf[k][0], xf[k][1]),
                velocity: Vector2::new(xf[k][2], xf[k][3]),
                cov: pf[k],
                observed: by_frame[k].is_some(),
                cov_next: cov_next[k],
            })
            .collect()
    } else {
        Vec::new()
    };
    Some(Pass {
        states,
        residual_moment: moment,
        transitions: n - 1,
        log_likelihood: ll,
    })
}

/// The initial `Q`: the settings' position and velocity variances on the diagonal, or for white
/// acceleration the density giving that velocity variance per step.
pub fn initial_q(s: &SmoothSettings) -> Matrix4<f64> {
    let (a, b) = (
        s.q_position_m * s.q_position_m,
        s.q_velocity_m_s * s.q_velocity_m_s,
    );
    match s.model {
        NoiseModel::WhiteAcceleration => white_acceleration_q(s.dt, b / s.dt, b / s.dt),
        _ => Matrix4::from_diagonal(&Vector4::new(a, a, b, b)),
    }
}

/// The M-step: the `Q` of the model closest (in likelihood) to the mean transition moment `m`.
fn m_step(m: &Matrix4<f64>, model: NoiseModel, dt: f64) -> Matrix4<f64> {
    let m = (m + m.transpose()) * 0.5;
    let mut q = match model {
        NoiseModel::Full => m,
        NoiseModel::Diagonal => Matrix4::from_diagonal(&m.diagonal()),
        NoiseModel::WhiteAcceleration => {
            // For a Gaussian of covariance q·G, the likelihood is largest at q = tr(G⁻¹ M) / 2.
            let g_inv = white_acceleration_shape(dt).try_inverse().expect("dt > 0");
            let axis =
                |i: usize| Matrix2::new(m[(i, i)], m[(i, i + 2)], m[(i + 2, i)], m[(i + 2, i + 2)]);
            let (qe, qn) = (
                (g_inv * axis(0)).trace() / 2.0,
                (g_inv * axis(1)).trace() / 2.0,
            );
            white_acceleration_q(dt, qe.max(1e-12), qn.max(1e-12))
        }
    };
    // Keep Q positive definite (a degenerate data set could make it singular).
    for k in 0..4 {
        q[(k, k)] = q[(k, k)].max(1e-12);
    }
    q
}

/// Tracks' observations (each sorted by frame, one observation per frame), given in their
/// order a batch at a time, as often as asked: EM passes over all of them many times, and a
/// long video's are read back from disk each time rather than held.
pub trait ObservationSource {
    fn each_batch(&self, f: &mut dyn FnMut(&[Vec<Observation>])) -> std::io::Result<()>;
}

impl ObservationSource for &[Vec<Observation>] {
    fn each_batch(&self, f: &mut dyn FnMut(&[Vec<Observation>])) -> std::io::Result<()> {
        f(self);
        Ok(())
    }
}

/// The model a smoother fitted to all the tracks: what smoothing a batch needs.
#[derive(Clone, Debug)]
pub struct Fit {
    /// The process noise (estimated when EM ran), per frame step.
    pub q: Matrix4<f64>,
    pub em_iterations: usize,
    pub converged: bool,
    /// Log-likelihood of the observations under the final model.
    pub log_likelihood: f64,
}

/// Estimates `Q` by EM over all the tracks when asked (else keeps the initial one). EM's passes
/// need only each track's moments, summed in the tracks' order whatever the batches.
pub fn fit(src: &dyn ObservationSource, s: &SmoothSettings) -> std::io::Result<Fit> {
    let mut q = initial_q(s);
    let mut iterations = 0;
    let mut converged = !s.em;
    let run = |q: &Matrix4<f64>| -> std::io::Result<Vec<Option<Pass>>> {
        // Tracks are independent given Q: in parallel, in their order.
        use rayon::prelude::*;
        let mut passes = Vec::new();
        src.each_batch(&mut |batch| {
            let p: Vec<Option<Pass>> = batch
                .par_iter()
                .map(|t| smooth_track(t, q, s, false))
                .collect();
            passes.extend(p);
        })?;
        Ok(passes)
    };
    let mut passes = run(&q)?;
    // One EM step: the M-step on the moments of the passes at the current Q.
    let em_step = |passes: &[Option<Pass>]| -> Option<Matrix4<f64>> {
        let (mut m, mut n) = (Matrix4::zeros(), 0usize);
        for p in passes.iter().flatten() {
            m += p.residual_moment;
            n += p.transitions;
        }
        (n > 0).then(|| m_step(&(m / n as f64), s.model, s.dt))
    };
    let ll = |passes: &[Option<Pass>]| -> f64 {
        passes.iter().flatten().map(|p| p.log_likelihood).sum()
    };
    if s.em {
        // EM accelerated by SQUAREM (Varadhan & Roland 2008): two EM steps give a direction
        // and a step length; the extrapolated Q is kept only if it is valid and not worse.
        while iterations < s.max_iterations {
            let Some(q1) = em_step(&passes) else {
                converged = true;
                break;
            };
            let p1 = run(&q1)?;
            let Some(q2) = em_step(&p1) else { break };
            let p2 = run(&q2)?;
            iterations += 2;
            let r = q1 - q;
            let v = q2 - q1 - r;
            let alpha = if v.norm() > 0.0 {
                (-r.norm() / v.norm()).min(-1.0)
            } else {
                -1.0
            };
            let extrapolated = q - r * (2.0 * alpha) + v * (alpha * alpha);
            let valid = extrapolated.cholesky().is_some()
                && (extrapolated - extrapolated.transpose()).norm() < 1e-9 * extrapolated.norm();
            let (mut next, mut next_passes) = (q2, p2);
            if valid && alpha < -1.0 {
                let pe = run(&extrapolated)?;
                if let Some(qe) = em_step(&pe) {
                    let pq = run(&qe)?;
                    iterations += 1;
                    if ll(&pq) >= ll(&next_passes) {
                        (next, next_passes) = (qe, pq);
                    }
                }
            }
            let change = (next - q).norm() / q.norm().max(1e-300);
            q = next;
            passes = next_passes;
            if change < s.tolerance {
                converged = true;
                break;
            }
        }
    }
    Ok(Fit {
        q,
        em_iterations: iterations,
        converged,
        // The passes were made at the final Q.
        log_likelihood: ll(&passes),
    })
}

/// Smooths a batch of tracks under a fitted model. Tracks with a single observation pass
/// through unsmoothed (velocity unknown).
pub fn smooth_batch(tracks: &[Vec<Observation>], fit: &Fit, s: &SmoothSettings) -> Vec<Vec<State>> {
    use rayon::prelude::*;
    tracks
        .par_iter()
        .map(|t| match smooth_track(t, &fit.q, s, true) {
            Some(p) => p.states,
            None => t
                .iter()
                .map(|o| {
                    let mut cov = Matrix4::zeros();
                    cov.fixed_view_mut::<2, 2>(0, 0).copy_from(&o.cov);
                    cov[(2, 2)] = f64::INFINITY;
                    cov[(3, 3)] = f64::INFINITY;
                    State {
                        frame: o.frame,
                        position: o.position,
                        velocity: Vector2::zeros(),
                        cov,
                        observed: true,
                        cov_next: Matrix2::zeros(),
                    }
                })
                .collect(),
        })
        .collect()
}

/// Smooths every track held in memory (each sorted by frame, one observation per frame),
/// estimating `Q` by EM when asked: [`fit`], then [`smooth_batch`].
pub fn smooth(tracks: &[Vec<Observation>], s: &SmoothSettings) -> Smoothed {
    KalmanRts(s.clone()).smooth(tracks)
}

/// Turns observed tracks into smoothed states; chosen by name in a project. The model is
/// fitted over all the tracks first, then the tracks are smoothed a batch at a time.
pub trait Smoother: Send + Sync {
    fn fit(&self, src: &dyn ObservationSource) -> std::io::Result<Fit>;
    fn smooth_batch(&self, fit: &Fit, tracks: &[Vec<Observation>]) -> Vec<Vec<State>>;

    /// Both, for tracks held in memory.
    fn smooth(&self, tracks: &[Vec<Observation>]) -> Smoothed {
        let fit = match self.fit(&tracks) {
            Ok(f) => f,
            Err(e) => unreachable!("tracks in memory are read without error: {e}"),
        };
        Smoothed {
            tracks: self.smooth_batch(&fit, tracks),
            q: fit.q,
            em_iterations: fit.em_iterations,
            converged: fit.converged,
            log_likelihood: fit.log_likelihood,
        }
    }
}

/// The constant-velocity Kalman filter and RTS smoother, with EM.
pub struct KalmanRts(pub SmoothSettings);

impl Smoother for KalmanRts {
    fn fit(&self, src: &dyn ObservationSource) -> std::io::Result<Fit> {
        fit(src, &self.0)
    }
    fn smooth_batch(&self, fit: &Fit, tracks: &[Vec<Observation>]) -> Vec<Vec<State>> {
        smooth_batch(tracks, fit, &self.0)
    }
}

/// No smoothing: the observations themselves, with velocities by central differences.
pub struct Unsmoothed {
    pub dt: f64,
}

impl Smoother for Unsmoothed {
    fn fit(&self, _: &dyn ObservationSource) -> std::io::Result<Fit> {
        Ok(Fit {
            q: Matrix4::zeros(),
            em_iterations: 0,
            converged: true,
            log_likelihood: f64::NAN,
        })
    }

    fn smooth_batch(&self, _: &Fit, tracks: &[Vec<Observation>]) -> Vec<Vec<State>> {
        tracks
            .iter()
            .map(|t| {
                (0..t.len())
                    .map(|k| {
                        let (a, b) = (&t[k.saturating_sub(1)], &t[(k + 1).min(t.len() - 1)]);
                        let span = (b.frame as f64 - a.frame as f64) * self.dt;
                        let velocity = if span > 0.0 {
                            (b.position - a.position) / span
                        } else {
                            Vector2::zeros()
                        };
                        let mut cov = Matrix4::zeros();
                        cov.fixed_view_mut::<2, 2>(0, 0).copy_from(&t[k].cov);
                        State {
                            frame: t[k].frame,
                            position: t[k].position,
                            velocity,
                            cov,
                            observed: true,
                            cov_next: Matrix2::zeros(),
                        }
                    })
                    .collect()
            })
            .collect()
    }
}

/// The share of the observations' stated variance that is not white noise but persists from
/// frame to frame (where a detector puts a head within a body box as the gait swings, how a
/// hat's blob sits on a head): the smoother follows it as if it were motion and cannot average
/// it away. `None` without enough to tell.
///
/// The white part shows in the change of the residual `r = y − x̂` from one frame to the next:
/// the smoothed track, the motion it misses and any slow error hardly change in a frame, white
/// noise of covariance `s·C` changes by `s·(Cₖ + Cₖ₊₁)`. So, with `u = (Cₖ + Cₖ₊₁)^-½ Δr`, `s`
/// is the mean of `u uᵀ` over consecutive observed frames, and the share is `I − s`. (The
/// residuals themselves would also count the motion a stiff smoother misses as white.) It is
/// found per direction (a matrix in the stated covariance's whitened frame): the error along a
/// walk (the gait) and along the view (a body's height) persist differently, and one number
/// would let the whiter direction hide the other's persistence.
pub fn persistent_share(
    observations: &[Vec<Observation>],
    tracks: &[Vec<State>],
) -> Option<Persistent> {
    let mut w = WhiteShare::default();
    for (obs, states) in observations.iter().zip(tracks) {
        w.add_smoothed(obs, states);
    }
    w.persistent()
}

/// The persistent share of stated covariances, from residuals against a smoothed track, per
/// track `(frame, residual, stated covariance)` in frame order (see [`persistent_share`]).
/// `None` with fewer than 20 pairs.
pub fn persistent_of<I, T>(tracks: I) -> Option<Persistent>
where
    I: IntoIterator<Item = T>,
    T: AsRef<[(usize, Vector2<f64>, Matrix2<f64>)]>,
{
    let mut w = WhiteShare::default();
    for t in tracks {
        w.add(t.as_ref());
    }
    w.persistent()
}

/// `f` of a symmetric 2×2 matrix's eigenvalues, `None` where one is not finite.
fn map_eigen(m: &Matrix2<f64>, f: impl Fn(f64) -> f64) -> Option<Matrix2<f64>> {
    let e = nalgebra::SymmetricEigen::new(0.5 * (m + m.transpose()));
    let d = e.eigenvalues.map(f);
    d.iter()
        .all(|v| v.is_finite())
        .then(|| e.eigenvectors * Matrix2::from_diagonal(&d) * e.eigenvectors.transpose())
}

/// The persistent share `P` of stated covariances, in their whitened frame: the persistent
/// part of a stated `C` is `C^½ P C^½`. Its eigenvalues are in [0, 1].
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Persistent(pub Matrix2<f64>);

impl Persistent {
    /// Nothing persists.
    pub fn none() -> Persistent {
        Persistent(Matrix2::zeros())
    }

    /// The persistent part of a stated covariance.
    pub fn of(&self, cov: &Matrix2<f64>) -> Matrix2<f64> {
        match map_eigen(cov, |v| v.max(0.0).sqrt()) {
            Some(half) => {
                let m = half * self.0 * half;
                0.5 * (m + m.transpose())
            }
            None => Matrix2::zeros(),
        }
    }

    /// The share averaged over the two directions (the report's one number).
    pub fn mean(&self) -> f64 {
        0.5 * self.0.trace()
    }
}

/// [`persistent_share`] summed a track at a time (a long video's tracks are smoothed a batch at
/// a time).
#[derive(Clone, Copy, Debug, Default)]
pub struct WhiteShare {
    sum: Matrix2<f64>,
    n: usize,
}

impl WhiteShare {
    /// One track's residuals `(frame, residual, stated covariance)` in frame order, against a
    /// track that hardly moves with one observation (white noise then changes the residual by
    /// the sum of two frames' covariances).
    pub fn add(&mut self, residuals: &[(usize, Vector2<f64>, Matrix2<f64>)]) {
        for w in residuals.windows(2) {
            let ((f0, r0, c0), (f1, r1, c1)) = (w[0], w[1]);
            if f1 == f0 + 1 {
                self.add_change(r1 - r0, &(c0 + c1));
            }
        }
    }

    /// One residual change against what white noise would make it, `expected`.
    fn add_change(&mut self, change: Vector2<f64>, expected: &Matrix2<f64>) {
        let inv_half = map_eigen(
            expected,
            |v| {
                if v > 0.0 { v.sqrt().recip() } else { f64::NAN }
            },
        );
        if let Some(inv_half) = inv_half {
            let u = inv_half * change;
            self.sum += u * u.transpose();
            self.n += 1;
        }
    }

    /// One track's observations against its smoothed states. The smoothed track follows the
    /// observations where the process noise is large, and takes part of their white noise
    /// with it: what white noise leaves in the residual's change is `Cₖ + Cₖ₊₁ − Pₖ − Pₖ₊₁ +
    /// Pₖ,ₖ₊₁ + Pₖ₊₁,ₖ` (the smoothed error is uncorrelated with the observations, so
    /// `Cov(rₖ, rₖ₊₁) = −Pₖ,ₖ₊₁`). Measured against the stated sum alone, a closely following
    /// smoother would make white noise look persistent.
    pub fn add_smoothed(&mut self, obs: &[Observation], states: &[State]) {
        fn at<'a>(o: &'a Observation, states: &'a [State]) -> Option<(&'a Observation, &'a State)> {
            let i = states.binary_search_by_key(&o.frame, |s| s.frame).ok()?;
            Some((o, &states[i]))
        }
        for w in obs.windows(2) {
            let (Some((o0, s0)), Some((o1, s1))) = (at(&w[0], states), at(&w[1], states)) else {
                continue;
            };
            if o1.frame != o0.frame + 1 {
                continue;
            }
            let stated = o0.cov + o1.cov;
            let p0: Matrix2<f64> = s0.cov.fixed_view::<2, 2>(0, 0).into();
            let p1: Matrix2<f64> = s1.cov.fixed_view::<2, 2>(0, 0).into();
            let left = stated - p0 - p1 + s0.cov_next + s0.cov_next.transpose();
            // Kept above a twentieth of the stated sum: where the track follows the
            // observations entirely, their change says nothing either way.
            let floor = 0.05 * stated.trace() / 2.0;
            let Some(expected) = map_eigen(&left, |v| v.max(floor)) else {
                continue;
            };
            let change = (o1.position - s1.position) - (o0.position - s0.position);
            self.add_change(change, &expected);
        }
    }

    /// The white share, a matrix in the whitened frame with eigenvalues at most 1; `None` with
    /// fewer than 20 pairs.
    pub fn share(&self) -> Option<Matrix2<f64>> {
        if self.n < 20 {
            return None;
        }
        map_eigen(&(self.sum / self.n as f64), |v| v.clamp(0.0, 1.0))
    }

    /// `I −` the white share: the persistent share ([`persistent_share`]).
    pub fn persistent(&self) -> Option<Persistent> {
        self.share().map(|w| Persistent(Matrix2::identity() - w))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn structured_transition_products_are_the_matrix_products() {
        let dt = 0.04;
        let mut f = Matrix4::identity();
        f[(0, 2)] = dt;
        f[(1, 3)] = dt;
        let p = Matrix4::from_fn(|r, c| (r * 4 + c) as f64 * 0.37 - 1.1);
        let x = Vector4::new(1.0, -2.0, 3.0, 0.5);
        assert!((f_x(&x, dt) - f * x).norm() < 1e-15);
        assert!((f_p(&p, dt) - f * p).norm() < 1e-14);
        assert!((p_ft(&p, dt) - p * f.transpose()).norm() < 1e-14);
    }
    use rand::SeedableRng;
    use rand_distr::{Distribution, Normal};

    /// Constant-velocity tracks with process noise `q` per step and observation σ `r`.
    fn simulate(
        q: &Matrix4<f64>,
        r: f64,
        tracks: usize,
        len: usize,
        seed: u64,
    ) -> (Vec<Vec<Observation>>, Vec<Vec<Vector2<f64>>>) {
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(seed);
        let chol = q.cholesky().unwrap().l();
        let std = Normal::new(0.0, 1.0).unwrap();
        let (mut obs, mut truth) = (Vec::new(), Vec::new());
        for t in 0..tracks {
            let mut x = Vector4::new(t as f64, 0.0, 3.5, 0.2);
            let (mut o, mut tr) = (Vec::new(), Vec::new());
            for k in 0..len {
                if k > 0 {
                    let w = Vector4::from_fn(|_, _| std.sample(&mut rng));
                    x = f_x(&x, 0.04) + chol * w;
                }
                tr.push(Vector2::new(x[0], x[1]));
                // Gaps: every 17th frame is missed.
                if k == 0 || k % 17 != 0 {
                    let z = Vector2::new(
                        x[0] + r * std.sample(&mut rng),
                        x[1] + r * std.sample(&mut rng),
                    );
                    o.push(Observation {
                        frame: k,
                        position: z,
                        cov: Matrix2::identity() * r * r,
                    });
                }
            }
            obs.push(o);
            truth.push(tr);
        }
        (obs, truth)
    }

    #[test]
    fn em_recovers_the_process_noise_and_intervals_cover_the_truth() {
        // Runners: white acceleration of 0.5 and 0.2 m/s² (√q over one second), 3 cm observations,
        // 25 frames per second.
        let q = white_acceleration_q(0.04, 0.25, 0.04);
        // 200 tracks of 12 s: enough that the estimate's own spread (about 3 %) is well inside 10 %.
        let (obs, truth) = simulate(&q, 0.03, 200, 300, 5);
        let out = smooth(&obs, &SmoothSettings::default());
        assert!(
            out.converged,
            "EM did not converge in {} iterations",
            out.em_iterations
        );
        for (k, truth_q) in [(0, 0.25), (1, 0.04)] {
            let est = out.q[(k + 2, k + 2)] / 0.04;
            let rel = est / truth_q - 1.0;
            assert!(
                rel.abs() < 0.1,
                "axis {k}: q off by {:.1} % ({est} vs {truth_q})",
                100.0 * rel
            );
        }
        // 95 % ellipses: χ²(2) = 5.991.
        let (mut inside, mut total) = (0, 0);
        for (states, tr) in out.tracks.iter().zip(&truth) {
            for st in states {
                let d = st.position - tr[st.frame];
                let c: Matrix2<f64> = st.cov.fixed_view::<2, 2>(0, 0).into();
                inside += usize::from(d.dot(&(c.try_inverse().unwrap() * d)) <= 5.991);
                total += 1;
            }
        }
        let coverage = inside as f64 / total as f64;
        println!(
            "EM: {} iterations, q = ({:.4}, {:.4}); coverage {coverage:.4}",
            out.em_iterations,
            out.q[(2, 2)] / 0.04,
            out.q[(3, 3)] / 0.04
        );
        assert!((0.93..=0.97).contains(&coverage), "coverage {coverage}");
    }

    #[test]
    fn the_paper_s_full_model_fits_as_well() {
        let q = white_acceleration_q(0.04, 0.25, 0.04);
        let (obs, _) = simulate(&q, 0.03, 30, 200, 6);
        let wa = smooth(&obs, &SmoothSettings::default());
        let full = smooth(
            &obs,
            &SmoothSettings {
                model: NoiseModel::Full,
                ..SmoothSettings::default()
            },
        );
        println!(
            "log-likelihood: white acceleration {:.2} ({} EM steps), full {:.2} ({} EM steps)",
            wa.log_likelihood, wa.em_iterations, full.log_likelihood, full.em_iterations
        );
        // The full model contains the white-acceleration one; EM approaches its optimum slowly
        // along weakly determined directions, so allow a fraction of a nat.
        assert!(full.log_likelihood >= wa.log_likelihood - 1.0);
        assert!(full.q.cholesky().is_some());
        for k in [2, 3] {
            let rel = full.q[(k, k)] / q[(k, k)] - 1.0;
            assert!(rel.abs() < 0.25, "Q[{k}{k}] off by {:.1} %", 100.0 * rel);
        }
    }

    /// White observation noise leaves nothing persistent; an error that drifts slowly (a
    /// Gauss–Markov process of one second) and holds half of the stated variance is found as
    /// about half, and adding it back covers the truth.
    #[test]
    fn persistent_share_finds_the_error_the_smoother_follows() {
        let q = white_acceleration_q(0.04, 0.25, 0.04);
        let (obs, truth) = simulate(&q, 0.03, 100, 300, 11);
        let out = smooth(&obs, &SmoothSettings::default());
        let white = persistent_share(&obs, &out.tracks).unwrap();
        assert!(white.mean() < 0.1, "{white:?}");

        // The same tracks, observed with white noise of 3 cm and a drift of 3 cm (stated as
        // one 4.24 cm σ, as a detector's error model would state its total).
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(12);
        let std = Normal::new(0.0, 1.0).unwrap();
        let rho: f64 = (-0.04f64).exp(); // one second at 25 frames per second
        let sd = 0.03;
        let obs2: Vec<Vec<Observation>> = obs
            .iter()
            .zip(&truth)
            .map(|(o, tr)| {
                let mut drift = Vector2::new(sd * std.sample(&mut rng), sd * std.sample(&mut rng));
                let mut last = 0;
                o.iter()
                    .map(|ob| {
                        for _ in last..ob.frame {
                            let w = Vector2::new(std.sample(&mut rng), std.sample(&mut rng));
                            drift = drift * rho + w * sd * (1.0 - rho * rho).sqrt();
                        }
                        last = ob.frame;
                        let white = Vector2::new(std.sample(&mut rng), std.sample(&mut rng)) * 0.03;
                        Observation {
                            frame: ob.frame,
                            position: tr[ob.frame] + white + drift,
                            cov: Matrix2::identity() * 2.0 * 0.03 * 0.03,
                        }
                    })
                    .collect()
            })
            .collect();
        let out2 = smooth(&obs2, &SmoothSettings::default());
        let share = persistent_share(&obs2, &out2.tracks).unwrap();
        assert!((0.35..0.75).contains(&share.mean()), "{share:?}");
        let (mut inside, mut plain, mut total) = (0, 0, 0);
        for ((states, tr), o) in out2.tracks.iter().zip(&truth).zip(&obs2) {
            for st in states.iter().filter(|s| s.observed) {
                let d = st.position - tr[st.frame];
                let c: Matrix2<f64> = st.cov.fixed_view::<2, 2>(0, 0).into();
                let stated = o[0].cov;
                let with = c + share.of(&stated);
                inside += usize::from(d.dot(&(with.try_inverse().unwrap() * d)) <= 5.991);
                plain += usize::from(d.dot(&(c.try_inverse().unwrap() * d)) <= 5.991);
                total += 1;
            }
        }
        let (inside, plain) = (inside as f64 / total as f64, plain as f64 / total as f64);
        // Measured: a share of 0.49, 96.5 % inside with it and 41 % without.
        assert!(
            (0.92..0.99).contains(&inside),
            "with the persistent part: {inside}"
        );
        assert!(plain < 0.6, "without it: {plain}");
    }

    /// Walkers that steer hard (a large process noise): the smoothed track follows the white
    /// observation noise and takes much of it along, so its residuals change little from frame
    /// to frame. Measured against the stated covariances alone that looked persistent (a share
    /// of 0.6); measured against what the smoother leaves of white noise it is not (0.006), and
    /// the smoothed covariance alone covers the truth.
    #[test]
    fn white_noise_a_closely_following_smoother_takes_along_is_not_persistent() {
        let q = white_acceleration_q(0.04, 400.0, 400.0);
        let (obs, truth) = simulate(&q, 0.03, 100, 300, 31);
        let out = smooth(&obs, &SmoothSettings::default());
        let share = persistent_share(&obs, &out.tracks).unwrap();
        assert!(share.mean() < 0.1, "{share:?}");
        // The stated sum alone, as before: most of the white noise called persistent.
        let naive = persistent_of(out.tracks.iter().zip(&obs).map(|(states, o)| {
            o.iter()
                .map(|ob| {
                    let st = &states[ob.frame - states[0].frame];
                    (ob.frame, ob.position - st.position, ob.cov)
                })
                .collect::<Vec<_>>()
        }))
        .unwrap();
        assert!(naive.mean() > 0.3, "{naive:?}");
        let (mut inside, mut total) = (0, 0);
        for ((states, tr), o) in out.tracks.iter().zip(&truth).zip(&obs) {
            for st in states.iter().filter(|s| s.observed) {
                let d = st.position - tr[st.frame];
                let c: Matrix2<f64> = st.cov.fixed_view::<2, 2>(0, 0).into();
                let with = c + share.of(&o[0].cov);
                inside += usize::from(d.dot(&(with.try_inverse().unwrap() * d)) <= 5.991);
                total += 1;
            }
        }
        let inside = inside as f64 / total as f64;
        assert!((0.93..0.975).contains(&inside), "{inside}");
    }

    /// A drift along one direction only (along a walk, say) is found there, and not across it,
    /// where the error is white: one pooled number would give each half.
    #[test]
    fn persistent_share_is_found_per_direction() {
        let q = white_acceleration_q(0.04, 0.25, 0.04);
        let (obs, truth) = simulate(&q, 0.03, 100, 300, 21);
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(22);
        let std = Normal::new(0.0, 1.0).unwrap();
        let (rho, sd): (f64, f64) = ((-0.04f64).exp(), 0.03);
        // East: white 3 cm and a drift of 3 cm; north: white 3 cm. Stated as their totals.
        let stated = Matrix2::new(2.0 * sd * sd, 0.0, 0.0, sd * sd);
        let obs2: Vec<Vec<Observation>> = obs
            .iter()
            .zip(&truth)
            .map(|(o, tr)| {
                let mut drift = sd * std.sample(&mut rng);
                let mut last = 0;
                o.iter()
                    .map(|ob| {
                        for _ in last..ob.frame {
                            drift =
                                drift * rho + std.sample(&mut rng) * sd * (1.0 - rho * rho).sqrt();
                        }
                        last = ob.frame;
                        let white = Vector2::new(std.sample(&mut rng), std.sample(&mut rng)) * sd;
                        Observation {
                            frame: ob.frame,
                            position: tr[ob.frame] + white + Vector2::new(drift, 0.0),
                            cov: stated,
                        }
                    })
                    .collect()
            })
            .collect();
        let out = smooth(&obs2, &SmoothSettings::default());
        let p = persistent_share(&obs2, &out.tracks).unwrap();
        assert!((0.35..0.75).contains(&p.0[(0, 0)]), "{p:?}");
        assert!(p.0[(1, 1)] < 0.1 && p.0[(0, 1)].abs() < 0.1, "{p:?}");
        let added = p.of(&stated);
        assert!(added[(1, 1)] < 0.1 * sd * sd, "{added}");
    }

    /// Tracks given a few at a time, as a long video's are read back from disk.
    struct InBatches<'a>(&'a [Vec<Observation>], usize);

    impl ObservationSource for InBatches<'_> {
        fn each_batch(&self, f: &mut dyn FnMut(&[Vec<Observation>])) -> std::io::Result<()> {
            self.0.chunks(self.1).for_each(f);
            Ok(())
        }
    }

    #[test]
    fn em_over_batches_is_em_over_all_the_tracks_to_the_bit() {
        let q = white_acceleration_q(0.04, 0.25, 0.04);
        let (mut obs, _) = simulate(&q, 0.03, 40, 120, 9);
        // A gap, a single observation and an empty track among them.
        obs[3].retain(|o| !(40..55).contains(&o.frame));
        obs[5].truncate(1);
        obs[7].clear();
        let s = SmoothSettings::default();
        let whole = smooth(&obs, &s);
        let k = KalmanRts(s.clone());
        let f = k.fit(&InBatches(&obs, 7)).unwrap();
        assert!(whole.em_iterations > 2);
        assert_eq!(f.em_iterations, whole.em_iterations);
        assert_eq!(f.q, whole.q);
        assert_eq!(f.log_likelihood.to_bits(), whole.log_likelihood.to_bits());
        let states: Vec<Vec<State>> = obs.chunks(7).flat_map(|b| k.smooth_batch(&f, b)).collect();
        assert_eq!(states, whole.tracks);
        // The persistent share summed a track at a time: the same.
        let mut w = WhiteShare::default();
        for (o, st) in obs.iter().zip(&states) {
            w.add_smoothed(o, st);
        }
        assert_eq!(w.persistent(), persistent_share(&obs, &whole.tracks));
    }
}
