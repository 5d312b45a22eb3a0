//! `geostride pose`: the camera pose from GCP picks, for one image or every frame of a
//! hovering video.

use std::fmt::Write as _;
use std::path::{Path, PathBuf};

use anyhow::{Context, anyhow};
use nalgebra::{Matrix3, Vector2, Vector3};
use serde::Serialize;

use super::survey::{Framed, ReadArgs, read_framed};
use super::{bad_input, check_output_file, load_camera, parse_positive, scale_to};
use geostride::camera::Camera;
use geostride::draw::Canvas;
use geostride::optim::RobustLoss;
use geostride::pose::attitude::attitude_sigma_deg;
use geostride::pose::solve::gcp_residual;
use geostride::pose::{Attitude, GcpResidual, PoseError, PoseSettings, PoseSolution, solve_pose};

#[derive(clap::Args)]
pub struct Args {
    /// Camera calibration (OpenCV YAML, Metashape XML, geostride JSON) or a preset name; scaled
    /// to the image or video size when the aspect ratio matches
    #[arg(long, value_name = "CAL")]
    pub(crate) camera: String,
    /// Ground control points: any survey file `geostride survey` reads (Emlid CSV, ODM
    /// gcp_list.txt, Metashape CSV, PeTrack .3dc, ...); its picks are used too
    #[arg(long, value_name = "FILE")]
    pub(crate) gcps: PathBuf,
    #[command(flatten)]
    pub(crate) read: ReadArgs,
    /// The photo: its size sets the camera's, its picks are those named after it, and an
    /// annotated copy (GCPs projected, residual vectors) is written
    #[arg(long, value_name = "IMG", conflicts_with = "video")]
    image: Option<PathBuf>,
    /// Where to write the annotated image [default: IMG's name with '-pose.jpg', in the
    /// current folder]
    #[arg(long, value_name = "FILE", requires = "image")]
    annotated: Option<PathBuf>,
    /// Use the picks of this image name [default: --image's file name, or the only image the
    /// picks name]
    #[arg(long, value_name = "NAME")]
    pub(crate) picks_image: Option<String>,
    /// σ of picks that do not state one, pixels
    #[arg(long, default_value = "1.0", value_parser = parse_positive, value_name = "PX")]
    pub(crate) pick_sigma: f64,
    /// σ of GCP positions that the file does not state, metres (horizontal and vertical)
    #[arg(long, default_value = "0.02", value_parser = parse_positive, value_name = "M")]
    pub(crate) gcp_sigma: f64,
    /// MSAC inlier threshold, pixels [default: 3.72 σ of the picks and the projected survey σ,
    /// at least 4]
    #[arg(long, value_parser = parse_positive, value_name = "PX")]
    pub(crate) threshold: Option<f64>,
    /// Robust loss of the refinement: none, huber[:K] or cauchy[:K] (K in σ)
    #[arg(long, default_value = "none", value_name = "LOSS")]
    pub(crate) loss: RobustLoss,
    /// Seed of the MSAC sampler
    #[arg(long, default_value = "0")]
    pub(crate) seed: u64,
    /// Print JSON instead of the report
    #[arg(long, conflicts_with = "video")]
    json: bool,
    /// A hovering video: stabilise it, choose key frames, carry the picks (made on one frame)
    /// to every frame and solve every frame's pose; needs --out
    #[arg(long, value_name = "VIDEO", requires = "out")]
    pub(crate) video: Option<PathBuf>,
    /// The frame the picks were made on [default: the '#N' ending of the picks' image name,
    /// e.g. 'video.mp4#0', else 0]
    #[arg(long, value_name = "N", requires = "video")]
    pub(crate) picks_frame: Option<usize>,
    /// Folder for the video results (created if missing): poses.csv, reprojection.csv and .png,
    /// key_frames.csv, gcps_adjusted.csv, pose.json
    #[arg(long, value_name = "DIR", requires = "video")]
    pub(crate) out: Option<PathBuf>,
    /// Process only the first this many seconds of the video
    #[arg(long, value_parser = parse_positive, value_name = "S", requires = "video")]
    pub(crate) duration: Option<f64>,
    /// Renew the reference frame when fewer tracked features than this agree with it
    #[arg(long, default_value = "40", value_name = "N", requires = "video")]
    pub(crate) min_features: usize,
    /// Renew the reference frame when the agreeing features fall below this fraction of its own
    #[arg(long, default_value = "0.5", value_parser = super::parse_fraction, value_name = "F", requires = "video")]
    pub(crate) key_fraction: f64,
    /// Renew the reference frame at least every this many seconds [default: only on the
    /// feature and conditioning criteria]
    #[arg(long, value_parser = parse_positive, value_name = "S", requires = "video")]
    pub(crate) key_every: Option<f64>,
    /// No progress bar
    #[arg(short, long)]
    pub(crate) quiet: bool,
}

/// The GCPs seen in one image, split by role.
pub(crate) type Seen = geostride::survey::load::ImageObservations;

/// Which image's picks to use.
pub(crate) fn choose_image(
    framed: &Framed,
    wanted: Option<&str>,
    photo: Option<&Path>,
) -> anyhow::Result<String> {
    let images = framed.picked_images();
    let list = || {
        images
            .iter()
            .map(|(k, n)| format!("'{k}' ({n})"))
            .collect::<Vec<_>>()
            .join(", ")
    };
    if images.is_empty() {
        return Err(bad_input(anyhow!(
            "{}: no pixel picks: add them with --picks FILE (CSV 'name,image,u,v[,sigma]') or use a GCP file with picks (ODM gcp_list.txt, PeTrack .3dc)",
            framed.survey.source.display()
        )));
    }
    if let Some(w) = wanted {
        return if images.contains_key(w) {
            Ok(w.to_string())
        } else {
            Err(bad_input(anyhow!(
                "--picks-image '{w}': no picks name that image; the picks name {}",
                list()
            )))
        };
    }
    if let Some(photo) = photo {
        let file = photo
            .file_name()
            .and_then(|f| f.to_str())
            .unwrap_or_default();
        let stem = photo
            .file_stem()
            .and_then(|f| f.to_str())
            .unwrap_or_default();
        if let Some(k) = images
            .keys()
            .find(|k| k.as_str() == file)
            .or_else(|| images.keys().find(|k| k.as_str() == stem))
        {
            return Ok(k.clone());
        }
        if images.len() == 1 {
            return Ok(images.keys().next().expect("one").clone());
        }
        return Err(bad_input(anyhow!(
            "no picks name '{file}'; choose with --picks-image among {}",
            list()
        )));
    }
    if images.len() == 1 {
        return Ok(images.keys().next().expect("one").clone());
    }
    Err(bad_input(anyhow!(
        "the picks name several images; choose one with --picks-image among {}",
        list()
    )))
}

/// Site-frame observations of the GCPs picked in `image` (bad picks: exit 2).
pub(crate) fn seen_in(
    framed: &Framed,
    image: &str,
    pick_sigma: f64,
    gcp_sigma: f64,
    camera: &Camera,
) -> anyhow::Result<Seen> {
    let size = camera.image_size.map(|s| (s.width, s.height));
    framed
        .observations(image, pick_sigma, gcp_sigma, size)
        .map_err(bad_input)
}

/// The camera, scaled to `size` when given.
pub(crate) fn camera_for(spec: &str, size: Option<(u32, u32)>) -> anyhow::Result<(Camera, String)> {
    let (camera, source) = load_camera(spec)?;
    let Some((w, h)) = size else {
        return Ok((camera, source));
    };
    match camera.image_size {
        Some(s) if s.width == w && s.height == h => Ok((camera, source)),
        Some(_) => Ok((
            scale_to(camera, w, h)?,
            format!("{source}, scaled to {w}x{h}"),
        )),
        None => Ok((camera.with_image_size(w, h), source)),
    }
}

/// A pose that cannot be solved from these picks, said with where they come from.
fn pose_error(e: PoseError, seen: &Seen, picks: &str) -> anyhow::Error {
    let e = match e {
        PoseError::BehindCamera { points } => {
            let names: Vec<&str> = points
                .iter()
                .filter_map(|&i| seen.control.get(i))
                .map(|o| o.name.as_str())
                .collect();
            anyhow!(
                "GCP(s) {} lie behind the camera: check their heights (units, ellipsoidal vs orthometric) and the picks",
                names.join(", ")
            )
        }
        other => anyhow!(other),
    };
    bad_input(e.context(picks.to_string()))
}

#[derive(Serialize)]
struct JsonPosition {
    x: f64,
    y: f64,
    z: f64,
    crs: Option<String>,
    height: String,
}

#[derive(Serialize)]
struct JsonResidual<'a> {
    name: &'a str,
    role: &'static str,
    u: f64,
    v: f64,
    projected_u: Option<f64>,
    projected_v: Option<f64>,
    residual_u_px: Option<f64>,
    residual_v_px: Option<f64>,
    residual_px: Option<f64>,
    ground_e_m: Option<f64>,
    ground_n_m: Option<f64>,
    ground_m: Option<f64>,
    normalised: Option<f64>,
    depth_m: Option<f64>,
    outlier: bool,
}

#[derive(Serialize)]
struct JsonAttitudeSigma {
    yaw_deg: f64,
    pitch_deg: f64,
    roll_deg: f64,
}

#[derive(Serialize)]
struct JsonCamFromWorld {
    rvec: [f64; 3],
    tvec: [f64; 3],
}

#[derive(Serialize)]
struct JsonPose<'a> {
    image: &'a str,
    camera: &'a str,
    /// In the GCP file's coordinate system and units.
    camera_position: JsonPosition,
    camera_position_sigma_m: [f64; 3],
    /// East, north, up in the site frame, metres.
    camera_position_local: [f64; 3],
    site_frame: &'a str,
    attitude: Attitude,
    attitude_sigma_deg: JsonAttitudeSigma,
    /// Yaw from the CRS's grid north (the attitude's yaw is from true north).
    yaw_grid_deg: Option<f64>,
    cam_from_world: JsonCamFromWorld,
    /// (δφ_e, δφ_n, δφ_u, C_e, C_n, C_u): rotation errors about the site axes (rad), centre (m).
    covariance: [[f64; 6]; 6],
    rms_px: f64,
    sigma0: f64,
    inliers: usize,
    outliers: usize,
    threshold_px: f64,
    ransac_iterations: usize,
    check_rms_px: Option<f64>,
    check_ground_rms_m: Option<f64>,
    residuals: Vec<JsonResidual<'a>>,
}

/// Everything reported about one solved image.
struct Report<'a> {
    image: &'a str,
    camera_source: &'a str,
    framed: &'a Framed,
    solution: &'a PoseSolution,
    checks: Vec<GcpResidual>,
}

impl Report<'_> {
    fn position(&self) -> anyhow::Result<Vector3<f64>> {
        self.framed
            .frame
            .source_from_local(&self.solution.centre)
            .map_err(|e| anyhow!("camera position to the GCP file's CRS: {e}"))
    }

    fn world_from_cam(&self) -> Matrix3<f64> {
        self.solution.cam_from_world.rotation.matrix().transpose()
    }

    /// The azimuth of grid north from true north at the camera, degrees; `None` without a
    /// projected CRS.
    fn grid_convergence_deg(&self, source: &Vector3<f64>) -> Option<f64> {
        let crs = self.framed.frame.crs.as_ref()?;
        if crs.horizontal != geostride::survey::crs::Horizontal::Projected {
            return None;
        }
        let step = 10.0 / crs.unit_m;
        let a = self
            .framed
            .frame
            .local_from_source(&Vector3::new(source.x, source.y, 0.0))
            .ok()?;
        let b = self
            .framed
            .frame
            .local_from_source(&Vector3::new(source.x, source.y + step, 0.0))
            .ok()?;
        let g = b - a;
        Some(g.x.atan2(g.y).to_degrees())
    }

    fn check_rms(&self) -> (Option<f64>, Option<f64>) {
        let px: Vec<f64> = self
            .checks
            .iter()
            .filter_map(|r| r.residual_px)
            .map(|r| r.norm_squared())
            .collect();
        let m: Vec<f64> = self
            .checks
            .iter()
            .filter_map(|r| r.ground_m)
            .map(|r| r.norm_squared())
            .collect();
        let rms =
            |v: &[f64]| (!v.is_empty()).then(|| (v.iter().sum::<f64>() / v.len() as f64).sqrt());
        (rms(&px), rms(&m))
    }

    fn rows(&self) -> impl Iterator<Item = (&GcpResidual, &'static str)> {
        self.solution
            .residuals
            .iter()
            .map(|r| (r, "control"))
            .chain(self.checks.iter().map(|r| (r, "check")))
    }

    fn json(&self) -> anyhow::Result<String> {
        let s = self.solution;
        let p = self.position()?;
        let att = Attitude::from_world_from_cam(&self.world_from_cam());
        let cov_phi: Matrix3<f64> = s.covariance.fixed_view::<3, 3>(0, 0).into();
        let sig = attitude_sigma_deg(&self.world_from_cam(), &cov_phi);
        let (check_rms_px, check_ground_rms_m) = self.check_rms();
        let rvec = s.cam_from_world.rvec();
        let t = s.cam_from_world.translation;
        let j = JsonPose {
            image: self.image,
            camera: self.camera_source,
            camera_position: JsonPosition {
                x: p.x,
                y: p.y,
                z: p.z,
                crs: self.framed.frame.crs.as_ref().map(|c| c.label()),
                height: self.framed.frame.height.to_string(),
            },
            camera_position_sigma_m: s.centre_sigma_m.into(),
            camera_position_local: s.centre.into(),
            site_frame: &self.framed.frame.origin_note,
            attitude: att,
            attitude_sigma_deg: JsonAttitudeSigma {
                yaw_deg: sig[0],
                pitch_deg: sig[1],
                roll_deg: sig[2],
            },
            yaw_grid_deg: self
                .grid_convergence_deg(&p)
                .map(|g| (att.yaw_deg - g).rem_euclid(360.0)),
            cam_from_world: JsonCamFromWorld {
                rvec: rvec.into(),
                tvec: t.into(),
            },
            covariance: std::array::from_fn(|r| std::array::from_fn(|c| s.covariance[(r, c)])),
            rms_px: s.rms_px,
            sigma0: s.sigma0,
            inliers: s.inliers,
            outliers: s.residuals.len() - s.inliers,
            threshold_px: s.threshold_px,
            ransac_iterations: s.ransac_iterations,
            check_rms_px,
            check_ground_rms_m,
            residuals: self
                .rows()
                .map(|(r, role)| JsonResidual {
                    name: &r.name,
                    role,
                    u: r.uv.x,
                    v: r.uv.y,
                    projected_u: r.projected.map(|p| p.x),
                    projected_v: r.projected.map(|p| p.y),
                    residual_u_px: r.residual_px.map(|d| d.x),
                    residual_v_px: r.residual_px.map(|d| d.y),
                    residual_px: r.residual_px.map(|d| d.norm()),
                    ground_e_m: r.ground_m.map(|d| d.x),
                    ground_n_m: r.ground_m.map(|d| d.y),
                    ground_m: r.ground_m.map(|d| d.norm()),
                    normalised: r.normalised,
                    depth_m: r.depth_m,
                    outlier: r.outlier,
                })
                .collect(),
        };
        Ok(serde_json::to_string_pretty(&j)?)
    }

    fn text(&self) -> anyhow::Result<String> {
        let s = self.solution;
        let mut out = String::new();
        let p = self.position()?;
        let frame = &self.framed.frame;
        let att = Attitude::from_world_from_cam(&self.world_from_cam());
        let cov_phi: Matrix3<f64> = s.covariance.fixed_view::<3, 3>(0, 0).into();
        let sig = attitude_sigma_deg(&self.world_from_cam(), &cov_phi);
        let outliers = s.residuals.len() - s.inliers;
        writeln!(
            out,
            "Pose of '{}' from {} control point(s): {} inlier(s), {} outlier(s); {} check point(s)",
            self.image,
            s.residuals.len(),
            s.inliers,
            outliers,
            self.checks.len()
        )?;
        writeln!(out, "  camera: {}", self.camera_source)?;
        writeln!(out, "  site frame: {}", frame.origin_note)?;
        let crs = frame
            .crs
            .as_ref()
            .map_or("the file's local frame".to_string(), |c| c.label());
        writeln!(out, "Camera position ({crs}; heights {}):", frame.height)?;
        writeln!(out, "  X {:.3}  Y {:.3}  Z {:.3}", p.x, p.y, p.z)?;
        writeln!(
            out,
            "  site frame E {:.3}  N {:.3}  U {:.3} m, σ ({:.3}, {:.3}, {:.3}) m",
            s.centre.x,
            s.centre.y,
            s.centre.z,
            s.centre_sigma_m.x,
            s.centre_sigma_m.y,
            s.centre_sigma_m.z
        )?;
        write!(
            out,
            "Attitude: yaw {:.3}° ± {:.3}  pitch {:.3}° ± {:.3}  roll {:.3}° ± {:.3}  (off nadir {:.3}°)",
            att.yaw_deg, sig[0], att.pitch_deg, sig[1], att.roll_deg, sig[2], att.off_nadir_deg
        )?;
        match self.grid_convergence_deg(&p) {
            Some(g) => writeln!(
                out,
                "; yaw from grid north {:.3}°",
                (att.yaw_deg - g).rem_euclid(360.0)
            )?,
            None => writeln!(out)?,
        }
        writeln!(
            out,
            "Fit: RMS {:.3} px over the inliers, σ0 {:.2} (1 when the stated σ are right); MSAC threshold {:.1} px, {} iteration(s)",
            s.rms_px, s.sigma0, s.threshold_px, s.ransac_iterations
        )?;
        let (cpx, cm) = self.check_rms();
        if let (Some(a), b) = (cpx, cm) {
            writeln!(
                out,
                "Check points: RMS {a:.3} px{}",
                b.map_or(String::new(), |b| format!(", {:.3} m on the ground", b))
            )?;
        }
        writeln!(out)?;
        writeln!(
            out,
            "{:<14} {:<8} {:>9} {:>9} {:>8} {:>8} {:>8} {:>8} {:>8} {:>6}  status",
            "name", "role", "u", "v", "du px", "dv px", "|r| px", "dE m", "dN m", "norm"
        )?;
        for (r, role) in self.rows() {
            let f = |v: Option<f64>, d: usize| v.map_or("-".to_string(), |v| format!("{v:.d$}"));
            let status = if role == "check" {
                "check"
            } else if r.outlier {
                "OUTLIER"
            } else {
                "ok"
            };
            writeln!(
                out,
                "{:<14} {:<8} {:>9.2} {:>9.2} {:>8} {:>8} {:>8} {:>8} {:>8} {:>6}  {status}",
                r.name,
                role,
                r.uv.x,
                r.uv.y,
                f(r.residual_px.map(|d| d.x), 2),
                f(r.residual_px.map(|d| d.y), 2),
                f(r.residual_px.map(|d| d.norm()), 2),
                f(r.ground_m.map(|d| d.x), 3),
                f(r.ground_m.map(|d| d.y), 3),
                f(r.normalised, 1),
            )?;
        }
        writeln!(
            out,
            "(residuals are pick minus projection; dE, dN where the pick's ray meets the GCP's height, minus the GCP; norm in σ)"
        )?;
        Ok(out)
    }
}

/// A residual-vector magnification that shows the largest inlier residual at about 4 % of the
/// image width: 1, 2 or 5 times a power of ten.
fn arrow_scale(residuals: &[&GcpResidual], width: f64) -> f64 {
    let largest = residuals
        .iter()
        .filter(|r| !r.outlier)
        .filter_map(|r| r.residual_px)
        .map(|d| d.norm())
        .fold(0.0, f64::max);
    if !(largest > 0.0) {
        return 1.0;
    }
    let raw = (0.04 * width / largest).max(1.0);
    let p = 10f64.powf(raw.log10().floor());
    [5.0, 2.0, 1.0]
        .iter()
        .map(|m| m * p)
        .find(|s| *s <= raw)
        .unwrap_or(p)
}

fn annotate(path_in: &Path, path_out: &Path, report: &Report) -> anyhow::Result<()> {
    let mut c = Canvas::read(path_in).map_err(|e| bad_input(anyhow!(e)))?;
    let rows: Vec<(&GcpResidual, &str)> = report.rows().collect();
    let width = f64::from(c.width());
    let scale = arrow_scale(&rows.iter().map(|(r, _)| *r).collect::<Vec<_>>(), width);
    let text_scale = (width / 2400.0).clamp(0.4, 1.6);
    let thick = (width / 1500.0).round().max(1.0) as i32;
    let err = |e: geostride::imageio::ImageError| anyhow!(e);
    for (r, role) in &rows {
        let rgb = if *role == "check" {
            [255, 170, 0]
        } else if r.outlier {
            [255, 40, 40]
        } else {
            [40, 230, 60]
        };
        let half = 8.0 * text_scale / 0.6;
        c.cross(&r.uv, half, rgb, thick).map_err(err)?;
        if let Some(p) = r.projected {
            c.circle(&p, half * 1.2, [0, 220, 255], thick)
                .map_err(err)?;
            let d = r.uv - p;
            if d.norm() * scale > 2.0 {
                c.arrow(&p, &(p + d * scale), rgb, thick).map_err(err)?;
            }
        }
        let label = match r.residual_px {
            Some(d) => format!("{} {:.2} px", r.name, d.norm()),
            None => format!("{} (behind)", r.name),
        };
        c.text(
            &(r.uv + Vector2::new(half * 1.6, -half * 1.2)),
            &label,
            text_scale,
            rgb,
            thick,
        )
        .map_err(err)?;
    }
    let s = report.solution;
    let band = (44.0 * text_scale / 0.6) as i32;
    c.shade_rect(0, 0, c.width() as i32, band).map_err(err)?;
    let head = format!(
        "geostride pose: RMS {:.2} px over {} inliers, {} outlier(s) | circle: projected GCP, cross: pick (green ok, red outlier, orange check) | arrows x{}",
        s.rms_px,
        s.inliers,
        s.residuals.len() - s.inliers,
        scale
    );
    c.text(
        &Vector2::new(10.0, f64::from(band) * 0.68),
        &head,
        text_scale,
        [255, 255, 255],
        thick,
    )
    .map_err(err)?;
    c.save(path_out).map_err(err)
}

/// `geostride pose` of one image (`--video` is `pose_video::run`'s).
pub fn run(args: Args) -> anyhow::Result<()> {
    let size = match &args.image {
        Some(img) => {
            let c = Canvas::read(img).map_err(|e| bad_input(anyhow!(e)))?;
            Some((c.width(), c.height()))
        }
        None => args.read.image_size,
    };
    let (camera, camera_source) = camera_for(&args.camera, size)?;
    let framed = read_framed(&args.gcps, &args.read, None)?;
    let image = choose_image(&framed, args.picks_image.as_deref(), args.image.as_deref())?;
    let annotated = args.image.as_ref().map(|img| {
        args.annotated.clone().unwrap_or_else(|| {
            let stem = img.file_stem().and_then(|s| s.to_str()).unwrap_or("image");
            PathBuf::from(format!("{stem}-pose.jpg"))
        })
    });
    if let Some(a) = &annotated {
        let mut inputs = vec![args.gcps.clone()];
        inputs.extend(args.image.iter().cloned());
        inputs.extend(args.read.picks.iter().cloned());
        inputs.push(PathBuf::from(&args.camera));
        check_output_file(a, &inputs)?;
        geostride::imageio::check_writable(a).map_err(|e| bad_input(anyhow!(e)))?;
    }
    let seen = seen_in(&framed, &image, args.pick_sigma, args.gcp_sigma, &camera)?;
    let settings = PoseSettings {
        threshold_px: args.threshold,
        seed: args.seed,
        loss: args.loss,
        ..PoseSettings::default()
    };
    let solution = solve_pose(&camera, &seen.control, &settings).map_err(|e| {
        let files: Vec<String> = std::iter::once(&args.gcps)
            .chain(&args.read.picks)
            .map(|p| p.display().to_string())
            .collect();
        pose_error(
            e,
            &seen,
            &format!("{}: the picks of image '{image}'", files.join(", ")),
        )
    })?;
    let pose = solution.cam_from_world;
    let checks = seen
        .check
        .iter()
        .map(|o| gcp_residual(&camera, &pose, o, false))
        .collect();
    let report = Report {
        image: &image,
        camera_source: &camera_source,
        framed: &framed,
        solution: &solution,
        checks,
    };
    if let (Some(img), Some(out)) = (&args.image, &annotated) {
        annotate(img, out, &report)
            .with_context(|| format!("annotated image {}", out.display()))?;
    }
    if args.json {
        println!("{}", report.json()?);
    } else {
        print!("{}", report.text()?);
        for w in &framed.survey.warnings {
            eprintln!("warning: {w}");
        }
        if let Some(a) = &annotated {
            println!("Annotated: {}", a.display());
        }
    }
    Ok(())
}
