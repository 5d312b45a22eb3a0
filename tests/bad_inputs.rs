//! The bad-input catalogue (docs/bad-inputs.md): every command that reads a file, given bad,
//! hostile or unusual input, exits 2 with a message that names the file and the line or field,
//! leaves no output behind and changes no input. Each case runs in a fresh copy of a small valid
//! project; the folder's files and their SHA-256 are compared before and after.

#![cfg(all(feature = "opencv", feature = "gdal", feature = "onnx"))]

mod common;

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::sync::OnceLock;

use sha2::{Digest, Sha256};

use common::geostride;

/// A small valid project: a simulated second of a drifting hover (video, Emlid GCPs, picks,
/// truth), a calibration, a project file, a BAL problem, MOT boxes, heights and the scene.
fn fixture() -> &'static Path {
    static DIR: OnceLock<PathBuf> = OnceLock::new();
    DIR.get_or_init(|| {
        let dir = std::env::temp_dir().join(format!("geostride-bad-inputs-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&dir);
        let root = Path::new(env!("CARGO_MANIFEST_DIR"));
        let out = geostride()
            .arg("simulate")
            .arg(root.join("tests/scenes/hover-drift.toml"))
            .arg("--out")
            .arg(&dir)
            .args(["--duration", "1", "-q"])
            .output()
            .unwrap();
        common::assert_success(&out);
        if dir.join("video.avi").is_file() {
            // Where OpenCV cannot write H.264 the simulator writes MJPEG; the cases name .mp4.
            std::fs::rename(dir.join("video.avi"), dir.join("video.mp4")).unwrap();
            let picks = std::fs::read_to_string(dir.join("picks.csv")).unwrap();
            std::fs::write(
                dir.join("picks.csv"),
                picks.replace("video.avi#", "video.mp4#"),
            )
            .unwrap();
        }
        std::fs::copy(
            root.join("calib/dji-mini3pro-4k.json"),
            dir.join("camera.json"),
        )
        .unwrap();
        std::fs::copy(
            root.join("tests/scenes/hover-drift.toml"),
            dir.join("scene.toml"),
        )
        .unwrap();
        std::fs::write(dir.join("project.toml"), PROJECT).unwrap();
        std::fs::write(dir.join("problem.bal"), BAL).unwrap();
        std::fs::write(dir.join("boxes.txt"), BOXES).unwrap();
        std::fs::write(dir.join("heights.csv"), "id,height_m\n1,1.75\n2,1.62\n").unwrap();
        std::fs::write(dir.join("picks-frame.csv"), picks_on_frame(&dir)).unwrap();
        more::extend_fixture(&dir);
        dir
    })
}

#[path = "bad_inputs/more.rs"]
mod more;

const PROJECT: &str = r#"name = "bad inputs"
[camera]
calibration = "camera.json"
[survey]
gcps = "gcps.csv"
picks = ["picks.csv"]
height = "ellipsoidal"
[video]
path = "video.mp4"
[ground]
kind = "deck"
centre_line = [[654460.0, 696000.0], [654540.0, 696000.0]]
width_m = 5.0
[projection]
head_height_m = 1.7
[export]
formats = ["csv", "geojson"]
"#;

/// Two cameras, two points, four observations.
const BAL: &str = "2 2 4\n0 0 -1.0 2.0\n1 0 -1.5 2.5\n0 1 3.0 -1.0\n1 1 2.5 -0.5\n\
0.01 0.02 0.03 0.1 0.2 -5.0 500 0 0\n-0.01 0.02 0.0 0.3 0.1 -5.0 500 0 0\n\
0.5 0.2 1.0\n-0.3 0.4 0.8\n";

const BOXES: &str = "1,-1,100,100,40,80,0.9\n2,-1,102,101,40,80,0.9\n3,-1,104,102,40,80,0.8\n";

/// The picks of frame 0 as written by the simulator (for cases that edit them).
fn picks_on_frame(dir: &Path) -> String {
    std::fs::read_to_string(dir.join("picks.csv")).unwrap()
}

/// One bad input.
#[derive(Default)]
struct Case {
    id: &'static str,
    category: &'static str,
    /// Files written (relative path, content), replacing the fixture's.
    files: Vec<(&'static str, String)>,
    /// Arguments; `-` separated words are not split.
    args: Vec<String>,
    /// What stderr must say.
    expect: &'static str,
    /// Where: the file and its line (`gcps.csv:3`) or field (`field 'export.crs'`).
    place: &'static str,
    /// Files written as bytes (relative path, content), after `setup`.
    bytes: Vec<(String, Vec<u8>)>,
    /// Files removed, after `setup`.
    remove: Vec<&'static str>,
    /// Commands that must succeed first (a split or a run to work on), in the case's folder.
    setup: Vec<Vec<String>>,
    /// Environment variables of the command.
    env: Vec<(&'static str, String)>,
}

fn args(words: &[&str]) -> Vec<String> {
    words.iter().map(|w| w.to_string()).collect()
}

/// The fixture's file with line `line` (1-based) changed by `f`.
fn edit_line(file: &str, line: usize, f: impl Fn(&str) -> String) -> String {
    let text = std::fs::read_to_string(fixture().join(file)).unwrap();
    text.lines()
        .enumerate()
        .map(|(i, l)| if i + 1 == line { f(l) } else { l.to_string() })
        .collect::<Vec<_>>()
        .join("\n")
        + "\n"
}

/// A CSV line with field `k` replaced.
fn set_field(l: &str, k: usize, v: &str) -> String {
    let mut f: Vec<String> = l.split(',').map(str::to_string).collect();
    f[k] = v.to_string();
    f.join(",")
}

/// The fixture's file with `from` replaced by `to` (which must occur).
fn replace(file: &str, from: &str, to: &str) -> String {
    let text = std::fs::read_to_string(fixture().join(file)).unwrap();
    assert!(text.contains(from), "{file} has no '{from}'");
    text.replacen(from, to, 1)
}

/// A Tsai calibration like PETS 2009's View_001, with its scale factor `sx` and distortion
/// `kappa1`.
fn tsai_xml(sx: &str, kappa1: &str) -> String {
    format!(
        "<?xml version=\"1.0\"?>\n<Camera name=\"View_001\">\n<Geometry width=\"768\" height=\"576\" ncx=\"795\" nfx=\"752\" dx=\"4.85e-03\" dy=\"4.65e-03\" dpx=\"5.1273e-03\" dpy=\"4.65e-03\"/>\n<Intrinsic focal=\"5.5549\" kappa1=\"{kappa1}\" cx=\"324.22\" cy=\"282.57\" sx=\"{sx}\"/>\n<Extrinsic tx=\"828.7\" ty=\"-3175.5\" tz=\"35469.3\" rx=\"2.0405\" ry=\"-0.8934\" rz=\"-0.4306\"/>\n</Camera>\n"
    )
}

fn project_with(extra: &str) -> String {
    format!("{PROJECT}{extra}")
}

fn cases() -> Vec<Case> {
    let survey = |file: &str| args(&["survey", "inspect", file]);
    let convert =
        |file: &str, to: &str, out: &str| args(&["survey", "convert", file, "--to", to, "-o", out]);
    let run = || args(&["run", "project.toml", "--out", "out", "-q"]);
    let pose_image = || {
        args(&[
            "pose",
            "--camera",
            "camera.json",
            "--gcps",
            "gcps.csv",
            "--picks",
            "picks.csv",
            "--image-size",
            "1280x720",
        ])
    };
    // Under the 1 MiB line limit, so that the number's own message quotes it.
    let long_token = "9".repeat(500_000);
    let mut c = vec![
        // --- Inputs never overwritten ------------------------------------------------------
        Case {
            id: "convert-onto-its-picks",
            category: "input overwritten",
            files: vec![],
            args: args(&[
                "survey", "convert", "gcps.csv", "--picks", "picks.csv", "--to", "odm", "-o",
                "picks.csv",
            ]),
            expect: "would overwrite the input",
            place: "picks.csv",
            ..Default::default()
        },
        Case {
            id: "convert-onto-its-reference",
            category: "input overwritten",
            files: vec![("ref.csv", replace("gcps.csv", "GCP1", "GCP1"))],
            args: args(&[
                "survey", "convert", "gcps.csv", "--fit-to", "ref.csv", "--to", "csv", "-o",
                "ref.csv",
            ]),
            expect: "would overwrite the input",
            place: "ref.csv",
            ..Default::default()
        },
        Case {
            id: "convert-onto-itself-by-another-path",
            category: "input overwritten",
            files: vec![],
            args: convert("gcps.csv", "csv", "truth/../gcps.csv"),
            expect: "would overwrite the input",
            place: "gcps.csv",
            ..Default::default()
        },
        Case {
            id: "calibrate-onto-an-image",
            category: "input overwritten",
            files: vec![],
            args: args(&[
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
            ]),
            expect: "would overwrite the input",
            place: "truth/frame.png",
            ..Default::default()
        },
        Case {
            id: "ba-onto-its-problem",
            category: "input overwritten",
            files: vec![],
            args: args(&["ba", "--bal", "problem.bal", "--out", "problem.bal"]),
            expect: "would overwrite the input",
            place: "problem.bal",
            ..Default::default()
        },
        Case {
            id: "camera-convert-onto-itself",
            category: "input overwritten",
            files: vec![],
            args: args(&["camera", "convert", "camera.json", "camera.json"]),
            expect: "would overwrite the input",
            place: "camera.json",
            ..Default::default()
        },
        Case {
            id: "run-into-the-project-folder",
            category: "input overwritten",
            files: vec![
                ("trajectories.csv", replace("gcps.csv", "GCP1", "GCP1")),
                (
                    "project.toml",
                    replace("project.toml", "gcps = \"gcps.csv\"", "gcps = \"trajectories.csv\""),
                ),
            ],
            args: args(&["run", "project.toml", "--out", ".", "-q"]),
            expect: "holds the input",
            place: ".",
            ..Default::default()
        },
        Case {
            id: "pose-video-into-the-inputs-folder",
            category: "input overwritten",
            files: vec![],
            args: args(&[
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
            ]),
            expect: "holds the input",
            place: ".",
            ..Default::default()
        },
        Case {
            id: "track-into-the-boxes-folder",
            category: "input overwritten",
            files: vec![],
            args: args(&[
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
            ]),
            expect: "holds the input",
            place: ".",
            ..Default::default()
        },
        Case {
            id: "simulate-into-the-scene-folder",
            category: "input overwritten",
            files: vec![],
            args: args(&["simulate", "scene.toml", "--out", "."]),
            expect: "holds the input",
            place: ".",
            ..Default::default()
        },
        // --- Outputs that cannot be written, found before the work ---------------------------
        Case {
            id: "calibrate-into-a-missing-folder",
            category: "wrong code",
            files: vec![],
            args: args(&[
                "calibrate",
                "--board",
                "9x6",
                "--square",
                "0.03",
                "-o",
                "missing/cal.yaml",
                "truth",
            ]),
            expect: "does not exist",
            place: "missing/cal.yaml",
            ..Default::default()
        },
        Case {
            id: "ba-into-a-missing-folder",
            category: "wrong code",
            files: vec![],
            args: args(&["ba", "--bal", "problem.bal", "--out", "missing/out.bal"]),
            expect: "does not exist",
            place: "missing/out.bal",
            ..Default::default()
        },
        Case {
            id: "convert-to-a-folder",
            category: "wrong code",
            files: vec![],
            args: convert("gcps.csv", "csv", "truth"),
            expect: "is a folder",
            place: "truth",
            ..Default::default()
        },
        Case {
            id: "run-out-is-a-file",
            category: "wrong code",
            files: vec![],
            args: args(&["run", "project.toml", "--out", "heights.csv", "-q"]),
            expect: "is a file",
            place: "heights.csv",
            ..Default::default()
        },
        Case {
            id: "track-out-is-a-file",
            category: "wrong code",
            files: vec![],
            args: args(&[
                "track",
                "video.mp4",
                "--detect",
                "boxes",
                "--boxes",
                "boxes.txt",
                "--px-per-m",
                "30",
                "--out",
                "heights.csv",
            ]),
            expect: "is a file",
            place: "heights.csv",
            ..Default::default()
        },
        Case {
            id: "annotated-image-without-a-format",
            category: "wrong code",
            files: vec![("shot.png", String::new())],
            args: {
                let mut a = pose_image();
                a.extend(args(&["--picks-image", "video.mp4#0", "--annotated", "out.txt"]));
                a.retain(|w| w != "--image-size" && w != "1280x720");
                a.extend(args(&["--image", "truth/frame.png"]));
                a
            },
            expect: "image format",
            place: "out.txt",
            ..Default::default()
        },
        // --- Project files checked whole, before any work -------------------------------------
        Case {
            id: "project-folder-as-gcp-file",
            category: "wrong code",
            files: vec![(
                "project.toml",
                replace("project.toml", "gcps = \"gcps.csv\"", "gcps = \"truth\""),
            )],
            args: run(),
            expect: "is a folder",
            place: "field 'survey.gcps'",
            ..Default::default()
        },
        Case {
            id: "project-image-as-video",
            category: "misleading message",
            files: vec![(
                "project.toml",
                replace("project.toml", "path = \"video.mp4\"", "path = \"truth/frame.png\""),
            )],
            args: run(),
            expect: "is an image",
            place: "field 'video.path'",
            ..Default::default()
        },
        Case {
            id: "project-bad-export-crs",
            category: "found late",
            files: vec![("project.toml", replace("project.toml", "[export]", "[export]\ncrs = \"EPSG:99999\""))],
            args: run(),
            expect: "PROJ does not know it",
            place: "field 'export.crs'",
            ..Default::default()
        },
        Case {
            id: "project-wrong-survey-crs",
            category: "misleading message",
            files: vec![(
                "project.toml",
                replace("project.toml", "height = \"ellipsoidal\"", "height = \"ellipsoidal\"\ncrs = \"EPSG:32631\""),
            )],
            args: run(),
            expect: "Longitude",
            place: "gcps.csv:2",
            ..Default::default()
        },
        Case {
            id: "project-picks-frame-beyond-video",
            category: "wrong code",
            files: vec![("project.toml", project_with("[pose]\npicks_frame = 500\n"))],
            args: run(),
            expect: "beyond the",
            place: "field 'pose.picks_frame'",
            ..Default::default()
        },
        Case {
            id: "project-onnx-model-missing",
            category: "nonsense accepted",
            files: vec![(
                "project.toml",
                project_with("[detect]\nkind = \"onnx\"\nmodel = \"nope.onnx\"\n"),
            )],
            args: run(),
            expect: "no such file",
            place: "field 'detect.model'",
            ..Default::default()
        },
        Case {
            id: "project-onnx-head-from-a-model-without-heads",
            category: "nonsense accepted",
            files: vec![(
                "project.toml",
                project_with("[detect]\nkind = \"onnx\"\nmodel = \"yolov3-tiny\"\nhead = \"model\"\n"),
            )],
            args: run(),
            expect: "gives no head points",
            place: "field 'detect.head'",
            ..Default::default()
        },
        Case {
            id: "project-motion-check-on-skipped-frames",
            category: "nonsense accepted",
            files: vec![(
                "project.toml",
                project_with("[detect]\nkind = \"onnx\"\nstride = 3\nmotion_check = true\n"),
            )],
            args: run(),
            expect: "needs stride = 1",
            place: "field 'detect.motion_check'",
            ..Default::default()
        },
        Case {
            id: "project-model-pose-without-a-model",
            category: "nonsense accepted",
            files: vec![(
                "project.toml",
                project_with("[pose]\nkind = \"model\"\nmodel = \"nowhere\"\nmodel_images = \".\"\n"),
            )],
            args: run(),
            expect: "has no cameras.txt",
            place: "field 'pose.model'",
            ..Default::default()
        },
        Case {
            id: "project-fixed-pose-without-extrinsics",
            category: "nonsense accepted",
            files: vec![("project.toml", project_with("[pose]\nkind = \"fixed\"\n"))],
            args: run(),
            expect: "has no camera pose",
            place: "field 'pose'",
            ..Default::default()
        },
        Case {
            id: "project-fixed-pose-and-a-survey-in-a-crs",
            category: "nonsense accepted",
            files: vec![
                ("View_001.xml", tsai_xml("1.09379", "5.1113e-03")),
                (
                    "project.toml",
                    project_with("[pose]\nkind = \"fixed\"\nextrinsics = \"View_001.xml\"\n"),
                ),
            ],
            args: run(),
            expect: "site frame is another",
            place: "field 'survey.gcps'",
            ..Default::default()
        },
        Case {
            id: "project-picks-image-not-a-frame",
            category: "nonsense accepted",
            files: vec![("picks.csv", picks_on_frame(fixture()).replace("video.mp4#0", "video.mp4#0a"))],
            args: run(),
            expect: "should end in '#N'",
            place: "field 'survey.picks'",
            ..Default::default()
        },
        Case {
            id: "project-nan-centre-line",
            category: "crash",
            files: vec![(
                "project.toml",
                replace("project.toml", "[654540.0, 696000.0]", "[nan, 696000.0]"),
            )],
            args: run(),
            expect: "finite",
            place: "field 'ground.centre_line'",
            ..Default::default()
        },
        Case {
            id: "project-infinite-sigma",
            category: "nonsense accepted",
            files: vec![("project.toml", replace("project.toml", "height = \"ellipsoidal\"", "height = \"ellipsoidal\"\ngcp_sigma_m = inf"))],
            args: run(),
            expect: "finite",
            place: "field 'survey.gcp_sigma_m'",
            ..Default::default()
        },
        Case {
            id: "project-auto-picks-beside-survey-picks",
            category: "nonsense accepted",
            files: vec![("project.toml", replace("project.toml", "[video]", "[picks]\nauto = true\n\n[video]"))],
            args: run(),
            expect: "survey.picks also gives picks",
            place: "field 'picks.auto'",
            ..Default::default()
        },
        Case {
            id: "project-auto-picks-heading-tolerance-0",
            category: "nonsense accepted",
            files: vec![("project.toml", replace("project.toml", "[video]", "[picks]\nheading_tolerance_deg = 0\n\n[video]"))],
            args: run(),
            expect: "(0, 180]",
            place: "field 'picks.heading_tolerance_deg'",
            ..Default::default()
        },
        Case {
            id: "project-auto-picks-no-design",
            category: "nonsense accepted",
            files: vec![("project.toml", replace("project.toml", "[video]", "[picks]\ndesigns = []\n\n[video]"))],
            args: run(),
            expect: "at least one design",
            place: "field 'picks.designs'",
            ..Default::default()
        },
        Case {
            id: "project-auto-picks-unknown-dictionary",
            category: "nonsense accepted",
            files: vec![("project.toml", replace("project.toml", "[video]", "[picks]\ndesigns = [\"coded\"]\ndictionary = \"4x4_51\"\n\n[video]"))],
            args: run(),
            expect: "unknown dictionary '4x4_51'",
            place: "field 'picks.dictionary'",
            ..Default::default()
        },
        Case {
            id: "project-auto-picks-codes-without-coded",
            category: "nonsense accepted",
            files: vec![("project.toml", replace("project.toml", "[video]", "[picks]\ncodes = \"codes.csv\"\n\n[video]"))],
            args: run(),
            expect: "add \"coded\" to designs",
            place: "field 'picks.codes'",
            ..Default::default()
        },
        Case {
            id: "project-unknown-key",
            category: "misleading message",
            files: vec![("project.toml", replace("project.toml", "head_height_m = 1.7", "head_heigth_m = 1.7"))],
            args: run(),
            expect: "head_heigth_m",
            place: "project.toml:",
            ..Default::default()
        },
        Case {
            id: "project-duplicate-heights",
            category: "nonsense accepted",
            files: vec![
                ("heights.csv", "id,height_m\n1,1.75\n1,1.80\n".into()),
                ("project.toml", replace("project.toml", "head_height_m = 1.7", "head_height_m = 1.7\nheights = \"heights.csv\"")),
            ],
            args: run(),
            expect: "already",
            place: "heights.csv:3",
            ..Default::default()
        },
        Case {
            id: "project-negative-height-sigma",
            category: "nonsense accepted",
            files: vec![
                ("heights.csv", "id,height_m,sd_m\n1,1.75,-0.1\n".into()),
                ("project.toml", replace("project.toml", "head_height_m = 1.7", "head_height_m = 1.7\nheights = \"heights.csv\"")),
            ],
            args: run(),
            expect: "negative",
            place: "heights.csv:2",
            ..Default::default()
        },
        Case {
            id: "project-inverted-roi",
            category: "nonsense accepted",
            files: vec![("project.toml", replace(
                "project.toml",
                "[projection]",
                "[detect]\nkind = \"boxes\"\nboxes = \"boxes.txt\"\nroi = [1280, 720, 0, 0]\n\n[projection]",
            ))],
            args: run(),
            expect: "roi",
            place: "field 'detect.roi'",
            ..Default::default()
        },
        Case {
            id: "project-box-filter-key",
            category: "misleading message",
            files: vec![("project.toml", replace(
                "project.toml",
                "[projection]",
                "[detect]\nkind = \"boxes\"\nboxes = \"boxes.txt\"\nmin_score = 2\n\n[projection]",
            ))],
            args: run(),
            expect: "min_score",
            place: "field 'detect.min_score'",
            ..Default::default()
        },
        Case {
            id: "project-boxes-of-another-video",
            category: "nonsense accepted",
            files: vec![
                ("boxes.txt", "9001,-1,100,100,40,80,0.9\n9002,-1,102,101,40,80,0.9\n".into()),
                ("project.toml", replace("project.toml", "[projection]", "[detect]\nkind = \"boxes\"\nboxes = \"boxes.txt\"\n\n[projection]")),
            ],
            args: run(),
            expect: "none of the 2 boxes",
            place: "field 'detect.boxes'",
            ..Default::default()
        },
        Case {
            id: "project-boxes-outside-the-image",
            category: "nonsense accepted",
            files: vec![
                ("boxes.txt", "1,-1,100,100,40,80,0.9\n1,-1,5000,3000,40,80,0.9\n".into()),
                ("project.toml", replace("project.toml", "[projection]", "[detect]\nkind = \"boxes\"\nboxes = \"boxes.txt\"\n\n[projection]")),
            ],
            args: run(),
            expect: "has its centre outside the",
            place: "field 'detect.boxes'",
            ..Default::default()
        },
        Case {
            id: "project-shadow-sample-not-whole",
            category: "nonsense accepted",
            files: vec![("project.toml", replace(
                "project.toml",
                "[projection]",
                "[detect]\nkind = \"boxes\"\nboxes = \"boxes.txt\"\nshadow_samples = [[0.5, 1, 1, 10, 10]]\n\n[projection]",
            ))],
            args: run(),
            expect: "whole pixels",
            place: "field 'detect.shadow_samples'",
            ..Default::default()
        },
        // --- Survey files: numbers, ranges, columns, duplicates, CRS ------------------------
        Case {
            id: "emlid-nan-easting",
            category: "nonsense accepted",
            files: vec![("gcps.csv", edit_line("gcps.csv", 2, |l| set_field(l, 1, "nan")))],
            args: survey("gcps.csv"),
            expect: "finite",
            place: "gcps.csv:2",
            ..Default::default()
        },
        Case {
            id: "emlid-1e400-northing",
            category: "nonsense accepted",
            files: vec![("gcps.csv", edit_line("gcps.csv", 3, |l| set_field(l, 2, "1e400")))],
            args: survey("gcps.csv"),
            expect: "finite",
            place: "gcps.csv:3",
            ..Default::default()
        },
        Case {
            id: "emlid-zero-rms",
            category: "nonsense accepted",
            files: vec![("gcps.csv", edit_line("gcps.csv", 4, |l| set_field(l, 8, "0")))],
            args: survey("gcps.csv"),
            expect: "positive",
            place: "gcps.csv:4",
            ..Default::default()
        },
        Case {
            id: "emlid-extra-field",
            category: "nonsense accepted",
            files: vec![("gcps.csv", edit_line("gcps.csv", 5, |l| format!("{l},extra")))],
            args: survey("gcps.csv"),
            expect: "fields",
            place: "gcps.csv:5",
            ..Default::default()
        },
        Case {
            id: "emlid-crs-contradicts-its-longitudes",
            category: "nonsense accepted",
            files: vec![("gcps.csv", edit_line("gcps.csv", 2, |l| set_field(l, 1, "9654482.0")))],
            args: survey("gcps.csv"),
            expect: "is the CRS right?",
            place: "gcps.csv:2",
            ..Default::default()
        },
        Case {
            id: "emlid-duplicate-name",
            category: "nonsense accepted",
            files: vec![("gcps.csv", edit_line("gcps.csv", 3, |l| set_field(l, 0, "GCP1")))],
            args: survey("gcps.csv"),
            expect: "duplicate point name",
            place: "gcps.csv:3",
            ..Default::default()
        },
        Case {
            id: "metashape-far-outside-the-crs",
            category: "nonsense accepted",
            files: vec![("m.csv", "#CoordinateSystem: ETRS89 / Belgian Lambert 2008 (EPSG::3812)\n#Label,X,Y,Z\nA,654482,696000,58\nB,9654490,695990,58\n".into())],
            args: survey("m.csv"),
            expect: "outside where",
            place: "m.csv:4",
            ..Default::default()
        },
        Case {
            id: "emlid-long-token-clipped",
            category: "runaway message",
            files: vec![("gcps.csv", edit_line("gcps.csv", 2, |l| set_field(l, 1, &format!("{long_token}x"))))],
            args: survey("gcps.csv"),
            expect: "bytes in all",
            place: "gcps.csv:2",
            ..Default::default()
        },
        Case {
            id: "metashape-decimal-commas",
            category: "nonsense accepted",
            files: vec![("m.csv", "#CoordinateSystem: ETRS89 / Belgian Lambert 2008 (EPSG::3812)\n#Label,X,Y,Z\nA,654482,5,696000,2,58,4\nB,654490,695990,58\n".into())],
            args: survey("m.csv"),
            expect: "decimal commas",
            place: "m.csv:3",
            ..Default::default()
        },
        Case {
            id: "metashape-negative-accuracy",
            category: "nonsense accepted",
            files: vec![("m.csv", "#CoordinateSystem: ETRS89 / Belgian Lambert 2008 (EPSG::3812)\n#Label,X,Y,Z,X_acc,Y_acc,Z_acc\nA,654482,696000,58,0.01,0.01,0.02\nB,654490,695990,58,-0.01,0.01,0.02\n".into())],
            args: survey("m.csv"),
            expect: "positive",
            place: "m.csv:4",
            ..Default::default()
        },
        Case {
            id: "metashape-latitude-out-of-range",
            category: "nonsense accepted",
            files: vec![("m.csv", "#CoordinateSystem: WGS 84 (EPSG::4326)\n#Label,X,Y,Z\nA,4.43,95.0,58\nB,4.44,51.0,58\n".into())],
            args: survey("m.csv"),
            expect: "out of range",
            place: "m.csv:3",
            ..Default::default()
        },
        Case {
            id: "odm-infinite-pixel",
            category: "nonsense accepted",
            files: vec![("gcp_list.txt", "EPSG:3812\n654482 696000 58 inf 445.9 video.mp4#0 G1\n654490 695990 58 300 400 video.mp4#0 G2\n".into())],
            args: survey("gcp_list.txt"),
            expect: "finite",
            place: "gcp_list.txt:2",
            ..Default::default()
        },
        Case {
            id: "odm-too-few-fields",
            category: "nonsense accepted",
            files: vec![("gcp_list.txt", "EPSG:3812\n654482 696000 58 100 445.9\n".into())],
            args: survey("gcp_list.txt"),
            expect: "fields",
            place: "gcp_list.txt:2",
            ..Default::default()
        },
        Case {
            id: "opensfm-latitude-out-of-range",
            category: "nonsense accepted",
            files: vec![("ground_control_points.json", r#"{"points": [{"id": "a", "position": {"latitude": 123.0, "longitude": 4.4, "altitude": 50}, "observations": []}, {"id": "b", "position": {"latitude": 51.0, "longitude": 4.4, "altitude": 50}, "observations": []}]}"#.into())],
            args: survey("ground_control_points.json"),
            expect: "out of range",
            place: "ground_control_points.json:1",
            ..Default::default()
        },
        Case {
            id: "petrack-no-points",
            category: "nonsense accepted",
            files: vec![("g.3dc", "0\n".into())],
            args: args(&["survey", "inspect", "g.3dc", "--format", "petrack"]),
            expect: "no points",
            place: "g.3dc:1",
            ..Default::default()
        },
        Case {
            id: "survey-long-crs",
            category: "runaway memory",
            files: vec![("gcp_list.txt", format!("+proj=utm {}\n654482 696000 58 100 445.9 a.jpg G1\n", "+zone=31 ".repeat(200_000)))],
            args: survey("gcp_list.txt"),
            expect: "KiB",
            place: "gcp_list.txt:1",
            ..Default::default()
        },
        Case {
            id: "picks-nan-pixel",
            category: "nonsense accepted",
            files: vec![("picks.csv", edit_line("picks.csv", 3, |l| set_field(l, 2, "NaN")))],
            args: args(&["survey", "inspect", "gcps.csv", "--picks", "picks.csv"]),
            expect: "finite",
            place: "picks.csv:3",
            ..Default::default()
        },
        Case {
            id: "picks-zero-sigma",
            category: "nonsense accepted",
            files: vec![("picks.csv", edit_line("picks.csv", 2, |l| set_field(l, 4, "0")))],
            args: args(&["survey", "inspect", "gcps.csv", "--picks", "picks.csv"]),
            expect: "positive",
            place: "picks.csv:2",
            ..Default::default()
        },
        Case {
            id: "picks-twice-in-one-image",
            category: "nonsense accepted",
            files: vec![("picks.csv", {
                let t = picks_on_frame(fixture());
                let second = t.lines().nth(1).unwrap().to_string();
                format!("{t}{second}\n")
            })],
            args: args(&["survey", "inspect", "gcps.csv", "--picks", "picks.csv"]),
            expect: "picked twice",
            place: "picks.csv:",
            ..Default::default()
        },
        Case {
            id: "picks-empty",
            category: "nonsense accepted",
            files: vec![("picks.csv", "name,image,u,v\n".into())],
            args: args(&["survey", "inspect", "gcps.csv", "--picks", "picks.csv"]),
            expect: "no picks",
            place: "picks.csv",
            ..Default::default()
        },
        Case {
            id: "pose-collinear-picks",
            category: "wrong code",
            files: vec![("picks.csv", {
                // The five GCPs along one edge of the deck: one line in the world and the image.
                let t = picks_on_frame(fixture());
                let mut out = String::from("name,image,u,v,sigma\n");
                for l in t.lines().skip(1) {
                    let n: usize = l.split(',').next().unwrap().trim_start_matches("GCP").parse().unwrap_or(0);
                    if n % 2 == 1 {
                        out += &format!("{l}\n");
                    }
                }
                out
            })],
            args: pose_image(),
            expect: "one line",
            place: "picks.csv",
            ..Default::default()
        },
        // --- Calibration files ---------------------------------------------------------------
        Case {
            id: "json-calibration-huge-focal",
            category: "nonsense accepted",
            files: vec![("camera.json", replace_number("camera.json", "\"fx\"", "1e400"))],
            args: args(&["camera", "show", "camera.json"]),
            expect: "number out of range",
            place: "camera.json:",
            ..Default::default()
        },
        Case {
            id: "yaml-calibration-nan-focal",
            category: "nonsense accepted",
            files: vec![("cam.yaml", "%YAML:1.0\n---\ncamera_matrix: !!opencv-matrix\n   rows: 3\n   cols: 3\n   dt: d\n   data: [ .Nan, 0., 640., 0., 1000., 360., 0., 0., 1. ]\ndistortion_coefficients: !!opencv-matrix\n   rows: 1\n   cols: 5\n   dt: d\n   data: [ 0., 0., 0., 0., 0. ]\n".into())],
            args: args(&["camera", "show", "cam.yaml"]),
            expect: "must be positive",
            place: "field 'camera_matrix'",
            ..Default::default()
        },
        Case {
            id: "yaml-calibration-deep-nesting",
            category: "crash",
            files: vec![("cam.yaml", format!("%YAML:1.0\n---\ncamera_matrix: {}{}\n", "[".repeat(100_000), "]".repeat(100_000)))],
            args: args(&["camera", "show", "cam.yaml"]),
            expect: "nested",
            place: "cam.yaml:3",
            ..Default::default()
        },
        Case {
            id: "yaml-calibration-huge-size",
            category: "runaway memory",
            files: vec![("cam.yaml", "%YAML:1.0\n---\nimage_width: 1000000000000\nimage_height: 1000000000000\ncamera_matrix: !!opencv-matrix\n   rows: 3\n   cols: 3\n   dt: d\n   data: [ 1000., 0., 640., 0., 1000., 360., 0., 0., 1. ]\ndistortion_coefficients: !!opencv-matrix\n   rows: 1\n   cols: 5\n   dt: d\n   data: [ 0., 0., 0., 0., 0. ]\n".into())],
            args: args(&["camera", "show", "cam.yaml"]),
            expect: "pixels",
            place: "field 'image_size'",
            ..Default::default()
        },
        Case {
            id: "xml-calibration-tiny-focal",
            category: "crash",
            files: vec![("cam.xml", "<?xml version=\"1.0\"?>\n<calibration>\n  <projection>frame</projection>\n  <width>4000</width>\n  <height>3000</height>\n  <f>1e-300</f>\n  <cx>0</cx>\n  <cy>0</cy>\n  <k4>1</k4>\n</calibration>\n".into())],
            args: args(&["camera", "show", "cam.xml"]),
            expect: "focal length",
            place: "field 'f'",
            ..Default::default()
        },
        Case {
            id: "tsai-calibration-impossible-scale",
            category: "nonsense accepted",
            files: vec![("View_001.xml", tsai_xml("7.0", "5.1113e-03"))],
            args: args(&["camera", "show", "View_001.xml"]),
            expect: "horizontal scale factor",
            place: "field 'sx'",
            ..Default::default()
        },
        Case {
            id: "tsai-calibration-folding-distortion",
            category: "nonsense accepted",
            files: vec![("View_001.xml", tsai_xml("1.09379", "-0.5"))],
            args: args(&["camera", "show", "View_001.xml"]),
            expect: "folds the image back",
            place: "field 'kappa1'",
            ..Default::default()
        },
        Case {
            id: "json-calibration-negative-variance",
            category: "nonsense accepted",
            files: vec![("cam.json", negative_variance_calibration())],
            args: args(&["camera", "show", "cam.json"]),
            expect: "positive semi-definite",
            place: "field 'covariance'",
            ..Default::default()
        },
        // --- Boxes, BAL, evaluate, scenes, plan ----------------------------------------------
        Case {
            id: "mot-frame-zero",
            category: "nonsense accepted",
            files: vec![("boxes.txt", "0,-1,100,100,40,80,0.9\n".into())],
            args: args(&["track", "video.mp4", "--detect", "boxes", "--boxes", "boxes.txt", "--px-per-m", "30", "--out", "tracks"]),
            expect: "frame",
            place: "boxes.txt:1",
            ..Default::default()
        },
        Case {
            id: "mot-decimal-commas",
            category: "nonsense accepted",
            files: vec![("boxes.txt", "1,-1,100,5,100,40,80,0,9\n".into())],
            args: args(&["track", "video.mp4", "--detect", "boxes", "--boxes", "boxes.txt", "--px-per-m", "30", "--out", "tracks"]),
            expect: "score",
            place: "boxes.txt:1",
            ..Default::default()
        },
        Case {
            id: "coco-duplicate-image-ids",
            category: "nonsense accepted",
            files: vec![("boxes.json", r#"{"images": [{"id": 1, "file_name": "f0001.jpg"}, {"id": 1, "file_name": "f0002.jpg"}], "categories": [{"id": 1, "name": "person"}], "annotations": [{"image_id": 1, "category_id": 1, "bbox": [1, 2, 30, 60], "score": 0.9}]}"#.into())],
            args: args(&["track", "video.mp4", "--detect", "boxes", "--boxes", "boxes.json", "--px-per-m", "30", "--out", "tracks"]),
            expect: "used twice",
            place: "boxes.json",
            ..Default::default()
        },
        Case {
            id: "bal-duplicate-observation",
            category: "nonsense accepted",
            files: vec![("problem.bal", BAL.replacen("0 1 3.0 -1.0", "0 0 3.0 -1.0", 1))],
            args: args(&["ba", "--bal", "problem.bal"]),
            expect: "both of point 0 in camera 0",
            place: "field 'observations'",
            ..Default::default()
        },
        Case {
            id: "bal-huge-counts",
            category: "runaway memory",
            files: vec![("problem.bal", "1000000000 1000000000 1000000000\n0 0 1 2\n".into())],
            args: args(&["ba", "--bal", "problem.bal"]),
            expect: "problem.bal",
            place: "problem.bal:",
            ..Default::default()
        },
        Case {
            id: "evaluate-empty-truth",
            category: "nonsense accepted",
            files: vec![("empty.csv", "frame,person,e_m,n_m,in_view\n".into())],
            args: args(&["evaluate", "--truth", "empty.csv", "--tracks", "truth/heads.csv", "--tracks-columns", "frame,person,e_m,n_m"]),
            expect: "no rows",
            place: "empty.csv",
            ..Default::default()
        },
        Case {
            id: "evaluate-fractional-frame",
            category: "nonsense accepted",
            files: vec![("t.csv", "frame,id,e_m,n_m\n0.9,1,0,0\n".into())],
            args: args(&["evaluate", "--truth", "truth/heads.csv", "--tracks", "t.csv"]),
            expect: "whole number",
            place: "t.csv:2",
            ..Default::default()
        },
        Case {
            id: "evaluate-duplicate-row",
            category: "nonsense accepted",
            files: vec![("t.csv", "frame,id,e_m,n_m\n0,1,0,0\n0,1,1,1\n".into())],
            args: args(&["evaluate", "--truth", "truth/heads.csv", "--tracks", "t.csv"]),
            expect: "twice",
            place: "t.csv:3",
            ..Default::default()
        },
        Case {
            id: "project-error-profile-unsorted",
            category: "nonsense accepted",
            files: vec![(
                "project.toml",
                replace("project.toml", "[export]", "[detect]\nkind = \"background\"\nerror_profile_px2 = [[0.5, 4, 9], [0.2, 4, 9]]\n[export]"),
            )],
            args: args(&["run", "project.toml", "--out", "out"]),
            expect: "t rising within 0 to 1",
            place: "field 'detect.error_profile_px2'",
            ..Default::default()
        },
        Case {
            id: "fit-error-no-width",
            category: "nonsense accepted",
            files: vec![
                ("det.csv", "frame,u_px,v_px\n0,10,10\n".into()),
                ("ann.csv", "frame,x_px,y_px\n0,11,10\n".into()),
            ],
            args: args(&["fit-error", "--detections", "det.csv", "--annotations", "ann.csv"]),
            expect: "give --width",
            place: "report.json",
            ..Default::default()
        },
        Case {
            id: "fit-error-too-few-heads",
            category: "nonsense accepted",
            files: vec![
                ("det.csv", "frame,u_px,v_px\n0,10,10\n1,20,20\n".into()),
                ("ann.csv", "frame,x_px,y_px\n0,11,10\n1,20,22\n".into()),
            ],
            args: args(&["fit-error", "--detections", "det.csv", "--annotations", "ann.csv", "--width", "1920"]),
            expect: "at least 20",
            place: "ann.csv",
            ..Default::default()
        },
        Case {
            id: "fit-error-missing-column",
            category: "nonsense accepted",
            files: vec![
                ("det.csv", "frame,u_px,v_px\n0,10,10\n".into()),
                ("ann.csv", "frame,x,y\n0,11,10\n".into()),
            ],
            args: args(&["fit-error", "--detections", "det.csv", "--annotations", "ann.csv", "--width", "1920"]),
            expect: "no column 'x_px'",
            place: "ann.csv:1",
            ..Default::default()
        },
        Case {
            id: "fit-error-feet-without-boxes",
            category: "nonsense accepted",
            files: vec![
                ("det.csv", "frame,u_px,v_px\n0,10,10\n".into()),
                ("ann.csv", "frame,x_px,y_px\n0,11,10\n".into()),
            ],
            args: args(&["fit-error", "--feet", "--detections", "det.csv", "--annotations", "ann.csv", "--width", "1920"]),
            expect: "no column 'box_x_px'",
            place: "det.csv:1",
            ..Default::default()
        },
        Case {
            id: "dataset-too-big-for-its-limit",
            category: "runaway memory",
            args: args(&["dataset", "--out", "tiles", "--tiles", "1000000", "--max-disk-mb", "100"]),
            expect: "more than --max-disk-mb 100",
            place: "1000000 tiles",
            ..Default::default()
        },
        Case {
            id: "dataset-scales-reversed",
            category: "nonsense accepted",
            args: args(&["dataset", "--out", "tiles", "--tiles", "2", "--gsd-cm", "3,1.2"]),
            expect: "the smaller first",
            place: "--gsd-cm",
            ..Default::default()
        },
        Case {
            id: "dataset-ground-detail-reversed",
            category: "nonsense accepted",
            args: args(&["dataset", "--out", "tiles", "--tiles", "2", "--ground-detail", "5,1"]),
            expect: "the smaller first",
            place: "--ground-detail",
            ..Default::default()
        },
        Case {
            id: "demo-onnx-for-the-bridge",
            category: "nonsense accepted",
            args: args(&["demo", "--detector", "onnx", "--out", "d"]),
            expect: "add --crowd or --group",
            place: "--detector onnx",
            ..Default::default()
        },
        Case {
            id: "dataset-over-an-existing-folder",
            category: "input overwritten",
            files: vec![("tiles/keep.txt", "mine\n".into())],
            args: args(&["dataset", "--out", "tiles", "--tiles", "2"]),
            expect: "already exists",
            place: "tiles",
            ..Default::default()
        },
        Case {
            id: "scene-huge-video",
            category: "runaway memory",
            files: vec![("scene.toml", replace("scene.toml", "video_mode = [1280, 720]", "video_mode = [160000, 90000]"))],
            args: args(&["simulate", "scene.toml", "--out", "sim"]),
            expect: "video_mode",
            place: "field 'camera.video_mode'",
            ..Default::default()
        },
        Case {
            id: "scene-narrow-deck",
            category: "crash",
            files: vec![("scene.toml", replace("scene.toml", "width_m = 5.0", "width_m = 0.5"))],
            args: args(&["simulate", "scene.toml", "--out", "sim"]),
            expect: "width",
            place: "field 'ground.width_m'",
            ..Default::default()
        },
        Case {
            id: "scene-infinite-noise",
            category: "crash",
            files: vec![("scene.toml", replace("scene.toml", "[output]", "[output]\ngcp_noise_m = [inf, 0.02]"))],
            args: args(&["simulate", "scene.toml", "--out", "sim"]),
            expect: "finite",
            place: "field 'output.gcp_noise_m'",
            ..Default::default()
        },
        Case {
            id: "scene-bad-site-crs",
            category: "found late",
            files: vec![("scene.toml", {
                let text = std::fs::read_to_string(fixture().join("scene.toml")).unwrap();
                format!("{text}\n[site]\ncrs = \"EPSG:99999\"\norigin = [0, 0, 0]\n")
            })],
            args: args(&["simulate", "scene.toml", "--out", "sim"]),
            expect: "site.crs",
            place: "scene.toml",
            ..Default::default()
        },
        Case {
            id: "simulate-endless-duration",
            category: "runaway memory",
            files: vec![],
            args: args(&["simulate", "scene.toml", "--out", "sim", "--duration", "1e300"]),
            expect: "3600",
            place: "--duration",
            ..Default::default()
        },
        Case {
            id: "plan-huge-video-mode",
            category: "runaway memory",
            files: vec![],
            args: args(&["plan", "--camera", "mini3pro", "--altitude", "30", "--video-mode", "1920000x1080000"]),
            expect: "WIDTHxHEIGHT",
            place: "--video-mode",
            ..Default::default()
        },
    ];
    c.extend(more::cases());
    // Every case runs in its own folder: relative names keep the messages short.
    for case in &mut c {
        assert!(!case.args.is_empty());
    }
    c
}

/// The fixture's calibration with a number after `key` replaced.
fn replace_number(file: &str, key: &str, value: &str) -> String {
    let text = std::fs::read_to_string(fixture().join(file)).unwrap();
    let at = text
        .find(key)
        .unwrap_or_else(|| panic!("{file} has no {key}"));
    let colon = at + text[at..].find(':').unwrap() + 1;
    let end = colon + text[colon..].find([',', '\n', '}']).unwrap();
    format!("{}{value}{}", &text[..colon], &text[end..])
}

/// A geostride JSON calibration whose covariance has a negative variance.
fn negative_variance_calibration() -> String {
    let mut v: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(fixture().join("camera.json")).unwrap())
            .unwrap();
    let names = [
        "fx", "fy", "cx", "cy", "skew", "k1", "k2", "p1", "p2", "k3", "k4", "k5", "k6",
    ];
    let mut m = vec![vec![0.0; 13]; 13];
    for (i, row) in m.iter_mut().enumerate() {
        row[i] = 1.0;
    }
    m[0][0] = -4.0;
    v["uncertainty"] = serde_json::json!({
        "parameters": names,
        "std_dev": vec![1.0; 13],
        "covariance": m,
    });
    serde_json::to_string_pretty(&v).unwrap()
}

/// Every file under `dir` (folders too) with the SHA-256 of its content.
fn snapshot(dir: &Path) -> BTreeMap<PathBuf, String> {
    let mut out = BTreeMap::new();
    let mut stack = vec![dir.to_path_buf()];
    while let Some(d) = stack.pop() {
        for e in std::fs::read_dir(&d).unwrap() {
            let p = e.unwrap().path();
            let rel = p.strip_prefix(dir).unwrap().to_path_buf();
            if p.is_dir() {
                out.insert(rel, "dir".into());
                stack.push(p);
            } else {
                let h = Sha256::digest(std::fs::read(&p).unwrap());
                out.insert(rel, h.iter().map(|b| format!("{b:02x}")).collect());
            }
        }
    }
    out
}

/// A case's folder made ready: its set-up commands run, its files written and removed.
fn prepare(dir: &Path, case: &Case) {
    for step in &case.setup {
        let out = geostride().args(step).current_dir(dir).output().unwrap();
        assert!(
            out.status.success(),
            "{}: the set-up {step:?} failed: {}",
            case.id,
            String::from_utf8_lossy(&out.stderr)
        );
    }
    let files = case
        .files
        .iter()
        .map(|(n, t)| (n.to_string(), t.as_bytes()))
        .chain(case.bytes.iter().map(|(n, b)| (n.clone(), b.as_slice())));
    for (name, bytes) in files {
        std::fs::create_dir_all(dir.join(&name).parent().unwrap()).unwrap();
        std::fs::write(dir.join(&name), bytes).unwrap();
    }
    for name in &case.remove {
        let p = dir.join(name);
        if p.is_dir() {
            std::fs::remove_dir_all(p).unwrap();
        } else {
            std::fs::remove_file(p).unwrap();
        }
    }
}

/// A case in words for the catalogue: its command, then what was made bad.
fn describe(c: &Case) -> String {
    let word = |w: &String| {
        let shown = w.escape_debug().to_string();
        if shown.is_empty() || shown.contains(' ') {
            format!("'{shown}'")
        } else {
            shown
        }
    };
    let mut s = format!(
        "`{}`",
        c.args.iter().map(word).collect::<Vec<_>>().join(" ")
    );
    let mut edits: Vec<String> = c
        .files
        .iter()
        .map(|(n, _)| n.to_string())
        .chain(c.bytes.iter().map(|(n, _)| n.clone()))
        .map(|n| format!("`{}`", n.escape_debug()))
        .collect();
    edits.dedup();
    if !c.setup.is_empty() {
        let steps: Vec<String> = c
            .setup
            .iter()
            .map(|st| format!("`{}`", st.join(" ")))
            .collect();
        s = format!("after {}, {s}", steps.join(", "));
    }
    if !edits.is_empty() {
        s.push_str(&format!(" (the case writes {})", edits.join(", ")));
    }
    for r in &c.remove {
        s.push_str(&format!(", `{r}` removed"));
    }
    for (k, v) in &c.env {
        s.push_str(&format!(", `{k}={v}`"));
    }
    s.replace('|', "\\|")
}

/// The largest resident memory of the children waited for so far, MB.
fn children_peak_mb() -> f64 {
    let mut usage: libc::rusage = unsafe { std::mem::zeroed() };
    // SAFETY: `usage` is a valid rusage to fill.
    let r = unsafe { libc::getrusage(libc::RUSAGE_CHILDREN, &mut usage) };
    assert_eq!(r, 0);
    usage.ru_maxrss as f64 / 1024.0
}

fn copy_dir(from: &Path, to: &Path) {
    std::fs::create_dir_all(to).unwrap();
    for e in std::fs::read_dir(from).unwrap() {
        let e = e.unwrap();
        let (src, dst) = (e.path(), to.join(e.file_name()));
        if src.is_dir() {
            copy_dir(&src, &dst);
        } else {
            std::fs::copy(&src, &dst).unwrap();
        }
    }
}

#[test]
fn every_bad_input_exits_2_with_its_place_and_leaves_everything_as_it_was() {
    let fixture = fixture();
    let tmp = tempfile::tempdir().unwrap();
    let cases = cases();
    let mut failures = Vec::new();
    let mut ids = std::collections::HashSet::new();
    let mut slowest = (0.0f64, "");
    for case in &cases {
        assert!(ids.insert(case.id), "two cases are named {}", case.id);
        let dir = tmp.path().join(case.id);
        copy_dir(fixture, &dir);
        prepare(&dir, case);
        let before = snapshot(&dir);
        let started = std::time::Instant::now();
        let out = geostride()
            .args(&case.args)
            .envs(case.env.iter().map(|(k, v)| (k, v)))
            .current_dir(&dir)
            .output()
            .unwrap();
        let seconds = started.elapsed().as_secs_f64();
        if seconds > slowest.0 {
            slowest = (seconds, case.id);
        }
        let stderr = String::from_utf8_lossy(&out.stderr);
        let mut why = Vec::new();
        if seconds > 60.0 {
            why.push(format!("ran {seconds:.0} s (60 s at most)"));
        }
        if out.status.code() != Some(2) {
            why.push(format!("exit {:?}, expected 2", out.status.code()));
        }
        if !stderr.contains(case.expect) {
            why.push(format!("no '{}' in the message", case.expect));
        }
        if !stderr.contains(case.place) {
            why.push(format!("the message does not name '{}'", case.place));
        }
        if stderr.len() > 8_000 {
            why.push(format!("a message of {} bytes", stderr.len()));
        }
        let after = snapshot(&dir);
        if after != before {
            let changed: Vec<String> = after
                .iter()
                .filter(|(k, v)| before.get(*k) != Some(v))
                .map(|(k, _)| k.display().to_string())
                .chain(
                    before
                        .keys()
                        .filter(|k| !after.contains_key(*k))
                        .map(|k| format!("{} (removed)", k.display())),
                )
                .collect();
            why.push(format!("files written or changed: {changed:?}"));
        }
        if !why.is_empty() {
            failures.push(format!(
                "{} [{}]: {}\n    stderr: {}",
                case.id,
                case.category,
                why.join("; "),
                geostride::io::clip(stderr.trim(), 300)
            ));
        }
    }
    // The largest resident memory of any case's process (and of the set-ups').
    let peak_mb = children_peak_mb();
    eprintln!(
        "{} bad-input cases; the slowest {} in {:.1} s; the largest process {peak_mb:.0} MB",
        cases.len(),
        slowest.1,
        slowest.0
    );
    assert!(
        cases.len() >= 230,
        "the catalogue has {} cases",
        cases.len()
    );
    assert!(peak_mb < 2048.0, "a process took {peak_mb:.0} MB");
    assert!(
        failures.is_empty(),
        "{} case(s) failed:\n{}",
        failures.len(),
        failures.join("\n")
    );

    // GEOSTRIDE_CATALOGUE=FILE writes the table rows of the cases the page lacks (for docs).
    if let Some(path) = std::env::var_os("GEOSTRIDE_CATALOGUE") {
        let doc = std::fs::read_to_string(
            Path::new(env!("CARGO_MANIFEST_DIR")).join("docs/bad-inputs.md"),
        )
        .unwrap();
        let rows: String = cases
            .iter()
            .filter(|c| !doc.contains(&format!("`{}`", c.id)))
            .map(|c| {
                // Paths relative to the repository: the page names no machine's folders.
                let root = concat!(env!("CARGO_MANIFEST_DIR"), "/");
                format!(
                    "| `{}` | {} | {} | {} | `{}` |\n",
                    c.id,
                    c.category,
                    describe(c).replace(root, ""),
                    c.expect.replace('|', "\\|").replace(root, ""),
                    c.place.replace('|', "\\|").replace(root, "")
                )
            })
            .collect();
        std::fs::write(path, rows).unwrap();
    }
    // docs/bad-inputs.md lists every case.
    let doc =
        std::fs::read_to_string(Path::new(env!("CARGO_MANIFEST_DIR")).join("docs/bad-inputs.md"))
            .unwrap();
    let missing: Vec<&str> = cases
        .iter()
        .map(|c| c.id)
        .filter(|id| !doc.contains(&format!("`{id}`")))
        .collect();
    assert!(missing.is_empty(), "docs/bad-inputs.md lacks {missing:?}");
    let _ = std::fs::remove_dir_all(fixture);
}

/// Every command aimed at its own inputs (its output equal to an input file, inside an input
/// folder or holding an input) is refused, and every input keeps its bytes; the commands that
/// only read run and change nothing.
#[test]
fn no_command_writes_into_its_inputs() {
    let fixture = fixture();
    let tmp = tempfile::tempdir().unwrap();
    let mut failures = Vec::new();
    let aimed = more::aimed_at_inputs();
    let commands: std::collections::BTreeSet<String> = aimed
        .iter()
        .map(|a| {
            a.label
                .split(':')
                .next()
                .unwrap()
                .trim_end_matches(" --video")
                .to_string()
        })
        .collect();
    for (k, a) in aimed.iter().enumerate() {
        let dir = tmp.path().join(format!("aimed-{k}"));
        copy_dir(fixture, &dir);
        prepare(&dir, &a.case);
        if let Some((file, folder)) = a.retarget {
            let canonical = dir.canonicalize().unwrap();
            let text = std::fs::read_to_string(dir.join(file)).unwrap();
            let from = canonical.join("project.toml").display().to_string();
            assert!(text.contains(&from), "{file} names no {from}");
            let to = canonical
                .join(folder)
                .join("project.toml")
                .display()
                .to_string();
            std::fs::write(dir.join(file), text.replace(&from, &to)).unwrap();
        }
        let before = snapshot(&dir);
        let out = geostride()
            .args(&a.args)
            .current_dir(&dir)
            .output()
            .unwrap();
        let after = snapshot(&dir);
        let changed: Vec<String> = after
            .iter()
            .filter(|(p, h)| before.get(*p) != Some(h))
            .map(|(p, _)| p.display().to_string())
            .chain(
                before
                    .keys()
                    .filter(|p| !after.contains_key(*p))
                    .map(|p| format!("{} (removed)", p.display())),
            )
            .collect();
        if out.status.code() != Some(a.code) || !changed.is_empty() {
            failures.push(format!(
                "{}: exit {:?} (expected {}), changed {changed:?}: {}",
                a.label,
                out.status.code(),
                a.code,
                geostride::io::clip(String::from_utf8_lossy(&out.stderr).trim(), 300)
            ));
        }
    }
    // Every command is here.
    let every = [
        "ba",
        "calibrate",
        "camera convert",
        "camera show",
        "demo",
        "detect",
        "evaluate",
        "fit-error",
        "plan",
        "pose",
        "render",
        "run",
        "segment",
        "merge",
        "sfm",
        "sfm register",
        "simulate",
        "slurm",
        "split",
        "survey convert",
        "survey inspect",
        "track",
    ];
    let missing: Vec<&str> = every
        .iter()
        .copied()
        .filter(|c| !commands.contains(*c))
        .collect();
    assert!(
        missing.is_empty(),
        "commands not aimed at their inputs: {missing:?}"
    );
    assert!(failures.is_empty(), "{}", failures.join("\n"));
}

/// A newline (or another character Slurm reads as more than a value) in any option of `slurm`
/// is refused before anything is written: no job script can run a line of the user's.
#[test]
fn no_slurm_option_becomes_a_shell_line() {
    let fixture = fixture();
    let tmp = tempfile::tempdir().unwrap();
    let mut failures = Vec::new();
    let options = [
        "--partition",
        "--time",
        "--merge-time",
        "--mem",
        "--merge-mem",
        "--sbatch",
        "--out",
        "--cpus",
    ];
    for (k, opt) in options.iter().enumerate() {
        for value in [
            "ok\ntouch pwned",
            "ok\r\ntouch pwned",
            "2\n#SBATCH --exclusive",
        ] {
            let dir = tmp.path().join(format!("slurm-{k}-{}", value.len()));
            copy_dir(fixture, &dir);
            let before = snapshot(&dir);
            let mut words: Vec<String> = vec![
                "slurm".into(),
                "project.toml".into(),
                "--segments".into(),
                "1".into(),
            ];
            let value = if *opt == "--sbatch" {
                format!("--account={value}")
            } else {
                value.to_string()
            };
            if *opt != "--out" {
                words.extend(["--out".to_string(), "sl".to_string()]);
            }
            words.push(format!("{opt}={value}"));
            let out = geostride().args(&words).current_dir(&dir).output().unwrap();
            let stderr = String::from_utf8_lossy(&out.stderr);
            if out.status.code() != Some(2) || !stderr.contains(opt) || snapshot(&dir) != before {
                failures.push(format!(
                    "{opt}={value:?}: exit {:?}: {}",
                    out.status.code(),
                    stderr.trim()
                ));
            }
        }
    }
    assert!(failures.is_empty(), "{}", failures.join("\n"));
}
