//! Robust estimation (pure): MSAC with an adaptive number of iterations, degenerate-sample
//! tests, optional (iterated) local optimisation, and a seeded sampler.
//!
//! MSAC scores a model by `Σ min(rᵢ², T²)` (Torr & Zisserman 2000): inliers count by how well
//! they fit, not only by whether they fit. After each new best model, local optimisation refits
//! on its inliers (a non-minimal solver), repeatedly while the score improves (LO-RANSAC, Chum
//! et al. 2003). The number of
//! iterations adapts to the best inlier ratio `w`: `N = log(1 − p) / log(1 − wˢ)`.

use rand::{Rng, RngExt, SeedableRng};

use super::EstimateError;

/// A model family for robust estimation over `len()` data.
pub trait Estimator {
    type Model: Clone;

    /// Size of a minimal sample.
    fn sample_size(&self) -> usize;

    /// Number of data.
    fn len(&self) -> usize;

    fn is_empty(&self) -> bool {
        self.len() == 0
    }

    /// Whether a minimal sample cannot determine a model (collinear points, say).
    fn is_degenerate(&self, sample: &[usize]) -> bool;

    /// Models from a minimal sample (several for P3P; none when it fails).
    fn fit_minimal(&self, sample: &[usize]) -> Vec<Self::Model>;

    /// A model from many data (least squares); `None` when not available or failing.
    fn fit_nonminimal(&self, _data: &[usize], _start: &Self::Model) -> Option<Self::Model> {
        None
    }

    /// Squared residual of datum `i` under `model`, in the units of the threshold squared.
    fn residual_sq(&self, model: &Self::Model, i: usize) -> f64;
}

/// Settings of a robust fit.
#[derive(Clone, Debug)]
pub struct RansacSettings {
    /// Inlier threshold on the residual (pixels for image residuals).
    pub threshold: f64,
    /// Probability of having drawn an all-inlier sample when stopping.
    pub confidence: f64,
    pub max_iterations: usize,
    pub min_iterations: usize,
    /// Refit on the inliers of every new best model.
    pub local_optimisation: bool,
    /// Also optimise a model that is not a new best when its inlier count reaches this fraction
    /// of the best's (above 1: never). With noisy data a minimal sample's model can be poor
    /// even when the sample is all inliers; optimising it is cheap for small problems.
    pub lo_count_fraction: f64,
    pub seed: u64,
}

impl Default for RansacSettings {
    fn default() -> Self {
        RansacSettings {
            threshold: 4.0,
            confidence: 0.9999,
            max_iterations: 10_000,
            min_iterations: 10,
            local_optimisation: true,
            lo_count_fraction: 2.0,
            seed: 0,
        }
    }
}

/// The best model with its inliers.
#[derive(Clone, Debug)]
pub struct RansacResult<M> {
    pub model: M,
    pub inliers: Vec<bool>,
    pub inlier_count: usize,
    /// MSAC cost of the model.
    pub score: f64,
    pub iterations: usize,
}

/// Iterations needed to draw an all-inlier sample of size `s` with probability `p` when a
/// fraction `w` of the data are inliers.
pub fn needed_iterations(w: f64, s: usize, p: f64) -> usize {
    if w >= 1.0 {
        return 1;
    }
    let ws = w.powi(s as i32);
    if ws <= f64::MIN_POSITIVE {
        return usize::MAX;
    }
    let n = (1.0 - p).ln() / (1.0 - ws).ln();
    if n.is_finite() {
        n.ceil().max(1.0) as usize
    } else {
        usize::MAX
    }
}

/// Draws `k` distinct indices from `0..n`.
pub fn sample_indices(rng: &mut impl Rng, n: usize, k: usize, out: &mut Vec<usize>) {
    out.clear();
    while out.len() < k {
        let i = rng.random_range(0..n);
        if !out.contains(&i) {
            out.push(i);
        }
    }
}

fn score<E: Estimator>(est: &E, model: &E::Model, t2: f64) -> (f64, usize) {
    let mut cost = 0.0;
    let mut count = 0;
    for i in 0..est.len() {
        let r2 = est.residual_sq(model, i);
        if r2 < t2 {
            cost += r2;
            count += 1;
        } else {
            cost += t2;
        }
    }
    (cost, count)
}

/// MSAC. Fails when there are too few data or no sample yields a model.
pub fn msac<E: Estimator>(
    est: &E,
    s: &RansacSettings,
) -> Result<RansacResult<E::Model>, EstimateError> {
    let n = est.len();
    let k = est.sample_size();
    if n < k {
        return Err(EstimateError::TooFewPoints { needed: k, got: n });
    }
    let t2 = s.threshold * s.threshold;
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(s.seed);
    let mut best: Option<(E::Model, f64, usize)> = None;
    let mut needed = s.max_iterations;
    let mut sample = Vec::with_capacity(k);
    let mut iterations = 0;
    let mut degenerate_draws = 0;
    while iterations < needed.max(s.min_iterations).min(s.max_iterations) {
        sample_indices(&mut rng, n, k, &mut sample);
        if est.is_degenerate(&sample) {
            degenerate_draws += 1;
            // Every draw degenerate: the data cannot determine a model.
            if degenerate_draws > 100 * (iterations + 1) {
                break;
            }
            continue;
        }
        iterations += 1;
        for model in est.fit_minimal(&sample) {
            let (cost, count) = score(est, &model, t2);
            let promising = best
                .as_ref()
                .is_none_or(|b| cost < b.1 || count as f64 >= s.lo_count_fraction * b.2 as f64);
            if promising {
                let mut cand = (model, cost, count);
                // Iterated local optimisation: refit on the inliers while the score improves
                // (a minimal sample's model is noisy and may see only part of the inliers).
                let mut rounds = 0;
                while s.local_optimisation && cand.2 > k && rounds < 8 {
                    rounds += 1;
                    let inliers: Vec<usize> = (0..n)
                        .filter(|&i| est.residual_sq(&cand.0, i) < t2)
                        .collect();
                    match est.fit_nonminimal(&inliers, &cand.0) {
                        Some(refit) => {
                            let (c2, n2) = score(est, &refit, t2);
                            if c2 < cand.1 * (1.0 - 1e-9) {
                                cand = (refit, c2, n2);
                            } else {
                                break;
                            }
                        }
                        None => break,
                    }
                }
                if best.as_ref().is_none_or(|b| cand.1 < b.1) {
                    needed = needed_iterations(cand.2 as f64 / n as f64, k, s.confidence);
                    best = Some(cand);
                }
            }
        }
    }
    let (model, score, inlier_count) = best.ok_or_else(|| {
        EstimateError::Degenerate(
            "no sample gave a model: the data are degenerate (collinear or coincident points?)"
                .into(),
        )
    })?;
    let inliers = (0..n).map(|i| est.residual_sq(&model, i) < t2).collect();
    Ok(RansacResult {
        model,
        inliers,
        inlier_count,
        score,
        iterations,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Lines y = a x + b through 2-point samples.
    struct Lines(Vec<(f64, f64)>);

    impl Estimator for Lines {
        type Model = (f64, f64);
        fn sample_size(&self) -> usize {
            2
        }
        fn len(&self) -> usize {
            self.0.len()
        }
        fn is_degenerate(&self, s: &[usize]) -> bool {
            (self.0[s[0]].0 - self.0[s[1]].0).abs() < 1e-9
        }
        fn fit_minimal(&self, s: &[usize]) -> Vec<(f64, f64)> {
            let ((x0, y0), (x1, y1)) = (self.0[s[0]], self.0[s[1]]);
            let a = (y1 - y0) / (x1 - x0);
            vec![(a, y0 - a * x0)]
        }
        fn residual_sq(&self, m: &(f64, f64), i: usize) -> f64 {
            let (x, y) = self.0[i];
            (y - m.0 * x - m.1).powi(2)
        }
    }

    #[test]
    fn finds_the_line_among_outliers_and_stops_early() {
        let mut pts: Vec<(f64, f64)> = (0..70)
            .map(|i| (i as f64, 2.0 * i as f64 + 1.0 + ((i * 7) % 5) as f64 * 0.01))
            .collect();
        pts.extend((0..30).map(|i| (i as f64 * 1.7, 500.0 - 3.0 * i as f64)));
        let r = msac(
            &Lines(pts),
            &RansacSettings {
                threshold: 0.1,
                seed: 3,
                ..RansacSettings::default()
            },
        )
        .unwrap();
        assert!((r.model.0 - 2.0).abs() < 0.01 && (r.model.1 - 1.0).abs() < 0.1);
        assert_eq!(r.inlier_count, 70);
        assert!(r.inliers[..70].iter().all(|&b| b) && r.inliers[70..].iter().all(|&b| !b));
        // 70 % inliers, s = 2, p = 0.9999: 14 draws suffice.
        assert!(r.iterations < 60, "{}", r.iterations);
        assert_eq!(needed_iterations(0.7, 2, 0.9999), 14);
        assert_eq!(needed_iterations(1.0, 3, 0.99), 1);
    }

    #[test]
    fn all_degenerate_data_is_an_error() {
        let pts = vec![(1.0, 2.0); 10];
        assert!(matches!(
            msac(&Lines(pts), &RansacSettings::default()),
            Err(EstimateError::Degenerate(_))
        ));
        assert!(matches!(
            msac(&Lines(vec![(1.0, 2.0)]), &RansacSettings::default()),
            Err(EstimateError::TooFewPoints { .. })
        ));
    }
}
