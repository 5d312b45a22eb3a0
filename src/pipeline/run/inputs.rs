//! The run's inputs read and checked before any work: the camera for the video's size, the survey
//! in its site frame, the picks, the head heights, the output CRS and the video's facts (the
//! ground is built by `registry::ground`, the pose source by `pose_source::open`); and the
//! checks that a split run's or a finished run's inputs are still those files.

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

use super::super::project::Loaded;
use super::super::settings::GroundInput;
use super::{InputRecord, KnownInput, MAX_FRAMES, RunError, file_record, size_and_time};
use crate::camera::{Camera, formats, presets};
use crate::pose::GcpObservation;
use crate::survey::crs::{Crs, Transform};
use crate::survey::frame::Origin;
use crate::survey::load::{Framed, LoadOptions, load_framed};
use crate::survey::read::{HeightChoice, ReadOptions};

/// Every input of the run, for the check that no output lands on one (a model is read as a
/// whole: nothing of the run goes inside it).
pub(super) fn input_guard(l: &Loaded) -> crate::io::Inputs {
    let p = &l.project;
    let files = l.input_files();
    let mut guard = crate::io::Inputs::new(files.iter().map(|(_, f)| f));
    guard.add(&l.path);
    if let super::super::settings::PoseSection::Model(m) = &p.pose
        && !m.model.is_empty()
    {
        guard.add_folder(l.resolve(&m.model));
    }
    if let Some(GroundInput::Model(model)) = p.ground.reads() {
        guard.add_folder(l.resolve(model));
    }
    guard
}

/// The video's facts from its header (no frame decoded).
pub(super) struct VideoFacts {
    pub path: PathBuf,
    pub fps: f64,
    pub width: u32,
    pub height: u32,
    /// The frames to process, when the video or `video.duration_s` states them.
    pub frames_total: Option<usize>,
}

pub(super) fn video_facts(l: &Loaded) -> Result<VideoFacts, RunError> {
    let p = &l.project;
    let video = l.resolve(&p.video.path);
    let reader = crate::video::source::FrameReader::open(&video)
        .map_err(|e| RunError::Input(l.error("video", "path", e.to_string())))?;
    let (fps, width, height, frame_count) =
        (reader.fps, reader.width, reader.height, reader.frame_count);
    drop(reader);
    if !(fps > 0.0) {
        return Err(RunError::Input(l.error(
            "video",
            "path",
            "the video states no frame rate",
        )));
    }
    let max_frames = p.video.duration_s.map(|d| (d * fps).ceil() as usize);
    let frames_total = match (frame_count, max_frames) {
        (Some(c), Some(m)) => Some(c.min(m)),
        (c, m) => c.or(m),
    };
    Ok(VideoFacts {
        path: video,
        fps,
        width,
        height,
        frames_total,
    })
}

/// The number of frames to process: stated, and no more than [`MAX_FRAMES`].
pub(super) fn frames_to_process(
    l: &Loaded,
    frames_total: Option<usize>,
) -> Result<usize, RunError> {
    let frames = frames_total.ok_or_else(|| {
        RunError::Input(l.error(
            "video",
            "duration_s",
            "the video states no frame count: give the seconds to process",
        ))
    })?;
    if frames > MAX_FRAMES {
        return Err(RunError::Input(l.error(
            "video",
            "duration_s",
            format!(
                "{frames} frames to process: more than a day at 120 frames a second ({MAX_FRAMES}); a damaged video states a wrong count: give the seconds to process"
            ),
        )));
    }
    Ok(frames)
}

/// The survey reader's warnings and the points it dropped, for the report.
pub(super) fn survey_warnings(framed: &Framed) -> Vec<String> {
    let mut warnings = framed.survey.warnings.clone();
    warnings.extend(framed.survey.dropped.iter().map(|d| {
        format!(
            "{}:{}: dropped: {}",
            framed.survey.source.display(),
            d.line,
            d.reason
        )
    }));
    warnings
}

/// The output CRS (`export.crs`) and the transform from the site's CRS to it.
pub(super) fn output_transform(
    l: &Loaded,
    framed: &Framed,
) -> Result<(Option<Crs>, Option<Transform>), RunError> {
    let out_crs = match &l.project.export.crs {
        Some(c) => Some(
            Crs::new(c).map_err(|e| RunError::Input(l.error("export", "crs", e.to_string())))?,
        ),
        None => None,
    };
    let transform = match (&out_crs, &framed.frame.crs) {
        (Some(o), Some(s)) => Some(
            Transform::new(s, o)
                .map_err(|e| RunError::Input(l.error("export", "crs", e.to_string())))?,
        ),
        (Some(_), None) => {
            return Err(RunError::Input(l.error(
                "export",
                "crs",
                "the GCP file has no CRS to convert from",
            )));
        }
        _ => None,
    };
    Ok((out_crs, transform))
}

/// Refuses, naming the project key, an input whose bytes differ from its record in `known` (a
/// split run's inputs: a video replaced after the split would make segments of another video).
/// A file whose size and time are as recorded is taken as unchanged, as everywhere else.
pub fn check_known_inputs(
    l: &Loaded,
    known: &[KnownInput],
    split_dir: &Path,
) -> Result<(), RunError> {
    for (role, path) in l.input_files() {
        let shown = path.display().to_string();
        let Some(k) = known.iter().find(|k| k.path == shown) else {
            continue;
        };
        let (section, key) = role.split_once('.').unwrap_or((role, ""));
        let changed = |how: String| {
            RunError::Input(l.error(
                section,
                key,
                format!(
                    "{shown}: {how} since it was split into {}: the segments would be of another file; split again",
                    split_dir.display()
                ),
            ))
        };
        let now = match size_and_time(&path) {
            Some(now) => now,
            None => return Err(changed("gone".into())),
        };
        if now.0 != k.bytes {
            return Err(changed(format!("{} bytes now, {} then", now.0, k.bytes)));
        }
        if file_record(role, &path, known)?.sha256 != k.sha256 {
            return Err(changed("its content changed".into()));
        }
    }
    Ok(())
}

/// The inputs of `l` hashed now and compared with a finished run's `recorded` ones (`geostride
/// render` draws that run's views: a changed input would make it a new run). Gives the records
/// as known inputs, so that the run does not read the files again.
pub fn check_recorded_inputs(
    l: &Loaded,
    recorded: &[InputRecord],
    run_dir: &Path,
) -> Result<Vec<KnownInput>, RunError> {
    let mut known = Vec::new();
    for (role, path) in l.input_files() {
        let now = file_record(role, &path, &[])?;
        let (section, key) = role.split_once('.').unwrap_or((role, ""));
        // By role and content: the run may have named the file by another path.
        let same = recorded
            .iter()
            .any(|r| r.role == now.role && r.sha256 == now.sha256);
        if !same {
            return Err(RunError::Input(l.error(
                section,
                key,
                format!(
                    "{}: not the file the run in {} read (changed since, or another): render draws that run's views; run the project again (geostride run) for new ones",
                    now.path,
                    run_dir.display()
                ),
            )));
        }
        if let Some((bytes, modified_ns)) = size_and_time(&path) {
            known.push(KnownInput {
                path: now.path,
                bytes,
                modified_ns,
                sha256: now.sha256,
            });
        }
    }
    Ok(known)
}

/// The camera of the project, scaled to the video.
pub(super) fn project_camera(l: &Loaded, width: u32, height: u32) -> Result<Camera, RunError> {
    let spec = &l.project.camera.calibration;
    let cal = match presets::preset(spec) {
        Some(c) => c,
        None => formats::read(&l.resolve(spec), None).map_err(RunError::from_input)?,
    };
    let cam = cal.camera;
    match cam.image_size {
        Some(s) if s.width == width && s.height == height => Ok(cam),
        Some(s) => cam.scaled_to(width, height).ok_or_else(|| {
            RunError::Input(l.error("camera", "calibration", format!("the calibration is for {}x{}, the video is {width}x{height}: another aspect ratio", s.width, s.height)))
        }),
        None => Ok(cam.with_image_size(width, height)),
    }
}

pub(super) fn load_survey(l: &Loaded) -> Result<Framed, RunError> {
    let s = &l.project.survey;
    if s.gcps.is_empty() {
        // A fixed camera without GCPs (the project's check allows no other): its pose's world
        // frame is the site frame.
        return Ok(Framed::without_points("the fixed camera's world frame"));
    }
    let origin = match &s.origin {
        Some(o) => Some(
            o.parse::<Origin>()
                .map_err(|e| RunError::Input(l.error("survey", "origin", e)))?,
        ),
        None => None,
    };
    let opts = LoadOptions {
        read: ReadOptions {
            crs: s.crs.clone(),
            height: s.height.as_deref().map(|h| {
                if h == "ellipsoidal" {
                    HeightChoice::Ellipsoidal
                } else {
                    HeightChoice::Orthometric
                }
            }),
            ..ReadOptions::default()
        },
        picks: s.picks.iter().map(|p| l.resolve(p)).collect(),
        check_prefix: Some(s.check_prefix.clone()),
        check: s.check.clone(),
        disable: Vec::new(),
        origin,
    };
    load_framed(&l.resolve(&s.gcps), &opts).map_err(RunError::from_input)
}

/// The picks of the picked frame: (frame, control, check), checked like `geostride pose` checks
/// them (inside the image, one per point, heights) and the frame inside the video.
pub(super) fn picked(
    l: &Loaded,
    framed: &Framed,
    size: (u32, u32),
    frames: Option<usize>,
) -> Result<(usize, Vec<GcpObservation>, Vec<GcpObservation>), RunError> {
    let s = &l.project.survey;
    let input = |key: &str, m: String| RunError::Input(l.error("survey", key, m));
    let images = framed.picked_images();
    let video_name = Path::new(&l.project.video.path)
        .file_name()
        .map(|f| f.to_string_lossy().into_owned())
        .unwrap_or_default();
    let image = images
        .keys()
        .find(|k| k.starts_with(&format!("{video_name}#")))
        .or_else(|| (images.len() == 1).then(|| images.keys().next()).flatten())
        .cloned()
        .ok_or_else(|| {
            input(
                "picks",
                format!(
                    "no picks of '{video_name}#N' (the frame N of the video); the picks name {:?}",
                    images.keys().take(10).collect::<Vec<_>>()
                ),
            )
        })?;
    let frame = match (
        l.project.pose.picks_frame(),
        crate::io::frame_of_name(&image),
    ) {
        (Some(f), _) => f,
        (None, Some(n)) => n.map_err(|_| {
            input(
                "picks",
                format!(
                    "the picks' image '{}' should end in '#N', N the frame number (from 0)",
                    crate::io::clip(&image, 60)
                ),
            )
        })?,
        (None, None) => 0,
    };
    if let Some(n) = frames
        && frame >= n
    {
        let key = if l.project.pose.picks_frame().is_some() {
            RunError::Input(l.error(
                "pose",
                "picks_frame",
                format!("frame {frame} is beyond the {n} frame(s) processed"),
            ))
        } else {
            input(
                "picks",
                format!("the picks are on frame {frame}, beyond the {n} frame(s) processed"),
            )
        };
        return Err(key);
    }
    let seen = framed
        .observations(&image, s.pick_sigma_px, s.gcp_sigma_m, Some(size))
        .map_err(RunError::from_input)?;
    if seen.control.len() < 4 {
        return Err(input(
            "picks",
            format!(
                "image '{image}' has picks of {} control point(s); a pose needs at least 4",
                seen.control.len()
            ),
        ));
    }
    Ok((frame, seen.control, seen.check))
}

/// What a track's and a frame's checks read: the heights file (`[projection] heights`), and
/// the drone's telemetry with its σ (`[video] telemetry`), read before any work.
pub(super) type HeightsAndTelemetry = (
    BTreeMap<usize, (f64, f64)>,
    Option<super::telemetry_site::Telemetry>,
);

/// [`HeightsAndTelemetry`] of the project.
pub(super) fn read_heights_and_telemetry(
    l: &Loaded,
) -> Result<HeightsAndTelemetry, crate::io::FileError> {
    let p = &l.project;
    let heights = match &p.projection.heights {
        Some(h) => read_heights(&l.resolve(h))?,
        None => BTreeMap::new(),
    };
    let telemetry = match &p.video.telemetry {
        Some(t) => {
            let path = l.resolve(t);
            let text = crate::io::FileCtx { path: &path }
                .read_text("a DJI telemetry subtitle file (.SRT)")?;
            let srt = crate::telemetry::srt::parse_srt(&path, &text)?;
            // The geoid grid checked before any work, not when the poses are compared.
            if p.video.telemetry_height.is_some()
                && let Err(e) = crate::survey::crs::Egm96::new()
            {
                return Err(l.error("video", "telemetry_height", e.message));
            }
            use super::telemetry_site::{AltitudeDatum, Telemetry};
            Some(Telemetry {
                srt,
                sigma_m: p.video.telemetry_sigma_m,
                sigma_vertical_m: p.video.telemetry_sigma_vertical_m,
                // Checked when the project was read.
                datum: match p.video.telemetry_height.as_deref() {
                    Some("ellipsoidal") => Some(AltitudeDatum::Ellipsoidal),
                    Some(_) => Some(AltitudeDatum::Egm96),
                    None => None,
                },
            })
        }
        None => None,
    };
    Ok((heights, telemetry))
}

/// Known head heights from a heights file (`parse_heights`).
pub(super) fn read_heights(
    path: &Path,
) -> Result<BTreeMap<usize, (f64, f64)>, crate::io::FileError> {
    let text = crate::io::FileCtx { path }.read_text("a CSV of heights")?;
    parse_heights(path, &text)
}

/// The most rows of a heights file (tracks of a day of a marathon are fewer).
pub const MAX_HEIGHTS: usize = 1_000_000;

/// Known head heights, `id,height_m[,sd_m]` per line (a header is optional): track id to
/// (height, σ), metres. `path` names the file in messages.
pub fn parse_heights(
    path: &Path,
    text: &str,
) -> Result<BTreeMap<usize, (f64, f64)>, crate::io::FileError> {
    let ctx = crate::io::FileCtx { path };
    let lines = text.lines().count();
    if lines > MAX_HEIGHTS {
        return Err(ctx.err(
            None,
            None,
            format!("{lines} lines: a heights file has at most {MAX_HEIGHTS}, one per track"),
        ));
    }
    // id -> (height, σ, line)
    let mut out: BTreeMap<usize, (f64, f64, usize)> = BTreeMap::new();
    for row in ctx.lines(text) {
        let (line, l) = row?;
        let f: Vec<&str> = l.split(',').map(str::trim).collect();
        if l.trim().is_empty() || (line == 1 && f[0].parse::<f64>().is_err()) {
            continue;
        }
        ctx.field_count(&f, line, 2, 3, "id,height_m[,sd_m]")?;
        let id = ctx.whole(f[0], line, "id")?;
        let h = ctx.number(f[1], line, "height_m")?;
        let sd = match f.get(2).filter(|s| !s.is_empty()) {
            Some(s) => {
                let sd = ctx.number(s, line, "sd_m")?;
                if sd < 0.0 {
                    return Err(ctx.err(
                        Some(line),
                        Some("sd_m"),
                        format!("a σ cannot be negative, found {sd}"),
                    ));
                }
                sd
            }
            None => 0.0,
        };
        if !(h > 0.0 && h < 3.0) {
            return Err(ctx.err(
                Some(line),
                Some("height_m"),
                format!("a head height of {h} m is not plausible (expected 0 to 3 m)"),
            ));
        }
        if let Some((_, _, first)) = out.insert(id as usize, (h, sd, line)) {
            return Err(ctx.at(
                line,
                format!("track {id} has a height on line {first} already; keep one"),
            ));
        }
    }
    Ok(out
        .into_iter()
        .map(|(k, (h, sd, _))| (k, (h, sd)))
        .collect())
}

/// `[picks] auto = true`: the GCP targets of the picked frame found and identified (as
/// `geostride gcp find`: from their layout, coded markers by their ids), added to the survey as its picks. Gives the picks
/// CSV the run writes (`picks-auto.csv`) and a warning naming the control points not found.
pub(super) fn auto_picks(
    l: &Loaded,
    framed: &mut Framed,
    video: &Path,
) -> Result<(String, Option<String>), RunError> {
    use crate::pipeline::project::TargetDesignName;
    use crate::survey::{Observation, Role};
    use crate::targets::codes::{CodeTable, Dictionary};
    use crate::targets::{Gray, LayoutSettings, TargetSettings, search::Search};
    let a = &l.project.picks;
    let frame = l.project.pose.picks_frame().unwrap_or(0);
    let input = |m: String| RunError::Input(l.error("picks", "auto", m));
    let names: Vec<String> = framed
        .survey
        .points
        .iter()
        .map(|p| p.name.clone())
        .collect();
    let coded = if a.designs.contains(&TargetDesignName::Coded) {
        let bad = |key: &str, m: String| RunError::Input(l.error("picks", key, m));
        let d: Dictionary = a.dictionary.parse().map_err(|e| bad("dictionary", e))?;
        let table = match &a.codes {
            Some(c) => CodeTable::read(&l.resolve(c), &names, &d)
                .map_err(|e| bad("codes", e.to_string()))?,
            None => CodeTable::from_names(&names),
        };
        Some((d, table))
    } else {
        None
    };
    let search = Search {
        ground: framed.local.iter().map(|p| p.xy()).collect(),
        names,
        targets: TargetSettings {
            min_contrast: a.min_contrast,
            saddles: a
                .designs
                .iter()
                .any(|d| matches!(d, TargetDesignName::Checker | TargetDesignName::X)),
            crosses: a.designs.contains(&TargetDesignName::Cross),
            ..TargetSettings::default()
        },
        layout: LayoutSettings {
            heading_deg: a.heading_deg.map(|d| (d, a.heading_tolerance_deg)),
            ..LayoutSettings::default()
        },
        by_layout: a.designs.iter().any(|d| *d != TargetDesignName::Coded),
        coded,
    };
    let (bgr, w, h) = crate::video::source::FrameReader::frame_bgr_bytes(video, frame)
        .map_err(|e| RunError::Input(l.error("video", "path", format!("frame {frame}: {e}"))))?;
    let out = search.run(&Gray::from_bgr(&bgr, w, h));
    if out.named.len() == 0 {
        return Err(input(format!(
            "no GCP target identified in frame {frame} of the video ({} found): {}; set \
             heading_deg for a symmetric layout, or pick by hand (`geostride gcp pick`) into \
             survey.picks",
            out.found.len(),
            out.not_identified.as_deref().unwrap_or("none named")
        )));
    }
    let video_name = video
        .file_name()
        .map(|f| f.to_string_lossy().into_owned())
        .unwrap_or_default();
    let image = format!("{video_name}#{frame}");
    let mut csv = String::from("name,image,u,v,sigma\n");
    let named = out.named.iter().filter_map(|&i| {
        let c = &out.found[i];
        Some((c.point?, c))
    });
    for (row, (k, c)) in named.enumerate() {
        let point = &mut framed.survey.points[k];
        csv += &format!(
            "{},{image},{:.3},{:.3},{:.3}\n",
            point.name, c.uv.x, c.uv.y, c.sigma_px
        );
        point.observations.push(Observation {
            image: image.clone(),
            uv: c.uv,
            sigma_px: Some(c.sigma_px),
            file: PathBuf::from("picks-auto.csv"),
            line: row + 2,
        });
    }
    let missed: Vec<&str> = framed
        .survey
        .points
        .iter()
        .filter(|p| p.role == Role::Control && p.observations.iter().all(|o| o.image != image))
        .map(|p| p.name.as_str())
        .collect();
    let warning = (!missed.is_empty()).then(|| {
        format!(
            "automatic picks: {} of frame {frame}'s targets identified; control point(s) {} not \
             found (covered, off the image, or unlike the designs looked for)",
            out.named.len(),
            missed.join(", ")
        )
    });
    Ok((csv, warning))
}
