//! Helmert (7-parameter similarity) fits between two sets of named points, with control points
//! fitted and check points held out, and residuals reported for both (pure).

use nalgebra::{SVector, Vector3};
use serde::Serialize;

use super::model::Role;
use crate::geom::similarity::{ScaleMode, Similarity, SimilarityError, fit};

/// One point as a fit sees it: local metres, role, and σ (metres, isotropic) when known.
#[derive(Clone, Debug)]
pub struct FitPoint {
    pub name: String,
    pub role: Role,
    pub position: Vector3<f64>,
    pub sigma_m: Option<f64>,
}

/// A point's residual `reference − T(source)`.
#[derive(Clone, Debug, Serialize)]
pub struct Residual {
    pub name: String,
    pub role: Role,
    /// East, north, up, metres.
    pub residual_m: [f64; 3],
    pub horizontal_m: f64,
    pub norm_m: f64,
    /// 1 unless the robust fit down-weighted the point.
    pub robust_weight: f64,
}

/// Root mean square errors, metres.
#[derive(Clone, Copy, Debug, Serialize)]
pub struct Rmse {
    pub count: usize,
    pub east_m: f64,
    pub north_m: f64,
    pub up_m: f64,
    pub horizontal_m: f64,
    pub total_m: f64,
}

impl Rmse {
    fn of(res: &[&Residual]) -> Option<Rmse> {
        if res.is_empty() {
            return None;
        }
        let n = res.len() as f64;
        let ms = |f: &dyn Fn(&Residual) -> f64| {
            (res.iter().map(|r| f(r).powi(2)).sum::<f64>() / n).sqrt()
        };
        Some(Rmse {
            count: res.len(),
            east_m: ms(&|r| r.residual_m[0]),
            north_m: ms(&|r| r.residual_m[1]),
            up_m: ms(&|r| r.residual_m[2]),
            horizontal_m: ms(&|r| r.horizontal_m),
            total_m: ms(&|r| r.norm_m),
        })
    }
}

/// The fitted transform and the residuals of control and check points.
#[derive(Clone, Debug, Serialize)]
pub struct FitReport {
    #[serde(skip)]
    pub transform: Similarity,
    pub scale: f64,
    pub scale_ppm: f64,
    /// Rotation as a Rodrigues vector, radians.
    pub rotation_rad: [f64; 3],
    pub translation_m: [f64; 3],
    /// Standard deviations: rotation (rad, 3), translation (m, 3), scale.
    pub std_dev: [f64; 7],
    pub sigma0: f64,
    pub robust: bool,
    pub residuals: Vec<Residual>,
    pub control: Option<Rmse>,
    pub check: Option<Rmse>,
    /// Names in only one of the two sets, or without a height.
    pub unmatched: Vec<String>,
}

#[derive(Debug, thiserror::Error, Clone, PartialEq)]
pub enum FitError {
    #[error(
        "a Helmert fit needs at least 3 control points in both files with heights; {0} found ({1})"
    )]
    TooFewControl(usize, String),
    #[error("the control points do not determine a similarity: {0}")]
    Degenerate(#[from] SimilarityError),
}

/// Fits `reference ≈ T(source)` on the control points common to both (matched by name), and
/// reports residuals of control and check points. Points disabled in either set are ignored.
pub fn helmert(
    source: &[FitPoint],
    reference: &[FitPoint],
    scale: ScaleMode,
    robust: bool,
) -> Result<FitReport, FitError> {
    let mut pairs = Vec::new();
    let mut unmatched = Vec::new();
    for s in source {
        match reference.iter().find(|r| r.name == s.name) {
            Some(r) if s.role == Role::Disabled || r.role == Role::Disabled => {}
            Some(r)
                if s.position
                    .iter()
                    .chain(r.position.iter())
                    .all(|v| v.is_finite()) =>
            {
                // The stricter role wins: a check point in either file is held out.
                let role = if s.role == Role::Check || r.role == Role::Check {
                    Role::Check
                } else {
                    Role::Control
                };
                pairs.push((s, r, role));
            }
            Some(_) => unmatched.push(format!("{} (no height)", s.name)),
            None => unmatched.push(format!("{} (only in the source)", s.name)),
        }
    }
    for r in reference {
        if !source.iter().any(|s| s.name == r.name) {
            unmatched.push(format!("{} (only in the reference)", r.name));
        }
    }
    let control: Vec<_> = pairs
        .iter()
        .filter(|(_, _, role)| *role == Role::Control)
        .collect();
    if control.len() < 3 {
        let names: Vec<&str> = control.iter().map(|(s, _, _)| s.name.as_str()).collect();
        return Err(FitError::TooFewControl(control.len(), names.join(", ")));
    }
    let src: Vec<Vector3<f64>> = control.iter().map(|(s, _, _)| s.position).collect();
    let dst: Vec<Vector3<f64>> = control.iter().map(|(_, r, _)| r.position).collect();
    let weights: Vec<f64> = control
        .iter()
        .map(|(s, r, _)| match (s.sigma_m, r.sigma_m) {
            (None, None) => 1.0,
            (a, b) => 1.0 / (a.unwrap_or(0.0).powi(2) + b.unwrap_or(0.0).powi(2)).max(1e-12),
        })
        .collect();
    let f = fit(&src, &dst, &weights, scale, robust)?;
    let t = &f.transform;
    let mut robust_w = control
        .iter()
        .map(|(s, _, _)| s.name.as_str())
        .zip(f.robust_weights.iter().copied());
    let residuals: Vec<Residual> = pairs
        .iter()
        .map(|(s, r, role)| {
            let d = r.position - t.apply(&s.position);
            let w = if *role == Role::Control {
                robust_w.find(|(n, _)| *n == s.name).map_or(1.0, |(_, w)| w)
            } else {
                1.0
            };
            Residual {
                name: s.name.clone(),
                role: *role,
                residual_m: d.into(),
                horizontal_m: d.xy().norm(),
                norm_m: d.norm(),
                robust_weight: w,
            }
        })
        .collect();
    let by = |role: Role| {
        Rmse::of(
            &residuals
                .iter()
                .filter(|r| r.role == role)
                .collect::<Vec<_>>(),
        )
    };
    let sd: SVector<f64, 7> = f.std_devs();
    Ok(FitReport {
        scale: t.scale,
        scale_ppm: (t.scale - 1.0) * 1e6,
        rotation_rad: t.rotation.scaled_axis().into(),
        translation_m: t.translation.into(),
        std_dev: sd.into(),
        sigma0: f.sigma0,
        robust,
        control: by(Role::Control),
        check: by(Role::Check),
        residuals,
        unmatched,
        transform: t.clone(),
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::UnitQuaternion;
    use rand::SeedableRng;
    use rand_distr::{Distribution, Normal};

    #[test]
    fn control_and_check_rmse_are_reported_apart() {
        let t = Similarity {
            scale: 0.9998,
            rotation: UnitQuaternion::from_scaled_axis(Vector3::new(0.0, 0.0, 1.2)),
            translation: Vector3::new(12.0, -30.0, 2.0),
        };
        let sigma = 0.01;
        let normal = Normal::new(0.0, sigma).unwrap();
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(3);
        let mut source = Vec::new();
        let mut reference = Vec::new();
        for i in 0..12 {
            let a = i as f64;
            let p = Vector3::new(
                50.0 * (a * 0.9).cos(),
                40.0 * (a * 1.3).sin(),
                (i % 4) as f64,
            );
            let role = if i % 4 == 3 {
                Role::Check
            } else {
                Role::Control
            };
            let name = format!("P{i}");
            source.push(FitPoint {
                name: name.clone(),
                role,
                position: p,
                sigma_m: Some(sigma),
            });
            let noisy = t.apply(&p) + Vector3::from_fn(|_, _| normal.sample(&mut rng));
            reference.push(FitPoint {
                name,
                role: Role::Control,
                position: noisy,
                sigma_m: None,
            });
        }
        reference.push(FitPoint {
            name: "extra".into(),
            role: Role::Control,
            position: Vector3::zeros(),
            sigma_m: None,
        });
        let r = helmert(&source, &reference, ScaleMode::Free, false).unwrap();
        assert_eq!(r.control.unwrap().count, 9);
        assert_eq!(r.check.unwrap().count, 3);
        assert_eq!(
            r.unmatched,
            vec!["extra (only in the reference)".to_string()]
        );
        // Check RMSE reflects the noise (about √3 σ in 3D), without having been fitted to.
        let c = r.check.unwrap();
        assert!(c.total_m > 0.3 * sigma && c.total_m < 4.0 * sigma, "{c:?}");
        // The transform is recovered within 3σ of its reported uncertainty.
        assert!((r.scale - t.scale).abs() < 3.0 * r.std_dev[6]);
        for k in 0..3 {
            assert!(
                (r.translation_m[k] - t.translation[k]).abs() < 3.0 * r.std_dev[3 + k],
                "t{k}"
            );
        }
        // Too few control points.
        let few: Vec<FitPoint> = source.iter().take(2).cloned().collect();
        assert!(matches!(
            helmert(&few, &reference, ScaleMode::Free, false),
            Err(FitError::TooFewControl(2, _))
        ));
    }
}
