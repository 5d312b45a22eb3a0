//! `geostride fit-error`: a detector's error model (`detect.error_px2` or
//! `detect.error_profile_px2`) from annotated heads.

use std::path::{Path, PathBuf};

use anyhow::anyhow;

use super::bad_input;
use geostride::detect::error_fit::{
    ErrorFit, Form, MAX_ANNOTATIONS, Pairing, fit_error_model, pair_annotations, read_box_feet,
    read_frame_points,
};

#[derive(clap::Args)]
pub struct Args {
    /// The detections of a run: its detections.csv (export format `detections`)
    #[arg(long, value_name = "CSV")]
    pub detections: PathBuf,
    /// Heads marked by hand in some frames: CSV with a header, one row per head, pixels with
    /// (0, 0) the centre of the top-left pixel and frames numbered from 0 as in geostride's
    /// outputs. Mark every person in a frame you annotate
    #[arg(long, value_name = "CSV")]
    pub annotations: PathBuf,
    /// The annotations' columns: frame, x, y
    #[arg(long, default_value = "frame,x_px,y_px", value_name = "F,X,Y")]
    pub annotation_columns: String,
    /// Image width, pixels [default: from report.json beside the detections]
    #[arg(long, value_parser = super::parse_positive, value_name = "PX")]
    pub width: Option<f64>,
    /// Furthest a detection may lie from an annotation and be the same head, pixels
    #[arg(long, default_value = "25", value_parser = super::parse_positive, value_name = "PX")]
    pub gate: f64,
    /// Fit both variances at up to five places across the image (`error_profile_px2`) instead
    /// of the paper's form (`error_px2`: one vertical variance, the horizontal one linear from
    /// the centre to the edges)
    #[arg(long)]
    pub profile: bool,
    /// The annotations mark the feet (the ground point between them), and each is paired with a
    /// detection box's bottom centre instead of its head point: the error of the boxes' feet
    /// end, which the `boxes`, `onnx` and `background` detectors read in oblique views
    #[arg(long)]
    pub feet: bool,
    /// Print JSON instead of the text
    #[arg(long)]
    pub json: bool,
}

/// The image width a run recorded in its report (the scan stage's `width_px`).
fn width_from_report(detections: &Path) -> anyhow::Result<f64> {
    let report = detections
        .parent()
        .unwrap_or(Path::new("."))
        .join("report.json");
    let missing = || {
        bad_input(anyhow!(
            "{}: no image width found (the report of the run that wrote {}); give --width",
            report.display(),
            detections.display()
        ))
    };
    let text = geostride::io::FileCtx { path: &report }
        .read_small_text("a run's report.json", 64 << 20)
        .map_err(|_| missing())?;
    let v: serde_json::Value = serde_json::from_str(&text).map_err(|_| missing())?;
    v["stages"]
        .as_array()
        .and_then(|s| s.iter().find(|s| s["name"] == "scan"))
        .and_then(|s| s["counts"]["width_px"].as_f64())
        .filter(|w| *w > 0.0)
        .ok_or_else(missing)
}

/// Reads both files, pairs the annotations with the detections and fits the model.
pub fn fit(args: &Args) -> anyhow::Result<(Pairing, ErrorFit, f64)> {
    let cols: Vec<&str> = args.annotation_columns.split(',').map(str::trim).collect();
    let cols: [&str; 3] = cols.try_into().map_err(|_| {
        bad_input(anyhow!(
            "--annotation-columns '{}': expected three column names: frame, x, y",
            args.annotation_columns
        ))
    })?;
    let width = match args.width {
        Some(w) => w,
        None => width_from_report(&args.detections)?,
    };
    let annotations = read_frame_points(
        &args.annotations,
        cols,
        if args.feet {
            "a CSV of annotated feet"
        } else {
            "a CSV of annotated heads"
        },
        None,
        MAX_ANNOTATIONS,
    )
    .map_err(bad_input)?;
    // Only the annotated frames' detections: a run's file may hold hours of them.
    let frames: std::collections::BTreeSet<usize> = annotations.keys().copied().collect();
    let detections = if args.feet {
        read_box_feet(&args.detections, Some(&frames))
    } else {
        read_frame_points(
            &args.detections,
            ["frame", "u_px", "v_px"],
            "a run's detections.csv",
            Some(&frames),
            usize::MAX,
        )
    }
    .map_err(bad_input)?;
    let pairing = pair_annotations(&detections, &annotations, args.gate);
    let form = if args.profile {
        Form::Profile
    } else {
        Form::Paper
    };
    let fitted = fit_error_model(&pairing.pairs, width, form).map_err(|e| {
        bad_input(anyhow!(
            "{} against {}: {e}",
            args.annotations.display(),
            args.detections.display()
        ))
    })?;
    Ok((pairing, fitted, width))
}

pub fn run(args: Args) -> anyhow::Result<()> {
    let (pairing, f, width) = fit(&args)?;
    let what = if args.feet { "feet" } else { "heads" };
    if args.json {
        let mut v = serde_json::to_value(&f)?;
        v["unpaired_annotations"] = pairing.unpaired_annotations.into();
        v["unpaired_detections"] = pairing.unpaired_detections.into();
        v["frames_without_detections"] = pairing.frames_without_detections.into();
        v["width_px"] = width.into();
        println!("{}", serde_json::to_string_pretty(&v)?);
        return Ok(());
    }
    for line in report_lines(&pairing, &f, what) {
        println!("{line}");
    }
    println!(
        "\nIn the project file's [detect] section:\n{}",
        f.toml_line()
    );
    Ok(())
}

/// What the fit found, in words.
pub fn report_lines(p: &Pairing, f: &ErrorFit, what: &str) -> Vec<String> {
    let mut out = vec![format!(
        "{} annotated {what} paired with a detection ({} beyond the model's 99.9 % region left \
         out); {} annotations without a detection, {} detections without an annotation in the \
         annotated frames",
        f.pairs_used + f.pairs_dropped,
        f.pairs_dropped,
        p.unpaired_annotations,
        p.unpaired_detections
    )];
    let (_, hc) = f.model.at(0.0);
    let (_, he) = f.model.at(1.0);
    if f.model.knots.len() == 1 || (f.form == Form::Paper && hc == he) {
        out.push(
            "one variance each for the whole image (the heads are not spread across it enough \
             to tell the centre from the edges)"
                .into(),
        );
    }
    out.push(format!(
        "{:<34} {:>18} {:>18}",
        "across the image (0 centre, 1 edge)", "vertical, px²", "horizontal, px²"
    ));
    for (k, [sv, sh]) in f.model.knots.iter().zip(&f.standard_error_px2) {
        out.push(format!(
            "{:<34} {:>18} {:>18}",
            format!("{:.2}", k.t),
            format!("{:.2} ± {sv:.2}", k.vertical_px2),
            format!("{:.2} ± {sh:.2}", k.horizontal_px2)
        ));
    }
    out.push(format!(
        "mean offset, detected − annotated: {:+.2} px across, {:+.2} px down",
        f.mean_error_px[0], f.mean_error_px[1]
    ));
    if p.frames_without_detections > 0 {
        out.push(format!(
            "{} annotated frames have no detections (frames numbered from 0? the right run?)",
            p.frames_without_detections
        ));
    }
    out
}
