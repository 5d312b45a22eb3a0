//! Which surveyed point each target found in an image is, from the layout alone: the targets lie
//! on the ground, so the ground-to-image map is near a similarity seen from above (a mirror
//! image: the image's rows run down, the survey's north up) and a homography in any view. Every
//! pairing of two targets with two surveyed points gives a similarity; the best supported ones
//! are refined to a homography over all the targets they explain, and the result is kept only
//! when no other pairing explains nearly as many targets differently.

use nalgebra::{Matrix3, Vector2, Vector3};

use crate::estimate::homography::homography_dlt;

/// `(point, target, distance in pixels)` pairs.
type Pairs = Vec<(usize, usize, f64)>;

/// A pairing refined: its pairs, the homography and the residuals' RMS, pixels.
type Refined = (Pairs, Matrix3<f64>, f64);

/// How identification is done and judged.
#[derive(Clone, Debug)]
pub struct LayoutSettings {
    /// Where the image's top points on the ground, as a bearing (degrees from north through
    /// east) and a tolerance, when known roughly (a drone's heading): rules out the pairings a
    /// symmetric layout would otherwise allow.
    pub heading_deg: Option<(f64, f64)>,
    /// A target explains a surveyed point when within this of its place under the homography,
    /// pixels (plus 3 σ of the target's centre).
    pub gate_px: f64,
    /// Under a first similarity from two pairs, the gate is this share of the two targets'
    /// distance apart (perspective bends the rest), at least `gate_px`.
    pub coarse_gate_share: f64,
}

impl Default for LayoutSettings {
    fn default() -> Self {
        LayoutSettings {
            heading_deg: None,
            gate_px: 3.0,
            coarse_gate_share: 0.06,
        }
    }
}

/// A target identified: the surveyed point's index, the target's, and its distance from where
/// the fitted map puts the point, pixels.
#[derive(Clone, Debug, PartialEq)]
pub struct Identified {
    pub point: usize,
    pub target: usize,
    pub residual_px: f64,
}

/// The outcome for one image.
#[derive(Clone, Debug, PartialEq)]
pub enum Identification {
    /// The targets identified, and the ground-to-image homography they fit.
    Found {
        identified: Vec<Identified>,
        ground_to_image: Matrix3<f64>,
    },
    /// Nothing written: why (too few targets, or another pairing explains as many).
    NotIdentified(String),
}

/// `(a + bi)`, as plain pairs: a ground point's mirror image under `α · conj(p) + β`.
#[derive(Clone, Copy, Debug)]
struct Similarity {
    alpha: (f64, f64),
    beta: (f64, f64),
}

impl Similarity {
    /// Through `pa → qa` and `pb → qb`; None when the two ground points coincide.
    fn through(
        pa: &Vector2<f64>,
        pb: &Vector2<f64>,
        qa: &Vector2<f64>,
        qb: &Vector2<f64>,
    ) -> Option<Self> {
        let dp = (pb.x - pa.x, -(pb.y - pa.y)); // conj
        let dq = (qb.x - qa.x, qb.y - qa.y);
        let n = dp.0 * dp.0 + dp.1 * dp.1;
        if n < 1e-12 {
            return None;
        }
        // α = dq / dp
        let alpha = (
            (dq.0 * dp.0 + dq.1 * dp.1) / n,
            (dq.1 * dp.0 - dq.0 * dp.1) / n,
        );
        let cp = (pa.x, -pa.y);
        let beta = (
            qa.x - (alpha.0 * cp.0 - alpha.1 * cp.1),
            qa.y - (alpha.0 * cp.1 + alpha.1 * cp.0),
        );
        Some(Similarity { alpha, beta })
    }

    fn apply(&self, p: &Vector2<f64>) -> Vector2<f64> {
        let (x, y) = (p.x, -p.y);
        Vector2::new(
            self.alpha.0 * x - self.alpha.1 * y + self.beta.0,
            self.alpha.0 * y + self.alpha.1 * x + self.beta.1,
        )
    }

    /// The bearing on the ground of the image's up direction, degrees from north.
    fn heading_deg(&self) -> f64 {
        // Image up (0, -1) = α · conj(d) ⇒ conj(d) = -i / α.
        let n = self.alpha.0 * self.alpha.0 + self.alpha.1 * self.alpha.1;
        let c = (-self.alpha.1 / n, -self.alpha.0 / n); // -i / α
        let d = (c.0, -c.1);
        d.0.atan2(d.1).to_degrees()
    }
}

fn apply_h(h: &Matrix3<f64>, p: &Vector2<f64>) -> Option<Vector2<f64>> {
    let q = h * Vector3::new(p.x, p.y, 1.0);
    (q.z.abs() > 1e-12).then(|| Vector2::new(q.x / q.z, q.y / q.z))
}

/// Each surveyed point's nearest target within its gate, one target per point (the nearer
/// point wins): `(point, target, distance)`.
fn assign(
    predicted: &[Option<Vector2<f64>>],
    targets: &[(Vector2<f64>, f64)],
    gate: &dyn Fn(usize) -> f64,
) -> Vec<(usize, usize, f64)> {
    let mut pairs: Vec<(usize, usize, f64)> = Vec::new();
    for (p, q) in predicted.iter().enumerate() {
        let Some(q) = q else { continue };
        let best = targets
            .iter()
            .enumerate()
            .map(|(t, (uv, _))| (t, (uv - q).norm()))
            .filter(|(t, d)| *d <= gate(*t))
            .min_by(|a, b| a.1.total_cmp(&b.1));
        if let Some((t, d)) = best {
            pairs.push((p, t, d));
        }
    }
    pairs.sort_by(|a, b| a.2.total_cmp(&b.2));
    let mut used = vec![false; targets.len()];
    pairs.retain(|(_, t, _)| !std::mem::replace(&mut used[*t], true));
    pairs.sort_by_key(|x| x.0);
    pairs
}

/// A pairing refined to a homography: the assignment it ends with and its residuals' RMS.
fn refine(
    ground: &[Vector2<f64>],
    targets: &[(Vector2<f64>, f64)],
    start: Vec<(usize, usize, f64)>,
    s: &LayoutSettings,
) -> Option<Refined> {
    let mut pairs = start;
    let mut h = None;
    for _ in 0..4 {
        if pairs.len() < 4 {
            return None;
        }
        let src: Vec<_> = pairs.iter().map(|(p, _, _)| ground[*p]).collect();
        let dst: Vec<_> = pairs.iter().map(|(_, t, _)| targets[*t].0).collect();
        let hm = homography_dlt(&src, &dst).ok()?;
        let predicted: Vec<_> = ground.iter().map(|g| apply_h(&hm, g)).collect();
        let next = assign(&predicted, targets, &|t| s.gate_px + 3.0 * targets[t].1);
        h = Some(hm);
        let same = next
            .iter()
            .map(|x| (x.0, x.1))
            .eq(pairs.iter().map(|x| (x.0, x.1)));
        pairs = next;
        if same {
            break;
        }
    }
    let h = h?;
    if pairs.len() < 4 {
        return None;
    }
    let rms = (pairs.iter().map(|x| x.2 * x.2).sum::<f64>() / pairs.len() as f64).sqrt();
    Some((pairs, h, rms))
}

/// Which surveyed point (`ground`: east, north in a local metric frame) each target (`targets`:
/// centre and σ, pixels) is. At least five targets must agree (four fit any homography), or
/// four that a similarity fits.
pub fn identify_by_layout(
    ground: &[Vector2<f64>],
    targets: &[(Vector2<f64>, f64)],
    s: &LayoutSettings,
) -> Identification {
    // A view from aside bends the layout more than the first similarity's gate allows: when
    // nothing is found, again with wider gates (the homography and its checks still decide).
    // An ambiguous layout stays refused: wider gates only let more assignments compete.
    let mut result = identify_once(ground, targets, s);
    for widen in [2.5, 5.0] {
        match &result {
            Identification::NotIdentified(why) if !why.starts_with("ambiguous") => {
                let wider = LayoutSettings {
                    coarse_gate_share: s.coarse_gate_share * widen,
                    ..s.clone()
                };
                if let found @ Identification::Found { .. } = identify_once(ground, targets, &wider)
                {
                    result = found;
                }
            }
            _ => break,
        }
    }
    result
}

fn identify_once(
    ground: &[Vector2<f64>],
    targets: &[(Vector2<f64>, f64)],
    s: &LayoutSettings,
) -> Identification {
    if targets.len() < 4 || ground.len() < 4 {
        return Identification::NotIdentified(format!(
            "{} targets found and {} surveyed points: at least four of each are needed to tell them apart by their layout",
            targets.len(),
            ground.len()
        ));
    }
    // Every pairing of two targets with two points, scored by how many targets its
    // similarity explains.
    let mut scored: Vec<(usize, f64, Pairs)> = Vec::new();
    for i in 0..targets.len() {
        for j in 0..targets.len() {
            if i == j {
                continue;
            }
            let (qi, qj) = (targets[i].0, targets[j].0);
            let gate = (s.coarse_gate_share * (qj - qi).norm()).max(s.gate_px);
            for a in 0..ground.len() {
                for b in a + 1..ground.len() {
                    let Some(sim) = Similarity::through(&ground[a], &ground[b], &qi, &qj) else {
                        continue;
                    };
                    if let Some((bearing, tol)) = s.heading_deg {
                        let d = (sim.heading_deg() - bearing + 540.0).rem_euclid(360.0) - 180.0;
                        if d.abs() > tol {
                            continue;
                        }
                    }
                    let predicted: Vec<_> = ground.iter().map(|g| Some(sim.apply(g))).collect();
                    let pairs = assign(&predicted, targets, &|_| gate);
                    if pairs.len() >= 3 {
                        let cost: f64 = pairs.iter().map(|x| x.2 * x.2).sum();
                        scored.push((pairs.len(), cost, pairs));
                    }
                }
            }
        }
    }
    scored.sort_by(|a, b| b.0.cmp(&a.0).then(a.1.total_cmp(&b.1)));
    // The distinct assignments among the best, each refined.
    let mut refined: Vec<Refined> = Vec::new();
    let mut tried: Vec<Vec<(usize, usize)>> = Vec::new();
    for (_, _, pairs) in scored {
        let key: Vec<_> = pairs.iter().map(|x| (x.0, x.1)).collect();
        if tried.contains(&key) {
            continue;
        }
        tried.push(key);
        if let Some(r) = refine(ground, targets, pairs, s) {
            refined.push(r);
        }
        if tried.len() >= 40 {
            break;
        }
    }
    refined.sort_by(|a, b| b.0.len().cmp(&a.0.len()).then(a.2.total_cmp(&b.2)));
    let Some((best, h, _)) = refined.first().cloned() else {
        return Identification::NotIdentified(
            "no four targets lie as any four surveyed points do".into(),
        );
    };
    if best.len() == 4 && !similar_enough(ground, targets, &best, s) {
        return Identification::NotIdentified(
            "only four targets agree, and a homography fits any four: give a heading or more targets".into(),
        );
    }
    // Another assignment nearly as well supported that disagrees: a symmetric layout.
    let conflicts = |other: &[(usize, usize, f64)]| {
        other
            .iter()
            .any(|(p, t, _)| best.iter().any(|(bp, bt, _)| (bp == p) != (bt == t)))
    };
    if let Some((other, _, _)) = refined[1..]
        .iter()
        .find(|(o, _, _)| o.len() + 1 >= best.len() && conflicts(o))
    {
        return Identification::NotIdentified(format!(
            "ambiguous: {} targets fit the survey one way and {} another (a symmetric layout); give the image's heading (--heading) or pick them",
            best.len(),
            other.len()
        ));
    }
    Identification::Found {
        identified: best
            .into_iter()
            .map(|(point, target, residual_px)| Identified {
                point,
                target,
                residual_px,
            })
            .collect(),
        ground_to_image: h,
    }
}

/// Whether four pairs fit a similarity (a near-nadir view) within the gate: four points then
/// check each other, where a homography would fit any four.
fn similar_enough(
    ground: &[Vector2<f64>],
    targets: &[(Vector2<f64>, f64)],
    pairs: &[(usize, usize, f64)],
    s: &LayoutSettings,
) -> bool {
    let (a, b) = (pairs[0], pairs[1]);
    let Some(sim) =
        Similarity::through(&ground[a.0], &ground[b.0], &targets[a.1].0, &targets[b.1].0)
    else {
        return false;
    };
    let gate = s.gate_px * 2.0;
    pairs.iter().all(|(p, t, _)| {
        (sim.apply(&ground[*p]) - targets[*t].0).norm() <= gate + 3.0 * targets[*t].1
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A camera's view of ground points: a homography made from a turn, a scale, a tilt and a
    /// shift (mirror image: rows run down).
    fn view(turn: f64, scale: f64, tilt: f64) -> Matrix3<f64> {
        let (c, s) = (turn.cos(), turn.sin());
        Matrix3::new(
            scale * c,
            scale * s,
            900.0,
            scale * s,
            -scale * c,
            500.0,
            tilt,
            0.3 * tilt,
            1.0,
        )
    }

    fn irregular() -> Vec<Vector2<f64>> {
        vec![
            Vector2::new(0.0, 0.0),
            Vector2::new(12.0, 1.5),
            Vector2::new(25.0, -2.0),
            Vector2::new(4.0, 9.0),
            Vector2::new(17.0, 11.0),
            Vector2::new(-6.0, 14.0),
            Vector2::new(30.0, 8.0),
        ]
    }

    #[test]
    fn an_irregular_layout_is_identified_in_nadir_and_tilted_views_with_false_targets() {
        let ground = irregular();
        for (turn, tilt) in [(0.0, 0.0), (2.0, 0.0), (-1.0, 0.004), (3.0, -0.006)] {
            let h = view(turn, 30.0, tilt);
            // The points in view as targets, two false ones, and one point missing.
            let mut targets: Vec<(Vector2<f64>, f64)> = ground
                .iter()
                .skip(1)
                .map(|g| (apply_h(&h, g).unwrap() + Vector2::new(0.3, -0.2), 0.1))
                .collect();
            targets.push((Vector2::new(640.0, 200.0), 0.1));
            targets.push((Vector2::new(1400.0, 800.0), 0.1));
            match identify_by_layout(&ground, &targets, &LayoutSettings::default()) {
                Identification::Found { identified, .. } => {
                    assert_eq!(identified.len(), ground.len() - 1, "turn {turn}");
                    for i in identified {
                        assert_eq!(i.point, i.target + 1, "turn {turn}");
                    }
                }
                Identification::NotIdentified(why) => panic!("turn {turn}, tilt {tilt}: {why}"),
            }
        }
    }

    #[test]
    fn a_symmetric_layout_is_refused_unless_the_heading_tells() {
        // A 2×3 grid: a half turn maps it onto itself.
        let ground: Vec<_> = (0..6)
            .map(|k| Vector2::new(10.0 * (k % 3) as f64, 4.0 * (k / 3) as f64))
            .collect();
        let h = view(0.4, 40.0, 0.0);
        let targets: Vec<_> = ground
            .iter()
            .map(|g| (apply_h(&h, g).unwrap(), 0.1))
            .collect();
        let r = identify_by_layout(&ground, &targets, &LayoutSettings::default());
        assert!(
            matches!(&r, Identification::NotIdentified(w) if w.contains("ambiguous")),
            "{r:?}"
        );
        // The image's up, as the test's view makes it: the bearing of (0, -1) back on the ground.
        let inv = h.try_inverse().unwrap();
        let (a, b) = (
            apply_h(&inv, &Vector2::new(900.0, 500.0)).unwrap(),
            apply_h(&inv, &Vector2::new(900.0, 499.0)).unwrap(),
        );
        let bearing = (b.x - a.x).atan2(b.y - a.y).to_degrees();
        let s = LayoutSettings {
            heading_deg: Some((bearing + 20.0, 45.0)),
            ..LayoutSettings::default()
        };
        match identify_by_layout(&ground, &targets, &s) {
            Identification::Found { identified, .. } => {
                assert_eq!(identified.len(), 6);
                assert!(identified.iter().all(|i| i.point == i.target));
            }
            other => panic!("{other:?}"),
        }
    }

    #[test]
    fn too_few_targets_are_not_guessed() {
        let ground = irregular();
        let h = view(0.5, 30.0, 0.002);
        let targets: Vec<_> = ground[..3]
            .iter()
            .map(|g| (apply_h(&h, g).unwrap(), 0.1))
            .collect();
        assert!(matches!(
            identify_by_layout(&ground, &targets, &LayoutSettings::default()),
            Identification::NotIdentified(_)
        ));
    }
}
