//! The `model` pose (a moving camera): the reference model moved into the run's site frame, key
//! frames registered in it, the frames between carried from their key frame's 2D–3D points.

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

use nalgebra::Vector3;

use super::telemetry_site::SiteTelemetry;
use super::{Env, FramePoseData, RunError, RunInputs, ScanData};
use crate::camera::Camera;
use crate::detect::Detection;
use crate::geom::Rigid3;
use crate::io::write_atomic;
use crate::pipeline::grounds::site_from_model;
use crate::pipeline::pose_outputs::{POSE_COLUMNS, csv_num, pose_columns};
use crate::pipeline::project::{Loaded, SurveySection};
use crate::pipeline::settings::ModelSettings;
use crate::pipeline::settings::{GroundSection, PoseSection};
use crate::progress::Progress;
use crate::sfm::FeatureSettings;
use crate::sfm::reference::{Reference, mask_features, model_max_features};
use crate::sfm::register::Registration;
use crate::sfm::register_job::{camera_series, write_pose_series};
use crate::sfm::sift::for_video_frames;
use crate::sfm::video_pose::{
    ModelFloor, PlacedKey, VideoPoseSettings, carry_to_frames, fill_unplaced,
};
use crate::survey::load::Framed;
use crate::terrain::HeightSurface;

/// A reference model in the run's site frame, and how well its georeferencing is known.
pub(super) struct SiteModel {
    pub reference: Reference,
    pub features: FeatureSettings,
    /// The model cameras' median σ: the floor of every frame's pose σ.
    pub floor: ModelFloor,
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
    (dir, images): (&Path, &Path),
    cache_dir: &Path,
    progress: &dyn Progress,
) -> Result<SiteModel, RunError> {
    // The model's own files checked first: its cameras' CSV is only as good as they are.
    let model = crate::sfm::register::read_model(dir)
        .map_err(|e| RunError::Input(l.error("pose", "model", e.to_string())))?;
    let (site_from, fit_rms_m, cams) = site_from_model(l, "pose", dir, framed)?;
    let features = FeatureSettings {
        max_features: m.max_features.unwrap_or_else(|| model_max_features(dir)),
        ..FeatureSettings::default()
    };
    let cache = crate::sfm::cache::SfmCache::new(Some(cache_dir));
    let mut reference = Reference::of_model(model, dir, images, &features, &cache, progress)
        .map_err(|e| RunError::Input(l.error("pose", "model_images", e.to_string())))?;
    reference.transform(&site_from);
    let pick =
        |f: &dyn Fn(&crate::sfm::reference::GeoCamera) -> f64| median(cams.iter().map(f).collect());
    let cameras = ModelFloor {
        sigma_centre_m: Vector3::new(
            pick(&|c| c.sigma_enu_m.x),
            pick(&|c| c.sigma_enu_m.y),
            pick(&|c| c.sigma_enu_m.z),
        ),
        sigma_rotation_rad: Vector3::repeat(pick(&|c| c.sigma_rotation_deg).to_radians()),
        lever_m: 0.0,
    };
    let camera_up = median(cams.iter().map(|c| site_from.apply(&c.centre).z).collect());
    let floor = if placed_by_control_points(dir) {
        ground_floor(l, framed, &cameras, camera_up)
    } else {
        cameras
    };
    Ok(SiteModel {
        reference,
        features,
        floor,
        fit_rms_m,
    })
}

/// Whether the model's `report.json` says its control points placed it (rather than its
/// camera centres).
fn placed_by_control_points(dir: &Path) -> bool {
    std::fs::read(dir.join("report.json"))
        .ok()
        .and_then(|b| serde_json::from_slice::<serde_json::Value>(&b).ok())
        .is_some_and(|r| r["georef"]["placed_by"] == "control points")
}

/// The floor of a model placed by its control points: the datum turns about them, so a
/// camera's centre σ east (north) is its tilt about north (east) times its height above them,
/// and what is left at the ground is the control points' own σ over their number. Yaw: their
/// horizontal σ over their spread. Falls back to `cameras` (centre and attitude independent)
/// without three control points below the cameras.
fn ground_floor(l: &Loaded, framed: &Framed, cameras: &ModelFloor, camera_up: f64) -> ModelFloor {
    let default = l.project.survey.gcp_sigma_m;
    let control: Vec<(Vector3<f64>, Vector3<f64>)> = framed
        .survey
        .points
        .iter()
        .zip(&framed.local)
        .filter(|(p, x)| p.role == crate::survey::Role::Control && x.z.is_finite())
        .map(|(p, x)| (*x, p.sigma_m.unwrap_or(Vector3::repeat(default))))
        .collect();
    let n = control.len() as f64;
    let lever = camera_up - median(control.iter().map(|(x, _)| x.z).collect());
    if control.len() < 3 || !(lever > 1.0) {
        return *cameras;
    }
    let rms = |k: usize| (control.iter().map(|(_, s)| s[k] * s[k]).sum::<f64>() / n).sqrt();
    let centroid = control
        .iter()
        .map(|(x, _)| x.xy())
        .sum::<nalgebra::Vector2<f64>>()
        / n;
    let spread = (control
        .iter()
        .map(|(x, _)| (x.xy() - centroid).norm_squared())
        .sum::<f64>()
        / n)
        .sqrt();
    let largest = cameras.sigma_rotation_rad.max();
    let tilt = |centre_sigma: f64| (centre_sigma / lever).min(largest);
    let yaw = (0.5 * (rms(0) + rms(1)) / (spread * n.sqrt()).max(1e-9)).min(largest);
    ModelFloor {
        sigma_centre_m: Vector3::new(
            rms(0) / n.sqrt(),
            rms(1) / n.sqrt(),
            cameras.sigma_centre_m.z,
        ),
        sigma_rotation_rad: Vector3::new(
            tilt(cameras.sigma_centre_m.y),
            tilt(cameras.sigma_centre_m.x),
            yaw,
        ),
        lever_m: lever,
    }
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

/// How the frames are placed, from the `[pose]` section.
fn video_pose_settings(m: &ModelSettings) -> VideoPoseSettings {
    VideoPoseSettings {
        neighbours: m.neighbours,
        min_inliers: m.min_inliers,
    }
}

/// The pose of frame 0, registered against every model photo: the detector's scale, and a
/// check that the video can be placed in the model before the long work.
pub(super) fn first_frame_pose(
    source: &Model,
    camera: &Camera,
    video: &Path,
) -> Result<Rigid3, RunError> {
    let (m, model) = (source.settings, &source.model);
    let video_error = |message: String| {
        RunError::Input(crate::io::FileError {
            message,
            ..source.video_at.clone()
        })
    };
    let mut first = None;
    for_video_frames(video, &[0], &model.features, |_, f| {
        first = Some(f);
        Ok::<(), RunError>(())
    })
    .map_err(|e| video_error(e.to_string()))?;
    let f = first.ok_or_else(|| video_error("the video has no frames".into()))?;
    let (r, _) = model
        .reference
        .place_frame(camera, "frame 0", &f, None, &video_pose_settings(m));
    r.pose.ok_or_else(|| {
        RunError::Unusable(format!(
            "{}: frame 0 could not be placed in the model {}: {} (is the model of this site, and the camera's calibration the video's?)",
            video.display(),
            source.model_path.display(),
            r.reason.unwrap_or_default()
        ))
    })
}

/// What the `model` pose gives the pose stage.
pub(super) struct ModelPoses {
    pub frames: Vec<FramePoseData>,
    pub key_frames: Vec<usize>,
    pub key_frames_failed: Vec<usize>,
    pub registrations: Vec<KeyRegistration>,
}

/// One key frame's registration in the model.
pub(super) struct KeyRegistration {
    pub frame: usize,
    pub registration: Registration,
    /// The model photos it was matched with.
    pub with: Vec<usize>,
    /// Which photos those were: `telemetry` (nearest its telemetry position), `last_placed`
    /// (nearest the last frame placed) or `all` (the nearest failed, or there was no position).
    pub near: &'static str,
    /// How far its placed centre is from that position (east-north, metres).
    pub from_telemetry_m: Option<f64>,
}

/// The telemetry as the key frames' prior: each key frame is expected at its SRT position
/// moved by the median offset between the poses placed so far (frame 0's first) and theirs.
struct KeyPrior<'a> {
    site: Option<SiteTelemetry<'a>>,
    /// Placed centre minus telemetry, east and north, metres, by frame.
    offsets: BTreeMap<usize, (f64, f64)>,
}

impl<'a> KeyPrior<'a> {
    fn new(x: &'a RunInputs) -> Result<KeyPrior<'a>, RunError> {
        let site = match &x.telemetry {
            // East and north choose the photos: no heights, no geoid.
            Some(t) => SiteTelemetry::new(t, &x.framed, x.fps, false)?.ok(),
            None => None,
        };
        let mut prior = KeyPrior {
            site,
            offsets: BTreeMap::new(),
        };
        prior.placed(0, &x.first_pose.centre())?;
        Ok(prior)
    }

    /// Frame `frame`'s telemetry in the site frame, where there is one.
    fn fix(&self, frame: usize) -> Result<Option<super::telemetry_site::Fix>, RunError> {
        Ok(self
            .site
            .as_ref()
            .map(|s| s.at(frame))
            .transpose()?
            .flatten())
    }

    /// Frame `frame` posed at `centre`: its offset from the telemetry joins the others.
    fn placed(&mut self, frame: usize, centre: &Vector3<f64>) -> Result<(), RunError> {
        if let Some(fix) = self.fix(frame)? {
            self.offsets
                .insert(frame, (centre.x - fix.site.x, centre.y - fix.site.y));
        }
        Ok(())
    }

    /// Where frame `frame` is expected (east and north; up NaN); `None` without telemetry for
    /// it, or before any frame placed has telemetry (its bias unknown).
    fn expected(&self, frame: usize) -> Result<Option<Vector3<f64>>, RunError> {
        if self.offsets.is_empty() {
            return Ok(None);
        }
        let Some(fix) = self.fix(frame)? else {
            return Ok(None);
        };
        let de = median(self.offsets.values().map(|o| o.0).collect());
        let dn = median(self.offsets.values().map(|o| o.1).collect());
        Ok(Some(Vector3::new(
            fix.site.x + de,
            fix.site.y + dn,
            fix.site.z,
        )))
    }
}

/// Every frame's pose: key frames registered in the model, the frames between carried.
pub(super) fn model_poses(
    env: &Env,
    x: &RunInputs,
    (m, model): (&ModelSettings, &SiteModel),
    scan: &ScanData,
    progress: &dyn Progress,
) -> Result<ModelPoses, RunError> {
    let camera = &x.camera;
    let n = scan.frames;
    let keys: Vec<usize> = scan
        .tracks
        .iter()
        .filter(|t| t.key.is_some())
        .map(|t| t.index)
        .collect();
    progress.set_length((keys.len() + n) as u64);
    let mask_px = m.mask_m * scan.px_per_m;
    let settings = video_pose_settings(m);

    // 1. Key frames: features (people masked), registered in order against the model photos
    // nearest the telemetry's position (its offset from the poses placed so far removed), else
    // nearest the last one placed.
    let mut placed_keys: BTreeMap<usize, PlacedKey> = BTreeMap::new();
    let mut registrations = Vec::new();
    let mut near = Some(x.first_pose.centre());
    let mut prior = KeyPrior::new(x)?;
    let video_name = x
        .video
        .file_name()
        .map_or("video".into(), |f| f.to_string_lossy().into_owned());
    // The key frames' detections, read back a chunk at a time (a long video's are not held).
    let mut chunk: Option<crate::pipeline::chunk_pass::ChunkData> = None;
    for_video_frames(&x.video, &keys, &model.features, |index, mut f| {
        let c = index / x.grid.chunk_frames;
        if chunk.as_ref().is_none_or(|d| d.index != c) {
            chunk = Some(
                super::scan_stage::load_chunk(&env.cache, &x.scan_key, c).ok_or_else(|| {
                    RunError::Failed(format!(
                        "{}: chunk {c}'s file is gone or damaged: run again",
                        env.out.display()
                    ))
                })?,
            );
        }
        let dets = chunk
            .as_ref()
            .and_then(|d| d.detections.get(index.checked_sub(d.start)?))
            .map_or(&[][..], Vec::as_slice);
        mask_people(&mut f, dets, mask_px);
        let name = format!("{video_name}#{index}");
        let expected = prior.expected(index)?;
        let around = expected.as_ref().or(near.as_ref());
        let nearest = model
            .reference
            .nearest_images(around, settings.neighbours)
            .len();
        let (r, with, key) =
            model
                .reference
                .place_key_frame(camera, &name, &f, around, (&model.floor, &settings));
        // Which photos it was matched with: all of them after a failure among the nearest.
        let matched_near = match (with.len() > nearest, expected.is_some(), near.is_some()) {
            (true, _, _) | (false, false, false) => "all",
            (false, true, _) => "telemetry",
            (false, false, true) => "last_placed",
        };
        let mut from_telemetry_m = None;
        if let Some(key) = key {
            let centre = key.placed.pose.centre();
            from_telemetry_m = expected.map(|e| (centre - e).xy().norm());
            prior.placed(index, &centre)?;
            near = Some(centre);
            placed_keys.insert(index, key);
        }
        registrations.push(KeyRegistration {
            frame: index,
            registration: r,
            with,
            near: matched_near,
            from_telemetry_m,
        });
        progress.inc(1);
        Ok::<(), RunError>(())
    })?;

    // 2. Every frame: a key frame's own pose, or its key frame's points carried into it.
    let tracks = &scan.tracks[..n.min(scan.tracks.len())];
    let placed = carry_to_frames(
        camera,
        &placed_keys,
        tracks,
        &model.floor,
        &settings,
        progress,
    );

    // 3. Frames not placed: interpolated between the nearest placed ones (held at the ends),
    // flagged, with the wider σ of their neighbours.
    let Some(filled) = fill_unplaced(&placed) else {
        return Err(RunError::Unusable(format!(
            "{}: no key frame could be placed in the model ({})",
            x.video.display(),
            registrations
                .iter()
                .filter_map(|k| k.registration.reason.clone())
                .next()
                .unwrap_or_default()
        )));
    };
    let frames = filled
        .iter()
        .enumerate()
        .map(|(i, p)| FramePoseData {
            frame: i,
            rotation: *p.pose.rotation.matrix(),
            translation: p.pose.translation,
            covariance: Some(p.covariance),
            interpolated: p.interpolated,
            mean_reprojection_px: p.rms_px,
        })
        .collect();
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
    let mut keys = String::from(
        "frame,placed,correspondences,inliers,rms_px,model_images,near,from_telemetry_m,reason\n",
    );
    for k in &poses.registrations {
        let (f, r) = (&k.frame, &k.registration);
        let names: Vec<&str> = k
            .with
            .iter()
            .map(|&i| model.reference.model.images[i].name.as_str())
            .collect();
        let _ = writeln!(
            keys,
            "{f},{},{},{},{},{},{},{},{}",
            if poses.key_frames_failed.contains(f) {
                "no"
            } else {
                "yes"
            },
            r.correspondences,
            r.inliers,
            r.rms_px.map_or(String::new(), |v| format!("{v:.4}")),
            names.join(" "),
            k.near,
            k.from_telemetry_m
                .map_or(String::new(), |v| format!("{v:.3}")),
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
    /// The sections the pose stage's key covers.
    pub key_sections: (&'a SurveySection, &'a PoseSection, &'a GroundSection),
    /// The model's folder, for messages.
    pub model_path: PathBuf,
    /// The project's `video.path` key, for a video the model cannot place.
    pub video_at: crate::io::FileError,
    pub settings: &'a ModelSettings,
    pub model: SiteModel,
}
