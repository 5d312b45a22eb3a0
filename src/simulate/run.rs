//! Running a scene: frames, video, truth files, GCP exports and checkerboard images. This ties the
//! pure simulation to its adapters (OpenCV video and images, PROJ for the site CRS).

use std::fmt::Write as _;
use std::path::{Path, PathBuf};

use nalgebra::{Vector2, Vector3};
use rand::SeedableRng;
use rand_distr::{Distribution, Normal};

use super::board::{BoardRenderer, random_board_poses};
use super::flight::{camera_pose, survey_poses};
use super::people::{Body, Person, Pose, spawn};
use super::render::{CameraPose, FrameInput, RenderSettings, Renderer, Shadow};
use super::scene::{Gait, Motion, Scene, Site};
use super::world::World;
use crate::camera::{BoardSpec, Camera};
use crate::geom::geodesy::{Geodetic, LocalTangentFrame};
use crate::progress::Progress;
use crate::survey::crs::{Crs, HeightKind, Horizontal};
use crate::survey::model::{Gcp, SolutionStatus};
use crate::survey::write::{OutCrs, OutPoint, emlid};

/// The scene with what the overrides change in it (the people without hats).
fn as_asked<'a>(scene: &'a Scene, over: &Overrides) -> std::borrow::Cow<'a, Scene> {
    if over.no_hats && scene.people.hats {
        let mut bare = scene.clone();
        bare.people.hats = false;
        std::borrow::Cow::Owned(bare)
    } else {
        std::borrow::Cow::Borrowed(scene)
    }
}

/// Overrides from the command line.
#[derive(Clone, Debug, Default)]
pub struct Overrides {
    pub seed: Option<u64>,
    pub duration_s: Option<f64>,
    pub no_video: bool,
    pub frames_every: Option<u32>,
    /// The site in this CRS instead of the scene's, at the same place (`--crs`).
    pub site_crs: Option<String>,
    /// The people without hats whatever the scene says (`--no-hats`: for a detector that
    /// needs none).
    pub no_hats: bool,
}

/// The same site in another CRS: its origin converted with PROJ, the ellipsoidal height with it
/// (a datum change moves it).
pub fn site_in_crs(site: &Site, crs: &str) -> Result<Site, SimError> {
    let input =
        |what: &str, e: crate::survey::crs::CrsError| SimError::Input(format!("{what}: {e}"));
    let from = Crs::new(&site.crs).map_err(|e| input("site.crs", e))?;
    let to = Crs::new(crs).map_err(|e| input("--crs", e))?;
    let t = crate::survey::crs::Transform::new(&from, &to).map_err(|e| input("--crs", e))?;
    let [x, y, h] = site.origin;
    let (x, y, h) = t.apply_3d(x, y, h).map_err(|e| input("site.origin", e))?;
    Ok(Site {
        crs: crs.to_string(),
        origin: [x, y, h],
    })
}

/// What a run produced.
#[derive(Clone, Debug, serde::Serialize)]
pub struct Summary {
    pub frames: usize,
    pub people: usize,
    /// People whose head was in view in at least one frame.
    pub people_in_view: usize,
    pub image_size: [u32; 2],
    pub video: Option<PathBuf>,
    pub codec: Option<String>,
    pub files: Vec<PathBuf>,
}

#[derive(Debug, thiserror::Error)]
pub enum SimError {
    #[error("{0}")]
    Input(String),
    #[error("{0}")]
    Output(String),
}

/// The site's CRS and its tangent frame at the origin.
fn site_frame(site: &Site) -> Result<(Crs, LocalTangentFrame), SimError> {
    let crs = Crs::new(&site.crs).map_err(|e| SimError::Input(format!("site.crs: {e}")))?;
    let o = site.origin;
    let (lon, lat) = crs
        .to_lon_lat(o[0], o[1])
        .ok()
        .filter(|(lon, lat)| lon.is_finite() && lat.abs() <= 90.0)
        .ok_or_else(|| {
            SimError::Input(format!(
                "site.origin: ({}, {}) is not a position in {}",
                o[0],
                o[1],
                crs.label()
            ))
        })?;
    let tangent = LocalTangentFrame::new(crs.ellipsoid, Geodetic::from_degrees(lat, lon, o[2]));
    Ok((crs, tangent))
}

/// The sun's direction (towards the sun) from azimuth and elevation in degrees.
pub(crate) fn sun_vector(azimuth_deg: f64, elevation_deg: f64) -> Vector3<f64> {
    let (a, e) = (azimuth_deg.to_radians(), elevation_deg.to_radians());
    Vector3::new(a.sin() * e.cos(), a.cos() * e.cos(), e.sin())
}

fn write_file(path: &Path, text: &str) -> Result<(), SimError> {
    crate::io::write_atomic(path, text.as_bytes())
        .map_err(|e| SimError::Output(format!("{}: {e}", path.display())))
}

/// The poses of everyone present at a time.
fn poses_at<'a>(people: &'a [Person], world: &World, t: f64) -> Vec<(&'a Person, Pose)> {
    people
        .iter()
        .filter_map(|p| p.pose(world, t).map(|pose| (p, pose)))
        .collect()
}

/// Area the camera sees over the scene (ground plane and deck top), with a margin.
fn view_box(camera: &Camera, world: &World, poses: &[CameraPose]) -> (Vector2<f64>, Vector2<f64>) {
    let size = camera.image_size.expect("size");
    let (w, h) = (f64::from(size.width), f64::from(size.height));
    let mut border = Vec::new();
    for k in 0..=16 {
        let f = f64::from(k) / 16.0;
        border.extend([
            Vector2::new(f * (w - 1.0), 0.0),
            Vector2::new(f * (w - 1.0), h - 1.0),
            Vector2::new(0.0, f * (h - 1.0)),
            Vector2::new(w - 1.0, f * (h - 1.0)),
        ]);
    }
    let (mut lo, mut hi) = (
        Vector2::repeat(f64::INFINITY),
        Vector2::repeat(f64::NEG_INFINITY),
    );
    let step = (poses.len() / 20).max(1);
    for pose in poses.iter().step_by(step).chain(poses.last()) {
        for uv in &border {
            let Ok(ray) = camera.unproject(uv) else {
                continue;
            };
            let dir = pose.world_from_cam * ray.into_inner();
            // An oblique view reaches to the horizon: beyond ten heights from the camera a
            // pixel covers metres of ground, and the albedo is computed there, not baked.
            let reach = 10.0 * pose.centre.z.max(1.0);
            let near = |p: Vector2<f64>| {
                let d = p - pose.centre.xy();
                pose.centre.xy() + d * (reach / d.norm().max(reach))
            };
            if let Some((p, _)) = world.intersect(&pose.centre, &dir) {
                lo = lo.inf(&near(p.xy()));
                hi = hi.sup(&near(p.xy()));
            }
            // The ground under a deck too.
            if dir.z < 0.0 {
                let p = near((pose.centre + dir * (-pose.centre.z / dir.z)).xy());
                lo = lo.inf(&p);
                hi = hi.sup(&p);
            }
        }
    }
    (lo - Vector2::repeat(3.0), hi + Vector2::repeat(3.0))
}

/// What a scene needs beyond its file's own checks, known before anything is rendered or
/// written: a camera size it can render, and a site PROJ knows.
pub fn check(scene: &Scene, camera: &Camera) -> Result<(), SimError> {
    let size = camera
        .image_size
        .ok_or_else(|| SimError::Input("the camera has no image size".into()))?;
    let max = super::scene::MAX_SIDE_PX;
    if size.width > max || size.height > max {
        return Err(SimError::Input(format!(
            "camera: {}x{} pixels; a scene renders at most {max}x{max} (set camera.video_mode)",
            size.width, size.height
        )));
    }
    if let Some(f) = &scene.survey_flight
        && camera.scaled_to(f.image_size[0], f.image_size[1]).is_none()
    {
        return Err(SimError::Input(format!(
            "survey_flight.image_size {}x{}: not the aspect ratio of the {}x{} camera",
            f.image_size[0], f.image_size[1], size.width, size.height
        )));
    }
    site_frame(&scene.site).map(|_| ())
}

/// Runs a scene into `out`.
pub fn simulate(
    scene: &Scene,
    camera: &Camera,
    out: &Path,
    over: &Overrides,
    progress: &dyn Progress,
) -> Result<Summary, SimError> {
    let scene = &as_asked(scene, over);
    let seed = over.seed.unwrap_or(scene.seed);
    let frames_every = over.frames_every.unwrap_or(scene.output.frames_every);
    let duration = over.duration_s.unwrap_or(scene.duration_s);
    let frames = ((duration * scene.fps).round() as usize).max(1);
    check(scene, camera)?;
    let size = camera.image_size.expect("checked");
    let mut world = World::new(&scene.ground, &scene.gcp, seed);
    world.detail = scene.ground_detail;
    let people = spawn(&scene.people, &world, duration, seed);
    let sun = sun_vector(scene.people.sun_azimuth_deg, scene.people.sun_elevation_deg);
    let hat = scene
        .people
        .hats
        .then(|| scene.people.hat_colour.map(|c| f32::from(c) / 255.0));
    for sub in ["truth", "checkerboards"] {
        std::fs::create_dir_all(out.join(sub))
            .map_err(|e| SimError::Output(format!("{}: {e}", out.join(sub).display())))?;
    }
    if frames_every > 0 {
        std::fs::create_dir_all(out.join("frames")).map_err(|e| SimError::Output(e.to_string()))?;
    }

    // Camera poses first: they set the area to texture.
    let times: Vec<f64> = (0..frames).map(|i| i as f64 / scene.fps).collect();
    let poses = camera_poses(scene, &people, &world, seed, &times);
    let renderer = scene_renderer(scene, camera, &world, &poses, sun, seed);

    let mut sink = if scene.output.video && !over.no_video {
        Some(
            crate::video::VideoSink::create(
                &out.join("video"),
                size.width,
                size.height,
                scene.fps,
                true,
            )
            .map_err(|e| SimError::Output(e.to_string()))?,
        )
    } else {
        None
    };
    let video_name = sink
        .as_ref()
        .and_then(|s| s.path.file_name().map(|n| n.to_string_lossy().into_owned()));

    let mut truth = TruthTables::new(people.len());
    progress.set_length(frames as u64);
    for (i, (&t, pose)) in times.iter().zip(&poses).enumerate() {
        let present = poses_at(&people, &world, t);
        let bodies: Vec<Body> = present
            .iter()
            .map(|(p, ps)| Body::new(p, ps, hat))
            .collect();
        let shadows: Vec<Shadow> = if scene.people.shadows {
            present
                .iter()
                .map(|(p, ps)| Shadow::of(&ps.foot, p.height_m, &sun))
                .collect()
        } else {
            Vec::new()
        };
        let light = 1.0
            + scene.people.light_change
                * (0.6 * (std::f64::consts::TAU * t / 17.0).sin()
                    + 0.4 * (std::f64::consts::TAU * t / 7.3 + 1.0).sin());
        let mut rgb = renderer.render(&FrameInput {
            index: i,
            pose,
            bodies: &bodies,
            shadows: &shadows,
            light,
        });
        if scene.output.lost_frames.contains(&(i as u32)) {
            rgb.fill(200);
        }
        if let Some(s) = sink.as_mut() {
            s.write_rgb(&rgb)
                .map_err(|e| SimError::Output(e.to_string()))?;
        }
        if frames_every > 0 && i % frames_every as usize == 0 {
            let p = out.join("frames").join(format!("frame-{i:05}.png"));
            crate::imageio::write_rgb(&p, size.width, size.height, &rgb)
                .map_err(|e| SimError::Output(e.to_string()))?;
        }
        let frame = TruthFrame {
            index: i,
            time_s: t,
            camera,
            pose,
        };
        truth.add_camera(&frame);
        truth.add_boxes(&frame, &present, &bodies, &shadows);
        truth.add_heads(&frame, &present);
        progress.inc(1);
    }
    let (video, codec) = match sink {
        Some(s) => {
            let codec = s.codec.to_string();
            (
                Some(s.finish().map_err(|e| SimError::Output(e.to_string()))?),
                Some(codec),
            )
        }
        None => (None, None),
    };
    let people_in_view = truth.seen.iter().filter(|s| **s).count();
    let mut files = truth.write(&out.join("truth"), &people, hat.is_some())?;
    let video_name = video_name.as_deref();
    files.extend(write_gcps(
        scene, &world, camera, &poses[0], out, seed, video_name,
    )?);
    files.extend(write_frame_picks(
        scene, &world, camera, &poses, out, seed, video_name,
    )?);
    if let Some(v) = &video {
        files.push(write_telemetry(scene, &poses, v, seed)?);
    }
    files.extend(write_checkerboards(scene, camera, out, seed)?);
    files.extend(write_survey_flight(scene, &world, camera, out, seed, &sun)?);
    files.push(write_scene_meta(
        scene, camera, out, seed, frames, duration,
    )?);
    files.extend(write_fixed_camera(scene, camera, &poses[0], out)?);
    if let Some(v) = &video {
        files.push(v.clone());
    }
    Ok(Summary {
        frames,
        people: people.len(),
        people_in_view,
        image_size: [size.width, size.height],
        video,
        codec,
        files,
    })
}

/// The camera's pose at each of `times`; a following camera looks at the people's mean foot.
fn camera_poses(
    scene: &Scene,
    people: &[Person],
    world: &World,
    seed: u64,
    times: &[f64],
) -> Vec<CameraPose> {
    times
        .iter()
        .enumerate()
        .map(|(i, &t)| {
            let centre = match scene.camera.motion {
                Motion::Follow { .. } => {
                    let ps = poses_at(people, world, t);
                    (!ps.is_empty()).then(|| {
                        ps.iter().fold(Vector3::zeros(), |a, (_, p)| a + p.foot) / ps.len() as f64
                    })
                }
                _ => None,
            };
            camera_pose(&scene.camera.motion, seed, i, t, centre)
        })
        .collect()
}

/// The renderer for the area every pose sees, its texels a little finer than the finest ground
/// sample distance.
fn scene_renderer<'w>(
    scene: &Scene,
    camera: &Camera,
    world: &'w World,
    poses: &[CameraPose],
    sun: Vector3<f64>,
    seed: u64,
) -> Renderer<'w> {
    let (lo, hi) = view_box(camera, world, poses);
    let gsd = poses
        .iter()
        .map(|p| p.centre.z)
        .fold(f64::INFINITY, f64::min)
        .max(1.0)
        / camera.fx.max(camera.fy);
    // At most about 40 million texels a layer (120 MB): coarser over a wide oblique view.
    let area = (hi.x - lo.x).max(0.0) * (hi.y - lo.y).max(0.0);
    let texel = (0.7 * gsd).clamp(0.004, 0.05).max((area / 4e7).sqrt());
    let settings = RenderSettings {
        texel_m: texel,
        sun,
        image_noise: scene.output.image_noise,
        seed,
    };
    Renderer::new(world, camera.clone(), (lo, hi), &settings)
}

/// One rendered frame, as the truth tables see it.
struct TruthFrame<'a> {
    index: usize,
    time_s: f64,
    camera: &'a Camera,
    pose: &'a CameraPose,
}

impl TruthFrame<'_> {
    /// The image box of `corners` clipped to the frame; none when a corner is behind the camera
    /// or less than 2 px of it is left.
    fn image_box(&self, corners: &mut dyn Iterator<Item = Vector3<f64>>) -> Option<[f64; 4]> {
        let size = self.camera.image_size.expect("checked");
        let (w, h) = (f64::from(size.width), f64::from(size.height));
        let mut b = [
            f64::INFINITY,
            f64::INFINITY,
            f64::NEG_INFINITY,
            f64::NEG_INFINITY,
        ];
        for c in corners {
            let uv = self.pose.project(self.camera, &c)?;
            b = [
                b[0].min(uv.x),
                b[1].min(uv.y),
                b[2].max(uv.x),
                b[3].max(uv.y),
            ];
        }
        let (x0, y0) = (b[0].max(-0.5), b[1].max(-0.5));
        let (x1, y1) = (b[2].min(w - 0.5), b[3].min(h - 0.5));
        (x1 - x0 >= 2.0 && y1 - y0 >= 2.0).then_some([x0, y0, x1 - x0, y1 - y0])
    }
}

/// The truth files' rows as the frames are rendered, and which people were ever in view.
struct TruthTables {
    cam_csv: String,
    heads_csv: String,
    /// What a perfect person detector would box, and each person's shadow (a detector's
    /// typical false alarm): image boxes clipped to the frame.
    boxes_csv: String,
    seen: Vec<bool>,
}

impl TruthTables {
    fn new(people: usize) -> Self {
        TruthTables {
            cam_csv: String::from(
                "frame,time_s,centre_e_m,centre_n_m,centre_u_m,rvec_x,rvec_y,rvec_z,tvec_x,tvec_y,tvec_z\n",
            ),
            heads_csv: String::from("frame,time_s,person,e_m,n_m,u_m,px,py,in_view\n"),
            boxes_csv: String::from("frame,person,kind,x,y,w,h\n"),
            seen: vec![false; people],
        }
    }

    /// The camera: cam_from_world as OpenCV's rvec, tvec.
    fn add_camera(&mut self, f: &TruthFrame) {
        let (i, t, pose) = (f.index, f.time_s, f.pose);
        let r_cw = pose.world_from_cam.transpose();
        let rvec = crate::geom::so3::log(&nalgebra::Rotation3::from_matrix_unchecked(r_cw));
        let tvec = -(r_cw * pose.centre);
        let _ = writeln!(
            self.cam_csv,
            "{i},{t:.6},{:.6},{:.6},{:.6},{:.9},{:.9},{:.9},{:.6},{:.6},{:.6}",
            pose.centre.x,
            pose.centre.y,
            pose.centre.z,
            rvec.x,
            rvec.y,
            rvec.z,
            tvec.x,
            tvec.y,
            tvec.z
        );
    }

    /// Each present person's body box and shadow box.
    fn add_boxes(
        &mut self,
        f: &TruthFrame,
        present: &[(&Person, Pose)],
        bodies: &[Body],
        shadows: &[Shadow],
    ) {
        for (k, ((p, _), body)) in present.iter().zip(bodies).enumerate() {
            let body_box = f.image_box(&mut body.outline(&f.pose.centre, 48).into_iter());
            let shadow_box = shadows.get(k).and_then(|sh| {
                let z = present[k].1.foot.z;
                let (a, b) = (
                    sh.axis * sh.semi_major,
                    Vector2::new(-sh.axis.y, sh.axis.x) * sh.semi_minor,
                );
                f.image_box(
                    &mut [(1.0, 1.0), (1.0, -1.0), (-1.0, 1.0), (-1.0, -1.0)]
                        .into_iter()
                        .map(|(i, j)| {
                            let q = sh.centre + a * i + b * j;
                            Vector3::new(q.x, q.y, z)
                        }),
                )
            });
            for (kind, bx) in [("body", body_box), ("shadow", shadow_box)] {
                if let Some(bx) = bx {
                    let _ = writeln!(
                        self.boxes_csv,
                        "{},{},{kind},{:.2},{:.2},{:.2},{:.2}",
                        f.index, p.id, bx[0], bx[1], bx[2], bx[3]
                    );
                }
            }
        }
    }

    /// Each present person's head top, in view or just outside it.
    fn add_heads(&mut self, f: &TruthFrame, present: &[(&Person, Pose)]) {
        let (i, t, pose, camera) = (f.index, f.time_s, f.pose, f.camera);
        let size = camera.image_size.expect("checked");
        let (w, h) = (f64::from(size.width), f64::from(size.height));
        for (p, ps) in present {
            let Some(uv) = pose.project(camera, &ps.head_top) else {
                continue;
            };
            let inside = |m: f64| {
                uv.x >= -0.5 - m && uv.y >= -0.5 - m && uv.x <= w - 0.5 + m && uv.y <= h - 0.5 + m
            };
            // A head just outside the image still shows part of its hat: listed, not in view.
            let depth = (pose.world_from_cam.transpose() * (ps.head_top - pose.centre)).z;
            let hat_px = crate::simulate::people::HAT_RADIUS_M * camera.fx / depth.max(1e-6);
            let in_view = inside(0.0);
            if !in_view && !inside(hat_px) {
                continue;
            }
            self.seen[p.id] |= in_view;
            let _ = writeln!(
                self.heads_csv,
                "{i},{t:.6},{},{:.6},{:.6},{:.6},{:.4},{:.4},{}",
                p.id,
                ps.head_top.x,
                ps.head_top.y,
                ps.head_top.z,
                uv.x,
                uv.y,
                u8::from(in_view)
            );
        }
    }

    /// The truth tables and the people's table into `truth`; the paths written.
    fn write(self, truth: &Path, people: &[Person], hats: bool) -> Result<Vec<PathBuf>, SimError> {
        write_file(&truth.join("camera.csv"), &self.cam_csv)?;
        write_file(&truth.join("heads.csv"), &self.heads_csv)?;
        write_file(&truth.join("boxes.csv"), &self.boxes_csv)?;
        let mut people_csv = String::from("person,height_m,speed_m_s,gait,start_s,hat\n");
        for p in people {
            let gait = match p.gait {
                Gait::Walk => "walk",
                Gait::Run => "run",
            };
            let _ = writeln!(
                people_csv,
                "{},{:.4},{:.4},{gait},{:.4},{}",
                p.id,
                p.height_m,
                p.speed_m_s,
                p.start_s,
                u8::from(hats)
            );
        }
        write_file(&truth.join("people.csv"), &people_csv)?;
        Ok(vec![
            truth.join("camera.csv"),
            truth.join("heads.csv"),
            truth.join("boxes.csv"),
            truth.join("people.csv"),
        ])
    }
}

/// `camera.json` for a camera that does not move (a hover with no drift and no jitter: a pole
/// or mast camera): the scene's camera with its pose in the site frame, for `[pose] kind =
/// "fixed"`.
fn write_fixed_camera(
    scene: &Scene,
    camera: &Camera,
    pose: &CameraPose,
    out: &Path,
) -> Result<Option<PathBuf>, SimError> {
    if !matches!(scene.camera.motion, Motion::Hover { drift_m, jitter_deg, .. }
        if drift_m == 0.0 && jitter_deg == 0.0)
    {
        return Ok(None);
    }
    let r_cw = pose.world_from_cam.transpose();
    let cam_from_world = crate::geom::Rigid3::new(
        nalgebra::Rotation3::from_matrix_unchecked(r_cw),
        -(r_cw * pose.centre),
    );
    let cal = crate::camera::Calibration {
        camera: camera.clone(),
        covariance: None,
        summary: None,
        notes: vec![String::from(
            "written by geostride simulate: the scene's camera and its exact pose",
        )],
        extrinsics: Some(crate::camera::Extrinsics {
            cam_from_world,
            world: String::from(
                "the scene's site frame: east, north, up in metres from its origin",
            ),
        }),
    };
    let path = out.join("camera.json");
    crate::camera::formats::write(&cal, &path, Some(crate::camera::formats::Format::Json))
        .map_err(|e| SimError::Output(e.to_string()))?;
    Ok(Some(path))
}

/// `truth/scene.json`: what the scene was run with.
fn write_scene_meta(
    scene: &Scene,
    camera: &Camera,
    out: &Path,
    seed: u64,
    frames: usize,
    duration: f64,
) -> Result<PathBuf, SimError> {
    let size = camera.image_size.expect("checked");
    let meta = serde_json::json!({
        "name": scene.name,
        "seed": seed,
        "fps": scene.fps,
        "frames": frames,
        "duration_s": duration,
        "image_size": [size.width, size.height],
        "camera": {"fx": camera.fx, "fy": camera.fy, "cx": camera.cx, "cy": camera.cy, "dist": camera.dist},
        "site": {"crs": scene.site.crs, "origin": scene.site.origin},
        "sun": {"azimuth_deg": scene.people.sun_azimuth_deg, "elevation_deg": scene.people.sun_elevation_deg},
        "frames_in_site_frame": "east, north, up in metres from the site origin",
    });
    let meta_path = out.join("truth").join("scene.json");
    write_file(
        &meta_path,
        &(serde_json::to_string_pretty(&meta).expect("json") + "\n"),
    )?;
    Ok(meta_path)
}

/// RTK-like noise of a surveyed position: σ horizontal and vertical in metres, the horizontal
/// noise converted to the CRS's unit.
struct RtkNoise {
    horizontal: Normal<f64>,
    vertical: Normal<f64>,
    sigma_m: [f64; 2],
    unit: f64,
}

impl RtkNoise {
    fn new(crs: &Crs, sigma_m: [f64; 2]) -> Self {
        RtkNoise {
            horizontal: Normal::new(0.0, sigma_m[0].max(1e-12)).expect("sigma"),
            vertical: Normal::new(0.0, sigma_m[1].max(1e-12)).expect("sigma"),
            sigma_m,
            unit: if crs.horizontal == Horizontal::Projected {
                crs.unit_m
            } else {
                1.0
            },
        }
    }

    /// The point at CRS `x`, `y` and height `h` as measured: noisy, with its σ and FIX status.
    fn measured(
        &self,
        name: &str,
        x: f64,
        y: f64,
        h: f64,
        line: usize,
        rng: &mut impl rand::Rng,
    ) -> Gcp {
        let [sh, sv] = self.sigma_m;
        let mut g = Gcp::new(
            name,
            Vector3::new(
                x + self.horizontal.sample(rng) / self.unit,
                y + self.horizontal.sample(rng) / self.unit,
                h + self.vertical.sample(rng),
            ),
            line,
        );
        g.sigma_m = Some(Vector3::new(sh, sh, sv));
        g.status = Some(SolutionStatus::Fix);
        g
    }
}

/// Points in the site CRS (ellipsoidal heights) as an Emlid CSV.
fn emlid_in_site_crs(scene: &Scene, crs: &Crs, points: &[Gcp]) -> Result<String, SimError> {
    let out_crs = OutCrs {
        spec: Some(crs.id.clone().unwrap_or_else(|| scene.site.crs.clone())),
        name: crs.name.clone(),
        projected: crs.horizontal == Horizontal::Projected,
        height: HeightKind::Ellipsoidal,
    };
    let points: Vec<OutPoint> = points
        .iter()
        .map(|g| OutPoint {
            gcp: g,
            position: g.position,
            lon_lat: crs.to_lon_lat(g.position.x, g.position.y).ok(),
            local: Vector3::zeros(),
            residual: None,
        })
        .collect();
    emlid(&out_crs, &points).map_err(|e| SimError::Output(e.0))
}

/// GCPs: an Emlid CSV in the site CRS with RTK-like noise, the exact positions, and picks on the
/// first frame with pixel noise.
fn write_gcps(
    scene: &Scene,
    world: &World,
    camera: &Camera,
    first: &CameraPose,
    out: &Path,
    seed: u64,
    video: Option<&str>,
) -> Result<Vec<PathBuf>, SimError> {
    if world.gcps.is_empty() {
        return Ok(Vec::new());
    }
    let (crs, tangent) = site_frame(&scene.site)?;
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(seed ^ 0x6C9_5EED);
    let rtk = RtkNoise::new(&crs, scene.output.gcp_noise_m);
    let pick_noise = Normal::new(0.0, scene.output.pick_noise_px.max(1e-12)).expect("sigma");
    let mut gcps = Vec::new();
    let mut truth = String::from("name,e_m,n_m,u_m,x,y,ellipsoidal_height_m\n");
    let mut picks = String::from("name,image,u,v,sigma\n");
    let image = video.map_or_else(|| "frame-00000".to_string(), |v| format!("{v}#0"));
    let (w, h) = (
        camera.image_size.expect("size").width as f64,
        camera.image_size.expect("size").height as f64,
    );
    for (line, (name, p)) in world.gcps.iter().enumerate() {
        let g = tangent.geodetic_from_enu(p);
        let (x, y) = crs
            .from_lon_lat(g.lon.to_degrees(), g.lat.to_degrees())
            .map_err(|e| SimError::Input(e.to_string()))?;
        let _ = writeln!(
            truth,
            "{name},{:.6},{:.6},{:.6},{x:.6},{y:.6},{:.6}",
            p.x, p.y, p.z, g.h
        );
        gcps.push(rtk.measured(name, x, y, g.h, line + 2, &mut rng));
        if let Some(uv) = first.project(camera, p)
            && uv.x >= 0.0
            && uv.y >= 0.0
            && uv.x <= w - 1.0
            && uv.y <= h - 1.0
        {
            let (u, v) = (
                uv.x + pick_noise.sample(&mut rng),
                uv.y + pick_noise.sample(&mut rng),
            );
            let _ = writeln!(
                picks,
                "{name},{image},{u:.3},{v:.3},{}",
                scene.output.pick_noise_px
            );
        }
    }
    let csv = emlid_in_site_crs(scene, &crs, &gcps)?;
    let paths = [
        out.join("gcps.csv"),
        out.join("truth").join("gcps.csv"),
        out.join("picks.csv"),
    ];
    write_file(&paths[0], &csv)?;
    write_file(&paths[1], &truth)?;
    write_file(&paths[2], &picks)?;
    Ok(paths.to_vec())
}

/// A moving camera's GCP picks on every second's frame (0, fps, 2 fps, ...), each target in
/// view 10 px inside the edge, with pixel noise: what a user picks in the video itself when
/// there was no survey flight (`picks-frames.csv`). None for a camera that does not move.
fn write_frame_picks(
    scene: &Scene,
    world: &World,
    camera: &Camera,
    poses: &[CameraPose],
    out: &Path,
    seed: u64,
    video: Option<&str>,
) -> Result<Vec<PathBuf>, SimError> {
    if world.gcps.is_empty() || matches!(scene.camera.motion, Motion::Hover { .. }) {
        return Ok(Vec::new());
    }
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(seed ^ 0xF4A3_E5C1);
    let pick_noise = Normal::new(0.0, scene.output.pick_noise_px.max(1e-12)).expect("sigma");
    let every = (scene.fps.round() as usize).max(1);
    let mut picks = String::from("name,image,u,v,sigma\n");
    for (i, pose) in poses.iter().enumerate().step_by(every) {
        let image = video.map_or_else(|| format!("frame-{i:05}"), |v| format!("{v}#{i}"));
        let noise = (&pick_noise, scene.output.pick_noise_px);
        write_visible_picks(&mut picks, &image, (world, pose, camera), noise, &mut rng);
    }
    let path = out.join("picks-frames.csv");
    write_file(&path, &picks)?;
    Ok(vec![path])
}

/// The picks rows of image `image`: every GCP its camera sees 10 px inside the edge and not
/// hidden (behind the deck), with `noise` (its distribution and stated σ, px) on each axis.
fn write_visible_picks(
    picks: &mut String,
    image: &str,
    (world, pose, camera): (&World, &CameraPose, &Camera),
    (noise, sigma_px): (&Normal<f64>, f64),
    rng: &mut rand_chacha::ChaCha8Rng,
) {
    let size = camera.image_size.expect("size");
    let (w, h) = (f64::from(size.width), f64::from(size.height));
    for (name, p) in &world.gcps {
        let Some(uv) = pose.project(camera, p) else {
            continue;
        };
        let inside = uv.x >= 10.0 && uv.y >= 10.0 && uv.x <= w - 11.0 && uv.y <= h - 11.0;
        let dir = (p - pose.centre).normalize();
        let seen = world
            .intersect(&pose.centre, &dir)
            .is_some_and(|(hit, _)| (hit - p).norm() < 0.05);
        if inside && seen {
            let (u, v) = (uv.x + noise.sample(rng), uv.y + noise.sample(rng));
            let _ = writeln!(picks, "{name},{image},{u:.3},{v:.3},{sigma_px}");
        }
    }
}

/// The gimbal's yaw, pitch and roll of a camera pose, degrees, as DJI writes them: pitch up
/// from the horizon (−90 straight down), yaw the heading of the image's top (clockwise from
/// north; the view's for a tilted camera), roll the image's x axis above the horizon.
fn gimbal_angles(pose: &CameraPose) -> [f64; 3] {
    let r = &pose.world_from_cam;
    let (x, forward, up) = (
        r.column(0).into_owned(),
        r.column(2).into_owned(),
        -r.column(1).into_owned(),
    );
    let heading = forward.xy() + up.xy();
    [
        heading.x.atan2(heading.y).to_degrees(),
        forward.z.clamp(-1.0, 1.0).asin().to_degrees(),
        x.z.clamp(-1.0, 1.0).asin().to_degrees(),
    ]
}

/// DJI's telemetry subtitles for the video (`video.SRT`, the bracketed generation with the
/// gimbal's angles), one block a frame: the camera centre as a consumer drone's GNSS gives it
/// (an offset common to the flight, σ 2 m per horizontal axis and 3 m up, and a slow wander of
/// σ 0.7 m per axis, correlated over about 10 s), its height above the site frame's origin as
/// `rel_alt` (the take-off point), the ellipsoidal height as `abs_alt`, and the gimbal's angles with 0.3°
/// of noise. Truth: the exact centres are in `truth/camera.csv`.
fn write_telemetry(
    scene: &Scene,
    poses: &[CameraPose],
    video: &Path,
    seed: u64,
) -> Result<PathBuf, SimError> {
    use std::fmt::Write as _;
    let (_, tangent) = site_frame(&scene.site)?;
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(seed ^ 0x5127_7E1E);
    let n = |s: f64| Normal::new(0.0, s).expect("sigma");
    let offset = Vector3::new(
        n(2.0).sample(&mut rng),
        n(2.0).sample(&mut rng),
        n(3.0).sample(&mut rng),
    );
    // AR(1) per axis: step correlation exp(−dt/τ), τ = 10 s, stationary σ 0.7 m.
    let dt = 1.0 / scene.fps;
    let phi = (-dt / 10.0f64).exp();
    let step = n(0.7 * (1.0 - phi * phi).sqrt());
    let mut wander = Vector3::new(
        n(0.7).sample(&mut rng),
        n(0.7).sample(&mut rng),
        n(0.7).sample(&mut rng),
    );
    let angle_noise = n(0.3);
    let ms = (1000.0 * dt).round() as u64;
    let stamp = |t: f64| {
        let ms = (t * 1000.0).round() as u64;
        format!(
            "{:02}:{:02}:{:02},{:03}",
            ms / 3_600_000,
            ms / 60_000 % 60,
            ms / 1000 % 60,
            ms % 1000
        )
    };
    let mut s = String::new();
    for (i, pose) in poses.iter().enumerate() {
        let t = i as f64 * dt;
        let measured = pose.centre + offset + wander;
        wander = wander * phi
            + Vector3::new(
                step.sample(&mut rng),
                step.sample(&mut rng),
                step.sample(&mut rng),
            );
        let g = tangent.geodetic_from_enu(&measured);
        let [yaw, pitch, roll] = gimbal_angles(pose).map(|a| a + angle_noise.sample(&mut rng));
        let clock = 36_000.0 + t;
        let _ = write!(
            s,
            "{}\n{} --> {}\n<font size=\"28\">FrameCnt: {}, DiffTime: {ms}ms\n2026-06-01 {:02}:{:02}:{:06.3}\n\
             [iso: 100] [shutter: 1/1000.0] [fnum: 2.8] [ev: 0] [color_md: default] [focal_len: 24.00] \
             [latitude: {:.7}] [longitude: {:.7}] [rel_alt: {:.3} abs_alt: {:.3}] \
             [gb_yaw: {yaw:.1} gb_pitch: {pitch:.1} gb_roll: {roll:.1}] </font>\n\n",
            i + 1,
            stamp(t),
            stamp(t + dt),
            i + 1,
            (clock / 3600.0).floor(),
            (clock / 60.0).floor() % 60.0,
            clock % 60.0,
            g.lat.to_degrees(),
            g.lon.to_degrees(),
            measured.z,
            g.h,
        );
    }
    let path = video.with_extension("SRT");
    write_file(&path, &s)?;
    Ok(path)
}

/// Checkerboard images taken with the scene's camera (9x6 inner corners, 5 cm squares).
fn write_checkerboards(
    scene: &Scene,
    camera: &Camera,
    out: &Path,
    seed: u64,
) -> Result<Vec<PathBuf>, SimError> {
    let n = scene.output.checkerboards as usize;
    if n == 0 {
        return Ok(Vec::new());
    }
    let board = BoardSpec {
        cols: 9,
        rows: 6,
        square_m: 0.05,
    };
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(seed ^ 0xB0A2D);
    let poses = random_board_poses(camera, &board, n, &mut rng);
    let renderer = BoardRenderer::new(camera, 2);
    let mut files = Vec::new();
    for (i, p) in poses.iter().enumerate() {
        let img = renderer.render(&board, p, 2.0, &mut rng);
        let path = out.join("checkerboards").join(format!("board-{i:02}.png"));
        crate::imageio::write_gray(&path, &img).map_err(|e| SimError::Output(e.to_string()))?;
        files.push(path);
    }
    Ok(files)
}

/// The survey flight's photos (JPEG, no people: taken before the event), their camera centres
/// as recorded (an Emlid CSV in the site CRS with RTK-like noise, named after the photos), the
/// GCP picks in every photo that sees them (pixel noise as for the video's picks) and the exact
/// cameras, under `survey/`.
fn write_survey_flight(
    scene: &Scene,
    world: &World,
    camera: &Camera,
    out: &Path,
    seed: u64,
    sun: &Vector3<f64>,
) -> Result<Vec<PathBuf>, SimError> {
    let Some(spec) = &scene.survey_flight else {
        return Ok(Vec::new());
    };
    let [w, h] = spec.image_size;
    let photo_camera = camera.scaled_to(w, h).ok_or_else(|| {
        SimError::Input(format!(
            "survey_flight.image_size {w}x{h}: not the camera's aspect ratio"
        ))
    })?;
    let dir = out.join("survey");
    let photos = dir.join("photos");
    std::fs::create_dir_all(&photos)
        .map_err(|e| SimError::Output(format!("{}: {e}", photos.display())))?;
    let poses = survey_poses(spec, photo_camera.fx, photo_camera.fy, w, h, seed);
    // Textures over what the nadir photos see; the obliques' far field is drawn procedurally.
    let nadir = &poses[..poses.len() - spec.obliques as usize];
    let (lo, hi) = view_box(&photo_camera, world, nadir);
    let gsd = spec.altitude_m / photo_camera.fx.max(photo_camera.fy);
    let area = (hi.x - lo.x) * (hi.y - lo.y);
    let texel = (0.7 * gsd).max((area / 60e6).sqrt()).clamp(0.004, 0.05);
    let settings = RenderSettings {
        texel_m: texel,
        sun: *sun,
        image_noise: scene.output.image_noise,
        seed: seed ^ 0x5EED,
    };
    let renderer = Renderer::new(world, photo_camera.clone(), (lo, hi), &settings);
    let (crs, tangent) = site_frame(&scene.site)?;
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(seed ^ 0x5A7E_F117);
    let rtk = RtkNoise::new(&crs, spec.rtk_noise_m);
    let pick_noise = Normal::new(0.0, scene.output.pick_noise_px.max(1e-12)).expect("sigma");
    let mut centres = Vec::new();
    let mut picks = String::from("name,image,u,v,sigma\n");
    let mut truth = String::from("image,e_m,n_m,u_m,x,y,ellipsoidal_height_m,qw,qx,qy,qz\n");
    for (i, pose) in poses.iter().enumerate() {
        let name = format!("IMG_{:04}.jpg", i + 1);
        let rgb = renderer.render(&FrameInput {
            index: i,
            pose,
            bodies: &[],
            shadows: &[],
            light: 1.0,
        });
        crate::imageio::write_rgb(&photos.join(&name), w, h, &rgb)
            .map_err(|e| SimError::Output(e.to_string()))?;
        let g = tangent.geodetic_from_enu(&pose.centre);
        let (x, y) = crs
            .from_lon_lat(g.lon.to_degrees(), g.lat.to_degrees())
            .map_err(|e| SimError::Input(e.to_string()))?;
        let q = nalgebra::UnitQuaternion::from_matrix(&pose.world_from_cam.transpose());
        let _ = writeln!(
            truth,
            "{name},{:.6},{:.6},{:.6},{x:.6},{y:.6},{:.6},{:.12},{:.12},{:.12},{:.12}",
            pose.centre.x, pose.centre.y, pose.centre.z, g.h, q.w, q.i, q.j, q.k
        );
        centres.push(rtk.measured(&name, x, y, g.h, i + 2, &mut rng));
        let noise = (&pick_noise, scene.output.pick_noise_px);
        write_visible_picks(
            &mut picks,
            &name,
            (world, pose, &photo_camera),
            noise,
            &mut rng,
        );
    }
    let csv = emlid_in_site_crs(scene, &crs, &centres)?;
    let paths = [
        dir.join("centres.csv"),
        dir.join("picks.csv"),
        out.join("truth").join("survey_cameras.csv"),
    ];
    write_file(&paths[0], &csv)?;
    write_file(&paths[1], &picks)?;
    write_file(&paths[2], &truth)?;
    let mut files = vec![photos];
    files.extend(paths);
    Ok(files)
}
