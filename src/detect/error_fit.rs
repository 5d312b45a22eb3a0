//! A detector's error model fitted to annotated heads (the paper's section 4.1.3): detections are
//! paired with heads a person marked in some frames, and the vertical variance and the
//! horizontal variance at the image's centre and edges (an [`ErrorModel`]) are estimated from
//! the pairs' differences.
//!
//! The variances are mean squares about the annotation, bias included: what the covariance of a
//! detection must cover. Pairs further than the gate are not the same person; of the rest, the
//! few whose difference the fitted model puts beyond its 99.9 % region are dropped and the model
//! refitted (a stray pairing with a false alarm would otherwise dominate a mean of squares).

use std::collections::BTreeMap;
use std::path::Path;

use nalgebra::Vector2;
use serde::Serialize;

use super::{Detection, ErrorKnot, ErrorModel};
use crate::io::{FileCtx, FileError};

/// A head position in one frame: a detection or an annotation.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct FramePoint {
    pub frame: usize,
    /// Pixels, (0, 0) the centre of the top-left pixel.
    pub uv: Vector2<f64>,
}

/// One annotated head and the detection paired with it.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Pair {
    pub frame: usize,
    pub annotated: Vector2<f64>,
    pub detected: Vector2<f64>,
}

impl Pair {
    /// Detected minus annotated, pixels.
    pub fn error(&self) -> Vector2<f64> {
        self.detected - self.annotated
    }
}

/// The annotations' pairing with the detections.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Pairing {
    pub pairs: Vec<Pair>,
    /// Annotated heads with no detection within the gate (the detector's misses).
    pub unpaired_annotations: usize,
    /// Detections in the annotated frames paired with no annotation (false alarms, or people
    /// the annotator left out).
    pub unpaired_detections: usize,
    /// Frames annotated that have no detections at all.
    pub frames_without_detections: usize,
}

/// Pairs each annotation with a detection of its frame, closest pairs first, one to one, no
/// further apart than `gate_px`. Detections of frames nobody annotated are not looked at.
pub fn pair_annotations(
    detections: &BTreeMap<usize, Vec<Vector2<f64>>>,
    annotations: &BTreeMap<usize, Vec<Vector2<f64>>>,
    gate_px: f64,
) -> Pairing {
    let mut out = Pairing::default();
    for (&frame, heads) in annotations {
        let Some(dets) = detections.get(&frame).filter(|d| !d.is_empty()) else {
            out.frames_without_detections += 1;
            out.unpaired_annotations += heads.len();
            continue;
        };
        let mut candidates: Vec<(f64, usize, usize)> = Vec::new();
        for (i, a) in heads.iter().enumerate() {
            for (j, d) in dets.iter().enumerate() {
                let dist = (d - a).norm();
                if dist <= gate_px {
                    candidates.push((dist, i, j));
                }
            }
        }
        candidates.sort_by(|x, y| x.0.total_cmp(&y.0).then((x.1, x.2).cmp(&(y.1, y.2))));
        let mut head_used = vec![false; heads.len()];
        let mut det_used = vec![false; dets.len()];
        for (_, i, j) in candidates {
            if head_used[i] || det_used[j] {
                continue;
            }
            head_used[i] = true;
            det_used[j] = true;
            out.pairs.push(Pair {
                frame,
                annotated: heads[i],
                detected: dets[j],
            });
        }
        out.unpaired_annotations += head_used.iter().filter(|u| !**u).count();
        out.unpaired_detections += det_used.iter().filter(|u| !**u).count();
    }
    out
}

/// A fitted error model and how well the pairs determine it.
#[derive(Clone, Debug, Serialize, PartialEq)]
pub struct ErrorFit {
    pub form: Form,
    pub model: ErrorModel,
    /// Standard errors `[vertical, horizontal]` of each knot's variances, px².
    pub standard_error_px2: Vec<[f64; 2]>,
    /// Pairs used, and pairs dropped as beyond the fitted model's 99.9 % region.
    pub pairs_used: usize,
    pub pairs_dropped: usize,
    /// Mean difference, detected − annotated, `[horizontal, vertical]`, pixels: a systematic
    /// offset (a box's head end placed too far in, say, or an annotator clicking pixel corners).
    pub mean_error_px: [f64; 2],
}

/// The shape of the model fitted.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum Form {
    /// The paper's: one vertical variance, the horizontal one linear from the image's centre
    /// line to its left and right edges (`error_px2`).
    Paper,
    /// Both variances at up to five knots across the image (`error_profile_px2`).
    Profile,
}

impl ErrorFit {
    /// The project file's setting: `(error_px2, error_profile_px2)`, one of them given, in px²
    /// to two decimals (as the project file is written).
    pub fn setting(&self) -> (Option<[f64; 3]>, Option<Vec<[f64; 3]>>) {
        let r = |v: f64| format!("{v:.2}").parse::<f64>().unwrap_or(v);
        if self.form == Form::Paper {
            let (v, hc) = self.model.at(0.0);
            let (_, he) = self.model.at(1.0);
            return (Some([r(v), r(hc), r(he)]), None);
        }
        let rows = self
            .model
            .knots
            .iter()
            .map(|k| [r(k.t), r(k.vertical_px2), r(k.horizontal_px2)])
            .collect();
        (None, Some(rows))
    }

    /// The project file's line for [`ErrorFit::setting`].
    pub fn toml_line(&self) -> String {
        let row = |k: &[f64; 3]| format!("[{:.2}, {:.2}, {:.2}]", k[0], k[1], k[2]);
        match self.setting() {
            (Some(p), _) => format!("error_px2 = {}", row(&p)),
            (None, rows) => {
                let rows: Vec<String> = rows.unwrap_or_default().iter().map(row).collect();
                format!("error_profile_px2 = [{}]", rows.join(", "))
            }
        }
    }
}

/// The fewest pairs a fit is made from: fewer leave a variance uncertain by more than about a
/// third.
pub const MIN_PAIRS: usize = 20;

/// Knot counts tried, most first. The knots lie at quantiles of the pairs' places across the
/// image (none where no pair is: the model is constant beyond its first and last knot), and a
/// count is kept only if the pairs around every knot weigh at least [`MIN_KNOT_WEIGHT`] (a
/// variance from 30 squares is known to about a quarter) and every variance comes out positive.
const KNOT_COUNTS: [usize; 3] = [5, 3, 2];
const MIN_KNOT_WEIGHT: f64 = 30.0;

/// `count` knots at quantiles of `sorted_ts`, to two decimals; None when they coincide.
fn quantile_knots(sorted_ts: &[f64], count: usize) -> Option<Vec<f64>> {
    let n = sorted_ts.len();
    let knots: Vec<f64> = (0..count)
        .map(|i| {
            let q = sorted_ts[(i * (n - 1)) / (count - 1)];
            (q * 100.0).round() / 100.0
        })
        .collect();
    knots.windows(2).all(|w| w[0] < w[1]).then_some(knots)
}

/// The piecewise-linear basis at `t`: each knot's weight (one knot: a constant).
fn basis(knots: &[f64], t: f64) -> Vec<f64> {
    let mut b = vec![0.0; knots.len()];
    if knots.len() == 1 || t <= knots[0] {
        b[0] = 1.0;
        return b;
    }
    for k in 0..knots.len() - 1 {
        if t <= knots[k + 1] {
            let f = (t - knots[k]) / (knots[k + 1] - knots[k]);
            b[k] = 1.0 - f;
            b[k + 1] = f;
            return b;
        }
    }
    b[knots.len() - 1] = 1.0;
    b
}

/// Least squares of `ys` on the basis rows: the values and their standard errors (White's
/// heteroscedasticity-consistent form: a variance's squares scatter more where it is larger).
fn least_squares(rows: &[Vec<f64>], ys: &[f64]) -> Option<(Vec<f64>, Vec<f64>)> {
    use nalgebra::{DMatrix, DVector};
    let k = rows.first()?.len();
    let mut n = DMatrix::<f64>::zeros(k, k);
    let mut b = DVector::<f64>::zeros(k);
    for (r, &y) in rows.iter().zip(ys) {
        let r = DVector::from_column_slice(r);
        n += &r * r.transpose();
        b += &r * y;
    }
    let inv = n.try_inverse()?;
    let x = &inv * b;
    let mut meat = DMatrix::<f64>::zeros(k, k);
    for (r, &y) in rows.iter().zip(ys) {
        let r = DVector::from_column_slice(r);
        let e = y - r.dot(&x);
        meat += &r * r.transpose() * (e * e);
    }
    let cov = &inv * meat * &inv;
    let se = (0..k).map(|i| cov[(i, i)].max(0.0).sqrt()).collect();
    Some((x.iter().copied().collect(), se))
}

/// Why no error model could be fitted.
#[derive(Clone, Debug, PartialEq, thiserror::Error)]
pub enum FitError {
    #[error(
        "{paired} annotated heads paired with a detection; at least {MIN_PAIRS} are needed \
         (annotate more frames, or widen the gate if the detector is far off)"
    )]
    TooFewPairs { paired: usize },
    #[error(
        "only {agreeing} of the {paired} pairs agree with one error model; the annotations may \
         not be of the detected heads"
    )]
    Inconsistent { agreeing: usize, paired: usize },
}

/// Fits the model to `pairs` in an image `width_px` wide.
pub fn fit_error_model(pairs: &[Pair], width_px: f64, form: Form) -> Result<ErrorFit, FitError> {
    if pairs.len() < MIN_PAIRS {
        return Err(FitError::TooFewPairs {
            paired: pairs.len(),
        });
    }
    // 99.9 % of a two-dimensional Gaussian.
    const CHI2_2D_999: f64 = 13.815510557964274;
    let mut used: Vec<&Pair> = pairs.iter().collect();
    let mut fit = fit_once(&used, width_px, form);
    for _ in 0..20 {
        let keep: Vec<&Pair> = pairs
            .iter()
            .filter(|p| {
                let cov = fit.model.cov(&p.detected, width_px);
                let e = p.error();
                cov.try_inverse()
                    .is_some_and(|inv| (e.transpose() * inv * e)[0] <= CHI2_2D_999)
            })
            .collect();
        if keep.len() == used.len() {
            break;
        }
        if keep.len() < MIN_PAIRS {
            return Err(FitError::Inconsistent {
                agreeing: keep.len(),
                paired: pairs.len(),
            });
        }
        used = keep;
        fit = fit_once(&used, width_px, form);
    }
    fit.pairs_dropped = pairs.len() - used.len();
    Ok(fit)
}

fn fit_once(pairs: &[&Pair], width_px: f64, form: Form) -> ErrorFit {
    let n = pairs.len() as f64;
    let ts: Vec<f64> = pairs
        .iter()
        .map(|p| ErrorModel::across(p.detected.x, width_px))
        .collect();
    let dv2: Vec<f64> = pairs.iter().map(|p| p.error().y.powi(2)).collect();
    let du2: Vec<f64> = pairs.iter().map(|p| p.error().x.powi(2)).collect();
    // A variance of exactly zero (annotations copied from the detections) would make every
    // later pair infinitely unlikely: a floor of a hundredth of a pixel.
    let floor = 1e-4;
    if form == Form::Paper {
        return fit_paper(pairs, &ts, &dv2, &du2, floor);
    }
    let mut sorted = ts.clone();
    sorted.sort_by(f64::total_cmp);
    let candidates = KNOT_COUNTS
        .iter()
        .filter_map(|&k| quantile_knots(&sorted, k))
        .chain(std::iter::once(vec![0.0]));
    let mut chosen = None;
    for knots in candidates {
        let rows: Vec<Vec<f64>> = ts.iter().map(|&t| basis(&knots, t)).collect();
        let weight_ok =
            (0..knots.len()).all(|k| rows.iter().map(|r| r[k]).sum::<f64>() >= MIN_KNOT_WEIGHT);
        if knots.len() > 1 && !weight_ok {
            continue;
        }
        let (Some((v, sv)), Some((h, sh))) =
            (least_squares(&rows, &dv2), least_squares(&rows, &du2))
        else {
            continue;
        };
        if knots.len() > 1 && !v.iter().chain(&h).all(|x| *x > 0.0) {
            continue;
        }
        chosen = Some((knots, v, h, sv, sh));
        break;
    }
    // The constant always solves (its normal matrix is the count).
    let (knots, v, h, sv, sh) = chosen.expect("a constant model");
    let model = ErrorModel {
        knots: knots
            .iter()
            .enumerate()
            .map(|(k, &t)| ErrorKnot {
                t,
                vertical_px2: v[k].max(floor),
                horizontal_px2: h[k].max(floor),
            })
            .collect(),
    };
    let mean_err = pairs.iter().map(|p| p.error()).sum::<Vector2<f64>>() / n;
    ErrorFit {
        form,
        model,
        standard_error_px2: sv.iter().zip(&sh).map(|(a, b)| [*a, *b]).collect(),
        pairs_used: pairs.len(),
        pairs_dropped: 0,
        mean_error_px: [mean_err.x, mean_err.y],
    }
}

/// The paper's form: the vertical variance a mean of squares, the horizontal one a line from
/// the centre (knot 0) to the edges (knot 1), or a constant when the pairs do not tell the two
/// ends apart or the line dips to zero.
fn fit_paper(pairs: &[&Pair], ts: &[f64], dv2: &[f64], du2: &[f64], floor: f64) -> ErrorFit {
    let line: Vec<Vec<f64>> = ts.iter().map(|&t| basis(&[0.0, 1.0], t)).collect();
    let ends_weigh = (0..2).all(|k| line.iter().map(|r| r[k]).sum::<f64>() >= MIN_KNOT_WEIGHT);
    let one: Vec<Vec<f64>> = ts.iter().map(|_| vec![1.0]).collect();
    let (v, sv) = least_squares(&one, dv2).expect("a mean");
    let (h, sh) = ends_weigh
        .then(|| least_squares(&line, du2))
        .flatten()
        .filter(|(h, _)| h.iter().all(|x| *x > 0.0))
        .unwrap_or_else(|| {
            let (h, sh) = least_squares(&one, du2).expect("a mean");
            (vec![h[0]; 2], vec![sh[0]; 2])
        });
    let n = pairs.len() as f64;
    let mean_err = pairs.iter().map(|p| p.error()).sum::<Vector2<f64>>() / n;
    ErrorFit {
        form: Form::Paper,
        model: ErrorModel::paper(v[0].max(floor), h[0].max(floor), h[1].max(floor)),
        standard_error_px2: vec![[sv[0], sh[0]], [sv[0], sh[1]]],
        pairs_used: pairs.len(),
        pairs_dropped: 0,
        mean_error_px: [mean_err.x, mean_err.y],
    }
}

/// The header of `detections.csv`, the detections a run found (before tracking).
pub const DETECTIONS_HEADER: &str =
    "frame,u_px,v_px,var_u_px2,cov_uv_px2,var_v_px2,score,box_x_px,box_y_px,box_w_px,box_h_px";

/// The rows of `detections.csv` for consecutive frames from `first_frame` (a chunk's).
pub fn write_detection_rows(
    w: &mut dyn std::io::Write,
    first_frame: usize,
    detections: &[Vec<Detection>],
) -> std::io::Result<()> {
    use crate::text::fixed::Fixed;
    use std::fmt::Write;
    let mut out = crate::text::Pieces::new(w);
    for (k, dets) in detections.iter().enumerate() {
        let frame = first_frame + k;
        for d in dets {
            let _ = writeln!(
                out.s,
                "{frame},{},{},{},{},{},{},{},{},{},{}",
                Fixed::<3>(d.uv.x),
                Fixed::<3>(d.uv.y),
                Fixed::<3>(d.cov[(0, 0)]),
                Fixed::<3>(d.cov[(0, 1)]),
                Fixed::<3>(d.cov[(1, 1)]),
                Fixed::<3>(d.score),
                Fixed::<2>(d.bbox[0]),
                Fixed::<2>(d.bbox[1]),
                Fixed::<2>(d.bbox[2]),
                Fixed::<2>(d.bbox[3]),
            );
        }
        out.done_piece()?;
    }
    out.finish()
}

/// The most heads in one frame (a 4K frame of a dense crowd holds a few hundred): pairing is
/// quadratic in them.
pub const MAX_HEADS_PER_FRAME: usize = 2000;
/// The most annotated heads in all.
pub const MAX_ANNOTATIONS: usize = 1_000_000;

/// Head positions per frame from a CSV with a header naming `columns` (frame, x, y); other
/// columns are ignored. Only the frames in `keep` are kept when it is given; at most
/// `max_rows` rows are read. `what` says what the file should be, for messages.
pub fn read_frame_points(
    path: &Path,
    columns: [&str; 3],
    what: &str,
    keep: Option<&std::collections::BTreeSet<usize>>,
    max_rows: usize,
) -> Result<BTreeMap<usize, Vec<Vector2<f64>>>, FileError> {
    let text = FileCtx { path }.read_text(what)?;
    parse_frame_points(path, &text, columns, keep, max_rows)
}

/// The feet ends of a run's detections (its `detections.csv`): each box's bottom centre, by
/// frame, in the frames of `keep`.
pub fn read_box_feet(
    path: &Path,
    keep: Option<&std::collections::BTreeSet<usize>>,
) -> Result<BTreeMap<usize, Vec<Vector2<f64>>>, FileError> {
    let text = FileCtx { path }.read_text("a run's detections.csv")?;
    parse_box_feet(path, &text, keep)
}

/// [`read_box_feet`] on text.
pub fn parse_box_feet(
    path: &Path,
    text: &str,
    keep: Option<&std::collections::BTreeSet<usize>>,
) -> Result<BTreeMap<usize, Vec<Vector2<f64>>>, FileError> {
    parse_points(
        path,
        text,
        &["frame", "box_x_px", "box_y_px", "box_w_px", "box_h_px"],
        keep,
        usize::MAX,
        |v| Vector2::new(v[0] + v[2] / 2.0, v[1] + v[3]),
    )
}

/// [`read_frame_points`] on text; `path` names the file in messages.
pub fn parse_frame_points(
    path: &Path,
    text: &str,
    columns: [&str; 3],
    keep: Option<&std::collections::BTreeSet<usize>>,
    max_rows: usize,
) -> Result<BTreeMap<usize, Vec<Vector2<f64>>>, FileError> {
    parse_points(path, text, &columns, keep, max_rows, |v| {
        Vector2::new(v[0], v[1])
    })
}

/// Rows of `frame` and numbers, each row's point made from its numbers by `point`.
fn parse_points(
    path: &Path,
    text: &str,
    columns: &[&str],
    keep: Option<&std::collections::BTreeSet<usize>>,
    max_rows: usize,
    point: impl Fn(&[f64]) -> Vector2<f64>,
) -> Result<BTreeMap<usize, Vec<Vector2<f64>>>, FileError> {
    let ctx = FileCtx { path };
    let mut out: BTreeMap<usize, Vec<Vector2<f64>>> = BTreeMap::new();
    let mut count = 0usize;
    let rows = crate::io::csv_rows(ctx, text, columns, |line, f, idx, _| {
        count += 1;
        if count > max_rows {
            return Err(ctx.at(
                line,
                format!("more than {max_rows} rows; is it the right file?"),
            ));
        }
        let frame = ctx.whole(f[idx[0]], line, columns[0])? as usize;
        let mut values = Vec::with_capacity(columns.len() - 1);
        for k in 1..columns.len() {
            values.push(ctx.number(f[idx[k]], line, columns[k])?);
        }
        let uv = point(&values);
        if keep.is_some_and(|k| !k.contains(&frame)) {
            return Ok(());
        }
        let heads = out.entry(frame).or_default();
        if heads.len() == MAX_HEADS_PER_FRAME {
            return Err(ctx.at(
                line,
                format!("more than {MAX_HEADS_PER_FRAME} heads in frame {frame}"),
            ));
        }
        heads.push(uv);
        Ok(())
    })?;
    if rows == 0 {
        return Err(ctx.err(None, None, "no rows below the header"));
    }
    Ok(out)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn box_feet_are_the_bottom_centres_of_the_kept_frames() {
        let text = "frame,u_px,v_px,var_u_px2,cov_uv_px2,var_v_px2,score,box_x_px,box_y_px,box_w_px,box_h_px\n\
                    0,322.9,134.3,13.5,0.0,10.0,0.9,312.0,101.0,20.0,38.5\n\
                    3,415.6,199.6,17.3,0.0,10.0,0.7,399.0,152.5,30.5,52.0\n";
        let keep: std::collections::BTreeSet<usize> = [3].into_iter().collect();
        let feet = parse_box_feet(Path::new("d.csv"), text, Some(&keep)).unwrap();
        assert_eq!(feet.len(), 1);
        assert_eq!(feet[&3], vec![Vector2::new(414.25, 204.5)]);
        let all = parse_box_feet(Path::new("d.csv"), text, None).unwrap();
        assert_eq!(all[&0], vec![Vector2::new(322.0, 139.5)]);
        // A detections file without boxes (a hat detector's) says which column is missing.
        let e = parse_box_feet(Path::new("d.csv"), "frame,u_px,v_px\n0,1,2\n", None).unwrap_err();
        assert!(e.to_string().contains("box_x_px"), "{e}");
    }
    use rand::{RngExt, SeedableRng};
    use rand_distr::{Distribution, Normal};

    /// Pairs drawn from `model` at random places in a `w`-wide image, and a few stray ones.
    fn pairs_from(model: &ErrorModel, w: f64, n: usize, seed: u64) -> Vec<Pair> {
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(seed);
        let z = Normal::new(0.0, 1.0).unwrap();
        (0..n)
            .map(|k| {
                let a = Vector2::new(rng.random_range(0.0..w), rng.random_range(0.0..1080.0));
                let cov = model.cov(&a, w);
                let e = Vector2::new(
                    cov[(0, 0)].sqrt() * z.sample(&mut rng),
                    cov[(1, 1)].sqrt() * z.sample(&mut rng),
                );
                Pair {
                    frame: k,
                    annotated: a,
                    detected: a + e,
                }
            })
            .collect()
    }

    /// Each knot of `fit` within 4 standard errors of `truth` there, those a tenth of the value
    /// at most.
    fn assert_near(fit: &ErrorFit, truth: &ErrorModel) {
        for (k, se) in fit.model.knots.iter().zip(&fit.standard_error_px2) {
            let (v, h) = truth.at(k.t);
            for (got, want, se) in [(k.vertical_px2, v, se[0]), (k.horizontal_px2, h, se[1])] {
                assert!(
                    (got - want).abs() < 4.0 * se,
                    "t {}: {got} vs {want} ± {se}",
                    k.t
                );
                assert!(se < 0.12 * want, "t {}: {se}", k.t);
            }
        }
    }

    #[test]
    fn recovers_the_papers_model_and_drops_strays() {
        let truth = ErrorModel::paper(6.0, 8.0, 24.0);
        let w = 1920.0;
        let mut pairs = pairs_from(&truth, w, 4000, 3);
        // Five detections of someone else, 18 px off.
        for p in pairs.iter_mut().take(5) {
            p.detected = p.annotated + Vector2::new(18.0, 0.0);
        }
        let fit = fit_error_model(&pairs, w, Form::Profile).unwrap();
        assert_eq!(fit.model.knots.len(), 5);
        assert!(fit.pairs_dropped >= 5, "{fit:?}");
        assert_near(&fit, &truth);
        assert!(
            fit.toml_line().starts_with("error_profile_px2 = [[0.00, "),
            "{}",
            fit.toml_line()
        );
        // The paper's form, from the same pairs.
        let fit = fit_error_model(&pairs, w, Form::Paper).unwrap();
        assert_eq!(fit.model.knots.len(), 2);
        assert!(fit.pairs_dropped >= 5, "{fit:?}");
        assert_near(&fit, &truth);
        assert!(
            fit.toml_line().starts_with("error_px2 = ["),
            "{}",
            fit.toml_line()
        );
    }

    #[test]
    fn recovers_an_error_largest_below_the_camera() {
        // A head placed from a box, least certain where the body is seen end-on.
        let truth = ErrorModel::from_rows(&[
            [0.0, 15.0, 20.0],
            [0.25, 4.0, 8.0],
            [0.5, 3.0, 6.0],
            [1.0, 3.0, 5.0],
        ])
        .unwrap();
        let w = 1920.0;
        let fit = fit_error_model(&pairs_from(&truth, w, 6000, 5), w, Form::Profile).unwrap();
        assert_eq!(fit.model.knots.len(), 5);
        assert_near(&fit, &truth);
    }

    #[test]
    fn few_pairs_or_pairs_in_one_place_give_fewer_knots() {
        let truth = ErrorModel::paper(5.0, 9.0, 9.0);
        let w = 1920.0;
        // 150 pairs: not 30 around each of five knots, but around each of three.
        let fit = fit_error_model(&pairs_from(&truth, w, 150, 4), w, Form::Profile).unwrap();
        assert_eq!(fit.model.knots.len(), 3, "{fit:?}");
        // Everyone within a pixel of the centre line: one variance for the whole image.
        let mut pairs = pairs_from(&truth, w, 500, 4);
        for p in &mut pairs {
            let e = p.error();
            p.annotated.x = 959.5 + p.annotated.x / w;
            p.detected = p.annotated + e;
        }
        let fit = fit_error_model(&pairs, w, Form::Profile).unwrap();
        assert_eq!(fit.model.knots.len(), 1, "{fit:?}");
        assert_near(&fit, &truth);
        // The paper's form: one horizontal variance for both ends.
        let fit = fit_error_model(&pairs, w, Form::Paper).unwrap();
        assert_eq!(fit.model.at(0.0), fit.model.at(1.0));
        assert_near(&fit, &truth);
        // Too few pairs: a clear error, not a guess.
        let e = fit_error_model(&pairs[..5], w, Form::Paper).unwrap_err();
        assert!(e.to_string().contains("at least 20"), "{e}");
    }

    #[test]
    fn annotations_pair_with_the_nearest_detection_once_within_the_gate() {
        let dets = BTreeMap::from([
            (
                0,
                vec![
                    Vector2::new(100.0, 100.0),
                    Vector2::new(104.0, 100.0),
                    Vector2::new(500.0, 500.0),
                ],
            ),
            (5, vec![Vector2::new(10.0, 10.0)]),
        ]);
        let ann = BTreeMap::from([
            (
                0,
                vec![Vector2::new(103.0, 100.0), Vector2::new(101.0, 100.0)],
            ),
            (1, vec![Vector2::new(0.0, 0.0)]),
            (5, vec![Vector2::new(50.0, 10.0)]),
        ]);
        let p = pair_annotations(&dets, &ann, 20.0);
        assert_eq!(p.pairs.len(), 2);
        assert!(
            p.pairs.iter().all(|q| q.error().norm() <= 1.0 + 1e-12),
            "{p:?}"
        );
        assert_eq!(p.unpaired_annotations, 2);
        assert_eq!(p.unpaired_detections, 2);
        assert_eq!(p.frames_without_detections, 1);
    }

    #[test]
    fn detections_csv_reads_back_as_frame_points() {
        let d = Detection {
            uv: Vector2::new(10.25, 20.5),
            cov: nalgebra::Matrix2::new(9.0, 0.0, 0.0, 5.0),
            bbox: [1.0, 2.0, 3.0, 4.0],
            area_px: 12.0,
            score: 1.0,
            model_head: None,
        };
        // As the export writes it: the header, then chunk by chunk from each one's first frame.
        let text = crate::text::text_of(|w| {
            writeln!(w, "{DETECTIONS_HEADER}")?;
            write_detection_rows(w, 0, &[vec![d.clone()], vec![]])?;
            write_detection_rows(w, 2, &[vec![d.clone(), d]])
        });
        let pts = parse_frame_points(
            Path::new("d.csv"),
            &text,
            ["frame", "u_px", "v_px"],
            None,
            10,
        )
        .unwrap();
        assert_eq!(pts[&0], vec![Vector2::new(10.25, 20.5)]);
        assert_eq!(pts[&2].len(), 2);
        assert!(!pts.contains_key(&1));
        let e = parse_frame_points(
            Path::new("a.csv"),
            "frame,x_px\n1,2\n",
            ["frame", "x_px", "y_px"],
            None,
            10,
        )
        .unwrap_err()
        .to_string();
        assert!(e.contains("a.csv") && e.contains("y_px"), "{e}");
        let e = parse_frame_points(
            Path::new("a.csv"),
            "frame,x_px,y_px\n1.5,2,3\n",
            ["frame", "x_px", "y_px"],
            None,
            10,
        )
        .unwrap_err()
        .to_string();
        assert!(e.contains("a.csv:2"), "{e}");
        // Only the frames asked for; bounded rows and heads per frame.
        let keep = std::collections::BTreeSet::from([2]);
        let only = parse_frame_points(
            Path::new("d.csv"),
            &text,
            ["frame", "u_px", "v_px"],
            Some(&keep),
            10,
        )
        .unwrap();
        assert_eq!(only.keys().collect::<Vec<_>>(), [&2]);
        let e = parse_frame_points(
            Path::new("d.csv"),
            &text,
            ["frame", "u_px", "v_px"],
            None,
            2,
        )
        .unwrap_err()
        .to_string();
        assert!(
            e.contains("d.csv:4") && e.contains("more than 2 rows"),
            "{e}"
        );
        let crowded = format!(
            "frame,x_px,y_px\n{}",
            "0,1,1\n".repeat(MAX_HEADS_PER_FRAME + 1)
        );
        let e = parse_frame_points(
            Path::new("a.csv"),
            &crowded,
            ["frame", "x_px", "y_px"],
            None,
            1 << 20,
        )
        .unwrap_err()
        .to_string();
        assert!(e.contains("heads in frame 0"), "{e}");
    }
}
