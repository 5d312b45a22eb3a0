//! The Levenberg–Marquardt trust-region loop (the strategy of Ceres) and its checks.

use super::covariance::{Freedom, Linearisation, from_normal};
use super::*;
use crate::optim::Damping;

pub(super) fn projection_error<const M: usize>(p: &Problem<M>, k: usize) -> BaError {
    let o = &p.observations[k];
    BaError::Projection {
        observation: k,
        image: o.camera,
        point: o.point,
    }
}

/// The decrease of the linearised cost along a step `δ` (in the own variables of the problem):
/// `−(Jδ)ᵀ(r + Jδ/2)` over the observations and the priors.
pub(super) fn model_decrease<const M: usize>(
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
        .with_min_len(GRAIN)
        .map(|k| {
            let (pk, ik) = lay.of(p, obs[k].camera);
            let jd = e.j_pose[k] * delta_cam.fixed_rows::<6>(pk)
                + e.ji(k) * delta_cam.fixed_rows::<M>(ik)
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
            let jd = q.sqrt_information * delta_point[q.point];
            -jd.dot(&(prior_residual(p, q) + jd * 0.5))
        })
        .sum();
    observed + centres + points
}

/// The problem moved by a step.
pub(super) fn stepped<const M: usize>(
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

/// Every prior names a point or image of the problem, has a finite position and a positive σ
/// (a positive-definite covariance), and no point prior is on a fixed point.
pub(super) fn check_priors<const M: usize>(p: &Problem<M>, priors: &Priors) -> Result<(), BaError> {
    let named = |kind: &str, index: usize, count: usize| {
        if index >= count {
            return Err(BaError::Invalid(format!(
                "a prior names {kind} {index} of {count}"
            )));
        }
        Ok(())
    };
    for q in &priors.points {
        named("point", q.point, p.points.len())?;
        let w = &q.sqrt_information;
        let lower = (0..3).all(|r| (r + 1..3).all(|c| w[(r, c)] == 0.0));
        if !(q.position.iter().all(|v| v.is_finite())
            && w.iter().all(|v| v.is_finite())
            && lower
            && w.diagonal().iter().all(|v| *v > 0.0))
        {
            return Err(BaError::Invalid(format!(
                "the prior on point {} needs a finite position and σ > 0 (a positive-definite \
                 covariance), got {:?} with W = {:?}",
                q.point,
                q.position,
                w.as_slice()
            )));
        }
        if p.fixed_points[q.point] {
            return Err(BaError::Invalid(format!(
                "point {} is held fixed and has a prior: free it or drop the prior",
                q.point
            )));
        }
    }
    for q in &priors.centres {
        named("image", q.camera, p.poses.len())?;
        let (x, s) = (&q.position, &q.sigma);
        if !(x.iter().all(|v| v.is_finite()) && s.iter().all(|v| v.is_finite() && *v > 0.0)) {
            return Err(BaError::Invalid(format!(
                "the prior on image {}\u{27}s centre needs a finite position and σ > 0, got {x:?} ± {s:?}",
                q.camera
            )));
        }
    }
    Ok(())
}

/// Adjusts the poses, intrinsics and points of the problem in place, with priors on some points
/// and camera centres (which also fix the gauge: without them the solution is defined up to a
/// similarity).
pub fn adjust<const M: usize>(
    p: &mut Problem<M>,
    model: &impl Projection<M>,
    priors: &Priors,
    settings: &BaSettings,
) -> Result<BaSummary, BaError> {
    // The loops of a small problem are not split and run on this thread; those of a larger one
    // run on a worker of the pool, whose loops hand work to the other workers directly instead of each
    // loop crossing from this thread into the pool and back.
    on_pool(p.observations.len(), || {
        adjust_on_pool(p, model, priors, settings, None).map(|r| r.0)
    })
}

/// [`adjust`], then [`covariance`] at the optimum (`sigma_px` as there), from the last normal
/// equations of the solver where they are those of the covariance (no priors, or the σ of the
/// observations given as 1), rather than linearising again.
pub fn adjust_with_covariance<const M: usize>(
    p: &mut Problem<M>,
    model: &impl Projection<M>,
    priors: &Priors,
    settings: &BaSettings,
    sigma_px: Option<f64>,
) -> Result<(BaSummary, CameraCovariance), BaError> {
    let reusable = (priors.points.is_empty() && priors.centres.is_empty()) || sigma_px == Some(1.0);
    if !reusable {
        let summary = adjust(p, model, priors, settings)?;
        let cov = covariance(p, model, priors, settings.loss, sigma_px)?;
        return Ok((summary, cov));
    }
    on_pool(p.observations.len(), || {
        let (summary, cov) = adjust_on_pool(p, model, priors, settings, Some(sigma_px))?;
        Ok((summary, cov.expect("asked for")))
    })
}

/// Runs `f` on this thread when the problem is small (its loops are not split), else on a
/// worker of the pool, whose loops hand work to the other workers directly instead of each
/// crossing from this thread into the pool and back.
pub(super) fn on_pool<R: Send>(observations: usize, f: impl FnOnce() -> R + Send) -> R {
    if observations <= GRAIN {
        f()
    } else {
        rayon::scope(|_| f())
    }
}

impl BaIteration {
    /// The record of an iteration, not accepted, with no change, ratio or time yet.
    fn at(
        iteration: usize,
        cost: f64,
        gradient_max_norm: f64,
        step_norm: f64,
        radius: f64,
    ) -> BaIteration {
        BaIteration {
            iteration,
            cost,
            cost_change: 0.0,
            gradient_max_norm,
            step_norm,
            rho: f64::NAN,
            radius,
            accepted: false,
            seconds: 0.0,
        }
    }
}

/// The one trust-region controller of the least-squares solvers, with the radii of the settings.
fn trust_region(s: &BaSettings) -> Damping {
    Damping::with_limits(
        1.0 / s.initial_radius,
        1.0 / s.max_radius,
        1.0 / s.min_radius,
    )
}

/// The problem, its priors and its memory checked before any work.
fn check_before<const M: usize>(
    p: &Problem<M>,
    priors: &Priors,
    settings: &BaSettings,
) -> Result<(), BaError> {
    p.check()?;
    check_priors(p, priors)?;
    let needed = p.memory_estimate(settings.linear_solver);
    if needed > settings.max_memory_bytes {
        return Err(BaError::TooLarge {
            needed,
            limit: settings.max_memory_bytes,
        });
    }
    Ok(())
}

/// The gradient of the unscaled problem, Jᵀr (the scaled one divided by the scales): its largest
/// component.
fn gradient_max_norm<const M: usize>(
    n: &Normal<M>,
    s_cam: &DVector<f64>,
    s_point: &[Vector3<f64>],
) -> f64 {
    n.g_cam.component_div(s_cam).amax().max(
        n.g_point
            .iter()
            .zip(s_point)
            .map(|(g, sc)| g.component_div(sc).amax())
            .fold(0.0, f64::max),
    )
}

/// The norm of every parameter.
fn x_norm<const M: usize>(p: &Problem<M>) -> f64 {
    (p.poses.iter().flatten().map(|v| v * v).sum::<f64>()
        + p.intrinsics.iter().flatten().map(|v| v * v).sum::<f64>()
        + p.points.iter().flatten().map(|v| v * v).sum::<f64>())
    .sqrt()
}

/// The step in the variables of the problem (the scaled Schur step times the scales) and the
/// decrease of the model, −(Jδ)ᵀ(r + Jδ/2); `None` when it cannot be computed.
#[allow(clippy::type_complexity)]
fn unscaled_step<const M: usize>(
    p: &Problem<M>,
    priors: &Priors,
    at: &Linearisation<M>,
    e: &Evaluation<M>,
    (d_cam, d_point): (&DVector<f64>, &[Vector3<f64>]),
    radius: f64,
    s: &BaSettings,
) -> Option<(DVector<f64>, Vec<Vector3<f64>>, f64)> {
    schur_step(
        p,
        at.st,
        at.lay,
        at.n,
        d_cam,
        d_point,
        radius,
        (s.linear_solver, s.iterative_tolerance),
    )
    .map(|(y_cam, y_point)| {
        let delta_cam = y_cam.component_mul(at.s_cam);
        let delta_point: Vec<Vector3<f64>> = y_point
            .iter()
            .zip(at.s_point)
            .map(|(y, sp)| y.component_mul(sp))
            .collect();
        let model_change = model_decrease(p, priors, at.lay, e, &delta_cam, &delta_point);
        (delta_cam, delta_point, model_change)
    })
}

/// The covariance at the solution from its last normal equations, with `sigma_px` or the σ of
/// the residuals.
fn covariance_at<const M: usize>(
    p: &Problem<M>,
    priors: &Priors,
    at: &Linearisation<M>,
    e: &Evaluation<M>,
    sigma_px: Option<f64>,
) -> Result<CameraCovariance, BaError> {
    let freedom = Freedom::of(p, priors, at.lay);
    let sigma = sigma_px.unwrap_or_else(|| freedom.sigma(&e.residuals));
    from_normal(p, at, &freedom, sigma, sigma * sigma)
}

/// The adjustment; with `covariance` (its `sigma_px`), the covariance from the last normal
/// equations too.
fn adjust_on_pool<const M: usize>(
    p: &mut Problem<M>,
    model: &impl Projection<M>,
    priors: &Priors,
    settings: &BaSettings,
    covariance: Option<Option<f64>>,
) -> Result<(BaSummary, Option<CameraCovariance>), BaError> {
    let start = Instant::now();
    check_before(p, priors, settings)?;
    let s = settings;
    let st = Structure::new(p);
    let lay = Layout::new(p);
    let mut e = evaluate(p, model, priors, s.loss).map_err(|k| projection_error(p, k))?;
    // The buffers of the trial evaluation, swapped with `e` when a step is accepted.
    let mut spare = e.clone();
    let initial_cost = e.cost;
    let (s_cam, s_point) = scales(p, priors, &st, &lay, &e);
    let mut n = scaled_normal(p, priors, &st, &lay, &e, &s_cam, &s_point);
    let diag_of = |n: &Normal<M>| clamped_diagonals(&lay, n, s.min_diagonal, s.max_diagonal);
    let (mut d_cam, mut d_point) = diag_of(&n);
    let gradient_max = |n: &Normal<M>| gradient_max_norm(n, &s_cam, &s_point);
    let mut region = trust_region(s);
    let mut iterations = Vec::new();
    let mut accepted_steps = 0;
    let mut invalid = 0;
    let mut termination = BaTermination::MaxIterations;
    if gradient_max(&n) <= s.gradient_tolerance {
        termination = BaTermination::GradientTolerance;
    }
    while termination == BaTermination::MaxIterations && iterations.len() < s.max_iterations {
        let t0 = Instant::now();
        // The step in the own variables of the problem, and the decrease of the model −(Jδ)ᵀ(r + Jδ/2).
        let at = Linearisation::new((&st, &lay), &n, (&s_cam, &s_point));
        let step = unscaled_step(p, priors, &at, &e, (&d_cam, &d_point), region.radius(), s);
        let step_norm = step.as_ref().map_or(0.0, |(dc, dp, _)| {
            (dc.norm_squared() + dp.iter().map(|d| d.norm_squared()).sum::<f64>()).sqrt()
        });
        // A step that could not be computed, or whose model does not decrease, is rejected;
        // five in a row is a failure.
        let Some((delta_cam, delta_point, model_change)) = step.filter(|st| st.2 > 0.0) else {
            invalid += 1;
            region.reject();
            iterations.push(BaIteration {
                cost_change: 0.0,
                rho: f64::NAN,
                seconds: t0.elapsed().as_secs_f64(),
                ..BaIteration::at(
                    iterations.len() + 1,
                    e.cost,
                    gradient_max(&n),
                    step_norm,
                    region.radius(),
                )
            });
            if invalid >= 5 {
                termination = BaTermination::Failure;
            } else if region.exhausted() {
                termination = BaTermination::MinRadius;
            }
            continue;
        };
        invalid = 0;
        // The candidate evaluated once, Jacobians included: most steps are accepted, and a
        // rejected one costs the Jacobians it need not have had.
        let candidate = stepped(p, &lay, &delta_cam, &delta_point);
        let trial = evaluate_into(&candidate, model, priors, s.loss, &mut spare).is_ok();
        let new_cost = if trial { spare.cost } else { f64::INFINITY };
        let xn = x_norm(p);
        let mut record = BaIteration {
            cost_change: e.cost - new_cost,
            rho: (e.cost - new_cost) / model_change,
            ..BaIteration::at(
                iterations.len() + 1,
                new_cost,
                gradient_max(&n),
                step_norm,
                region.radius(),
            )
        };
        // Where the Jacobians of the candidate cannot be evaluated, the step is rejected.
        let accepted = if step_norm <= s.parameter_tolerance * (xn + s.parameter_tolerance) {
            termination = BaTermination::ParameterTolerance;
            None
        } else if (e.cost - new_cost).abs() <= s.function_tolerance * e.cost {
            termination = BaTermination::FunctionTolerance;
            None
        } else if record.rho > s.min_relative_decrease {
            trial.then_some(candidate)
        } else {
            None
        };
        match accepted {
            Some(candidate) => {
                *p = candidate;
                std::mem::swap(&mut e, &mut spare);
                region.accept(record.rho);
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
                region.reject();
                if region.exhausted() {
                    termination = BaTermination::MinRadius;
                }
            }
            None => {}
        }
        record.radius = region.radius();
        record.seconds = t0.elapsed().as_secs_f64();
        iterations.push(record);
    }
    let cov = match covariance {
        None => None,
        Some(sigma_px) => {
            let at = Linearisation::new((&st, &lay), &n, (&s_cam, &s_point));
            Some(covariance_at(p, priors, &at, &e, sigma_px)?)
        }
    };
    let summary = BaSummary {
        cameras: p.poses.len(),
        points: p.points.len(),
        observations: p.observations.len(),
        initial_cost,
        final_cost: e.cost,
        iterations,
        accepted_steps,
        termination,
        seconds: start.elapsed().as_secs_f64(),
    };
    Ok((summary, cov))
}
