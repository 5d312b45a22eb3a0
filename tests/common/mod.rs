//! Shared helpers for integration tests.
#![allow(dead_code)]

pub mod exif;
pub mod onnx;
pub mod targets;

use std::path::PathBuf;

/// The real-data folder from `GEOSTRIDE_DATA`. Outside CI a missing folder skips the test with
/// a message; with `CI=true` it fails, so real-data tests never silently vanish from CI.
pub fn data_dir(sub: &str) -> Option<PathBuf> {
    let in_ci = std::env::var("CI").is_ok_and(|v| v == "true" || v == "1");
    let dir = std::env::var_os("GEOSTRIDE_DATA")
        .map(PathBuf::from)
        .map(|d| d.join(sub));
    match dir {
        Some(d) if d.is_dir() => Some(d),
        other => {
            let why = match other {
                Some(d) => format!("{} does not exist", d.display()),
                None => "GEOSTRIDE_DATA is not set".to_string(),
            };
            if in_ci {
                panic!(
                    "real-data test cannot run in CI: {why} (make test sets GEOSTRIDE_DATA=../shared/data)"
                );
            }
            eprintln!("SKIPPED: real-data test needs {sub}: {why}; run it through `make test`");
            None
        }
    }
}

/// Rows of a CSV as maps from header to field.
pub fn read_csv(path: &std::path::Path) -> Vec<std::collections::HashMap<String, String>> {
    let text = std::fs::read_to_string(path).unwrap_or_else(|e| panic!("{}: {e}", path.display()));
    let mut lines = text.lines();
    let header: Vec<String> = lines
        .next()
        .unwrap()
        .split(',')
        .map(str::to_string)
        .collect();
    lines
        .map(|l| {
            header
                .iter()
                .cloned()
                .zip(l.split(',').map(str::to_string))
                .collect()
        })
        .collect()
}

/// A row's field as a number.
pub fn num(row: &std::collections::HashMap<String, String>, key: &str) -> f64 {
    row[key]
        .parse()
        .unwrap_or_else(|_| panic!("{key}: '{}'", row[key]))
}

/// The geostride binary built for these tests.
pub fn geostride() -> std::process::Command {
    std::process::Command::new(env!("CARGO_BIN_EXE_geostride"))
}

/// Fails the test with the command's stderr unless it succeeded.
pub fn assert_success(out: &std::process::Output) {
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
}

/// The video `geostride simulate` wrote into `dir`: H.264 MP4 where the encoder exists, else AVI.
pub fn simulated_video(dir: &std::path::Path) -> &'static str {
    if dir.join("video.mp4").is_file() {
        "video.mp4"
    } else {
        "video.avi"
    }
}

/// A project file for a simulated hover (mini3pro camera, the simulator's GCPs and picks,
/// ellipsoidal heights), with its own `[ground]` lines and `[export]` lines.
pub fn hover_project(name: &str, video: &str, ground: &str, export: &str) -> String {
    format!(
        "name = \"{name}\"\n[camera]\ncalibration = \"mini3pro\"\n[survey]\ngcps = \"gcps.csv\"\npicks = [\"picks.csv\"]\nheight = \"ellipsoidal\"\n[video]\npath = \"{video}\"\n[ground]\n{ground}\n[export]\n{export}\n"
    )
}

/// The drifting hover scene's project in `dir` (simulated there already) on its deck, run in
/// chunks of 0.6 s with 0.3 s of overlap (short enough for a split into segments), exporting
/// `formats`, with `detect_track` (`[detect]` and `[track]` sections) appended: `dir/FILE`.
pub fn chunked_deck_project(
    dir: &std::path::Path,
    file: &str,
    name: &str,
    formats: &str,
    detect_track: &str,
) -> std::path::PathBuf {
    let video = simulated_video(dir);
    let text = hover_project(
        name,
        video,
        "kind = \"deck\"\ncentre_line = [[654460.0, 696000.0], [654540.0, 696000.0]]\nwidth_m = 5.0",
        &format!("formats = {formats}"),
    )
    .replace(
        &format!("path = \"{video}\"\n"),
        &format!("path = \"{video}\"\nchunk_s = 0.6\noverlap_s = 0.3\n"),
    ) + detect_track;
    let path = dir.join(file);
    std::fs::write(&path, text).unwrap();
    path
}

/// Simulates `tests/scenes/NAME.toml` into `dir`, failing the test on an error.
#[allow(dead_code)]
pub fn simulate_scene(name: &str, dir: &std::path::Path) {
    let scene = std::path::Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("tests/scenes")
        .join(format!("{name}.toml"));
    simulate(&scene, dir);
}

/// Simulates the scene file `scene` into `dir`, failing the test on an error.
#[allow(dead_code)]
pub fn simulate(scene: &std::path::Path, dir: &std::path::Path) {
    let out = geostride()
        .arg("simulate")
        .arg(scene)
        .arg("--out")
        .arg(dir)
        .arg("-q")
        .output()
        .unwrap();
    assert_success(&out);
}

/// `geostride evaluate --truth TRUTH --tracks TRACKS --json` with `extra` arguments, its JSON;
/// fails the test on an error.
#[allow(dead_code)]
pub fn evaluate_json(
    truth: &std::path::Path,
    tracks: &std::path::Path,
    extra: &[&str],
) -> serde_json::Value {
    let out = geostride()
        .arg("evaluate")
        .arg("--truth")
        .arg(truth)
        .arg("--tracks")
        .arg(tracks)
        .args(extra)
        .arg("--json")
        .output()
        .unwrap();
    assert_success(&out);
    serde_json::from_slice(&out.stdout).unwrap()
}

/// `geostride run PROJECT --out OUT -q`.
#[allow(dead_code)]
pub fn run_project(project: &std::path::Path, out: &std::path::Path) -> std::process::Output {
    geostride()
        .arg("run")
        .arg(project)
        .arg("--out")
        .arg(out)
        .arg("-q")
        .output()
        .unwrap()
}

/// Seven targets in no symmetric layout (east, north), one a check point, all in view of
/// [`target_scene`]'s camera.
pub const IRREGULAR_GCPS: [(&str, f64, f64); 7] = [
    ("G1", -15.0, -6.0),
    ("G2", -8.0, 7.0),
    ("G3", 2.0, -4.0),
    ("G4", 9.0, 8.5),
    ("G5", 14.0, -7.5),
    ("G6", -2.0, 3.0),
    ("CHK-1", 5.5, 1.0),
];

/// A picks CSV by name: u, v and σ (0 where none is stated).
pub fn picks(path: &std::path::Path) -> std::collections::HashMap<String, (f64, f64, f64)> {
    read_csv(path)
        .into_iter()
        .map(|r| {
            let sigma = r.get("sigma").and_then(|s| s.parse().ok()).unwrap_or(0.0);
            (r["name"].clone(), (num(&r, "u"), num(&r, "v"), sigma))
        })
        .collect()
}

/// A hovering camera 30 m up, turned `heading_deg`, over targets at `gcps` (east, north), few people.
pub fn target_scene(heading_deg: f64, gcps: &[(&str, f64, f64)]) -> String {
    let mut s = format!(
        "name = \"GCP targets\"\nseed = 5\nduration_s = 0.2\nfps = 25\n\
         [site]\ncrs = \"EPSG:3812\"\norigin = [654500.0, 696000.0, 52.0]\n\
         [camera]\ncalibration = \"mini3pro\"\nvideo_mode = [1920, 1080]\n\
         [camera.motion]\nkind = \"hover\"\nposition = [0.0, 0.0, 30.0]\nheading_deg = {heading_deg}\n\
         drift_m = 0.0\njitter_deg = 0.0\n\
         [ground]\nkind = \"deck\"\nheading_deg = 90\nwidth_m = 30.0\nlength_m = 60.0\nheight_m = 0.0\n\
         [people]\nmode = \"stream\"\nrate_per_s = 0.5\ngait = \"walk\"\nhats = false\n\
         [output]\nvideo = true\ncheckerboards = 0\npick_noise_px = 0.0\n"
    );
    for (name, e, n) in gcps {
        s += &format!("[[gcp]]\nname = \"{name}\"\nposition = [{e}, {n}]\n");
    }
    s
}
