//! Random GCP-target scenes and their scoring, shared by `tests/gcp_find.rs` (a few images) and
//! `benches/gcp_targets.rs` (over a thousand targets): a hovering camera at 25–40 m, any
//! heading, straight down to 50° below the horizon, eight targets of one design, 20–60 px
//! across, scattered irregularly in view; `geostride gcp find` (layout alone, no heading) on the
//! first frame of the H.264 video, scored against the simulator's exact picks.
#![allow(dead_code)]

use std::collections::HashMap;
use std::path::Path;
use std::process::Command;

/// A small deterministic generator (xorshift64*), so that a seed names a scene.
pub struct Rng(u64);

impl Rng {
    pub fn new(seed: u64) -> Rng {
        Rng(seed.wrapping_mul(0x9E37_79B9_7F4A_7C15) | 1)
    }

    pub fn uniform(&mut self, lo: f64, hi: f64) -> f64 {
        self.0 ^= self.0 >> 12;
        self.0 ^= self.0 << 25;
        self.0 ^= self.0 >> 27;
        let x = (self.0.wrapping_mul(0x2545_F491_4F6C_DD1D) >> 11) as f64 / (1u64 << 53) as f64;
        lo + (hi - lo) * x
    }
}

/// The scene file of image `seed` with targets of `design`.
pub fn scene(seed: u64, design: &str) -> String {
    let mut rng = Rng::new(seed);
    let altitude = rng.uniform(25.0, 40.0);
    let heading = rng.uniform(0.0, 360.0);
    let below = if rng.uniform(0.0, 1.0) < 0.5 {
        90.0
    } else {
        rng.uniform(50.0, 90.0)
    };
    // mini3pro at 1920 px: a focal length of about 1378 px.
    let range = altitude / below.to_radians().sin();
    let forward = altitude / below.to_radians().tan();
    let h = heading.to_radians();
    let (ahead, right) = ([h.sin(), h.cos()], [h.cos(), -h.sin()]);
    let centre = [forward * ahead[0], forward * ahead[1]];
    let mut s = format!(
        "name = \"targets {seed}\"\nseed = {seed}\nduration_s = 0.04\nfps = 25\n\
         [site]\ncrs = \"EPSG:3812\"\norigin = [654500.0, 696000.0, 52.0]\n\
         [camera]\ncalibration = \"mini3pro\"\nvideo_mode = [1920, 1080]\n\
         [camera.motion]\nkind = \"hover\"\nposition = [0.0, 0.0, {altitude:.2}]\n\
         heading_deg = {heading:.2}\nbelow_horizon_deg = {below:.2}\ndrift_m = 0.0\njitter_deg = 0.0\n\
         [ground]\nkind = \"deck\"\nheading_deg = 90\nwidth_m = 200.0\nlength_m = 200.0\nheight_m = 0.0\n\
         [people]\nmode = \"stream\"\nrate_per_s = 0.5\ngait = \"walk\"\nhats = false\n\
         [output]\nvideo = true\ncheckerboards = 0\npick_noise_px = 0.0\n"
    );
    let mut placed: Vec<([f64; 2], f64)> = Vec::new();
    let mut tries = 0;
    while placed.len() < 8 && tries < 1000 {
        tries += 1;
        let across = rng.uniform(-0.5, 0.5) * range * 1.2;
        let along = rng.uniform(-0.3, 0.3) * range * 0.7 / below.to_radians().sin();
        let p = [
            centre[0] + across * right[0] + along * ahead[0],
            centre[1] + across * right[1] + along * ahead[1],
        ];
        let size_m = rng.uniform(20.0, 60.0) * range / 1378.0;
        if placed
            .iter()
            .any(|(q, sq)| (q[0] - p[0]).hypot(q[1] - p[1]) < 1.5 * (size_m + sq) + 1.0)
        {
            continue;
        }
        placed.push((p, size_m));
    }
    for (k, (p, size_m)) in placed.iter().enumerate() {
        s += &format!(
            "[[gcp]]\nname = \"T{}\"\nposition = [{:.3}, {:.3}]\ndesign = \"{design}\"\nsize_m = {size_m:.3}\n",
            k + 1,
            p[0],
            p[1]
        );
        // Coded markers: id k + 1 names T(k + 1), as `gcp find` reads names without a table.
        if design == "coded" {
            s += &format!("code = {}\n", k + 1);
        }
    }
    s
}

/// How one image went.
#[derive(Debug, Default, Clone)]
pub struct Score {
    /// Targets whose whole square is in the image (their centre 40 px from every edge).
    pub visible: usize,
    /// Of those, found and given their own name.
    pub right: usize,
    /// Targets given another point's name (anywhere in the image).
    pub wrong: usize,
    /// Squared centre errors of the right ones, pixels², and their sizes, pixels.
    pub errors: Vec<(f64, f64)>,
    /// Whether any target was identified.
    pub identified: bool,
}

/// Simulates the scene file text `scene` into `dir/sim` (the scene file beside it).
pub fn simulate(dir: &Path, scene: &str) {
    std::fs::create_dir_all(dir).unwrap();
    std::fs::write(dir.join("scene.toml"), scene).unwrap();
    let sim = Command::new(env!("CARGO_BIN_EXE_geostride"))
        .args(["simulate", "scene.toml", "--out", "sim"])
        .current_dir(dir)
        .output()
        .unwrap();
    assert!(
        sim.status.success(),
        "{}",
        String::from_utf8_lossy(&sim.stderr)
    );
}

/// Simulates image `seed` with `design` into `dir` and scores `geostride gcp find` on it.
pub fn run(dir: &Path, seed: u64, design: &str) -> Score {
    let bin = env!("CARGO_BIN_EXE_geostride");
    simulate(dir, &scene(seed, design));
    let find = Command::new(bin)
        .args([
            "gcp",
            "find",
            "sim/video.mp4",
            "--gcps",
            "sim/gcps.csv",
            "--json",
        ])
        .args(["--design", design, "--out", "found.csv"])
        .current_dir(dir)
        .output()
        .unwrap();
    let report: serde_json::Value =
        serde_json::from_slice(&find.stdout).unwrap_or(serde_json::Value::Null);
    let truth: HashMap<String, (f64, f64)> = std::fs::read_to_string(dir.join("sim/picks.csv"))
        .unwrap()
        .lines()
        .skip(1)
        .filter_map(|l| {
            let f: Vec<&str> = l.split(',').collect();
            Some((f[0].to_string(), (f[2].parse().ok()?, f[3].parse().ok()?)))
        })
        .collect();
    let mut score = Score::default();
    let targets = report[0]["targets"].as_array().cloned().unwrap_or_default();
    let named: HashMap<String, (f64, f64, f64)> = targets
        .iter()
        .filter_map(|t| {
            let name = t["name"].as_str()?.to_string();
            let uv = (t["u"].as_f64()?, t["v"].as_f64()?, t["size_px"].as_f64()?);
            Some((name, uv))
        })
        .collect();
    score.identified = !named.is_empty();
    for (name, (u, v)) in &truth {
        let whole = *u >= 40.0 && *v >= 40.0 && *u <= 1879.0 && *v <= 1039.0;
        match named.get(name) {
            Some((fu, fv, size)) if (fu - u).hypot(fv - v) < 3.0 && whole => {
                score.visible += 1;
                score.right += 1;
                score
                    .errors
                    .push(((fu - u).powi(2) + (fv - v).powi(2), *size));
            }
            // Named rightly, but partly outside the image: not counted.
            Some((fu, fv, _)) if (fu - u).hypot(fv - v) < 3.0 => {}
            Some(_) => score.wrong += 1,
            None if whole => score.visible += 1,
            None => {}
        }
    }
    // A name given to a place where no target of that name is.
    score.wrong += named.keys().filter(|n| !truth.contains_key(*n)).count();
    score
}
