//! The pose outputs of a hovering video: per-frame poses, the reprojection error per frame (table
//! and plot), key frames and adjusted GCPs.

use std::fmt::Write as _;
use std::path::{Path, PathBuf};

use nalgebra::Matrix3;

use crate::camera::Camera;
use crate::draw::{Chart, Series, Style, line_chart};
use crate::geom::Rigid3;
use crate::io::write_atomic;
use crate::pose::hover::HoverResult;
use crate::pose::stabilise::FrameTrack;
use crate::pose::{Attitude, GcpObservation};
use crate::survey::load::Framed;

/// A number for a CSV field; empty when unknown.
pub(crate) fn csv_num(v: Option<f64>, decimals: usize) -> String {
    v.filter(|v| v.is_finite())
        .map_or(String::new(), |v| format!("{v:.decimals$}"))
}

/// The columns of `poses.csv` that say where a camera is (both pose kinds write them).
pub const POSE_COLUMNS: &str = "centre_e_m,centre_n_m,centre_u_m,sigma_e_m,sigma_n_m,sigma_u_m,x,y,z,yaw_deg,pitch_deg,roll_deg,off_nadir_deg,rvec_x,rvec_y,rvec_z,tvec_x,tvec_y,tvec_z";

/// A camera's [`POSE_COLUMNS`]: its centre (site frame) and σ, the centre in the GCP file's CRS,
/// its attitude, and `cam_from_world` as OpenCV's rvec/tvec.
pub(crate) fn pose_columns(
    pose: &Rigid3,
    centre_sigma_m: Option<nalgebra::Vector3<f64>>,
    framed: &Framed,
) -> Result<String, PoseOutputError> {
    let c = pose.centre();
    let src = framed
        .frame
        .source_from_local(&c)
        .map_err(|e| PoseOutputError::Crs(format!("camera position to the GCP file's CRS: {e}")))?;
    let att = Attitude::from_world_from_cam(&pose.rotation.inverse().into_inner());
    let (rv, tv) = (pose.rvec(), pose.translation);
    let sg = centre_sigma_m;
    Ok(format!(
        "{:.4},{:.4},{:.4},{},{},{},{:.4},{:.4},{:.4},{:.5},{:.5},{:.5},{:.5},{:.9},{:.9},{:.9},{:.6},{:.6},{:.6}",
        c.x,
        c.y,
        c.z,
        csv_num(sg.map(|s| s.x), 4),
        csv_num(sg.map(|s| s.y), 4),
        csv_num(sg.map(|s| s.z), 4),
        src.x,
        src.y,
        src.z,
        att.yaw_deg,
        att.pitch_deg,
        att.roll_deg,
        att.off_nadir_deg,
        rv.x,
        rv.y,
        rv.z,
        tv.x,
        tv.y,
        tv.z
    ))
}

/// What a video's pose solution produced, for the output files.
pub struct PoseRun<'a> {
    pub camera: &'a Camera,
    pub result: &'a HoverResult,
    pub tracks: &'a [FrameTrack],
    /// Mean reprojection error of the check points' carried picks per frame.
    pub check_mean: &'a [Option<f64>],
    pub fps: f64,
    pub framed: &'a Framed,
    /// The control GCPs, in the order of the solution's points.
    pub control: &'a [GcpObservation],
}

/// Writes `poses.csv`, `reprojection.csv` and `.png`, `key_frames.csv` and `gcps_adjusted.csv`
/// into `out`; returns the paths.
/// Why `pose/` could not be written.
#[derive(Debug, thiserror::Error)]
pub enum PoseOutputError {
    #[error("{}: {source}", path.display())]
    Write {
        path: PathBuf,
        #[source]
        source: std::io::Error,
    },
    /// A position could not be converted to the GCP file's CRS.
    #[error("{0}")]
    Crs(String),
    #[error(transparent)]
    Chart(crate::imageio::ImageError),
    #[error("formatting a table: {0}")]
    Format(#[from] std::fmt::Error),
}

pub fn write_pose_outputs(out: &Path, run: &PoseRun) -> Result<Vec<PathBuf>, PoseOutputError> {
    let PoseRun {
        camera,
        result: r,
        tracks,
        check_mean,
        fps,
        framed,
        control,
    } = *run;
    let mut written = Vec::new();
    let mut put = |name: &str, text: String| -> Result<(), PoseOutputError> {
        let p = out.join(name);
        write_atomic(&p, text.as_bytes()).map_err(|source| PoseOutputError::Write {
            path: p.clone(),
            source,
        })?;
        written.push(p);
        Ok(())
    };
    let mut poses = format!(
        "frame,time_s,key,reference,interpolated,features,feature_inliers,picks_used,mean_reprojection_px,max_reprojection_px,{POSE_COLUMNS}\n"
    );
    let mut reproj = String::from(
        "frame,time_s,key,picks_used,mean_reprojection_px,max_reprojection_px,check_mean_reprojection_px\n",
    );
    for ((f, t), chk) in r.frames.iter().zip(tracks).zip(check_mean) {
        let time = f.index as f64 / fps;
        writeln!(
            poses,
            "{},{time:.6},{},{},{},{},{},{},{},{},{}",
            f.index,
            u8::from(f.key),
            t.reference,
            u8::from(f.interpolated),
            t.features,
            t.inliers,
            f.picks_used,
            csv_num(f.mean_reprojection_px, 4),
            csv_num(f.max_reprojection_px, 4),
            pose_columns(&f.cam_from_world, f.centre_sigma_m, framed)?
        )?;
        writeln!(
            reproj,
            "{},{time:.6},{},{},{},{},{}",
            f.index,
            u8::from(f.key),
            f.picks_used,
            csv_num(f.mean_reprojection_px, 4),
            csv_num(f.max_reprojection_px, 4),
            csv_num(*chk, 4)
        )?;
    }
    put("poses.csv", poses)?;
    put("reprojection.csv", reproj)?;

    put("key_frames.csv", key_frames_csv(run)?)?;

    put("gcps_adjusted.csv", gcps_adjusted_csv(run)?)?;

    // The paper's Fig. 13: mean reprojection error per frame, and the level the survey's
    // uncertainty alone explains.
    let mean: Vec<(f64, f64)> = r
        .frames
        .iter()
        .map(|f| {
            (
                f.index as f64 / fps,
                f.mean_reprojection_px.unwrap_or(f64::NAN),
            )
        })
        .collect();
    let mut series = vec![Series {
        label: "mean reprojection error".into(),
        xy: mean,
        rgb: [0, 0, 0],
        style: Style::Line,
    }];
    if check_mean.iter().any(Option::is_some) {
        series.push(Series {
            label: "check points".into(),
            xy: r
                .frames
                .iter()
                .zip(check_mean)
                .map(|(f, c)| (f.index as f64 / fps, c.unwrap_or(f64::NAN)))
                .collect(),
            rgb: [230, 120, 0],
            style: Style::Line,
        });
    }
    if let Some(level) = survey_level_px(r, control, camera) {
        series.push(Series {
            label: format!("GCP survey sigma ({level:.2} px)"),
            xy: vec![
                (0.0, level),
                (tracks.len().saturating_sub(1) as f64 / fps, level),
            ],
            rgb: [150, 150, 150],
            style: Style::Dashed,
        });
    }
    let chart = Chart {
        title: "Mean reprojection error of the GCPs per frame".into(),
        x_label: "time (s)".into(),
        y_label: "pixels".into(),
        series,
        ticks: r.key_frames.iter().map(|k| k.index as f64 / fps).collect(),
        ticks_label: "key frames".into(),
        y_from_data: false,
        x_from_zero: false,
    };
    let png = out.join("reprojection.png");
    line_chart(&chart, 1200, 500)
        .and_then(|c| c.save(&png))
        .map_err(PoseOutputError::Chart)?;
    written.push(png);
    Ok(written)
}

/// `key_frames.csv`: each key frame, why it is one, and its PnP solution or error.
fn key_frames_csv(run: &PoseRun) -> Result<String, PoseOutputError> {
    let (r, tracks, fps) = (run.result, run.tracks, run.fps);
    let mut keys =
        String::from("frame,time_s,reason,features,picks,inliers,outliers,rms_px,sigma0,error\n");
    for k in &r.key_frames {
        let t = tracks.iter().find(|t| t.index == k.index);
        match &k.solution {
            Ok(s) => writeln!(
                keys,
                "{},{:.6},{},{},{},{},{},{:.4},{:.3},",
                k.index,
                k.index as f64 / fps,
                k.reason.as_str(),
                t.map_or(0, |t| t.features),
                k.picks,
                s.inliers,
                k.picks - s.inliers,
                s.rms_px,
                s.sigma0
            )?,
            Err(e) => writeln!(
                keys,
                "{},{:.6},{},{},{},,,,,\"{}\"",
                k.index,
                k.index as f64 / fps,
                k.reason.as_str(),
                t.map_or(0, |t| t.features),
                k.picks,
                e.to_string().replace('"', "'")
            )?,
        }
    }
    Ok(keys)
}

/// `gcps_adjusted.csv`: the control points after the joint adjustment, with their shift and σ.
fn gcps_adjusted_csv(run: &PoseRun) -> Result<String, PoseOutputError> {
    let (r, control, framed) = (run.result, run.control, run.framed);
    let mut g = String::from(
        "name,e_m,n_m,u_m,shift_e_m,shift_n_m,shift_u_m,sigma_e_m,sigma_n_m,sigma_u_m,x,y,z\n",
    );
    for ((o, p), c) in control.iter().zip(&r.joint.points).zip(&r.joint.point_cov) {
        let d = p - o.world;
        let src = framed
            .frame
            .source_from_local(p)
            .map_err(|e| PoseOutputError::Crs(format!("GCP {} to the file's CRS: {e}", o.name)))?;
        let sd = |m: &Matrix3<f64>, k: usize| m[(k, k)].max(0.0).sqrt();
        writeln!(
            g,
            "{},{:.4},{:.4},{:.4},{:.4},{:.4},{:.4},{:.4},{:.4},{:.4},{:.4},{:.4},{:.4}",
            o.name,
            p.x,
            p.y,
            p.z,
            d.x,
            d.y,
            d.z,
            sd(c, 0),
            sd(c, 1),
            sd(c, 2),
            src.x,
            src.y,
            src.z
        )?;
    }
    Ok(g)
}

/// The pixel error the GCPs' survey σ alone explains: the mean over GCPs of the horizontal σ
/// seen at its depth in the first solved key frame.
fn survey_level_px(r: &HoverResult, control: &[GcpObservation], camera: &Camera) -> Option<f64> {
    let pose: Rigid3 = *r.joint.poses.first()?;
    let focal = 0.5 * (camera.fx + camera.fy);
    let mut sum = 0.0;
    for o in control {
        let depth = pose.apply(&o.world).z;
        if depth <= 0.0 {
            return None;
        }
        sum += focal * (0.5 * (o.world_cov[(0, 0)] + o.world_cov[(1, 1)])).sqrt() / depth;
    }
    Some(sum / control.len() as f64)
}
