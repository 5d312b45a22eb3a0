//! Throughput of `geostride run` on a simulated 3840x2160 video (`benches/scenes/stream-4k.toml`:
//! 4 s, a dense stream of runners with hats), beside the plain decode rate of the same video in
//! the same run: frames per second of every stage and end to end. Target: the colour pipeline at
//! no less than half the decode rate.
//!
//! `GEOSTRIDE_BENCH_DIR=DIR` keeps the simulated scene in DIR and reuses it on the next run.

use std::path::{Path, PathBuf};
use std::time::Instant;

use geostride::camera::presets;
use geostride::cli::demo::project_for_scene;
use geostride::pipeline::project::load;
use geostride::pipeline::run::{Silent, run};
use geostride::simulate::run::{Overrides, simulate};
use geostride::simulate::scene::Scene;
use geostride::video::source::FrameReader;
use indicatif::{ProgressBar, ProgressDrawTarget, ProgressStyle};

const TARGET_RATIO: f64 = 0.5;

/// CPU seconds used by the process so far (all threads).
fn cpu_s() -> f64 {
    let mut u: libc::rusage = unsafe { std::mem::zeroed() };
    // SAFETY: getrusage fills the struct it is given.
    unsafe { libc::getrusage(libc::RUSAGE_SELF, &mut u) };
    let t = |v: libc::timeval| v.tv_sec as f64 + v.tv_usec as f64 * 1e-6;
    t(u.ru_utime) + t(u.ru_stime)
}

fn simulated(scene_path: &Path, dir: &Path) -> Scene {
    let scene = Scene::load(scene_path).expect("benchmark scene");
    if dir.join("video.mp4").exists() && dir.join("gcps.csv").exists() {
        eprintln!("reusing the scene simulated in {}", dir.display());
        return scene;
    }
    let mut camera = presets::preset(&scene.camera.calibration)
        .expect("preset")
        .camera;
    if let Some([w, h]) = scene.camera.video_mode {
        camera = camera.scaled_to(w, h).expect("same aspect");
    }
    let bar = ProgressBar::with_draw_target(Some(0), ProgressDrawTarget::stderr());
    bar.set_style(
        ProgressStyle::with_template("{spinner} simulating {bar:30} {pos}/{len} frames ({eta})")
            .expect("template"),
    );
    let s = simulate(&scene, &camera, dir, &Overrides::default(), &bar).expect("simulate");
    bar.finish_and_clear();
    eprintln!(
        "simulated {} frames of {}x{}, {} people ({} seen)",
        s.frames, s.image_size[0], s.image_size[1], s.people, s.people_in_view
    );
    scene
}

/// Decodes every frame once into BGR, as fast as the reader can (one frame's memory reused):
/// (frames, wall s, CPU s).
fn decode(video: &Path) -> (usize, f64, f64) {
    let (t, c) = (Instant::now(), cpu_s());
    let mut reader = FrameReader::open(video).expect("video");
    let mut frame = opencv::core::Mat::default();
    let mut n = 0;
    while reader.read_bgr_into(&mut frame).expect("decode").is_some() {
        std::hint::black_box(&frame);
        n += 1;
    }
    (n, t.elapsed().as_secs_f64(), cpu_s() - c)
}

fn main() {
    let root = Path::new(env!("CARGO_MANIFEST_DIR"));
    let scene_path = root.join("benches/scenes/stream-4k.toml");
    let temp;
    let dir: PathBuf = match std::env::var_os("GEOSTRIDE_BENCH_DIR") {
        Some(d) => PathBuf::from(d),
        None => {
            temp = tempfile::tempdir().expect("temporary folder");
            temp.path().to_path_buf()
        }
    };
    std::fs::create_dir_all(&dir).expect("bench folder");
    let scene = simulated(&scene_path, &dir);
    let project = dir.join("project.toml");
    let text = project_for_scene(&scene, &scene.camera.calibration, None).expect("project");
    std::fs::write(&project, text).expect("project file");
    let video = dir.join("video.mp4");

    // Warm the file cache, then decode alone, run the pipeline, decode alone again.
    let _ = decode(&video);
    let (frames, dec1, dec1_cpu) = decode(&video);
    let out = dir.join("run");
    let _ = std::fs::remove_dir_all(&out);
    let loaded = load(&project).expect("project loads");
    let (t, c) = (Instant::now(), cpu_s());
    let report = run(&loaded, &out, &Silent).expect("pipeline");
    let (wall, wall_cpu) = (t.elapsed().as_secs_f64(), cpu_s() - c);
    let (_, dec2, dec2_cpu) = decode(&video);
    let decode_fps = frames as f64 * 2.0 / (dec1 + dec2);

    println!(
        "pipeline_throughput: {} ({} frames of 3840x2160, {} threads)",
        scene.name,
        frames,
        std::thread::available_parallelism().map_or(1, |n| n.get())
    );
    println!(
        "  plain decode: {:.1} frames/s ({dec1:.2} s, {dec1_cpu:.2} CPU s; again {dec2:.2} s, {dec2_cpu:.2} CPU s)",
        decode_fps
    );
    println!(
        "  stage           seconds   frames/s   (the scan's decoder, stabiliser and detector run side by side: busy seconds of each)"
    );
    let fps = |s: f64| {
        if s > 0.0 {
            frames as f64 / s
        } else {
            f64::INFINITY
        }
    };
    for st in &report.stages {
        println!(
            "  {:<14} {:>8.3} {:>10.1}",
            st.name,
            st.seconds,
            fps(st.seconds)
        );
        if st.name == "scan" {
            for k in ["decode_s", "stabilise_s", "detect_s"] {
                if let Some(&v) = st.counts.get(k) {
                    println!(
                        "    {:<12} {:>8.3} {:>10.1}",
                        k.trim_end_matches("_s"),
                        v,
                        fps(v)
                    );
                }
            }
        }
    }
    let count = |stage: &str, key: &str| {
        report
            .stages
            .iter()
            .find(|s| s.name == stage)
            .and_then(|s| s.counts.get(key))
            .copied()
            .unwrap_or(0.0)
    };
    println!(
        "  {} detections, {} tracks",
        count("scan", "detections"),
        count("track", "tracks")
    );
    let e2e = frames as f64 / wall;
    let ratio = e2e / decode_fps;
    println!(
        "  end to end: {wall:.2} s ({wall_cpu:.2} CPU s), {e2e:.1} frames/s = {ratio:.2} of the decode rate; target >= {TARGET_RATIO}: {}",
        if ratio >= TARGET_RATIO {
            "met"
        } else {
            "NOT met"
        }
    );
}
