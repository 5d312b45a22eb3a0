//! `geostride render RUN_DIR`: a finished run's views again (the annotated video among them),
//! from its own stages: the project it read is run again into the same folder, every stage
//! reused while its inputs are unchanged.

use std::path::PathBuf;

use anyhow::{Context, anyhow};

use super::bad_input;
use geostride::pipeline::project::load;
use geostride::pipeline::run::{RunError, run as run_project};

#[derive(clap::Args)]
pub struct Args {
    /// A run's output folder (with its report.json)
    run_dir: PathBuf,
    /// The annotated video's largest width, pixels [default: the project's, 1920]
    #[arg(long, value_name = "PX")]
    video_width: Option<u32>,
    /// Plots and site image only, no annotated video
    #[arg(long)]
    no_video: bool,
    /// No progress bars
    #[arg(short, long)]
    quiet: bool,
}

pub fn run(args: Args) -> anyhow::Result<()> {
    let report_path = args.run_dir.join("report.json");
    // A run's report is kilobytes to a few megabytes (its warnings).
    let text = geostride::io::FileCtx { path: &report_path }
        .read_small_text("a geostride run report", 64 << 20)
        .with_context(|| {
            format!(
                "{}: give the output folder of a geostride run",
                report_path.display()
            )
        })
        .map_err(bad_input)?;
    let report: serde_json::Value = serde_json::from_str(&text)
        .with_context(|| format!("{}: not a geostride run report", report_path.display()))
        .map_err(bad_input)?;
    let project_file = report
        .get("project_file")
        .and_then(|p| p.as_str())
        .unwrap_or_default();
    if project_file.is_empty() {
        return Err(bad_input(anyhow!(
            "{}: the report does not name its project file (a run by an older geostride): run the project again",
            report_path.display()
        )));
    }
    let mut loaded = load(std::path::Path::new(project_file)).map_err(bad_input)?;
    // The run as it was: its settings and inputs unchanged, or this would be a new run (hours,
    // and the run's files replaced) under the name of drawing its views.
    let recorded: Vec<geostride::pipeline::run::InputRecord> = report
        .get("inputs")
        .cloned()
        .and_then(|v| serde_json::from_value(v).ok())
        .ok_or_else(|| {
            bad_input(anyhow!(
                "{}: the report lists no inputs (a run by an older geostride): run the project again",
                report_path.display()
            ))
        })?;
    // The settings as the run recorded them, [output] aside (what render changes).
    let now = serde_json::to_value(&loaded.project)?;
    let strip = |v: &serde_json::Value| {
        let mut v = v.clone();
        if let Some(o) = v.as_object_mut() {
            o.remove("output");
        }
        v
    };
    if report.get("parameters").map(strip) != Some(strip(&now)) {
        return Err(bad_input(anyhow!(
            "{project_file}: its settings changed since the run in {} (beyond [output]): render draws that run's views; run the project again (geostride run) for new ones",
            args.run_dir.display()
        )));
    }
    loaded.known_inputs =
        geostride::pipeline::run::check_recorded_inputs(&loaded, &recorded, &args.run_dir)
            .map_err(|e| bad_input(anyhow!(e)))?;
    let o = &mut loaded.project.output;
    o.plots = true;
    o.site_image = true;
    o.video = !args.no_video;
    if let Some(w) = args.video_width {
        if !(160..=7680).contains(&w) {
            return Err(bad_input(anyhow!(
                "--video-width: expected 160 to 7680 pixels, got {w}"
            )));
        }
        o.video_width = w;
    }
    let report = run_project(
        &loaded,
        &args.run_dir,
        &super::StageBars { quiet: args.quiet },
    )
    .map_err(|e: RunError| {
        if e.is_input() {
            bad_input(anyhow!(e))
        } else {
            anyhow!(e)
        }
    })?;
    super::run::print_stages(&report);
    for (title, file) in &report.views {
        println!("{title}: {}", args.run_dir.join(file).display());
    }
    Ok(())
}
