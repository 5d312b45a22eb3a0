//! Trajectories against the truth (pure): position errors and the standard multi-object tracking
//! metrics (CLEAR MOT: MOTA, MOTP, ID switches, fragmentations, mostly tracked/lost; and IDF1).
//!
//! In every frame, truth and estimated positions are matched one to one within a distance
//! threshold: a pair matched in the previous frame is kept while it stays within the threshold,
//! the rest are assigned by the Hungarian method on distance (Bernardin & Stiefelhagen 2008).
//! IDF1 matches whole trajectories once, maximising the frames they agree on (Ristani et al.
//! 2016).

use std::collections::HashMap;

use nalgebra::Vector2;
use serde::Serialize;

use std::path::Path;

use crate::io::{FileCtx, FileError};
use crate::optim::assignment::assign;

/// A position of one object in one frame.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Sample {
    pub frame: usize,
    pub id: usize,
    pub position: Vector2<f64>,
}

/// Positions read from a CSV: those that count, and those that count neither way (a truth row
/// whose `in_view` is 0).
#[derive(Clone, Debug, Default, PartialEq)]
pub struct SampleTable {
    pub samples: Vec<Sample>,
    pub ignored: Vec<Sample>,
}

/// Reads MOTChallenge 3D ground truth (`frame, id, left, top, width, height, flag, x, y, z`,
/// no header, frames from 1; 2D MOT 2015's `gt.txt` with world coordinates, as PETS 2009 S2L1
/// has): the world x, y by frame from 0 and id; a row whose flag is 0 counts neither way.
pub fn parse_mot_truth(path: &Path, text: &str) -> Result<SampleTable, FileError> {
    let ctx = FileCtx { path };
    let mut table = SampleTable::default();
    let mut seen: HashMap<(usize, usize), usize> = HashMap::new();
    let names = [
        "frame", "id", "left", "top", "width", "height", "flag", "x", "y",
    ];
    for (i, raw) in text.lines().enumerate() {
        let line = i + 1;
        let raw = raw.trim();
        if raw.is_empty() {
            continue;
        }
        let f: Vec<&str> = raw
            .split(|c: char| c == ',' || c.is_whitespace())
            .filter(|x| !x.is_empty())
            .collect();
        if f.len() < 9 {
            return Err(ctx.at(
                line,
                format!(
                    "expected MOTChallenge 3D ground truth: frame, id, left, top, width, height, \
                     flag, x, y, z ({} fields found)",
                    f.len()
                ),
            ));
        }
        let frame = ctx.whole(f[0], line, names[0])? as usize;
        if frame == 0 {
            return Err(ctx.at(
                line,
                "field 'frame': MOTChallenge frames count from 1, found 0",
            ));
        }
        let id = ctx.whole(f[1], line, names[1])? as usize;
        let flag = ctx.number(f[6], line, names[6])?;
        let sample = Sample {
            frame: frame - 1,
            id,
            position: Vector2::new(
                ctx.number(f[7], line, names[7])?,
                ctx.number(f[8], line, names[8])?,
            ),
        };
        if let Some(first) = seen.insert((frame, id), line) {
            return Err(ctx.at(
                line,
                format!("id {id} is in frame {frame} twice (lines {first} and {line})"),
            ));
        }
        if flag == 0.0 {
            table.ignored.push(sample);
        } else {
            table.samples.push(sample);
        }
    }
    if seen.is_empty() {
        return Err(ctx.err(None, None, "no rows"));
    }
    Ok(table)
}

/// Reads `frame, id, x, y` samples from a CSV with a header, the four columns named by
/// `columns`. Frames and ids are whole numbers, positions finite, each (frame, id) once; a row
/// whose `in_view` column is 0 is put apart. A table without rows is an error.
pub fn read_samples(path: &Path, columns: [&str; 4]) -> Result<SampleTable, FileError> {
    let text = FileCtx { path }.read_text("a CSV of positions with a header")?;
    parse_samples(path, &text, columns)
}

/// [`read_samples`] on text; `path` names the file in messages.
pub fn parse_samples(
    path: &Path,
    text: &str,
    columns: [&str; 4],
) -> Result<SampleTable, FileError> {
    let ctx = FileCtx { path };
    let mut table = SampleTable::default();
    let mut seen: HashMap<(usize, usize), usize> = HashMap::new();
    crate::io::csv_rows(ctx, text, &columns, |line, f, idx, header| {
        let in_view = header.iter().position(|h| *h == "in_view");
        let frame = ctx.whole(f[idx[0]], line, columns[0])? as usize;
        let id = ctx.whole(f[idx[1]], line, columns[1])? as usize;
        let sample = Sample {
            frame,
            id,
            position: Vector2::new(
                ctx.number(f[idx[2]], line, columns[2])?,
                ctx.number(f[idx[3]], line, columns[3])?,
            ),
        };
        if let Some(first) = seen.insert((frame, id), line) {
            return Err(ctx.at(
                line,
                format!(
                    "{} {id} is in frame {frame} twice (lines {first} and {line})",
                    columns[1]
                ),
            ));
        }
        if in_view.is_some_and(|c| f[c].trim() == "0") {
            table.ignored.push(sample);
        } else {
            table.samples.push(sample);
        }
        Ok(())
    })?;
    if seen.is_empty() {
        return Err(ctx.err(None, None, "no rows below the header"));
    }
    Ok(table)
}

/// The numbers.
#[derive(Clone, Debug, Serialize, PartialEq)]
pub struct Evaluation {
    pub threshold_m: f64,
    /// Horizontal error of matched positions: RMSE, mean, 95th percentile and largest, metres.
    pub rmse_m: f64,
    pub mean_error_m: f64,
    pub p95_error_m: f64,
    pub max_error_m: f64,
    pub matches: usize,
    pub truth_positions: usize,
    pub estimated_positions: usize,
    pub misses: usize,
    pub false_positives: usize,
    pub id_switches: usize,
    pub fragmentations: usize,
    pub mota: f64,
    /// Mean distance of the matches, metres.
    pub motp_m: f64,
    pub idf1: f64,
    pub truth_tracks: usize,
    pub estimated_tracks: usize,
    /// Truth tracks matched in at least 80 % / at most 20 % of their frames.
    pub mostly_tracked: usize,
    pub mostly_lost: usize,
    /// Truth tracks matched in at least 90 % of their frames.
    pub tracked_90: usize,
    /// Fraction of the truth tracks that are `tracked_90`.
    pub tracked_90_fraction: f64,
    /// ID switches per truth track.
    pub id_switch_rate: f64,
}

/// The samples sorted by frame, each frame's in their order: frames are then runs of a slice
/// (a map of small vectors took some 20 times the memory of millions of samples).
fn by_frame(samples: &[Sample]) -> Vec<Sample> {
    let mut v = samples.to_vec();
    v.sort_by_key(|s| s.frame);
    v
}

/// The run of `sorted` (by frame) in `frame`, starting the search at `from`.
fn frame_run(sorted: &[Sample], from: usize, frame: usize) -> std::ops::Range<usize> {
    let start = from + sorted[from..].partition_point(|s| s.frame < frame);
    let end = start + sorted[start..].partition_point(|s| s.frame == frame);
    start..end
}

/// The largest total of `weight` over a one-to-one pairing of `a`s with `b`s, found per
/// connected group of pairs of positive weight (trajectories that never agree cannot help).
fn best_pairing(weight: &HashMap<(usize, usize), usize>) -> usize {
    // Union-find over the truth ids and the estimate ids (tagged apart).
    let mut nodes: HashMap<(bool, usize), usize> = HashMap::new();
    let mut parent: Vec<usize> = Vec::new();
    fn find(parent: &mut [usize], mut x: usize) -> usize {
        while parent[x] != x {
            parent[x] = parent[parent[x]];
            x = parent[x];
        }
        x
    }
    let mut node = |key: (bool, usize), parent: &mut Vec<usize>| {
        *nodes.entry(key).or_insert_with(|| {
            parent.push(parent.len());
            parent.len() - 1
        })
    };
    let mut pairs: Vec<(usize, usize, usize, usize)> = Vec::new();
    let mut keys: Vec<_> = weight.keys().copied().collect();
    keys.sort_unstable();
    for (g, h) in keys {
        let (a, b) = (node((true, g), &mut parent), node((false, h), &mut parent));
        let (ra, rb) = (find(&mut parent, a), find(&mut parent, b));
        if ra != rb {
            parent[ra] = rb;
        }
        pairs.push((a, b, g, h));
    }
    let mut groups: HashMap<usize, Vec<(usize, usize)>> = HashMap::new();
    for &(a, _, g, h) in &pairs {
        let r = find(&mut parent, a);
        groups.entry(r).or_default().push((g, h));
    }
    let big = 1e12;
    let mut total = 0;
    let mut roots: Vec<usize> = groups.keys().copied().collect();
    roots.sort_unstable();
    for r in roots {
        let group = &groups[&r];
        let mut gs: Vec<usize> = group.iter().map(|p| p.0).collect();
        let mut hs: Vec<usize> = group.iter().map(|p| p.1).collect();
        gs.sort_unstable();
        gs.dedup();
        hs.sort_unstable();
        hs.dedup();
        let cost: Vec<Vec<f64>> = gs
            .iter()
            .map(|g| {
                hs.iter()
                    .map(|h| weight.get(&(*g, *h)).map_or(big, |&n| -(n as f64)))
                    .collect()
            })
            .collect();
        for (k, m) in assign(&cost, 0.0).into_iter().enumerate() {
            if let Some(m) = m {
                total += weight.get(&(gs[k], hs[m])).copied().unwrap_or(0);
            }
        }
    }
    total
}

/// Moves the people seen in fewer than `min_frames` frames of `truth` into `ignored`: someone
/// crossing a corner of the image, or cut off by the video's start or end, for less time than
/// the shortest track kept counts neither way. Returns how many people were moved.
pub fn ignore_brief(
    truth: &mut Vec<Sample>,
    ignored: &mut Vec<Sample>,
    min_frames: usize,
) -> usize {
    let mut frames: HashMap<usize, usize> = HashMap::new();
    for s in truth.iter() {
        *frames.entry(s.id).or_default() += 1;
    }
    let brief: std::collections::HashSet<usize> = frames
        .into_iter()
        .filter(|&(_, n)| n < min_frames)
        .map(|(id, _)| id)
        .collect();
    let (moved, kept): (Vec<Sample>, Vec<Sample>) =
        truth.drain(..).partition(|s| brief.contains(&s.id));
    *truth = kept;
    ignored.extend(moved);
    brief.len()
}

/// Which person each estimated track follows: for every estimate, the nearest truth position of
/// its frame within `max_m` votes for that person; a track is the person with most votes.
/// (track id → person id; tracks that never came within `max_m` of anyone are left out.)
pub fn identify_tracks(truth: &[Sample], est: &[Sample], max_m: f64) -> HashMap<usize, usize> {
    let mut by_frame: HashMap<usize, Vec<&Sample>> = HashMap::new();
    for t in truth {
        by_frame.entry(t.frame).or_default().push(t);
    }
    let mut votes: HashMap<(usize, usize), usize> = HashMap::new();
    for e in est {
        if let Some(t) = by_frame.get(&e.frame).and_then(|v| {
            v.iter().min_by(|a, b| {
                (a.position - e.position)
                    .norm()
                    .total_cmp(&(b.position - e.position).norm())
            })
        }) && (t.position - e.position).norm() < max_m
        {
            *votes.entry((e.id, t.id)).or_default() += 1;
        }
    }
    // Ties go to the lower person id, whatever the hash order.
    let mut best: HashMap<usize, (usize, usize)> = HashMap::new();
    for ((track, person), n) in votes {
        let b = best.entry(track).or_insert((person, 0));
        if n > b.1 || (n == b.1 && person < b.0) {
            *b = (person, n);
        }
    }
    best.into_iter().map(|(t, (p, _))| (t, p)).collect()
}

/// Evaluates `estimated` against `truth` with a match threshold in metres. Estimates within the
/// threshold of an `ignored` truth position (someone the truth does not count in that frame: a
/// head just outside the image, say) count neither way.
pub fn evaluate(
    truth: &[Sample],
    estimated: &[Sample],
    ignored: &[Sample],
    threshold_m: f64,
) -> Evaluation {
    evaluate_inner(truth, estimated, ignored, threshold_m, false).0
}

/// [`evaluate`], and the matched pairs (truth, estimate) of every frame, in frame order.
pub fn evaluate_matches(
    truth: &[Sample],
    estimated: &[Sample],
    ignored: &[Sample],
    threshold_m: f64,
) -> (Evaluation, Vec<(Sample, Sample)>) {
    evaluate_inner(truth, estimated, ignored, threshold_m, true)
}

/// One frame's truth `t` and estimates `e` paired: last frame's correspondences that still hold
/// within `threshold_m`, then a global assignment of the rest; the pairs and which are used.
fn frame_pairs(
    t: &[Sample],
    e: &[Sample],
    last_match: &HashMap<usize, usize>,
    threshold_m: f64,
) -> (Vec<(usize, usize)>, Vec<bool>, Vec<bool>) {
    let mut t_used = vec![false; t.len()];
    let mut e_used = vec![false; e.len()];
    let mut pairs: Vec<(usize, usize)> = Vec::new();
    // Keep last frame's correspondences that still hold.
    for (i, a) in t.iter().enumerate() {
        if let Some(&h) = last_match.get(&a.id)
            && let Some(j) = e.iter().position(|b| b.id == h)
            && !e_used[j]
            && (a.position - e[j].position).norm() <= threshold_m
        {
            t_used[i] = true;
            e_used[j] = true;
            pairs.push((i, j));
        }
    }
    let ti: Vec<usize> = (0..t.len()).filter(|&i| !t_used[i]).collect();
    let ej: Vec<usize> = (0..e.len()).filter(|&j| !e_used[j]).collect();
    let cost: Vec<Vec<f64>> = ti
        .iter()
        .map(|&i| {
            ej.iter()
                .map(|&j| (t[i].position - e[j].position).norm())
                .collect()
        })
        .collect();
    for (k, m) in assign(&cost, threshold_m).into_iter().enumerate() {
        if let Some(m) = m {
            pairs.push((ti[k], ej[m]));
            t_used[ti[k]] = true;
            e_used[ej[m]] = true;
        }
    }
    (pairs, t_used, e_used)
}

/// RMSE, mean and 95th percentile of the matched errors (sorted here; NaN without any).
fn error_stats(errors: &mut [f64]) -> (f64, f64, f64) {
    errors.sort_by(f64::total_cmp);
    let n_match = errors.len();
    let rmse = if n_match > 0 {
        (errors.iter().map(|e| e * e).sum::<f64>() / n_match as f64).sqrt()
    } else {
        f64::NAN
    };
    let mean = if n_match > 0 {
        errors.iter().sum::<f64>() / n_match as f64
    } else {
        f64::NAN
    };
    let p95 = if n_match > 0 {
        errors[((0.95 * n_match as f64).ceil() as usize).clamp(1, n_match) - 1]
    } else {
        f64::NAN
    };
    (rmse, mean, p95)
}

/// The pairs are kept only when asked for: 64 bytes each, a gigabyte for a 200 MB table.
fn evaluate_inner(
    truth: &[Sample],
    estimated: &[Sample],
    ignored: &[Sample],
    threshold_m: f64,
    keep_matches: bool,
) -> (Evaluation, Vec<(Sample, Sample)>) {
    let mut matched = Vec::new();
    let ig = by_frame(ignored);
    // One sorted copy of each side: a run's tables can hold millions of positions.
    let mut ef: Vec<Sample> = estimated
        .iter()
        .filter(|e| {
            !ig[frame_run(&ig, 0, e.frame)]
                .iter()
                .any(|i| (i.position - e.position).norm() <= threshold_m)
        })
        .copied()
        .collect();
    drop(ig);
    ef.sort_by_key(|s| s.frame);
    let estimated = &ef[..];
    let tf = by_frame(truth);
    let mut last_match: HashMap<usize, usize> = HashMap::new(); // truth id → estimated id
    // Per truth id: whether it has been tracked, and whether it is in an interruption now.
    let mut interrupted: HashMap<usize, bool> = HashMap::new();
    let mut matched_frames: HashMap<usize, usize> = HashMap::new();
    let mut truth_frames: HashMap<usize, usize> = HashMap::new();
    let mut errors = Vec::new();
    let (mut misses, mut fps, mut idsw, mut frags) = (0, 0, 0, 0);
    // IDF1: frames each (truth, estimate) pair agree within the threshold.
    let mut agree: HashMap<(usize, usize), usize> = HashMap::new();
    let (mut ti0, mut ei0) = (0, 0);
    // The frames of either, in order.
    while ti0 < tf.len() || ei0 < ef.len() {
        let f = match (tf.get(ti0), ef.get(ei0)) {
            (Some(a), Some(b)) => a.frame.min(b.frame),
            (Some(a), None) => a.frame,
            (None, Some(b)) => b.frame,
            (None, None) => unreachable!("loop condition"),
        };
        let (tr, er) = (frame_run(&tf, ti0, f), frame_run(&ef, ei0, f));
        (ti0, ei0) = (tr.end, er.end);
        let (t, e) = (&tf[tr], &ef[er]);
        for a in t {
            *truth_frames.entry(a.id).or_default() += 1;
            for b in e {
                if (a.position - b.position).norm() <= threshold_m {
                    *agree.entry((a.id, b.id)).or_default() += 1;
                }
            }
        }
        let (pairs, t_used, e_used) = frame_pairs(t, e, &last_match, threshold_m);
        for &(i, j) in &pairs {
            let (a, b) = (&t[i], &e[j]);
            if let Some(&h) = last_match.get(&a.id)
                && h != b.id
            {
                idsw += 1;
            }
            last_match.insert(a.id, b.id);
            errors.push((a.position - b.position).norm());
            if keep_matches {
                matched.push((*a, *b));
            }
            *matched_frames.entry(a.id).or_default() += 1;
        }
        for (i, a) in t.iter().enumerate() {
            // A fragmentation: tracking resumes after an interruption.
            match (t_used[i], interrupted.get(&a.id).copied()) {
                (true, Some(true)) => {
                    frags += 1;
                    interrupted.insert(a.id, false);
                }
                (true, None) => {
                    interrupted.insert(a.id, false);
                }
                (false, Some(false)) => {
                    interrupted.insert(a.id, true);
                }
                _ => {}
            }
            if !t_used[i] {
                misses += 1;
            }
        }
        fps += e_used.iter().filter(|u| !**u).count();
    }
    // IDF1 by a global one-to-one assignment of trajectories.
    let truth_ids: Vec<usize> = truth_frames.keys().copied().collect();
    let mut est_len: HashMap<usize, usize> = HashMap::new();
    for s in estimated {
        *est_len.entry(s.id).or_default() += 1;
    }
    let idtp = best_pairing(&agree);
    let n_truth = truth.len();
    let n_est = estimated.len();
    let idf1 = if n_truth + n_est > 0 {
        2.0 * idtp as f64 / (n_truth + n_est) as f64
    } else {
        1.0
    };
    let n_match = errors.len();
    let (rmse, mean, p95) = error_stats(&mut errors);
    let ratio =
        |id: &usize| matched_frames.get(id).copied().unwrap_or(0) as f64 / truth_frames[id] as f64;
    let tracked_90 = truth_ids.iter().filter(|id| ratio(id) >= 0.9).count();
    let evaluation = Evaluation {
        threshold_m,
        rmse_m: rmse,
        mean_error_m: mean,
        p95_error_m: p95,
        max_error_m: errors.last().copied().unwrap_or(f64::NAN),
        matches: n_match,
        truth_positions: n_truth,
        estimated_positions: n_est,
        misses,
        false_positives: fps,
        id_switches: idsw,
        fragmentations: frags,
        mota: if n_truth > 0 {
            1.0 - (misses + fps + idsw) as f64 / n_truth as f64
        } else {
            f64::NAN
        },
        motp_m: mean,
        idf1,
        truth_tracks: truth_ids.len(),
        estimated_tracks: est_len.len(),
        mostly_tracked: truth_ids.iter().filter(|id| ratio(id) >= 0.8).count(),
        mostly_lost: truth_ids.iter().filter(|id| ratio(id) <= 0.2).count(),
        tracked_90,
        tracked_90_fraction: if truth_ids.is_empty() {
            f64::NAN
        } else {
            tracked_90 as f64 / truth_ids.len() as f64
        },
        id_switch_rate: if truth_ids.is_empty() {
            f64::NAN
        } else {
            idsw as f64 / truth_ids.len() as f64
        },
    };
    (evaluation, matched)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn motchallenge_truth_is_read_from_frame_one_with_its_flag() {
        let path = Path::new("gt.txt");
        let t = parse_mot_truth(
            path,
            "1,9,10,20,30,60,1,-3.5,2.25,0\n1,11,5,5,5,5,0,1.0,2.0,0\n2 9 10 20 30 60 1 -3.4 2.3 0\n",
        )
        .unwrap();
        assert_eq!(t.samples.len(), 2);
        assert_eq!((t.samples[0].frame, t.samples[0].id), (0, 9));
        assert_eq!(t.samples[0].position, Vector2::new(-3.5, 2.25));
        assert_eq!(t.samples[1].frame, 1);
        assert_eq!((t.ignored.len(), t.ignored[0].id), (1, 11));
        for (text, says) in [
            (
                "0,9,1,1,1,1,1,0,0,0\n",
                "gt.txt:1: field 'frame': MOTChallenge frames count from 1",
            ),
            (
                "1,9,1,1,1,1,1,0\n",
                "gt.txt:1: expected MOTChallenge 3D ground truth",
            ),
            (
                "1,9,1,1,1,1,1,0,0,0\n1,9,1,1,1,1,1,0,0,0\n",
                "gt.txt:2: id 9 is in frame 1 twice",
            ),
        ] {
            let e = parse_mot_truth(path, text).unwrap_err().to_string();
            assert!(e.starts_with(says), "{e}");
        }
    }

    /// Errors drawn from the stated covariance fill its 95 % ellipse 95 % of the time; errors
    /// twice as large do not, and a shift shows as a mean error over σ.
    #[test]
    fn consistency_of_errors_drawn_from_the_stated_covariance() {
        use rand::SeedableRng;
        use rand_distr::{Distribution, Normal};
        let cov = crate::export::PointCov {
            random: nalgebra::Matrix2::new(4e-4, 1e-4, 1e-4, 2e-4),
            height: nalgebra::Matrix2::identity() * 1e-4,
            pose: nalgebra::Matrix2::zeros(),
        };
        let chol = cov.total().cholesky().unwrap().l();
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(3);
        let n01 = Normal::new(0.0, 1.0).unwrap();
        let run = |scale: f64, shift: f64, rng: &mut rand_chacha::ChaCha8Rng| {
            let mut matches = Vec::new();
            let mut covs = Covariances::new();
            for k in 0..20_000 {
                let z = Vector2::new(n01.sample(rng), n01.sample(rng));
                let t = s(k, 1, 10.0, 5.0);
                let e = s(k, 1, 10.0 + shift, 5.0);
                let e = Sample {
                    position: e.position + chol * z * scale,
                    ..e
                };
                covs.insert((k, 1), cov);
                matches.push((t, e));
            }
            consistency(&matches, &covs).0
        };
        let c = run(1.0, 0.0, &mut rng);
        assert_eq!(c.points, 20_000);
        assert!((c.inside_95 - 0.95).abs() < 0.005, "{c:?}");
        assert!((c.mean_nees_per_axis - 1.0).abs() < 0.03, "{c:?}");
        assert!((c.median_normalised_error - 0.833).abs() < 0.02, "{c:?}");
        assert!(c.mean_normalised_e.abs() < 0.03, "{c:?}");
        assert!((c.median_sigma_height_m - 0.01).abs() < 1e-9, "{c:?}");
        let c = run(2.0, 0.0, &mut rng);
        assert!(c.inside_95 < 0.6, "{c:?}");
        let c = run(1.0, 0.02, &mut rng);
        assert!(
            (c.mean_normalised_e - 0.02 / 5e-4f64.sqrt()).abs() < 0.05,
            "{c:?}"
        );
    }

    #[test]
    fn tracks_are_identified_by_their_nearest_person() {
        // Track 7 follows person 1 for three frames and strays to person 2 for one; track 8 is
        // nowhere near anyone.
        let truth = vec![
            s(0, 1, 0.0, 0.0),
            s(0, 2, 5.0, 0.0),
            s(1, 1, 0.1, 0.0),
            s(1, 2, 5.1, 0.0),
            s(2, 1, 0.2, 0.0),
            s(2, 2, 0.6, 0.0),
        ];
        let est = vec![
            s(0, 7, 0.05, 0.0),
            s(1, 7, 0.15, 0.0),
            s(2, 7, 0.25, 0.0),
            s(2, 7, 0.6, 0.01),
            s(0, 8, 20.0, 0.0),
        ];
        let ids = identify_tracks(&truth, &est, 0.5);
        assert_eq!(ids.get(&7), Some(&1));
        assert_eq!(ids.get(&8), None);
    }

    fn s(frame: usize, id: usize, x: f64, y: f64) -> Sample {
        Sample {
            frame,
            id,
            position: Vector2::new(x, y),
        }
    }

    #[test]
    fn perfect_tracks_score_perfectly() {
        let truth: Vec<Sample> = (0..50)
            .flat_map(|f| (0..3).map(move |p| s(f, p, f as f64 * 0.14, p as f64)))
            .collect();
        let est: Vec<Sample> = truth
            .iter()
            .map(|t| Sample {
                id: t.id + 10,
                position: t.position + Vector2::new(0.03, -0.04),
                ..*t
            })
            .collect();
        let e = evaluate(&truth, &est, &[], 0.5);
        assert_eq!(
            (e.misses, e.false_positives, e.id_switches, e.fragmentations),
            (0, 0, 0, 0)
        );
        assert!((e.mota - 1.0).abs() < 1e-12 && (e.idf1 - 1.0).abs() < 1e-12);
        assert!((e.rmse_m - 0.05).abs() < 1e-12);
        assert_eq!((e.mostly_tracked, e.tracked_90, e.truth_tracks), (3, 3, 3));
    }

    #[test]
    fn a_swap_a_gap_and_a_ghost_are_counted() {
        // Two people on parallel lines; the estimate swaps their identities at frame 20, loses
        // person 0 in frames 30–34, and adds a ghost in frame 40.
        let mut truth = Vec::new();
        let mut est = Vec::new();
        for f in 0..50 {
            let x = f as f64 * 0.1;
            truth.push(s(f, 0, x, 0.0));
            truth.push(s(f, 1, x, 0.3));
            let (a, b) = if f < 20 { (100, 101) } else { (101, 100) };
            if !(30..35).contains(&f) {
                est.push(s(f, a, x, 0.01));
            }
            est.push(s(f, b, x, 0.31));
            if f == 40 {
                est.push(s(f, 102, 9.0, 9.0));
            }
        }
        let e = evaluate(&truth, &est, &[s(40, 9, 9.0, 9.0)][..0], 0.2);
        assert_eq!(e.misses, 5);
        assert_eq!(e.false_positives, 1);
        // The swap changes both people's estimate: two switches.
        assert_eq!(e.id_switches, 2);
        assert_eq!(e.fragmentations, 1);
        assert!((e.mota - (1.0 - 8.0 / 100.0)).abs() < 1e-12, "{}", e.mota);
        // IDF1: each truth agrees with one estimate over 30 frames at best.
        assert!(e.idf1 < 0.7 && e.idf1 > 0.5, "{}", e.idf1);
        // Person 0 is matched in 45 of 50 frames: exactly 90 %.
        assert_eq!(e.tracked_90, 2);
        // The ghost sits where the truth says someone is but does not count: ignored.
        let e = evaluate(&truth, &est, &[s(40, 9, 9.05, 9.0)], 0.2);
        assert_eq!(e.false_positives, 0);
    }

    #[test]
    fn people_seen_briefly_count_neither_way() {
        let mut truth: Vec<Sample> = (0..30).map(|f| s(f, 0, f as f64 * 0.1, 0.0)).collect();
        truth.extend((0..4).map(|f| s(f, 1, 5.0, f as f64 * 0.1)));
        let mut ignored = vec![s(0, 7, 1.0, 1.0)];
        assert_eq!(ignore_brief(&mut truth, &mut ignored, 5), 1);
        assert_eq!(truth.len(), 30);
        assert!(truth.iter().all(|t| t.id == 0));
        assert_eq!(ignored.len(), 5);
        // An estimate of the brief person is no false alarm, and they are no miss.
        let est: Vec<Sample> = (0..4).map(|f| s(f, 9, 5.0, f as f64 * 0.1)).collect();
        let e = evaluate(&truth, &est, &ignored, 0.2);
        assert_eq!((e.false_positives, e.misses, e.truth_tracks), (0, 30, 1));
    }
}

/// The 95 % point of χ² with two degrees of freedom: a 2D error inside its 95 % ellipse has a
/// squared Mahalanobis distance below this.
pub const CHI2_2D_95: f64 = 5.991_464_547_107_979;

/// A point's stated covariance, by source (m²), looked up by (frame, id) of the estimate.
pub type Covariances = HashMap<(usize, usize), crate::export::PointCov>;

/// How well stated uncertainties describe the errors of matched points.
#[derive(Clone, Debug, Default, Serialize, PartialEq)]
pub struct Consistency {
    /// Matched points with a covariance.
    pub points: usize,
    /// The share whose 95 % error ellipse holds the truth (0.95 when the covariances are right).
    pub inside_95: f64,
    /// The mean of the squared Mahalanobis distance over two (1 when right), and its median
    /// normalised error d/√2.
    pub mean_nees_per_axis: f64,
    pub median_normalised_error: f64,
    /// The mean error over σ east and north (0 without a bias).
    pub mean_normalised_e: f64,
    pub mean_normalised_n: f64,
    /// Median σ per axis (√(trace/2)) of the whole covariance and of each source, metres.
    pub median_sigma_m: f64,
    pub median_sigma_random_m: f64,
    pub median_sigma_height_m: f64,
    pub median_sigma_pose_m: f64,
}

/// One matched point's error against its stated covariance.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct PointCheck {
    pub truth: Sample,
    pub estimate: Sample,
    pub cov: crate::export::PointCov,
    /// Squared Mahalanobis distance of the error under the total covariance.
    pub d2: f64,
}

/// Checks matched points (from [`evaluate_matches`]) against their covariances; points
/// without one, or with a singular one, are left out.
pub fn consistency(
    matches: &[(Sample, Sample)],
    covariances: &Covariances,
) -> (Consistency, Vec<PointCheck>) {
    let mut checks = Vec::new();
    for (t, e) in matches {
        let Some(cov) = covariances.get(&(e.frame, e.id)) else {
            continue;
        };
        let err = e.position - t.position;
        let Some(inv) = cov.total().try_inverse() else {
            continue;
        };
        let d2 = (err.transpose() * inv * err)[(0, 0)];
        if d2.is_finite() {
            checks.push(PointCheck {
                truth: *t,
                estimate: *e,
                cov: *cov,
                d2,
            });
        }
    }
    let n = checks.len();
    if n == 0 {
        return (Consistency::default(), checks);
    }
    let median = |mut v: Vec<f64>| {
        v.sort_by(f64::total_cmp);
        v[v.len() / 2]
    };
    let rms = crate::export::rms_sigma;
    let mean = |f: &dyn Fn(&PointCheck) -> f64| checks.iter().map(f).sum::<f64>() / n as f64;
    let c = Consistency {
        points: n,
        inside_95: checks.iter().filter(|c| c.d2 <= CHI2_2D_95).count() as f64 / n as f64,
        mean_nees_per_axis: mean(&|c| c.d2 / 2.0),
        median_normalised_error: median(checks.iter().map(|c| (c.d2 / 2.0).sqrt()).collect()),
        mean_normalised_e: mean(&|c| {
            (c.estimate.position.x - c.truth.position.x) / c.cov.total()[(0, 0)].sqrt()
        }),
        mean_normalised_n: mean(&|c| {
            (c.estimate.position.y - c.truth.position.y) / c.cov.total()[(1, 1)].sqrt()
        }),
        median_sigma_m: median(checks.iter().map(|c| rms(&c.cov.total())).collect()),
        median_sigma_random_m: median(checks.iter().map(|c| rms(&c.cov.random)).collect()),
        median_sigma_height_m: median(checks.iter().map(|c| rms(&c.cov.height)).collect()),
        median_sigma_pose_m: median(checks.iter().map(|c| rms(&c.cov.pose)).collect()),
    };
    (c, checks)
}

/// The covariances of a `trajectories.csv` (its `sigma_e_m`, `sigma_n_m`, `cov_en_m2` and the
/// σ of each source), by (frame, id). The total is exact; the height's and the pose's parts are
/// taken as isotropic (the file gives their σ only) and the random part is the rest.
pub fn read_covariances(path: &Path) -> Result<Covariances, FileError> {
    let ctx = FileCtx { path };
    let text = ctx.read_text("a trajectories.csv")?;
    let names = [
        "frame",
        "id",
        "sigma_e_m",
        "sigma_n_m",
        "cov_en_m2",
        "sigma_random_m",
        "sigma_height_m",
        "sigma_pose_m",
    ];
    let mut out = Covariances::new();
    crate::io::csv_rows(ctx, &text, &names, |line, f, idx, _| {
        let v = |k: usize| ctx.number(f[idx[k]], line, names[k]);
        let frame = ctx.whole(f[idx[0]], line, names[0])? as usize;
        let id = ctx.whole(f[idx[1]], line, names[1])? as usize;
        let (se, sn, en) = (v(2)?, v(3)?, v(4)?);
        let total = nalgebra::Matrix2::new(se * se, en, en, sn * sn);
        v(5)?;
        let height = nalgebra::Matrix2::identity() * v(6)?.powi(2);
        let pose = nalgebra::Matrix2::identity() * v(7)?.powi(2);
        out.insert(
            (frame, id),
            crate::export::PointCov {
                random: total - height - pose,
                height,
                pose,
            },
        );
        Ok(())
    })?;
    Ok(out)
}
