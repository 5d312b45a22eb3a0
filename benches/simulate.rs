//! Renders the benchmark scene (`benches/scenes/stream-100.toml`: 20 s of 1920x1080 at 25 fps,
//! a stream of runners over a deck) with a progress bar, and reports the time against the
//! target of two minutes. There is no peer renderer to compare with; the time is the result.

use std::path::Path;
use std::time::Instant;

use geostride::camera::presets;
use geostride::simulate::run::{Overrides, simulate};
use geostride::simulate::scene::Scene;
use indicatif::{ProgressBar, ProgressDrawTarget, ProgressStyle};

fn main() {
    let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("benches/scenes/stream-100.toml");
    let scene = Scene::load(&path).expect("benchmark scene");
    let mut camera = presets::preset(&scene.camera.calibration)
        .expect("preset")
        .camera;
    if let Some([w, h]) = scene.camera.video_mode {
        camera = camera.scaled_to(w, h).expect("same aspect");
    }
    let out = tempfile::tempdir().expect("temporary folder");
    let bar = ProgressBar::with_draw_target(Some(0), ProgressDrawTarget::stderr());
    bar.set_style(
        ProgressStyle::with_template(
            "{spinner} rendering {bar:30} {pos}/{len} frames ({per_sec}, {eta})",
        )
        .expect("template"),
    );
    let t = Instant::now();
    let s = simulate(&scene, &camera, out.path(), &Overrides::default(), &bar).expect("simulate");
    let secs = t.elapsed().as_secs_f64();
    bar.finish_and_clear();
    println!(
        "simulate: {} ({} threads)",
        scene.name,
        rayon::current_num_threads()
    );
    println!(
        "  {} frames of {}x{}, {} runners ({} seen), video {}",
        s.frames,
        s.image_size[0],
        s.image_size[1],
        s.people,
        s.people_in_view,
        s.codec.as_deref().unwrap_or("none")
    );
    println!(
        "  {secs:.1} s in all, {:.1} frames/s; target under 120 s: {}",
        s.frames as f64 / secs,
        if secs < 120.0 { "met" } else { "NOT met" }
    );
}
