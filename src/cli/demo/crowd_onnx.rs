//! `geostride demo --crowd` (`--detector onnx`, the crowd's main run): the crowd without hats
//! (`surveys/marathon-stream`) with the default neural detector (geostride's overhead model,
//! `models/overhead-person.onnx`) on the rendered video, checked against the same targets as
//! the simulated boxes of `--detector simulated` (issue 38).

use super::*;
use geostride::pipeline::settings::OnnxSection;

#[derive(Serialize)]
struct OnnxCrowdReport {
    /// The detector's settings as run (with the fitted error model).
    detector: OnnxSection,
    /// The detector's error model fitted to the annotated frames.
    error_fit: geostride::detect::error_fit::ErrorFit,
    /// With the fitted error model (`run-onnx/`, `accuracy-onnx.csv`).
    evaluation: Evaluation,
    uncertainty: Consistency,
    /// With the paper's error model (`run-onnx-paper-model/`).
    paper_model: Evaluation,
    paper_model_uncertainty: Consistency,
    brief_people_not_counted: usize,
    detections: f64,
    seconds: f64,
    passed: bool,
}

pub(super) fn run_crowd_onnx(args: Args) -> anyhow::Result<()> {
    let started = std::time::Instant::now();
    let json = args.json;
    let (scene, scene_path, dir) = demo_scene(&args, "surveys/marathon-stream")?;
    simulate_step(
        &args,
        "geostride demo --crowd (the overhead model)",
        &scene,
        &scene_path,
        &dir,
    )?;
    // The default model for a view from above (geostride's own), at its own scale from the
    // pose: whole frames.
    let detector = OnnxSection::default();
    let mut project = crowd_project(&scene, &scene.camera.calibration, "unused.txt", &[])
        .map(|p| with_auto_picks(p, &scene))
        .map_err(|e| anyhow!("{}: {e}", scene_path.display()))?;
    project.detect = DetectSection::Onnx(detector.clone());
    let (mut truth, mut ignored) = truth_samples(&dir.join("truth/heads.csv"))?;
    let min_frames = (project.track.min_length_s() * scene.fps).round() as usize;
    let brief = ignore_brief(&mut truth, &mut ignored, min_frames);
    let (report, pe, pcons) = DemoRun {
        dir: &dir,
        file: "project-onnx-paper-model.toml",
        what: "The crowd, detected by geostride's overhead model (ONNX Runtime) at its own scale; the paper's error model.",
        step: "2. With the overhead neural detector and the paper's error model: ",
        out: "run-onnx-paper-model",
        accuracy: "accuracy-onnx-paper-model.csv",
    }
    .run(&args, &project, &truth, &ignored)?;
    let detections = scan_detections(&report);
    // This detector's own error model, from heads marked in a few frames, as for the boxes.
    let error_fit = fit_detector_error(json, &scene, &dir, &dir.join("run-onnx-paper-model"))?;
    let mut fitted = detector.clone();
    (fitted.error_px2, fitted.error_profile_px2) = error_fit.setting();
    project.detect = DetectSection::Onnx(fitted.clone());
    let (_, e, cons) = DemoRun {
        dir: &dir,
        file: "project-onnx.toml",
        what: "The crowd, detected by geostride's overhead model (ONNX Runtime) at its own scale, with its error model fitted by geostride fit-error.",
        step: "4. With the fitted error model: ",
        out: "run-onnx",
        accuracy: "accuracy-onnx.csv",
    }
    .run(&args, &project, &truth, &ignored)?;
    say!(
        json,
        "\n5. Against the truth ({} people in view for ≥ {min_frames} frames, {brief} briefer not counted; {detections:.0} detections kept; matches within 0.5 m):",
        e.truth_tracks
    );
    print_crowd_table(json, (&pe, &pcons), (&e, &cons));
    coverage_scope_note(json, &args, &scene);
    say!(
        json,
        "   geostride's overhead model on the rendered video (trained on other simulated tiles), checked against the simulated boxes' targets with its fitted error model."
    );
    // The people's heads are the model's own head points (`[detect] head`), not the boxes'.
    let from_model = report
        .stages
        .iter()
        .find(|s| s.name == "scan")
        .and_then(|s| s.counts.get("heads_from_model"))
        .copied()
        .unwrap_or(0.0);
    let mut checks = crowd_checks(&args, &scene, &e, &cons).to_vec();
    checks.push((
        from_model >= 0.9 * detections,
        format!("the heads from the model's head points ({from_model:.0} for {detections:.0} detections)"),
    ));
    let failed: Vec<&String> = checks.iter().filter(|c| !c.0).map(|c| &c.1).collect();
    let out = OnnxCrowdReport {
        detector: fitted,
        error_fit,
        evaluation: e,
        uncertainty: cons,
        paper_model: pe,
        paper_model_uncertainty: pcons,
        brief_people_not_counted: brief,
        detections,
        seconds: started.elapsed().as_secs_f64(),
        passed: failed.is_empty(),
    };
    finish(
        "crowd demo with the onnx detector",
        json,
        &dir,
        &out,
        &failed,
        out.seconds,
    )
}
