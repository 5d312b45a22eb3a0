//! Poses for every frame of a hovering camera (pure), from the stabiliser's carried picks:
//! robust PnP on each key frame, a joint refinement of the key-frame poses with the GCPs free
//! within their survey σ (a carried pick counting as one measurement however many key frames
//! repeat it), then every frame's pose refined on its own carried picks with the adjusted GCPs,
//! starting from its neighbour's. A frame with too few usable picks gets a pose
//! interpolated between its solved neighbours, and says so.

use nalgebra::{Matrix2, Matrix3, Vector2, Vector3};

use super::PoseError;
use super::joint::{JointObs, JointResult, refine_jointly};
use super::refine::{PointObs, project_pose, refine_pose, world_covariance};
use super::solve::{CHI2_2DOF_999, GcpObservation, PoseSettings, PoseSolution, solve_pose};
use super::stabilise::{FrameTrack, KeyReason};
use crate::camera::Camera;
use crate::geom::Rigid3;
use crate::optim::{LmSettings, RobustLoss};
use crate::progress::Progress;

/// The most key frames in the joint refinement with the GCPs.
pub const JOINT_MAX: usize = 120;

/// Whether the `n`-th of `count` items is one of `most` picked evenly (all when they are few).
fn spread_pick(n: usize, count: usize, most: usize) -> bool {
    count <= most || n * most / count != (n + 1) * most / count
}

/// A GCP as the hovering solver needs it.
#[derive(Clone, Debug)]
pub struct HoverGcp {
    pub name: String,
    pub world: Vector3<f64>,
    pub world_cov: Matrix3<f64>,
    /// σ of its pick, pixels.
    pub sigma_px: f64,
}

/// One key frame's robust solution.
#[derive(Clone, Debug)]
pub struct KeyFrame {
    pub index: usize,
    pub reason: KeyReason,
    /// Carried picks available in this frame.
    pub picks: usize,
    pub solution: Result<PoseSolution, PoseError>,
}

/// One frame's pose.
#[derive(Clone, Debug)]
pub struct FramePose {
    pub index: usize,
    pub key: bool,
    pub cam_from_world: Rigid3,
    /// σ of the camera centre (east, north, up), metres; `None` when interpolated.
    pub centre_sigma_m: Option<Vector3<f64>>,
    /// Covariance of the pose's increment (`refine` convention); `None` when interpolated.
    pub covariance: Option<nalgebra::Matrix6<f64>>,
    /// Picks used, and their mean and largest reprojection error in pixels.
    pub picks_used: usize,
    pub mean_reprojection_px: Option<f64>,
    pub max_reprojection_px: Option<f64>,
    /// Too few usable picks: the pose is interpolated between solved neighbours.
    pub interpolated: bool,
}

/// The result for a video.
#[derive(Clone, Debug)]
pub struct HoverResult {
    pub key_frames: Vec<KeyFrame>,
    /// The joint refinement over the solved key frames (in `key_frames` order, skipping failures;
    /// at most [`JOINT_MAX`] of them, evenly spread).
    pub joint: JointResult,
    pub frames: Vec<FramePose>,
}

impl HoverResult {
    /// The key frames whose pose was not solved.
    pub fn failed_key_frames(&self) -> Vec<usize> {
        self.key_frames
            .iter()
            .filter(|k| k.solution.is_err())
            .map(|k| k.index)
            .collect()
    }
}

/// Pixel covariance of a carried pick: its σ, plus the adjusted GCP's covariance projected.
fn obs_info(
    camera: &Camera,
    pose: &Rigid3,
    world: &Vector3<f64>,
    cov: &Matrix3<f64>,
    sigma_px: f64,
) -> Option<Matrix2<f64>> {
    let (_, _, jx) = project_pose(camera, pose, world)?;
    (Matrix2::identity() * (sigma_px * sigma_px) + jx * cov * jx.transpose()).try_inverse()
}

/// One frame's refined pose, its centre σ and increment covariance, and the picks it used.
struct FrameSolve {
    pose: Rigid3,
    sigma: Vector3<f64>,
    covariance: nalgebra::Matrix6<f64>,
    used: Vec<bool>,
}

/// Refines one frame's pose from `start` on its picks, dropping picks that fail the χ² test
/// (at most twice). Returns the pose, its centre σ, its increment covariance and the flags of
/// the picks used.
fn frame_pose(
    camera: &Camera,
    start: &Rigid3,
    gcps: &[HoverGcp],
    points: &[Vector3<f64>],
    point_cov: &[Matrix3<f64>],
    picks: &[Option<Vector2<f64>>],
) -> Option<FrameSolve> {
    let info = |pose: &Rigid3, j: usize| {
        obs_info(camera, pose, &points[j], &point_cov[j], gcps[j].sigma_px)
    };
    let lm = LmSettings {
        max_iterations: 30,
        ..LmSettings::default()
    };
    let mut used: Vec<bool> = picks.iter().map(Option::is_some).collect();
    let mut pose = *start;
    for pass in 0..3 {
        let obs: Vec<PointObs> = (0..gcps.len())
            .filter(|&j| used[j])
            .filter_map(|j| {
                Some(PointObs {
                    world: points[j],
                    uv: picks[j]?,
                    info: info(&pose, j)?,
                })
            })
            .collect();
        if obs.len() < 4 {
            return None;
        }
        let refined = refine_pose(camera, &pose, &obs, RobustLoss::Huber(2.0), &lm).ok()?;
        pose = refined.cam_from_world;
        let cov = world_covariance(&pose, &refined.covariance);
        let sigma = Vector3::new(cov[(3, 3)].sqrt(), cov[(4, 4)].sqrt(), cov[(5, 5)].sqrt());
        let next: Vec<bool> = (0..gcps.len())
            .map(|j| {
                let (Some(uv), Some((p, _, _)), Some(w)) = (
                    picks[j],
                    project_pose(camera, &pose, &points[j]),
                    info(&pose, j),
                ) else {
                    return false;
                };
                (uv - p).dot(&(w * (uv - p))) < CHI2_2DOF_999
            })
            .collect();
        if next == used || pass == 2 {
            return Some(FrameSolve {
                pose,
                sigma,
                covariance: refined.covariance,
                used,
            });
        }
        used = next;
    }
    None
}

/// The joint refinement's inputs: the poses of the key frames that join it (at most
/// `JOINT_MAX`, evenly spread among the solved ones), their inlying picks with σ grown by
/// √(key frames seeing the pick), and which key frames join.
fn joint_inputs(
    key_frames: &[KeyFrame],
    key_obs: &[Vec<(usize, GcpObservation)>],
    n_gcps: usize,
) -> (Vec<Rigid3>, Vec<JointObs>, Vec<bool>) {
    let mut poses = Vec::new();
    let mut jobs = Vec::new();
    // At most JOINT_MAX key frames, evenly spread, join the refinement (a crowd covering the
    // ground renews the reference almost every frame; the GCPs are as well fixed by a hundred
    // frames as by a thousand, and its cost grows with the cube of the frames); the others are
    // refined on their own in step 3 like every other frame.
    let solved_keys = key_frames.iter().filter(|k| k.solution.is_ok()).count();
    let mut in_joint = vec![false; key_frames.len()];
    {
        let mut n = 0;
        for (i, k) in key_frames.iter().enumerate() {
            if k.solution.is_ok() {
                in_joint[i] = spread_pick(n, solved_keys, JOINT_MAX);
                n += 1;
            }
        }
    }
    for ((k, obs), _) in key_frames
        .iter()
        .zip(key_obs)
        .zip(&in_joint)
        .filter(|(_, joint)| **joint)
    {
        let Ok(sol) = &k.solution else { continue };
        let pose_index = poses.len();
        poses.push(sol.cam_from_world);
        for ((j, o), r) in obs.iter().zip(&sol.residuals) {
            if !r.outlier {
                jobs.push(JointObs {
                    pose: pose_index,
                    point: *j,
                    uv: o.uv,
                    sigma_px: o.sigma_px,
                });
            }
        }
    }
    // A pick carried from one frame repeats that frame's picking error in every key frame: it is
    // one measurement, not one per key frame, so its σ grows with √(key frames seeing it).
    let mut seen_in = vec![0usize; n_gcps];
    for o in &jobs {
        seen_in[o.point] += 1;
    }
    for o in &mut jobs {
        o.sigma_px *= (seen_in[o.point] as f64).sqrt();
    }
    (poses, jobs, in_joint)
}

/// Solves every frame. `tracks` are the stabiliser's, in frame order.
pub fn solve_hover(
    camera: &Camera,
    gcps: &[HoverGcp],
    tracks: &[FrameTrack],
    settings: &PoseSettings,
    progress: &dyn Progress,
) -> Result<HoverResult, PoseError> {
    let observations = |t: &FrameTrack| -> Vec<(usize, GcpObservation)> {
        t.picks
            .iter()
            .enumerate()
            .filter_map(|(j, p)| {
                p.map(|uv| {
                    (
                        j,
                        GcpObservation {
                            name: gcps[j].name.clone(),
                            world: gcps[j].world,
                            world_cov: gcps[j].world_cov,
                            uv,
                            sigma_px: gcps[j].sigma_px,
                        },
                    )
                })
            })
            .collect()
    };
    // 1. Robust PnP on every key frame.
    let mut key_frames = Vec::new();
    let mut key_obs = Vec::new();
    for t in tracks.iter().filter(|t| t.key.is_some()) {
        let obs = observations(t);
        let list: Vec<GcpObservation> = obs.iter().map(|(_, o)| o.clone()).collect();
        let solution = solve_pose(camera, &list, settings);
        key_frames.push(KeyFrame {
            index: t.index,
            reason: t.key.expect("key"),
            picks: list.len(),
            solution,
        });
        key_obs.push(obs);
    }
    // 2. Joint refinement of the solved key frames with the GCPs.
    let (poses, jobs, in_joint) = joint_inputs(&key_frames, &key_obs, gcps.len());
    if poses.is_empty() {
        let why = key_frames
            .first()
            .and_then(|k| k.solution.as_ref().err())
            .map_or("no key frames".to_string(), |e| e.to_string());
        return Err(PoseError::Degenerate(format!(
            "no key frame could be solved; the first: {why}"
        )));
    }
    let prior: Vec<Vector3<f64>> = gcps.iter().map(|g| g.world).collect();
    let prior_cov: Vec<Matrix3<f64>> = gcps.iter().map(|g| g.world_cov).collect();
    let joint = refine_jointly(
        camera,
        &poses,
        &prior,
        &prior_cov,
        &jobs,
        settings.loss,
        &LmSettings::default(),
    )?;
    // 3. Every frame from its neighbour's pose, key frames from the joint solution.
    let mut key_pose = std::collections::HashMap::new();
    let mut solved = key_frames
        .iter()
        .zip(&in_joint)
        .filter(|(k, joint)| **joint && k.solution.is_ok())
        .map(|(k, _)| k);
    for p in &joint.poses {
        if let Some(k) = solved.next() {
            key_pose.insert(k.index, *p);
        }
    }
    progress.set_length(tracks.len() as u64);
    let mut frames: Vec<Option<FramePose>> = Vec::with_capacity(tracks.len());
    let mut last: Option<Rigid3> = None;
    let first_key = joint.poses[0];
    for t in tracks {
        let start = key_pose
            .get(&t.index)
            .copied()
            .or(last)
            .unwrap_or(first_key);
        let fp = frame_pose(
            camera,
            &start,
            gcps,
            &joint.points,
            &joint.point_cov,
            &t.picks,
        )
        .map(
            |FrameSolve {
                 pose,
                 sigma,
                 covariance,
                 used,
             }| {
                let errs: Vec<f64> = (0..gcps.len())
                    .filter(|&j| used[j])
                    .filter_map(|j| {
                        Some(
                            (t.picks[j]? - project_pose(camera, &pose, &joint.points[j])?.0).norm(),
                        )
                    })
                    .collect();
                FramePose {
                    index: t.index,
                    key: t.key.is_some(),
                    cam_from_world: pose,
                    centre_sigma_m: sigma.iter().all(|s| s.is_finite()).then_some(sigma),
                    covariance: Some(covariance),
                    picks_used: errs.len(),
                    mean_reprojection_px: Some(errs.iter().sum::<f64>() / errs.len() as f64),
                    max_reprojection_px: errs.iter().copied().reduce(f64::max),
                    interpolated: false,
                }
            },
        );
        if let Some(f) = &fp {
            last = Some(f.cam_from_world);
        }
        frames.push(fp);
        progress.inc(1);
    }
    // 4. Interpolate the frames that could not be solved.
    let out = fill_gaps(&frames, tracks)?;
    Ok(HoverResult {
        key_frames,
        joint,
        frames: out,
    })
}

/// Every frame's pose: the solved ones as they are, the others interpolated between the nearest
/// solved ones (held at the ends) and flagged.
fn fill_gaps(
    frames: &[Option<FramePose>],
    tracks: &[FrameTrack],
) -> Result<Vec<FramePose>, PoseError> {
    let solved_idx: Vec<usize> = (0..frames.len()).filter(|&i| frames[i].is_some()).collect();
    if solved_idx.is_empty() {
        return Err(PoseError::Degenerate(
            "no frame has 4 usable carried picks".into(),
        ));
    }
    let pose_of = |k: usize| frames[k].as_ref().expect("solved").cam_from_world;
    let mut out = Vec::with_capacity(frames.len());
    for (i, f) in frames.iter().enumerate() {
        if let Some(f) = f {
            out.push(f.clone());
            continue;
        }
        let pose = match super::gap_neighbours(&solved_idx, i) {
            (a, b, t) if a != b => pose_of(a).interpolate(&pose_of(b), t),
            (a, _, _) => pose_of(a),
        };
        out.push(FramePose {
            index: tracks[i].index,
            key: tracks[i].key.is_some(),
            cam_from_world: pose,
            centre_sigma_m: None,
            covariance: None,
            picks_used: 0,
            mean_reprojection_px: None,
            max_reprojection_px: None,
            interpolated: true,
        });
    }
    Ok(out)
}

/// Solves a video whose tracks carry the picks of `control` then `check` GCPs (in that order):
/// the poses from the control picks, then each frame's mean reprojection error of the check
/// points' carried picks (an independent accuracy check).
pub fn solve_with_checks(
    camera: &Camera,
    control: &[GcpObservation],
    check: &[GcpObservation],
    tracks: &[FrameTrack],
    settings: &PoseSettings,
    progress: &dyn Progress,
) -> Result<(HoverResult, Vec<Option<f64>>), PoseError> {
    let nc = control.len();
    let gcps: Vec<HoverGcp> = control
        .iter()
        .map(|o| HoverGcp {
            name: o.name.clone(),
            world: o.world,
            world_cov: o.world_cov,
            sigma_px: o.sigma_px,
        })
        .collect();
    let control_tracks: Vec<FrameTrack> = tracks
        .iter()
        .map(|t| FrameTrack {
            picks: t.picks[..nc].to_vec(),
            ..t.clone()
        })
        .collect();
    let result = solve_hover(camera, &gcps, &control_tracks, settings, progress)?;
    let check_mean = tracks
        .iter()
        .zip(&result.frames)
        .map(|(t, f)| {
            let errs: Vec<f64> = check
                .iter()
                .enumerate()
                .filter_map(|(k, o)| {
                    Some(
                        (t.picks.get(nc + k).copied().flatten()?
                            - project_pose(camera, &f.cam_from_world, &o.world)?.0)
                            .norm(),
                    )
                })
                .collect();
            (!errs.is_empty()).then(|| errs.iter().sum::<f64>() / errs.len() as f64)
        })
        .collect();
    Ok((result, check_mean))
}

#[cfg(test)]
mod tests {

    #[test]
    fn at_most_joint_max_key_frames_are_picked_evenly() {
        let picked: Vec<usize> = (0..1180).filter(|&n| spread_pick(n, 1180, 120)).collect();
        assert_eq!(picked.len(), 120);
        assert!(picked.windows(2).all(|w| (9..=10).contains(&(w[1] - w[0]))));
        assert!((0..7).all(|n| spread_pick(n, 7, 120)));
    }

    use super::*;
    use nalgebra::Rotation3;

    #[test]
    fn interpolation_is_exact_at_the_ends_and_halfway() {
        let a = Rigid3 {
            rotation: Rotation3::from_scaled_axis(Vector3::new(3.1, 0.0, 0.0)),
            translation: Vector3::new(0.0, 0.0, 30.0),
        };
        let rb = Rotation3::from_scaled_axis(Vector3::new(3.1, 0.02, 0.0));
        let b = Rigid3 {
            rotation: rb,
            translation: -(rb * Vector3::new(1.0, 0.0, -30.0)),
        };
        let m = a.interpolate(&b, 0.5);
        assert!((m.centre() - (a.centre() + b.centre()) / 2.0).norm() < 1e-9);
        assert!((a.interpolate(&b, 1.0).rotation.matrix() - b.rotation.matrix()).norm() < 1e-9);
    }
}
