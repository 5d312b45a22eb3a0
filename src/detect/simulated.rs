//! A simulated person detector (pure), for tests and the demo: the simulator's true body boxes
//! (`truth/boxes.csv`) with localisation noise, misses and false alarms (people's shadows and
//! boxes on empty ground), written as a MOTChallenge detection file like an external
//! detector's.

use std::fmt::Write as _;
use std::path::Path;

use rand::{RngExt, SeedableRng};
use rand_chacha::ChaCha8Rng;
use rand_distr::{Distribution, Normal};

use crate::io::{FileCtx, FileError};

/// One row of `truth/boxes.csv`.
#[derive(Clone, Debug, PartialEq)]
pub struct TruthBox {
    pub frame: usize,
    pub person: usize,
    /// A body, or that body's shadow.
    pub shadow: bool,
    /// `[x, y, w, h]`, pixels.
    pub bbox: [f64; 4],
}

/// Reads `truth/boxes.csv` (`frame,person,kind,x,y,w,h`).
pub fn read_truth_boxes(path: &Path) -> Result<Vec<TruthBox>, FileError> {
    let text = FileCtx { path }.read_text("the simulator's truth boxes")?;
    parse_truth_boxes(path, &text)
}

/// [`read_truth_boxes`] on text; `path` names the file in messages.
pub fn parse_truth_boxes(path: &Path, text: &str) -> Result<Vec<TruthBox>, FileError> {
    let ctx = FileCtx { path };
    let mut lines = text.lines().enumerate();
    match lines.next() {
        Some((_, h)) if h.trim() == "frame,person,kind,x,y,w,h" => {}
        _ => {
            return Err(ctx.at(1, "expected the header 'frame,person,kind,x,y,w,h'"));
        }
    }
    let mut out = Vec::new();
    for (i, l) in lines {
        let line = i + 1;
        if l.trim().is_empty() {
            continue;
        }
        let f: Vec<&str> = l.split(',').map(str::trim).collect();
        if f.len() != 7 {
            return Err(ctx.at(line, format!("expected 7 fields, found {}", f.len())));
        }
        let shadow = match f[2] {
            "body" => false,
            "shadow" => true,
            k => {
                return Err(ctx.at(
                    line,
                    format!("field 'kind': expected 'body' or 'shadow', found '{k}'"),
                ));
            }
        };
        let n = |k: usize, name: &str| ctx.number(f[k], line, name);
        out.push(TruthBox {
            frame: ctx.whole(f[0], line, "frame")? as usize,
            person: ctx.whole(f[1], line, "person")? as usize,
            shadow,
            bbox: [
                n(3, "x")?,
                n(4, "y")?,
                ctx.positive(f[5], line, "w")?,
                ctx.positive(f[6], line, "h")?,
            ],
        });
    }
    Ok(out)
}

/// How the simulated detector errs.
#[derive(Clone, Debug)]
pub struct SimulatedDetector {
    /// Standard deviation of each box edge, pixels.
    pub edge_sd_px: f64,
    /// Probability that a person in view is not detected in a frame.
    pub miss_rate: f64,
    /// False alarms per true detection.
    pub false_alarm_rate: f64,
    /// Share of the false alarms that box a person's shadow (the rest box empty ground).
    pub shadow_share: f64,
    pub seed: u64,
}

impl Default for SimulatedDetector {
    fn default() -> Self {
        SimulatedDetector {
            edge_sd_px: 2.0,
            miss_rate: 0.05,
            false_alarm_rate: 0.10,
            shadow_share: 0.5,
            seed: 1,
        }
    }
}

/// A detector's box: frame, `[x, y, w, h]` pixels, score.
pub type ScoredBox = (usize, [f64; 4], f64);

impl SimulatedDetector {
    /// Detections for every frame of the truth, in frame order, inside an image of `size`.
    pub fn detect(&self, truth: &[TruthBox], size: (f64, f64)) -> Vec<ScoredBox> {
        let mut rng = ChaCha8Rng::seed_from_u64(self.seed);
        let edge = Normal::new(0.0, self.edge_sd_px.max(0.0)).expect("finite sd");
        let mut out = Vec::new();
        let bodies: Vec<&TruthBox> = truth.iter().filter(|t| !t.shadow).collect();
        let shadows: Vec<&TruthBox> = truth.iter().filter(|t| t.shadow).collect();
        // A typical body box, for false alarms on empty ground.
        let typical = bodies
            .iter()
            .map(|b| (b.bbox[2], b.bbox[3]))
            .fold((0.0, 0.0, 0usize), |a, (w, h)| (a.0 + w, a.1 + h, a.2 + 1));
        let typical = if typical.2 > 0 {
            (typical.0 / typical.2 as f64, typical.1 / typical.2 as f64)
        } else {
            (40.0, 40.0)
        };
        let clip = |b: [f64; 4]| -> Option<[f64; 4]> {
            let (x0, y0) = (b[0].max(-0.5), b[1].max(-0.5));
            let (x1, y1) = (
                (b[0] + b[2]).min(size.0 - 0.5),
                (b[1] + b[3]).min(size.1 - 0.5),
            );
            (x1 - x0 >= 2.0 && y1 - y0 >= 2.0).then_some([x0, y0, x1 - x0, y1 - y0])
        };
        let noisy = |b: &[f64; 4], rng: &mut ChaCha8Rng| {
            let (x0, y0) = (b[0] + edge.sample(rng), b[1] + edge.sample(rng));
            let (x1, y1) = (
                b[0] + b[2] + edge.sample(rng),
                b[1] + b[3] + edge.sample(rng),
            );
            clip([x0, y0, x1 - x0, y1 - y0])
        };
        let last = truth.iter().map(|t| t.frame).max().unwrap_or(0);
        let (mut bi, mut si) = (0, 0);
        for frame in 0..=last {
            let start = bi;
            while bi < bodies.len() && bodies[bi].frame == frame {
                bi += 1;
            }
            let shadow_start = si;
            while si < shadows.len() && shadows[si].frame == frame {
                si += 1;
            }
            let here = &bodies[start..bi];
            let here_shadows = &shadows[shadow_start..si];
            for b in here {
                if rng.random::<f64>() < self.miss_rate {
                    continue;
                }
                if let Some(bx) = noisy(&b.bbox, &mut rng) {
                    out.push((frame, bx, 0.5 + 0.5 * rng.random::<f64>()));
                }
            }
            for _ in 0..here.len() {
                if rng.random::<f64>() >= self.false_alarm_rate {
                    continue;
                }
                let score = 0.3 + 0.4 * rng.random::<f64>();
                let bx = if rng.random::<f64>() < self.shadow_share && !here_shadows.is_empty() {
                    let s = here_shadows[rng.random_range(0..here_shadows.len())];
                    noisy(&s.bbox, &mut rng)
                } else {
                    let (w, h) = typical;
                    clip([
                        rng.random::<f64>() * (size.0 - w),
                        rng.random::<f64>() * (size.1 - h),
                        w,
                        h,
                    ])
                };
                if let Some(bx) = bx {
                    out.push((frame, bx, score));
                }
            }
        }
        out
    }
}

/// Boxes as a MOTChallenge detection file (`frame,-1,left,top,width,height,score,-1,-1,-1`,
/// frames from 1).
pub fn mot_text(boxes: &[ScoredBox]) -> String {
    let mut s = String::new();
    for (f, b, score) in boxes {
        let _ = writeln!(
            s,
            "{},-1,{:.2},{:.2},{:.2},{:.2},{:.3},-1,-1,-1",
            f + 1,
            b[0],
            b[1],
            b[2],
            b[3],
            score
        );
    }
    s
}

#[cfg(test)]
mod tests {
    use super::*;

    fn truth() -> Vec<TruthBox> {
        (0..200)
            .flat_map(|f| {
                (0..10).flat_map(move |p| {
                    let x = 50.0 * p as f64 + f as f64;
                    [
                        TruthBox {
                            frame: f,
                            person: p,
                            shadow: false,
                            bbox: [x, 100.0, 30.0, 40.0],
                        },
                        TruthBox {
                            frame: f,
                            person: p,
                            shadow: true,
                            bbox: [x + 20.0, 130.0, 30.0, 20.0],
                        },
                    ]
                })
            })
            .collect()
    }

    #[test]
    fn misses_and_false_alarms_at_the_rates_asked() {
        let d = SimulatedDetector::default();
        let boxes = d.detect(&truth(), (1000.0, 600.0));
        let (true_hits, false_alarms) = boxes.iter().fold((0, 0), |(t, f), b| {
            if b.2 >= 0.5 && (b.1[1] - 100.0).abs() < 10.0 && (b.1[3] - 40.0).abs() < 10.0 {
                (t + 1, f)
            } else {
                (t, f + 1)
            }
        });
        let n = 2000.0;
        assert!(
            (f64::from(true_hits) / n - 0.95).abs() < 0.02,
            "{true_hits} hits"
        );
        assert!(
            (f64::from(false_alarms) / n - 0.10).abs() < 0.02,
            "{false_alarms} false alarms"
        );
        let text = mot_text(&boxes);
        assert!(text.starts_with("1,-1,"));
        assert_eq!(text.lines().count(), boxes.len());
    }

    #[test]
    fn truth_boxes_errors_name_the_line() {
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("boxes.csv");
        std::fs::write(
            &p,
            "frame,person,kind,x,y,w,h\n0,1,body,1,2,3,4\n1,1,hat,1,2,3,4\n",
        )
        .unwrap();
        let e = read_truth_boxes(&p).unwrap_err().to_string();
        assert!(e.contains(":3:") && e.contains("kind"), "{e}");
    }
}
