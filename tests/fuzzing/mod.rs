//! Fuzzing every parser of geostride on the stable toolchain: seeded generators (random bytes,
//! mutations of valid files, structured rows of hostile values) fed to the in-memory parsers.
//! A parser must return `Ok` or an error that names the file, never panic, and stay fast and
//! small. Shared by `tests/fuzz.rs` (a bounded run in `make test`) and `examples/fuzz.rs` (the
//! long run of `make fuzz`, which also feeds 200 MB inputs to the commands).

#![allow(dead_code, unused_braces)]

use std::alloc::{GlobalAlloc, Layout, System};
use std::path::Path;
use std::sync::atomic::{AtomicUsize, Ordering};
use std::time::Instant;

use rand::{RngExt, SeedableRng};
use rand_chacha::ChaCha8Rng;

#[path = "../common/exif.rs"]
mod exif;
#[path = "../common/onnx.rs"]
mod onnx;

/// The system allocator, counting the bytes in use and their peak.
pub struct Counting;

pub static IN_USE: AtomicUsize = AtomicUsize::new(0);
pub static PEAK: AtomicUsize = AtomicUsize::new(0);

unsafe impl GlobalAlloc for Counting {
    unsafe fn alloc(&self, layout: Layout) -> *mut u8 {
        let p = unsafe { System.alloc(layout) };
        if !p.is_null() {
            let now = IN_USE.fetch_add(layout.size(), Ordering::Relaxed) + layout.size();
            PEAK.fetch_max(now, Ordering::Relaxed);
        }
        p
    }

    unsafe fn dealloc(&self, ptr: *mut u8, layout: Layout) {
        unsafe { System.dealloc(ptr, layout) };
        IN_USE.fetch_sub(layout.size(), Ordering::Relaxed);
    }

    unsafe fn realloc(&self, ptr: *mut u8, layout: Layout, new_size: usize) -> *mut u8 {
        let p = unsafe { System.realloc(ptr, layout, new_size) };
        if !p.is_null() {
            if new_size >= layout.size() {
                let now = IN_USE.fetch_add(new_size - layout.size(), Ordering::Relaxed) + new_size
                    - layout.size();
                PEAK.fetch_max(now, Ordering::Relaxed);
            } else {
                IN_USE.fetch_sub(layout.size() - new_size, Ordering::Relaxed);
            }
        }
        p
    }
}

/// What a parser did with one input.
pub enum Outcome {
    Ok,
    /// An error and its message.
    Err(String),
}

/// One parser under fuzzing.
pub struct Target {
    pub name: &'static str,
    /// The share of `make test`'s bounded run this target gets: PROJ's parser, behind `crs`,
    /// takes milliseconds on a string that is nearly a CRS. `make fuzz` gives every target all.
    pub share: f64,
    /// The file name the parser is told it reads (errors must name it).
    pub file: &'static str,
    /// Valid inputs to mutate.
    pub seeds: Vec<Vec<u8>>,
    pub run: Parser,
}

/// A parser run on (the file name it is told, the input).
pub type Parser = Box<dyn Fn(&Path, &[u8]) -> Outcome + Send + Sync>;

fn text(bytes: &[u8]) -> Option<&str> {
    std::str::from_utf8(bytes).ok()
}

fn outcome<T, E: std::fmt::Display>(r: Result<T, E>) -> Outcome {
    match r {
        Ok(_) => Outcome::Ok,
        Err(e) => Outcome::Err(e.to_string()),
    }
}

/// Text parsers see what `FileCtx::read_text` would give them: bytes that are not UTF-8 are an
/// error there, named with the file.
fn not_text(path: &Path) -> Outcome {
    Outcome::Err(format!("{}: not UTF-8 text", path.display()))
}

macro_rules! target {
    ($name:expr, $file:expr, [$($seed:expr),* $(,)?], |$p:ident, $t:ident| $body:expr) => {
        Target {
            name: $name,
            share: 1.0,
            file: $file,
            seeds: vec![$(Vec::from($seed.as_bytes())),*],
            run: Box::new(|$p: &Path, bytes: &[u8]| match text(bytes) {
                Some($t) => outcome($body),
                None => not_text($p),
            }),
        }
    };
}

const EMLID: &str = "Name,Easting,Northing,Elevation,Description,Longitude,Latitude,Ellipsoidal height,Easting RMS,Northing RMS,Elevation RMS,Lateral RMS,Antenna height,Antenna height units,Solution status,Averaging start,Averaging end,Samples,PDOP,Base easting,Base northing,Base elevation,Base longitude,Base latitude,Base ellipsoidal height,Baseline,CS name
GCP1,654481.99876,695998.08092,58.454,,4.432755527,51.074089203,58.454,0.01,0.01,0.02,,,,FIX,,,,,,,,,,,,ETRS89 / Belgian Lambert 2008
GCP2,654481.98491,696001.88703,58.407,,4.432755384,51.074123416,58.407,0.01,0.01,0.02,,,,FIX,,,,,,,,,,,,ETRS89 / Belgian Lambert 2008
CHK-1,654495.5,696001.9,58.5,,4.432947,51.0741233,58.5,0.012,0.011,0.02,,,,FLOAT,,,,,,,,,,,,ETRS89 / Belgian Lambert 2008
";
const ODM: &str = "EPSG:32631\n600391.4 5659042.6 52.1 1520.5 980.25 DJI_0001.JPG GCP1\n600401.4 5659042.6 52.3 2020.5 985.25 DJI_0001.JPG GCP2\n600391.4 5659052.6 nan 1525.5 480.25 DJI_0002.JPG\n";
const OPENSFM: &str = r#"{"points": [{"id": "g1", "position": {"latitude": 50.8, "longitude": 4.35, "altitude": 52.0}, "observations": [{"shot_id": "a.jpg", "projection": [0.1, -0.2]}]}, {"id": "g2", "position": {"latitude": 50.8001, "longitude": 4.3502}, "observations": []}]}"#;
const METASHAPE: &str = "#CoordinateSystem: ETRS89 / Belgian Lambert 2008 (EPSG::3812)\n#Label,X/East,Y/North,Z/Altitude,X_error,Y_error,Z_error,Enabled\nA,654482.0,696000.0,58.4,0.01,0.01,0.02,1\nB,654490.5,695990.25,58.1,0.01,0.01,0.02,0\nCHK-C,654470,696010,57.9,,,,1\n";
const CSV: &str = "name,x,y,z\nA,654482.0,696000.0,58.4\nB,654490.5,695990.25,58.1\n";
const PETRACK: &str =
    "3\n100.0 200.0 0.0 512.5 300.25\n300.0 200.0 0.0 900.5 310.0\n100.0 400.0 15.0 520.0 700.0\n";
const PICKS: &str = "name,image,u,v,sigma\nGCP1,video.mp4#0,99.21,445.86,0.5\nGCP2,video.mp4#0,99.74,331.96,0.5\nCHK-1,video.mp4#0,500,500\n";
const YAML: &str = "%YAML:1.0\n---\nimage_width: 1920\nimage_height: 1080\ncamera_matrix: !!opencv-matrix\n   rows: 3\n   cols: 3\n   dt: d\n   data: [ 1378.3, 0., 959.5, 0., 1378.3, 539.5, 0., 0., 1. ]\ndistortion_coefficients: !!opencv-matrix\n   rows: 1\n   cols: 5\n   dt: d\n   data: [ -0.01, 0.02, 0.0001, -0.0002, 0.001 ]\navg_reprojection_error: 0.3\n";
const XML: &str = "<?xml version=\"1.0\" encoding=\"UTF-8\"?>\n<calibration>\n  <projection>frame</projection>\n  <width>4000</width>\n  <height>3000</height>\n  <f>3000.5</f>\n  <cx>10.2</cx>\n  <cy>-5.1</cy>\n  <b1>0.5</b1>\n  <k1>-0.01</k1>\n  <k2>0.02</k2>\n  <k4>0.0001</k4>\n  <p1>0.0001</p1>\n  <covariance>\n    <params>f cx cy</params>\n    <coeffs>1 0 0 0 1 0 0 0 1</coeffs>\n  </covariance>\n</calibration>\n";
const JSON_CAL: &str = include_str!("../../calib/dji-mini3pro-4k.json");
const SCENE: &str = include_str!("../scenes/hover-drift.toml");
const PROJECT: &str = "name = \"fuzz\"\n[camera]\ncalibration = \"mini3pro\"\n[survey]\ngcps = \"gcps.csv\"\npicks = [\"picks.csv\"]\nheight = \"ellipsoidal\"\norigin = \"51.07,4.43,52\"\n[video]\npath = \"video.mp4\"\nduration_s = 2\n[ground]\nkind = \"deck\"\ncentre_line = [[654460.0, 696000.0], [654540.0, 696000.0]]\nwidth_m = 5.0\n[detect]\nkind = \"boxes\"\nboxes = \"boxes.txt\"\nroi = [0, 0, 100, 100]\n[track]\nkind = \"klt\"\n[projection]\nhead_height_m = 1.7\n[smooth]\nkind = \"kalman_rts\"\n[export]\ncrs = \"EPSG:32631\"\nformats = [\"csv\", \"geojson\"]\n";
const MOT: &str = "frame,id,left,top,width,height,conf\n1,-1,100,100,40,80,0.9\n2,-1,102.5,101,40,80,0.95,-1,-1,-1\n3,7,104,102,40,80,-1\n";
const JSONL: &str = "{\"frame\": 0, \"boxes\": [{\"bbox\": [1, 2, 30, 60], \"score\": 0.9, \"label\": \"person\"}]}\n{\"frame\": 1, \"bbox\": [3, 4, 30, 60], \"score\": 0.8}\n";
const COCO: &str = r#"{"images": [{"id": 1, "file_name": "frame_0001.jpg"}, {"id": 2, "frame_index": 7}], "categories": [{"id": 1, "name": "person"}, {"id": 2, "name": "car"}], "annotations": [{"image_id": 1, "category_id": 1, "bbox": [1, 2, 30, 60], "score": 0.9}, {"image_id": 2, "category_id": 2, "bbox": [1, 2, 3, 4]}]}"#;
const BAL: &str = "2 2 4\n0 0 -1.0 2.0\n1 0 -1.5 2.5\n0 1 3.0 -1.0\n1 1 2.5 -0.5\n0.01 0.02 0.03 0.1 0.2 -5.0 500 0 0\n-0.01 0.02 0.0 0.3 0.1 -5.0 500 0 0\n0.5 0.2 1.0\n-0.3 0.4 0.8\n";
const HEIGHTS: &str = "id,height_m,sd_m\n1,1.75,0.02\n2,1.62\n3,1.8,0\n";
const SAMPLES: &str = "frame,id,e_m,n_m,in_view\n0,1,1.5,2.5,1\n0,2,3.25,-4,0\n1,1,1.6,2.5,1\n";
const DETECTIONS: &str = "frame,u_px,v_px,var_u_px2,cov_uv_px2,var_v_px2,score,box_x_px,box_y_px,box_w_px,box_h_px\n0,941.217,475.116,10.000,0.000,10.000,1.000,920.00,460.00,40.00,30.00\n0,1879.622,643.743,19.800,0.000,10.000,0.900,1860.00,630.00,38.00,28.00\n3,12.5,7.25,9,0,9,1,0,0,20,20\n";
const POSES: &str = "frame,time_s,centre_e_m,centre_n_m,centre_u_m,rvec_x,rvec_y,rvec_z,tvec_x,tvec_y,tvec_z\n0,0.0,0,0.25,36.58,3.1409,0.0004,-0.0029,0.0686,0.2745,36.5816\n1,0.04,0.0019,0.253,36.58,3.1411,0.0003,-0.0027,0.0606,0.2707,36.5814\n";
const GCPS_TRUTH: &str = "name,e_m,n_m,u_m,x,y,ellipsoidal_height_m\nGCP1,-18.0,-1.9,6.39875,654482.002377,695998.082162,58.398776\nGCP2,-18.0,1.9,6.39875,654481.9986,696001.882059,58.398776\n";
const TRUTH_BOXES: &str = "frame,person,kind,x,y,w,h\n0,7,body,1471.64,568.05,81.12,50.45\n0,7,shadow,1443.71,512.73,62.48,88.02\n";

/// A folder with the (empty) files the project seed names.
fn project_dir() -> &'static Path {
    static DIR: std::sync::OnceLock<std::path::PathBuf> = std::sync::OnceLock::new();
    DIR.get_or_init(|| {
        let d = std::env::temp_dir().join(format!("geostride-fuzz-project-{}", std::process::id()));
        std::fs::create_dir_all(&d).unwrap();
        for f in [
            "gcps.csv",
            "picks.csv",
            "video.mp4",
            "boxes.txt",
            "heights.csv",
        ] {
            std::fs::write(d.join(f), b"").unwrap();
        }
        d
    })
}

/// A survey of the seeds' points, for the picks parser to merge into.
fn picks_survey() -> geostride::survey::Survey {
    geostride::survey::read::parse(
        Path::new("gcps.csv"),
        EMLID,
        &geostride::survey::read::ReadOptions::default(),
    )
    .expect("the Emlid seed is valid")
}

/// A COLMAP text model in one text: each file after a `== NAME ==` line.
const COLMAP: &str = "== cameras.txt ==\n# Camera list\n1 OPENCV 1280 720 1000.5 1001 640.5 360.5 -0.01 0.002 0.0001 -0.0002\n== images.txt ==\n# Image list\n1 1 0 0 0 0 0 0 1 p0.png\n100.5 200.5 1 300.5 400.5 2 50 60 -1\n2 0.9998 0.02 0 0 -1 0.1 0 1 p1.png\n120.5 210.5 1 320.5 390.5 2\n3 1 0 0 0 -2 0 0 1 p2.png\n\n== points3D.txt ==\n# 3D point list\n1 0.5 0.25 10 200 200 200 0.4 1 0 2 0\n2 -0.5 0.5 11 200 200 200 0.4 1 1 2 1\n";

/// A model with a SIMPLE_RADIAL camera, a point seen by no image, an image of no keypoints.
const COLMAP_RADIAL: &str = "== cameras.txt ==\n1 SIMPLE_RADIAL 640 480 500 320 240 -0.1\n2 PINHOLE 640 480 500 500 320 240\n== images.txt ==\n5 0.7 0.1 0.1 0.7 1 2 3 1 a/b_c.jpg\n1 2 -1 3 4 7\n9 1 0 0 0 0 0 0 1 d.jpg\n\n== points3D.txt ==\n7 0 0 1 0 0 0 0.5 5 1\n8 1 1 1 1 1 1 1\n";

/// The three binary files of a [`COLMAP`]-like text, split by [`SPLIT`].
fn colmap_binary_seed(t: &str) -> Vec<u8> {
    let [c, i, p] = colmap_parts(t);
    let path = Path::new("seed");
    let model = geostride::sfm::colmap_model::parse_text((path, &c), (path, &i), (path, &p))
        .unwrap_or_else(|e| panic!("the seed parses: {e}"));
    let [c, i, p] = model.to_binary();
    [c, SPLIT.to_vec(), i, SPLIT.to_vec(), p].concat()
}

const SPLIT: &[u8] = b"@@next file@@";

/// Bytes cut at the first two [`SPLIT`]s (missing parts empty).
fn split_three(b: &[u8]) -> [&[u8]; 3] {
    let find = |b: &[u8]| b.windows(SPLIT.len()).position(|w| w == SPLIT);
    let Some(k) = find(b) else {
        return [b, &[], &[]];
    };
    let (c, rest) = (&b[..k], &b[k + SPLIT.len()..]);
    let Some(k) = find(rest) else {
        return [c, rest, &[]];
    };
    [c, &rest[..k], &rest[k + SPLIT.len()..]]
}

/// A parsed COLMAP model must survive being written and read again (the same records, in the
/// hash map's order) and its conversion for georeferencing (an error or a reconstruction).
fn colmap_checked(
    parsed: Result<
        geostride::sfm::colmap_model::ColmapModel,
        geostride::sfm::colmap_model::ColmapError,
    >,
) -> Outcome {
    use geostride::sfm::colmap_model::{ColmapModel, parse_binary, parse_text};
    let m = match parsed {
        Ok(m) => m,
        Err(e) => return Outcome::Err(e.to_string()),
    };
    let sorted = |mut m: ColmapModel| {
        m.cameras.sort_by_key(|c| c.id);
        m.images.sort_by_key(|c| c.id);
        m.points.sort_by_key(|c| c.id);
        m
    };
    let path = Path::new("again");
    // Writing normalises each quaternion, and reading does again (as COLMAP does): the model
    // read back holds them normalised twice more.
    let norm = geostride::sfm::colmap_model::normalize_quaternion;
    let mut expected = m.clone();
    for i in &mut expected.images {
        i.qvec = norm(norm(i.qvec));
    }
    let [c, i, p] = m.to_binary();
    let again = parse_binary((path, &c), (path, &i), (path, &p));
    let bytes = |m: ColmapModel| sorted(m).to_binary();
    if again.map(bytes).ok() != Some(bytes(expected.clone())) {
        return Outcome::Err("(accepted): the binary written does not read back".into());
    }
    // Text holds names without spaces and control characters only (as COLMAP's).
    if m.images.iter().all(|i| {
        !i.name.is_empty()
            && !i
                .name
                .contains(|c: char| c.is_whitespace() || c.is_control())
    }) {
        let [c, i, p] = m.to_text();
        let again = parse_text((path, &c), (path, &i), (path, &p));
        let same = again
            .as_ref()
            .is_ok_and(|a| a.to_binary() == sorted_binary(&expected, a));
        if !same {
            return Outcome::Err("(accepted): the text written does not read back".into());
        }
    }
    let _ = geostride::sfm::colmap_convert::to_reconstruction(&m);
    Outcome::Ok
}

/// `m`'s binary in the order `a` (the same records read back) holds them.
fn sorted_binary(
    m: &geostride::sfm::colmap_model::ColmapModel,
    a: &geostride::sfm::colmap_model::ColmapModel,
) -> [Vec<u8>; 3] {
    let mut m = m.clone();
    let pos = |ids: &[u64], id: u64| ids.iter().position(|v| *v == id).unwrap_or(usize::MAX);
    let cams: Vec<u64> = a.cameras.iter().map(|c| u64::from(c.id)).collect();
    let imgs: Vec<u64> = a.images.iter().map(|c| u64::from(c.id)).collect();
    let pts: Vec<u64> = a.points.iter().map(|c| c.id).collect();
    m.cameras.sort_by_key(|c| pos(&cams, u64::from(c.id)));
    m.images.sort_by_key(|c| pos(&imgs, u64::from(c.id)));
    m.points.sort_by_key(|c| pos(&pts, c.id));
    m.to_binary()
}

/// The three files of a [`COLMAP`]-like text (missing ones empty).
fn colmap_parts(t: &str) -> [String; 3] {
    let mut parts: [String; 3] = Default::default();
    let mut at = None;
    for line in t.split_inclusive('\n') {
        let name = line
            .trim()
            .strip_prefix("== ")
            .and_then(|l| l.strip_suffix(" =="));
        match name {
            Some("cameras.txt") => at = Some(0),
            Some("images.txt") => at = Some(1),
            Some("points3D.txt") => at = Some(2),
            _ => {
                if let Some(k) = at {
                    parts[k].push_str(line);
                }
            }
        }
    }
    parts
}

/// A small JPEG with EXIF (35 mm focal length, GPS; a DSLR's focal plane) and DJI XMP, and
/// variants.
fn exif_seeds() -> Vec<Vec<u8>> {
    // A JPEG's frame, scan and end: what follows the metadata hardly matters to its reader.
    let body: &[u8] = &[
        0xFF, 0xD8, 0xFF, 0xC0, 0, 11, 8, 0, 8, 0, 8, 1, 1, 0x11, 0, 0xFF, 0xDA, 0, 8, 1, 1, 0, 0,
        0x3F, 0, 0x12, 0x34, 0xFF, 0xD9,
    ];
    let e = |focal, gps, rtk| exif::Exif {
        focal_35mm: focal,
        gps,
        rtk_sigma_m: rtk,
        ..Default::default()
    };
    vec![
        exif::with_exif(
            body,
            &e(
                Some(24),
                Some((51.07, 4.43, 88.5)),
                Some([0.02, 0.02, 0.03]),
            ),
        ),
        exif::with_exif(body, &e(None, Some((-33.85, -70.12, -12.0)), None)),
        exif::with_exif(body, &e(Some(65535), None, None)),
        // A DSLR's: the focal length on the sensor's pixel pitch, no 35 mm equivalent.
        exif::with_exif(
            body,
            &exif::Exif {
                focal_mm: Some(24.0),
                focal_plane_x: Some((3942.4, 2)),
                pixel_x_dimension: Some(5616),
                ..Default::default()
            },
        ),
    ]
}

/// Image headers of every format `imageheader` reads.
fn header_seeds() -> Vec<Vec<u8>> {
    let mut jpeg = vec![0xFF, 0xD8, 0xFF, 0xE0, 0, 4, 0, 0, 0xFF, 0xC2, 0, 11, 8];
    jpeg.extend(2160u16.to_be_bytes());
    jpeg.extend(3840u16.to_be_bytes());
    jpeg.extend([1, 1, 0x11, 0]);
    let mut png = b"\x89PNG\r\n\x1a\n\0\0\0\x0dIHDR".to_vec();
    png.extend(4000u32.to_be_bytes());
    png.extend(3000u32.to_be_bytes());
    png.extend([8, 2, 0, 0, 0]);
    let mut tiff = b"MM\0*".to_vec();
    tiff.extend(8u32.to_be_bytes());
    tiff.extend(2u16.to_be_bytes());
    for (tag, v) in [(256u16, 6000u32), (257, 4000)] {
        tiff.extend(tag.to_be_bytes());
        tiff.extend(4u16.to_be_bytes());
        tiff.extend(1u32.to_be_bytes());
        tiff.extend(v.to_be_bytes());
    }
    let mut big = b"II+\0\x08\0\0\0".to_vec();
    big.extend(16u64.to_le_bytes());
    big.extend(1u64.to_le_bytes());
    big.extend(256u16.to_le_bytes());
    big.extend(16u16.to_le_bytes());
    big.extend(1u64.to_le_bytes());
    big.extend(70000u64.to_le_bytes());
    let mut bmp = b"BM".to_vec();
    bmp.extend([0u8; 16]);
    bmp.extend(640i32.to_le_bytes());
    bmp.extend((-480i32).to_le_bytes());
    let mut webp = b"RIFF\0\0\0\0WEBPVP8X".to_vec();
    webp.extend([0u8; 8]);
    webp.extend([0xFF, 0x0E, 0, 0x6F, 0x08, 0]);
    webp.resize(32, 0);
    vec![
        jpeg,
        png,
        tiff,
        big,
        bmp,
        webp,
        b"P6\n# c\n640 480\n255\n".to_vec(),
    ]
}

/// Stage caches as the run writes them: the smoothed trajectories, image tracks, a palette.
fn stage_seeds() -> Vec<Vec<u8>> {
    use geostride::export::{PointCov, Trajectory, TrajectoryPoint};
    use nalgebra::{Matrix2, Vector2, Vector3};
    let dir = std::env::temp_dir().join(format!("geostride-fuzz-stage-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let point = |f: usize| TrajectoryPoint {
        frame: f,
        time_s: f as f64 / 25.0,
        local: Vector3::new(f as f64 * 0.05, 1.0, 7.7),
        crs: Vector3::new(654_500.0, 696_000.0, 59.7),
        velocity: Vector2::new(1.2, 0.0),
        sigma_m: Vector2::new(0.03, 0.04),
        cov: PointCov {
            random: Matrix2::identity() * 1e-3,
            height: Matrix2::zeros(),
            pose: Matrix2::identity() * 2e-4,
        },
        observed: !f.is_multiple_of(3),
        score: (!f.is_multiple_of(3)).then_some(0.9),
    };
    let trajectories = vec![
        Trajectory {
            id: 1,
            height_m: 1.7,
            height_source: "default".into(),
            points: (0..4).map(point).collect(),
        },
        Trajectory {
            id: 2,
            height_m: 1.62,
            height_source: "heights.csv".into(),
            points: vec![point(9)],
        },
    ];
    let path = dir.join("smooth.bin");
    geostride::cache::write_stage_file(&path, STAGE_KEY, &trajectories).unwrap();
    let bytes = std::fs::read(&path).unwrap();
    let _ = std::fs::remove_dir_all(&dir);
    vec![bytes]
}

/// The key the stage-cache seeds are made under.
const STAGE_KEY: &str = "0f1e2d3c4b5a69788796a5b4c3d2e1f0";

/// Every parser, with its seeds.
pub fn targets() -> Vec<Target> {
    use geostride::survey::model::SurveyFormat;
    use geostride::survey::read::{ReadOptions, parse};
    let survey =
        |name: &'static str, file: &'static str, seeds: Vec<&str>, format: Option<SurveyFormat>| {
            let opts = ReadOptions {
                format,
                columns: (format == Some(SurveyFormat::Csv)).then(|| "name,x,y,z".parse().unwrap()),
                crs: (format == Some(SurveyFormat::Csv)).then(|| "EPSG:3812".to_string()),
                image_size: Some((4000, 3000)),
                ..ReadOptions::default()
            };
            Target {
                name,
                share: 1.0,
                file,
                seeds: seeds.into_iter().map(|s| s.as_bytes().to_vec()).collect(),
                run: Box::new(move |p: &Path, b: &[u8]| match text(b) {
                    Some(t) => outcome(parse(p, t, &opts)),
                    None => not_text(p),
                }),
            }
        };
    let all_surveys = vec![EMLID, ODM, OPENSFM, METASHAPE, PETRACK];
    let base = picks_survey();
    vec![
        survey("survey", "gcps.csv", all_surveys, None),
        survey(
            "survey-emlid",
            "gcps.csv",
            vec![EMLID],
            Some(SurveyFormat::Emlid),
        ),
        survey(
            "survey-odm",
            "gcp_list.txt",
            vec![ODM],
            Some(SurveyFormat::Odm),
        ),
        survey(
            "survey-opensfm",
            "ground_control_points.json",
            vec![OPENSFM],
            Some(SurveyFormat::OpenSfm),
        ),
        survey(
            "survey-metashape",
            "reference.csv",
            vec![METASHAPE],
            Some(SurveyFormat::Metashape),
        ),
        survey(
            "survey-csv",
            "points.csv",
            vec![CSV],
            Some(SurveyFormat::Csv),
        ),
        survey(
            "survey-petrack",
            "points.3dc",
            vec![PETRACK],
            Some(SurveyFormat::Petrack),
        ),
        Target {
            name: "picks",
            share: 1.0,
            file: "picks.csv",
            seeds: vec![PICKS.as_bytes().to_vec()],
            run: Box::new(move |p: &Path, b: &[u8]| match text(b) {
                Some(t) => outcome(geostride::survey::read::parse_picks(
                    p,
                    t,
                    &mut base.clone(),
                )),
                None => not_text(p),
            }),
        },
        target!(
            "calibration",
            "camera.cal",
            [YAML, XML, JSON_CAL],
            |p, t| { geostride::camera::formats::parse(p, t, None) }
        ),
        target!("calibration-yaml", "camera.yaml", [YAML], |p, t| {
            geostride::camera::formats::parse(
                p,
                t,
                Some(geostride::camera::formats::Format::OpenCvYaml),
            )
        }),
        target!("calibration-xml", "camera.xml", [XML], |p, t| {
            geostride::camera::formats::parse(
                p,
                t,
                Some(geostride::camera::formats::Format::Metashape),
            )
        }),
        target!("calibration-json", "camera.json", [JSON_CAL], |p, t| {
            geostride::camera::formats::parse(p, t, Some(geostride::camera::formats::Format::Json))
        }),
        Target {
            name: "project",
            share: 1.0,
            file: "project.toml",
            seeds: vec![PROJECT.as_bytes().to_vec()],
            // In a folder that has the files the seed names, so that checks go past them.
            run: Box::new(|_: &Path, b: &[u8]| match text(b) {
                Some(t) => outcome(geostride::pipeline::project::parse(
                    &project_dir().join("project.toml"),
                    t.to_string(),
                )),
                None => not_text(Path::new("project.toml")),
            }),
        },
        target!("scene", "scene.toml", [SCENE], |p, t| {
            geostride::simulate::scene::Scene::parse(&geostride::io::FileCtx { path: p }, t)
        }),
        target!("boxes-mot", "boxes.txt", [MOT], |p, t| {
            geostride::detect::boxes::parse_boxes(p, t, geostride::detect::boxes::BoxFormat::Mot)
        }),
        target!("boxes-jsonl", "boxes.jsonl", [JSONL], |p, t| {
            geostride::detect::boxes::parse_boxes(
                p,
                t,
                geostride::detect::boxes::BoxFormat::JsonLines,
            )
        }),
        target!("boxes-coco", "boxes.json", [COCO], |p, t| {
            geostride::detect::boxes::parse_boxes(p, t, geostride::detect::boxes::BoxFormat::Coco)
        }),
        target!("bal", "problem.txt", [BAL], |p, t| {
            geostride::optim::bal::parse_bal(p, t)
        }),
        target!("heights", "heights.csv", [HEIGHTS], |p, t| {
            geostride::pipeline::run::parse_heights(p, t)
        }),
        target!("samples", "tracks.csv", [SAMPLES], |p, t| {
            geostride::evaluate::parse_samples(p, t, ["frame", "id", "e_m", "n_m"])
        }),
        target!("frame-points", "detections.csv", [DETECTIONS], |p, t| {
            geostride::detect::error_fit::parse_frame_points(
                p,
                t,
                ["frame", "u_px", "v_px"],
                None,
                geostride::detect::error_fit::MAX_ANNOTATIONS,
            )
        }),
        target!("truth-poses", "camera.csv", [POSES], |p, t| {
            geostride::simulate::truth::parse_poses(p, t)
        }),
        target!("truth-gcps", "gcps.csv", [GCPS_TRUTH], |p, t| {
            geostride::simulate::truth::parse_gcps(p, t)
        }),
        target!("truth-boxes", "boxes.csv", [TRUTH_BOXES], |p, t| {
            geostride::detect::simulated::parse_truth_boxes(p, t)
        }),
        target!(
            "dji-srt",
            "DJI_0001.SRT",
            [
                include_str!("../data/dji-srt/mavic3t.SRT"),
                include_str!("../data/dji-srt/m300rtk.SRT"),
                include_str!("../data/dji-srt/mavic2ea.SRT"),
                include_str!("../data/dji-srt/neo2-nogps.SRT"),
                include_str!("../data/dji-srt/p4rtk.SRT"),
                include_str!("../data/dji-srt/mavicpro.SRT"),
                include_str!("../data/dji-srt/m300-legacy.srt"),
            ],
            |p, t| geostride::telemetry::srt::parse_srt(p, t).and_then(|f| {
                // What is read must be in range: a position on the globe, times in order.
                let sane = f.records.iter().all(|r| {
                    r.latitude_deg.is_none_or(|v| v.abs() <= 90.0)
                        && r.longitude_deg.is_none_or(|v| v.abs() <= 180.0)
                        && r.end_s >= r.start_s
                        && r.shutter_s.is_none_or(|s| s > 0.0 && s.is_finite())
                }) && f.records.windows(2).all(|w| w[1].start_s >= w[0].start_s);
                if sane {
                    Ok(f)
                } else {
                    // Not naming the file: the fuzzer reports it.
                    Err(geostride::io::FileError {
                        path: "(accepted)".into(),
                        line: None,
                        field: None,
                        message: "a value out of range was accepted".into(),
                    })
                }
            })
        ),
        Target {
            name: "colmap-model",
            share: 1.0,
            file: "model/",
            seeds: vec![COLMAP.as_bytes().to_vec()],
            run: Box::new(|_: &Path, b: &[u8]| match text(b) {
                Some(t) => {
                    let [c, i, p] = colmap_parts(t);
                    outcome(geostride::sfm::register::parse_model(
                        (Path::new("model/cameras.txt"), &c),
                        (Path::new("model/images.txt"), &i),
                        (Path::new("model/points3D.txt"), &p),
                    ))
                }
                None => Outcome::Err("model/: not UTF-8 text".into()),
            }),
        },
        Target {
            name: "colmap-text",
            share: 1.0,
            file: "model/",
            seeds: vec![COLMAP.as_bytes().to_vec(), COLMAP_RADIAL.as_bytes().to_vec()],
            run: Box::new(|_: &Path, b: &[u8]| match text(b) {
                Some(t) => {
                    let [c, i, p] = colmap_parts(t);
                    let parsed = geostride::sfm::colmap_model::parse_text(
                        (Path::new("model/cameras.txt"), &c),
                        (Path::new("model/images.txt"), &i),
                        (Path::new("model/points3D.txt"), &p),
                    );
                    colmap_checked(parsed)
                }
                None => Outcome::Err("model/: not UTF-8 text".into()),
            }),
        },
        Target {
            name: "colmap-binary",
            share: 1.0,
            file: "model/",
            seeds: vec![colmap_binary_seed(COLMAP), colmap_binary_seed(COLMAP_RADIAL)],
            run: Box::new(|_: &Path, b: &[u8]| {
                let [c, i, p] = split_three(b);
                let parsed = geostride::sfm::colmap_model::parse_binary(
                    (Path::new("model/cameras.bin"), c),
                    (Path::new("model/images.bin"), i),
                    (Path::new("model/points3D.bin"), p),
                );
                colmap_checked(parsed)
            }),
        },
        Target {
            name: "exif",
            share: 1.0,
            file: "",
            seeds: exif_seeds(),
            // Metadata is optional: what cannot be read is left out, never an error.
            run: Box::new(|_: &Path, b: &[u8]| {
                let m = geostride::sfm::exif::meta_from_bytes(b);
                let sane = m.gps.is_none_or(|g| g.lat_deg.abs() <= 90.0 && g.lon_deg.abs() <= 180.0)
                    && m.focal_35mm.is_none_or(f64::is_finite)
                    && m.rtk_sigma_m.is_none_or(|s| s.iter().all(|v| *v > 0.0))
                    && {
                        let f = geostride::sfm::exif::focal_px_from_exif(&m, 4000, 3000).0;
                        f.is_finite() && f > 0.0
                    };
                if sane {
                    Outcome::Ok
                } else {
                    Outcome::Err(format!("metadata out of range: {m:?}"))
                }
            }),
        },
        Target {
            name: "image-header",
            share: 1.0,
            file: "",
            seeds: header_seeds(),
            run: Box::new(|_: &Path, b: &[u8]| {
                outcome(geostride::imageheader::read_size(&mut std::io::Cursor::new(b)))
            }),
        },
        Target {
            name: "onnx-metadata",
            share: 1.0,
            file: "",
            seeds: vec![
                b"[\"person\", \"bicycle\", \"car\"]".to_vec(),
                b"{0: 'person', 1: 'bicycle', 2: 'car'}".to_vec(),
                br#"{"anchors": [[10, 14], [23, 27], [37, 58], [81, 82], [135, 169], [344, 319]], "masks": [[3, 4, 5], [0, 1, 2]], "strides": [32, 16]}"#.to_vec(),
            ],
            run: Box::new(|_: &Path, b: &[u8]| match text(b) {
                Some(t) => {
                    let _ = geostride::detect::neural::parse_names(t);
                    outcome(geostride::detect::neural::darknet_layout(t))
                }
                None => Outcome::Err("not text".into()),
            }),
        },
        Target {
            name: "stage-cache",
            share: 1.0,
            file: "",
            seeds: stage_seeds(),
            // A cache that is not whole under its key is a miss (the stage runs again), never an
            // error: read as the smoothed trajectories (a sequence) and whole.
            run: Box::new(|_: &Path, b: &[u8]| {
                thread_local! {
                    static DIR: std::path::PathBuf = {
                        let d = std::env::temp_dir().join(format!(
                            "geostride-fuzz-cache-{}-{:?}",
                            std::process::id(),
                            std::thread::current().id()
                        ));
                        std::fs::create_dir_all(&d).unwrap();
                        d
                    };
                }
                DIR.with(|d| {
                    let path = d.join("smooth.bin");
                    std::fs::write(&path, b).unwrap();
                    let _ = geostride::cache::read_stage_seq_file::<geostride::export::Trajectory>(&path, STAGE_KEY);
                    std::fs::write(&path, b).unwrap();
                    let _ = geostride::cache::read_stage_file::<Vec<geostride::export::Trajectory>>(&path, STAGE_KEY);
                    let _ = geostride::cache::read_stage_file::<geostride::detect::colour::Palette>(&path, STAGE_KEY);
                });
                Outcome::Ok
            }),
        },
        Target {
            name: "crs",
            share: 0.2,
            file: "",
            seeds: [
                "EPSG:31370",
                "WGS84 UTM 17N",
                "+proj=utm +zone=22 +south +datum=WGS84",
                "ETRS89 / Belgian Lambert 2008",
                "EPSG:6190",
                "local",
            ]
            .iter()
            .map(|s| s.as_bytes().to_vec())
            .collect(),
            run: Box::new(|_: &Path, b: &[u8]| match text(b) {
                Some(t) => outcome(geostride::survey::crs::Crs::new(t)),
                None => Outcome::Err("not text".into()),
            }),
        },
        Target {
            name: "origin",
            share: 1.0,
            file: "",
            seeds: ["centroid", "point:GCP1", "51.07,4.43,52.5"]
                .iter()
                .map(|s| s.as_bytes().to_vec())
                .collect(),
            run: Box::new(|_: &Path, b: &[u8]| match text(b) {
                Some(t) => outcome(t.parse::<geostride::survey::frame::Origin>()),
                None => Outcome::Err("not text".into()),
            }),
        },
        Target {
            name: "columns",
            share: 1.0,
            file: "",
            seeds: [
                "name=Label,x=E,y=N,z=H,sx=1",
                "name,x,y,z,sx,sy,sz",
                "x=3,y=2,name=1",
            ]
            .iter()
            .map(|s| s.as_bytes().to_vec())
            .collect(),
            run: Box::new(|_: &Path, b: &[u8]| match text(b) {
                Some(t) => outcome(t.parse::<geostride::survey::read::ColumnMap>()),
                None => Outcome::Err("not text".into()),
            }),
        },
    ]
}

/// Values that break careless parsers.
const HOSTILE: &[&str] = &[
    "nan",
    "NaN",
    "-nan",
    "inf",
    "-inf",
    "infinity",
    "1e400",
    "-1e400",
    "1e-400",
    "0",
    "-0",
    "-1",
    "1e308",
    "4294967296",
    "18446744073709551616",
    "9007199254740993",
    "99999999999999999999999999999",
    ".nan",
    ".Inf",
    "-.Inf",
    "",
    " ",
    "1,5",
    "12,5;3,4",
    "0x10",
    "1_000",
    "+",
    "-",
    ".",
    "e5",
    "\"",
    "'",
    "\\",
    "#",
    "[",
    "{",
    "]",
    "}",
    "\t",
    "\u{feff}",
    "é",
    "\u{0}",
    "null",
    "true",
    "[]",
    "{}",
    "[[[[[[[[",
    "\"\"\"",
];

fn is_number_byte(b: u8) -> bool {
    b.is_ascii_digit() || b == b'.' || b == b'-' || b == b'+' || b == b'e' || b == b'E'
}

/// One mutation of `input`.
fn mutate_once(rng: &mut ChaCha8Rng, input: &mut Vec<u8>, seeds: &[Vec<u8>]) {
    let len = input.len();
    match rng.random_range(0..14) {
        0 if len > 0 => {
            let i = rng.random_range(0..len);
            input[i] ^= 1 << rng.random_range(0..8);
        }
        1 if len > 0 => {
            let a = rng.random_range(0..len);
            let b = (a + rng.random_range(1..=16.min(len - a).max(1))).min(len);
            input.drain(a..b);
        }
        2 => {
            let at = rng.random_range(0..=len);
            let n = rng.random_range(1..8);
            let bytes: Vec<u8> = (0..n).map(|_| rng.random()).collect();
            input.splice(at..at, bytes);
        }
        3 if len > 0 => {
            let a = rng.random_range(0..len);
            let b = (a + rng.random_range(1..=64)).min(len);
            let chunk = input[a..b].to_vec();
            let at = rng.random_range(0..=input.len());
            input.splice(at..at, chunk);
        }
        4..=6 => {
            // A number, or anything between delimiters, replaced by a hostile value.
            if len == 0 {
                input.extend_from_slice(HOSTILE[rng.random_range(0..HOSTILE.len())].as_bytes());
                return;
            }
            let i = rng.random_range(0..len);
            let (mut a, mut b) = (i, i);
            if is_number_byte(input[i]) {
                while a > 0 && is_number_byte(input[a - 1]) {
                    a -= 1;
                }
                while b < len && is_number_byte(input[b]) {
                    b += 1;
                }
            } else {
                let stop =
                    |c: u8| matches!(c, b',' | b';' | b'\t' | b' ' | b'\n' | b'"' | b':' | b'=');
                while a > 0 && !stop(input[a - 1]) {
                    a -= 1;
                }
                while b < len && !stop(input[b]) {
                    b += 1;
                }
            }
            let v = HOSTILE[rng.random_range(0..HOSTILE.len())];
            input.splice(a..b, v.bytes());
        }
        7 => {
            // A line duplicated, deleted or swapped.
            let mut lines: Vec<Vec<u8>> =
                input.split(|c| *c == b'\n').map(<[u8]>::to_vec).collect();
            if lines.len() > 1 {
                let i = rng.random_range(0..lines.len());
                let j = rng.random_range(0..lines.len());
                match rng.random_range(0..3) {
                    0 => {
                        let l = lines[i].clone();
                        lines.insert(j, l);
                    }
                    1 => {
                        lines.remove(i);
                    }
                    _ => lines.swap(i, j),
                }
                *input = lines.join(&b'\n');
            }
        }
        8 if len > 0 => {
            // Delimiters changed.
            let from = [b',', b';', b'\t', b' ', b'\n', b':'][rng.random_range(0..6)];
            let to = [b',', b';', b'\t', b' ', b'\n', b'.'][rng.random_range(0..6)];
            for c in input.iter_mut() {
                if *c == from && rng.random_bool(0.5) {
                    *c = to;
                }
            }
        }
        9 => {
            // Something long: a token, a line, or deep nesting.
            let at = rng.random_range(0..=len);
            let n = 1usize << rng.random_range(4..16);
            let piece: Vec<u8> = match rng.random_range(0..4) {
                0 => vec![b'9'; n],
                1 => b"[".repeat(n),
                2 => b"{\"a\":".repeat(n / 5),
                _ => {
                    let l = input
                        .split(|c| *c == b'\n')
                        .nth(1)
                        .unwrap_or(b"x,1,2")
                        .to_vec();
                    let mut v = Vec::new();
                    for _ in 0..(n / 64).max(2) {
                        v.extend_from_slice(&l);
                        v.push(b'\n');
                    }
                    v
                }
            };
            input.splice(at..at, piece);
        }
        10 if len > 0 => input.truncate(rng.random_range(0..len)),
        11 => {
            // Crossover with another seed.
            let other = &seeds[rng.random_range(0..seeds.len())];
            if !other.is_empty() {
                let cut = rng.random_range(0..=len);
                let from = rng.random_range(0..other.len());
                input.truncate(cut);
                input.extend_from_slice(&other[from..]);
            }
        }
        12 if len > 0 => {
            // A byte repeated (quotes, brackets, separators).
            let i = rng.random_range(0..len);
            let b = input[i];
            let n = rng.random_range(1..64);
            input.splice(i..i, std::iter::repeat_n(b, n));
        }
        _ => {
            let at = rng.random_range(0..=len);
            let v = HOSTILE[rng.random_range(0..HOSTILE.len())];
            input.splice(at..at, v.bytes());
        }
    }
}

/// A structured table of `rows` lines of hostile and ordinary fields: what a spreadsheet or a
/// careless export makes of a CSV.
fn random_table(rng: &mut ChaCha8Rng, seed: &[u8]) -> Vec<u8> {
    let header = seed.split(|c| *c == b'\n').next().unwrap_or(b"");
    let mut out = header.to_vec();
    out.push(b'\n');
    let fields = header.iter().filter(|c| **c == b',').count() + 1;
    for _ in 0..rng.random_range(0..20) {
        let n = (fields as i64 + rng.random_range(-2i64..=2)).max(1);
        let row: Vec<String> = (0..n)
            .map(|_| match rng.random_range(0..4) {
                0 => HOSTILE[rng.random_range(0..HOSTILE.len())].to_string(),
                1 => format!("{}", rng.random_range(-1e7..1e7)),
                2 => format!("{}", rng.random_range(0..100u32)),
                _ => ["GCP1", "CHK-2", "a.jpg", "video.mp4#0", "FIX", "body"]
                    [rng.random_range(0..6)]
                .to_string(),
            })
            .collect();
        out.extend_from_slice(row.join(",").as_bytes());
        out.push(b'\n');
    }
    out
}

/// The `index`-th input of a run: the same seed and index give the same input.
pub fn input(target: &Target, seed: u64, index: u64) -> Vec<u8> {
    let mut rng = ChaCha8Rng::seed_from_u64(seed ^ index.wrapping_mul(0x9E37_79B9_7F4A_7C15));
    let seeds = &target.seeds;
    match rng.random_range(0..20) {
        0 => (0..rng.random_range(0..512))
            .map(|_| rng.random())
            .collect(),
        1 => {
            let s = &seeds[rng.random_range(0..seeds.len())];
            random_table(&mut rng, s)
        }
        _ => {
            let mut v = seeds[rng.random_range(0..seeds.len())].clone();
            for _ in 0..rng.random_range(1..=5) {
                mutate_once(&mut rng, &mut v, seeds);
            }
            v
        }
    }
}

/// What fuzzing one target found.
#[derive(Debug, Default)]
pub struct Report {
    pub target: String,
    pub inputs: u64,
    pub ok: u64,
    pub errors: u64,
    /// (index, the panic's message)
    pub panics: Vec<(u64, String)>,
    /// (index, why): an error that does not name the file, or a message over 8 kB.
    pub bad_messages: Vec<(u64, String)>,
    /// The slowest input: (index, seconds, bytes).
    pub slowest: (u64, f64, usize),
    /// The largest heap in use at once, bytes (with the counting allocator installed).
    pub peak_bytes: usize,
    pub seconds: f64,
}

/// Fuzzes `target` with inputs `first..first + count` of `seed`.
pub fn fuzz(target: &Target, seed: u64, first: u64, count: u64) -> Report {
    let path = Path::new(if target.file.is_empty() {
        "input"
    } else {
        target.file
    });
    let mut r = Report {
        target: target.name.to_string(),
        ..Report::default()
    };
    PEAK.store(IN_USE.load(Ordering::Relaxed), Ordering::Relaxed);
    let started = Instant::now();
    let quiet = std::panic::take_hook();
    std::panic::set_hook(Box::new(|_| {}));
    for i in first..first + count {
        let bytes = input(target, seed, i);
        let t0 = Instant::now();
        let result =
            std::panic::catch_unwind(std::panic::AssertUnwindSafe(|| (target.run)(path, &bytes)));
        let dt = t0.elapsed().as_secs_f64();
        if dt > r.slowest.1 {
            r.slowest = (i, dt, bytes.len());
        }
        r.inputs += 1;
        match result {
            Ok(Outcome::Ok) => r.ok += 1,
            Ok(Outcome::Err(m)) => {
                r.errors += 1;
                if !target.file.is_empty() && !m.contains(target.file) && r.bad_messages.len() < 10
                {
                    r.bad_messages.push((
                        i,
                        format!(
                            "does not name {}: {}",
                            target.file,
                            geostride::io::clip(&m, 200)
                        ),
                    ));
                }
                if m.len() > 8000 && r.bad_messages.len() < 10 {
                    r.bad_messages.push((
                        i,
                        format!(
                            "a message of {} bytes: {}",
                            m.len(),
                            geostride::io::clip(&m, 160)
                        ),
                    ));
                }
            }
            Err(p) => {
                let msg = p
                    .downcast_ref::<String>()
                    .cloned()
                    .or_else(|| p.downcast_ref::<&str>().map(|s| s.to_string()))
                    .unwrap_or_default();
                if r.panics.len() < 10 {
                    r.panics.push((i, msg));
                }
            }
        }
    }
    std::panic::set_hook(quiet);
    r.peak_bytes = PEAK.load(Ordering::Relaxed);
    r.seconds = started.elapsed().as_secs_f64();
    r
}
