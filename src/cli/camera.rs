//! `geostride camera show|convert`.

use std::fmt::Write as _;
use std::path::PathBuf;

use anyhow::anyhow;

use super::calibrate::FormatArg;
use super::{bad_input, check_output_file};
use geostride::camera::formats::{self, Format};
use geostride::camera::{Calibration, ImageSize, PARAM_NAMES};

#[derive(clap::Subcommand)]
pub enum Command {
    /// Print a calibration file's camera, uncertainty and views
    Show {
        /// Calibration file (OpenCV YAML, Metashape XML, geostride JSON or Tsai)
        file: PathBuf,
        /// Input format, when detection from the content is not wanted
        #[arg(long, value_enum)]
        format: Option<FormatArg>,
        /// Print the camera as geostride JSON instead of a table
        #[arg(long)]
        json: bool,
    },
    /// Convert a calibration between OpenCV YAML, Metashape XML and geostride JSON (Tsai read)
    #[command(
        after_help = "The output format follows the extension (.yaml, .xml, .json) unless --to is given.\n\
Conversions and the conventions they rest on are in docs/formats.md."
    )]
    Convert {
        /// Input calibration file
        input: PathBuf,
        /// Output calibration file
        output: PathBuf,
        /// Input format, when detection from the content is not wanted
        #[arg(long, value_enum)]
        from: Option<FormatArg>,
        /// Output format, overriding the extension
        #[arg(long, value_enum)]
        to: Option<FormatArg>,
        /// Image size WIDTHxHEIGHT, for inputs that lack it (needed by Metashape output)
        #[arg(long, value_parser = super::parse_size, value_name = "WxH")]
        image_size: Option<(u32, u32)>,
    },
}

pub fn run(cmd: Command) -> anyhow::Result<()> {
    match cmd {
        Command::Show { file, format, json } => {
            let cal = formats::read(&file, format.map(Format::from)).map_err(bad_input)?;
            if json {
                print!(
                    "{}",
                    formats::render(&cal, Format::Json, &file).map_err(|e| anyhow!(e))?
                );
            } else {
                print!("{}", describe(&cal));
            }
            Ok(())
        }
        Command::Convert {
            input,
            output,
            from,
            to,
            image_size,
        } => {
            check_output_file(&output, [&input])?;
            formats::output_format(&output, to.map(Format::from)).map_err(bad_input)?;
            let mut cal = formats::read(&input, from.map(Format::from)).map_err(bad_input)?;
            if let Some((w, h)) = image_size {
                match cal.camera.image_size {
                    Some(s) if (s.width, s.height) != (w, h) => {
                        return Err(bad_input(anyhow!(
                            "--image-size {w}x{h} contradicts the {}x{} in '{}'",
                            s.width,
                            s.height,
                            input.display()
                        )));
                    }
                    _ => {
                        cal.camera.image_size = Some(ImageSize {
                            width: w,
                            height: h,
                        })
                    }
                }
            }
            for n in &cal.notes {
                eprintln!("note: {n}");
            }
            let f =
                formats::write(&cal, &output, to.map(Format::from)).map_err(super::write_error)?;
            if cal.extrinsics.is_some() && f != Format::Json {
                eprintln!(
                    "note: the camera's pose is not written to {} (geostride JSON keeps it)",
                    f.name()
                );
            }
            println!("Written: {} ({})", output.display(), f.name());
            Ok(())
        }
    }
}

fn describe(cal: &Calibration) -> String {
    let mut s = String::new();
    let c = &cal.camera;
    match c.image_size {
        Some(sz) => {
            let _ = writeln!(s, "image size   {} x {} px", sz.width, sz.height);
        }
        None => {
            let _ = writeln!(s, "image size   unknown");
        }
    }
    let sd = cal.std_devs();
    let p = c.params();
    for (i, name) in PARAM_NAMES.iter().enumerate() {
        let _ = match sd {
            Some(sd) if sd[i] > 0.0 => writeln!(s, "{name:<6} {:>18.8}  ±{:.8}", p[i], sd[i]),
            _ => writeln!(s, "{name:<6} {:>18.8}", p[i]),
        };
    }
    if let Some(sz) = c.image_size {
        let hfov = 2.0 * (f64::from(sz.width) / (2.0 * c.fx)).atan().to_degrees();
        let vfov = 2.0 * (f64::from(sz.height) / (2.0 * c.fy)).atan().to_degrees();
        let _ = writeln!(s, "field of view (pinhole) {hfov:.2}° x {vfov:.2}°");
    }
    if let Some(e) = &cal.extrinsics {
        let r = e.cam_from_world.rvec();
        let t = e.cam_from_world.translation;
        let c = e.cam_from_world.centre();
        let _ = writeln!(s, "pose (cam_from_world, {})", e.world);
        let _ = writeln!(s, "  rvec   {:.6} {:.6} {:.6} rad", r.x, r.y, r.z);
        let _ = writeln!(s, "  tvec   {:.4} {:.4} {:.4} m", t.x, t.y, t.z);
        let _ = writeln!(s, "  centre {:.4} {:.4} {:.4} m", c.x, c.y, c.z);
    }
    if let Some(sum) = &cal.summary {
        let _ = writeln!(
            s,
            "calibrated from {} view(s), RMS {:.4} px",
            sum.views.len(),
            sum.rms_px
        );
        if let Some(b) = sum.board {
            let _ = writeln!(
                s,
                "board {}x{} inner corners, {} m squares",
                b.cols, b.rows, b.square_m
            );
        }
        for v in &sum.views {
            let _ = writeln!(
                s,
                "  {:<30} {:>8.4} px{}",
                v.name,
                v.rms_px,
                if v.outlier { "  OUTLIER" } else { "" }
            );
        }
    }
    for n in &cal.notes {
        let _ = writeln!(s, "note: {n}");
    }
    s
}
