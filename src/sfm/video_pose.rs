//! A moving camera's every frame placed in a reference model (pure), the twin of `pose::hover`
//! for a camera that travels: each key frame registered in the model (`Reference::place_key_frame`,
//! beside the model in `sfm::reference`), the frames between carried from their key frame's
//! 2D–3D inliers through the stabiliser's homography ([`carry_to_frames`]), the frames left
//! interpolated by the one gap rule, `pose::gap_neighbours` ([`fill_unplaced`]). Every pose's σ
//! has the model's georeferencing σ as its floor. The run's `model` pose source decodes the
//! frames, masks the people and calls these.

use std::collections::BTreeMap;

use nalgebra::{Matrix2, Matrix3, Matrix6, Vector2, Vector3};

use crate::camera::Camera;
use crate::geom::Rigid3;
use crate::optim::{LmSettings, RobustLoss};
use crate::pose::refine::{PointObs, RefinedPose, refine_pose};
use crate::pose::stabilise::FrameTrack;
use crate::progress::Progress;

/// The image noise a placed frame's fit assumes, pixels: its covariance is scaled up by its
/// residuals beyond.
pub const SIGMA_PX: f64 = 1.0;

/// How frames are placed.
#[derive(Clone, Debug)]
pub struct VideoPoseSettings {
    /// Model photos a key frame is matched with, nearest the last frame placed.
    pub neighbours: usize,
    /// Inliers a frame needs.
    pub min_inliers: usize,
}

/// The model's georeferencing σ: centre east/north/up (m), attitude about the east, north and
/// up axes (rad). No frame placed in the model is better placed than the model.
///
/// A model placed by GCPs on the ground turns about them: a datum tilt ω moves a camera `lever_m`
/// above the ground by ω × (0, 0, lever) with it, so its centre and attitude errors are one
/// error that cancels on the ground. With a lever, `sigma_centre_m` is the datum's shift at the
/// ground and the centre's σ is that and the tilt's share together, correlated with the
/// attitude; with none, centre and attitude are independent (a camera on a pole).
#[derive(Clone, Copy, Debug)]
pub struct ModelFloor {
    pub sigma_centre_m: Vector3<f64>,
    pub sigma_rotation_rad: Vector3<f64>,
    pub lever_m: f64,
}

/// One frame's pose from the model: `cam_from_world`, its covariance (increment `(δθ, δt)`),
/// the RMS reprojection error of its points.
#[derive(Clone, Copy, Debug)]
pub struct Placed {
    pub pose: Rigid3,
    pub covariance: Matrix6<f64>,
    pub rms_px: f64,
}

/// A key frame placed, and its inliers (pixel, model point) that carry it to the frames that
/// reference it.
#[derive(Clone, Debug)]
pub struct PlacedKey {
    pub placed: Placed,
    pub matched: Vec<(Vector2<f64>, Vector3<f64>)>,
}

/// Every frame's pose once the gaps are filled.
#[derive(Clone, Copy, Debug)]
pub struct FramePose {
    pub pose: Rigid3,
    pub covariance: Matrix6<f64>,
    /// Interpolated between placed frames (no reprojection error of its own).
    pub interpolated: bool,
    pub rms_px: Option<f64>,
}

impl ModelFloor {
    /// The pose covariance (increment `(δθ, δt)`) with the model's σ added: centre σ in the
    /// world, attitude σ about each world axis.
    pub fn add_to(&self, pose: &Rigid3, cov: &Matrix6<f64>) -> Matrix6<f64> {
        // δθ = −R δφ_world and δt = −R δC (the inverse of `pose::refine::world_covariance`).
        let r = *pose.rotation.matrix();
        let mut j = Matrix6::zeros();
        j.fixed_view_mut::<3, 3>(0, 0).copy_from(&(-r));
        j.fixed_view_mut::<3, 3>(3, 3).copy_from(&(-r));
        cov + j * self.world_covariance() * j.transpose()
    }

    /// The floor as a covariance of `(δφ_world, δC)`: a shift at the ground and a tilt about
    /// it, δC = t + ω × (0, 0, lever).
    pub fn world_covariance(&self) -> Matrix6<f64> {
        let var = self.sigma_rotation_rad.map(|s| s * s);
        let l = self.lever_m;
        let mut world = Matrix6::zeros();
        for k in 0..3 {
            world[(k, k)] = var[k];
            world[(3 + k, 3 + k)] = self.sigma_centre_m[k].powi(2);
        }
        // ω × (0, 0, l) = (l ω_y, −l ω_x, 0).
        world[(3, 3)] += l * l * var.y;
        world[(4, 4)] += l * l * var.x;
        world[(3, 1)] = l * var.y;
        world[(1, 3)] = l * var.y;
        world[(4, 0)] = -l * var.x;
        world[(0, 4)] = -l * var.x;
        world
    }

    /// A refined pose as placed: its covariance scaled by its residuals (σ taken as
    /// [`SIGMA_PX`] in the fit), the model's σ added.
    pub fn placed(&self, p: &RefinedPose, rms_px: f64) -> Placed {
        let scaled = p.covariance * (rms_px / SIGMA_PX).max(1.0).powi(2);
        Placed {
            covariance: self.add_to(&p.cam_from_world, &scaled),
            pose: p.cam_from_world,
            rms_px,
        }
    }
}

/// Every frame of `tracks` (the stabiliser's, in order): a key frame's own pose, or its key
/// frame's inliers carried into it; `None` where neither is there.
pub fn carry_to_frames(
    camera: &Camera,
    keys: &BTreeMap<usize, PlacedKey>,
    tracks: &[FrameTrack],
    floor: &ModelFloor,
    s: &VideoPoseSettings,
    progress: &dyn Progress,
) -> Vec<Option<Placed>> {
    let mut placed = Vec::with_capacity(tracks.len());
    for t in tracks {
        let f = t.index;
        let p = if let Some(k) = keys.get(&f).filter(|_| t.key.is_some()) {
            Some(k.placed)
        } else if let Some(k) = keys.get(&t.reference) {
            pose_from_carried(
                camera,
                &k.placed.pose,
                &k.matched,
                &t.frame_from_ref,
                SIGMA_PX,
                s.min_inliers,
            )
            .map(|(p, rms, _)| floor.placed(&p, rms))
        } else {
            None
        };
        placed.push(p);
        progress.inc(1);
    }
    placed
}

/// A frame's pose from a key frame's 2D–3D inliers carried into it by `frame_from_key` (the
/// stabiliser's homography of tracked features), refined from `start` with a Cauchy loss at
/// `sigma_px` so that a point the homography carries badly (off the ground plane) loses its
/// pull. Gives the pose and the RMS reprojection error of the points within 3 σ, or `None`
/// when too few points land in the image or the refinement fails.
pub fn pose_from_carried(
    camera: &Camera,
    start: &Rigid3,
    key_points: &[(Vector2<f64>, Vector3<f64>)],
    frame_from_key: &Matrix3<f64>,
    sigma_px: f64,
    min_points: usize,
) -> Option<(RefinedPose, f64, usize)> {
    let size = camera.image_size;
    let info = Matrix2::identity() / (sigma_px * sigma_px);
    let obs: Vec<PointObs> = key_points
        .iter()
        .filter_map(|(uv, world)| {
            let h = frame_from_key * uv.push(1.0);
            if h.z.abs() < 1e-12 {
                return None;
            }
            let uv = h.xy() / h.z;
            if let Some(s) = size
                && (uv.x < 0.0 || uv.y < 0.0 || uv.x > s.width as f64 || uv.y > s.height as f64)
            {
                return None;
            }
            Some(PointObs {
                world: *world,
                uv,
                info,
            })
        })
        .collect();
    if obs.len() < min_points {
        return None;
    }
    let refined = refine_pose(
        camera,
        start,
        &obs,
        RobustLoss::Cauchy(3.0),
        &LmSettings::default(),
    )
    .ok()?;
    let errs: Vec<f64> = obs
        .iter()
        .filter_map(|o| {
            camera
                .project(&refined.cam_from_world.apply(&o.world))
                .ok()
                .map(|p| (p - o.uv).norm())
        })
        .filter(|e| *e <= 3.0 * sigma_px)
        .collect();
    if errs.len() < min_points {
        return None;
    }
    let rms = (errs.iter().map(|e| e * e).sum::<f64>() / errs.len() as f64).sqrt();
    Some((refined, rms, errs.len()))
}

/// Every frame's pose: the placed ones as they are, the others interpolated between the
/// nearest placed ones (held at the ends), flagged, their σ the wider neighbour's plus half the
/// camera's travel across the gap. `None` when no frame is placed.
pub fn fill_unplaced(placed: &[Option<Placed>]) -> Option<Vec<FramePose>> {
    let known: Vec<usize> = (0..placed.len()).filter(|&i| placed[i].is_some()).collect();
    if known.is_empty() {
        return None;
    }
    let mut frames = Vec::with_capacity(placed.len());
    for (i, p) in placed.iter().enumerate() {
        let d = match p {
            Some(p) => FramePose {
                pose: p.pose,
                covariance: p.covariance,
                interpolated: false,
                rms_px: Some(p.rms_px),
            },
            None => {
                let (a, b, t) = crate::pose::gap_neighbours(&known, i);
                let (pa, pb) = (
                    placed[a].as_ref().expect("known"),
                    placed[b].as_ref().expect("known"),
                );
                let pose = pa.pose.interpolate(&pb.pose, t);
                // The gap's own motion is unknown: at least the neighbours' σ, plus how far the
                // camera moved across it.
                let gap = (pb.pose.centre() - pa.pose.centre()).norm() * t.min(1.0 - t);
                let mut cov = if pa.covariance.trace() >= pb.covariance.trace() {
                    pa.covariance
                } else {
                    pb.covariance
                };
                for k in 3..6 {
                    cov[(k, k)] += (0.5 * gap).powi(2);
                }
                FramePose {
                    pose,
                    covariance: cov,
                    interpolated: true,
                    rms_px: None,
                }
            }
        };
        frames.push(d);
    }
    Some(frames)
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::Rotation3;

    #[test]
    fn a_ground_tied_floor_leaves_its_ground_shift_below_the_camera() {
        // A datum tilted about the ground moves a camera 30 m up by 30 m × the tilt, and its
        // attitude with it: the point below it stays within the shift at the ground.
        let floor = ModelFloor {
            sigma_centre_m: Vector3::new(0.005, 0.006, 0.04),
            sigma_rotation_rad: Vector3::new(0.002, 0.0055, 0.0003),
            lever_m: 30.0,
        };
        let world = floor.world_covariance();
        // The camera centre's σ east is the shift and the tilt about north together.
        let east = (0.005f64.powi(2) + (30.0f64 * 0.0055).powi(2)).sqrt();
        assert!((world[(3, 3)].sqrt() - east).abs() < 1e-12);
        // δG = δC + δφ × (G − C), G 30 m below C.
        let below = Vector3::new(0.0, 0.0, -30.0);
        let mut j = nalgebra::Matrix3x6::zeros();
        j.fixed_view_mut::<3, 3>(0, 0)
            .copy_from(&(-below.cross_matrix()));
        j.fixed_view_mut::<3, 3>(0, 3)
            .copy_from(&Matrix3::identity());
        let ground = j * world * j.transpose();
        assert!((ground[(0, 0)].sqrt() - 0.005).abs() < 1e-9, "{ground}");
        assert!((ground[(1, 1)].sqrt() - 0.006).abs() < 1e-9, "{ground}");
        assert!(ground[(0, 1)].abs() < 1e-12, "{ground}");
        // Without a lever the two are independent: the tilt's share reaches the ground.
        let pole = ModelFloor {
            lever_m: 0.0,
            ..floor
        };
        let ground = j * pole.world_covariance() * j.transpose();
        assert!(ground[(0, 0)].sqrt() > 0.16, "{ground}");
    }

    #[test]
    fn carried_points_give_the_moved_cameras_pose() {
        // A nadir camera 30 m over flat ground, then 1 m further east: the ground's homography
        // between the two images carries the key frame's points exactly.
        let camera = Camera::pinhole(1400.0, 1400.0, 960.0, 540.0).with_image_size(1920, 1080);
        let r = Rotation3::from_euler_angles(std::f64::consts::PI, 0.0, 0.0);
        let at = |e: f64| Rigid3::new(r, -(r * Vector3::new(e, 0.0, 30.0)));
        let (key, moved) = (at(0.0), at(1.0));
        let mut pts = Vec::new();
        for i in 0..10 {
            for j in 0..6 {
                let w = Vector3::new(-12.0 + 2.5 * i as f64, -7.0 + 2.5 * j as f64, 0.0);
                pts.push((camera.project(&key.apply(&w)).unwrap(), w));
            }
        }
        // 1 m east is 1400/30 px to the left in this camera (x right = east when looking down
        // with this rotation: x stays east).
        let dx = -1400.0 / 30.0;
        let h = Matrix3::new(1.0, 0.0, dx, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0);
        let (p, rms, n) = pose_from_carried(&camera, &key, &pts, &h, 0.5, 6).unwrap();
        assert!(rms < 1e-6, "{rms}");
        assert!(n > 40);
        assert!((p.cam_from_world.centre() - moved.centre()).norm() < 1e-6);
    }

    #[test]
    fn unplaced_frames_are_interpolated_flagged_and_less_certain() {
        let r = nalgebra::Rotation3::from_euler_angles(std::f64::consts::PI, 0.0, 0.0);
        let at = |n: f64| Placed {
            pose: Rigid3::new(r, -(r * Vector3::new(0.0, n, 30.0))),
            covariance: Matrix6::identity() * 1e-6,
            rms_px: 0.2,
        };
        let placed = vec![None, Some(at(0.0)), None, None, Some(at(3.0)), None];
        let f = fill_unplaced(&placed).unwrap();
        let flags: Vec<bool> = f.iter().map(|p| p.interpolated).collect();
        assert_eq!(flags, [true, false, true, true, false, true]);
        // Frame 2 a third of the way from frame 1 to 4; the ends held.
        assert!((f[2].pose.centre() - Vector3::new(0.0, 1.0, 30.0)).norm() < 1e-9);
        assert!((f[0].pose.centre() - Vector3::new(0.0, 0.0, 30.0)).norm() < 1e-9);
        assert!((f[5].pose.centre() - Vector3::new(0.0, 3.0, 30.0)).norm() < 1e-9);
        // Less certain than the measured ones, and no reprojection error claimed.
        let c = f[2].covariance;
        assert!(c[(4, 4)] > 1e-6 && f[2].rms_px.is_none());
        assert!(fill_unplaced(&[None, None]).is_none());
    }
}
