//! Whole-body detectors (pure): an external detector's boxes, read from a file and filtered
//! ([`BoxesDetector`]), and the step every body box goes through, from the box to the head
//! with the detection-error covariance ([`HeadsFromBodies`]).

use nalgebra::Vector2;

use super::boxes::{BoxFilter, FilterCounts, FilterError, RawBox, filter_frame};
use super::{Detection, Detector, ErrorModel, FrameDetections, FrameView, head_from_box};

/// One box a model found in a frame.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct FoundBox {
    /// `[x, y, w, h]`, pixels.
    pub bbox: [f64; 4],
    pub score: f64,
    /// The top of the head, pixels ((0, 0) the top-left pixel's centre), where the model gives it.
    pub head: Option<[f64; 2]>,
}

/// What finds a frame's people as it comes (the neural detector, `detect::neural`): the frame's
/// BGR bytes and size (pixels) to boxes with their scores.
pub trait FrameBoxes: Send {
    fn boxes(&mut self, bgr: &[u8], wh: [usize; 2]) -> Result<Vec<FoundBox>, crate::PluginError>;

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
    /// One past the last frame pushed.
    frames_end: usize,
    /// The video's length in frames, when known (a chunk of it sees only some).
    video_frames: Option<usize>,
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
            frames_end: 0,
            video_frames: None,
        })
    }

    /// The video's length in frames: the box file's frames beyond it are counted against it,
    /// not against the frames this detector was given (a chunk's).
    pub fn with_video_frames(mut self, frames: Option<usize>) -> Self {
        self.video_frames = frames;
        self
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
            frames_end: 0,
            video_frames: None,
        })
    }
}

impl Detector for BoxesDetector {
    fn push(&mut self, frame: &FrameView) -> Result<Vec<FrameDetections>, crate::PluginError> {
        self.frames_end = self.frames_end.max(frame.index + 1);
        if let Some((m, stride)) = self.model.as_mut() {
            if frame.index % *stride != 0 {
                return Ok(vec![(frame.index, Vec::new())]);
            }
            self.boxes = m
                .boxes(frame.bgr, [frame.width, frame.height])?
                .into_iter()
                .map(|f| RawBox {
                    frame: frame.index,
                    bbox: f.bbox,
                    score: f.score,
                    label: None,
                    line: 0,
                    head: f.head,
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
                model_head: b.head.map(|h| Vector2::new(h[0], h[1])),
            })
            .collect();
        Ok(vec![(frame.index, dets)])
    }

    fn summary(&self) -> Vec<(String, f64)> {
        let n = &self.counts;
        // A file's frames beyond the video (a model's boxes are the current frame's).
        let end = self.video_frames.unwrap_or(self.frames_end);
        let beyond = if self.model.is_some() {
            0
        } else {
            let first_beyond = self.boxes.partition_point(|b| b.frame < end);
            let mut frames: Vec<usize> =
                self.boxes[first_beyond..].iter().map(|b| b.frame).collect();
            frames.dedup();
            frames.len()
        };
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
/// ([`head_from_box`]), or the model's own head point where asked and given, and the
/// detection-error covariance of where it lies in the image.
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
    /// Take a detection's `model_head` where it has one.
    pub model_heads: bool,
    /// Heads taken from the model, and found from the box (none given, or not asked).
    pub heads_from_model: usize,
    pub heads_from_box: usize,
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
            model_heads: false,
            heads_from_model: 0,
            heads_from_box: 0,
        }
    }

    /// The model's head points where it gives them (else the box's geometry).
    pub fn with_model_heads(mut self) -> Self {
        self.model_heads = true;
        self
    }

    /// Whether a model's head point lies outside the image, or within a quarter body radius of
    /// its border (the head then partly outside: its point is a guess).
    fn outside(&self, head: &Vector2<f64>) -> bool {
        let m = (0.25 * self.body_radius_px).max(1.0) - 0.5;
        head.x < m || head.y < m || head.x > self.width - 1.0 - m || head.y > self.height - 1.0 - m
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
                let given = d.model_head.filter(|_| self.model_heads);
                let cut = match &given {
                    Some(h) => self.outside(h),
                    None => self.head_cut_off(&d.bbox),
                };
                if cut {
                    self.head_cut += 1;
                    continue;
                }
                d.uv = match given {
                    Some(h) => {
                        self.heads_from_model += 1;
                        h
                    }
                    None => {
                        self.heads_from_box += 1;
                        head_from_box(&d.bbox, &self.nadir, self.body_radius_px)
                    }
                };
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
        if self.model_heads {
            s.push(("heads_from_model".into(), self.heads_from_model as f64));
            s.push(("heads_from_box".into(), self.heads_from_box as f64));
        }
        s
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Boxes, each with the model's head point or none.
    struct Fixed(Vec<([f64; 4], Option<[f64; 2]>)>);

    impl Detector for Fixed {
        fn push(&mut self, frame: &FrameView) -> Result<Vec<FrameDetections>, crate::PluginError> {
            let dets = self
                .0
                .iter()
                .map(|(b, h)| Detection {
                    uv: Vector2::zeros(),
                    cov: nalgebra::Matrix2::identity(),
                    bbox: *b,
                    area_px: b[2] * b[3],
                    score: 1.0,
                    model_head: h.map(|h| Vector2::new(h[0], h[1])),
                })
                .collect();
            Ok(vec![(frame.index, dets)])
        }
    }

    fn heads(nadir: Vector2<f64>, boxes: Vec<[f64; 4]>) -> (Vec<Detection>, usize) {
        let boxes = boxes.into_iter().map(|b| (b, None)).collect();
        run(HeadsFromBodies::new(
            Box::new(Fixed(boxes)),
            nadir,
            20.0,
            ErrorModel::default(),
        ))
    }

    fn run(mut d: HeadsFromBodies) -> (Vec<Detection>, usize) {
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

    #[test]
    fn the_models_head_point_is_taken_where_asked_and_given() {
        let nadir = Vector2::new(320.0, 180.0);
        let boxes = vec![
            // The model's head at (50, 170), off the box's geometry.
            ([10.0, 160.0, 60.0, 30.0], Some([50.0, 170.0])),
            // No head point (a split group's box): the box's geometry.
            ([100.0, 160.0, 60.0, 30.0], None),
            // A box cut by the border on its head's side whose head point is inside: kept.
            ([0.0, 160.0, 60.0, 30.0], Some([12.0, 175.0])),
            // A head point on the border: dropped.
            ([400.0, 0.0, 40.0, 60.0], Some([420.0, 1.0])),
        ];
        let make = || {
            HeadsFromBodies::new(
                Box::new(Fixed(boxes.clone())),
                nadir,
                20.0,
                ErrorModel::default(),
            )
        };
        let (kept, cut) = run(make().with_model_heads());
        assert_eq!((kept.len(), cut), (3, 1));
        assert_eq!(kept[0].uv, Vector2::new(50.0, 170.0));
        assert!(
            (kept[1].uv - Vector2::new(120.0, 175.0)).norm() < 1.0,
            "{}",
            kept[1].uv
        );
        assert_eq!(kept[2].uv, Vector2::new(12.0, 175.0));
        // Not asked: every head from its box, the model's points ignored.
        let (kept, _) = run(make());
        assert!(
            (kept[0].uv - Vector2::new(30.0, 175.0)).norm() < 1.0,
            "{}",
            kept[0].uv
        );
    }

    #[test]
    fn box_frames_beyond_the_video_are_counted_against_the_video_not_the_chunk() {
        use crate::detect::boxes::{BoxFilter, RawBox};
        // Boxes on frames 0-9 and on frame 12 of a 10-frame video.
        let boxes: Vec<RawBox> = (0..10)
            .chain([12])
            .map(|frame| RawBox {
                frame,
                bbox: [10.0, 10.0, 20.0, 40.0],
                score: 0.9,
                label: None,
                line: frame + 1,
                head: None,
            })
            .collect();
        let beyond = |video: Option<usize>, frames: std::ops::Range<usize>| {
            let mut d = BoxesDetector::new(boxes.clone(), BoxFilter::new(40.0))
                .unwrap()
                .with_video_frames(video);
            let bgr = vec![0u8; 64 * 64 * 3];
            for index in frames {
                let f = FrameView {
                    index,
                    width: 64,
                    height: 64,
                    bgr: &bgr,
                };
                d.push(&f).unwrap();
            }
            d.summary()
                .into_iter()
                .find(|(k, _)| k == "box_frames_beyond_video")
                .map(|(_, v)| v)
        };
        // A chunk holding frames 5-7 of the video: one frame beyond (12), not frames 3-12.
        assert_eq!(beyond(Some(10), 5..8), Some(1.0));
        // Without the video's length, beyond the last frame given.
        assert_eq!(beyond(None, 0..10), Some(1.0));
    }
}
