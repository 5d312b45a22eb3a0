//! `geostride telemetry`: a DJI flight telemetry subtitle file (`.SRT`) read, summarised and
//! written as CSV.

use std::path::PathBuf;

use anyhow::Context;

use super::bad_input;
use geostride::telemetry::srt::{parse_srt, records_csv};

#[derive(clap::Args)]
#[command(after_help = "\
Reads every generation of DJI's telemetry subtitles (docs/formats.md): position, heights above
take-off and absolute, gimbal and aircraft attitude, the camera's settings.

Example: geostride telemetry DJI_0001.SRT --out DJI_0001-telemetry.csv")]
pub struct Args {
    /// The `.SRT` file DJI wrote beside the video
    srt: PathBuf,
    /// CSV of the blocks, one row each (`--out -` prints it)
    #[arg(long, value_name = "CSV")]
    out: Option<PathBuf>,
}

pub fn run(args: Args) -> anyhow::Result<()> {
    if let Some(out) = args.out.as_ref().filter(|o| o.as_os_str() != "-") {
        super::check_output_file(out, [&args.srt])?;
    }
    let text = geostride::io::FileCtx { path: &args.srt }
        .read_text("a DJI telemetry subtitle file (.SRT)")
        .map_err(bad_input)?;
    let file = parse_srt(&args.srt, &text).map_err(bad_input)?;
    let n = file.records.len();
    let (first, last) = (&file.records[0], &file.records[n - 1]);
    let with_fix = file
        .records
        .iter()
        .filter(|r| r.latitude_deg.is_some())
        .count();
    let count = |f: &dyn Fn(&geostride::telemetry::srt::SrtRecord) -> bool| {
        file.records.iter().filter(|r| f(r)).count()
    };
    eprintln!(
        "{}: {n} blocks from {:.3} s to {:.3} s; {with_fix} with a position, {} with a height above take-off, {} with an absolute altitude, {} with the gimbal's attitude, {} with the aircraft's",
        args.srt.display(),
        first.start_s,
        last.end_s,
        count(&|r| r.rel_alt_m.is_some()),
        count(&|r| r.abs_alt_m.is_some()),
        count(&|r| r.gimbal.is_some()),
        count(&|r| r.aircraft.is_some()),
    );
    let csv = records_csv(&file);
    match &args.out {
        Some(out) if out.as_os_str() != "-" => {
            geostride::io::write_atomic(out, csv.as_bytes())
                .with_context(|| format!("cannot write {}", out.display()))?;
            eprintln!("Written: {}", out.display());
        }
        Some(_) => print!("{csv}"),
        None => {}
    }
    Ok(())
}
