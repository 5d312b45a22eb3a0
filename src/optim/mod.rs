//! Least-squares machinery (pure): the Levenberg–Marquardt trust-region controller of the one
//! sparse engine, `ba` (calibration refinement and the joint key-frame refinement are its
//! configurations); small dense problems (a homography, one pose) go to the
//! `levenberg-marquardt` crate.
//!
//! The strategy follows Ceres Solver's Levenberg–Marquardt: the damped system
//! `(JᵀJ + μ·D) δ = −Jᵀr` with `D = diag(JᵀJ)` clamped to `[1e-6, 1e32]`, a step accepted when
//! the actual over predicted decrease `ρ` exceeds 1e-3, `μ` scaled by `max(1/3, 1 − (2ρ − 1)³)`
//! after a success and doubled-and-growing after a failure (Nielsen), and termination on the
//! function, gradient and parameter tolerances.

pub mod assignment;
pub mod ba;
pub mod ba_camera;
pub mod bal;

use serde::Serialize;

/// Tolerances and limits of a Levenberg–Marquardt run.
#[derive(Clone, Debug)]
pub struct LmSettings {
    pub max_iterations: usize,
    /// Stop when `|Δcost| / cost` of an accepted step falls below this.
    pub function_tolerance: f64,
    /// Stop when the largest gradient component falls below this.
    pub gradient_tolerance: f64,
    /// Stop when `‖δ‖ ≤ tol · (‖x‖ + tol)`.
    pub parameter_tolerance: f64,
    pub initial_mu: f64,
    pub min_diagonal: f64,
    pub max_diagonal: f64,
    pub min_relative_decrease: f64,
}

impl Default for LmSettings {
    fn default() -> Self {
        LmSettings {
            max_iterations: 100,
            function_tolerance: 1e-12,
            gradient_tolerance: 1e-12,
            parameter_tolerance: 1e-12,
            initial_mu: 1e-4,
            min_diagonal: 1e-6,
            max_diagonal: 1e32,
            min_relative_decrease: 1e-3,
        }
    }
}

/// Why an optimiser stopped.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum Termination {
    FunctionTolerance,
    GradientTolerance,
    ParameterTolerance,
    MaxIterations,
    /// The damping grew without bound: no step lowers the cost any more.
    NoFurtherProgress,
}

impl Termination {
    /// Whether the result is a converged optimum.
    pub fn converged(self) -> bool {
        !matches!(self, Termination::MaxIterations)
    }
}

impl std::fmt::Display for Termination {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(match self {
            Termination::FunctionTolerance => "function tolerance reached",
            Termination::GradientTolerance => "gradient tolerance reached",
            Termination::ParameterTolerance => "parameter tolerance reached",
            Termination::MaxIterations => "maximum number of iterations reached",
            Termination::NoFurtherProgress => "no step lowers the cost further",
        })
    }
}

/// The damping state of a Levenberg–Marquardt run.
#[derive(Clone, Debug)]
pub struct Damping {
    /// `μ = 1/Δ`, Δ the trust region's radius.
    pub mu: f64,
    nu: f64,
    /// μ never falls below this (Δ never above its largest radius).
    min_mu: f64,
    /// μ beyond this is a radius too small to move.
    max_mu: f64,
}

impl Damping {
    pub fn new(settings: &LmSettings) -> Self {
        Damping::with_limits(settings.initial_mu, 0.0, 1e32)
    }

    /// A trust region of radius `1/mu`, kept within `[1/max_mu, 1/min_mu]`.
    pub fn with_limits(mu: f64, min_mu: f64, max_mu: f64) -> Self {
        Damping {
            mu,
            nu: 2.0,
            min_mu,
            max_mu,
        }
    }

    /// The trust region's radius `Δ = 1/μ`.
    pub fn radius(&self) -> f64 {
        1.0 / self.mu
    }

    /// The regularised diagonal entry `μ·clamp(d)` to add to a normal-matrix diagonal `d`.
    pub fn regularizer(&self, d: f64, settings: &LmSettings) -> f64 {
        self.mu * d.clamp(settings.min_diagonal, settings.max_diagonal)
    }

    /// Updates μ after a step with gain ratio `rho`; returns whether the step is accepted.
    pub fn update(&mut self, rho: f64, settings: &LmSettings) -> bool {
        if rho.is_finite() && rho > settings.min_relative_decrease {
            self.accept(rho);
            true
        } else {
            self.reject();
            false
        }
    }

    /// An accepted step of gain ratio `rho`: the region grows by up to 3×, shrinks for a poor
    /// model (Nielsen's rule, as Ceres).
    pub fn accept(&mut self, rho: f64) {
        let f = 1.0 - (2.0 * rho - 1.0).powi(3);
        self.mu = (self.mu * f.max(1.0 / 3.0)).max(self.min_mu);
        self.nu = 2.0;
    }

    /// A rejected step: the region shrinks, twice as fast each time in a row.
    pub fn reject(&mut self) {
        self.mu *= self.nu;
        self.nu *= 2.0;
    }

    /// True when the damping is so large that steps are meaningless.
    pub fn exhausted(&self) -> bool {
        self.mu > self.max_mu || !self.mu.is_finite()
    }
}

/// A robust loss on a whitened residual of squared norm `s` (units of σ²): the least-squares
/// weight of an iteratively reweighted step.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum RobustLoss {
    /// Plain least squares.
    Squared,
    /// Quadratic up to `k` σ, linear beyond.
    Huber(f64),
    /// `k² log(1 + s/k²)`: outliers lose influence altogether.
    Cauchy(f64),
}

impl RobustLoss {
    /// The loss `ρ(s)` (equal to `s` for small residuals).
    pub fn rho(self, s: f64) -> f64 {
        match self {
            RobustLoss::Squared => s,
            RobustLoss::Huber(k) => {
                if s <= k * k {
                    s
                } else {
                    2.0 * k * s.sqrt() - k * k
                }
            }
            RobustLoss::Cauchy(k) => k * k * (s / (k * k)).ln_1p(),
        }
    }

    /// The weight `ρ'(s)` of a residual in a reweighted least-squares step.
    pub fn weight(self, s: f64) -> f64 {
        match self {
            RobustLoss::Squared => 1.0,
            RobustLoss::Huber(k) => {
                if s <= k * k {
                    1.0
                } else {
                    k / s.sqrt()
                }
            }
            RobustLoss::Cauchy(k) => 1.0 / (1.0 + s / (k * k)),
        }
    }
}

impl std::str::FromStr for RobustLoss {
    type Err = String;

    /// `none`, `huber[:K]` or `cauchy[:K]` (K in σ; default 2).
    fn from_str(s: &str) -> Result<Self, String> {
        let (name, k) = match s.split_once(':') {
            Some((n, k)) => (
                n,
                k.trim()
                    .parse::<f64>()
                    .ok()
                    .filter(|k| *k > 0.0 && k.is_finite())
                    .ok_or_else(|| format!("loss scale must be a positive number, got '{k}'"))?,
            ),
            None => (s, 2.0),
        };
        match name.trim().to_ascii_lowercase().as_str() {
            "none" | "squared" => Ok(RobustLoss::Squared),
            "huber" => Ok(RobustLoss::Huber(k)),
            "cauchy" => Ok(RobustLoss::Cauchy(k)),
            _ => Err(format!(
                "expected 'none', 'huber[:K]' or 'cauchy[:K]', got '{s}'"
            )),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn robust_weights_are_the_derivatives_of_the_losses() {
        for loss in [
            RobustLoss::Squared,
            RobustLoss::Huber(2.0),
            RobustLoss::Cauchy(1.5),
        ] {
            for s in [0.1, 1.0, 3.9, 4.1, 30.0] {
                let fd = (loss.rho(s + 1e-6) - loss.rho(s - 1e-6)) / 2e-6;
                assert!((fd - loss.weight(s)).abs() < 1e-6, "{loss:?} at {s}");
            }
        }
        assert_eq!(
            "huber:1.5".parse::<RobustLoss>(),
            Ok(RobustLoss::Huber(1.5))
        );
        assert_eq!("none".parse::<RobustLoss>(), Ok(RobustLoss::Squared));
        assert!("tukey".parse::<RobustLoss>().is_err());
    }

    #[test]
    fn damping_shrinks_on_good_steps_and_grows_on_bad_ones() {
        let s = LmSettings::default();
        let mut d = Damping::new(&s);
        assert!(d.update(1.0, &s));
        assert!((d.mu - s.initial_mu / 3.0).abs() < 1e-18);
        let before = d.mu;
        assert!(!d.update(-1.0, &s));
        assert_eq!(d.mu, before * 2.0);
        assert!(!d.update(f64::NAN, &s));
        assert_eq!(d.mu, before * 8.0);
    }
}
