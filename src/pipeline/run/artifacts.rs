//! What each stage hands the next: the scan's frames, every frame's pose, the projected
//! tracks. The stage caches hold them (serde), so a re-run reads them back.

use nalgebra::{Matrix3, Matrix6, Vector3};
use serde::{Deserialize, Serialize};

use crate::geom::Rigid3;
use crate::pipeline::chunk_pass::ScanTimes;
use crate::pose::stabilise::FrameTrack;
use crate::projection::WorldPoint;

/// What the scan stage gives: its chunks put together.
#[derive(Clone, Debug)]
pub(super) struct ScanData {
    pub(super) fps: f64,
    pub(super) width: u32,
    pub(super) height: u32,
    pub(super) frames: usize,
    pub(super) px_per_m: f64,
    pub(super) detector_summary: Vec<(String, f64)>,
    pub(super) tracks: Vec<FrameTrack>,
    /// How many detections the chunks hold.
    pub(super) detections: usize,
    pub(super) times: ScanTimes,
}

/// A frame's pose as the later stages need it.
#[derive(Clone, Debug, Serialize, Deserialize)]
pub(super) struct FramePoseData {
    pub(super) frame: usize,
    pub(super) rotation: Matrix3<f64>,
    pub(super) translation: Vector3<f64>,
    pub(super) covariance: Option<Matrix6<f64>>,
    pub(super) interpolated: bool,
    pub(super) mean_reprojection_px: Option<f64>,
}

impl FramePoseData {
    pub(super) fn pose(&self) -> Rigid3 {
        Rigid3 {
            rotation: nalgebra::Rotation3::from_matrix_unchecked(self.rotation),
            translation: self.translation,
        }
    }
}

#[derive(Clone, Debug, Serialize, Deserialize)]
pub(super) struct PoseData {
    pub(super) frames: Vec<FramePoseData>,
    pub(super) key_frames: Vec<usize>,
    pub(super) key_frames_failed: Vec<usize>,
    pub(super) mean_reprojection_px: f64,
    pub(super) max_reprojection_px: f64,
    pub(super) check_mean_reprojection_px: Option<f64>,
}

impl PoseData {
    /// The frames' poses and the key frames, with the mean and the largest of the frames'
    /// reprojection errors (over the frames that have one).
    pub(super) fn new(
        frames: Vec<FramePoseData>,
        key_frames: Vec<usize>,
        key_frames_failed: Vec<usize>,
        check_mean_reprojection_px: Option<f64>,
    ) -> PoseData {
        let rms: Vec<f64> = frames
            .iter()
            .filter_map(|f| f.mean_reprojection_px)
            .collect();
        PoseData {
            mean_reprojection_px: rms.iter().sum::<f64>() / rms.len().max(1) as f64,
            max_reprojection_px: rms.iter().copied().fold(0.0, f64::max),
            check_mean_reprojection_px,
            frames,
            key_frames,
            key_frames_failed,
        }
    }
}

/// A track projected to the world.
#[derive(Clone, Debug, Serialize, Deserialize)]
pub(super) struct WorldTrack {
    pub(super) id: usize,
    pub(super) height_m: f64,
    pub(super) height_sd_m: f64,
    pub(super) height_source: String,
    pub(super) points: Vec<(usize, WorldPoint)>,
    /// The detector's score of each point (`None` where the tracker bridged a frame).
    pub(super) scores: Vec<Option<f64>>,
}
