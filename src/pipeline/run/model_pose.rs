//! The `model` pose (a moving camera): the reference model moved into the run's site frame, key
//! frames registered in it, the frames between carried from their key frame's 2D–3D points.

use super::*;
use crate::pipeline::grounds::site_from_model;
use crate::pipeline::pose_outputs::{POSE_COLUMNS, csv_num, pose_columns};
use crate::pipeline::settings::ModelSettings;
use crate::sfm::FeatureSettings;
use crate::sfm::matching::MatchSettings;
use crate::sfm::reference::{Reference, mask_features, model_max_features, pose_from_carried};
use crate::sfm::register::{RegisterSettings, Registration};
use crate::sfm::register_job::{camera_series, write_pose_series};
use crate::sfm::sift::for_video_frames;

/// A reference model in the run's site frame, and how well its georeferencing is known.
pub(super) struct SiteModel {
    pub reference: Reference,
    pub features: FeatureSettings,
    /// The model cameras' median σ: centre east/north/up (m), attitude (rad). The floor of
    /// every frame's pose σ: a frame placed in the model is no better placed than the model.
    pub sigma_centre_m: Vector3<f64>,
    pub sigma_rotation_rad: f64,
    /// RMS of the model's cameras from their CRS positions after the move, metres.
    pub fit_rms_m: f64,
}

fn median(mut v: Vec<f64>) -> f64 {
    v.sort_by(f64::total_cmp);
    v.get(v.len() / 2).copied().unwrap_or(0.0)
}

/// Reads the reference model of `[pose] kind = "model"`, its photos' features (kept in
/// `cache_dir`, under the run's output: the model folder is an input, never written), and moves
/// it into the site frame.
pub(super) fn open_model(
    l: &Loaded,
    m: &ModelSettings,
    framed: &Framed,
    cache_dir: &Path,
    progress: &dyn Progress,
) -> Result<SiteModel, RunError> {
    let dir = l.resolve(&m.model);
    // The model's own files checked first: its cameras' CSV is only as good as they are.
    let model = crate::sfm::register::read_model(&dir)
        .map_err(|e| RunError::Input(l.error("pose", "model", e.to_string())))?;
    let (site_from, fit_rms_m, cams) = site_from_model(l, "pose", &dir, framed)?;
    let features = FeatureSettings {
        max_features: m.max_features.unwrap_or_else(|| model_max_features(&dir)),
        ..FeatureSettings::default()
    };
    let cache = crate::sfm::cache::SfmCache::new(Some(cache_dir));
    let mut reference = Reference::of_model(
        model,
        &dir,
        &l.resolve(&m.model_images),
        &features,
        &cache,
        progress,
    )
    .map_err(|e| RunError::Input(l.error("pose", "model_images", e.to_string())))?;
    reference.transform(&site_from);
    let pick =
        |f: &dyn Fn(&crate::sfm::reference::GeoCamera) -> f64| median(cams.iter().map(f).collect());
    Ok(SiteModel {
        reference,
        features,
        sigma_centre_m: Vector3::new(
            pick(&|c| c.sigma_enu_m.x),
            pick(&|c| c.sigma_enu_m.y),
            pick(&|c| c.sigma_enu_m.z),
        ),
        sigma_rotation_rad: pick(&|c| c.sigma_rotation_deg).to_radians(),
        fit_rms_m,
    })
}

/// Leaves the people out of a frame's features: squares of `mask_px` around each detection,
/// and the detections' boxes.
fn mask_people(f: &mut crate::sfm::Features, detections: &[Detection], mask_px: f64) {
    let boxes: Vec<[f64; 4]> = detections
        .iter()
        .flat_map(|d| {
            let h = mask_px / 2.0;
            [[d.uv.x - h, d.uv.y - h, mask_px, mask_px], d.bbox]
        })
        .collect();
    mask_features(f, &boxes);
}

fn settings_of(m: &ModelSettings) -> RegisterSettings {
    RegisterSettings {
        min_inliers: m.min_inliers,
        ..RegisterSettings::default()
    }
}

/// Registers one frame against the model photos nearest `near` (all when it fails there); gives
/// the photos it was last matched with too.
fn register_frame(
    model: &SiteModel,
    camera: &Camera,
    name: &str,
    features: &crate::sfm::Features,
    near: Option<&Vector3<f64>>,
    m: &ModelSettings,
) -> (Registration, Vec<usize>) {
    let with = model.reference.nearest_images(near, m.neighbours);
    let all = model.reference.model.images.len();
    let r = model.reference.register(
        camera,
        name,
        features,
        &with,
        &MatchSettings::default(),
        &settings_of(m),
    );
    if r.pose.is_some() || with.len() == all {
        return (r, with);
    }
    let every: Vec<usize> = (0..all).collect();
    let r = model.reference.register(
        camera,
        name,
        features,
        &every,
        &MatchSettings::default(),
        &settings_of(m),
    );
    (r, every)
}

/// The pose of frame 0, registered against every model photo: the detector's scale, and a
/// check that the video can be placed in the model before the long work.
pub(super) fn first_frame_pose(
    l: &Loaded,
    m: &ModelSettings,
    model: &SiteModel,
    camera: &Camera,
    video: &Path,
) -> Result<Rigid3, RunError> {
    let mut first = None;
    for_video_frames(video, &[0], &model.features, |_, f| {
        first = Some(f);
        Ok::<(), RunError>(())
    })
    .map_err(|e| RunError::Input(l.error("video", "path", e.to_string())))?;
    let f = first
        .ok_or_else(|| RunError::Input(l.error("video", "path", "the video has no frames")))?;
    let (r, _) = register_frame(model, camera, "frame 0", &f, None, m);
    r.pose.ok_or_else(|| {
        RunError::Unusable(format!(
            "{}: frame 0 could not be placed in the model {}: {} (is the model of this site, and the camera's calibration the video's?)",
            video.display(),
            l.resolve(&m.model).display(),
            r.reason.unwrap_or_default()
        ))
    })
}

/// One frame's pose from the model.
#[derive(Clone, Copy)]
struct Placed {
    pose: Rigid3,
    covariance: Matrix6<f64>,
    rms_px: f64,
}

/// The pose covariance (increment `(δθ, δt)`) with the model's georeferencing σ added: centre
/// σ in the world, attitude σ about each world axis.
fn with_floor(pose: &Rigid3, cov: &Matrix6<f64>, model: &SiteModel) -> Matrix6<f64> {
    // δθ = −R δφ_world and δt = −R δC (the inverse of `pose::refine::world_covariance`).
    let r = *pose.rotation.matrix();
    let mut j = Matrix6::zeros();
    j.fixed_view_mut::<3, 3>(0, 0).copy_from(&(-r));
    j.fixed_view_mut::<3, 3>(3, 3).copy_from(&(-r));
    let mut world = Matrix6::zeros();
    for k in 0..3 {
        world[(k, k)] = model.sigma_rotation_rad.powi(2);
        world[(3 + k, 3 + k)] = model.sigma_centre_m[k].powi(2);
    }
    cov + j * world * j.transpose()
}

/// A refined pose's covariance scaled by its residuals (σ taken as `sigma_px` in the fit).
fn scaled(p: &crate::pose::refine::RefinedPose, rms_px: f64, sigma_px: f64) -> Matrix6<f64> {
    p.covariance * (rms_px / sigma_px).max(1.0).powi(2)
}

/// What the `model` pose gives the pose stage.
pub(super) struct ModelPoses {
    pub frames: Vec<FramePoseData>,
    pub key_frames: Vec<usize>,
    pub key_frames_failed: Vec<usize>,
    pub registrations: Vec<(usize, Registration, Vec<usize>)>,
}

/// Every frame's pose: key frames registered in the model, the frames between carried.
pub(super) fn model_poses(
    ctx: &Ctx,
    m: &ModelSettings,
    model: &SiteModel,
    scan: &ScanData,
    progress: &dyn Progress,
) -> Result<ModelPoses, RunError> {
    let camera = &ctx.camera;
    let n = scan.frames;
    let keys: Vec<usize> = scan
        .tracks
        .iter()
        .filter(|t| t.key.is_some())
        .map(|t| t.index)
        .collect();
    progress.set_length((keys.len() + n) as u64);
    let mask_px = m.mask_m * scan.px_per_m;
    let sigma_px = 1.0;

    // 1. Key frames: features (people masked), registered in order near the last one placed.
    let mut placed_keys: BTreeMap<usize, (Placed, Vec<(Vector2<f64>, Vector3<f64>)>)> =
        BTreeMap::new();
    let mut registrations = Vec::new();
    let mut near = Some(ctx.first_pose.centre());
    let video_name = ctx
        .video
        .file_name()
        .map_or("video".into(), |f| f.to_string_lossy().into_owned());
    // The key frames' detections, read back a chunk at a time (a long video's are not held).
    let mut chunk: Option<crate::pipeline::chunk_pass::ChunkData> = None;
    for_video_frames(&ctx.video, &keys, &model.features, |index, mut f| {
        let c = index / ctx.grid.chunk_frames;
        if chunk.as_ref().is_none_or(|d| d.index != c) {
            chunk = Some(super::scan_stage::load_chunk(ctx, c).ok_or_else(|| {
                RunError::Failed(format!(
                    "{}: chunk {c}'s file is gone or damaged: run again",
                    ctx.out.display()
                ))
            })?);
        }
        let dets = chunk
            .as_ref()
            .and_then(|d| d.detections.get(index.checked_sub(d.start)?))
            .map_or(&[][..], Vec::as_slice);
        mask_people(&mut f, dets, mask_px);
        let name = format!("{video_name}#{index}");
        let (mut r, with) = register_frame(model, camera, &name, &f, near.as_ref(), m);
        if let Some(start) = r.pose {
            // The pose and its covariance from the inliers (model points held fixed).
            let refined = pose_from_carried(
                camera,
                &start,
                &r.matched,
                &Matrix3::identity(),
                sigma_px,
                m.min_inliers,
            );
            if let Some((p, rms, _)) = refined {
                near = Some(p.cam_from_world.centre());
                let cov = with_floor(&p.cam_from_world, &scaled(&p, rms, sigma_px), model);
                placed_keys.insert(
                    index,
                    (
                        Placed {
                            pose: p.cam_from_world,
                            covariance: cov,
                            rms_px: rms,
                        },
                        r.matched.clone(),
                    ),
                );
            } else {
                r.reason = Some("its inliers did not refine to a pose".into());
            }
        }
        registrations.push((index, r, with));
        progress.inc(1);
        Ok::<(), RunError>(())
    })?;

    // 2. Every frame: a key frame's own pose, or its key frame's points carried into it.
    let mut placed: Vec<Option<Placed>> = Vec::with_capacity(n);
    for t in scan.tracks.iter().take(n) {
        let f = t.index;
        let p = if let Some((k, _)) = placed_keys.get(&f).filter(|_| t.key.is_some()) {
            Some(*k)
        } else if let Some((k, pts)) = placed_keys.get(&t.reference) {
            pose_from_carried(
                camera,
                &k.pose,
                pts,
                &t.frame_from_ref,
                sigma_px,
                m.min_inliers,
            )
            .map(|(p, rms, _)| Placed {
                covariance: with_floor(&p.cam_from_world, &scaled(&p, rms, sigma_px), model),
                pose: p.cam_from_world,
                rms_px: rms,
            })
        } else {
            None
        };
        placed.push(p);
        progress.inc(1);
    }

    // 3. Frames not placed: interpolated between the nearest placed ones (held at the ends),
    // flagged, with the wider σ of their neighbours.
    let Some(frames) = fill_unplaced(&placed) else {
        return Err(RunError::Unusable(format!(
            "{}: no key frame could be placed in the model ({})",
            ctx.video.display(),
            registrations
                .iter()
                .filter_map(|(_, r, _)| r.reason.clone())
                .next()
                .unwrap_or_default()
        )));
    };
    Ok(ModelPoses {
        frames,
        key_frames: keys.clone(),
        key_frames_failed: keys
            .iter()
            .copied()
            .filter(|k| !placed_keys.contains_key(k))
            .collect(),
        registrations,
    })
}

/// Every frame's pose: the placed ones as they are, the others interpolated between the
/// nearest placed ones (held at the ends), flagged, their σ the wider neighbour's plus half the
/// camera's travel across the gap. `None` when no frame is placed.
fn fill_unplaced(placed: &[Option<Placed>]) -> Option<Vec<FramePoseData>> {
    let known: Vec<usize> = (0..placed.len()).filter(|&i| placed[i].is_some()).collect();
    if known.is_empty() {
        return None;
    }
    let mut frames = Vec::with_capacity(placed.len());
    for (i, p) in placed.iter().enumerate() {
        let d = match p {
            Some(p) => FramePoseData {
                frame: i,
                rotation: *p.pose.rotation.matrix(),
                translation: p.pose.translation,
                covariance: Some(p.covariance),
                interpolated: false,
                mean_reprojection_px: Some(p.rms_px),
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
                FramePoseData {
                    frame: i,
                    rotation: *pose.rotation.matrix(),
                    translation: pose.translation,
                    covariance: Some(cov),
                    interpolated: true,
                    mean_reprojection_px: None,
                }
            }
        };
        frames.push(d);
    }
    Some(frames)
}

/// `pose/` of a `model` run: `poses.csv` (every frame), `key_frames.csv` (each key frame's
/// registration) and the paper's Fig. 10 (`pose_series.csv`, `pose_translation.png`,
/// `pose_altitude.png`, `pose_off_nadir.png`).
pub(super) fn write_model_pose_outputs(
    dir: &Path,
    poses: &ModelPoses,
    scan: &ScanData,
    framed: &Framed,
    ground: Option<&dyn HeightSurface>,
    model: &SiteModel,
) -> Result<(), RunError> {
    use std::fmt::Write as _;
    let fps = scan.fps;
    let io = |path: PathBuf| move |source| RunError::Io { path, source };
    let mut csv = format!("frame,time_s,key,reference,interpolated,rms_px,{POSE_COLUMNS}\n");
    for (f, t) in poses.frames.iter().zip(&scan.tracks) {
        let pose = f.pose();
        let sg = f.covariance.map(|cv| {
            let w = crate::pose::refine::world_covariance(&pose, &cv);
            Vector3::new(w[(3, 3)].sqrt(), w[(4, 4)].sqrt(), w[(5, 5)].sqrt())
        });
        let _ = writeln!(
            csv,
            "{},{:.6},{},{},{},{},{}",
            f.frame,
            f.frame as f64 / fps,
            u8::from(t.key.is_some()),
            t.reference,
            u8::from(f.interpolated),
            csv_num(f.mean_reprojection_px, 4),
            pose_columns(&pose, sg, framed)?
        );
    }
    write_atomic(&dir.join("poses.csv"), csv.as_bytes()).map_err(io(dir.join("poses.csv")))?;
    let mut keys =
        String::from("frame,placed,correspondences,inliers,rms_px,model_images,reason\n");
    for (f, r, with) in &poses.registrations {
        let names: Vec<&str> = with
            .iter()
            .map(|&k| model.reference.model.images[k].name.as_str())
            .collect();
        let _ = writeln!(
            keys,
            "{f},{},{},{},{},{},{}",
            if poses.key_frames_failed.contains(f) {
                "no"
            } else {
                "yes"
            },
            r.correspondences,
            r.inliers,
            r.rms_px.map_or(String::new(), |v| format!("{v:.4}")),
            names.join(" "),
            // One plain field: no comma, no quote.
            r.reason
                .clone()
                .unwrap_or_default()
                .replace([',', '"'], ";")
        );
    }
    write_atomic(&dir.join("key_frames.csv"), keys.as_bytes())
        .map_err(io(dir.join("key_frames.csv")))?;
    let series = camera_series(
        ground,
        &poses
            .frames
            .iter()
            .map(|f| (f.frame, f.pose(), f.interpolated))
            .collect::<Vec<_>>(),
        fps,
    );
    write_pose_series(dir, &series).map_err(io(dir.to_path_buf()))?;
    Ok(())
}

/// A moving camera: key frames registered in a reference model, the frames between carried
/// from their key frame's 2D–3D points.
pub(super) struct Model<'a> {
    pub l: &'a Loaded,
    pub settings: &'a ModelSettings,
    pub model: SiteModel,
}

impl super::pose_source::PoseSource for Model<'_> {
    fn carried_picks(&self) -> (usize, Vec<Vector2<f64>>) {
        (0, Vec::new())
    }

    fn first_pose(&self, camera: &Camera, video: &Path) -> Result<Rigid3, RunError> {
        first_frame_pose(self.l, self.settings, &self.model, camera, video)
    }

    fn stage_key(&self, scan_key: &str) -> String {
        let p = &self.l.project;
        stage_key("pose", &[scan_key], &(&p.survey, &p.pose, &p.ground))
    }

    fn poses(&self, ctx: &Ctx, scan: &ScanData, pose_dir: &Path) -> Result<PoseData, RunError> {
        let bar = ctx.progress.stage("pose");
        let poses = model_poses(ctx, self.settings, &self.model, scan, bar.as_ref())?;
        ctx.guard.create_dir(pose_dir).map_err(output_error)?;
        write_model_pose_outputs(
            pose_dir,
            &poses,
            scan,
            &ctx.framed,
            Some(ctx.surface.as_ref()),
            &self.model,
        )?;
        Ok(PoseData::new(
            poses.frames,
            poses.key_frames,
            poses.key_frames_failed,
            None,
        ))
    }

    fn notes(&self) -> super::pose_source::PoseNotes {
        super::pose_source::PoseNotes {
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
}

#[cfg(test)]
mod tests {
    use super::*;

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
        assert!((f[2].pose().centre() - Vector3::new(0.0, 1.0, 30.0)).norm() < 1e-9);
        assert!((f[0].pose().centre() - Vector3::new(0.0, 0.0, 30.0)).norm() < 1e-9);
        assert!((f[5].pose().centre() - Vector3::new(0.0, 3.0, 30.0)).norm() < 1e-9);
        // Less certain than the measured ones, and no reprojection error claimed.
        let c = f[2].covariance.unwrap();
        assert!(c[(4, 4)] > 1e-6 && f[2].mean_reprojection_px.is_none());
        assert!(fill_unplaced(&[None, None]).is_none());
    }
}
