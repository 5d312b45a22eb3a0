//! `geostride calibrate`, `camera` and `demo` end to end on temporary folders: synthetic board
//! images and videos with known truth, and bad inputs.

#![cfg(all(feature = "opencv", feature = "gdal", feature = "onnx"))]

mod common;

use std::path::{Path, PathBuf};

use geostride::camera::formats;
use geostride::camera::{BoardSpec, Camera};
use geostride::simulate::board::{BoardRenderer, random_board_poses};
use opencv::core::{CV_8UC1, Mat, Size};
use opencv::prelude::*;
use opencv::{imgproc, videoio};
use rand::SeedableRng;

const BOARD: BoardSpec = BoardSpec {
    cols: 9,
    rows: 6,
    square_m: 0.03,
};

fn truth() -> Camera {
    Camera::pinhole(560.0, 558.0, 322.0, 241.0)
        .with_distortion(&[-0.15, 0.05, 0.0, 0.0, 0.0])
        .with_image_size(640, 480)
}

/// Renders `n` board views into `dir` as PNG files.
fn render_boards(dir: &Path, n: usize, seed: u64) -> Vec<PathBuf> {
    let cam = truth();
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(seed);
    let renderer = BoardRenderer::new(&cam, 2);
    random_board_poses(&cam, &BOARD, n, &mut rng)
        .iter()
        .enumerate()
        .map(|(i, p)| {
            let path = dir.join(format!("b{i:02}.png"));
            geostride::imageio::write_gray(&path, &renderer.render(&BOARD, p, 1.0, &mut rng))
                .unwrap();
            path
        })
        .collect()
}

fn run(args: &[&str], extra: &[&Path]) -> std::process::Output {
    let mut cmd = common::geostride();
    cmd.args(args);
    for p in extra {
        cmd.arg(p);
    }
    cmd.output().unwrap()
}

fn stderr(o: &std::process::Output) -> String {
    String::from_utf8_lossy(&o.stderr).into_owned()
}

#[test]
fn calibrates_rendered_images_and_recovers_the_truth() {
    let tmp = tempfile::tempdir().unwrap();
    let boards = tmp.path().join("boards");
    std::fs::create_dir(&boards).unwrap();
    render_boards(&boards, 8, 1);
    // An unreadable file among the images is listed and skipped.
    std::fs::write(boards.join("broken.jpg"), b"not an image").unwrap();
    let out = tmp.path().join("cam.json");
    let o = run(
        &[
            "calibrate",
            "--board",
            "9x6",
            "--square",
            "0.03",
            "-q",
            "-o",
        ],
        &[&out, &boards],
    );
    assert!(o.status.success(), "{}", stderr(&o));
    assert!(
        stderr(&o).contains("skipped unreadable image") && stderr(&o).contains("broken.jpg"),
        "{}",
        stderr(&o)
    );
    let cal = formats::read(&out, None).unwrap();
    let sd = cal.std_devs().unwrap();
    let (est, tru) = (cal.camera.params(), truth().params());
    for i in 0..4 {
        assert!(
            (est[i] - tru[i]).abs() < 6.0 * sd[i] + 0.05,
            "param {i}: {} vs {} (σ {})",
            est[i],
            tru[i],
            sd[i]
        );
    }
    assert_eq!(cal.summary.unwrap().views.len(), 8);
}

#[test]
fn too_few_views_is_an_input_error() {
    let tmp = tempfile::tempdir().unwrap();
    let files = render_boards(tmp.path(), 2, 2);
    let o = run(
        &["calibrate", "--board", "9x6", "--square", "0.03", "-q"],
        &[&files[0], &files[1]],
    );
    assert_eq!(o.status.code(), Some(2), "{}", stderr(&o));
    assert!(stderr(&o).contains("2 usable view(s)"), "{}", stderr(&o));
}

#[test]
fn bad_usage_and_missing_inputs_exit_2_without_output() {
    let tmp = tempfile::tempdir().unwrap();
    let out = tmp.path().join("x.yaml");
    let missing = tmp.path().join("nope");
    let o = run(
        &["calibrate", "--board", "9x6", "--square", "0.03", "-o"],
        &[&out, &missing],
    );
    assert_eq!(o.status.code(), Some(2));
    assert!(stderr(&o).contains("does not exist"), "{}", stderr(&o));
    assert!(!out.exists());

    let o = run(
        &["calibrate", "--board", "9", "--square", "0.03"],
        &[tmp.path()],
    );
    assert_eq!(o.status.code(), Some(2));
    assert!(stderr(&o).contains("COLSxROWS"), "{}", stderr(&o));

    let o = run(
        &["calibrate", "--board", "9x6", "--square", "-1"],
        &[tmp.path()],
    );
    assert_eq!(o.status.code(), Some(2));

    let files = render_boards(tmp.path(), 1, 3);
    let bad_out = tmp.path().join("x.txt");
    let o = run(
        &["calibrate", "--board", "9x6", "--square", "0.03", "-o"],
        &[&bad_out, &files[0]],
    );
    assert_eq!(o.status.code(), Some(2));
    assert!(stderr(&o).contains("extension"), "{}", stderr(&o));
    assert!(!bad_out.exists());

    // An output that would replace an input, or in a missing folder, is refused before any work.
    let before = std::fs::read(&files[0]).unwrap();
    let o = run(
        &[
            "calibrate",
            "--board",
            "9x6",
            "--square",
            "0.03",
            "--format",
            "json",
            "-o",
        ],
        &[&files[0], &files[0]],
    );
    assert_eq!(o.status.code(), Some(2));
    assert!(
        stderr(&o).contains("would overwrite the input"),
        "{}",
        stderr(&o)
    );
    assert_eq!(
        std::fs::read(&files[0]).unwrap(),
        before,
        "the input image is intact"
    );
    let nested = tmp.path().join("no/such/dir/x.yaml");
    let o = run(
        &["calibrate", "--board", "9x6", "--square", "0.03", "-o"],
        &[&nested, &files[0]],
    );
    assert_eq!(o.status.code(), Some(2));
    assert!(stderr(&o).contains("does not exist"), "{}", stderr(&o));

    let empty = tmp.path().join("empty");
    std::fs::create_dir(&empty).unwrap();
    let o = run(
        &["calibrate", "--board", "9x6", "--square", "0.03"],
        &[&empty],
    );
    assert_eq!(o.status.code(), Some(2));
    assert!(stderr(&o).contains("holds no images"), "{}", stderr(&o));
}

#[test]
fn help_documents_every_option() {
    let o = run(&["calibrate", "--help"], &[]);
    assert!(o.status.success());
    let help = String::from_utf8_lossy(&o.stdout);
    for opt in [
        "--board",
        "--square",
        "--output",
        "--format",
        "--fix-aspect",
        "--aspect-ratio",
        "--fix-principal-point",
        "--zero-tangential",
        "--radial-terms",
        "--rational",
        "--outlier-factor",
        "--drop-outliers",
        "--detector",
        "--subpix-window",
        "--cap-subpix-window",
        "--subpix-eps",
        "--every",
        "--blur-fraction",
        "--min-motion",
        "--max-iterations",
        "--json",
        "--quiet",
    ] {
        assert!(help.contains(opt), "calibrate --help lacks {opt}");
    }
}

/// Writes a video of the board moving, with runs of identical frames and one blurred stretch.
fn write_video(path: &Path) {
    let cam = truth();
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(5);
    let renderer = BoardRenderer::new(&cam, 2);
    let poses = random_board_poses(&cam, &BOARD, 6, &mut rng);
    let fourcc = videoio::VideoWriter::fourcc('M', 'J', 'P', 'G').unwrap();
    let mut writer = videoio::VideoWriter::new(
        path.to_str().unwrap(),
        fourcc,
        10.0,
        Size::new(640, 480),
        false,
    )
    .unwrap();
    assert!(writer.is_opened().unwrap());
    for (i, p) in poses.iter().enumerate() {
        let img = renderer.render(&BOARD, p, 1.0, &mut rng);
        let mat = Mat::new_rows_cols_with_data(480, 640, &img.pixels)
            .unwrap()
            .try_clone()
            .unwrap();
        assert_eq!(mat.typ(), CV_8UC1);
        let frame = if i == 3 {
            let mut blurred = Mat::default();
            imgproc::gaussian_blur_def(&mat, &mut blurred, Size::new(0, 0), 2.0).unwrap();
            blurred
        } else {
            mat
        };
        // Each pose held for 4 frames: with --every 2 that is 2 sampled frames per pose.
        for _ in 0..4 {
            writer.write(&frame).unwrap();
        }
    }
    writer.release().unwrap();
}

#[test]
fn calibrates_from_a_video_skipping_blur_and_duplicates() {
    let tmp = tempfile::tempdir().unwrap();
    let video = tmp.path().join("board.avi");
    write_video(&video);
    let o = run(
        &[
            "calibrate",
            "--board",
            "9x6",
            "--square",
            "0.03",
            "--every",
            "2",
            "--json",
        ],
        &[&video],
    );
    assert!(o.status.success(), "{}", stderr(&o));
    let v: serde_json::Value = serde_json::from_slice(&o.stdout).unwrap();
    let names: Vec<&str> = v["views"]
        .as_array()
        .unwrap()
        .iter()
        .map(|x| x["name"].as_str().unwrap())
        .collect();
    // Six poses, one blurred: five views, one per pose (the second sample of each is a duplicate).
    assert_eq!(
        names,
        vec![
            "board.avi#0",
            "board.avi#4",
            "board.avi#8",
            "board.avi#16",
            "board.avi#20"
        ],
        "{names:?}"
    );

    let o = run(
        &[
            "calibrate",
            "--board",
            "9x6",
            "--square",
            "0.03",
            "--every",
            "2",
        ],
        &[&video],
    );
    let table = String::from_utf8_lossy(&o.stdout);
    assert!(table.contains("blurred 2, near-duplicate 5"), "{table}");
}

#[test]
fn demo_runs_and_its_outputs_convert_between_formats() {
    // A short demo: simulation, calibration from its checkerboards, two runs, evaluation.
    let tmp = tempfile::tempdir().unwrap();
    let o = run(
        &["demo", "-q", "--duration", "3", "--json", "--out"],
        &[tmp.path()],
    );
    assert!(
        o.status.success(),
        "{}\n{}",
        String::from_utf8_lossy(&o.stdout),
        stderr(&o)
    );
    let j: serde_json::Value = serde_json::from_slice(&o.stdout).unwrap();
    assert!(j["rmse_m"].as_f64().unwrap() < 0.12, "{j}");
    assert!(j["rmse_known_heights_m"].as_f64().unwrap() < 0.05);
    assert_eq!(j["passed"], true);
    assert!(stderr(&o).contains("Demo OK"));
    let dir = tmp.path().join("bridge-stream");
    for f in [
        "run/trajectories.csv",
        "run/trajectories.gpkg",
        "run/report.md",
        "run-heights/trajectories.csv",
        "demo.json",
    ] {
        assert!(dir.join(f).is_file(), "{f}");
    }
    let yaml = dir.join("camera.yaml");
    let xml = dir.join("converted.xml");
    let o = run(&["camera", "convert"], &[&yaml, &xml]);
    assert!(o.status.success(), "{}", stderr(&o));
    let a = formats::read(&yaml, None).unwrap();
    let b = formats::read(&xml, None).unwrap();
    for (x, y) in a.camera.params().iter().zip(b.camera.params()) {
        assert!((x - y).abs() <= 1e-9 * (1.0 + y.abs()));
    }
    let o = run(&["camera", "show"], &[&xml]);
    assert!(o.status.success());
    assert!(String::from_utf8_lossy(&o.stdout).contains("field of view"));
    // Converting onto the input itself is refused.
    let o = run(&["camera", "convert"], &[&yaml, &yaml]);
    assert_eq!(o.status.code(), Some(2));
    // A broken file names itself and the line.
    let broken = tmp.path().join("broken.yaml");
    std::fs::write(&broken, "%YAML:1.0\ncamera_matrix: !!opencv-matrix\n   rows: 3\n   cols: 3\n   dt: d\n   data: [ 1, 2 ]\n").unwrap();
    let o = run(&["camera", "show"], &[&broken]);
    assert_eq!(o.status.code(), Some(2));
    assert!(
        stderr(&o).contains("broken.yaml:2: field 'camera_matrix'"),
        "{}",
        stderr(&o)
    );
}
