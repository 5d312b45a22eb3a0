//! Where every frame's pose comes from: the project's `[pose]` kind, chosen once in [`open`].

use std::path::Path;

use nalgebra::{Matrix6, Vector2, Vector3};

use super::inputs::picked;
use super::{Env, FramePoseData, PoseData, RunError, RunInputs, ScanData, StageProgress};
use super::{model_pose, output_error};
use crate::cache::stage_key;
use crate::camera::Camera;
use crate::geom::Rigid3;
use crate::pipeline::pose_outputs::{PoseRun, write_pose_outputs};
use crate::pipeline::project::{Loaded, SurveySection};
use crate::pipeline::settings::{FixedSettings, PoseSection};
use crate::pose::hover::solve_with_checks;
use crate::pose::{GcpObservation, PoseSettings, solve_pose};
use crate::survey::load::Framed;

/// A way of posing every frame of the video.
///
/// Implemented by [`Hover`] (a hovering camera: GCP picks on one frame, carried through the
/// video by the scan's stabiliser, solved by `pose::hover`) and by `model_pose::Model` (a
/// moving camera: key frames registered in a reference model built by `geostride sfm`, the
/// frames between carried from their key frame's 2D–3D points). [`open`] makes the project's
/// one; `prepare` asks it for the first frame's pose (a head's scale in the image, before the
/// scan) and the picks the scan carries; the pose stage asks it for every frame's pose and
/// wraps the answer in the stage cache and the report. A new kind implements this trait, gets
/// a `[pose]` variant in `settings::PoseSection` and one arm in [`open`].
pub(super) trait PoseSource {
    /// The frame whose picks the scan carries through the video, and those picks' pixels
    /// (none for a source that does not use picks).
    fn carried_picks(&self) -> (usize, Vec<Vector2<f64>>);

    /// The first frame's `cam_from_world`, checked before the long work.
    fn first_pose(&self, camera: &Camera, video: &Path) -> Result<Rigid3, RunError>;

    /// The pose stage's cache key, from the scan's and the sections the source reads.
    fn stage_key(&self, scan_key: &str) -> String;

    /// Every frame's pose from the scan, the `pose/` files written into `pose_dir` (made by
    /// the source, through `env.guard`).
    fn poses(
        &self,
        env: &Env,
        x: &RunInputs,
        scan: &ScanData,
        pose_dir: &Path,
    ) -> Result<PoseData, RunError>;

    /// What the warnings say after "key frames …: [list]" and "N frame(s) have interpolated
    /// poses…".
    fn notes(&self) -> PoseNotes;

    /// The report's counts beyond those of every source (key frames, mean and largest
    /// reprojection error, interpolated frames).
    fn own_counts(&self, data: &PoseData) -> Vec<(String, f64)>;

    /// The reference model the frames are placed in, where there is one (local planes
    /// without a model of their own use it).
    fn model_dir(&self) -> Option<&Path> {
        None
    }
}

/// A source's words for its warnings.
pub(super) struct PoseNotes {
    /// Before the list of key frames not posed.
    pub failed: &'static str,
    /// After "N frame(s) have interpolated poses".
    pub interpolated: &'static str,
}

/// The project's pose source, its inputs read and checked (the model opened, the picks found):
/// the one place that reads the `[pose]` section's inputs.
pub(super) fn open<'a>(
    l: &'a Loaded,
    framed: &Framed,
    (camera, video, fps): (&Camera, &Path, f64),
    size: (u32, u32),
    frames_total: Option<usize>,
    out: &Path,
    progress: &dyn StageProgress,
) -> Result<Box<dyn PoseSource + 'a>, RunError> {
    Ok(match &l.project.pose {
        PoseSection::Hover(_) => {
            let (pick_frame, control, check) = picked(l, framed, size, frames_total)?;
            Box::new(Hover {
                key_sections: (&l.project.survey, &l.project.pose),
                pick_frame,
                control,
                check,
            })
        }
        PoseSection::Fixed(f) => Box::new(fixed_pose(l, f, framed)?),
        PoseSection::Model(m) => {
            // No survey flight's model: one from the video's own frames and picks.
            let (dir, images) = if m.model.is_empty() {
                let built = super::video_model::build_video_model(
                    l,
                    m,
                    framed,
                    (camera, video, fps, frames_total),
                    out,
                    (
                        progress.stage("video model features").as_ref(),
                        progress.stage("video model matching").as_ref(),
                    ),
                )?;
                (built.dir, built.images)
            } else {
                (l.resolve(&m.model), l.resolve(&m.model_images))
            };
            Box::new(model_pose::Model {
                key_sections: (&l.project.survey, &l.project.pose, &l.project.ground),
                model: model_pose::open_model(
                    l,
                    m,
                    framed,
                    (&dir, &images),
                    &out.join(".stages").join("model-features"),
                    progress.stage("model").as_ref(),
                )?,
                model_path: dir,
                video_at: l.error("video", "path", ""),
                settings: m,
            })
        }
    })
}

/// A hovering camera: the picks of one frame carried to every frame, key frames solved from
/// them (P3P + MSAC, refinement, a joint adjustment of the key frames and the GCPs).
pub(super) struct Hover<'a> {
    /// The sections the pose stage's key covers.
    key_sections: (&'a SurveySection, &'a PoseSection),
    /// The picked frame, and its control and check points' picks.
    pick_frame: usize,
    control: Vec<GcpObservation>,
    check: Vec<GcpObservation>,
}

impl PoseSource for Hover<'_> {
    fn carried_picks(&self) -> (usize, Vec<Vector2<f64>>) {
        let picks = self.control.iter().chain(&self.check).map(|o| o.uv);
        (self.pick_frame, picks.collect())
    }

    fn first_pose(&self, camera: &Camera, _video: &Path) -> Result<Rigid3, RunError> {
        Ok(solve_pose(camera, &self.control, &PoseSettings::default())
            .map_err(|e| {
                RunError::Unusable(format!("the picks of frame {}: {e}", self.pick_frame))
            })?
            .cam_from_world)
    }

    fn stage_key(&self, scan_key: &str) -> String {
        stage_key("pose", &[scan_key], &self.key_sections)
    }

    fn poses(
        &self,
        env: &Env,
        x: &RunInputs,
        scan: &ScanData,
        pose_dir: &Path,
    ) -> Result<PoseData, RunError> {
        let (result, check_mean) = solve_with_checks(
            &x.camera,
            &self.control,
            &self.check,
            &scan.tracks,
            &PoseSettings::default(),
            env.progress.stage("pose").as_ref(),
        )
        .map_err(|e| RunError::Unusable(format!("{}: {e}", x.video.display())))?;
        env.guard.create_dir(pose_dir).map_err(output_error)?;
        write_pose_outputs(
            pose_dir,
            &PoseRun {
                camera: &x.camera,
                result: &result,
                tracks: &scan.tracks,
                check_mean: &check_mean,
                fps: x.fps,
                framed: &x.framed,
                control: &self.control,
            },
        )?;
        let checks: Vec<f64> = check_mean.iter().flatten().copied().collect();
        let frames = result
            .frames
            .iter()
            .map(|f| FramePoseData {
                frame: f.index,
                rotation: *f.cam_from_world.rotation.matrix(),
                translation: f.cam_from_world.translation,
                covariance: f.covariance,
                interpolated: f.interpolated,
                mean_reprojection_px: f.mean_reprojection_px,
            })
            .collect();
        Ok(PoseData::new(
            frames,
            result.key_frames.iter().map(|k| k.index).collect(),
            result.failed_key_frames(),
            (!checks.is_empty()).then(|| checks.iter().sum::<f64>() / checks.len() as f64),
        ))
    }

    fn notes(&self) -> PoseNotes {
        PoseNotes {
            failed: "key frames not solved (too few carried picks)",
            interpolated: " (fewer than 4 usable picks)",
        }
    }

    fn own_counts(&self, data: &PoseData) -> Vec<(String, f64)> {
        data.check_mean_reprojection_px
            .map(|c| ("check_mean_reprojection_px".to_string(), c))
            .into_iter()
            .collect()
    }
}

/// The moving camera (`model_pose`): the model opened by [`open`], the algorithm in
/// `sfm::video_pose`.
impl PoseSource for model_pose::Model<'_> {
    fn carried_picks(&self) -> (usize, Vec<Vector2<f64>>) {
        (0, Vec::new())
    }

    fn first_pose(&self, camera: &Camera, video: &Path) -> Result<Rigid3, RunError> {
        model_pose::first_frame_pose(self, camera, video)
    }

    fn stage_key(&self, scan_key: &str) -> String {
        stage_key("pose", &[scan_key], &self.key_sections)
    }

    fn poses(
        &self,
        env: &Env,
        x: &RunInputs,
        scan: &ScanData,
        pose_dir: &Path,
    ) -> Result<PoseData, RunError> {
        let bar = env.progress.stage("pose");
        let poses =
            model_pose::model_poses(env, x, (self.settings, &self.model), scan, bar.as_ref())?;
        env.guard.create_dir(pose_dir).map_err(output_error)?;
        model_pose::write_model_pose_outputs(
            pose_dir,
            &poses,
            scan,
            &x.framed,
            Some(x.surface.as_ref()),
            &self.model,
        )?;
        Ok(PoseData::new(
            poses.frames,
            poses.key_frames,
            poses.key_frames_failed,
            None,
        ))
    }

    fn notes(&self) -> PoseNotes {
        PoseNotes {
            failed: "key frames not placed in the model (see pose/key_frames.csv)",
            interpolated: ", flagged in pose/poses.csv (their features did not place them in the model)",
        }
    }

    fn own_counts(&self, data: &PoseData) -> Vec<(String, f64)> {
        vec![
            (
                "key_frames_failed".into(),
                data.key_frames_failed.len() as f64,
            ),
            ("model_fit_rms_m".into(), self.model.fit_rms_m),
        ]
    }

    fn model_dir(&self) -> Option<&Path> {
        Some(&self.model_path)
    }
}

/// The fixed camera's pose from its file, in the site frame: the file's world must be the run's
/// (a survey in a CRS has a site frame of its own).
fn fixed_pose<'a>(
    l: &'a Loaded,
    f: &FixedSettings,
    framed: &Framed,
) -> Result<Fixed<'a>, RunError> {
    let (key, name) = match &f.extrinsics {
        Some(file) => ("extrinsics", file.as_str()),
        None => ("", l.project.camera.calibration.as_str()),
    };
    let at = |message: String| RunError::Input(l.error("pose", key, message));
    if crate::camera::presets::preset(name).is_some() {
        return Err(at(format!(
            "'{name}' is a camera preset, which has no pose: set extrinsics = \"FILE\" (a Tsai \
             calibration, or geostride JSON with 'extrinsics')"
        )));
    }
    let path = l.resolve(name);
    let cal = crate::camera::formats::read(&path, None).map_err(|e| at(e.to_string()))?;
    let Some(extrinsics) = cal.extrinsics else {
        return Err(at(format!(
            "{} has no camera pose: a fixed camera needs a Tsai calibration or geostride JSON \
             with 'extrinsics' (geostride camera convert writes one)",
            path.display()
        )));
    };
    if let Some(crs) = &framed.frame.crs {
        return Err(RunError::Input(l.error(
            "survey",
            "gcps",
            format!(
                "the fixed camera's pose is in {} ({}), and this survey is in {}, whose site \
                 frame is another: give the GCPs in the pose's world frame without a CRS, or \
                 leave gcps out",
                extrinsics.world,
                path.display(),
                crs.label()
            ),
        )));
    }
    let floor = crate::sfm::video_pose::ModelFloor {
        sigma_centre_m: Vector3::repeat(f.sigma_m),
        sigma_rotation_rad: Vector3::repeat(f.sigma_deg.to_radians()),
        lever_m: 0.0,
    };
    let pose = extrinsics.cam_from_world;
    Ok(Fixed {
        key_sections: (&l.project.survey, &l.project.pose),
        pose,
        covariance: floor.add_to(&pose, &Matrix6::zeros()),
    })
}

/// A camera that does not move: one pose, from its calibration file, for every frame.
pub(super) struct Fixed<'a> {
    key_sections: (&'a SurveySection, &'a PoseSection),
    pose: Rigid3,
    /// The pose's covariance (increment `(δθ, δt)`), from the stated σ.
    covariance: Matrix6<f64>,
}

impl PoseSource for Fixed<'_> {
    fn carried_picks(&self) -> (usize, Vec<Vector2<f64>>) {
        (0, Vec::new())
    }

    fn first_pose(&self, _camera: &Camera, _video: &Path) -> Result<Rigid3, RunError> {
        Ok(self.pose)
    }

    fn stage_key(&self, scan_key: &str) -> String {
        stage_key("pose", &[scan_key], &self.key_sections)
    }

    fn poses(
        &self,
        env: &Env,
        x: &RunInputs,
        scan: &ScanData,
        pose_dir: &Path,
    ) -> Result<PoseData, RunError> {
        let frames: Vec<FramePoseData> = (0..scan.frames)
            .map(|frame| FramePoseData {
                frame,
                rotation: *self.pose.rotation.matrix(),
                translation: self.pose.translation,
                covariance: Some(self.covariance),
                interpolated: false,
                mean_reprojection_px: None,
            })
            .collect();
        env.guard.create_dir(pose_dir).map_err(output_error)?;
        let sigma = crate::pose::refine::world_covariance(&self.pose, &self.covariance);
        let columns = crate::pipeline::pose_outputs::pose_columns(
            &self.pose,
            Some(Vector3::new(
                sigma[(3, 3)].sqrt(),
                sigma[(4, 4)].sqrt(),
                sigma[(5, 5)].sqrt(),
            )),
            &x.framed,
        )?;
        let csv = format!(
            "frames,{}\n0-{},{columns}\n",
            crate::pipeline::pose_outputs::POSE_COLUMNS,
            scan.frames.saturating_sub(1)
        );
        let path = pose_dir.join("poses.csv");
        crate::io::write_atomic(&path, csv.as_bytes())
            .map_err(|source| RunError::Io { path, source })?;
        Ok(PoseData::new(frames, Vec::new(), Vec::new(), None))
    }

    fn notes(&self) -> PoseNotes {
        PoseNotes {
            failed: "",
            interpolated: "",
        }
    }

    fn own_counts(&self, _data: &PoseData) -> Vec<(String, f64)> {
        Vec::new()
    }
}
