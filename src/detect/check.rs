//! A second detector run beside the first as a check (pure): what the check finds where no
//! detection of the first lies (a moving blob the neural detector missed) is kept, to be
//! reported. The first detector's detections go on unchanged.

use std::collections::BTreeMap;

use super::{Detector, FrameDetections, FrameView, Missed};

/// The first detector, checked by a second.
pub struct CrossCheck {
    main: Box<dyn Detector>,
    check: Box<dyn Detector>,
    /// Boxes of frames one side has returned and the other not yet (the motion detector
    /// returns its frames a few late).
    main_boxes: BTreeMap<usize, Vec<[f64; 4]>>,
    check_boxes: BTreeMap<usize, Vec<[f64; 4]>>,
    /// A check's box this close to a detection's box (pixels) is that detection's.
    margin_px: f64,
    /// The check's boxes compared, in frames both returned.
    compared: usize,
    frames_compared: usize,
    missed: Vec<Missed>,
}

impl CrossCheck {
    pub fn new(main: Box<dyn Detector>, check: Box<dyn Detector>, margin_px: f64) -> Self {
        CrossCheck {
            main,
            check,
            main_boxes: BTreeMap::new(),
            check_boxes: BTreeMap::new(),
            margin_px: margin_px.max(0.0),
            compared: 0,
            frames_compared: 0,
            missed: Vec::new(),
        }
    }

    /// Files both sides' new frames, then compares every frame both have returned.
    fn take(&mut self, main: &[FrameDetections], check: Vec<FrameDetections>) {
        for (i, d) in main {
            self.main_boxes
                .insert(*i, d.iter().map(|x| x.bbox).collect());
        }
        for (i, d) in check {
            self.check_boxes
                .insert(i, d.iter().map(|x| x.bbox).collect());
        }
        let both: Vec<usize> = self
            .check_boxes
            .keys()
            .filter(|i| self.main_boxes.contains_key(i))
            .copied()
            .collect();
        for i in both {
            let found = self.main_boxes.remove(&i).unwrap_or_default();
            let checked = self.check_boxes.remove(&i).unwrap_or_default();
            self.frames_compared += 1;
            self.compared += checked.len();
            for c in checked {
                if !found.iter().any(|f| near(&c, f, self.margin_px)) {
                    self.missed.push((i, c));
                }
            }
        }
    }
}

/// Whether box `a` grown by `margin` on every side meets box `b`.
fn near(a: &[f64; 4], b: &[f64; 4], margin: f64) -> bool {
    a[0] - margin < b[0] + b[2]
        && b[0] < a[0] + a[2] + margin
        && a[1] - margin < b[1] + b[3]
        && b[1] < a[1] + a[3] + margin
}

impl Detector for CrossCheck {
    fn push(&mut self, frame: &FrameView) -> Result<Vec<FrameDetections>, crate::PluginError> {
        let done = self.main.push(frame)?;
        let checked = self.check.push(frame)?;
        self.take(&done, checked);
        Ok(done)
    }

    fn finish(&mut self) -> Result<Vec<FrameDetections>, crate::PluginError> {
        let done = self.main.finish()?;
        let checked = self.check.finish()?;
        self.take(&done, checked);
        Ok(done)
    }

    fn summary(&self) -> Vec<(String, f64)> {
        let mut frames: Vec<usize> = self.missed.iter().map(|m| m.0).collect();
        frames.dedup();
        let mut s = self.main.summary();
        s.extend(
            [
                ("check_frames", self.frames_compared),
                ("check_blobs", self.compared),
                ("check_blobs_missed", self.missed.len()),
                ("check_frames_missed", frames.len()),
            ]
            .map(|(k, v)| (k.to_string(), v as f64)),
        );
        s
    }

    fn missed(&self) -> Vec<Missed> {
        self.missed.clone()
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::detect::Detection;
    use nalgebra::{Matrix2, Vector2};

    /// Boxes by frame, returned `late` frames after their own (all at the end).
    struct Fixed {
        boxes: BTreeMap<usize, Vec<[f64; 4]>>,
        late: usize,
        seen: Vec<usize>,
    }

    impl Fixed {
        fn frame(&self, i: usize) -> FrameDetections {
            let dets = self.boxes.get(&i).cloned().unwrap_or_default();
            let dets = dets
                .into_iter()
                .map(|b| Detection {
                    uv: Vector2::new(b[0], b[1]),
                    cov: Matrix2::identity(),
                    bbox: b,
                    area_px: b[2] * b[3],
                    score: 1.0,
                    model_head: None,
                })
                .collect();
            (i, dets)
        }
    }

    impl Detector for Fixed {
        fn push(&mut self, frame: &FrameView) -> Result<Vec<FrameDetections>, crate::PluginError> {
            self.seen.push(frame.index);
            let n = self.seen.len();
            Ok(if n > self.late {
                vec![self.frame(self.seen[n - 1 - self.late])]
            } else {
                Vec::new()
            })
        }
        fn finish(&mut self) -> Result<Vec<FrameDetections>, crate::PluginError> {
            let n = self.seen.len();
            let from = n.saturating_sub(self.late);
            Ok(self.seen[from..].iter().map(|i| self.frame(*i)).collect())
        }
    }

    #[test]
    fn the_checks_boxes_that_no_detection_is_near_are_kept_and_the_detections_pass() {
        let person = [100.0, 100.0, 20.0, 40.0];
        let main = Fixed {
            boxes: (0..6).map(|i| (i, vec![person])).collect(),
            late: 0,
            seen: Vec::new(),
        };
        // The check sees the person (a blob a little off their box) in every frame, and in
        // frame 3 a second mover the detector missed; its frames come 2 late.
        let mut check_boxes: BTreeMap<usize, Vec<[f64; 4]>> = (0..6)
            .map(|i| (i, vec![[124.0, 95.0, 30.0, 30.0]]))
            .collect();
        check_boxes
            .get_mut(&3)
            .unwrap()
            .push([300.0, 50.0, 25.0, 25.0]);
        let check = Fixed {
            boxes: check_boxes,
            late: 2,
            seen: Vec::new(),
        };
        let mut c = CrossCheck::new(Box::new(main), Box::new(check), 5.0);
        let bgr = vec![0u8; 3];
        let mut out = Vec::new();
        for index in 0..6 {
            let f = FrameView {
                index,
                width: 1,
                height: 1,
                bgr: &bgr,
            };
            out.extend(c.push(&f).unwrap());
        }
        out.extend(c.finish().unwrap());
        // The detections as the detector gave them, in order.
        assert_eq!(out.len(), 6);
        assert!(
            out.iter()
                .enumerate()
                .all(|(k, (i, d))| *i == k && d[0].bbox == person)
        );
        assert_eq!(c.missed(), vec![(3, [300.0, 50.0, 25.0, 25.0])]);
        let s: BTreeMap<String, f64> = c.summary().into_iter().collect();
        assert_eq!(s["check_frames"], 6.0);
        assert_eq!(s["check_blobs"], 7.0);
        assert_eq!(s["check_blobs_missed"], 1.0);
        assert_eq!(s["check_frames_missed"], 1.0);
        // With no margin, the blob 4 px right of the box is not the person's.
        assert!(!near(&[124.0, 95.0, 30.0, 30.0], &person, 0.0));
        assert!(near(&[124.0, 95.0, 30.0, 30.0], &person, 5.0));
    }
}
