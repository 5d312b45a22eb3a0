//! Whole-body detectors (pure): an external detector's boxes, read from a file and filtered
//! ([`BoxesDetector`]), and the step every body box goes through, from the box to the head
//! with the detection-error covariance ([`HeadsFromBodies`]).

use nalgebra::Vector2;

use super::boxes::{BoxFilter, FilterCounts, FilterError, RawBox, filter_frame};
use super::{Detection, Detector, ErrorModel, FrameDetections, FrameView, head_from_box};

/// What finds a frame's people as it comes (the neural detector, `detect::neural`): the frame's
/// BGR bytes and size (pixels) to boxes `[x, y, w, h]` in pixels with their scores.
pub trait FrameBoxes: Send {
    fn boxes(
        &mut self,
        bgr: &[u8],
        wh: [usize; 2],
    ) -> Result<Vec<([f64; 4], f64)>, crate::PluginError>;

    /// Numbers for the run report (how it was run).
    fn summary(&self) -> Vec<(String, f64)> {
        Vec::new()
    }
}

/// Boxes from a file or a neural detector, filtered frame by frame (the shadow test looks at the
/// frame's pixels).
pub struct BoxesDetector {
    /// The boxes sorted by frame (a map of small vectors took four times the memory).
    boxes: Vec<RawBox>,
    /// Or the model that finds each frame's, on every `.1`-th frame.
    model: Option<(Box<dyn FrameBoxes>, usize)>,
    filter: BoxFilter,
    counts: FilterCounts,
    frames: usize,
}

impl BoxesDetector {
    pub fn new(boxes: Vec<RawBox>, filter: BoxFilter) -> Result<BoxesDetector, FilterError> {
        filter.check()?;
        let mut boxes = boxes;
        boxes.sort_by_key(|b| b.frame);
        Ok(BoxesDetector {
            boxes,
            model: None,
            filter,
            counts: FilterCounts::default(),
            frames: 0,
        })
    }

    /// Boxes found by `model` in each frame as it comes.
    pub fn from_model(
        model: Box<dyn FrameBoxes>,
        stride: usize,
        filter: BoxFilter,
    ) -> Result<BoxesDetector, FilterError> {
        filter.check()?;
        Ok(BoxesDetector {
            boxes: Vec::new(),
            model: Some((model, stride.max(1))),
            filter,
            counts: FilterCounts::default(),
            frames: 0,
        })
    }
}

impl Detector for BoxesDetector {
    fn push(&mut self, frame: &FrameView) -> Result<Vec<FrameDetections>, crate::PluginError> {
        self.frames += 1;
        if let Some((m, stride)) = self.model.as_mut() {
            if frame.index % *stride != 0 {
                return Ok(vec![(frame.index, Vec::new())]);
            }
            self.boxes = m
                .boxes(frame.bgr, [frame.width, frame.height])?
                .into_iter()
                .map(|(bbox, score)| RawBox {
                    frame: frame.index,
                    bbox,
                    score,
                    label: None,
                    line: 0,
                })
                .collect();
        }
        let from = self.boxes.partition_point(|b| b.frame < frame.index);
        let to = from + self.boxes[from..].partition_point(|b| b.frame == frame.index);
        if from == to {
            return Ok(vec![(frame.index, Vec::new())]);
        }
        let boxes = &self.boxes[from..to];
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
        let first_beyond = self.boxes.partition_point(|b| b.frame < self.frames);
        let mut beyond: Vec<usize> = self.boxes[first_beyond..].iter().map(|b| b.frame).collect();
        beyond.dedup();
        let beyond = beyond.len();
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
        .chain(self.model.iter().flat_map(|(m, _)| m.summary()))
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
    /// The frames' size, pixels (from the first frame).
    pub width: f64,
    pub height: f64,
    /// Boxes dropped because the image border cuts them on the head's side.
    pub head_cut: usize,
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
            height: 0.0,
            head_cut: 0,
        }
    }

    /// Whether the image border cuts the box on the side away from the nadir, where the head
    /// is: then the head is (partly) outside and the box says nothing of where it is.
    fn head_cut_off(&self, bbox: &[f64; 4]) -> bool {
        let c = Vector2::new(bbox[0] + bbox[2] / 2.0, bbox[1] + bbox[3] / 2.0);
        let Some(d) = (c - self.nadir).try_normalize(1e-9) else {
            return false;
        };
        // A detector's edges are a few pixels off: within a quarter body radius is touching.
        let touches = (0.25 * self.body_radius_px).max(1.0);
        (d.x < -0.2 && bbox[0] <= touches)
            || (d.y < -0.2 && bbox[1] <= touches)
            || (d.x > 0.2 && bbox[0] + bbox[2] >= self.width - touches)
            || (d.y > 0.2 && bbox[1] + bbox[3] >= self.height - touches)
    }

    fn heads(&mut self, done: Vec<FrameDetections>) -> Vec<FrameDetections> {
        let mut out = Vec::with_capacity(done.len());
        for (i, dets) in done {
            let mut heads = Vec::with_capacity(dets.len());
            for mut d in dets {
                if self.head_cut_off(&d.bbox) {
                    self.head_cut += 1;
                    continue;
                }
                d.uv = head_from_box(&d.bbox, &self.nadir, self.body_radius_px);
                d.cov = self.error.cov(&d.uv, self.width);
                heads.push(d);
            }
            out.push((i, heads));
        }
        out
    }
}

impl Detector for HeadsFromBodies {
    fn push(&mut self, frame: &FrameView) -> Result<Vec<FrameDetections>, crate::PluginError> {
        self.width = frame.width as f64;
        self.height = frame.height as f64;
        let done = self.inner.push(frame)?;
        Ok(self.heads(done))
    }
    fn finish(&mut self) -> Result<Vec<FrameDetections>, crate::PluginError> {
        let done = self.inner.finish()?;
        Ok(self.heads(done))
    }
    fn summary(&self) -> Vec<(String, f64)> {
        let mut s = self.inner.summary();
        s.push(("boxes_head_cut".into(), self.head_cut as f64));
        s
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    struct Fixed(Vec<[f64; 4]>);

    impl Detector for Fixed {
        fn push(&mut self, frame: &FrameView) -> Result<Vec<FrameDetections>, crate::PluginError> {
            let dets = self
                .0
                .iter()
                .map(|b| Detection {
                    uv: Vector2::zeros(),
                    cov: nalgebra::Matrix2::identity(),
                    bbox: *b,
                    area_px: b[2] * b[3],
                    score: 1.0,
                })
                .collect();
            Ok(vec![(frame.index, dets)])
        }
    }

    fn heads(nadir: Vector2<f64>, boxes: Vec<[f64; 4]>) -> (Vec<Detection>, usize) {
        let mut d =
            HeadsFromBodies::new(Box::new(Fixed(boxes)), nadir, 20.0, ErrorModel::default());
        let bgr = vec![0u8; 640 * 360 * 3];
        let view = FrameView {
            index: 0,
            width: 640,
            height: 360,
            bgr: &bgr,
        };
        let mut out = d.push(&view).unwrap();
        let cut = d
            .summary()
            .iter()
            .find(|(k, _)| k == "boxes_head_cut")
            .map_or(usize::MAX, |(_, v)| *v as usize);
        (out.remove(0).1, cut)
    }

    #[test]
    fn boxes_cut_by_the_border_on_the_heads_side_are_dropped() {
        // Nadir at the centre of a 640 × 360 image; body radius 20 px (5 px tolerance).
        let (kept, cut) = heads(
            Vector2::new(320.0, 180.0),
            vec![
                // Entering on the left: the head (away from the nadir) is still outside.
                [0.0, 160.0, 60.0, 30.0],
                // Leaving on the right, 2 px from the border: the head is going out.
                [600.0, 160.0, 38.0, 30.0],
                // Above the nadir, touching the top: the head's side.
                [300.0, 0.0, 40.0, 100.0],
                // Wholly inside, 10 px from the left border.
                [10.0, 160.0, 60.0, 30.0],
            ],
        );
        assert_eq!(cut, 3);
        assert_eq!(kept.len(), 1);
        // Its head lies at its left end, one radius in.
        assert!(
            (kept[0].uv - Vector2::new(30.0, 175.0)).norm() < 1.0,
            "{}",
            kept[0].uv
        );
        // With the nadir left of the image, the left border cuts the feet's side: kept, the
        // head at the right end.
        let (kept, cut) = heads(Vector2::new(-100.0, 175.0), vec![[0.0, 160.0, 60.0, 30.0]]);
        assert_eq!((kept.len(), cut), (1, 0));
        assert!(
            (kept[0].uv - Vector2::new(40.0, 175.0)).norm() < 1e-9,
            "{}",
            kept[0].uv
        );
    }
}
