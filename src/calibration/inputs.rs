//! Calibration inputs (OpenCV adapter): image files, folders of images and videos, turned into
//! board views. Unreadable images are listed and skipped; video frames are sampled every N,
//! and blurred frames and near-duplicates of an accepted view are skipped.

use std::path::{Path, PathBuf};

use nalgebra::Vector2;
use opencv::core::{Mat, Size};
use opencv::prelude::*;
use opencv::{imgcodecs, imgproc, videoio};
use rayon::prelude::*;
use thiserror::Error;

use super::View;
use super::detect::{DetectSettings, find_corners, sharpness};
use crate::camera::{BoardSpec, ImageSize};
use crate::progress::Progress;

pub const IMAGE_EXTENSIONS: [&str; 11] = [
    "jpg", "jpeg", "png", "bmp", "tif", "tiff", "webp", "pgm", "ppm", "pbm", "jp2",
];
pub const VIDEO_EXTENSIONS: [&str; 12] = [
    "mp4", "avi", "mov", "mkv", "m4v", "mpg", "mpeg", "wmv", "webm", "mts", "ts", "mjpeg",
];

#[derive(Debug, Error)]
pub enum InputError {
    #[error("input '{0}' does not exist")]
    Missing(PathBuf),
    #[error("folder '{0}' holds no images (looked for .{exts})", exts = IMAGE_EXTENSIONS.join(", ."))]
    EmptyFolder(PathBuf),
    #[error("cannot read folder '{0}': {1}")]
    Folder(PathBuf, std::io::Error),
    #[error(
        "cannot open video '{0}': OpenCV could not decode it (is it a video? is the codec installed?)"
    )]
    Video(PathBuf),
    #[error("{}: {source}", path.display())]
    Image {
        path: PathBuf,
        #[source]
        source: crate::imageheader::HeaderError,
    },
    #[error("OpenCV failed on '{path}': {source}")]
    OpenCv {
        path: String,
        #[source]
        source: opencv::Error,
    },
}

/// How frames are sampled and filtered.
#[derive(Clone, Debug)]
pub struct CollectSettings {
    pub detect: DetectSettings,
    /// Use every N-th frame of a video.
    pub every: usize,
    /// A video frame is blurred when its sharpness is below this fraction of the median.
    pub blur_fraction: f64,
    /// A video view is a near-duplicate when its corners moved less than this (mean, pixels)
    /// from an accepted view.
    pub min_motion_px: Option<f64>,
}

impl Default for CollectSettings {
    fn default() -> Self {
        CollectSettings {
            detect: DetectSettings::default(),
            every: 10,
            blur_fraction: 0.5,
            min_motion_px: None,
        }
    }
}

/// What happened to each input.
#[derive(Clone, Debug, Default)]
pub struct InputLog {
    /// Images and video frames examined.
    pub tried: usize,
    pub unreadable: Vec<String>,
    pub no_board: Vec<String>,
    pub wrong_size: Vec<String>,
    pub blurred: Vec<String>,
    pub duplicates: Vec<String>,
    /// Views accepted for calibration.
    pub used: usize,
}

/// The views found, the image size they share, and the log.
pub struct Collected {
    pub views: Vec<View>,
    pub image_size: Option<ImageSize>,
    pub log: InputLog,
}

pub fn is_video(path: &Path) -> bool {
    has_extension(path, &VIDEO_EXTENSIONS)
}

fn has_extension(path: &Path, exts: &[&str]) -> bool {
    path.extension()
        .and_then(|e| e.to_str())
        .is_some_and(|e| exts.contains(&e.to_ascii_lowercase().as_str()))
}

/// Expands folders (their images, sorted by name) and checks that every input exists.
pub fn expand(paths: &[PathBuf]) -> Result<Vec<PathBuf>, InputError> {
    let mut out = Vec::new();
    for p in paths {
        if p.is_dir() {
            let mut files: Vec<PathBuf> = std::fs::read_dir(p)
                .map_err(|e| InputError::Folder(p.clone(), e))?
                .filter_map(|e| e.ok().map(|e| e.path()))
                .filter(|f| f.is_file() && has_extension(f, &IMAGE_EXTENSIONS))
                .collect();
            if files.is_empty() {
                return Err(InputError::EmptyFolder(p.clone()));
            }
            files.sort();
            out.extend(files);
        } else if p.exists() {
            out.push(p.clone());
        } else {
            return Err(InputError::Missing(p.clone()));
        }
    }
    Ok(out)
}

fn cv(path: &str) -> impl Fn(opencv::Error) -> InputError + '_ {
    move |source| InputError::OpenCv {
        path: path.to_string(),
        source,
    }
}

fn to_gray(frame: &Mat) -> opencv::Result<Mat> {
    if frame.channels() == 1 {
        return Ok(frame.clone());
    }
    let mut gray = Mat::default();
    imgproc::cvt_color_def(frame, &mut gray, imgproc::COLOR_BGR2GRAY)?;
    Ok(gray)
}

enum Outcome {
    Unreadable,
    Found(Vec<Vector2<f64>>, ImageSize),
    NoBoard(ImageSize),
}

fn detect_image(
    path: &Path,
    board: &BoardSpec,
    settings: &DetectSettings,
) -> Result<Outcome, InputError> {
    let name = path.display().to_string();
    let Some(path_str) = path.to_str() else {
        return Ok(Outcome::Unreadable);
    };
    crate::imageheader::check_file(path).map_err(|source| InputError::Image {
        path: path.to_path_buf(),
        source,
    })?;
    // imread does not fail on unreadable files: it returns an empty image.
    let gray = imgcodecs::imread(path_str, imgcodecs::IMREAD_GRAYSCALE).map_err(cv(&name))?;
    if gray.empty() {
        return Ok(Outcome::Unreadable);
    }
    let size = ImageSize {
        width: gray.cols() as u32,
        height: gray.rows() as u32,
    };
    Ok(
        match find_corners(&gray, board, settings).map_err(cv(&name))? {
            Some(c) => Outcome::Found(c, size),
            None => Outcome::NoBoard(size),
        },
    )
}

/// Collects board views from images, folders and videos.
pub fn collect(
    inputs: &[PathBuf],
    board: &BoardSpec,
    settings: &CollectSettings,
    progress: &dyn Progress,
) -> Result<Collected, InputError> {
    let files = expand(inputs)?;
    let (videos, images): (Vec<PathBuf>, Vec<PathBuf>) =
        files.into_iter().partition(|p| is_video(p));
    let mut log = InputLog::default();
    let mut views = Vec::new();
    let mut image_size: Option<ImageSize> = None;

    progress.set_length(images.len() as u64);
    let outcomes: Vec<Result<Outcome, InputError>> = images
        .par_iter()
        .map(|p| {
            let r = detect_image(p, board, &settings.detect);
            progress.inc(1);
            r
        })
        .collect();
    for (path, outcome) in images.iter().zip(outcomes) {
        log.tried += 1;
        let name = path.file_name().map_or_else(
            || path.display().to_string(),
            |n| n.to_string_lossy().into_owned(),
        );
        match outcome? {
            Outcome::Unreadable => log.unreadable.push(path.display().to_string()),
            Outcome::NoBoard(size) | Outcome::Found(_, size)
                if *image_size.get_or_insert(size) != size =>
            {
                log.wrong_size
                    .push(format!("{name} ({}x{})", size.width, size.height));
            }
            Outcome::NoBoard(_) => log.no_board.push(name),
            Outcome::Found(corners, _) => views.push(View { name, corners }),
        }
    }
    for video in &videos {
        collect_video(
            video,
            board,
            settings,
            progress,
            &mut views,
            &mut image_size,
            &mut log,
        )?;
    }
    log.used = views.len();
    Ok(Collected {
        views,
        image_size,
        log,
    })
}

struct Candidate {
    frame: usize,
    sharpness: f64,
    corners: Option<Vec<Vector2<f64>>>,
}

fn collect_video(
    path: &Path,
    board: &BoardSpec,
    settings: &CollectSettings,
    progress: &dyn Progress,
    views: &mut Vec<View>,
    image_size: &mut Option<ImageSize>,
    log: &mut InputLog,
) -> Result<(), InputError> {
    let name = path.display().to_string();
    let short = path
        .file_name()
        .map_or_else(|| name.clone(), |n| n.to_string_lossy().into_owned());
    let mut cap = videoio::VideoCapture::from_file(&name, videoio::CAP_ANY).map_err(cv(&name))?;
    if !cap.is_opened().map_err(cv(&name))? {
        return Err(InputError::Video(path.to_path_buf()));
    }
    let total = cap
        .get(videoio::CAP_PROP_FRAME_COUNT)
        .unwrap_or(0.0)
        .max(0.0) as u64;
    progress.set_length(total);
    progress.set_message(short.clone());
    let every = settings.every.max(1);
    let mut detect = settings.detect;
    detect.fast_check = true;

    let mut frame_size: Option<ImageSize> = None;
    let mut candidates = Vec::new();
    let mut batch: Vec<(usize, Mat)> = Vec::new();
    let batch_len = 2 * rayon::current_num_threads().max(1);
    let mut index = 0usize;
    let mut frame = Mat::default();
    loop {
        let more = cap.read(&mut frame).map_err(cv(&name))?;
        if more && !frame.empty() {
            if index.is_multiple_of(every) {
                let gray = to_gray(&frame).map_err(cv(&name))?;
                let size = ImageSize {
                    width: gray.cols() as u32,
                    height: gray.rows() as u32,
                };
                frame_size.get_or_insert(size);
                batch.push((index, gray));
            }
            index += 1;
            progress.inc(1);
        }
        if batch.len() >= batch_len || (!more && !batch.is_empty()) {
            let results: Vec<opencv::Result<Candidate>> = batch
                .par_iter()
                .map(|(i, gray)| {
                    Ok(Candidate {
                        frame: *i,
                        sharpness: frame_sharpness(gray)?,
                        corners: find_corners(gray, board, &detect)?,
                    })
                })
                .collect();
            for r in results {
                candidates.push(r.map_err(cv(&name))?);
            }
            batch.clear();
        }
        if !more {
            break;
        }
    }
    if candidates.is_empty() {
        return Err(InputError::Video(path.to_path_buf()));
    }
    let size = frame_size.expect("a frame was read");
    if *image_size.get_or_insert(size) != size {
        log.tried += candidates.len();
        log.wrong_size
            .push(format!("{short} ({}x{})", size.width, size.height));
        return Ok(());
    }

    let mut sharp: Vec<f64> = candidates.iter().map(|c| c.sharpness).collect();
    sharp.sort_by(f64::total_cmp);
    let threshold = settings.blur_fraction * sharp[sharp.len() / 2];
    let min_motion = settings
        .min_motion_px
        .unwrap_or(0.01 * f64::from(size.width).hypot(f64::from(size.height)));
    let first_new = views.len();
    for c in candidates {
        log.tried += 1;
        let view_name = format!("{short}#{}", c.frame);
        let Some(corners) = c.corners else {
            log.no_board.push(view_name);
            continue;
        };
        if c.sharpness < threshold {
            log.blurred.push(view_name);
            continue;
        }
        let duplicate = views[first_new..]
            .iter()
            .any(|v| mean_motion(&v.corners, &corners) < min_motion);
        if duplicate {
            log.duplicates.push(view_name);
            continue;
        }
        views.push(View {
            name: view_name,
            corners,
        });
    }
    Ok(())
}

/// Sharpness on a copy at most 640 pixels wide, so the measure does not depend on resolution.
fn frame_sharpness(gray: &Mat) -> opencv::Result<f64> {
    if gray.cols() <= 640 {
        return sharpness(gray);
    }
    let scale = 640.0 / f64::from(gray.cols());
    let mut small = Mat::default();
    imgproc::resize(
        gray,
        &mut small,
        Size::new(0, 0),
        scale,
        scale,
        imgproc::INTER_AREA,
    )?;
    sharpness(&small)
}

fn mean_motion(a: &[Vector2<f64>], b: &[Vector2<f64>]) -> f64 {
    a.iter().zip(b).map(|(p, q)| (p - q).norm()).sum::<f64>() / a.len().max(1) as f64
}
