//! Stage 5, `smooth`.

use super::*;
use crate::pipeline::settings::SmoothSection;

/// Stage 5: smoothing, and each point's covariance by source.
pub(super) fn smooth_stage(
    ctx: &Ctx,
    project_key: &str,
    world: Vec<WorldTrack>,
    warnings: &mut Vec<String>,
) -> Result<(SmoothData, StageRecord), RunError> {
    let fps = ctx.fps;
    let framed = &ctx.framed;
    let transform = &ctx.transform;
    let p = &ctx.l.project;
    let smooth_key = stage_key("smooth", &[project_key], &p.smooth);
    let t0 = Instant::now();
    let to_out = |local: &Vector3<f64>| -> Result<Vector3<f64>, RunError> {
        let src = framed
            .frame
            .source_from_local(local)
            .map_err(|e| RunError::Failed(e.to_string()))?;
        match &transform {
            Some(t) => {
                let (x, y) = t
                    .apply(src.x, src.y)
                    .map_err(|e| RunError::Failed(e.to_string()))?;
                Ok(Vector3::new(x, y, src.z))
            }
            None => Ok(src),
        }
    };
    let (smoothed, status) = cached(
        &ctx.cache,
        ctx.progress,
        "smooth",
        &smooth_key,
        true,
        || {
            let obs: Vec<Vec<Observation>> = world
                .iter()
                .map(|t| {
                    t.points
                        .iter()
                        .map(|(f, w)| Observation {
                            frame: *f,
                            position: w.position.xy(),
                            cov: w.cov_pixel,
                        })
                        .collect()
                })
                .collect();
            let smoother = crate::pipeline::registry::smoother(&p.smooth, 1.0 / fps);
            let r = smoother.smooth(&obs);
            // What smoothing cannot average away: detection errors that persist over frames.
            let persistent = if matches!(p.smooth, SmoothSection::None(_)) {
                0.0
            } else {
                crate::smooth::persistent_share(&obs, &r.tracks).unwrap_or(0.0)
            };
            let (states, iterations, converged) = (r.tracks, r.em_iterations, r.converged);
            let q: Vec<f64> = if matches!(p.smooth, SmoothSection::None(_)) {
                Vec::new()
            } else {
                r.q.iter().copied().collect()
            };
            // What is used is freed as the trajectories are made: a long video's merge holds
            // its points once, not four times.
            drop(obs);
            let trajectories = trajectory_points(ctx, world, states, persistent, &to_out)?;
            let d = SmoothData {
                trajectories,
                em_iterations: iterations,
                em_converged: converged,
                q,
                persistent_share: persistent,
            };
            Ok(d)
        },
    )?;
    if !smoothed.em_converged {
        warnings.push(format!(
            "EM did not converge in {} iterations",
            smoothed.em_iterations
        ));
    }
    let mut counts = BTreeMap::from([
        ("trajectories".into(), smoothed.trajectories.len() as f64),
        ("em_iterations".into(), smoothed.em_iterations as f64),
        ("persistent_share".into(), smoothed.persistent_share),
    ]);
    if smoothed.q.len() == 16 {
        counts.insert("q_velocity_e_m2_s2".into(), smoothed.q[10]);
        counts.insert("q_velocity_n_m2_s2".into(), smoothed.q[15]);
    }
    let sig: Vec<f64> = smoothed
        .trajectories
        .iter()
        .flat_map(|t| t.points.iter().map(|q| q.sigma_m.norm()))
        .collect();
    if !sig.is_empty() {
        let mut s = sig.clone();
        s.sort_by(f64::total_cmp);
        counts.insert("median_sigma_m".into(), s[s.len() / 2]);
    }
    let record = StageRecord {
        name: "smooth".into(),
        status: status.into(),
        seconds: t0.elapsed().as_secs_f64(),
        counts,
    };

    Ok((smoothed, record))
}

/// Each smoothed state as a trajectory point: its covariance by source (the random part with
/// the detections' persistent share added back; the height's and the pose's from the nearest
/// observation) and its coordinates in the output CRS.
fn trajectory_points(
    ctx: &Ctx,
    world: Vec<WorldTrack>,
    states: Vec<Vec<crate::smooth::State>>,
    persistent: f64,
    to_out: &ToOut,
) -> Result<Vec<Trajectory>, RunError> {
    let (fps, surface) = (ctx.fps, &ctx.surface);
    let mut trajectories = Vec::with_capacity(world.len());
    for (t, states) in world.into_iter().zip(states) {
        let by_frame: BTreeMap<usize, &WorldPoint> =
            t.points.iter().map(|(f, w)| (*f, w)).collect();
        // Sized once: a long video's points are most of the merge's memory.
        let mut points = Vec::with_capacity(states.len());
        for st in &states {
            let (frame, en, vel, observed) = (st.frame, st.position, st.velocity, st.observed);
            let cov_random: Matrix2<f64> = st.cov.fixed_view::<2, 2>(0, 0).into();
            // Systematic parts: the height's and the pose's, from the nearest observation.
            let near = by_frame
                .range(..=frame)
                .next_back()
                .or_else(|| by_frame.range(frame..).next())
                .map(|(_, w)| *w);
            let cov = PointCov {
                random: cov_random + near.map_or(Matrix2::zeros(), |w| w.cov_pixel * persistent),
                height: near.map_or(Matrix2::zeros(), |w| w.cov_height),
                pose: near.map_or(Matrix2::zeros(), |w| w.cov_pose),
            };
            let total = cov.total();
            let u = head_up(surface.as_ref(), &en, t.height_m, near);
            let local = Vector3::new(en.x, en.y, u);
            points.push(TrajectoryPoint {
                frame,
                time_s: frame as f64 / fps,
                local,
                crs: to_out(&local)?,
                velocity: vel,
                sigma_m: Vector2::new(total[(0, 0)].sqrt(), total[(1, 1)].sqrt()),
                cov,
                observed,
            });
        }
        drop(by_frame);
        trajectories.push(Trajectory {
            id: t.id,
            height_m: t.height_m,
            height_source: t.height_source,
            points,
        });
    }
    Ok(trajectories)
}

/// The head's height at a smoothed position: the surface's there plus the person's height; where
/// the smoothed position lies just off the surface (a deck's edge), the nearest observation's
/// (an undefined height made GeoJSON's conversion fail and lost the whole run).
fn head_up(
    surface: &dyn HeightSurface,
    en: &Vector2<f64>,
    height_m: f64,
    near: Option<&WorldPoint>,
) -> f64 {
    surface
        .height(en)
        .map(|z| z + height_m)
        .or_else(|| near.map(|w| w.position.z))
        .unwrap_or(f64::NAN)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::terrain::deck::VerticalAlignment;

    #[test]
    fn a_smoothed_position_off_the_deck_takes_its_observations_height() {
        let deck = DeckProfile {
            centre_line: vec![Vector2::new(-40.0, 0.0), Vector2::new(40.0, 0.0)],
            start_s: 0.0,
            width_m: 10.0,
            alignment: VerticalAlignment::Stations(vec![(0.0, 6.0), (80.0, 6.0)]),
        };
        let seen = WorldPoint {
            position: Vector3::new(-5.6, -4.98, 7.7),
            cov_pixel: Matrix2::identity(),
            cov_height: Matrix2::identity(),
            cov_pose: Matrix2::identity(),
        };
        // On the deck: the deck's height plus the person's.
        let on = head_up(&deck, &Vector2::new(-5.6, -4.9), 1.7, Some(&seen));
        assert!((on - 7.7).abs() < 1e-9, "{on}");
        // 2 cm off its edge: the observation's height, not NaN.
        let off = head_up(&deck, &Vector2::new(-5.6, -5.02), 1.7, Some(&seen));
        assert_eq!(off, 7.7);
    }
}
