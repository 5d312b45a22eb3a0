//! The catalogue's second part (issue 35): the commands added since the first hardening
//! (`sfm`, `sfm register`, `detect`, split/segment/merge, `slurm`, `render`, the model pose) and
//! more of every other command.

use std::path::Path;

use super::common::exif::{Exif, with_exif};
use super::common::onnx::constant_model;
use super::{Case, args, fixture, geostride, project_with, replace};

/// The fixture's extra files: frames as photos (two folders holding a photo of one name), a
/// JPEG to carry chosen EXIF, a small COLMAP model of the photos, ONNX models whose outputs no
/// detector can read, and a folder of images for `calibrate`.
pub(super) fn extend_fixture(dir: &Path) {
    let out = geostride()
        .arg("simulate")
        .arg(dir.join("scene.toml"))
        .arg("--out")
        .arg(dir.join("frames"))
        .args([
            "--duration",
            "0.2",
            "--frames-every",
            "1",
            "--no-video",
            "-q",
        ])
        .output()
        .unwrap();
    super::common::assert_success(&out);
    let mut frames: Vec<_> = std::fs::read_dir(dir.join("frames/frames"))
        .unwrap()
        .map(|e| e.unwrap().path())
        .collect();
    frames.sort();
    assert!(frames.len() >= 3);
    for d in ["photos", "photos2", "boards"] {
        std::fs::create_dir_all(dir.join(d)).unwrap();
    }
    std::fs::copy(&frames[0], dir.join("truth/frame.png")).unwrap();
    std::fs::copy(&frames[0], dir.join("photos/p0.png")).unwrap();
    std::fs::copy(&frames[1], dir.join("photos/p1.png")).unwrap();
    std::fs::copy(&frames[2], dir.join("photos2/p0.png")).unwrap();
    std::fs::copy(&frames[2], dir.join("boards/b0.png")).unwrap();
    std::fs::remove_dir_all(dir.join("frames")).unwrap();
    // A textured JPEG (EXIF is added per case).
    let (w, h) = (96u32, 64u32);
    let rgb: Vec<u8> = (0..w * h * 3)
        .map(|i| ((i * 2_654_435_761u32) >> 24) as u8)
        .collect();
    geostride::imageio::write_rgb(&dir.join("base.jpg"), w, h, &rgb).unwrap();
    // A model of the two photos, as `geostride sfm` writes it.
    std::fs::create_dir_all(dir.join("model")).unwrap();
    std::fs::write(dir.join("model/cameras.txt"), MODEL_CAMERAS).unwrap();
    std::fs::write(dir.join("model/images.txt"), MODEL_IMAGES).unwrap();
    std::fs::write(dir.join("model/points3D.txt"), MODEL_POINTS).unwrap();
    std::fs::write(
        dir.join("model/cameras.csv"),
        "image,registered,frame,x,y,z,qw,qx,qy,qz\np0.png,yes,model,0,0,0,1,0,0,0\n",
    )
    .unwrap();
    std::fs::write(
        dir.join("model/report.json"),
        "{\"frame\": \"model\", \"max_features\": 4096}\n",
    )
    .unwrap();
    let names = [("names", "[\"person\", \"bicycle\"]")];
    std::fs::write(
        dir.join("nan.onnx"),
        constant_model(64, 64, &[1, 6, 10], f32::NAN, &names),
    )
    .unwrap();
    std::fs::write(
        dir.join("future.onnx"),
        constant_model(
            64,
            64,
            &[1, 8, 7],
            0.0,
            &[("geostride.layout", "geostride-centre-heatmap-9")],
        ),
    )
    .unwrap();
    std::fs::write(
        dir.join("centre6.onnx"),
        constant_model(
            64,
            64,
            &[1, 8, 6],
            0.0,
            &[("geostride.layout", "geostride-centre-heatmap-1")],
        ),
    )
    .unwrap();
    std::fs::write(
        dir.join("centre-bad-gsd.onnx"),
        constant_model(
            64,
            64,
            &[1, 8, 7],
            0.0,
            &[
                ("geostride.layout", "geostride-centre-heatmap-1"),
                ("geostride.gsd_m", "[0.03, 0.012]"),
            ],
        ),
    )
    .unwrap();
    std::fs::write(
        dir.join("rank2.onnx"),
        constant_model(64, 64, &[6, 10], 0.0, &names),
    )
    .unwrap();
}

const MODEL_CAMERAS: &str = "# Camera list\n1 PINHOLE 1280 720 1000 1000 640 360\n";
const MODEL_POINTS: &str = "# 3D point list\n1 0.5 0.25 10 200 200 200 0.4 1 0 2 0\n2 -0.5 0.5 11 200 200 200 0.4 1 1 2 1\n";
const MODEL_IMAGES: &str = "# Image list\n1 1 0 0 0 0 0 0 1 p0.png\n100.5 200.5 1 300.5 400.5 2\n2 1 0 0 0 -1 0 0 1 p1.png\n120.5 210.5 1 320.5 390.5 2\n";

/// A case: the command, what its message must say and where.
fn case(
    id: &'static str,
    category: &'static str,
    words: &[&str],
    expect: &'static str,
    place: &'static str,
) -> Case {
    Case {
        id,
        category,
        args: args(words),
        expect,
        place,
        ..Case::default()
    }
}

impl Case {
    fn file(mut self, name: &'static str, text: String) -> Case {
        self.files.push((name, text));
        self
    }
    fn bytes(mut self, name: &str, bytes: Vec<u8>) -> Case {
        self.bytes.push((name.to_string(), bytes));
        self
    }
    fn without(mut self, name: &'static str) -> Case {
        self.remove.push(name);
        self
    }
    fn after(mut self, words: &[&str]) -> Case {
        self.setup.push(args(words));
        self
    }
    fn env(mut self, key: &'static str, value: &str) -> Case {
        self.env.push((key, value.to_string()));
        self
    }
}

/// One DJI telemetry block: its counter, time range and fields line.
fn srt_block(index: u32, times: &str, fields: &str) -> String {
    format!("{index}\n{times}\n{fields}\n")
}

/// The fixture's file as bytes.
fn read(name: &str) -> Vec<u8> {
    std::fs::read(fixture().join(name)).unwrap()
}

/// The fixture's JPEG with `e` as its EXIF.
fn jpeg(e: Exif) -> Vec<u8> {
    with_exif(&read("base.jpg"), &e)
}

/// A JPEG header claiming `w`x`h` pixels, and nothing after it.
fn jpeg_claiming(w: u16, h: u16) -> Vec<u8> {
    let mut b = vec![0xFF, 0xD8, 0xFF, 0xC0, 0, 17, 8];
    b.extend(h.to_be_bytes());
    b.extend(w.to_be_bytes());
    b.extend([3, 1, 0x22, 0, 2, 0x11, 1, 3, 0x11, 1]);
    b.extend([0xFF, 0xD9]);
    b
}

/// A PNG header claiming `w`x`h` pixels.
fn png_claiming(w: u32, h: u32) -> Vec<u8> {
    let mut b = b"\x89PNG\r\n\x1a\n\0\0\0\x0dIHDR".to_vec();
    b.extend(w.to_be_bytes());
    b.extend(h.to_be_bytes());
    b.extend([8, 2, 0, 0, 0, 0, 0, 0, 0]);
    b.extend(b"\0\0\0\0IEND\xae\x42\x60\x82");
    b
}

/// The video with bytes in its middle changed: the same size, another content.
fn video_changed() -> Vec<u8> {
    let mut v = read("video.mp4");
    let n = v.len();
    for b in &mut v[n / 2..n / 2 + 64] {
        *b ^= 0x5A;
    }
    v
}

/// The model's file with `from` replaced by `to`.
fn model(file: &str, from: &str, to: &str) -> String {
    replace(&format!("model/{file}"), from, to)
}

/// Camera centres named after the photos, in the GCP file's CRS.
const CENTRES: &str = "name,x,y,z\np0.png,654500.0,696000.0,88.0\np1.png,654502.0,696000.0,88.0\np2.png,654504.0,696001.0,88.0\n";

/// Picks of the GCPs in the photos.
const SFM_PICKS: &str = "name,image,u,v\nGCP1,p0.png,100,100\nGCP1,p1.png,110,100\nGCP2,p0.png,200,300\nGCP2,p1.png,210,300\nGCP3,p0.png,600,400\nGCP3,p1.png,610,400\n";

pub(super) fn cases() -> Vec<Case> {
    let sfm = |extra: &[&str]| {
        let mut w = vec![
            "sfm",
            "photos/p0.png",
            "photos/p1.png",
            "--camera",
            "camera.json",
            "--out",
            "m",
            "-q",
        ];
        w.extend_from_slice(extra);
        w.into_iter().map(str::to_string).collect::<Vec<_>>()
    };
    let sfm_case = |id, category, extra: &[&str], expect, place| Case {
        id,
        category,
        args: sfm(extra),
        expect,
        place,
        ..Case::default()
    };
    let register = |extra: &[&str]| {
        let mut w = vec![
            "sfm",
            "register",
            "model",
            "photos2/p0.png",
            "--model-images",
            "photos",
            "--out",
            "r",
            "-q",
        ];
        w.extend_from_slice(extra);
        w.into_iter().map(str::to_string).collect::<Vec<_>>()
    };
    let register_case = |id, category, expect, place| Case {
        id,
        category,
        args: register(&[]),
        expect,
        place,
        ..Case::default()
    };
    let frame = "truth/frame.png";
    let detect = |extra: &[&str]| {
        let mut w = vec!["detect", frame, "--out", "boxes-out.txt", "-q"];
        w.extend_from_slice(extra);
        w.into_iter().map(str::to_string).collect::<Vec<_>>()
    };
    let detect_case = |id, category, extra: &[&str], expect, place| Case {
        id,
        category,
        args: detect(extra),
        expect,
        place,
        ..Case::default()
    };
    let slurm = |extra: &[&str]| {
        let mut w = vec![
            "slurm",
            "project.toml",
            "--segments",
            "1",
            "--out",
            "sl",
            "-q",
        ];
        w.extend_from_slice(extra);
        w.into_iter().map(str::to_string).collect::<Vec<_>>()
    };
    let slurm_case = |id, extra: &[&str], expect, place| Case {
        id,
        category: "command injected",
        args: slurm(extra),
        expect,
        place,
        ..Case::default()
    };
    let run = || args(&["run", "project.toml", "--out", "out", "-q"]);
    let project_case = |id, category, extra: &str, expect, place| {
        Case {
            id,
            category,
            args: run(),
            expect,
            place,
            ..Case::default()
        }
        .file("project.toml", project_with(extra))
    };
    let onnx = |extra: &str| format!("[detect]\nkind = \"onnx\"\n{extra}");
    let model_pose = "[pose]\nkind = \"model\"\nmodel = \"model\"\nmodel_images = \"photos\"\n";
    let calibrate = |extra: &[&str]| {
        let mut w = vec!["calibrate", "--board", "9x6", "--square", "0.03"];
        w.extend_from_slice(extra);
        w.into_iter().map(str::to_string).collect::<Vec<_>>()
    };
    let pose_image = |extra: &[&str]| {
        let mut w = vec![
            "pose",
            "--camera",
            "camera.json",
            "--gcps",
            "gcps.csv",
            "--picks",
            "picks.csv",
            "--image-size",
            "1280x720",
        ];
        w.extend_from_slice(extra);
        w.into_iter().map(str::to_string).collect::<Vec<_>>()
    };
    let pose_video = |extra: &[&str]| {
        let mut w = vec![
            "pose",
            "--camera",
            "camera.json",
            "--gcps",
            "gcps.csv",
            "--picks",
            "picks.csv",
            "--video",
            "video.mp4",
        ];
        w.extend_from_slice(extra);
        w.into_iter().map(str::to_string).collect::<Vec<_>>()
    };
    let track = |extra: &[&str]| {
        let mut w = vec![
            "track",
            "video.mp4",
            "--detect",
            "boxes",
            "--boxes",
            "boxes.txt",
        ];
        w.extend_from_slice(extra);
        w.into_iter().map(str::to_string).collect::<Vec<_>>()
    };
    let plan = |extra: &[&str]| {
        let mut w = vec!["plan", "--camera", "mini3pro"];
        w.extend_from_slice(extra);
        w.into_iter().map(str::to_string).collect::<Vec<_>>()
    };
    let with = |id, category, words: Vec<String>, expect, place| Case {
        id,
        category,
        args: words,
        expect,
        place,
        ..Case::default()
    };
    let split = [
        "split",
        "project.toml",
        "--segments",
        "1",
        "--out",
        "split",
        "-q",
    ];
    let a_run = ["run", "project.toml", "--out", "runout", "-q"];

    let mut c = vec![
        // --- sfm: names, images and metadata, all found before the features ----------------
        case("sfm-one-name-in-two-folders", "silently wrong model", &["sfm", "photos/p0.png", "photos2/p0.png", "--camera", "camera.json", "--out", "m"], "two images of one name", "photos2/p0.png"),
        case("sfm-one-stem-two-extensions", "silently wrong model", &["sfm", "photos/p0.png", "photos/P0.jpg", "--camera", "camera.json", "--out", "m"], "two images of one name", "P0.jpg")
            .bytes("photos/P0.jpg", read("base.jpg")),
        case("sfm-name-with-a-space", "output broken", &["sfm", "photos/p0.png", "photos/p 1.png", "--camera", "camera.json", "--out", "m"], "holds a space", "photos/p 1.png")
            .bytes("photos/p 1.png", read("photos/p1.png")),
        case("sfm-name-with-a-comma", "output broken", &["sfm", "photos/p0.png", "photos/p,1.png", "--camera", "camera.json", "--out", "m"], "holds a comma", "photos/p,1.png")
            .bytes("photos/p,1.png", read("photos/p1.png")),
        case("sfm-name-with-a-newline", "output broken", &["sfm", "photos", "--camera", "camera.json", "--out", "m"], "control character", "photos/")
            .bytes("photos/p\n1.png", read("photos/p1.png")),
        case("sfm-name-with-a-quote", "output broken", &["sfm", "photos/p0.png", "photos/p\"1.png", "--camera", "camera.json", "--out", "m"], "double quote", "photos/p\"1.png")
            .bytes("photos/p\"1.png", read("photos/p1.png")),
        case("sfm-one-image", "nonsense accepted", &["sfm", "photos/p0.png", "--camera", "camera.json", "--out", "m"], "at least two", "got 1"),
        case("sfm-no-such-image", "wrong code", &["sfm", "photos/p0.png", "photos/p9.png", "--out", "m"], "no such file or folder", "photos/p9.png"),
        case("sfm-folder-without-images", "wrong code", &["sfm", "nodir", "photos", "--out", "m"], "no images in this folder", "nodir")
            .file("nodir/readme.txt", "no images here\n".into()),
        case("sfm-out-holds-an-image", "input overwritten", &["sfm", "photos/p0.png", "photos/p1.png", "--camera", "camera.json", "--out", "photos"], "holds the input", "photos"),
        case("sfm-out-is-a-file", "wrong code", &["sfm", "photos/p0.png", "photos/p1.png", "--camera", "camera.json", "--out", "heights.csv"], "is a file", "heights.csv"),
        case("sfm-out-inside-its-photos", "input overwritten", &["sfm", "photos", "--camera", "camera.json", "--out", "photos/model"], "inside the input folder", "photos"),
        case("sfm-camera-not-there", "wrong code", &["sfm", "photos/p0.png", "photos/p1.png", "--camera", "nope.yaml", "--out", "m"], "nope.yaml", "nope.yaml"),
        case("sfm-camera-of-another-aspect", "silently wrong model", &["sfm", "photos/p0.png", "photos/p1.png", "--camera", "square.json", "--out", "m"], "another aspect", "1280x720")
            .file("square.json", replace("camera.json", "\"height\": 2160", "\"height\": 3840")),
        case("sfm-exif-focal-1mm", "silently wrong model", &["sfm", "e0.jpg", "e1.jpg", "--out", "m"], "no lens has that", "e0.jpg")
            .bytes("e0.jpg", jpeg(Exif { focal_35mm: Some(1), ..Exif::default() }))
            .bytes("e1.jpg", jpeg(Exif { focal_35mm: Some(1), ..Exif::default() })),
        case("sfm-exif-focal-65535mm", "silently wrong model", &["sfm", "e0.jpg", "e1.jpg", "--out", "m"], "65535 mm", "e1.jpg")
            .bytes("e0.jpg", jpeg(Exif { focal_35mm: Some(24), ..Exif::default() }))
            .bytes("e1.jpg", jpeg(Exif { focal_35mm: Some(65535), ..Exif::default() })),
        case("sfm-exif-focals-differ", "silently wrong model", &["sfm", "e0.jpg", "e1.jpg", "--out", "m"], "focal lengths differ", "e1.jpg (48 mm)")
            .bytes("e0.jpg", jpeg(Exif { focal_35mm: Some(24), ..Exif::default() }))
            .bytes("e1.jpg", jpeg(Exif { focal_35mm: Some(48), ..Exif::default() })),
        case("sfm-jpeg-claiming-a-gigapixel", "runaway memory", &["sfm", "huge.jpg", "e1.jpg", "--camera", "camera.json", "--out", "m"], "its header claims 32000x32000", "huge.jpg")
            .bytes("huge.jpg", jpeg_claiming(32000, 32000))
            .bytes("e1.jpg", read("base.jpg")),
        case("sfm-png-claiming-a-gigapixel", "runaway memory", &["sfm", "huge.png", "photos/p1.png", "--camera", "camera.json", "--out", "m"], "its header claims 40000x30000", "huge.png")
            .bytes("huge.png", png_claiming(40000, 30000)),
        case("sfm-images-of-two-sizes", "wrong code", &["sfm", "photos/p0.png", "base.jpg", "--camera", "camera.json", "--out", "m"], "every image must have its size", "base.jpg"),
        case("sfm-image-not-an-image", "wrong code", &["sfm", "photos/p0.png", "notes.png", "--camera", "camera.json", "--out", "m"], "cannot decode", "notes.png")
            .file("notes.png", "not an image\n".into()),
        sfm_case("sfm-picks-without-gcps", "wrong code", &["--picks", "sfm-picks.csv"], "--picks needs --gcps", "--gcps")
            .file("sfm-picks.csv", SFM_PICKS.into()),
        sfm_case("sfm-picks-of-other-images", "found late", &["--gcps", "gcps.csv", "--picks", "sfm-picks.csv"], "outside every image", "q0.png")
            .file("sfm-picks.csv", SFM_PICKS.replace("p0.png", "q0.png").replace("p1.png", "q1.png")),
        sfm_case("sfm-pick-outside-its-image", "found late", &["--gcps", "gcps.csv", "--picks", "sfm-picks.csv"], "outside the 1280x720 image", "sfm-picks.csv:6")
            .file("sfm-picks.csv", SFM_PICKS.replace("GCP3,p0.png,600,400", "GCP3,p0.png,6000,400")),
        sfm_case("sfm-two-gcps-only", "found late", &["--gcps", "gcps.csv", "--picks", "sfm-picks.csv"], "2 control point(s)", "3 needed")
            .file("sfm-picks.csv", SFM_PICKS.lines().take(5).collect::<Vec<_>>().join("\n") + "\n"),
        sfm_case("sfm-centres-112-km-from-the-gcps", "silently wrong model", &["--gcps", "gcps.csv", "--picks", "sfm-picks.csv", "--centres", "centres.csv", "--crs", "EPSG:3812", "--height", "ellipsoidal"], "km (median) from the nearest GCP", "112")
            .file("sfm-picks.csv", SFM_PICKS.into())
            .file("centres.csv", CENTRES.replace(",6545", ",7665")),
        sfm_case("sfm-centres-in-another-crs", "silently wrong model", &["--gcps", "gcps.csv", "--picks", "sfm-picks.csv", "--centres", "centres.csv"], "give both in one CRS", "centres.csv")
            .file("sfm-picks.csv", SFM_PICKS.into())
            .file("centres.csv", "#CoordinateSystem: WGS 84 / UTM zone 31N (EPSG::32631)\n#Label,X/East,Y/North,Z/Altitude\np0.png,600000,5660000,90\np1.png,600002,5660000,90\np2.png,600004,5660001,90\n".into()),
        sfm_case("sfm-gcps-without-picks", "wrong code", &["--gcps", "gcps.csv"], "no pixel picks", "gcps.csv"),
        sfm_case("sfm-sequential-0", "nonsense accepted", &["--sequential", "0"], "--sequential 0", "--sequential"),
        sfm_case("sfm-max-features-10", "nonsense accepted", &["--max-features", "10"], "too few", "--max-features"),
        sfm_case("sfm-centre-sigma-nan", "nonsense accepted", &["--centre-sigma", "nan,0.05"], "two positive numbers", "--centre-sigma"),
        sfm_case("sfm-centre-sigma-one-number", "nonsense accepted", &["--centre-sigma", "0.03"], "two positive numbers", "--centre-sigma"),
        sfm_case("sfm-pick-sigma-0", "nonsense accepted", &["--pick-sigma", "0"], "positive", "--pick-sigma"),
        sfm_case("sfm-gcp-sigma-inf", "nonsense accepted", &["--gcp-sigma", "inf"], "positive", "--gcp-sigma"),
        // --- sfm register and the model pose: the model is an input -------------------------
        register_case("register-model-nan-point", "nonsense accepted", "finite", "model/points3D.txt:2")
            .file("model/points3D.txt", model("points3D.txt", "1 0.5 0.25 10", "1 nan 0.25 10")),
        register_case("register-model-inf-point", "nonsense accepted", "finite", "model/points3D.txt:3")
            .file("model/points3D.txt", model("points3D.txt", "2 -0.5 0.5 11", "2 -0.5 inf 11")),
        register_case("register-model-point-far-away", "nonsense accepted", "beyond", "model/points3D.txt:2")
            .file("model/points3D.txt", model("points3D.txt", "1 0.5 0.25 10", "1 0.5 0.25 1e300")),
        register_case("register-model-fx-0", "nonsense accepted", "focal length", "model/cameras.txt:2")
            .file("model/cameras.txt", model("cameras.txt", "1280 720 1000 1000", "1280 720 0 1000")),
        register_case("register-model-fy-negative", "nonsense accepted", "focal length", "model/cameras.txt:2")
            .file("model/cameras.txt", model("cameras.txt", "1280 720 1000 1000", "1280 720 1000 -5")),
        register_case("register-model-fx-nan", "nonsense accepted", "finite", "model/cameras.txt:2")
            .file("model/cameras.txt", model("cameras.txt", "1280 720 1000 1000", "1280 720 nan 1000")),
        register_case("register-model-size-0", "nonsense accepted", "expected whole numbers from 1", "model/cameras.txt:2")
            .file("model/cameras.txt", model("cameras.txt", "1280 720", "0 720")),
        register_case("register-model-size-fractional", "nonsense accepted", "expected whole numbers from 1", "model/cameras.txt:2")
            .file("model/cameras.txt", model("cameras.txt", "1280 720", "1280.5 720")),
        register_case("register-model-unknown-camera-model", "nonsense accepted", "PINHOLE, OPENCV or FULL_OPENCV", "model/cameras.txt:2")
            .file("model/cameras.txt", model("cameras.txt", "PINHOLE", "FISHEYE_X")),
        register_case("register-model-two-cameras", "nonsense accepted", "more than one camera", "model/cameras.txt:3")
            .file("model/cameras.txt", format!("{MODEL_CAMERAS}2 PINHOLE 1280 720 1000 1000 640 360\n")),
        register_case("register-model-no-camera", "nonsense accepted", "no camera", "model/cameras.txt:1")
            .file("model/cameras.txt", "# nothing\n".into()),
        register_case("register-model-point-twice", "nonsense accepted", "listed twice", "model/points3D.txt:3")
            .file("model/points3D.txt", model("points3D.txt", "2 -0.5 0.5 11", "1 -0.5 0.5 11")),
        register_case("register-model-point-id-negative", "nonsense accepted", "ids are 0 or more", "model/points3D.txt:2")
            .file("model/points3D.txt", model("points3D.txt", "1 0.5 0.25 10", "-7 0.5 0.25 10")),
        register_case("register-model-image-twice", "nonsense accepted", "image 1 is listed twice", "model/images.txt:4")
            .file("model/images.txt", model("images.txt", "2 1 0 0 0 -1", "1 1 0 0 0 -1")),
        register_case("register-model-name-twice", "nonsense accepted", "image p0.png is listed twice", "model/images.txt:4")
            .file("model/images.txt", model("images.txt", "0 1 p1.png", "0 1 p0.png")),
        register_case("register-model-point-not-listed", "nonsense accepted", "point 9 is not in points3D.txt", "model/images.txt:3")
            .file("model/images.txt", model("images.txt", "300.5 400.5 2\n2", "300.5 400.5 9\n2")),
        register_case("register-model-fractional-point-id", "nonsense accepted", "whole number", "model/images.txt:3")
            .file("model/images.txt", model("images.txt", "300.5 400.5 2\n2", "300.5 400.5 1.7\n2")),
        register_case("register-model-zero-quaternion", "nonsense accepted", "unit quaternion", "model/images.txt:2")
            .file("model/images.txt", model("images.txt", "1 1 0 0 0 0 0 0 1 p0.png", "1 0 0 0 0 0 0 0 1 p0.png")),
        register_case("register-model-translation-inf", "nonsense accepted", "finite", "model/images.txt:4")
            .file("model/images.txt", model("images.txt", "2 1 0 0 0 -1 0 0", "2 1 0 0 0 inf 0 0")),
        register_case("register-model-camera-id-unknown", "nonsense accepted", "camera 5 is not the camera", "model/images.txt:2")
            .file("model/images.txt", model("images.txt", "0 0 0 0 1 p0.png", "0 0 0 0 5 p0.png")),
        register_case("register-model-name-leaves-its-folder", "input read from elsewhere", "inside the images' folder", "model/images.txt:2")
            .file("model/images.txt", model("images.txt", "1 p0.png", "1 ../camera.json")),
        register_case("register-model-absolute-name", "input read from elsewhere", "inside the images' folder", "model/images.txt:2")
            .file("model/images.txt", model("images.txt", "1 p0.png", "1 /etc/passwd")),
        register_case("register-model-keypoint-outside", "nonsense accepted", "outside the 1280x720 image", "model/images.txt:3")
            .file("model/images.txt", model("images.txt", "100.5 200.5 1", "100.5 20000.5 1")),
        register_case("register-model-no-images", "nonsense accepted", "no registered image", "model/images.txt")
            .file("model/images.txt", "# none\n".into()),
        register_case("register-model-photo-missing", "found late", "a photo of the model is not here", "photos/p1.png")
            .without("photos/p1.png"),
        case("register-not-a-model", "wrong code", &["sfm", "register", "truth", "photos2/p0.png", "--out", "r"], "not a model folder", "truth"),
        case("register-every-0", "nonsense accepted", &["sfm", "register", "model", "--video", "video.mp4", "--every", "0", "--model-images", "photos", "--out", "r"], "--every 0", "--every"),
        case("register-video-without-model-images", "wrong code", &["sfm", "register", "model", "--video", "video.mp4", "--out", "r"], "--model-images", "--video"),
        case("register-out-inside-the-model", "input overwritten", &["sfm", "register", "model", "photos2/p0.png", "--model-images", "photos", "--out", "model/more"], "inside the input folder", "model"),
        case("register-out-is-the-model", "input overwritten", &["sfm", "register", "model", "photos2/p0.png", "--model-images", "photos", "--out", "model"], "holds the input", "model"),
        case("register-max-features-10", "nonsense accepted", &["sfm", "register", "model", "photos2/p0.png", "--model-images", "photos", "--max-features", "10", "--out", "r"], "too few", "--max-features"),
        case("register-image-name-with-a-space", "output broken", &["sfm", "register", "model", "photos2/p 0.png", "--model-images", "photos", "--out", "r"], "holds a space", "photos2/p 0.png")
            .bytes("photos2/p 0.png", read("photos2/p0.png")),
        project_case("project-model-pose-nan-point", "nonsense accepted", model_pose, "finite", "model/points3D.txt:2")
            .file("model/points3D.txt", model("points3D.txt", "1 0.5 0.25 10", "1 nan 0.25 10")),
        project_case("project-model-pose-fx-0", "nonsense accepted", model_pose, "focal length", "model/cameras.txt:2")
            .file("model/cameras.txt", model("cameras.txt", "1280 720 1000 1000", "1280 720 0 1000")),
        Case {
            args: args(&["run", "project.toml", "--out", "model/run", "-q"]),
            ..project_case("project-model-pose-out-inside-the-model", "input overwritten", model_pose, "inside the input folder", "model")
        },
        // --- detect: every option in range before the model runs ---------------------------
        detect_case("detect-tile-1", "runaway time", &["--tile", "1"], "expected tiles of 32 pixels or more", "--tile"),
        detect_case("detect-tile-not-above-overlap", "runaway time", &["--tile", "64", "--overlap", "64"], "overlapping by at most half", "--tile"),
        detect_case("detect-threads-100000", "runaway memory", &["--threads", "100000"], "expected 0", "--threads"),
        detect_case("detect-mean-nan", "nonsense accepted", &["--mean", "nan,0,0"], "from -10 to 10", "--mean"),
        detect_case("detect-mean-two-numbers", "nonsense accepted", &["--mean", "0,0"], "three numbers each", "--mean"),
        detect_case("detect-std-inf", "nonsense accepted", &["--std", "1e39,1,1"], "from 1e-6 to 1000", "--std"),
        detect_case("detect-std-0", "nonsense accepted", &["--std", "0,1,1"], "from 1e-6 to 1000", "--std"),
        detect_case("detect-roi-of-no-width", "nonsense accepted", &["--roi", "0,0,0,100"], "at least 1", "--roi"),
        detect_case("detect-roi-three-numbers", "nonsense accepted", &["--roi", "0,0,100"], "four whole numbers", "--roi"),
        detect_case("detect-roi-outside-the-frame", "nonsense accepted", &["--roi", "5000,5000,10,10"], "lies outside the 1280x720 frame", "roi"),
        detect_case("detect-input-size-0", "nonsense accepted", &["--input-size", "0x0"], "WIDTHxHEIGHT", "--input-size"),
        detect_case("detect-input-size-8192", "runaway memory", &["--input-size", "8192x8192"], "32 to 4096", "--input-size"),
        detect_case("detect-max-boxes-0", "nonsense accepted", &["--max-boxes", "0"], "expected 1 to 10000", "--max-boxes"),
        detect_case("detect-max-boxes-huge", "runaway memory", &["--max-boxes", "100000000"], "expected 1 to 10000", "--max-boxes"),
        detect_case("detect-min-score-2", "nonsense accepted", &["--min-score", "2"], "fraction from 0 to 1", "--min-score"),
        detect_case("detect-nms-nan", "nonsense accepted", &["--nms", "nan"], "fraction from 0 to 1", "--nms"),
        detect_case("detect-every-0", "nonsense accepted", &["--every", "0"], "--every 0", "--every"),
        detect_case("detect-max-frames-0", "nonsense accepted", &["--max-frames", "0"], "--max-frames 0", "--max-frames"),
        detect_case("detect-empty-class", "nonsense accepted", &["--classes", "person,"], "none empty", "--classes"),
        detect_case("detect-unknown-class", "nonsense accepted", &["--classes", "unicorn"], "has no class 'unicorn'", "overhead-person.onnx"),
        detect_case("detect-model-gives-nan", "nonsense accepted", &["--model", "nan.onnx"], "not numbers", "nan.onnx"),
        detect_case("detect-model-of-unknown-layout", "nonsense accepted", &["--model", "rank2.onnx"], "cannot tell the output layout", "rank2.onnx"),
        detect_case("detect-model-of-a-future-geostride-layout", "nonsense accepted", &["--model", "future.onnx"], "this geostride reads 'geostride-centre-heatmap-1'", "future.onnx"),
        detect_case("detect-centre-heatmap-of-6-values", "nonsense accepted", &["--model", "centre6.onnx"], "the centre heatmap layout has 7", "centre6.onnx"),
        detect_case("detect-model-of-reversed-scales", "nonsense accepted", &["--model", "centre-bad-gsd.onnx"], "expected [finest, coarsest] metres a pixel", "centre-bad-gsd.onnx"),
        detect_case("detect-gsd-for-a-model-without-scales", "nonsense accepted", &["--gsd-cm", "1.5", "--model", "yolov3-tiny"], "does not state the scales it was trained at", "yolov3-tiny.onnx"),
        detect_case("detect-gsd-0", "nonsense accepted", &["--gsd-cm", "0"], "from 0.01 to 100 cm a pixel", "--gsd-cm"),
        detect_case("detect-own-model-read-as-yolov8", "nonsense accepted", &["--layout", "yolov8"], "says it is a centre_heatmap model", "overhead-person.onnx"),
        detect_case("detect-darknet-without-anchors", "nonsense accepted", &["--model", "nan.onnx", "--layout", "darknet"], "darknet_yolo metadata", "nan.onnx"),
        detect_case("detect-model-not-onnx", "wrong code", &["--model", "gcps.csv"], "gcps.csv", "gcps.csv"),
        detect_case("detect-model-missing", "wrong code", &["--model", "nope.onnx"], "nope.onnx", "nope.onnx"),
        case("detect-image-claiming-a-gigapixel", "runaway memory", &["detect", "huge.jpg", "--out", "b.txt"], "its header claims 32000x32000", "huge.jpg")
            .bytes("huge.jpg", jpeg_claiming(32000, 32000)),
        case("detect-image-not-an-image", "wrong code", &["detect", "notes.png", "--out", "b.txt"], "not an image OpenCV can read", "notes.png")
            .file("notes.png", "text\n".into()),
        case("detect-out-onto-its-image", "input overwritten", &["detect", frame, "--out", frame], "would overwrite the input", frame),
        detect_case("detect-preview-onto-its-image", "input overwritten", &["--preview", frame], "would overwrite the input", frame),
        detect_case("detect-out-into-a-missing-folder", "wrong code", &["--preview", "missing/p.png"], "does not exist", "missing/p.png"),
        // --- the project's detectors: the same checks -----------------------------------------
        project_case("project-onnx-tile-1", "runaway time", &onnx("tile = 1\n"), "expected tiles of 32 pixels or more", "field 'detect.tile'"),
        project_case("project-onnx-threads-100000", "runaway memory", &onnx("threads = 100000\n"), "expected 0", "field 'detect.threads'"),
        project_case("project-onnx-std-beyond-f32", "nonsense accepted", &onnx("std = [1e39, 1.0, 1.0]\n"), "from 1e-6 to 1000", "field 'detect.std'"),
        project_case("project-onnx-roi-of-no-height", "nonsense accepted", &onnx("roi = [0, 0, 100, 0]\n"), "at least 1", "field 'detect.roi'"),
        project_case("project-onnx-input-size-0", "nonsense accepted", &onnx("input_size = [0, 0]\n"), "32 to 4096", "field 'detect.input_size'"),
        project_case("project-onnx-max-boxes-huge", "runaway memory", &onnx("max_boxes = 100000000\n"), "expected 1 to 10000", "field 'detect.max_boxes'"),
        project_case("project-onnx-stride-0", "nonsense accepted", &onnx("stride = 0\n"), "expected 1 or more", "field 'detect.stride'"),
        project_case("project-onnx-model-gives-nan", "nonsense accepted", &onnx("model = \"nan.onnx\"\n"), "not numbers", "field 'detect.model'"),
        project_case("project-onnx-darknet-without-anchors", "nonsense accepted", &onnx("model = \"nan.onnx\"\nlayout = \"darknet\"\n"), "darknet_yolo metadata", "field 'detect.model'"),
        project_case("project-onnx-unknown-layout-name", "nonsense accepted", &onnx("layout = \"yolov99\"\n"), "expected 'darknet'", "field 'detect.layout'"),
        project_case("project-onnx-merge-iou-2", "nonsense accepted", &onnx("merge_iou = 2.0\n"), "must be in [0, 1]", "field 'detect.merge_iou'"),
        project_case("project-boxes-roi-of-no-width", "nonsense accepted", "[detect]\nkind = \"boxes\"\nboxes = \"boxes.txt\"\nroi = [10, 0, 10, 100]\n", "0 <= x0 < x1", "field 'detect.roi'"),
        project_case("project-boxes-aspect-inverted", "nonsense accepted", "[detect]\nkind = \"boxes\"\nboxes = \"boxes.txt\"\naspect = [4.0, 0.25]\n", "0 < min <= max", "field 'detect.aspect'"),
        project_case("project-boxes-size-zero", "nonsense accepted", "[detect]\nkind = \"boxes\"\nboxes = \"boxes.txt\"\nsize_m = [0.0, 1.6]\n", "0 < min <= max", "field 'detect.size_m'"),
        project_case("project-unknown-tracker", "misleading message", "[track]\nkind = \"sort\"\n", "sort", "project.toml:"),
        project_case("project-unknown-smoother", "misleading message", "[smooth]\nkind = \"particle\"\n", "particle", "project.toml:"),
        project_case("project-unknown-export-format", "misleading message", "[output]\n", "", "").file(
            "project.toml",
            replace("project.toml", "formats = [\"csv\", \"geojson\"]", "formats = [\"csv\", \"shapefile\"]"),
        ),
        project_case("project-video-missing", "wrong code", "", "no such", "field 'video.path'").file(
            "project.toml",
            replace("project.toml", "path = \"video.mp4\"", "path = \"nope.mp4\""),
        ),
        project_case("project-negative-duration", "nonsense accepted", "", "duration_s", "field 'video.duration_s'").file(
            "project.toml",
            replace("project.toml", "path = \"video.mp4\"", "path = \"video.mp4\"\nduration_s = -5.0"),
        ),
        project_case("project-chunk-of-no-seconds", "runaway time", "", "chunk_s", "field 'video.chunk_s'").file(
            "project.toml",
            replace("project.toml", "path = \"video.mp4\"", "path = \"video.mp4\"\nchunk_s = 0.0"),
        ),
        project_case("project-head-height-nan", "nonsense accepted", "", "head_height_m", "project.toml").file(
            "project.toml",
            replace("project.toml", "head_height_m = 1.7", "head_height_m = nan"),
        ),
        project_case("project-head-height-20-m", "nonsense accepted", "", "head_height_m", "field 'projection.head_height_m'").file(
            "project.toml",
            replace("project.toml", "head_height_m = 1.7", "head_height_m = 20.0"),
        ),
        // --- slurm: no value becomes a shell line -----------------------------------------------
        slurm_case("slurm-time-with-a-newline", &["--time", "1:00:00\ntouch pwned"], "expected a Slurm time", "--time"),
        slurm_case("slurm-merge-time-with-a-newline", &["--merge-time", "1:00:00\ntouch pwned"], "expected a Slurm time", "--merge-time"),
        slurm_case("slurm-mem-with-a-newline", &["--mem", "8G\ntouch pwned"], "expected a Slurm memory size", "--mem"),
        slurm_case("slurm-merge-mem-with-a-newline", &["--merge-mem", "8G\ntouch pwned"], "expected a Slurm memory size", "--merge-mem"),
        slurm_case("slurm-partition-with-a-newline", &["--partition", "short\ntouch pwned"], "expected partition names", "--partition"),
        slurm_case("slurm-sbatch-with-a-newline", &["--sbatch=--account=x\ntouch pwned"], "expected one sbatch option", "--sbatch"),
        slurm_case("slurm-sbatch-not-an-option", &["--sbatch", "account=x"], "expected one sbatch option", "--sbatch"),
        slurm_case("slurm-sbatch-with-a-quote", &["--sbatch=--comment='a"], "without '\\''", "--sbatch"),
        slurm_case("slurm-sbatch-with-a-space", &["--sbatch=--account=a --exclusive"], "without ' '", "--sbatch"),
        slurm_case("slurm-time-with-a-space", &["--time", "1:00 --exclusive"], "expected a Slurm time", "--time"),
        slurm_case("slurm-cpus-0", &["--cpus", "0"], "expected 1 to 4096", "--cpus"),
        with("slurm-out-with-a-newline", "command injected", args(&["slurm", "project.toml", "--segments", "1", "--out", "sl\nx"]), "cannot name this folder", "--out"),
        // --- split, segment, merge ----------------------------------------------------------------
        case("split-0-segments", "misleading message", &["split", "project.toml", "--segments", "0", "--out", "split"], "at least 1", "--segments"),
        case("split-a-billion-segments", "runaway memory", &["split", "project.toml", "--segments", "1000000000", "--out", "split"], "ask for at most", "video.chunk_s"),
        case("split-into-the-project-folder", "input overwritten", &["split", "project.toml", "--segments", "1", "--out", "."], "holds the input", "."),
        case("split-out-is-a-file", "wrong code", &["split", "project.toml", "--segments", "1", "--out", "heights.csv"], "is a file", "heights.csv"),
        case("segment-not-a-split", "wrong code", &["segment", "truth", "--index", "0"], "split.json", "truth"),
        case("segment-index-beyond", "wrong code", &["segment", "split", "--index", "7"], "segments 0 to 0", "split")
            .after(&split),
        case("segment-index-variable-not-a-number", "wrong code", &["segment", "split"], "SLURM_ARRAY_TASK_ID", "x7")
            .after(&split)
            .env("SLURM_ARRAY_TASK_ID", "x7"),
        case("segment-video-replaced", "misleading message", &["segment", "split", "--index", "0"], "since it was split", "field 'video.path'")
            .after(&split)
            .bytes("video.mp4", video_changed()),
        case("segment-project-edited", "misleading message", &["segment", "split", "--index", "0"], "changed since it was split", "project.toml")
            .after(&split)
            .file("project.toml", project_with("\n")),
        case("segment-manifest-garbage", "nonsense accepted", &["segment", "split", "--index", "0"], "split.json", "split")
            .after(&split)
            .file("split/split.json", "{ not json".into()),
        case("merge-not-a-split", "wrong code", &["merge", "truth"], "split.json", "truth"),
        case("merge-video-replaced", "misleading message", &["merge", "split"], "since it was split", "field 'video.path'")
            .after(&split)
            .bytes("video.mp4", video_changed()),
        case("merge-video-gone", "misleading message", &["merge", "split"], "no such file", "field 'video.path'")
            .after(&split)
            .without("video.mp4"),
        // --- render: a finished run's views, nothing else ---------------------------------------
        case("render-not-a-run", "wrong code", &["render", "truth"], "give the output folder of a geostride run", "truth/report.json"),
        case("render-report-not-json", "nonsense accepted", &["render", "runout"], "not a geostride run report", "runout/report.json")
            .after(&a_run)
            .file("runout/report.json", "{ broken".into()),
        case("render-project-edited", "silently wrong output", &["render", "runout"], "settings changed since the run", "project.toml")
            .after(&a_run)
            .file("project.toml", replace("project.toml", "head_height_m = 1.7", "head_height_m = 1.6")),
        case("render-video-replaced", "silently wrong output", &["render", "runout"], "not the file the run", "field 'video.path'")
            .after(&a_run)
            .bytes("video.mp4", video_changed()),
        case("render-video-width-10", "nonsense accepted", &["render", "runout", "--video-width", "10"], "160 to 7680", "--video-width")
            .after(&a_run),
        // --- calibrate ------------------------------------------------------------------------------
        with("calibrate-onto-an-image-of-its-folder", "input overwritten", calibrate(&["--format", "json", "-o", "boards/b0.png", "boards"]), "would overwrite the input", "boards/b0.png"),
        with("calibrate-into-its-folder", "input overwritten", calibrate(&["-o", "boards/cal.yaml", "boards"]), "inside the input folder", "boards"),
        with("calibrate-board-2x2", "nonsense accepted", args(&["calibrate", "--board", "2x2", "--square", "0.03", "boards"]), "at least 3x3", "--board"),
        with("calibrate-square-nan", "nonsense accepted", args(&["calibrate", "--board", "9x6", "--square", "nan", "boards"]), "positive number", "--square"),
        with("calibrate-no-such-input", "wrong code", calibrate(&["nope"]), "does not exist", "nope"),
        with("calibrate-empty-folder", "wrong code", calibrate(&["nodir"]), "holds no images", "nodir")
            .file("nodir/readme.txt", "no images here\n".into()),
        with("calibrate-image-claiming-a-gigapixel", "runaway memory", calibrate(&["huge.jpg"]), "its header claims 32000x32000", "huge.jpg")
            .bytes("huge.jpg", jpeg_claiming(32000, 32000)),
        // --- pose -----------------------------------------------------------------------------------
        with("pose-image-size-0", "nonsense accepted", args(&["pose", "--camera", "camera.json", "--gcps", "gcps.csv", "--picks", "picks.csv", "--image-size", "0x0"]), "WIDTHxHEIGHT", "--image-size"),
        with("pose-camera-missing", "wrong code", args(&["pose", "--camera", "nope.json", "--gcps", "gcps.csv", "--picks", "picks.csv", "--image-size", "1280x720"]), "nope.json", "nope.json"),
        with("pose-annotated-onto-its-picks", "input overwritten", pose_image(&["--image", frame, "--annotated", "picks.csv"]), "picks.csv", "picks.csv"),
        with("pose-annotated-onto-its-image", "input overwritten", pose_image(&["--image", frame, "--annotated", frame]), "would overwrite the input", frame),
        with("pose-video-missing", "wrong code", pose_video(&["--out", "pv"]).into_iter().map(|w| if w == "video.mp4" { "nope.mp4".into() } else { w }).collect(), "nope.mp4", "nope.mp4"),
        with("pose-video-out-is-a-file", "wrong code", pose_video(&["--out", "heights.csv"]), "is a file", "heights.csv"),
        // --- gcp find -------------------------------------------------------------------------------
        case("gcp-find-onto-its-gcps", "input overwritten", &["gcp", "find", frame, "--gcps", "gcps.csv", "--out", "gcps.csv"], "would overwrite the input", "gcps.csv"),
        case("gcp-find-image-missing", "wrong code", &["gcp", "find", "nope.png", "--gcps", "gcps.csv", "--out", "found.csv"], "no such file", "nope.png"),
        case("gcp-find-not-an-image", "wrong code", &["gcp", "find", "fake.png", "--gcps", "gcps.csv", "--out", "found.csv"], "fake.png", "fake.png")
            .file("fake.png", "not an image at all\n".into()),
        case("gcp-find-image-claiming-a-gigapixel", "runaway memory", &["gcp", "find", "huge.jpg", "--gcps", "gcps.csv", "--out", "found.csv"], "its header claims 32000x32000", "huge.jpg")
            .bytes("huge.jpg", jpeg_claiming(32000, 32000)),
        case("gcp-find-heading-tolerance-500", "nonsense accepted", &["gcp", "find", frame, "--gcps", "gcps.csv", "--heading", "0:500", "--out", "found.csv"], "tolerance", "--heading"),
        case("gcp-find-unknown-design", "nonsense accepted", &["gcp", "find", frame, "--gcps", "gcps.csv", "--design", "checker,hexagon", "--out", "found.csv"], "hexagon", "--design"),
        case("gcp-find-code-table-names-an-unknown-gcp", "nonsense accepted", &["gcp", "find", frame, "--gcps", "gcps.csv", "--design", "coded", "--codes", "codes.csv", "--out", "found.csv"], "'NOPE' is not a point of the survey", "codes.csv: line 3")
            .file("codes.csv", "id,name\n# a marker on every control point\n7,NOPE\n".into()),
        case("gcp-find-unknown-dictionary", "nonsense accepted", &["gcp", "find", frame, "--gcps", "gcps.csv", "--design", "coded", "--dictionary", "4x4_51", "--out", "found.csv"], "unknown dictionary", "--dictionary"),
        case("gcp-find-codes-without-coded-design", "nonsense accepted", &["gcp", "find", frame, "--gcps", "gcps.csv", "--codes", "codes.csv", "--out", "found.csv"], "add 'coded' to --design", "--codes")
            .file("codes.csv", "1,GCP1\n".into()),
        case("gcp-find-video-frame-beyond-its-end", "wrong code", &["gcp", "find", "video.mp4", "--frame", "100000", "--gcps", "gcps.csv", "--out", "found.csv"], "100000", "video.mp4"),
        // --- gcp pick (each refused before the page is served) ------------------------------------
        case("gcp-pick-onto-its-gcps", "input overwritten", &["gcp", "pick", frame, "--gcps", "gcps.csv", "--out", "gcps.csv"], "would overwrite the input", "gcps.csv"),
        case("gcp-pick-onto-its-picks", "input overwritten", &["gcp", "pick", frame, "--gcps", "gcps.csv", "--picks", "picks.csv", "--out", "picks.csv"], "would overwrite the input", "picks.csv"),
        case("gcp-pick-image-missing", "wrong code", &["gcp", "pick", "nope.png", "--gcps", "gcps.csv", "--out", "picked.csv"], "no such file", "nope.png"),
        case("gcp-pick-camera-missing", "wrong code", &["gcp", "pick", frame, "--gcps", "gcps.csv", "--camera", "nope.json", "--out", "picked.csv"], "nope.json", "nope.json"),
        // --- track ----------------------------------------------------------------------------------
        with("track-px-per-m-0", "nonsense accepted", track(&["--px-per-m", "0", "--out", "t"]), "positive number", "--px-per-m"),
        with("track-px-per-m-huge", "nonsense accepted", track(&["--px-per-m", "1e9", "--out", "t"]), "--px-per-m", "--px-per-m"),
        with("track-boxes-missing", "wrong code", args(&["track", "video.mp4", "--detect", "boxes", "--boxes", "nope.txt", "--px-per-m", "30", "--out", "t"]), "nope.txt", "nope.txt"),
        with("track-areas-inverted", "nonsense accepted", args(&["track", "video.mp4", "--px-per-m", "30", "--min-area-m2", "5", "--max-area-m2", "1", "--out", "t"]), "area", "--min-area-m2"),
        with("track-image-as-video", "wrong code", args(&["track", frame, "--px-per-m", "30", "--out", "t"]), "is an image", frame),
        // --- plan -----------------------------------------------------------------------------------
        with("plan-altitude-0", "nonsense accepted", plan(&["--altitude", "0"]), "positive number", "--altitude"),
        with("plan-altitude-nan", "nonsense accepted", plan(&["--altitude", "nan"]), "positive number", "--altitude"),
        with("plan-unknown-camera", "wrong code", args(&["plan", "--camera", "hasselblad", "--altitude", "30"]), "hasselblad", "--camera"),
        with("plan-head-height-nan", "nonsense accepted", plan(&["--altitude", "30", "--head-height", "nan"]), "head", "--head-height"),
        with("plan-height-error-negative", "nonsense accepted", plan(&["--altitude", "30", "--height-error=-1"]), "height", "--height-error"),
        with("plan-map-step-0", "nonsense accepted", plan(&["--altitude", "30", "--map-step", "0"]), "map-step", "--map-step"),
        with("plan-out-is-a-file", "wrong code", plan(&["--altitude", "30", "--out", "heights.csv"]), "is a file", "heights.csv"),
        // --- camera, survey, ba, evaluate, fit-error, simulate, demo ------------------------------------
        case("camera-show-missing", "wrong code", &["camera", "show", "nope.yaml"], "nope.yaml", "nope.yaml"),
        case("camera-convert-to-an-unknown-format", "wrong code", &["camera", "convert", "camera.json", "cam.xyz"], "cam.xyz", "cam.xyz"),
        case("camera-convert-into-a-missing-folder", "wrong code", &["camera", "convert", "camera.json", "missing/c.yaml"], "does not exist", "missing/c.yaml"),
        case("camera-json-focal-zero", "nonsense accepted", &["camera", "show", "camera.json"], "focal length", "camera.json")
            .file("camera.json", super::replace_number("camera.json", "\"fx\"", "0")),
        case("survey-inspect-missing", "wrong code", &["survey", "inspect", "nope.csv"], "nope.csv", "nope.csv"),
        case("survey-convert-unknown-format", "wrong code", &["survey", "convert", "gcps.csv", "--to", "kml", "-o", "g.kml"], "kml", "--to"),
        case("survey-unknown-crs-option", "wrong code", &["survey", "inspect", "gcps.csv", "--crs", "EPSG:99999"], "PROJ does not know it", "EPSG:99999"),
        case("survey-picks-missing", "wrong code", &["survey", "inspect", "gcps.csv", "--picks", "nope.csv"], "nope.csv", "nope.csv"),
        case("ba-missing", "wrong code", &["ba", "--bal", "nope.bal"], "nope.bal", "nope.bal"),
        case("ba-nan-point", "nonsense accepted", &["ba", "--bal", "problem.bal"], "finite", "problem.bal:")
            .file("problem.bal", super::BAL.replace("0.5 0.2 1.0", "0.5 nan 1.0")),
        case("ba-out-is-a-folder", "wrong code", &["ba", "--bal", "problem.bal", "--out", "truth"], "is a folder", "truth"),
        case("evaluate-missing-truth", "wrong code", &["evaluate", "--truth", "nope.csv", "--tracks", "t.csv"], "nope.csv", "nope.csv")
            .file("t.csv", "frame,id,e_m,n_m\n0,1,0,0\n".into()),
        case("evaluate-nan-position", "nonsense accepted", &["evaluate", "--truth", "truth.csv", "--tracks", "t.csv"], "finite", "t.csv:2")
            .file("truth.csv", "frame,person,e_m,n_m\n0,1,0,0\n".into())
            .file("t.csv", "frame,id,e_m,n_m\n0,1,nan,0\n".into()),
        case("fit-error-missing-detections", "wrong code", &["fit-error", "--detections", "nope.csv", "--annotations", "ann.csv", "--width", "1280"], "nope.csv", "nope.csv")
            .file("ann.csv", "frame,x_px,y_px\n0,10,10\n".into()),
        case("simulate-fps-0.001", "wrong code", &["simulate", "scene.toml", "--out", "sim"], "from 1 to 240", "field 'fps'")
            .file("scene.toml", replace("scene.toml", "fps = 15", "fps = 0.001")),
        case("simulate-fps-half", "wrong code", &["simulate", "scene.toml", "--out", "sim"], "from 1 to 240", "field 'fps'")
            .file("scene.toml", replace("scene.toml", "fps = 15", "fps = 0.5")),
        case("simulate-duration-0", "nonsense accepted", &["simulate", "scene.toml", "--out", "sim", "--duration", "0"], "--duration", "--duration"),
        case("simulate-out-is-a-file", "wrong code", &["simulate", "scene.toml", "--out", "heights.csv"], "is a file", "heights.csv"),
        case("simulate-scene-missing", "wrong code", &["simulate", "nope.toml", "--out", "sim"], "nope.toml", "nope.toml"),
        with(
            "demo-out-is-a-file",
            "wrong code",
            args(&["demo", "--out", "heights.csv", "--survey", concat!(env!("CARGO_MANIFEST_DIR"), "/surveys/bridge-stream")]),
            "is a file",
            "heights.csv",
        ),
        // DJI telemetry subtitles (`geostride telemetry`).
        case("srt-latitude-beyond-90", "nonsense accepted", &["telemetry", "d.SRT", "--out", "t.csv"], "within ±90", "d.SRT:3")
            .file("d.SRT", srt_block(1, "00:00:00,000 --> 00:00:00,033", "[latitude: 97.5] [longitude: 8.5]")),
        case("srt-bad-time-range", "wrong code", &["telemetry", "d.SRT", "--out", "t.csv"], "HH:MM:SS,mmm", "d.SRT:2")
            .file("d.SRT", srt_block(1, "00:00:00,000 -> 00:00:00,033", "[latitude: 47.5] [longitude: 8.5]")),
        case("srt-number-unread", "nonsense accepted", &["telemetry", "d.SRT", "--out", "t.csv"], "field 'rel_alt'", "d.SRT:3")
            .file("d.SRT", srt_block(1, "00:00:00,000 --> 00:00:00,033", "[latitude: 47.5] [longitude: 8.5] [rel_alt: 3,5 abs_alt: 400.0]")),
        case("srt-out-of-order", "nonsense accepted", &["telemetry", "d.SRT", "--out", "t.csv"], "time order", "d.SRT:6")
            .file(
                "d.SRT",
                srt_block(1, "00:00:01,000 --> 00:00:01,033", "[latitude: 47.5] [longitude: 8.5]")
                    + "\n"
                    + &srt_block(2, "00:00:00,000 --> 00:00:00,033", "[latitude: 47.5] [longitude: 8.5]"),
            ),
        case("srt-no-blocks", "nonsense accepted", &["telemetry", "d.SRT", "--out", "t.csv"], "no subtitle blocks", "d.SRT")
            .file("d.SRT", "\n\n".into()),
        case("srt-not-text", "wrong code", &["telemetry", "d.SRT", "--out", "t.csv"], "not UTF-8", "d.SRT")
            .bytes("d.SRT", vec![0xff, 0xfe, 0x31, 0x0a]),
    ];
    // Keep the id order readable in failures.
    c.retain(|x| !x.id.is_empty());
    c
}

/// One command pointed at its own inputs: its output equal to an input file, or a folder inside
/// an input folder or holding an input. `code`: the exit code expected (2: refused; 0 for the
/// commands that write nothing).
pub(super) struct Aimed {
    pub label: &'static str,
    pub args: Vec<String>,
    pub case: Case,
    pub code: i32,
    /// (file, folder): after the set-up, the project that `file` names is the copy in `folder`.
    pub retarget: Option<(&'static str, &'static str)>,
}

/// Every command that writes, aimed at its inputs; and the ones that only read, run on them.
pub(super) fn aimed_at_inputs() -> Vec<Aimed> {
    let at = |label: &'static str, words: &[&str], code: i32| Aimed {
        label,
        args: args(words),
        case: Case::default(),
        code,
        retarget: None,
    };
    let survey = concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/surveys/bridge-stream/scene.toml"
    );
    let scene = std::fs::read(survey).unwrap();
    let split = [
        "split",
        "project.toml",
        "--segments",
        "1",
        "--out",
        "split",
        "-q",
    ];
    let a_run = ["run", "project.toml", "--out", "runout", "-q"];
    // A project and its inputs copied into `dir`, where a split or run folder is.
    let inside = |dir: &str| -> Vec<(String, Vec<u8>)> {
        [
            "project.toml",
            "camera.json",
            "gcps.csv",
            "picks.csv",
            "video.mp4",
        ]
        .iter()
        .map(|f| (format!("{dir}/{f}"), read(f)))
        .collect()
    };
    let mut segment = at(
        "segment: its split folder holds the project's inputs",
        &["segment", "split", "--index", "0", "-q"],
        2,
    );
    segment.case = Case::default().after(&split);
    segment.case.bytes = inside("split");
    segment.retarget = Some(("split/split.json", "split"));
    let mut merge = at(
        "merge: its split folder holds the project's inputs",
        &["merge", "split", "-q"],
        2,
    );
    merge.case = Case::default().after(&split);
    merge.case.bytes = inside("split");
    merge.retarget = Some(("split/split.json", "split"));
    let mut render = at(
        "render: its run folder holds the project's inputs",
        &["render", "runout", "-q"],
        2,
    );
    render.case = Case::default().after(&a_run);
    render.case.bytes = inside("runout");
    render.retarget = Some(("runout/report.json", "runout"));
    let mut demo = at(
        "demo: --out the survey's folder",
        &["demo", "--survey", "bs", "--out", "bs"],
        2,
    );
    demo.case.bytes = vec![("bs/scene.toml".into(), scene.clone())];
    let mut demo_in = at(
        "demo: --out inside the survey's folder",
        &["demo", "--survey", "bs", "--out", "bs/out"],
        2,
    );
    demo_in.case.bytes = vec![("bs/scene.toml".into(), scene)];
    vec![
        at(
            "ba: --out its problem",
            &["ba", "--bal", "problem.bal", "--out", "problem.bal"],
            2,
        ),
        at(
            "calibrate: -o its image",
            &[
                "calibrate",
                "--board",
                "9x6",
                "--square",
                "0.03",
                "--format",
                "json",
                "-o",
                "truth/frame.png",
                "truth/frame.png",
            ],
            2,
        ),
        at(
            "calibrate: -o an image of its folder",
            &[
                "calibrate",
                "--board",
                "9x6",
                "--square",
                "0.03",
                "--format",
                "json",
                "-o",
                "boards/b0.png",
                "boards",
            ],
            2,
        ),
        at(
            "calibrate: -o into its folder",
            &[
                "calibrate",
                "--board",
                "9x6",
                "--square",
                "0.03",
                "-o",
                "boards/cal.json",
                "boards",
            ],
            2,
        ),
        at(
            "camera convert: onto itself",
            &["camera", "convert", "camera.json", "camera.json"],
            2,
        ),
        at(
            "camera show: reads only",
            &["camera", "show", "camera.json"],
            0,
        ),
        demo,
        demo_in,
        at(
            "detect: --out its image",
            &["detect", "truth/frame.png", "--out", "truth/frame.png"],
            2,
        ),
        at(
            "detect: --preview its model",
            &[
                "detect",
                "truth/frame.png",
                "--model",
                "nan.onnx",
                "--out",
                "b.txt",
                "--preview",
                "nan.onnx",
            ],
            2,
        ),
        at(
            "evaluate: reads only",
            &[
                "evaluate",
                "--truth",
                "truth/heads.csv",
                "--tracks",
                "truth/heads.csv",
                "--tracks-columns",
                "frame,person,e_m,n_m",
            ],
            0,
        ),
        at(
            "fit-error: reads only",
            &[
                "fit-error",
                "--detections",
                "truth/heads.csv",
                "--annotations",
                "truth/heads.csv",
                "--width",
                "1280",
            ],
            2,
        ),
        at(
            "plan: --out the camera's folder",
            &[
                "plan",
                "--camera",
                "camera.json",
                "--altitude",
                "30",
                "--out",
                ".",
            ],
            2,
        ),
        at(
            "pose: --annotated its image",
            &[
                "pose",
                "--camera",
                "camera.json",
                "--gcps",
                "gcps.csv",
                "--picks",
                "picks-frame.csv",
                "--image",
                "truth/frame.png",
                "--annotated",
                "truth/frame.png",
            ],
            2,
        ),
        at(
            "pose --video: --out its folder",
            &[
                "pose",
                "--camera",
                "camera.json",
                "--gcps",
                "gcps.csv",
                "--picks",
                "picks.csv",
                "--video",
                "video.mp4",
                "--out",
                ".",
            ],
            2,
        ),
        render,
        at(
            "run: --out its folder",
            &["run", "project.toml", "--out", ".", "-q"],
            2,
        ),
        segment,
        merge,
        at(
            "sfm: --out its photos' folder",
            &[
                "sfm",
                "photos",
                "--camera",
                "camera.json",
                "--out",
                "photos",
            ],
            2,
        ),
        at(
            "sfm: --out inside its photos' folder",
            &[
                "sfm",
                "photos",
                "--camera",
                "camera.json",
                "--out",
                "photos/model",
            ],
            2,
        ),
        at(
            "sfm register: --out its model",
            &[
                "sfm",
                "register",
                "model",
                "photos2/p0.png",
                "--model-images",
                "photos",
                "--out",
                "model",
            ],
            2,
        ),
        at(
            "sfm register: --out inside its model",
            &[
                "sfm",
                "register",
                "model",
                "photos2/p0.png",
                "--model-images",
                "photos",
                "--out",
                "model/more",
            ],
            2,
        ),
        at(
            "sfm register: --out inside its model's photos",
            &[
                "sfm",
                "register",
                "model",
                "photos2/p0.png",
                "--model-images",
                "photos",
                "--out",
                "photos/more",
            ],
            2,
        ),
        at(
            "simulate: --out its scene's folder",
            &["simulate", "scene.toml", "--out", "."],
            2,
        ),
        at(
            "slurm: --out its project's folder",
            &["slurm", "project.toml", "--segments", "1", "--out", "."],
            2,
        ),
        at(
            "split: --out its project's folder",
            &["split", "project.toml", "--segments", "1", "--out", "."],
            2,
        ),
        at(
            "survey convert: -o its file",
            &[
                "survey", "convert", "gcps.csv", "--to", "csv", "-o", "gcps.csv",
            ],
            2,
        ),
        at(
            "survey inspect: reads only",
            &["survey", "inspect", "gcps.csv"],
            0,
        ),
        at(
            "track: --out its folder",
            &[
                "track",
                "video.mp4",
                "--detect",
                "boxes",
                "--boxes",
                "boxes.txt",
                "--px-per-m",
                "30",
                "--out",
                ".",
            ],
            2,
        ),
    ]
}
