//! `geostride demo --group`: the moving camera end to end (the paper's group events). It
//! simulates `surveys/track-group` (a survey flight's photos with RTK centres and GCP picks,
//! then the video of a drone following 16 runners with magenta hats), calibrates the camera
//! from the checkerboards, builds the reference model with `geostride sfm`, runs the project
//! (every frame placed in the model, local ground planes, colour detection, association
//! tracking, projection, smoothing) with the default head height and with every runner's
//! height known, and compares everything with the truth.

use std::collections::BTreeMap;

use super::*;

/// The "must show".
const RMSE_KNOWN_M: f64 = 0.05;
const RMSE_DEFAULT_M: f64 = 0.10;
const CENTRE_M: f64 = 0.05;
const GCP_MEAN_PX: f64 = 0.9;

#[derive(Serialize)]
struct ModelCheck {
    photos: usize,
    registered: usize,
    points: usize,
    mean_reprojection_px: f64,
    /// Mean distance of the GCP picks from the projections of the adjusted GCPs (the paper's
    /// 0.9 px).
    gcp_mean_px: f64,
    /// Control points against the survey, and camera centres against the RTK ones: RMS
    /// horizontal, vertical (m).
    control_rms_m: [f64; 2],
    centres_rms_m: [f64; 2],
}

#[derive(Serialize)]
struct FramesCheck {
    frames: usize,
    /// Frames with a pose measured (not interpolated).
    measured: usize,
    interpolated: usize,
    key_frames: usize,
    /// Camera centre and attitude against the truth: mean and worst, metres and degrees.
    mean_centre_m: f64,
    worst_centre_m: f64,
    worst_attitude_deg: f64,
}

#[derive(Serialize)]
struct GroupReport {
    rmse_m: f64,
    rmse_known_heights_m: f64,
    calibration: CalibrationCheck,
    model: ModelCheck,
    pose: FramesCheck,
    /// Runners matched in every frame they are in view, of those in view.
    runners_every_frame: usize,
    runners: usize,
    default_height: Evaluation,
    known_heights: Evaluation,
    default_height_uncertainty: Consistency,
    known_heights_uncertainty: Consistency,
    /// The run again with no survey flight (the model from the video's frames).
    no_survey_flight: VideoModelCheck,
    seconds: f64,
    passed: bool,
}

/// The run with no survey flight: the model the run built from the video and the GCP picks on
/// its frames, every frame placed in it, the 1.7 m default height.
#[derive(Serialize)]
struct VideoModelCheck {
    /// Frames in the model, registered.
    model_frames: usize,
    model_registered: usize,
    /// The check points' and the control points' RMS from the survey, horizontal and vertical
    /// (m), as the model's georeferencing reports them.
    control_rms_m: [f64; 2],
    check_rms_m: [f64; 2],
    pose: FramesCheck,
    evaluation: Evaluation,
    uncertainty: Consistency,
}

/// Step 6: the default-height run with no survey flight, in `DIR/run-video`.
fn video_model_run(
    args: &Args,
    scene: &Scene,
    scene_path: &Path,
    dir: &Path,
    (truth, ignored): (&[Sample], &[Sample]),
) -> anyhow::Result<VideoModelCheck> {
    let project = geostride::simulate::project::group_video_project(scene, "camera.yaml")
        .map_err(|e| anyhow!("{}: {e}", scene_path.display()))?;
    let (report, evaluation, uncertainty) = DemoRun {
        dir,
        file: "project-video.toml",
        what: "Group with no survey flight: the reference model built by the run from the video's own frames (one a second) and the GCP picks on every second's frame (picks-frames.csv), every frame placed in it, its local planes the ground.",
        step: "6. With no survey flight (the model from the video's frames): ",
        out: "run-video",
        accuracy: "accuracy-video.csv",
    }
    .run(args, &project, truth, ignored)?;
    let pose = frames_check_in(dir, "run-video", &report)?;
    let model: serde_json::Value = serde_json::from_slice(
        &std::fs::read(dir.join("run-video/model/report.json"))
            .map_err(|e| anyhow!("{}: {e}", dir.join("run-video/model/report.json").display()))?,
    )?;
    let rms = |k: &str| {
        let r = &model["georef"][k];
        [
            r["horizontal_m"].as_f64().unwrap_or(f64::NAN),
            r["vertical_m"].as_f64().unwrap_or(f64::NAN),
        ]
    };
    let check = VideoModelCheck {
        model_frames: model["images"].as_u64().unwrap_or(0) as usize,
        model_registered: model["registered"].as_u64().unwrap_or(0) as usize,
        control_rms_m: rms("control_rms"),
        check_rms_m: rms("check_rms"),
        pose,
        evaluation,
        uncertainty,
    };
    say!(
        args.json,
        "   model: {} of {} frames registered, control points {:.3}/{:.3} m (horizontal/vertical) from the survey; {} of {} frames placed from their own features, centres {:.3} m from the truth on average; horizontal RMSE {:.4} m (1.7 m default)",
        check.model_registered,
        check.model_frames,
        check.control_rms_m[0],
        check.control_rms_m[1],
        check.pose.measured,
        check.pose.frames,
        check.pose.mean_centre_m,
        check.evaluation.rmse_m
    );
    Ok(check)
}

/// The targets for the run with no survey flight.
fn video_model_checks(v: &VideoModelCheck, frames: usize) -> [(bool, String); 2] {
    [
        (
            v.evaluation.rmse_m <= RMSE_DEFAULT_M,
            format!(
                "with no survey flight: horizontal RMSE ≤ {RMSE_DEFAULT_M} m with the 1.7 m default"
            ),
        ),
        (
            v.pose.measured == frames && v.pose.frames == frames,
            "with no survey flight: every frame posed from its own features".to_string(),
        ),
    ]
}

/// Runners whose every in-view frame has a match.
fn runners_every_frame(truth: &[Sample], matches: &[(Sample, Sample)]) -> (usize, usize) {
    let mut frames: BTreeMap<usize, usize> = BTreeMap::new();
    for t in truth {
        *frames.entry(t.id).or_default() += 1;
    }
    let mut matched: BTreeMap<usize, usize> = BTreeMap::new();
    for (t, _) in matches {
        *matched.entry(t.id).or_default() += 1;
    }
    let full = frames
        .iter()
        .filter(|(id, n)| matched.get(id) == Some(n))
        .count();
    (full, frames.len())
}

/// Runners of `truth` matched in every in-view frame by `DIR/run/trajectories.csv`, and how many
/// runners were in view.
fn runners_tracked_throughout(
    dir: &Path,
    truth: &[Sample],
    ignored: &[Sample],
) -> anyhow::Result<(usize, usize)> {
    let tracks = track_samples(&dir.join("run/trajectories.csv"))?;
    let (_, matches) = evaluate_matches(truth, &tracks, ignored, 0.5);
    Ok(runners_every_frame(truth, &matches))
}

/// The group demo's scene: any camera, but a survey flight to build the reference model from.
fn group_scene(args: &Args) -> anyhow::Result<(Scene, PathBuf, PathBuf)> {
    let (scene, scene_path, dir) = any_scene(args, "surveys/track-group")?;
    if scene.survey_flight.is_none() {
        return Err(super::super::bad_input(anyhow!(
            "{}: the group demo needs a [survey_flight] (the photos its reference model is built from)",
            scene_path.display()
        )));
    }
    Ok((scene, scene_path, dir))
}

/// The run's camera against the truth, frame by frame.
fn frames_check(dir: &Path, report: &RunReport) -> anyhow::Result<FramesCheck> {
    frames_check_in(dir, "run", report)
}

/// [`frames_check`] of the run in `DIR/out`.
fn frames_check_in(dir: &Path, out: &str, report: &RunReport) -> anyhow::Result<FramesCheck> {
    let truth = read_poses(&dir.join("truth/camera.csv")).map_err(|e| anyhow!(e))?;
    let est = read_poses(&dir.join(out).join("pose/poses.csv")).map_err(|e| anyhow!(e))?;
    let (mut sum, mut worst, mut worst_deg) = (0.0, 0.0f64, 0.0f64);
    for ((_, t), (_, e)) in truth.iter().zip(&est) {
        let d = (t.centre() - e.centre()).norm();
        sum += d;
        worst = worst.max(d);
        worst_deg = worst_deg.max(
            geostride::geom::so3::log(&(t.rotation * e.rotation.inverse()))
                .norm()
                .to_degrees(),
        );
    }
    let count = |k: &str| {
        report
            .stages
            .iter()
            .find(|s| s.name == "pose")
            .and_then(|s| s.counts.get(k))
            .copied()
            .unwrap_or(0.0) as usize
    };
    let interpolated = count("interpolated_frames");
    Ok(FramesCheck {
        frames: est.len(),
        measured: est.len() - interpolated,
        interpolated,
        key_frames: count("key_frames"),
        mean_centre_m: sum / est.len().max(1) as f64,
        worst_centre_m: worst,
        worst_attitude_deg: worst_deg,
    })
}

/// Step 3: the reference model built from the survey flight as `geostride sfm` does, in
/// `DIR/model`, and its check.
fn build_model(json: bool, dir: &Path) -> anyhow::Result<ModelCheck> {
    let words: Vec<String> = [
        "survey/photos",
        "--camera",
        "camera.yaml",
        "--gcps",
        "gcps.csv",
        "--picks",
        "survey/picks.csv",
        "--centres",
        "survey/centres.csv",
        "--max-features",
        "4096",
        "--out",
        "model",
    ]
    .iter()
    .map(|w| w.to_string())
    .collect();
    say!(
        json,
        "\n3. $ (cd {}; geostride sfm {})",
        dir.display(),
        words.join(" ")
    );
    let in_dir: Vec<String> = words
        .iter()
        .enumerate()
        .map(|(k, w)| {
            // Paths are the words not following a value-taking option's number.
            if k == 0
                || (k > 0 && words[k - 1].starts_with("--") && words[k - 1] != "--max-features")
            {
                dir.join(w).display().to_string()
            } else {
                w.clone()
            }
        })
        .chain(["--quiet".to_string()])
        .collect();
    let built = super::super::sfm::build(&super::super::sfm::args_from(in_dir)?)?;
    let r = &built.run.report;
    let g = r
        .georef
        .as_ref()
        .ok_or_else(|| anyhow!("the model was not georeferenced"))?;
    let pair = |x: &Option<geostride::sfm::georef::Rms>| {
        x.as_ref()
            .map_or([f64::NAN; 2], |x| [x.horizontal_m, x.vertical_m])
    };
    let model = ModelCheck {
        photos: r.images,
        registered: r.registered,
        points: r.points,
        mean_reprojection_px: r.mean_reprojection_px,
        gcp_mean_px: g.control_mean_px.unwrap_or(f64::NAN),
        control_rms_m: pair(&g.control_rms),
        centres_rms_m: pair(&g.centres_rms),
    };
    say!(
        json,
        "   {} of {} photos, {} points, {:.3} px; GCPs {:.3}/{:.3} m (horizontal/vertical) from the survey, picks {:.2} px from them; camera centres {:.3}/{:.3} m from the RTK ones",
        model.registered,
        model.photos,
        model.points,
        model.mean_reprojection_px,
        model.control_rms_m[0],
        model.control_rms_m[1],
        model.gcp_mean_px,
        model.centres_rms_m[0],
        model.centres_rms_m[1]
    );
    Ok(model)
}

/// The rows under the accuracy table: the camera's poses, the model's GCPs, the calibration.
fn camera_rows(pose: &FramesCheck, model: &ModelCheck, calibration: &CalibrationCheck) -> [Row; 5] {
    let centre_m = [pose.mean_centre_m, pose.worst_centre_m].map(|v| format!("{v:.4} m"));
    [
        Row::new(
            "frames posed (measured / interpolated)",
            [
                format!("{} / {}", pose.measured, pose.interpolated),
                format!("{} key", pose.key_frames),
            ],
            "all / 0",
        ),
        Row::new(
            "camera centre vs truth (mean / worst)",
            centre_m,
            "≤ 0.05 m",
        ),
        Row::one(
            "camera attitude vs truth (worst)",
            format!("{:.4}°", pose.worst_attitude_deg),
            "",
        ),
        Row::one(
            "GCP picks vs model GCPs (mean)",
            format!("{:.3} px", model.gcp_mean_px),
            "≤ 0.9 px",
        ),
        Row::calibration(calibration, ""),
    ]
}

/// The group demo's targets: `rmse` (heights known, default), every one of `frames` posed,
/// the centres, the GCP picks, `(full, runners, count)` runners tracked throughout, no ID
/// switch in either of `evals`.
fn group_checks(
    rmse: [(bool, String); 2],
    pose: &FramesCheck,
    frames: usize,
    model: &ModelCheck,
    (full, runners, count): (usize, usize, usize),
    evals: [&Evaluation; 2],
) -> Vec<(bool, String)> {
    let [known, default] = rmse;
    vec![
        known,
        default,
        (
            pose.measured == frames && pose.frames == frames,
            "every frame posed from its own features".to_string(),
        ),
        (
            pose.worst_centre_m <= CENTRE_M,
            format!("every camera centre within {CENTRE_M} m of the truth"),
        ),
        (
            model.gcp_mean_px <= GCP_MEAN_PX,
            format!("GCP picks within {GCP_MEAN_PX} px of the model's GCPs on average"),
        ),
        (
            full == runners && runners == count,
            format!(
                "all {} runners tracked over every frame they are in view",
                count
            ),
        ),
        (
            evals.iter().all(|e| e.id_switches == 0),
            "no ID switch".to_string(),
        ),
    ]
}

pub(super) fn run_group(args: Args) -> anyhow::Result<()> {
    let started = std::time::Instant::now();
    let json = args.json;
    let (scene, scene_path, dir) = group_scene(&args)?;

    // 1. Simulate.
    let sim = simulate_step(&args, "geostride demo --group", &scene, &scene_path, &dir)?;
    say!(
        json,
        "   survey flight in {}",
        dir.join("survey/photos").display()
    );

    // 2. The camera from the checkerboards (the video's mode; the photos' is the same sensor).
    let (calibration, _) = calibrate_scene(&args, &scene, &scene_path, &dir, sim.image_size)?;

    // 3. The reference model from the survey flight.
    let model = build_model(json, &dir)?;

    // 4. The run with the default head height, then 5. with every runner's height known.
    let runs = height_runs(
        &args,
        &dir,
        &|heights| {
            group_project(&scene, "camera.yaml", "model", "survey/photos", heights)
                .map_err(|e| anyhow!("{}: {e}", scene_path.display()))
        },
        [
            (
                "Group: every frame placed in the reference model (model/, from survey/photos), local ground planes, hats.",
                "4. ",
            ),
            (
                "Group, with every runner's height known (heights.csv, by track id).",
                "5. With every runner's height known: ",
            ),
        ],
    )?;
    let [known_eval, default_eval] = runs.evals;
    let [known_cons, default_cons] = runs.cons;
    let (report, truth, ignored) = (runs.report, runs.truth, runs.ignored);
    let pose = frames_check(&dir, &report)?;
    let (full, runners) = runners_tracked_throughout(&dir, &truth, &ignored)?;

    // 6. No survey flight: the model from the video's own frames and the GCP picks on them.
    let video_model = video_model_run(&args, &scene, &scene_path, &dir, (&truth, &ignored))?;

    // 7. The accuracy table.
    let [known_check, default_check] =
        rmse_checks(&known_eval, &default_eval, [RMSE_KNOWN_M, RMSE_DEFAULT_M]);
    let checks = group_checks(
        [known_check, default_check],
        &pose,
        sim.frames,
        &model,
        (full, runners, scene.people.count as usize),
        [&known_eval, &default_eval],
    );
    say!(
        json,
        "\n7. Accuracy against the truth ({} runners, {} frames; matches within 0.5 m):",
        default_eval.truth_tracks,
        pose.frames
    );
    let both = |f: &dyn Fn(&Evaluation) -> String| [f(&known_eval), f(&default_eval)];
    let mut rows = error_rows(&known_eval, &default_eval, "0.05 / 0.10 m");
    rows.extend([
        Row::new(
            "runners tracked over every frame",
            [format!("{full} of {runners}"), String::new()],
            "all",
        ),
        Row::new("ID switches", both(&|e| format!("{}", e.id_switches)), "0"),
        mota_row(&known_eval, &default_eval),
    ]);
    rows.extend(uncertainty_rows(&known_cons, &default_cons));
    let after = camera_rows(&pose, &model, &calibration);
    let head = ["heights known", "1.7 m default", "target"];
    print_table(json, (40, 12), head, &rows);
    print_table(json, (40, 12), ["", "", ""], &after);
    say!(
        json,
        "   The camera over time (the paper's Fig. 10): {}",
        dir.join("run/pose/pose_series.csv").display()
    );
    let checks: Vec<(bool, String)> = checks
        .into_iter()
        .chain(video_model_checks(&video_model, sim.frames))
        .collect();
    let failed: Vec<&String> = checks.iter().filter(|c| !c.0).map(|c| &c.1).collect();
    let report = GroupReport {
        rmse_m: default_eval.rmse_m,
        rmse_known_heights_m: known_eval.rmse_m,
        calibration,
        model,
        pose,
        runners_every_frame: full,
        runners,
        default_height: default_eval,
        known_heights: known_eval,
        default_height_uncertainty: default_cons,
        known_heights_uncertainty: known_cons,
        no_survey_flight: video_model,
        seconds: started.elapsed().as_secs_f64(),
        passed: failed.is_empty(),
    };
    finish("group demo", json, &dir, &report, &failed, report.seconds)
}

#[derive(Serialize)]
struct GroupOnnxReport {
    rmse_m: f64,
    calibration: CalibrationCheck,
    /// The detector's settings as run.
    detector: geostride::pipeline::settings::OnnxSection,
    detections: f64,
    model: ModelCheck,
    pose: FramesCheck,
    runners_every_frame: usize,
    runners: usize,
    evaluation: Evaluation,
    uncertainty: Consistency,
    seconds: f64,
    passed: bool,
}

/// `geostride demo --group --detector onnx`: the same scene with the runners WITHOUT hats,
/// found by the default neural detector (geostride's overhead model) in every frame, tracked by
/// `klt`, with the 1.7 m default height. Checked: horizontal RMSE ≤ 0.10 m; the rest reported.
pub(super) fn run_group_onnx(args: Args) -> anyhow::Result<()> {
    use geostride::pipeline::settings::{OnnxSection, TrackSection};
    let started = std::time::Instant::now();
    let json = args.json;
    let (scene, scene_path, dir) = group_scene(&args)?;
    // Beside the hat demo's folder, not over it.
    let dir = dir.with_file_name(format!(
        "{}-onnx",
        dir.file_name().unwrap_or_default().to_string_lossy()
    ));
    let sim = simulate_step(
        &args,
        "geostride demo --group --detector onnx (the runners without hats)",
        &scene,
        &scene_path,
        &dir,
    )?;
    let (calibration, _) = calibrate_scene(&args, &scene, &scene_path, &dir, sim.image_size)?;
    let model = build_model(json, &dir)?;
    let detector = OnnxSection::default();
    let mut project = group_project(&scene, "camera.yaml", "model", "survey/photos", None)
        .map_err(|e| anyhow!("{}: {e}", scene_path.display()))?;
    project.detect = DetectSection::Onnx(detector.clone());
    project.track = TrackSection::Klt(Default::default());
    let (truth, ignored) = truth_samples(&dir.join("truth/heads.csv"))?;
    let (report, e, cons) = DemoRun {
        dir: &dir,
        file: "project.toml",
        what: "Group without hats: every frame placed in the reference model, local ground planes, geostride's overhead model (ONNX Runtime) at its own scale, KLT tracking.",
        step: "4. ",
        out: "run",
        accuracy: "accuracy-default.csv",
    }
    .run(&args, &project, &truth, &ignored)?;
    let detections = scan_detections(&report);
    let pose = frames_check(&dir, &report)?;
    let (full, runners) = runners_tracked_throughout(&dir, &truth, &ignored)?;
    say!(
        json,
        "\n5. Against the truth ({} runners, {} frames; {detections:.0} detections kept; matches within 0.5 m):",
        e.truth_tracks,
        pose.frames
    );
    let one = |label: &'static str, v: String, target: &'static str| Row::one(label, v, target);
    let rows = vec![
        one("horizontal RMSE", format!("{:.3} m", e.rmse_m), "≤ 0.10 m"),
        Row::new(
            "95th percentile / largest error",
            [
                format!("{:.3} m", e.p95_error_m),
                format!("{:.3} m", e.max_error_m),
            ],
            "",
        ),
        one(
            "runners tracked over every frame",
            format!("{full} of {runners}"),
            "",
        ),
        one(
            "tracked over ≥ 90 % of their frames",
            format!("{} of {}", e.tracked_90, e.truth_tracks),
            "",
        ),
        one("ID switches", format!("{}", e.id_switches), ""),
        Row::new(
            "misses / false positives (positions)",
            [format!("{}", e.misses), format!("{}", e.false_positives)],
            "",
        ),
        one("estimated tracks", format!("{}", e.estimated_tracks), ""),
        one(
            "95 % ellipses holding the truth",
            format!("{:.1} %", 100.0 * cons.inside_95),
            "",
        ),
    ];
    print_table(json, (40, 10), ["1.7 m default", "", "target"], &rows);
    let checks = [(
        e.rmse_m <= RMSE_DEFAULT_M,
        format!("horizontal RMSE ≤ {RMSE_DEFAULT_M} m with the 1.7 m default"),
    )];
    say!(
        json,
        "   Camera: {:.3} px calibration RMS; centres {:.4} m from the truth on average",
        calibration.rms_px,
        pose.mean_centre_m
    );
    let failed: Vec<&String> = checks.iter().filter(|c| !c.0).map(|c| &c.1).collect();
    let out = GroupOnnxReport {
        rmse_m: e.rmse_m,
        calibration,
        detector,
        detections,
        model,
        pose,
        runners_every_frame: full,
        runners,
        evaluation: e,
        uncertainty: cons,
        seconds: started.elapsed().as_secs_f64(),
        passed: failed.is_empty(),
    };
    finish(
        "group demo without hats",
        json,
        &dir,
        &out,
        &failed,
        out.seconds,
    )
}
