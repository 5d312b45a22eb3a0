//! Whole-body detectors (pure): an external detector's boxes, read from a file and filtered
//! ([`BoxesDetector`]), and the step every body box goes through, from the box to the head
//! with the detection-error covariance ([`HeadsFromBodies`]).

use std::collections::HashMap;

use nalgebra::Vector2;

use super::boxes::{BoxFilter, FilterCounts, RawBox, filter_frame};
use super::{Detection, Detector, ErrorModel, FrameDetections, FrameView, head_from_box};

/// Boxes from a file, filtered frame by frame (the shadow test looks at the frame's pixels).
pub struct BoxesDetector {
    by_frame: HashMap<usize, Vec<RawBox>>,
    filter: BoxFilter,
    counts: FilterCounts,
    frames: usize,
}

impl BoxesDetector {
    pub fn new(boxes: Vec<RawBox>, filter: BoxFilter) -> Result<BoxesDetector, String> {
        filter.check()?;
        let mut by_frame: HashMap<usize, Vec<RawBox>> = HashMap::new();
        for b in boxes {
            by_frame.entry(b.frame).or_default().push(b);
        }
        Ok(BoxesDetector {
            by_frame,
            filter,
            counts: FilterCounts::default(),
            frames: 0,
        })
    }
}

impl Detector for BoxesDetector {
    fn push(&mut self, frame: &FrameView) -> Result<Vec<FrameDetections>, String> {
        self.frames += 1;
        let Some(boxes) = self.by_frame.get(&frame.index) else {
            return Ok(vec![(frame.index, Vec::new())]);
        };
        let (kept, n) = filter_frame(boxes, &self.filter, Some(frame));
        self.counts += n;
        let dets = kept
            .iter()
            .map(|b| Detection {
                uv: Vector2::new(b.bbox[0] + b.bbox[2] / 2.0, b.bbox[1] + b.bbox[3] / 2.0),
                cov: nalgebra::Matrix2::identity(),
                bbox: b.bbox,
                area_px: b.bbox[2] * b.bbox[3],
                score: b.score,
            })
            .collect();
        Ok(vec![(frame.index, dets)])
    }

    fn summary(&self) -> Vec<(String, f64)> {
        let n = &self.counts;
        let beyond = self.by_frame.keys().filter(|&&f| f >= self.frames).count();
        [
            ("boxes_read", n.read),
            ("boxes_low_score", n.low_score),
            ("boxes_outside_roi", n.outside_roi),
            ("boxes_merged", n.merged),
            ("boxes_suppressed", n.suppressed),
            ("boxes_bad_aspect", n.bad_aspect),
            ("boxes_bad_size", n.bad_size),
            ("boxes_split", n.split),
            ("boxes_shadows", n.shadows),
            ("boxes_kept", n.kept),
            ("box_frames_beyond_video", beyond),
        ]
        .into_iter()
        .map(|(k, v)| (k.to_string(), v as f64))
        .collect()
    }
}

/// Turns a body detector's boxes into heads: the head found along the line from the nadir
/// ([`head_from_box`]) and the detection-error covariance of where it lies in the image.
pub struct HeadsFromBodies {
    pub inner: Box<dyn Detector>,
    /// The nadir's image (where vertical lines meet), pixels.
    pub nadir: Vector2<f64>,
    pub body_radius_px: f64,
    pub error: ErrorModel,
    /// The frames' width, pixels (from the first frame).
    pub width: f64,
}

impl HeadsFromBodies {
    pub fn new(
        inner: Box<dyn Detector>,
        nadir: Vector2<f64>,
        body_radius_px: f64,
        error: ErrorModel,
    ) -> Self {
        HeadsFromBodies {
            inner,
            nadir,
            body_radius_px,
            error,
            width: 0.0,
        }
    }

    fn heads(&self, width: f64, done: Vec<FrameDetections>) -> Vec<FrameDetections> {
        done.into_iter()
            .map(|(i, dets)| {
                let dets = dets
                    .into_iter()
                    .map(|mut d| {
                        d.uv = head_from_box(&d.bbox, &self.nadir, self.body_radius_px);
                        d.cov = self.error.cov(&d.uv, width);
                        d
                    })
                    .collect();
                (i, dets)
            })
            .collect()
    }
}

impl Detector for HeadsFromBodies {
    fn push(&mut self, frame: &FrameView) -> Result<Vec<FrameDetections>, String> {
        self.width = frame.width as f64;
        let done = self.inner.push(frame)?;
        Ok(self.heads(self.width, done))
    }
    fn finish(&mut self) -> Result<Vec<FrameDetections>, String> {
        let done = self.inner.finish()?;
        Ok(self.heads(self.width, done))
    }
    fn summary(&self) -> Vec<(String, f64)> {
        self.inner.summary()
    }
}
