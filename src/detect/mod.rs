//! Person detection: detectors turn a frame into head positions in pixels with a covariance.
//! `colour` finds coloured hats (the paper's section 3.1.1); `boxes` reads an external
//! detector's boxes (`boxes`, `person`); `background` finds moving people under a stationary
//! camera and `motion` under a moving one (OpenCV adapters, as are the neural detectors).

#[cfg(feature = "opencv")]
pub mod background;
pub mod boxes;
pub mod check;
pub mod colour;
pub mod error_fit;
pub mod models;
pub mod morph;
#[cfg(feature = "opencv")]
pub mod motion;
#[cfg(all(feature = "opencv", feature = "onnx"))]
pub mod neural;
#[cfg(feature = "onnx")]
pub mod onnx;
#[cfg(feature = "opencv")]
pub mod opencv_dnn;
pub mod person;
pub mod simulated;
pub mod yolo;

use nalgebra::{Matrix2, Vector2};

/// A frame as 8-bit BGR (OpenCV's order), row-major, tightly packed.
#[derive(Clone, Copy, Debug)]
pub struct FrameView<'a> {
    pub index: usize,
    pub width: usize,
    pub height: usize,
    pub bgr: &'a [u8],
}

impl FrameView<'_> {
    pub fn pixel(&self, x: usize, y: usize) -> [u8; 3] {
        let i = 3 * (y * self.width + x);
        [self.bgr[i + 2], self.bgr[i + 1], self.bgr[i]]
    }
}

/// One detected head.
#[derive(Clone, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct Detection {
    /// The head's centre, pixels ((0, 0) the centre of the top-left pixel).
    pub uv: Vector2<f64>,
    /// Covariance of `uv`, px².
    pub cov: Matrix2<f64>,
    /// Bounding box `[x, y, width, height]`, pixels.
    pub bbox: [f64; 4],
    pub area_px: f64,
    /// 1 for a clean detection, lower for doubtful ones.
    pub score: f64,
    /// The top of the head as the detector's model gives it (geostride's overhead model), for
    /// [`person::HeadsFromBodies`] to take instead of the box's geometry; None from the others.
    pub model_head: Option<Vector2<f64>>,
}

/// Detections of one frame, by frame index.
pub type FrameDetections = (usize, Vec<Detection>);

/// Something a check found that the detector missed: the frame and the box `[x, y, w, h]`,
/// pixels ([`check::CrossCheck`]).
pub type Missed = (usize, [f64; 4]);

/// Finds people in frames, which come in order. Implementations keep whatever they learn (a
/// colour model, a background) between calls; one still learning may hold frames back and
/// return them later, so each call returns the frames it completed, in order.
pub trait Detector: Send {
    /// Takes the next frame. Errors mean the video cannot be processed with these settings.
    fn push(&mut self, frame: &FrameView) -> Result<Vec<FrameDetections>, crate::PluginError>;
    /// After the last frame: the frames still held back.
    fn finish(&mut self) -> Result<Vec<FrameDetections>, crate::PluginError> {
        Ok(Vec::new())
    }
    /// Numbers for the run report (what was learnt, say).
    fn summary(&self) -> Vec<(String, f64)> {
        Vec::new()
    }
    /// What a check run beside it found that it missed ([`check::CrossCheck`]), so far.
    fn missed(&self) -> Vec<Missed> {
        Vec::new()
    }
}

/// The detection error of a person detector across the image: vertical and horizontal
/// variances at knots of `t`, how far across the image the head lies (0 on the vertical centre
/// line, 1 at the left and right edges), linear between the knots and constant beyond the
/// first and last. The paper's model (section 4.1.3) has two knots: the vertical variance
/// constant, the horizontal one rising from the centre to the edges, where people are seen most
/// obliquely; a fitted model ([`error_fit`]) may have more.
#[derive(Clone, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct ErrorModel {
    /// By increasing `t`; at least one.
    pub knots: Vec<ErrorKnot>,
}

/// The variances at one place across the image.
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct ErrorKnot {
    pub t: f64,
    pub vertical_px2: f64,
    pub horizontal_px2: f64,
}

impl Default for ErrorModel {
    fn default() -> Self {
        ErrorModel::paper(10.0, 10.0, 20.0)
    }
}

impl ErrorModel {
    /// The paper's form: the vertical variance, the horizontal one at the centre and at the
    /// edges, px².
    pub fn paper(vertical_px2: f64, horizontal_centre_px2: f64, horizontal_edge_px2: f64) -> Self {
        ErrorModel {
            knots: vec![
                ErrorKnot {
                    t: 0.0,
                    vertical_px2,
                    horizontal_px2: horizontal_centre_px2,
                },
                ErrorKnot {
                    t: 1.0,
                    vertical_px2,
                    horizontal_px2: horizontal_edge_px2,
                },
            ],
        }
    }

    /// From rows `[t, vertical, horizontal]`; None unless the `t` rise strictly within [0, 1]
    /// and every variance is positive and finite.
    pub fn from_rows(rows: &[[f64; 3]]) -> Option<Self> {
        let ok = !rows.is_empty()
            && rows.iter().all(|r| {
                (0.0..=1.0).contains(&r[0]) && r[1..].iter().all(|v| v.is_finite() && *v > 0.0)
            })
            && rows.windows(2).all(|w| w[0][0] < w[1][0]);
        ok.then(|| ErrorModel {
            knots: rows
                .iter()
                .map(|r| ErrorKnot {
                    t: r[0],
                    vertical_px2: r[1],
                    horizontal_px2: r[2],
                })
                .collect(),
        })
    }

    /// Where across an image `width` pixels wide `u` lies: 0 on the vertical centre line, 1 at
    /// the left and right edges.
    pub fn across(u: f64, width: f64) -> f64 {
        let half = (width / 2.0).max(1.0);
        ((u - (width - 1.0) / 2.0).abs() / half).min(1.0)
    }

    /// (vertical, horizontal) variances at `t`, px².
    pub fn at(&self, t: f64) -> (f64, f64) {
        let k = &self.knots;
        let Some(first) = k.first() else {
            return (f64::NAN, f64::NAN);
        };
        if t <= first.t {
            return (first.vertical_px2, first.horizontal_px2);
        }
        for w in k.windows(2) {
            if t <= w[1].t {
                let f = (t - w[0].t) / (w[1].t - w[0].t);
                return (
                    w[0].vertical_px2 + f * (w[1].vertical_px2 - w[0].vertical_px2),
                    w[0].horizontal_px2 + f * (w[1].horizontal_px2 - w[0].horizontal_px2),
                );
            }
        }
        let last = k[k.len() - 1];
        (last.vertical_px2, last.horizontal_px2)
    }

    /// Covariance (px²) of a detection at `uv` in an image `width` pixels wide.
    pub fn cov(&self, uv: &Vector2<f64>, width: f64) -> Matrix2<f64> {
        let (v, h) = self.at(Self::across(uv.x, width));
        Matrix2::new(h, 0.0, 0.0, v)
    }
}

/// A person's head from the box around the whole body, seen from above: vertical lines meet at
/// the nadir's image, so the body lies along the line from the nadir through the box and the
/// head is at its far end, one body radius (`body_radius_px`) in from the box's edge.
pub fn head_from_box(bbox: &[f64; 4], nadir: &Vector2<f64>, body_radius_px: f64) -> Vector2<f64> {
    let c = Vector2::new(bbox[0] + bbox[2] / 2.0, bbox[1] + bbox[3] / 2.0);
    let away = c - nadir;
    let Some(d) = away.try_normalize(1e-9) else {
        return c;
    };
    // Half the box's extent along d.
    let half = d.x.abs() * bbox[2] / 2.0 + d.y.abs() * bbox[3] / 2.0;
    c + d * (half - body_radius_px).max(0.0)
}

#[cfg(test)]
mod model_tests {
    use super::*;

    #[test]
    fn error_model_rises_to_the_edges_and_head_lies_away_from_the_nadir() {
        let m = ErrorModel::default();
        let w = 3840.0;
        assert_eq!(
            m.cov(&Vector2::new((w - 1.0) / 2.0, 100.0), w)[(0, 0)],
            10.0
        );
        assert!((m.cov(&Vector2::new(0.0, 100.0), w)[(0, 0)] - 20.0).abs() < 0.01);
        assert!((m.cov(&Vector2::new(w * 0.75, 5.0), w)[(0, 0)] - 15.0).abs() < 0.01);
        assert_eq!(m.cov(&Vector2::new(0.0, 100.0), w)[(1, 1)], 10.0);
        // More knots: linear between them, constant beyond.
        let m =
            ErrorModel::from_rows(&[[0.2, 4.0, 20.0], [0.6, 2.0, 6.0], [1.0, 2.0, 5.0]]).unwrap();
        assert_eq!(m.at(0.0), (4.0, 20.0));
        let near = |a: (f64, f64), b: (f64, f64)| (a.0 - b.0).abs() + (a.1 - b.1).abs() < 1e-12;
        assert!(near(m.at(0.4), (3.0, 13.0)), "{:?}", m.at(0.4));
        assert!(near(m.at(0.8), (2.0, 5.5)), "{:?}", m.at(0.8));
        assert!(ErrorModel::from_rows(&[[0.5, 1.0, 1.0], [0.5, 1.0, 1.0]]).is_none());
        assert!(ErrorModel::from_rows(&[[0.0, 0.0, 1.0]]).is_none());
        assert!(ErrorModel::from_rows(&[]).is_none());
        // A body lying to the right of the nadir: the head at the right end, one radius in.
        let nadir = Vector2::new(100.0, 100.0);
        let h = head_from_box(&[300.0, 90.0, 60.0, 20.0], &nadir, 10.0);
        assert!((h - Vector2::new(350.0, 100.0)).norm() < 1e-9, "{h}");
        // Below the nadir: the box centre.
        let h = head_from_box(&[90.0, 90.0, 20.0, 20.0], &nadir, 10.0);
        assert!((h - Vector2::new(100.0, 100.0)).norm() < 1e-9);
    }
}
