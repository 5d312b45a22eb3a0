//! What the benchmarks share: CPU time, and a scene simulated once (or reused).

use std::path::Path;

use geostride::camera::presets;
use geostride::simulate::run::{Overrides, simulate};
use geostride::simulate::scene::Scene;
use indicatif::{ProgressBar, ProgressDrawTarget, ProgressStyle};

/// CPU seconds used by the process so far (all threads).
#[allow(dead_code)]
pub fn cpu_s() -> f64 {
    let mut u: libc::rusage = unsafe { std::mem::zeroed() };
    // SAFETY: getrusage fills the struct it is given.
    unsafe { libc::getrusage(libc::RUSAGE_SELF, &mut u) };
    let t = |v: libc::timeval| v.tv_sec as f64 + v.tv_usec as f64 * 1e-6;
    t(u.ru_utime) + t(u.ru_stime)
}

pub fn simulated(scene_path: &Path, dir: &Path) -> Scene {
    let scene = Scene::load(scene_path).expect("benchmark scene");
    if dir.join("video.mp4").exists()
        && dir.join("gcps.csv").exists()
        && dir.join("truth/boxes.csv").exists()
    {
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
