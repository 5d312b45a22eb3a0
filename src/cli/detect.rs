//! `geostride detect VIDEO-OR-IMAGES`: people found by a neural detector (any YOLO-family ONNX
//! model through ONNX Runtime; the bundled YOLOv3-tiny by default), written as MOTChallenge
//! boxes for any other tool, with an annotated preview frame.

use std::fmt::Write as _;
use std::path::{Path, PathBuf};
use std::time::Instant;

use anyhow::anyhow;
use nalgebra::Vector2;

use super::bad_input;
use geostride::detect::neural::{Detected, NeuralDetector, NeuralError, NeuralSettings};
use geostride::detect::onnx::{OVERHEAD_MODEL, OnnxError, given_model, overhead_model};
use geostride::detect::yolo::Layout;

#[derive(clap::Args)]
pub struct Args {
    /// A video, or images (one frame each, in the order given)
    #[arg(required = true, value_name = "VIDEO-OR-IMAGES")]
    inputs: Vec<PathBuf>,
    /// The ONNX model, or a bundled one by name: overhead (geostride's own, for views from
    /// above) or yolov3-tiny (COCO, for views from the side) [default: overhead]
    #[arg(long, value_name = "M.onnx")]
    model: Option<PathBuf>,
    /// MOTChallenge boxes: frame (from 1), -1, left, top, width, height, score, -1, -1, -1
    #[arg(long, value_name = "FILE")]
    out: PathBuf,
    /// Also draw the boxes of one frame (--preview-frame) into this PNG
    #[arg(long, value_name = "PNG")]
    preview: Option<PathBuf>,
    /// The frame (from 0) of the preview
    #[arg(long, default_value = "0", value_name = "N")]
    preview_frame: usize,
    /// The output layout: darknet (anchors from the model's metadata), yolov5, yolov8,
    /// yolox or centre_heatmap (geostride's own) [default: the model's metadata, else told from its outputs]
    #[arg(long, value_parser = ["darknet", "yolov5", "yolov8", "yolox", "centre_heatmap"])]
    layout: Option<String>,
    /// Input size WIDTHxHEIGHT [default: the model's, else 640x640]
    #[arg(long, value_parser = super::parse_size, value_name = "WxH")]
    input_size: Option<(u32, u32)>,
    /// Stretch frames to the input instead of letterboxing
    #[arg(long)]
    stretch: bool,
    /// The model takes BGR instead of RGB
    #[arg(long)]
    bgr: bool,
    /// Per channel mean, subtracted from v/255 (model's channel order)
    #[arg(long, value_delimiter = ',', default_values_t = [0.0f32, 0.0, 0.0], value_name = "M,M,M")]
    mean: Vec<f32>,
    /// Per channel std, dividing (v/255 − mean)
    #[arg(long, value_delimiter = ',', default_values_t = [1.0f32, 1.0, 1.0], value_name = "S,S,S")]
    std: Vec<f32>,
    /// At most N boxes a frame
    #[arg(long, default_value = "300", value_name = "N")]
    max_boxes: usize,
    /// Classes kept, by name or id, comma-separated
    #[arg(long, default_value = "person", value_delimiter = ',')]
    classes: Vec<String>,
    /// Lowest score kept
    #[arg(long, default_value = "0.3", value_name = "S")]
    min_score: f64,
    /// Non-maximum suppression's IoU
    #[arg(long, default_value = "0.45", value_name = "IOU")]
    nms: f64,
    /// Also suppress a box lying more than this share of its area inside a better one (1:
    /// never) [default: the model's geostride.nms_contained metadata, else 1]
    #[arg(long, value_name = "F")]
    nms_contained: Option<f64>,
    /// Tiles of N pixels for small people (0: the whole frame at once)
    #[arg(long, default_value = "0", value_name = "N")]
    tile: usize,
    /// The frames' ground sample distance, cm a pixel: a model that states the scales it was
    /// trained at (geostride's own) sees the frames scaled to them
    #[arg(long, value_name = "CM")]
    gsd_cm: Option<f64>,
    /// Tiles' overlap, pixels
    #[arg(long, default_value = "64", value_name = "PX")]
    overlap: usize,
    /// Only inside X,Y,W,H (pixels)
    #[arg(long, value_delimiter = ',', value_name = "X,Y,W,H")]
    roi: Option<Vec<usize>>,
    /// Every N-th frame of a video
    #[arg(long, default_value = "1", value_name = "N")]
    every: usize,
    /// Only the first N frames
    #[arg(long, value_name = "N")]
    max_frames: Option<usize>,
    /// ONNX Runtime threads (0: its choice)
    #[arg(long, default_value = "0", value_name = "N")]
    threads: usize,
    /// Print the summary as JSON
    #[arg(long)]
    json: bool,
    /// No progress bar
    #[arg(short, long)]
    quiet: bool,
}

#[derive(serde::Serialize)]
struct Summary {
    model: String,
    layout: String,
    input_size: [usize; 2],
    /// How much the frames were scaled for a model that states the scales it was trained at
    /// (it then sees them at that scale, not fitted to `input_size`).
    frame_scale: Option<f64>,
    /// The suppression's containment in use (1: none).
    nms_contained: f64,
    frames: usize,
    boxes: usize,
    mean_per_frame: f64,
    max_per_frame: usize,
    ms_per_frame: f64,
    out: String,
    preview: Option<String>,
}

/// Draws one frame's boxes (green, score above) into a PNG.
fn write_preview(
    path: &Path,
    bgr: &[u8],
    wh: [usize; 2],
    boxes: &[Detected],
) -> anyhow::Result<()> {
    let mut c = geostride::draw::Canvas::from_bgr_bytes(bgr, wh[0] as u32, wh[1] as u32)?;
    for b in boxes {
        let [x, y, w, h] = b.xywh;
        let p = [
            Vector2::new(x, y),
            Vector2::new(x + w, y),
            Vector2::new(x + w, y + h),
            Vector2::new(x, y + h),
        ];
        for k in 0..4 {
            c.line(&p[k], &p[(k + 1) % 4], [0, 230, 0], 1)?;
        }
        c.text(
            &Vector2::new(x, y - 2.0),
            &format!("{:.2}", b.score),
            0.35,
            [0, 230, 0],
            1,
        )?;
    }
    c.save(path)?;
    Ok(())
}

/// The detector's settings from the flags, checked as the project's are (named by the flags).
fn settings_of(args: &Args) -> anyhow::Result<NeuralSettings> {
    if args.mean.len() != 3 || args.std.len() != 3 {
        return Err(bad_input(anyhow!(
            "--mean and --std take three numbers each, comma-separated (0.485,0.456,0.406)"
        )));
    }
    if args
        .gsd_cm
        .is_some_and(|g| !(g.is_finite() && (0.01..=100.0).contains(&g)))
    {
        return Err(bad_input(anyhow!(
            "--gsd-cm {}: expected the ground sample distance from 0.01 to 100 cm a pixel",
            args.gsd_cm.unwrap_or_default()
        )));
    }
    if args.roi.as_ref().is_some_and(|r| r.len() != 4) {
        return Err(bad_input(anyhow!(
            "--roi takes four whole numbers, comma-separated: X,Y,W,H pixels"
        )));
    }
    let settings = NeuralSettings {
        layout: args.layout.as_deref().and_then(Layout::from_name),
        want_darknet: args.layout.as_deref() == Some("darknet"),
        input_size: args.input_size.map(|(w, h)| [w as usize, h as usize]),
        letterbox: !args.stretch,
        bgr: args.bgr,
        mean: [args.mean[0], args.mean[1], args.mean[2]],
        std: [args.std[0], args.std[1], args.std[2]],
        max_boxes: args.max_boxes,
        classes: args.classes.clone(),
        min_score: args.min_score,
        nms_iou: args.nms,
        nms_contained: args.nms_contained,
        tile: args.tile,
        overlap: args.overlap,
        roi: args.roi.as_ref().map(|r| [r[0], r[1], r[2], r[3]]),
        threads: args.threads,
        frame_gsd_m: args.gsd_cm.map(|g| g / 100.0),
    };
    // The project's check, named by the flags.
    settings.check().map_err(|(key, message)| {
        let flag = match key {
            "nms_iou" => "nms",
            k => k,
        };
        bad_input(anyhow!("--{} {message}", flag.replace('_', "-")))
    })?;
    Ok(settings)
}

pub fn run(args: Args) -> anyhow::Result<()> {
    if args.every == 0 {
        return Err(bad_input(anyhow!("--every 0: give N ≥ 1")));
    }
    let settings = settings_of(&args)?;
    if args.max_frames == Some(0) {
        return Err(bad_input(anyhow!("--max-frames 0: give N ≥ 1")));
    }
    let model = match &args.model {
        Some(m) => given_model(&m.to_string_lossy(), m.clone()),
        None => overhead_model().ok_or_else(|| {
            bad_input(anyhow!(
                "the overhead model ({OVERHEAD_MODEL}) is not here: is this a whole checkout? Or give --model M.onnx"
            ))
        })?,
    };
    let mut inputs: Vec<&Path> = args.inputs.iter().map(PathBuf::as_path).collect();
    inputs.push(&model);
    super::check_output_file(&args.out, inputs.iter().copied())?;
    if let Some(p) = &args.preview {
        super::check_output_file(p, inputs.iter().copied())?;
        geostride::imageio::check_writable(p).map_err(bad_input)?;
    }
    let mut det = NeuralDetector::load(&model, &settings).map_err(|e| match e {
        NeuralError::Onnx(OnnxError::Run { .. }) => anyhow!(e),
        other => bad_input(other),
    })?;

    let bar = super::progress_bar(
        args.quiet || args.json,
        args.max_frames.unwrap_or(0) as u64,
        "{spinner} detect {pos} frames ({per_sec})",
    );
    let mut text = String::new();
    let (mut frames, mut boxes, mut most) = (0usize, 0usize, 0usize);
    let mut busy = 0.0;
    let mut preview_done = false;
    let mut each = |index: usize, bgr: &[u8], wh: [usize; 2]| -> anyhow::Result<()> {
        let t = Instant::now();
        let found = det.detect(bgr, wh).map_err(|e| match e {
            NeuralError::Onnx(_) => anyhow!(e),
            other => bad_input(anyhow!("frame {index}: {other}")),
        })?;
        busy += t.elapsed().as_secs_f64();
        for b in &found {
            let _ = writeln!(
                text,
                "{},-1,{:.2},{:.2},{:.2},{:.2},{:.4},-1,-1,-1",
                index + 1,
                b.xywh[0],
                b.xywh[1],
                b.xywh[2],
                b.xywh[3],
                b.score
            );
        }
        frames += 1;
        boxes += found.len();
        most = most.max(found.len());
        if let Some(p) = &args.preview
            && index == args.preview_frame
        {
            write_preview(p, bgr, wh, &found)?;
            preview_done = true;
        }
        bar.inc(1);
        Ok(())
    };
    let video = args.inputs.len() == 1
        && geostride::video::source::FrameReader::open(&args.inputs[0]).is_ok()
        && !is_image(&args.inputs[0]);
    if video {
        let mut r = geostride::video::source::FrameReader::open(&args.inputs[0])
            .map_err(|e| bad_input(anyhow!(e)))?;
        while let Some((i, bgr, w, h)) = r.next_bgr_bytes().map_err(|e| anyhow!(e))? {
            if args.max_frames.is_some_and(|m| i >= m) {
                break;
            }
            if i % args.every == 0 {
                each(i, &bgr, [w, h])?;
            }
        }
    } else {
        for (i, p) in args.inputs.iter().enumerate() {
            if args.max_frames.is_some_and(|m| i >= m) {
                break;
            }
            let (bgr, w, h) =
                geostride::imageio::read_bgr_bytes(p).map_err(|e| bad_input(anyhow!(e)))?;
            each(i, &bgr, [w, h])?;
        }
    }
    bar.finish_and_clear();
    if frames == 0 {
        return Err(bad_input(anyhow!(
            "{}: no frame read",
            args.inputs[0].display()
        )));
    }
    geostride::io::write_atomic(&args.out, text.as_bytes())?;
    if args.preview.is_some() && !preview_done {
        eprintln!(
            "note: frame {} was not read, so no preview was drawn",
            args.preview_frame
        );
    }
    let s = Summary {
        model: model.display().to_string(),
        layout: det.layout().name().into(),
        input_size: det.input_size(),
        frame_scale: det.frame_scale(),
        nms_contained: det.nms_contained(),
        frames,
        boxes,
        mean_per_frame: boxes as f64 / frames as f64,
        max_per_frame: most,
        ms_per_frame: 1000.0 * busy / frames as f64,
        out: args.out.display().to_string(),
        preview: args
            .preview
            .as_ref()
            .filter(|_| preview_done)
            .map(|p| p.display().to_string()),
    };
    if args.json {
        println!("{}", serde_json::to_string_pretty(&s)?);
    } else {
        let input = match s.frame_scale {
            Some(f) => format!("frames scaled {f:.3}× to the model's own scale"),
            None => format!("input {}x{}", s.input_size[0], s.input_size[1]),
        };
        println!(
            "{} frames, {} boxes ({:.2} a frame, at most {}), {:.1} ms a frame ({} layout, {input})",
            s.frames, s.boxes, s.mean_per_frame, s.max_per_frame, s.ms_per_frame, s.layout,
        );
        println!("Written: {}", s.out);
        if let Some(p) = &s.preview {
            println!("Written: {p}");
        }
    }
    Ok(())
}

fn is_image(p: &Path) -> bool {
    p.extension().is_some_and(|e| {
        ["png", "jpg", "jpeg", "tif", "tiff", "bmp"]
            .contains(&e.to_string_lossy().to_lowercase().as_str())
    })
}
