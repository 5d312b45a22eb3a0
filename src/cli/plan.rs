//! `geostride plan`: footprint, ground sample distance and the paper's error maps for a flight.

use std::path::PathBuf;

use anyhow::anyhow;

use super::{bad_input, load_camera, parse_positive, scale_to};
use geostride::imageio::HeatMap;
use geostride::simulate::plan::{PixelNoise, PlanSettings, plan};

fn parse_detector(s: &str) -> Result<(f64, f64, f64), String> {
    let v: Vec<f64> = s
        .split(',')
        .map(|x| x.trim().parse::<f64>())
        .collect::<Result<_, _>>()
        .map_err(|_| format!("expected VERTICAL,HCENTRE,HEDGE in px², got '{s}'"))?;
    match v.as_slice() {
        [a, b, c] if *a > 0.0 && *b > 0.0 && *c > 0.0 => Ok((*a, *b, *c)),
        _ => Err(format!(
            "expected three positive variances VERTICAL,HCENTRE,HEDGE in px², got '{s}'"
        )),
    }
}

#[derive(clap::Args)]
#[command(after_help = "\
Presets (nominal, from published specifications, not calibrated): mavic3e (DJI Mavic 3 Enterprise,
4K 16:9), mini3pro (DJI Mini 3 Pro, 4K 16:9); or any calibration file.

Example: geostride plan --camera mavic3e --altitude 30 --height-error 0.1 --out plan/")]
pub struct Args {
    /// Camera: a preset name (mavic3e, mini3pro) or a calibration file (OpenCV YAML, Metashape XML, JSON)
    #[arg(long, value_name = "CAL")]
    camera: String,
    /// Camera height above the ground, metres
    #[arg(long, value_parser = parse_positive, value_name = "M")]
    altitude: f64,
    /// Video resolution WIDTHxHEIGHT; the camera is scaled to it (same aspect ratio only)
    #[arg(long, value_parser = super::parse_size, value_name = "WxH")]
    video_mode: Option<(u32, u32)>,
    /// Height of the heads above the ground (the homography plane), metres
    #[arg(long, default_value_t = 1.7, value_name = "M")]
    head_height: f64,
    /// Error of the assumed head height, metres (the paper: 0.1)
    #[arg(long, default_value_t = 0.1, value_name = "DH")]
    height_error: f64,
    /// Pixel variance of a head detection, px² (the paper: 4)
    #[arg(long, default_value_t = 4.0, value_parser = parse_positive, value_name = "V")]
    pixel_var: f64,
    /// Instead of --pixel-var, a detector whose horizontal variance grows from the centre to the
    /// edges: VERTICAL,HCENTRE,HEDGE in px² (the paper's section 4.1.3: 10,10,20)
    #[arg(long, value_parser = parse_detector, value_name = "V,HC,HE", conflicts_with = "pixel_var")]
    detector_model: Option<(f64, f64, f64)>,
    /// Spacing of the map samples, pixels
    #[arg(long, default_value_t = 4, value_name = "PX")]
    map_step: u32,
    /// Folder for the PNG heat maps (height-error.png, noise95.png)
    #[arg(long, value_name = "DIR")]
    out: Option<PathBuf>,
    /// Print the numbers as JSON
    #[arg(long)]
    json: bool,
}

pub fn run(args: Args) -> anyhow::Result<()> {
    if !(args.head_height.is_finite() && (0.0..=3.0).contains(&args.head_height)) {
        return Err(bad_input(anyhow!(
            "--head-height {}: expected 0 to 3 m",
            args.head_height
        )));
    }
    if !(args.height_error.is_finite() && (0.0..=3.0).contains(&args.height_error)) {
        return Err(bad_input(anyhow!(
            "--height-error {}: expected 0 to 3 m",
            args.height_error
        )));
    }
    if args.map_step == 0 {
        return Err(bad_input(anyhow!("--map-step 0: expected 1 pixel or more")));
    }
    let (mut camera, source) = load_camera(&args.camera)?;
    if let Some((w, h)) = args.video_mode {
        camera = scale_to(camera, w, h)?;
    }
    let noise = match args.detector_model {
        Some((v, hc, he)) => PixelNoise::Detector {
            vertical_px2: v,
            horizontal_centre_px2: hc,
            horizontal_edge_px2: he,
        },
        None => PixelNoise::Constant {
            var_px2: args.pixel_var,
        },
    };
    let settings = PlanSettings {
        altitude_m: args.altitude,
        head_height_m: args.head_height,
        height_error_m: args.height_error,
        noise,
        map_step_px: args.map_step.max(1),
    };
    let guard = match &args.out {
        Some(dir) => Some(super::check_output_dir(dir, [&args.camera])?),
        None => None,
    };
    let p = plan(&camera, &settings).map_err(bad_input)?;
    if let (Some(dir), Some(g)) = (&args.out, guard) {
        g.create_dir(dir).map_err(super::output_error)?;
    }
    let mut written = Vec::new();
    if let Some(dir) = &args.out {
        let maps = [
            (
                &p.height_error_map,
                "height-error.png",
                format!(
                    "Horizontal error of a {} m head-height error at {} m",
                    args.height_error, args.altitude
                ),
            ),
            (
                &p.noise_95_map,
                "noise95.png",
                format!("95 % error of head detections at {} m", args.altitude),
            ),
        ];
        for (m, name, title) in maps {
            let f = dir.join(name);
            let map = HeatMap {
                cols: m.cols,
                rows: m.rows,
                values: &m.values_m,
                title,
                unit: "cm",
                scale: 100.0,
            };
            geostride::imageio::write_heatmap(&f, &map, 960).map_err(|e| anyhow!(e))?;
            written.push(f);
        }
    }
    if args.json {
        println!("{}", serde_json::to_string_pretty(&p)?);
        return Ok(());
    }
    println!(
        "Camera: {source}, {}x{} px",
        p.image_size[0], p.image_size[1]
    );
    println!(
        "Altitude {} m above the ground; heads at {} m",
        p.altitude_m, p.head_height_m
    );
    println!(
        "  ground sample distance: {:.2} cm/px on the ground, {:.2} cm/px at head height",
        p.gsd_ground_m * 100.0,
        p.gsd_head_m * 100.0
    );
    println!(
        "  footprint: {:.1} m x {:.1} m on the ground, {:.1} m x {:.1} m at head height",
        p.footprint_ground_m[0],
        p.footprint_ground_m[1],
        p.footprint_head_m[0],
        p.footprint_head_m[1]
    );
    println!(
        "  head-height error of {} m -> horizontal error: max {:.3} m over the full frame, {:.3} m in the central half x half",
        p.height_error_m, p.height_error.max_full_m, p.height_error.max_central_m
    );
    let noise = match p.noise {
        PixelNoise::Constant { var_px2 } => format!("{var_px2} px² pixel noise"),
        PixelNoise::Detector {
            vertical_px2,
            horizontal_centre_px2,
            horizontal_edge_px2,
        } => {
            format!(
                "detector noise ({vertical_px2} px² vertical, {horizontal_centre_px2}-{horizontal_edge_px2} px² horizontal)"
            )
        }
    };
    println!(
        "  {noise} -> 95 % error: {:.3} m at the centre, max {:.3} m over the full frame, {:.3} m in the central half x half",
        p.noise_95.at_centre_m, p.noise_95.max_full_m, p.noise_95.max_central_m
    );
    for f in written {
        println!("Written: {}", f.display());
    }
    Ok(())
}
