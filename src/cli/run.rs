//! `geostride run PROJECT.toml`: the whole job, from a video to trajectories.

use std::path::PathBuf;

use anyhow::anyhow;

use super::bad_input;
use geostride::pipeline::project::load;
use geostride::pipeline::run::{RunError, run as run_project};

#[derive(clap::Args)]
pub struct Args {
    /// The project file (TOML): camera, GCPs and picks, video, ground, stages, outputs
    project: PathBuf,
    /// Output folder [default: 'out' beside the project file]
    #[arg(long, value_name = "DIR")]
    out: Option<PathBuf>,
    /// No progress bars
    #[arg(short, long)]
    quiet: bool,
}

pub fn run(args: Args) -> anyhow::Result<()> {
    let loaded = load(&args.project).map_err(bad_input)?;
    let out = args.out.clone().unwrap_or_else(|| loaded.resolve("out"));
    let report = run_project(&loaded, &out, &super::StageBars { quiet: args.quiet }).map_err(
        |e: RunError| {
            if e.is_input() {
                bad_input(anyhow!(e))
            } else {
                anyhow!(e)
            }
        },
    )?;
    println!("Project: {} -> {}", report.project, out.display());
    println!(
        "  site frame: {}; output CRS: {}",
        report.site_frame, report.output_crs
    );
    print_stages(&report);
    for o in report
        .outputs
        .iter()
        .chain(["report.json".to_string(), "report.md".to_string()].iter())
    {
        println!("Written: {}", out.join(o).display());
    }
    Ok(())
}

/// The report's stages as a table, and its warnings on stderr.
pub(crate) fn print_stages(report: &geostride::pipeline::run::RunReport) {
    println!("{:<8} {:<13} {:>8}  numbers", "stage", "status", "seconds");
    for s in &report.stages {
        println!(
            "{:<8} {:<13} {:>8.2}  {}",
            s.name,
            s.status,
            s.seconds,
            s.numbers(3)
        );
    }
    for w in &report.warnings {
        eprintln!("warning: {w}");
    }
}
