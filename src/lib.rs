//! geostride: photogrammetry for people-tracking from drone video.
//!
//! Conventions (see `docs/conventions.md`): camera frame x right, y down, z forward; pixel (0, 0)
//! is the centre of the top-left pixel; transforms are named `dst_from_src`; metres, radians,
//! pixels, seconds; distortion in OpenCV order `k1 k2 p1 p2 k3 k4 k5 k6`.
//!
//! # Entry points
//!
//! - A whole job: [`pipeline::project::load`] reads a project file, [`pipeline::run::run`] runs
//!   it (scan, pose, track, project, smooth, export) into a folder, cached and resumable.
//! - Calibration: [`calibration::calibrate`] from board views; [`camera::formats`] reads and
//!   writes OpenCV YAML, Metashape XML and JSON calibrations.
//! - Survey: [`survey::load::load_framed`] reads a GCP file (six formats, any CRS through PROJ)
//!   into a local metric site frame.
//! - Pose: [`pose::solve_pose`] for one image from GCP picks, [`pose::hover::solve_with_checks`]
//!   for every frame of a hovering camera's video.
//! - Structure from motion: [`sfm::job::run_sfm`] (features, matches, reconstruction,
//!   georeferencing); [`optim::ba::adjust`] is the bundle adjuster underneath, a problem stated
//!   as [`optim::ba::Problem`] and [`optim::ba::Priors`].
//! - People: a [`detect::Detector`], a [`track::Tracker`], [`projection::project`] to the
//!   ground through a [`terrain::HeightSurface`], [`smooth::smooth`] (Kalman + RTS with EM).
//! - Checking: [`evaluate::evaluate`] against a truth; [`simulate::run::simulate`] makes scenes
//!   with one.
//!
//! # Pure core and adapters
//!
//! The maths (`geom`, `camera`, `estimate`, `optim`, `detect`, `track`, `projection`, `smooth`,
//! `terrain`, `sfm`'s solvers, `pose`, `evaluate`) uses nalgebra and std; OpenCV, GDAL + PROJ
//! and ONNX Runtime stay in adapters behind the cargo features `opencv`, `gdal` and `onnx` (on
//! by default). `cargo test --no-default-features` builds and tests the core without them
//! (`docs/architecture.md`).

// `!(x > 0.0)` is used on purpose: it also rejects NaN.
#![allow(clippy::neg_cmp_op_on_partial_ord)]

/// What a plug-in (a `detect::Detector`, a `features::FeatureTracker`) reports when it cannot
/// go on: any error, boxed, so that an implementation outside geostride keeps its own type.
pub type PluginError = Box<dyn std::error::Error + Send + Sync>;

pub mod analysis;
pub mod cache;
pub mod calibration;
pub mod camera;
pub mod detect;
#[cfg(feature = "opencv")]
pub mod draw;
pub mod estimate;
pub mod evaluate;
pub mod export;
pub mod features;
pub mod geom;
#[cfg(feature = "gdal")]
pub mod gis;
pub mod image;
pub mod imageheader;
#[cfg(feature = "opencv")]
pub mod imageio;
pub mod io;
pub mod optim;
#[cfg(all(feature = "opencv", feature = "gdal", feature = "onnx"))]
pub mod pipeline;
pub mod pose;
pub mod progress;
pub mod projection;
pub mod sfm;
pub mod simulate;
pub mod smooth;
#[cfg(feature = "gdal")]
pub mod survey;
pub mod targets;
pub mod telemetry;
pub mod terrain;
pub mod text;
pub mod track;
#[cfg(feature = "opencv")]
pub mod video;

/// Helpers shared by the unit tests.
#[cfg(test)]
pub(crate) mod testing {
    /// Uniform numbers in [−1, 1) from a seed.
    pub struct Uniform(rand_chacha::ChaCha8Rng);

    impl Uniform {
        pub fn new(seed: u64) -> Self {
            Uniform(rand::SeedableRng::seed_from_u64(seed))
        }

        pub fn next(&mut self) -> f64 {
            rand::RngExt::random_range(&mut self.0, -1.0..1.0)
        }

        /// Uniform in [lo, hi).
        pub fn range(&mut self, lo: f64, hi: f64) -> f64 {
            lo + (hi - lo) * (self.next() + 1.0) / 2.0
        }

        /// Standard normal (Box–Muller).
        pub fn normal(&mut self) -> f64 {
            let u = (self.next() + 1.0) / 2.0;
            let v = (self.next() + 1.0) / 2.0;
            (-2.0 * (1.0 - u).ln()).sqrt() * (std::f64::consts::TAU * v).cos()
        }
    }
}
