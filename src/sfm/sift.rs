//! SIFT features through OpenCV (adapter): an image read in grey (its stored pixels, the EXIF
//! orientation ignored, as the intrinsics are those of the sensor), searched at the working
//! size, capped over a grid, RootSIFT descriptors, keypoints at full resolution.

use std::path::Path;

use opencv::core::{KeyPoint, Mat, Size, Vector, no_array};
use opencv::prelude::*;
use opencv::{features2d, imgcodecs, imgproc};

use super::{DESCRIPTOR_LEN, FeatureSettings, Features, Keypoint, grid_cap, root_sift};
use crate::imageio::{ImageError, file_error};

/// Whether a decoder knows the file's format from its first bytes (nothing is decoded).
pub fn decodable(path: &Path) -> bool {
    path.to_str()
        .is_some_and(|name| imgcodecs::have_image_reader(name).unwrap_or(false))
}

/// The features of the image file `path`.
pub fn read_features(path: &Path, s: &FeatureSettings) -> Result<Features, ImageError> {
    let name = path
        .to_str()
        .ok_or_else(|| file_error(path, "the file name is not valid UTF-8"))?;
    if !path.is_file() {
        return Err(file_error(path, "no such file"));
    }
    crate::imageheader::check_file(path).map_err(|e| file_error(path, e))?;
    let grey = imgcodecs::imread(
        name,
        imgcodecs::IMREAD_GRAYSCALE | imgcodecs::IMREAD_IGNORE_ORIENTATION,
    )
    .map_err(|e| file_error(path, e))?;
    // imread does not fail on a file it cannot decode: it returns an empty image.
    if grey.empty() {
        return Err(file_error(
            path,
            "cannot decode the image (not a JPEG, PNG, TIFF or other format OpenCV reads)",
        ));
    }
    features_of_grey(&grey, s).map_err(ImageError::from)
}

/// The features of the frames `frames` (increasing) of a video, each given to `each` with its
/// index as it is decoded (a long video's key frames are not all held at once); stops early
/// when `each` fails. Frames beyond the video's end are not given.
pub fn for_video_frames<E: From<String>>(
    video: &Path,
    frames: &[usize],
    s: &FeatureSettings,
    mut each: impl FnMut(usize, Features) -> Result<(), E>,
) -> Result<(), E> {
    let mut reader =
        crate::video::source::FrameReader::open(video).map_err(|e| E::from(e.to_string()))?;
    let mut next = 0;
    while next < frames.len() {
        let Some((index, grey)) = reader.next_gray().map_err(|e| E::from(e.to_string()))? else {
            break;
        };
        if index != frames[next] {
            continue;
        }
        next += 1;
        let f = features_of_grey(&grey, s).map_err(|e| {
            E::from(format!(
                "{}: features of frame {index}: {e}",
                video.display()
            ))
        })?;
        each(index, f)?;
    }
    Ok(())
}

/// The features of a greyscale image.
pub fn features_of_grey(grey: &Mat, s: &FeatureSettings) -> Result<Features, opencv::Error> {
    let (w, h) = (grey.cols(), grey.rows());
    let largest = w.max(h);
    // Working pixels per full-resolution pixel.
    let scale = match s.working_size_px {
        Some(size) if (size as i32) < largest => f64::from(size) / f64::from(largest),
        _ => 1.0,
    };
    let small;
    let work = if scale < 1.0 {
        let mut m = Mat::default();
        imgproc::resize(
            grey,
            &mut m,
            Size::new(
                (f64::from(w) * scale).round() as i32,
                (f64::from(h) * scale).round() as i32,
            ),
            0.0,
            0.0,
            imgproc::INTER_AREA,
        )?;
        small = m;
        &small
    } else {
        grey
    };
    let (sx, sy) = (
        f64::from(w) / f64::from(work.cols()),
        f64::from(h) / f64::from(work.rows()),
    );
    let mut sift = features2d::SIFT::create(0, 3, s.contrast_threshold, 10.0, 1.6)?;
    let mut kps = Vector::<KeyPoint>::new();
    let mut desc = Mat::default();
    sift.detect_and_compute(work, &no_array(), &mut kps, &mut desc, false)?;
    let keypoints: Vec<Keypoint> = kps
        .iter()
        .map(|k| {
            let p = k.pt();
            Keypoint {
                // Pixel centres at integers in both resolutions.
                x: (f64::from(p.x) + 0.5) * sx - 0.5,
                y: (f64::from(p.y) + 0.5) * sy - 0.5,
                size: f64::from(k.size()) * sx,
                angle_deg: f64::from(k.angle()),
                response: f64::from(k.response()),
            }
        })
        .collect();
    let keep = grid_cap(&keypoints, w as u32, h as u32, s.max_features, s.grid_cols);
    let mut out = Features {
        width: w as u32,
        height: h as u32,
        keypoints: Vec::with_capacity(keep.len()),
        descriptors: Vec::with_capacity(keep.len() * DESCRIPTOR_LEN),
    };
    for i in keep {
        let row = desc.at_row::<f32>(i as i32)?;
        let mut d = row[..DESCRIPTOR_LEN].to_vec();
        root_sift(&mut d);
        out.keypoints.push(keypoints[i]);
        out.descriptors.extend(d);
    }
    Ok(out)
}
