//! `geostride sfm` as a library call: images in, a reconstruction, its report and its files out.
//! Features, exhaustive pair matching, the incremental reconstruction; COLMAP text model, PLY,
//! `report.json` and `report.md`.

use std::path::{Path, PathBuf};
use std::time::Instant;

use nalgebra::{Vector2, Vector3};
use serde::Serialize;
use sha2::{Digest, Sha256};

use super::cache::{SfmCache, key_of};
use super::colmap::{cameras_txt, images_txt, ply, points3d_txt};
use super::exif::{FOCAL_35MM_RANGE, GpsFix, PhotoMeta, focal_px_from_exif, read_meta};
use super::georef::{
    CentreMeasurement, GeorefError, GeorefReport, GeorefSettings, GroundPoint, Pick, PointRole,
    georeference,
};
use super::matching::{MatchSettings, match_features};
use super::reconstruct::{Reconstruction, SfmError, SfmSettings, reconstruct};
use super::sift::read_features;
use super::tracks::PairMatches;
use super::{FeatureSettings, Features};
use crate::camera::Camera;
use crate::geom::geodesy::{Ellipsoid, Geodetic, LocalTangentFrame};
use crate::imageio::ImageError;
use crate::progress::Progress;

/// What to reconstruct, and how.
#[derive(Clone, Debug)]
pub struct SfmJob {
    pub images: Vec<PathBuf>,
    /// The camera of every image (its size is scaled to the images' when the aspect agrees);
    /// `None`: a pinhole from the EXIF 35 mm focal length, principal point at the centre,
    /// refined.
    pub camera: Option<Camera>,
    /// With a position for every image (measured centres, else GPS in its EXIF), each image
    /// is matched with this many nearest (horizontally) rather than with every other; 0:
    /// always every pair.
    pub gps_neighbours: usize,
    /// Ordered frames (a flight's photos in time order, video frames): each image matched with
    /// the next this many only (ahead of GPS neighbours); 0: not used.
    pub sequential: usize,
    pub features: FeatureSettings,
    pub matching: MatchSettings,
    pub sfm: SfmSettings,
    /// Surveyed points with their picks and measured camera centres, in a site frame: the
    /// model is placed and adjusted in that frame (the EXIF GPS then only chooses pairs).
    pub georef: Option<GeorefInput>,
    /// Where features and matches are cached (`sfm::cache`); `None`: nowhere.
    pub cache_dir: Option<PathBuf>,
}

/// A pixel pick of a surveyed point, by image name (its file name, or the file name without
/// its extension), with where it was read.
#[derive(Clone, Debug, PartialEq)]
pub struct NamedPick {
    pub image: String,
    pub uv: Vector2<f64>,
    pub sigma_px: f64,
    pub file: PathBuf,
    pub line: usize,
}

/// A surveyed point in the site frame and its picks by image name.
#[derive(Clone, Debug, PartialEq)]
pub struct NamedGroundPoint {
    pub name: String,
    pub role: PointRole,
    pub position: Vector3<f64>,
    pub sigma_m: Vector3<f64>,
    pub picks: Vec<NamedPick>,
}

/// The survey's control and check points (`local`: their site-frame positions, in `points`'
/// order) with their picks, for the georeferencing. σ a file does not state are `sigmas` (pick
/// pixels, point metres); `image` names a pick's image in the job (`None`: the pick is left
/// out). Err: the first point used that has no height.
pub fn ground_points<'a>(
    points: &'a [crate::survey::model::Gcp],
    local: &[Vector3<f64>],
    (pick_sigma_px, gcp_sigma_m): (f64, f64),
    image: impl Fn(&str) -> Option<String>,
) -> Result<Vec<NamedGroundPoint>, &'a crate::survey::model::Gcp> {
    let mut out = Vec::new();
    for (p, local) in points.iter().zip(local) {
        let role = match p.role {
            crate::survey::Role::Control => PointRole::Control,
            crate::survey::Role::Check => PointRole::Check,
            crate::survey::Role::Disabled => continue,
        };
        if !local.z.is_finite() {
            return Err(p);
        }
        let picks = p.observations.iter().filter_map(|o| {
            Some(NamedPick {
                image: image(&o.image)?,
                uv: o.uv,
                sigma_px: o.sigma_px.unwrap_or(pick_sigma_px),
                file: o.file.clone(),
                line: o.line,
            })
        });
        out.push(NamedGroundPoint {
            name: p.name.clone(),
            role,
            position: *local,
            sigma_m: p.sigma_m.unwrap_or(Vector3::repeat(gcp_sigma_m)),
            picks: picks.collect(),
        });
    }
    Ok(out)
}

/// A measured camera centre in the site frame, by image name.
#[derive(Clone, Debug, PartialEq)]
pub struct NamedCentre {
    pub image: String,
    pub position: Vector3<f64>,
    pub sigma_m: Vector3<f64>,
}

/// What places the model in a site frame.
#[derive(Clone, Debug, Default)]
pub struct GeorefInput {
    pub points: Vec<NamedGroundPoint>,
    pub centres: Vec<NamedCentre>,
    pub settings: GeorefSettings,
    /// The site frame, in words, for the report (the CRS and origin).
    pub frame: String,
}

/// Why a job could not run.
#[derive(Debug, thiserror::Error)]
pub enum SfmJobError {
    #[error(transparent)]
    Image(#[from] ImageError),
    #[error(
        "{}: {width}x{height}, but {} is {first_w}x{first_h}: one camera is used for every image, so \
         every image must have its size (give the images of one camera)",
        path.display(),
        first.display()
    )]
    MixedSizes {
        path: PathBuf,
        width: u32,
        height: u32,
        first: PathBuf,
        first_w: u32,
        first_h: u32,
    },
    #[error(
        "the camera is for {cw}x{ch} images, the images are {width}x{height}: another aspect \
         ratio (give the calibration of this camera at this resolution)"
    )]
    CameraSize {
        cw: u32,
        ch: u32,
        width: u32,
        height: u32,
    },
    #[error(transparent)]
    Sfm(#[from] SfmError),
    #[error(transparent)]
    Meta(#[from] crate::io::FileError),
    #[error("{}:{line}: the pick of '{point}' at ({u:.1}, {v:.1}) lies outside the {width}x{height} image '{image}': check the image name and the pixel origin", file.display())]
    PickOutside {
        file: PathBuf,
        line: usize,
        point: String,
        image: String,
        u: f64,
        v: f64,
        width: u32,
        height: u32,
    },
    #[error(
        "none of the {picks} GCP picks names one of the {images} images given (the picks name {named}; the images are {given}): the GCPs lie outside every image, or the picks are for other images"
    )]
    NoPicksInImages {
        picks: usize,
        images: usize,
        named: String,
        given: String,
    },
    #[error(transparent)]
    Georef(#[from] GeorefError),
    #[error("the stage cache: {0}")]
    Cache(String),
    #[error(
        "{}: its name {reason}: COLMAP's images.txt and cameras.csv could not hold it; rename the file (letters, digits, '_', '-', '.')",
        path.display()
    )]
    BadName { path: PathBuf, reason: String },
    #[error(
        "{} and {}: two images of one name (case and extension aside): the model, the picks and the centres name images by their file names; rename one",
        first.display(),
        second.display()
    )]
    DuplicateName { first: PathBuf, second: PathBuf },
    #[error(
        "{}: its EXIF 35 mm-equivalent focal length is {value} mm: no lens has that (expected {} to {} mm); give --camera (a calibration file or a preset)",
        path.display(),
        FOCAL_35MM_RANGE.start(),
        FOCAL_35MM_RANGE.end()
    )]
    Focal35 { path: PathBuf, value: f64 },
    #[error(
        "{} ({a} mm) and {} ({b} mm): the EXIF focal lengths differ, but one camera is used for every image; give the photos of one zoom setting, or --camera",
        first.display(),
        second.display()
    )]
    FocalsDiffer {
        first: PathBuf,
        a: f64,
        second: PathBuf,
        b: f64,
    },
    #[error(
        "the measured camera centres lie {distance_km:.1} km (median) from the nearest GCP: the centres and the GCPs are not of one site, or not in one CRS (check the CRS and the heights of both files)"
    )]
    CentresFarFromGcps { distance_km: f64 },
}

impl SfmJobError {
    /// Whether the inputs are at fault (exit code 2) rather than the run.
    pub fn is_input(&self) -> bool {
        match self {
            SfmJobError::Image(ImageError::File { .. }) => true,
            SfmJobError::Image(_) => false,
            SfmJobError::Sfm(SfmError::Adjustment(_)) => false,
            SfmJobError::Georef(GeorefError::Adjustment(_)) => false,
            SfmJobError::Cache(_) => false,
            _ => true,
        }
    }
}

/// One image's part of the report.
#[derive(Clone, Debug, Serialize)]
pub struct ImageReport {
    pub name: String,
    pub registered: bool,
    pub features: usize,
    /// Features that observe a point of the model.
    pub observations: usize,
    /// Why it is not registered.
    pub reason: Option<String>,
}

/// A model the photos made beside the one kept.
#[derive(Clone, Debug, Serialize)]
pub struct OtherModelReport {
    pub images: Vec<String>,
    pub points: usize,
}

impl OtherModelReport {
    /// `r`'s other models, their images by name.
    fn of(r: &Reconstruction, names: &[String]) -> Vec<OtherModelReport> {
        r.other_models
            .iter()
            .map(|m| OtherModelReport {
                images: m.images.iter().map(|&i| names[i].clone()).collect(),
                points: m.points,
            })
            .collect()
    }
}

/// The model on the photos' GPS positions.
#[derive(Clone, Debug, Serialize)]
pub struct GpsPlacement {
    /// The east-north-up frame's origin: WGS 84 latitude, longitude (degrees), height (m).
    pub origin: [f64; 3],
    /// Model units per metre before placement.
    pub scale: f64,
    pub images: usize,
    /// RMS of the registered cameras' horizontal and vertical distances from their GPS
    /// positions after the similarity and the adjustment, metres.
    pub rms_horizontal_m: f64,
    pub rms_vertical_m: f64,
    /// The GPS positions' σ as priors of the adjustment (east, north, up, metres): DJI's RTK
    /// fields where every photo has them, else a consumer receiver's.
    pub prior_sigma_m: [f64; 3],
    pub rtk: bool,
    /// Images whose GPS position was not used, with why (far from the others', no altitude
    /// among fixes with one, far from where the others place the model).
    pub left_out: Vec<(String, String)>,
}

/// σ of a consumer drone's GPS position as a prior (east, north, up, metres): a few metres
/// horizontally, more vertically.
pub const CONSUMER_GPS_SIGMA_M: [f64; 3] = [3.0, 3.0, 5.0];

/// What a run found (`report.json`).
#[derive(Clone, Debug, Serialize)]
pub struct SfmReport {
    pub images: usize,
    pub registered: usize,
    pub points: usize,
    pub observations: usize,
    pub mean_track_length: f64,
    pub mean_reprojection_px: f64,
    /// The camera at the end: `[fx, fy, cx, cy, skew, k1, k2, p1, p2, k3, k4, k5, k6]`, pixel
    /// centres at integers.
    pub camera: Vec<f64>,
    pub pairs_matched: usize,
    /// How pairs were chosen: `all`, `sequential`, `centre-neighbours` (the measured centres)
    /// or `gps-neighbours` (the EXIF GPS).
    pub pair_selection: String,
    /// Where the camera came from: `given`, or without one where its starting focal length
    /// came from: `exif` (the 35 mm equivalent), `exif-focal-plane` (the focal length on the
    /// sensor's pixel pitch) or `guess` (1.2 times the longer side).
    pub camera_source: String,
    /// The focal length the reconstruction started from, pixels.
    pub starting_focal_px: f64,
    /// With the intrinsics refined: the principal point's σ and whether it was refined (else it
    /// stayed where it started).
    pub principal_point: Option<super::reconstruct::PrincipalPoint>,
    /// The models of images that share no points with the one kept (the largest), largest
    /// first: their images, registered there but not here.
    pub other_models: Vec<OtherModelReport>,
    /// With GPS: the model scaled and placed on the GPS positions (a local east-north-up frame
    /// at their centroid, metres), and the camera centres' distances from their GPS positions.
    pub gps: Option<GpsPlacement>,
    /// Placement in a site frame by surveyed points and camera centres, when given.
    pub georef: Option<GeorefReport>,
    /// The frame of the model's coordinates: `site` (the survey's, `site_frame` says which),
    /// `enu` (east-north-up metres at the GPS centroid) or `model` (arbitrary).
    pub frame: String,
    pub site_frame: Option<String>,
    /// Picks and centres naming images that are not among those given.
    pub unmatched_names: Vec<String>,
    pub initial_pair: (String, String),
    /// How the initial pair's relative pose was found: `model` (`essential` or `homography`),
    /// the matches each explains, the pairs passed over because the camera only turned.
    pub initial_pair_geometry: super::reconstruct::Start,
    /// The bundle adjustments of the whole model and the local ones made as it grew.
    pub adjustments: super::reconstruct::Adjustments,
    pub per_image: Vec<ImageReport>,
    pub seconds_features: f64,
    pub seconds_matching: f64,
    /// The features' cap per image (`geostride sfm register` finds the model images' features
    /// with it again).
    pub max_features: usize,
    /// Images whose features, and pairs whose matches, came from the cache.
    pub features_cached: usize,
    pub pairs_cached: usize,
    pub seconds_reconstruction: f64,
    /// Of `seconds_reconstruction`: placing the model (GCPs, centres or GPS) and its σ.
    pub seconds_georeferencing: f64,
}

/// A finished run: the model, the images' names and keypoints, the report.
pub struct SfmRun {
    pub reconstruction: Reconstruction,
    pub names: Vec<String>,
    pub keypoints: Vec<Vec<Vector2<f64>>>,
    pub width: u32,
    pub height: u32,
    pub report: SfmReport,
}

pub(crate) fn file_name(p: &Path) -> String {
    p.file_name().map_or_else(
        || p.display().to_string(),
        |n| n.to_string_lossy().into_owned(),
    )
}

/// What in an image's file name no model file can hold: `None` for a name written as it is.
pub(crate) fn name_problem(name: &str) -> Option<String> {
    if let Some(c) = name
        .chars()
        .find(|c| c.is_whitespace() || c.is_control() || *c == ',' || *c == '"')
    {
        return Some(format!(
            "{} holds {}",
            crate::io::clip(&format!("{name:?}"), 60),
            match c {
                ',' => "a comma".to_string(),
                '"' => "a double quote".to_string(),
                c if c.is_control() => format!("a control character ({c:?})"),
                _ => "a space".to_string(),
            }
        ));
    }
    None
}

/// The images' names checked (usable in every output, none twice: the name and the name without
/// its extension, case aside, are how picks and centres name an image) and their sizes from
/// their headers, before any is decoded (`None` where the header is not one geostride reads).
pub(crate) fn check_images(images: &[PathBuf]) -> Result<Vec<Option<(u32, u32)>>, SfmJobError> {
    let mut seen: std::collections::HashMap<String, usize> = std::collections::HashMap::new();
    let mut sizes = Vec::with_capacity(images.len());
    for (k, path) in images.iter().enumerate() {
        let name = match path.file_name().and_then(|n| n.to_str()) {
            Some(n) => n.to_string(),
            None => {
                return Err(SfmJobError::BadName {
                    path: path.clone(),
                    reason: "is not UTF-8 text".into(),
                });
            }
        };
        if let Some(reason) = name_problem(&name) {
            return Err(SfmJobError::BadName {
                path: path.clone(),
                reason,
            });
        }
        let stem = Path::new(&name)
            .file_stem()
            .map(|s| s.to_string_lossy().to_lowercase())
            .unwrap_or_default();
        for key in [name.to_lowercase(), stem] {
            if let Some(&first) = seen.get(&key) {
                if first != k {
                    return Err(SfmJobError::DuplicateName {
                        first: images[first].clone(),
                        second: path.clone(),
                    });
                }
            } else {
                seen.insert(key, k);
            }
        }
        let size = crate::imageheader::check_file(path)
            .map_err(|e| SfmJobError::Image(crate::imageio::file_error(path, e)))?;
        if size.is_none() && !super::sift::decodable(path) {
            return Err(SfmJobError::Image(crate::imageio::file_error(
                path,
                "cannot decode the image (not a JPEG, PNG, TIFF or other format OpenCV reads)",
            )));
        }
        sizes.push(size);
    }
    Ok(sizes)
}

/// Checks the EXIF focal lengths when no camera is given: a 35 mm equivalent must be a lens's,
/// and the photos that state a focal length (35 mm equivalent, else on the sensor) must share
/// the first one's (one camera is used for every image).
fn check_exif_focals(images: &[PathBuf], metas: &[PhotoMeta]) -> Result<(), SfmJobError> {
    for (path, m) in images.iter().zip(metas) {
        if let Some(v) = m.focal_35mm.filter(|v| !FOCAL_35MM_RANGE.contains(v)) {
            return Err(SfmJobError::Focal35 {
                path: path.clone(),
                value: v,
            });
        }
    }
    // Compared in the first photo's kind: a 35 mm equivalent is not a focal length on the sensor.
    let stated: fn(&PhotoMeta) -> Option<f64> = if metas[0].focal_35mm.is_some() {
        |m| m.focal_35mm
    } else {
        |m| m.focal_mm
    };
    let Some(f) = stated(&metas[0]) else {
        return Ok(());
    };
    for (path, m) in images.iter().zip(metas) {
        let Some(v) = stated(m) else { continue };
        if (v - f).abs() > 0.01 * f {
            return Err(SfmJobError::FocalsDiffer {
                first: images[0].clone(),
                a: f,
                second: path.clone(),
                b: v,
            });
        }
    }
    Ok(())
}

/// Refuses measured camera centres that lie far from every GCP (the two in different CRSs or
/// sites): no drone flies kilometres from the targets it photographs.
pub(crate) fn check_centres_near_gcps(g: &GeorefInput) -> Result<(), SfmJobError> {
    if g.points.is_empty() || g.centres.is_empty() {
        return Ok(());
    }
    let mut nearest: Vec<f64> = g
        .centres
        .iter()
        .map(|c| {
            g.points
                .iter()
                .map(|p| (p.position - c.position).xy().norm())
                .fold(f64::INFINITY, f64::min)
        })
        .collect();
    nearest.sort_by(f64::total_cmp);
    let median = nearest[nearest.len() / 2];
    if !(median <= MAX_CENTRE_GCP_DISTANCE_M) {
        return Err(SfmJobError::CentresFarFromGcps {
            distance_km: median / 1000.0,
        });
    }
    Ok(())
}

/// The farthest the measured camera centres (their median) may lie from the nearest GCP, metres.
pub const MAX_CENTRE_GCP_DISTANCE_M: f64 = 5000.0;

/// Runs the job; `features` and `matching` show the progress of those two stages.
///
/// The chain: check the images (sizes, names, EXIF) → index the GCP picks → features → pairs
/// → matches → reconstruction → placement (GCPs, else GPS) → report. An SfM step goes in as one
/// function between two of these, taking the previous step's plain output.
pub fn run_sfm(
    job: &SfmJob,
    features: &dyn Progress,
    matching: &dyn Progress,
) -> Result<SfmRun, SfmJobError> {
    if job.images.len() < 2 {
        return Err(SfmError::TooFewImages(job.images.len()).into());
    }
    // Everything that can be checked before the features is checked first.
    let sizes = check_images(&job.images)?;
    let metas: Vec<PhotoMeta> = job
        .images
        .iter()
        .map(|p| read_meta(p))
        .collect::<Result<_, _>>()?;
    if job.camera.is_none() {
        check_exif_focals(&job.images, &metas)?;
    }
    let header_size = common_size(job, &sizes)?;
    let names: Vec<String> = job.images.iter().map(|p| file_name(p)).collect();
    let mut unmatched_names = Vec::new();
    if let Some(g) = &job.georef {
        check_centres_near_gcps(g)?;
    }
    let mut indexed = match (&job.georef, header_size) {
        (Some(g), Some((width, height))) => Some(index_georef(
            g,
            &names,
            width,
            height,
            &mut unmatched_names,
        )?),
        _ => None,
    };
    let t = Instant::now();
    let cache = SfmCache::new(job.cache_dir.as_deref());
    let (mut found, feature_keys, features_cached) =
        extract_features(&job.images, &job.features, &cache, features)?;
    let seconds_features = t.elapsed().as_secs_f64();
    let (width, height) = (found[0].width, found[0].height);
    // Images whose headers geostride does not read: their picks are checked now.
    if let (Some(g), None) = (&job.georef, &indexed) {
        indexed = Some(index_georef(
            g,
            &names,
            width,
            height,
            &mut unmatched_names,
        )?);
    }
    let mut sfm_settings = job.sfm.clone();
    let (camera, camera_source) = job_camera(job, &metas[0], width, height)?;
    if camera_source != "given" {
        // Known only roughly: refined.
        sfm_settings.refine_intrinsics = true;
    }
    let t = Instant::now();
    let gps = consistent_gps(&metas, &names);
    let centres = indexed.as_ref().map(|(_, c)| c.as_slice());
    let (chosen, pair_selection) = choose_pairs(job, found.len(), &gps, centres);
    let (pairs, pairs_cached) = match_pairs(job, &found, &feature_keys, &chosen, &cache, matching)?;
    // Matched: the descriptors (a flight's largest data: 0.5 GB for 118 photos) are done with.
    found.iter_mut().for_each(|f| f.descriptors = Vec::new());
    let seconds_matching = t.elapsed().as_secs_f64();
    let keypoints = keypoint_positions(&found);
    let t = Instant::now();
    let sigmas = super::keypoint_sigmas(&found);
    let mut r = reconstruct(&camera, &keypoints, Some(&sigmas), &pairs, &sfm_settings)?;
    let t_georef = Instant::now();
    let (gps_placement, georef) = match (&job.georef, indexed) {
        (Some(g), Some((points, centres))) => {
            let mut settings = g.settings.clone();
            settings.refine_intrinsics |= sfm_settings.refine_intrinsics;
            let report = georeference(
                &mut r,
                &keypoints,
                Some(&sigmas),
                &points,
                &centres,
                &names,
                &settings,
            )?;
            (None, Some(report))
        }
        _ => match gps_placement(
            &mut r,
            &gps,
            &metas,
            &names,
            &keypoints,
            &sigmas,
            sfm_settings.refine_intrinsics,
        )? {
            Some((placement, report)) => (Some(placement), Some(report)),
            None => (None, None),
        },
    };
    let frame = if job.georef.is_some() && georef.is_some() {
        "site"
    } else if gps_placement.is_some() {
        "enu"
    } else {
        "model"
    };
    let seconds_georeferencing = t_georef.elapsed().as_secs_f64();
    let seconds_reconstruction = t.elapsed().as_secs_f64();
    let (observations, per_image) = image_reports(job, &r, &names, &found);
    let report = SfmReport {
        images: found.len(),
        registered: r.poses.iter().filter(|p| p.is_some()).count(),
        points: r.points.len(),
        observations,
        mean_track_length: observations as f64 / r.points.len().max(1) as f64,
        mean_reprojection_px: r.mean_reprojection_px,
        camera: r.camera.params().to_vec(),
        pairs_matched: pairs.len(),
        pair_selection: pair_selection.to_string(),
        camera_source: camera_source.to_string(),
        starting_focal_px: camera.fx,
        principal_point: r.principal_point,
        other_models: OtherModelReport::of(&r, &names),
        gps: gps_placement,
        georef,
        frame: frame.to_string(),
        site_frame: job.georef.as_ref().map(|g| g.frame.clone()),
        unmatched_names,
        initial_pair_geometry: r.start,
        adjustments: r.adjustments,
        initial_pair: (
            names[r.initial_pair.0].clone(),
            names[r.initial_pair.1].clone(),
        ),
        per_image,
        seconds_features,
        seconds_matching,
        max_features: job.features.max_features,
        features_cached,
        pairs_cached,
        seconds_reconstruction,
        seconds_georeferencing,
    };
    Ok(SfmRun {
        reconstruction: r,
        names,
        keypoints,
        width,
        height,
        report,
    })
}

/// The images' common size from their headers (none when a header is not read); a differing
/// size, or a given camera of another size, is an error.
fn common_size(
    job: &SfmJob,
    sizes: &[Option<(u32, u32)>],
) -> Result<Option<(u32, u32)>, SfmJobError> {
    match sizes[0] {
        Some(first) if sizes.iter().all(|s| s.is_some()) => {
            if let Some(k) = sizes.iter().position(|s| *s != Some(first)) {
                let (width, height) = sizes[k].expect("all known");
                return Err(SfmJobError::MixedSizes {
                    path: job.images[k].clone(),
                    width,
                    height,
                    first: job.images[0].clone(),
                    first_w: first.0,
                    first_h: first.1,
                });
            }
            if let Some(c) = &job.camera {
                given_camera(c, first.0, first.1)?;
            }
            Ok(Some(first))
        }
        _ => Ok(None),
    }
}

/// The camera to start from and where it came from: the given one ("given"), else a pinhole
/// whose focal length comes from the first photo's EXIF or a guess (`FocalSource::name`), to
/// be refined.
fn job_camera(
    job: &SfmJob,
    first: &PhotoMeta,
    width: u32,
    height: u32,
) -> Result<(Camera, &'static str), SfmJobError> {
    if let Some(c) = &job.camera {
        return Ok((given_camera(c, width, height)?, "given"));
    }
    let (f, source) = focal_px_from_exif(first, width, height);
    let c = Camera::pinhole(
        f,
        f,
        (f64::from(width) - 1.0) / 2.0,
        (f64::from(height) - 1.0) / 2.0,
    )
    .with_image_size(width, height);
    Ok((c, source.name()))
}

/// Each image's keypoints' positions, pixels.
fn keypoint_positions(found: &[Features]) -> Vec<Vec<Vector2<f64>>> {
    found
        .iter()
        .map(|f| f.keypoints.iter().map(|k| Vector2::new(k.x, k.y)).collect())
        .collect()
}

/// The image pairs to match and how they were chosen: a sequential window, the nearest by
/// measured centre when every image has one, else by GPS when every image has a fix, else all
/// pairs.
fn choose_pairs(
    job: &SfmJob,
    n: usize,
    gps: &ConsistentGps,
    centres: Option<&[CentreMeasurement]>,
) -> (Vec<(usize, usize)>, &'static str) {
    let all_gps: Option<Vec<GpsFix>> = gps.fixes.iter().copied().collect();
    let mut measured: Vec<Option<Vector2<f64>>> = vec![None; n];
    for c in centres.unwrap_or(&[]) {
        measured[c.image] = Some(c.position.xy());
    }
    let all_measured: Option<Vec<Vector2<f64>>> = measured.into_iter().collect();
    let neighbours = job.gps_neighbours > 0 && n > job.gps_neighbours + 1;
    match (&all_measured, &all_gps) {
        _ if job.sequential > 0 => (sequential_pairs(n, job.sequential), "sequential"),
        (Some(c), _) if neighbours => (nearest_pairs(c, job.gps_neighbours), "centre-neighbours"),
        (_, Some(g)) if neighbours => {
            (gps_neighbour_pairs(g, job.gps_neighbours), "gps-neighbours")
        }
        _ => (
            (0..n)
                .flat_map(|i| (i + 1..n).map(move |j| (i, j)))
                .collect(),
            "all",
        ),
    }
}

/// The matches of each chosen pair, from the cache when it holds them; how many came from it.
fn match_pairs(
    job: &SfmJob,
    found: &[Features],
    feature_keys: &[String],
    chosen: &[(usize, usize)],
    cache: &SfmCache,
    matching: &dyn Progress,
) -> Result<(Vec<PairMatches>, usize), SfmJobError> {
    matching.set_length(chosen.len() as u64);
    let mut pairs = Vec::new();
    let mut pairs_cached = 0;
    let match_settings = format!("{:?}", job.matching);
    for &(i, j) in chosen {
        let key = key_of(&[
            feature_keys[i].as_bytes(),
            feature_keys[j].as_bytes(),
            match_settings.as_bytes(),
        ]);
        let matches = match cache.matches(&key) {
            Some(m)
                if m.iter()
                    .all(|&(a, b)| a < found[i].len() && b < found[j].len()) =>
            {
                pairs_cached += 1;
                m
            }
            _ => {
                let m: Vec<(usize, usize)> = match_features(&found[i], &found[j], &job.matching)
                    .iter()
                    .map(|m| (m.a, m.b))
                    .collect();
                cache
                    .store_matches(&key, &m)
                    .map_err(|e| SfmJobError::Cache(e.to_string()))?;
                m
            }
        };
        pairs.push(PairMatches { i, j, matches });
        matching.inc(1);
    }
    Ok((pairs, pairs_cached))
}

/// Each image's line of the report, and the observations in all.
fn image_reports(
    job: &SfmJob,
    r: &Reconstruction,
    names: &[String],
    found: &[Features],
) -> (usize, Vec<ImageReport>) {
    let n = found.len();
    let mut seen = vec![0usize; n];
    for p in &r.points {
        for &(i, _) in &p.observations {
            seen[i] += 1;
        }
    }
    let other = |i: usize| {
        r.other_models
            .iter()
            .position(|m| m.images.contains(&i))
            .map(|k| (k, r.other_models[k].images.len()))
    };
    let per_image = (0..n)
        .map(|i| ImageReport {
            name: names[i].clone(),
            registered: r.poses[i].is_some(),
            features: found[i].len(),
            observations: seen[i],
            reason: r.poses[i].is_none().then(|| match other(i) {
                Some((k, size)) => format!(
                    "in model {} ({size} images), which shares no points with the one kept: \
                     photos of another place, or a gap in the flight",
                    k + 2
                ),
                None => format!(
                    "fewer than {} of its features agree on a pose with the model's points \
                     (too little overlap with the registered images, or too little texture)",
                    job.sfm.min_pnp_inliers
                ),
            }),
        })
        .collect();
    (seen.iter().sum(), per_image)
}

/// The image a pick or centre names: its file name, or its file name without the extension
/// (case aside).
fn image_index(names: &[String], wanted: &str) -> Option<usize> {
    names.iter().position(|n| n == wanted).or_else(|| {
        let stem = |s: &str| {
            Path::new(s)
                .file_stem()
                .map(|x| x.to_string_lossy().to_lowercase())
                .unwrap_or_default()
        };
        let w = stem(wanted);
        names.iter().position(|n| stem(n) == w)
    })
}

/// The georeferencing input with image indices; picks outside their image are an error, names
/// of images not given are collected in `unmatched`.
pub(crate) fn index_georef(
    g: &GeorefInput,
    names: &[String],
    width: u32,
    height: u32,
    unmatched: &mut Vec<String>,
) -> Result<(Vec<GroundPoint>, Vec<CentreMeasurement>), SfmJobError> {
    let mut note = |n: &str| {
        if !unmatched.iter().any(|u| u == n) {
            unmatched.push(n.to_string());
        }
    };
    let (w, h) = (f64::from(width), f64::from(height));
    let mut points = Vec::new();
    let mut total_picks = 0;
    let mut matched_picks = 0;
    for p in &g.points {
        let mut picks = Vec::new();
        for k in &p.picks {
            total_picks += 1;
            let Some(image) = image_index(names, &k.image) else {
                note(&k.image);
                continue;
            };
            if !(k.uv.x >= -0.5 && k.uv.x <= w - 0.5 && k.uv.y >= -0.5 && k.uv.y <= h - 0.5) {
                return Err(SfmJobError::PickOutside {
                    file: k.file.clone(),
                    line: k.line,
                    point: p.name.clone(),
                    image: k.image.clone(),
                    u: k.uv.x,
                    v: k.uv.y,
                    width,
                    height,
                });
            }
            matched_picks += 1;
            picks.push(Pick {
                image,
                uv: k.uv,
                sigma_px: k.sigma_px,
            });
        }
        points.push(GroundPoint {
            name: p.name.clone(),
            role: p.role,
            position: p.position,
            sigma_m: p.sigma_m,
            picks,
        });
    }
    let mut centres = Vec::new();
    for c in &g.centres {
        match image_index(names, &c.image) {
            Some(image) => centres.push(CentreMeasurement {
                image,
                position: c.position,
                sigma_m: c.sigma_m,
            }),
            None => note(&c.image),
        }
    }
    let placeable = points
        .iter()
        .filter(|p| {
            p.role == PointRole::Control && {
                let mut seen: Vec<usize> = p.picks.iter().map(|k| k.image).collect();
                seen.sort_unstable();
                seen.dedup();
                seen.len() >= 2
            }
        })
        .count();
    if matched_picks == 0 && total_picks > 0 && centres.len() < 3 {
        let list = |v: &[String]| {
            let shown: Vec<&str> = v.iter().take(5).map(String::as_str).collect();
            format!(
                "{}{}",
                shown.join(", "),
                if v.len() > 5 { ", ..." } else { "" }
            )
        };
        return Err(SfmJobError::NoPicksInImages {
            picks: total_picks,
            images: names.len(),
            named: list(unmatched),
            given: list(names),
        });
    }
    if placeable < 3 && centres.len() < 3 {
        return Err(GeorefError::NotEnough {
            control: placeable,
            centres: format!(" and {} image(s) have a measured centre", centres.len()),
        }
        .into());
    }
    Ok((points, centres))
}

/// Each image's features (from `cache` where it holds them, else found and stored), their
/// cache keys, and how many came from the cache. Every image must have the first one's size.
pub(crate) fn extract_features(
    images: &[PathBuf],
    settings: &FeatureSettings,
    cache: &SfmCache,
    features: &dyn Progress,
) -> Result<(Vec<Features>, Vec<String>, usize), SfmJobError> {
    features.set_length(images.len() as u64);
    let build = crate::cache::build_id();
    let feature_settings = format!("{:?}", settings);
    let mut found: Vec<Features> = Vec::with_capacity(images.len());
    let mut feature_keys = Vec::with_capacity(images.len());
    let mut features_cached = 0;
    for path in images {
        let key = if cache.is_active() {
            // The image's bytes: an edited or replaced file is a miss whatever its name.
            let bytes = std::fs::read(path)
                .map_err(|e| SfmJobError::Image(crate::imageio::file_error(path, e)))?;
            key_of(&[
                build.as_bytes(),
                &Sha256::digest(&bytes),
                feature_settings.as_bytes(),
            ])
        } else {
            String::new()
        };
        let f = match cache.features(&key) {
            Some(f) => {
                features_cached += 1;
                f
            }
            None => {
                let f = read_features(path, settings)?;
                cache
                    .store_features(&key, &f)
                    .map_err(|e| SfmJobError::Cache(e.to_string()))?;
                f
            }
        };
        feature_keys.push(key);
        if let Some(first) = found.first()
            && (f.width, f.height) != (first.width, first.height)
        {
            return Err(SfmJobError::MixedSizes {
                path: path.clone(),
                width: f.width,
                height: f.height,
                first: images[0].clone(),
                first_w: first.width,
                first_h: first.height,
            });
        }
        found.push(f);
        features.inc(1);
    }
    Ok((found, feature_keys, features_cached))
}

/// The given camera at the images' size.
fn given_camera(c: &Camera, width: u32, height: u32) -> Result<Camera, SfmJobError> {
    match c.image_size {
        Some(s) if (s.width, s.height) == (width, height) => Ok(c.clone()),
        Some(s) => c.scaled_to(width, height).ok_or(SfmJobError::CameraSize {
            cw: s.width,
            ch: s.height,
            width,
            height,
        }),
        None => Ok(c.clone().with_image_size(width, height)),
    }
}

/// East-north-up positions of GPS fixes (metres) in a frame at their centroid, and the frame.
pub(crate) fn enu_of(gps: &[GpsFix]) -> Option<(Vec<Vector3<f64>>, LocalTangentFrame)> {
    let g: Vec<Geodetic> = gps
        .iter()
        .map(|f| Geodetic::from_degrees(f.lat_deg, f.lon_deg, f.alt_m.unwrap_or(0.0)))
        .collect();
    let frame = LocalTangentFrame::at_centroid(Ellipsoid::WGS84, &g)?;
    Some((
        g.iter().map(|p| frame.enu_from_geodetic(p)).collect(),
        frame,
    ))
}

/// Each image with the next `window` in order: the pairs `(i, j)`, `i < j ≤ i + window`.
pub(crate) fn sequential_pairs(n: usize, window: usize) -> Vec<(usize, usize)> {
    (0..n)
        .flat_map(|i| (i + 1..n.min(i + window + 1)).map(move |j| (i, j)))
        .collect()
}

/// Each image with its `k` nearest by GPS (horizontal distance): the pairs, `i < j`, sorted.
pub(crate) fn gps_neighbour_pairs(gps: &[GpsFix], k: usize) -> Vec<(usize, usize)> {
    let Some((enu, _)) = enu_of(gps) else {
        return Vec::new();
    };
    let xy: Vec<Vector2<f64>> = enu.iter().map(|p| p.xy()).collect();
    nearest_pairs(&xy, k)
}

/// Each image with its `k` nearest by horizontal position (metres, any one frame): the pairs,
/// `i < j`, sorted.
pub(crate) fn nearest_pairs(xy: &[Vector2<f64>], k: usize) -> Vec<(usize, usize)> {
    let mut pairs = std::collections::BTreeSet::new();
    for i in 0..xy.len() {
        let others = xy.iter().copied().enumerate().filter(|&(j, _)| j != i);
        for j in nearest_to(xy[i], others, k) {
            pairs.insert((i.min(j), i.max(j)));
        }
    }
    pairs.into_iter().collect()
}

/// The indices of the `k` `positions` nearest `here` (horizontal distance, metres; ties to the
/// lower index), nearest first.
pub(crate) fn nearest_to(
    here: Vector2<f64>,
    positions: impl Iterator<Item = (usize, Vector2<f64>)>,
    k: usize,
) -> Vec<usize> {
    let mut by: Vec<(f64, usize)> = positions.map(|(j, p)| ((here - p).norm(), j)).collect();
    by.sort_by(|a, b| a.0.total_cmp(&b.0).then(a.1.cmp(&b.1)));
    by.into_iter().take(k).map(|(_, j)| j).collect()
}

/// The farthest a photo's GPS position may lie from the median of all of them (horizontally),
/// metres: a drone's flight, not a continent.
pub const MAX_GPS_SPREAD_M: f64 = 10_000.0;

/// The photos' GPS fixes that agree with each other: a fix far from the others' median, or
/// without the altitude the others have, is left out with why.
pub struct ConsistentGps {
    pub fixes: Vec<Option<GpsFix>>,
    pub left_out: Vec<(String, String)>,
}

/// The photos' fixes checked against each other ([`ConsistentGps`]).
pub(crate) fn consistent_gps(metas: &[PhotoMeta], names: &[String]) -> ConsistentGps {
    let mut fixes: Vec<Option<GpsFix>> = metas.iter().map(|m| m.gps).collect();
    let mut left_out = Vec::new();
    let median = |mut v: Vec<f64>| {
        v.sort_by(f64::total_cmp);
        v[v.len() / 2]
    };
    let known: Vec<GpsFix> = fixes.iter().flatten().copied().collect();
    if known.is_empty() {
        return ConsistentGps { fixes, left_out };
    }
    let centre = Geodetic::from_degrees(
        median(known.iter().map(|f| f.lat_deg).collect()),
        median(known.iter().map(|f| f.lon_deg).collect()),
        0.0,
    );
    let Some(frame) = LocalTangentFrame::at_centroid(Ellipsoid::WGS84, &[centre]) else {
        return ConsistentGps { fixes, left_out };
    };
    let with_altitude = known.iter().filter(|f| f.alt_m.is_some()).count() * 2 > known.len();
    for (i, f) in fixes.iter_mut().enumerate() {
        let Some(fix) = *f else { continue };
        let enu = frame.enu_from_geodetic(&Geodetic::from_degrees(fix.lat_deg, fix.lon_deg, 0.0));
        let d = enu.xy().norm();
        let why = if !(d <= MAX_GPS_SPREAD_M) {
            Some(format!(
                "its GPS position ({:.5}, {:.5}) is {:.1} km from the others' median: not used",
                fix.lat_deg,
                fix.lon_deg,
                d / 1000.0
            ))
        } else if with_altitude && fix.alt_m.is_none() {
            Some("its GPS position has no altitude, the others' have: not used".into())
        } else {
            None
        };
        if let Some(why) = why {
            left_out.push((names[i].clone(), why));
            *f = None;
        }
    }
    ConsistentGps { fixes, left_out }
}

/// Places and adjusts the model on the registered images' consistent GPS positions (priors at
/// their σ: DJI's RTK σ where every one has it, else a consumer receiver's), in an
/// east-north-up frame at their centroid; `None` with fewer than three.
fn gps_placement(
    r: &mut Reconstruction,
    gps: &ConsistentGps,
    metas: &[PhotoMeta],
    names: &[String],
    keypoints: &[Vec<Vector2<f64>>],
    sigmas: &[Vec<f64>],
    refine_intrinsics: bool,
) -> Result<Option<(GpsPlacement, GeorefReport)>, SfmJobError> {
    let used: Vec<usize> = (0..r.poses.len())
        .filter(|&i| r.poses[i].is_some() && gps.fixes[i].is_some())
        .collect();
    if used.len() < 3 {
        return Ok(None);
    }
    let geodetic: Vec<Geodetic> = used
        .iter()
        .map(|&i| {
            let f = gps.fixes[i].expect("used");
            Geodetic::from_degrees(f.lat_deg, f.lon_deg, f.alt_m.unwrap_or(0.0))
        })
        .collect();
    let Some(frame) = LocalTangentFrame::at_centroid(Ellipsoid::WGS84, &geodetic) else {
        return Ok(None);
    };
    let rtk: Option<Vec<[f64; 3]>> = used.iter().map(|&i| metas[i].rtk_sigma_m).collect();
    let centres: Vec<CentreMeasurement> = used
        .iter()
        .zip(&geodetic)
        .enumerate()
        .map(|(k, (&i, g))| CentreMeasurement {
            image: i,
            position: frame.enu_from_geodetic(g),
            // DJI gives longitude, latitude, height: east, north, up.
            sigma_m: Vector3::from(rtk.as_ref().map_or(CONSUMER_GPS_SIGMA_M, |s| s[k]))
                .map(|v| v.max(0.005)),
        })
        .collect();
    let settings = GeorefSettings {
        refine_intrinsics,
        ..GeorefSettings::default()
    };
    let report = match georeference(r, keypoints, Some(sigmas), &[], &centres, names, &settings) {
        Ok(report) => report,
        // Collinear or too few agreeing positions: the model stays in its own frame.
        Err(GeorefError::NotEnough { .. }) => return Ok(None),
        Err(e) => return Err(e.into()),
    };
    let o = frame.origin;
    let (h, v) = report
        .centres_rms
        .map_or((f64::NAN, f64::NAN), |c| (c.horizontal_m, c.vertical_m));
    let mut left_out = gps.left_out.clone();
    left_out.extend(report.left_out.iter().cloned());
    let placement = GpsPlacement {
        origin: [o.lat.to_degrees(), o.lon.to_degrees(), o.h],
        scale: 1.0 / report.scale,
        images: report.centres_rms.map_or(0, |c| c.points),
        rms_horizontal_m: h,
        rms_vertical_m: v,
        prior_sigma_m: rtk.as_ref().map_or(CONSUMER_GPS_SIGMA_M, |s| s[0]),
        rtk: rtk.is_some(),
        left_out,
    };
    Ok(Some((placement, report)))
}

/// `report.md`: the summary and a line per image.
pub(crate) fn report_md(r: &SfmReport) -> String {
    let principal_point = match r.principal_point {
        None => String::new(),
        Some(p) => format!(
            "- principal point: {} (σ {:.2}, {:.2} px with the images; refined within {} px)\n",
            if p.refined { "refined" } else { "held" },
            p.sigma_px[0],
            p.sigma_px[1],
            super::reconstruct::MAX_PRINCIPAL_POINT_SIGMA_PX
        ),
    };
    let mut s = format!(
        "# Structure from motion\n\n\
         - images registered: {} of {}\n\
         - points: {}, observations: {} (mean track length {:.2})\n\
         - mean reprojection error: {:.3} px\n\
         - camera: fx {:.2}, fy {:.2}, cx {:.2}, cy {:.2}, k1 {:.4}, k2 {:.4} (its focal \
         length started at {:.1} px: {})\n\
         {}\
         - started from: {} and {} (pose from the {} matrix; of the {} matches it kept, {} fit \
         one homography; {} pairs that only turned passed over)\n\
         - bundle adjustments as the model grew: {} of the whole model ({:.1} s), {} local (an \
         image and its neighbours, {:.1} s)\n\
         - time: features {:.1} s ({} images from the cache), matching {:.1} s ({} pairs, {} from \
         the cache), reconstruction {:.1} s (georeferencing {:.1} s of it)\n\n\
         | image | registered | features | observations | why not |\n\
         | --- | --- | --- | --- | --- |\n",
        r.registered,
        r.images,
        r.points,
        r.observations,
        r.mean_track_length,
        r.mean_reprojection_px,
        r.camera[0],
        r.camera[1],
        r.camera[2],
        r.camera[3],
        r.camera[5],
        r.camera[6],
        r.starting_focal_px,
        r.camera_source,
        principal_point,
        r.initial_pair.0,
        r.initial_pair.1,
        r.initial_pair_geometry.model,
        r.initial_pair_geometry.essential_inliers,
        r.initial_pair_geometry.homography_inliers,
        r.initial_pair_geometry.rotations_skipped,
        r.adjustments.global,
        r.adjustments.seconds_global,
        r.adjustments.local,
        r.adjustments.seconds_local,
        r.seconds_features,
        r.features_cached,
        r.seconds_matching,
        r.pairs_matched,
        r.pairs_cached,
        r.seconds_reconstruction,
        r.seconds_georeferencing
    );
    for i in &r.per_image {
        s.push_str(&format!(
            "| {} | {} | {} | {} | {} |\n",
            i.name,
            if i.registered { "yes" } else { "no" },
            i.features,
            i.observations,
            i.reason.as_deref().unwrap_or("")
        ));
    }
    if !r.other_models.is_empty() {
        s.push_str(&format!(
            "\n## Other models\n\nThe photos fall into {} models that share no points; the \
             largest (model 1, {} images) is kept and written. The others (their images are \
             not registered above; run `geostride sfm` on each group alone to model it):\n\n",
            r.other_models.len() + 1,
            r.registered
        ));
        for (k, m) in r.other_models.iter().enumerate() {
            s.push_str(&format!(
                "- model {}: {} images, {} points: {}\n",
                k + 2,
                m.images.len(),
                m.points,
                m.images.join(", ")
            ));
        }
    }
    if let Some(g) = &r.gps {
        s.push_str(&format!(
            "\n## Placed on the EXIF GPS\n\n\
             East-north-up metres at {:.7}, {:.7}, {:.1} m; {} images placed by a similarity, \
             then adjusted with their GPS positions as priors (σ {:.3}/{:.3}/{:.3} m east/north/up, \
             {}); cameras {:.2} m RMS horizontally and {:.2} m vertically from their GPS.\n",
            g.origin[0],
            g.origin[1],
            g.origin[2],
            g.images,
            g.prior_sigma_m[0],
            g.prior_sigma_m[1],
            g.prior_sigma_m[2],
            if g.rtk {
                "DJI's RTK fields"
            } else {
                "a consumer receiver's"
            },
            g.rms_horizontal_m,
            g.rms_vertical_m
        ));
        for (name, why) in &g.left_out {
            s.push_str(&format!("\nLeft out: {name}: {why}\n"));
        }
    }
    if let Some(g) = r.georef.as_ref().filter(|_| r.frame == "site") {
        s.push_str(&georef_md(g, r.site_frame.as_deref().unwrap_or("")));
    }
    if !r.unmatched_names.is_empty() {
        s.push_str(&format!(
            "\nPicks or centres name images not given here (ignored): {}\n",
            r.unmatched_names.join(", ")
        ));
    }
    s
}

/// The georeferencing section of `report.md`.
pub(crate) fn georef_md(g: &GeorefReport, frame: &str) -> String {
    let rms = |r: &Option<super::georef::Rms>| match r {
        Some(r) => format!(
            "{:.3} m horizontally, {:.3} m vertically ({} points)",
            r.horizontal_m, r.vertical_m, r.points
        ),
        None => "none".into(),
    };
    let px = |p: Option<f64>| p.map_or("-".into(), |p| format!("{p:.2} px"));
    let mut s = format!(
        "\n## Georeferencing\n\n\
         - frame: {frame}\n\
         - placed by the {}, then adjusted with the control points' and centres' σ\n\
         - control points: {}, picks {} RMS from the surveyed positions, {} mean from the adjusted ones\n\
         - check points: {}, picks {}\n\
         - camera centres against their measurements: {}\n\n\
         | point | role | images | east m | north m | up m | picks px | σ e/n/u m |\n\
         | --- | --- | --- | --- | --- | --- | --- | --- |\n",
        g.placed_by,
        rms(&g.control_rms),
        px(g.control_rms_px),
        px(g.control_mean_px),
        rms(&g.check_rms),
        px(g.check_rms_px),
        rms(&g.centres_rms),
    );
    for p in &g.points {
        let (e, n, u) = match p.residual_m {
            Some(r) => (
                format!("{:.3}", r[0]),
                format!("{:.3}", r[1]),
                format!("{:.3}", r[2]),
            ),
            None => ("-".into(), "-".into(), "-".into()),
        };
        s.push_str(&format!(
            "| {} | {} | {} | {e} | {n} | {u} | {} | {:.3}/{:.3}/{:.3} |\n",
            p.name,
            match p.role {
                PointRole::Control => "control",
                PointRole::Check => "check",
            },
            p.images,
            p.rms_px.map_or("-".into(), |x| format!("{x:.2}")),
            p.sigma_m[0],
            p.sigma_m[1],
            p.sigma_m[2]
        ));
    }
    for (name, why) in &g.left_out {
        s.push_str(&format!("\nLeft out: {name}: {why}\n"));
    }
    if g.sigma_scale > 1.0 {
        s.push_str(&format!(
            "\nThe cameras' σ are scaled by {:.2}: the surveyed points and centres spread that much more than their σ say.\n",
            g.sigma_scale
        ));
    }
    s
}

/// `cameras.csv`: each image, whether registered, its camera centre and its `cam_from_world`
/// rotation as a unit quaternion, in the model's frame: east-north-up metres at the GPS centroid
/// when placed on the GPS (`frame` says which), else the arbitrary frame of the reconstruction.
pub(crate) fn cameras_csv(run: &SfmRun, crs: Option<&CrsPositions>) -> String {
    cameras_csv_of(
        &run.names,
        &run.reconstruction.poses,
        &run.report.frame,
        run.report
            .georef
            .as_ref()
            .map(|g| g.camera_sigma.as_slice()),
        crs,
    )
}

/// `cameras.csv` of images `names` with `poses` in `frame`, their σ when georeferenced.
pub(crate) fn cameras_csv_of(
    names: &[String],
    poses: &[Option<crate::geom::Rigid3>],
    frame: &str,
    sigmas: Option<&[Option<super::georef::CameraSigma>]>,
    crs: Option<&CrsPositions>,
) -> String {
    let mut s = String::from("image,registered,frame,x,y,z,qw,qx,qy,qz");
    if crs.is_some() {
        s.push_str(",crs_x,crs_y,crs_h");
    }
    if sigmas.is_some() {
        s.push_str(",sigma_e_m,sigma_n_m,sigma_u_m,sigma_rotation_deg");
    }
    s.push('\n');
    for (i, name) in names.iter().enumerate() {
        let name = crate::survey::write::csv_field(name);
        match poses[i] {
            Some(pose) => {
                let c = pose.centre();
                let q = nalgebra::UnitQuaternion::from_rotation_matrix(&pose.rotation);
                s.push_str(&format!(
                    "{name},yes,{frame},{:.4},{:.4},{:.4},{:.9},{:.9},{:.9},{:.9}",
                    c.x, c.y, c.z, q.w, q.i, q.j, q.k
                ));
                if let Some(p) = crs.and_then(|c| c.positions[i]) {
                    s.push_str(&format!(",{:.4},{:.4},{:.4}", p[0], p[1], p[2]));
                } else if crs.is_some() {
                    s.push_str(",,,");
                }
                if let Some(Some(c)) = sigmas.map(|v| v[i]) {
                    s.push_str(&format!(
                        ",{:.4},{:.4},{:.4},{:.5}",
                        c.centre_m[0], c.centre_m[1], c.centre_m[2], c.rotation_deg
                    ));
                } else if sigmas.is_some() {
                    s.push_str(",,,,");
                }
            }
            None => {
                s.push_str(&format!("{name},no,{frame},,,,,,,"));
                if crs.is_some() {
                    s.push_str(",,,");
                }
                if sigmas.is_some() {
                    s.push_str(",,,,");
                }
            }
        }
        s.push('\n');
    }
    s
}

/// The camera centres in the survey's CRS (easting or longitude, northing or latitude, height),
/// per image, for `cameras.csv` and the GeoPackage.
#[derive(Clone, Debug)]
pub struct CrsPositions {
    pub positions: Vec<Option<[f64; 3]>>,
}

/// Writes the run's files into `out` (which exists): the COLMAP text model, `points.ply`,
/// `cameras.csv`, `report.json`, `report.md`. Returns their names.
pub fn write_outputs(
    out: &Path,
    run: &SfmRun,
    crs: Option<&CrsPositions>,
) -> std::io::Result<Vec<String>> {
    let r = &run.reconstruction;
    let files = [
        ("cameras.txt", cameras_txt(&r.camera, run.width, run.height)),
        ("images.txt", images_txt(r, &run.names, &run.keypoints)),
        ("points3D.txt", points3d_txt(r, &run.keypoints)),
        ("points.ply", ply(r)),
        ("cameras.csv", cameras_csv(run, crs)),
        (
            "report.json",
            serde_json::to_string_pretty(&run.report).map_err(std::io::Error::other)?,
        ),
        ("report.md", report_md(&run.report)),
    ];
    let mut written = Vec::new();
    for (name, text) in files {
        crate::io::write_atomic(&out.join(name), text.as_bytes())?;
        written.push(name.to_string());
    }
    Ok(written)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Zoom settings are told apart in one kind of focal length: a photo stating its 35 mm
    /// equivalent and one stating only its focal length on the sensor are not two zooms.
    #[test]
    fn exif_focal_lengths_are_compared_in_one_kind() {
        let images = [PathBuf::from("a.jpg"), PathBuf::from("b.jpg")];
        let meta = |f35: Option<f64>, mm: Option<f64>| PhotoMeta {
            focal_35mm: f35,
            focal_mm: mm,
            ..PhotoMeta::default()
        };
        let same = [meta(Some(24.0), Some(4.5)), meta(None, Some(4.5))];
        assert!(check_exif_focals(&images, &same).is_ok());
        let zoomed = [meta(None, Some(4.5)), meta(None, Some(9.0))];
        let e = check_exif_focals(&images, &zoomed).unwrap_err().to_string();
        assert!(
            e.contains("focal lengths differ") && e.contains("b.jpg (9 mm)"),
            "{e}"
        );
        let zoomed = [meta(Some(24.0), None), meta(Some(48.0), Some(9.0))];
        assert!(check_exif_focals(&images, &zoomed).is_err());
    }

    #[test]
    fn a_sequential_window_pairs_each_image_with_the_next() {
        assert_eq!(
            sequential_pairs(4, 2),
            vec![(0, 1), (0, 2), (1, 2), (1, 3), (2, 3)]
        );
        assert_eq!(sequential_pairs(3, 10).len(), 3);
        assert!(sequential_pairs(1, 3).is_empty());
    }

    #[test]
    fn gps_neighbours_pair_each_image_with_its_nearest() {
        // A line of five positions about 11 m apart (1e-4 degrees of latitude).
        let gps: Vec<GpsFix> = (0..5)
            .map(|k| GpsFix {
                lat_deg: 46.0 + 1e-4 * f64::from(k),
                lon_deg: 7.0,
                alt_m: Some(500.0),
            })
            .collect();
        assert_eq!(
            gps_neighbour_pairs(&gps, 1),
            vec![(0, 1), (1, 2), (2, 3), (3, 4)]
        );
        assert_eq!(gps_neighbour_pairs(&gps, 4).len(), 10);
    }

    /// Measured centres for every image choose the pairs before the EXIF GPS: six photos whose
    /// GPS puts them on a line but whose centres are two rows of three.
    #[test]
    fn measured_centres_choose_the_neighbours_before_the_gps() {
        let job = SfmJob {
            images: vec![PathBuf::new(); 6],
            camera: None,
            gps_neighbours: 1,
            sequential: 0,
            features: FeatureSettings::default(),
            matching: MatchSettings::default(),
            sfm: SfmSettings::default(),
            georef: None,
            cache_dir: None,
        };
        let gps = ConsistentGps {
            fixes: (0..6)
                .map(|k| {
                    Some(GpsFix {
                        lat_deg: 46.0 + 1e-4 * f64::from(k),
                        lon_deg: 7.0,
                        alt_m: Some(500.0),
                    })
                })
                .collect(),
            left_out: Vec::new(),
        };
        // Image k at column k % 3 (10 m apart), row k / 3 (3 m apart).
        let centres: Vec<CentreMeasurement> = (0..6)
            .map(|k| CentreMeasurement {
                image: k,
                position: Vector3::new(10.0 * (k % 3) as f64, 3.0 * (k / 3) as f64, 30.0),
                sigma_m: Vector3::repeat(0.03),
            })
            .collect();
        let (pairs, how) = choose_pairs(&job, 6, &gps, Some(&centres));
        assert_eq!(how, "centre-neighbours");
        assert_eq!(pairs, vec![(0, 3), (1, 4), (2, 5)]);
        let (pairs, how) = choose_pairs(&job, 6, &gps, Some(&centres[..5]));
        assert_eq!(how, "gps-neighbours");
        assert_eq!(pairs, vec![(0, 1), (1, 2), (2, 3), (3, 4), (4, 5)]);
    }
}
