//! `geostride demo --crowd --detector onnx`: the crowd without hats (`surveys/marathon-stream`)
//! with the default neural detector (geostride's overhead model, `models/overhead-person.onnx`)
//! on the rendered video instead of boxes simulated from the truth. Reported as it is, beside
//! the simulated boxes' targets.

use super::*;
use geostride::pipeline::settings::OnnxSection;

#[derive(Serialize)]
struct OnnxCrowdReport {
    /// The detector's settings as run.
    detector: OnnxSection,
    evaluation: Evaluation,
    uncertainty: Consistency,
    brief_people_not_counted: usize,
    detections: f64,
    seconds: f64,
}

pub(super) fn run_crowd_onnx(args: Args) -> anyhow::Result<()> {
    let started = std::time::Instant::now();
    let json = args.json;
    let (scene, scene_path, dir) = demo_scene(&args, "surveys/marathon-stream")?;
    simulate_step(
        &args,
        "geostride demo --crowd --detector onnx",
        &scene,
        &scene_path,
        &dir,
    )?;
    // The default model for a view from above (geostride's own), at its own scale from the
    // pose: whole frames.
    let detector = OnnxSection::default();
    let mut project = crowd_project(&scene, &scene.camera.calibration, "unused.txt", &[])
        .map_err(|e| anyhow!("{}: {e}", scene_path.display()))?;
    project.detect = DetectSection::Onnx(detector.clone());
    let (mut truth, mut ignored) = truth_samples(&dir.join("truth/heads.csv"))?;
    let min_frames = (project.track.min_length_s() * scene.fps).round() as usize;
    let brief = ignore_brief(&mut truth, &mut ignored, min_frames);
    let (report, e, cons) = DemoRun {
        dir: &dir,
        file: "project-onnx.toml",
        what: "The crowd, detected by geostride's overhead model (ONNX Runtime) at its own scale.",
        step: "2. With the overhead neural detector: ",
        out: "run-onnx",
        accuracy: "accuracy-onnx.csv",
    }
    .run(&args, &project, &truth, &ignored)?;
    let detections = report
        .stages
        .iter()
        .find(|s| s.name == "scan")
        .and_then(|s| s.counts.get("detections"))
        .copied()
        .unwrap_or(0.0);
    say!(
        json,
        "\n3. Against the truth ({} people in view for ≥ {min_frames} frames, {brief} briefer not counted; matches within 0.5 m):",
        e.truth_tracks
    );
    let rows = [
        Row::new(
            "detections kept",
            [format!("{detections:.0}"), String::new()],
            "",
        ),
        Row::new(
            "people tracked over ≥ 80 % of their time",
            [
                format!("{} of {}", e.mostly_tracked, e.truth_tracks),
                String::new(),
            ],
            "",
        ),
        Row::new(
            "horizontal RMSE of the matches",
            [
                format!("{:.4} m", e.rmse_m),
                format!("{} matches", e.matches),
            ],
            "",
        ),
        Row::new(
            "misses / false positives",
            [format!("{}", e.misses), format!("{}", e.false_positives)],
            "",
        ),
        mota_row(&e, &e),
    ];
    print_table(json, (44, 12), ["", "", ""], &rows);
    say!(
        json,
        "   Reported as it is, not checked: geostride's overhead model on the rendered video (trained on other simulated tiles); the error model is the boxes' default, not fitted to this detector."
    );
    let out = OnnxCrowdReport {
        detector,
        evaluation: e,
        uncertainty: cons,
        brief_people_not_counted: brief,
        detections,
        seconds: started.elapsed().as_secs_f64(),
    };
    finish(
        "crowd demo with the onnx detector (reported)",
        json,
        &dir,
        &out,
        &[],
        out.seconds,
    )
}
