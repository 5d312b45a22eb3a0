//! `geostride dataset`: training tiles for the overhead person detector, rendered by the
//! simulator (`simulate::dataset`) with their exact labels.

use std::fmt::Write as _;
use std::path::{Path, PathBuf};

use anyhow::{Context, anyhow};
use rayon::prelude::*;
use sha2::{Digest, Sha256};

use super::bad_input;
use std::sync::Arc;

use geostride::cache::hex;
use geostride::simulate::backdrop::Backdrop;
use geostride::simulate::dataset::{DatasetSpec, Tile, render_tile};

#[derive(clap::Args)]
#[command(
    after_help = "The tiles, their labels and how they vary are described in docs/detector.md."
)]
pub struct Args {
    /// Output folder (created; must not exist): images/, labels.csv, tiles.csv, dataset.json
    #[arg(long, value_name = "DIR")]
    out: PathBuf,
    /// How many tiles
    #[arg(long, value_name = "N")]
    tiles: u64,
    /// The dataset's seed: tile i is the same for the same seed, anywhere
    #[arg(long, default_value_t = 1)]
    seed: u64,
    /// The first tile's index (a later part of the same dataset)
    #[arg(long, value_name = "I", default_value_t = 0)]
    first: u64,
    /// Tile side, pixels
    #[arg(long, value_name = "PX", default_value_t = 256)]
    size: u32,
    /// Ground sample distance range, cm a pixel (drawn log-uniformly between the two)
    #[arg(long, value_name = "MIN,MAX", value_delimiter = ',', default_values_t = [0.4, 3.0])]
    gsd_cm: Vec<f64>,
    /// The ground's texture range (drawn uniformly): 1 is the simulator's default ground, 4 the
    /// feature-rich ground of a scene made for structure from motion
    #[arg(long, value_name = "MIN,MAX", value_delimiter = ',', default_values_t = [0.6, 2.0])]
    ground_detail: Vec<f64>,
    /// Real nadir photos of the ground (no people in them) to lay under some tiles, comma-separated
    #[arg(long, value_name = "FILE,...", value_delimiter = ',')]
    backdrops: Vec<PathBuf>,
    /// The backdrops' ground sample distance, cm a pixel
    #[arg(long, value_name = "CM")]
    backdrop_gsd_cm: Option<f64>,
    /// The share of tiles laid on a backdrop
    #[arg(long, value_name = "F", default_value_t = 0.5)]
    backdrop_share: f64,
    /// Refuse a request whose files would take more than this, MB (an estimate: JPEG tiles)
    #[arg(long, value_name = "MB", default_value_t = 4096)]
    max_disk_mb: u64,
    /// No progress bar
    #[arg(short, long)]
    quiet: bool,
}

/// Bytes a stored tile takes, a pixel: JPEG at the qualities drawn (measured about 0.25 on
/// 256 px tiles; a margin above it).
const BYTES_PER_PIXEL: f64 = 0.4;

/// Tiles rendered at a time (bounded memory: a chunk's images are written before the next).
const CHUNK: u64 = 64;

pub fn run(args: Args) -> anyhow::Result<()> {
    if !(32..=1024).contains(&args.size) {
        return Err(bad_input(anyhow!(
            "--size {}: expected a tile side from 32 to 1024 pixels",
            args.size
        )));
    }
    if args.tiles == 0 || args.tiles > 10_000_000 {
        return Err(bad_input(anyhow!(
            "--tiles {}: expected 1 to 10000000 tiles",
            args.tiles
        )));
    }
    let need_mb = args.tiles as f64 * f64::from(args.size).powi(2) * BYTES_PER_PIXEL / 1e6;
    if need_mb > args.max_disk_mb as f64 {
        return Err(bad_input(anyhow!(
            "{} tiles of {} px would take about {need_mb:.0} MB, more than --max-disk-mb {}; \
             ask for fewer tiles or raise the limit",
            args.tiles,
            args.size,
            args.max_disk_mb
        )));
    }
    if args.out.exists() {
        return Err(bad_input(anyhow!(
            "{}: already exists; remove it or choose another --out (a dataset is never \
             written over another)",
            args.out.display()
        )));
    }
    let [lo, hi] = match args.gsd_cm[..] {
        [lo, hi] => [lo, hi],
        _ => [f64::NAN; 2],
    };
    if !(lo.is_finite() && hi.is_finite() && 0.05 <= lo && lo <= hi && hi <= 20.0) {
        return Err(bad_input(anyhow!(
            "--gsd-cm {:?}: expected two numbers from 0.05 to 20 cm a pixel, the smaller first",
            args.gsd_cm
        )));
    }
    let detail = match args.ground_detail[..] {
        [lo, hi] if lo.is_finite() && hi.is_finite() && 0.0 <= lo && lo <= hi && hi <= 10.0 => {
            [lo, hi]
        }
        _ => {
            return Err(bad_input(anyhow!(
                "--ground-detail {:?}: expected two numbers from 0 to 10, the smaller first",
                args.ground_detail
            )));
        }
    };
    let backdrops = read_backdrops(&args)?;
    let spec = DatasetSpec {
        size_px: args.size,
        seed: args.seed,
        gsd_m: [lo / 100.0, hi / 100.0],
        ground_detail: detail,
        backdrop_share: if backdrops.is_empty() {
            0.0
        } else {
            args.backdrop_share
        },
        ..DatasetSpec::default()
    };
    // Written beside the target, then renamed: never a half-written dataset.
    let name = args
        .out
        .file_name()
        .ok_or_else(|| bad_input(anyhow!("{}: not a folder name", args.out.display())))?;
    let partial = args
        .out
        .with_file_name(format!("{}.partial", name.to_string_lossy()));
    if partial.exists() {
        std::fs::remove_dir_all(&partial).with_context(|| {
            format!(
                "{}: removing an earlier unfinished dataset",
                partial.display()
            )
        })?;
    }
    std::fs::create_dir_all(partial.join("images"))
        .with_context(|| format!("{}: cannot create", partial.display()))?;
    let summary = match write_tiles(&args, &spec, &backdrops, &partial) {
        Ok(n) => n,
        Err(e) => {
            let _ = std::fs::remove_dir_all(&partial);
            return Err(e);
        }
    };
    std::fs::rename(&partial, &args.out).with_context(|| {
        format!(
            "{}: cannot rename to {}",
            partial.display(),
            args.out.display()
        )
    })?;
    println!(
        "Rendered {} tile(s) of {} px with {} people: {}",
        args.tiles,
        args.size,
        summary,
        args.out.display()
    );
    Ok(())
}

/// Renders and writes the tiles; the number of people labelled.
fn write_tiles(
    args: &Args,
    spec: &DatasetSpec,
    backdrops: &[(Arc<Backdrop>, String)],
    dir: &Path,
) -> anyhow::Result<usize> {
    let photos: Vec<Arc<Backdrop>> = backdrops.iter().map(|(b, _)| b.clone()).collect();
    let bar = super::progress_bar(
        args.quiet,
        args.tiles,
        "{spinner} tiles {bar:30} {pos}/{len} ({per_sec}, {eta})",
    );
    let mut labels = String::from("tile,x,y,w,h,head_x,head_y,shoulder_px,inside\n");
    let mut tiles = String::from(
        "tile,file,gsd_m,off_nadir_deg,sun_elevation_deg,ground,people,objects,noise,motion_blur_px,defocus_px,jpeg_quality,ground_detail,backdrop\n",
    );
    let mut images_hash = Sha256::new();
    let mut people = 0;
    let end = args.first + args.tiles;
    let mut start = args.first;
    while start < end {
        let stop = (start + CHUNK).min(end);
        let rendered: Vec<anyhow::Result<(u64, Tile, Vec<u8>)>> = (start..stop)
            .into_par_iter()
            .map(|i| {
                let t = render_tile(spec, i, &photos);
                let jpeg = geostride::imageio::encode_rgb_jpeg(
                    spec.size_px,
                    spec.size_px,
                    &t.rgb,
                    t.info.jpeg_quality,
                )?;
                Ok((i, t, jpeg))
            })
            .collect();
        for r in rendered {
            let (i, t, jpeg) = r?;
            let file = format!("images/{i:07}.jpg");
            let path = dir.join(&file);
            std::fs::write(&path, &jpeg)
                .with_context(|| format!("{}: cannot write", path.display()))?;
            images_hash.update(&jpeg);
            for l in &t.labels {
                let _ = writeln!(
                    labels,
                    "{i},{:.2},{:.2},{:.2},{:.2},{:.2},{:.2},{:.2},{:.3}",
                    l.bbox[0],
                    l.bbox[1],
                    l.bbox[2],
                    l.bbox[3],
                    l.head[0],
                    l.head[1],
                    l.shoulder_px,
                    l.inside
                );
            }
            people += t.labels.len();
            let f = &t.info;
            let _ = writeln!(
                tiles,
                "{i},{file},{:.5},{:.2},{},{},{},{},{:.2},{:.2},{:.2},{},{:.2},{}",
                f.gsd_m,
                f.off_nadir_deg,
                f.sun_elevation_deg
                    .map_or(String::new(), |e| format!("{e:.1}")),
                f.ground,
                f.people,
                f.objects,
                f.noise,
                f.motion_blur_px,
                f.defocus_px,
                f.jpeg_quality,
                f.ground_detail,
                f.backdrop.as_deref().unwrap_or("")
            );
            bar.inc(1);
        }
        start = stop;
    }
    bar.finish_and_clear();
    let mut all = Sha256::new();
    all.update(labels.as_bytes());
    all.update(tiles.as_bytes());
    all.update(images_hash.finalize());
    let meta = serde_json::json!({
        "format": "geostride-dataset-1",
        "geostride_version": env!("CARGO_PKG_VERSION"),
        "spec": spec,
        "first": args.first,
        "tiles": args.tiles,
        "people": people,
        "sha256": hex(&all.finalize()),
        "backdrops": backdrops.iter().map(|(b, sha)| serde_json::json!({
            "file": b.name, "gsd_m": b.gsd_m, "sha256": sha,
        })).collect::<Vec<_>>(),
        "files": {"labels": "labels.csv", "tiles": "tiles.csv", "images": "images/"},
        "label_columns": {
            "x,y,w,h": "the silhouette's box, pixels, clipped to the tile",
            "head_x,head_y": "the top of the head, pixels",
            "shoulder_px": "0.5 m across at the shoulders, pixels",
            "inside": "the share of the silhouette's box inside the tile",
        },
    });
    for (name, text) in [
        ("labels.csv", labels),
        ("tiles.csv", tiles),
        ("dataset.json", serde_json::to_string_pretty(&meta)? + "\n"),
    ] {
        let p = dir.join(name);
        std::fs::write(&p, text).with_context(|| format!("{}: cannot write", p.display()))?;
    }
    Ok(people)
}

/// The backdrop photos, read whole, each with its file's SHA-256 (the dataset's record of what
/// it was made from).
fn read_backdrops(args: &Args) -> anyhow::Result<Vec<(Arc<Backdrop>, String)>> {
    if args.backdrops.is_empty() {
        if args.backdrop_gsd_cm.is_some() {
            return Err(bad_input(anyhow!(
                "--backdrop-gsd-cm without --backdrops: give the photos too, or leave it out"
            )));
        }
        return Ok(Vec::new());
    }
    let gsd_cm = args.backdrop_gsd_cm.ok_or_else(|| {
        bad_input(anyhow!(
            "--backdrops needs --backdrop-gsd-cm: the photos' ground sample distance, cm a \
             pixel (flight height x sensor width / focal length / image width)"
        ))
    })?;
    if !(gsd_cm.is_finite() && (0.05..=20.0).contains(&gsd_cm)) {
        return Err(bad_input(anyhow!(
            "--backdrop-gsd-cm {gsd_cm}: expected 0.05 to 20 cm a pixel"
        )));
    }
    if !(0.0..=1.0).contains(&args.backdrop_share) {
        return Err(bad_input(anyhow!(
            "--backdrop-share {}: expected a share from 0 to 1",
            args.backdrop_share
        )));
    }
    args.backdrops
        .iter()
        .map(|path| {
            let (bgr, w, h) = geostride::imageio::read_bgr_bytes(path)
                .map_err(|e| bad_input(anyhow!("--backdrops: {e}")))?;
            let rgb: Vec<u8> = bgr.chunks(3).flat_map(|p| [p[2], p[1], p[0]]).collect();
            let name = path.file_name().map_or_else(
                || path.display().to_string(),
                |n| n.to_string_lossy().into(),
            );
            let photo = Backdrop::new(name, w, h, rgb, gsd_cm / 100.0)
                .map_err(|e| bad_input(anyhow!("--backdrops: {e}")))?;
            let bytes =
                std::fs::read(path).with_context(|| format!("{}: cannot read", path.display()))?;
            let sha = hex(&Sha256::digest(&bytes));
            Ok((Arc::new(photo), sha))
        })
        .collect()
}
