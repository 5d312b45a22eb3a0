//! Stage 5, `smooth`.

use std::collections::BTreeMap;
use std::time::Instant;

use nalgebra::{Matrix2, Vector2, Vector3};
use serde::{Deserialize, Serialize};

use super::{Env, RunError, RunInputs, StageRecord, WorldTrack, cached_seq};
use crate::cache::{StageCache, in_batches, stage_key};
use crate::export::{PointCov, Trajectory, TrajectoryPoint};
use crate::pipeline::settings::SmoothSection;
use crate::projection::WorldPoint;
use crate::smooth::Observation;
use crate::terrain::HeightSurface;

/// A point's site-frame coordinates to the output CRS.
type ToOut<'a> = dyn Fn(&Vector3<f64>) -> Result<Vector3<f64>, RunError> + 'a;

/// What the smooth stage's cache holds besides the trajectories (`smooth.bin`, a trajectory at
/// a time in order of identity).
#[derive(Clone, Debug, Serialize, Deserialize)]
pub(super) struct SmoothSummary {
    pub trajectories: usize,
    pub points: usize,
    pub em_iterations: usize,
    pub em_converged: bool,
    pub q: Vec<f64>,
    /// The share of the detections' variance that persists from frame to frame, the mean of
    /// its two directions (`smooth::persistent_share`, added back to every point's random part).
    pub persistent_share: f64,
    pub median_sigma_m: Option<f64>,
}

/// The projected tracks' observations as the smoother takes them.
fn observations(world: &[WorldTrack]) -> Vec<Vec<Observation>> {
    world
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
        .collect()
}

/// The projected tracks' observations set aside for EM's passes in a file of their own, read
/// back a batch at a time for each pass (a long video's are never all in memory): per track its
/// number of observations, then each as frame, east, north and the covariance's four entries,
/// little-endian (a tenth of the time of decoding the projected tracks each pass).
struct ObservationFile {
    path: std::path::PathBuf,
}

const OBSERVATION_BYTES: usize = 7 * 8;

impl ObservationFile {
    /// Writes the file from the project stage's cache.
    fn write(
        cache: &StageCache,
        project_key: &str,
        path: std::path::PathBuf,
    ) -> Result<Self, RunError> {
        use std::io::Write;
        let io_err = |source| RunError::Io {
            path: path.clone(),
            source,
        };
        let file = std::fs::File::create(&path).map_err(io_err)?;
        let mut w = std::io::BufWriter::with_capacity(1 << 20, file);
        let points_of = |t: &WorldTrack| t.points.len();
        cache.read_batches::<_, RunError>("project", project_key, points_of, |batch| {
            for obs in observations(&batch) {
                let mut bytes = Vec::with_capacity(8 + obs.len() * OBSERVATION_BYTES);
                bytes.extend((obs.len() as u64).to_le_bytes());
                for o in &obs {
                    bytes.extend((o.frame as u64).to_le_bytes());
                    for v in [o.position.x, o.position.y]
                        .into_iter()
                        .chain(o.cov.iter().copied())
                    {
                        bytes.extend(v.to_le_bytes());
                    }
                }
                w.write_all(&bytes).map_err(io_err)?;
            }
            Ok(())
        })?;
        w.flush().map_err(io_err)?;
        Ok(ObservationFile { path })
    }
}

impl Drop for ObservationFile {
    fn drop(&mut self) {
        let _ = std::fs::remove_file(&self.path);
    }
}

/// The observation file's tracks, read one at a time.
struct ObservationReader {
    r: std::io::BufReader<std::fs::File>,
    bytes: Vec<u8>,
}

impl Iterator for ObservationReader {
    type Item = std::io::Result<Vec<Observation>>;

    fn next(&mut self) -> Option<std::io::Result<Vec<Observation>>> {
        use std::io::Read;
        let mut n = [0u8; 8];
        match self.r.read_exact(&mut n) {
            Ok(()) => {}
            Err(e) if e.kind() == std::io::ErrorKind::UnexpectedEof => return None,
            Err(e) => return Some(Err(e)),
        }
        self.bytes
            .resize(u64::from_le_bytes(n) as usize * OBSERVATION_BYTES, 0);
        if let Err(e) = self.r.read_exact(&mut self.bytes) {
            return Some(Err(e));
        }
        let f64_at = |b: &[u8], k: usize| {
            f64::from_le_bytes(b[8 * k..8 * k + 8].try_into().unwrap_or([0; 8]))
        };
        Some(Ok(self
            .bytes
            .chunks_exact(OBSERVATION_BYTES)
            .map(|b| Observation {
                frame: u64::from_le_bytes(b[..8].try_into().unwrap_or([0; 8])) as usize,
                position: Vector2::new(f64_at(b, 1), f64_at(b, 2)),
                cov: Matrix2::from_column_slice(&[
                    f64_at(b, 3),
                    f64_at(b, 4),
                    f64_at(b, 5),
                    f64_at(b, 6),
                ]),
            })
            .collect()))
    }
}

impl crate::smooth::ObservationSource for ObservationFile {
    fn each_batch(&self, f: &mut dyn FnMut(&[Vec<Observation>])) -> std::io::Result<()> {
        let r = std::io::BufReader::with_capacity(1 << 20, std::fs::File::open(&self.path)?);
        let tracks = ObservationReader {
            r,
            bytes: Vec::new(),
        };
        in_batches(tracks, Vec::len, |batch| {
            f(&batch);
            Ok(())
        })
    }
}

/// Stage 5: smoothing, and each point's covariance by source. Three kinds of pass over the
/// projected tracks, each a batch at a time: EM's (the model), one for the persistent share,
/// and the last that writes the trajectories.
pub(super) fn smooth_stage(
    env: &Env,
    x: &RunInputs,
    settings: &SmoothSection,
    project_key: &str,
    projected: &super::project_stage::ProjectSummary,
    warnings: &mut Vec<String>,
) -> Result<(SmoothSummary, String, StageRecord), RunError> {
    let fps = x.fps;
    let framed = &x.framed;
    let transform = &x.transform;
    let cache = &env.cache;
    let smooth_key = stage_key("smooth", &[project_key], settings);
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
    let points_of = |t: &WorldTrack| t.points.len();
    let (summary, status) = cached_seq(cache, env.progress, "smooth", &smooth_key, || {
        let smoother = crate::pipeline::registry::smoother(settings, 1.0 / fps);
        let observed = ObservationFile::write(
            cache,
            project_key,
            crate::io::temp_path(&cache.path("smooth"), ".observations"),
        )?;
        let read_err = |e: std::io::Error| RunError::Io {
            path: observed.path.clone(),
            source: e,
        };
        let fit = smoother.fit(&observed).map_err(read_err)?;
        let none = matches!(settings, SmoothSection::None(_));
        // What smoothing cannot average away: detection errors that persist over frames.
        let persistent = if none {
            crate::smooth::Persistent::none()
        } else {
            let mut white = crate::smooth::WhiteShare::default();
            crate::smooth::ObservationSource::each_batch(&observed, &mut |obs| {
                let states = smoother.smooth_batch(&fit, obs);
                for (o, st) in obs.iter().zip(&states) {
                    white.add_smoothed(o, st);
                }
            })
            .map_err(read_err)?;
            white
                .persistent()
                .unwrap_or(crate::smooth::Persistent::none())
        };
        let mut points = 0;
        cache.store_seq::<_, RunError>("smooth", &smooth_key, projected.tracks, |push| {
            cache.read_batches::<_, RunError>("project", project_key, points_of, |batch| {
                let states = smoother.smooth_batch(&fit, &observations(&batch));
                for t in trajectory_points(x, batch, states, persistent, &to_out)? {
                    points += t.points.len();
                    push(&t)?;
                }
                Ok(())
            })
        })?;
        // The middle σ (as sorting them all gives it), in a few passes over what was written.
        let median_sigma_m = crate::analysis::select_ranks::<RunError>(
            &[points as u64],
            &[(0, points as u64 / 2)],
            &mut |f| {
                for t in cache.read_seq::<Trajectory>("smooth", &smooth_key)? {
                    let t = t.map_err(|e| RunError::Failed(e.to_string()))?;
                    t.points.iter().for_each(|q| f(0, q.sigma_m.norm()));
                }
                Ok(())
            },
        )?[0];
        Ok(SmoothSummary {
            trajectories: projected.tracks,
            points,
            em_iterations: fit.em_iterations,
            em_converged: fit.converged,
            q: if none {
                Vec::new()
            } else {
                fit.q.iter().copied().collect()
            },
            persistent_share: persistent.mean(),
            median_sigma_m,
        })
    })?;
    if !summary.em_converged {
        warnings.push(format!(
            "EM did not converge in {} iterations",
            summary.em_iterations
        ));
    }
    let mut counts = BTreeMap::from([
        ("trajectories".into(), summary.trajectories as f64),
        ("em_iterations".into(), summary.em_iterations as f64),
        ("persistent_share".into(), summary.persistent_share),
    ]);
    if summary.q.len() == 16 {
        counts.insert("q_velocity_e_m2_s2".into(), summary.q[10]);
        counts.insert("q_velocity_n_m2_s2".into(), summary.q[15]);
    }
    if let Some(m) = summary.median_sigma_m {
        counts.insert("median_sigma_m".into(), m);
    }
    let record = StageRecord {
        name: "smooth".into(),
        status,
        seconds: t0.elapsed().as_secs_f64(),
        counts,
    };

    Ok((summary, smooth_key, record))
}

/// Each smoothed state as a trajectory point: its covariance by source (the random part with
/// the detections' persistent share added back; the height's and the pose's from the nearest
/// observation) and its coordinates in the output CRS.
fn trajectory_points(
    x: &RunInputs,
    world: Vec<WorldTrack>,
    states: Vec<Vec<crate::smooth::State>>,
    persistent: crate::smooth::Persistent,
    to_out: &ToOut,
) -> Result<Vec<Trajectory>, RunError> {
    let (fps, surface) = (x.fps, &x.surface);
    let mut trajectories = Vec::with_capacity(world.len());
    for (t, states) in world.into_iter().zip(states) {
        let by_frame: BTreeMap<usize, &WorldPoint> =
            t.points.iter().map(|(f, w)| (*f, w)).collect();
        let score_of: BTreeMap<usize, Option<f64>> = t
            .points
            .iter()
            .zip(&t.scores)
            .map(|((f, _), s)| (*f, *s))
            .collect();
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
                random: cov_random + near.map_or(Matrix2::zeros(), |w| persistent.of(&w.cov_pixel)),
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
                score: score_of.get(&frame).copied().flatten(),
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
    use crate::terrain::DeckProfile;
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
