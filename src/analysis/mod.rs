//! Pedestrian-dynamics measures of the trajectories, as PedPy (the Jülich group's library)
//! defines them, so that its figures and geostride's can be compared on the same file:
//! classic and Voronoi density and mean and Voronoi speed in a measurement area, frame by
//! frame (the fundamental diagram), and the summaries the run report plots.
//!
//! Definitions (PedPy 1.5, `docs/analysis.md`): a person's Voronoi cell is their cell of the
//! frame's Voronoi diagram clipped to the walkable area; Voronoi density
//! ρ_V = Σᵢ |Vᵢ ∩ M| / |Vᵢ| / |M|; Voronoi speed v_V = Σᵢ |Vᵢ ∩ M| · vᵢ / |M|; classic density
//! N / |M| with N the people strictly inside M; mean speed the mean over those people. Speeds
//! here are the smoother's (RTS) velocities; PedPy differences positions `frame_step` frames
//! apart.

pub mod polygon;

use nalgebra::Vector2;

use crate::export::Trajectory;
pub use polygon::{ConvexPolygon, PolygonError};

/// One frame's measures in the measurement area.
#[derive(Clone, Debug, PartialEq, serde::Serialize)]
pub struct FrameMeasures {
    pub frame: usize,
    pub time_s: f64,
    /// People in the frame (anywhere).
    pub people: usize,
    /// People strictly inside the measurement area.
    pub inside: usize,
    /// 1/m².
    pub classic_density: f64,
    pub voronoi_density: f64,
    /// m/s; NaN with no one inside.
    pub mean_speed: f64,
    pub voronoi_speed: f64,
}

/// A frame's people: (position in the site frame, speed m/s).
pub type FramePeople = Vec<(Vector2<f64>, f64)>;

/// The people of each frame, frames in order.
pub fn people_by_frame(trajs: &[Trajectory]) -> Vec<(usize, FramePeople)> {
    let mut by: std::collections::BTreeMap<usize, FramePeople> = Default::default();
    for t in trajs {
        for p in &t.points {
            by.entry(p.frame)
                .or_default()
                .push((p.local.xy(), p.velocity.norm()));
        }
    }
    by.into_iter().collect()
}

/// The measures of every frame with someone in it, in `measurement` (inside `walkable`).
pub fn measures(
    trajs: &[Trajectory],
    fps: f64,
    walkable: &ConvexPolygon,
    measurement: &ConvexPolygon,
) -> Vec<FrameMeasures> {
    measures_of_frames(people_by_frame(trajs), fps, walkable, measurement)
}

/// [`measures`] of the given frames' people (frames read a batch at a time from a long video's
/// trajectories), side by side, in their order.
pub fn measures_of_frames(
    frames: Vec<(usize, FramePeople)>,
    fps: f64,
    walkable: &ConvexPolygon,
    measurement: &ConvexPolygon,
) -> Vec<FrameMeasures> {
    use rayon::prelude::*;
    let area_m = measurement.area();
    frames
        .into_par_iter()
        .map(|(frame, people)| {
            let sites: Vec<Vector2<f64>> = people.iter().map(|p| p.0).collect();
            let cells = voronoi_cells(&sites, walkable);
            let (mut rho_v, mut v_v) = (0.0, 0.0);
            for (cell, (_, speed)) in cells.iter().zip(&people) {
                let Some(cell) = cell else { continue };
                let whole = cell.area();
                if whole <= 0.0 {
                    continue;
                }
                let part = cell.clip(measurement).map_or(0.0, |c| c.area());
                rho_v += part / whole;
                v_v += part * speed;
            }
            let inside: Vec<f64> = people
                .iter()
                .filter(|(p, _)| measurement.strictly_contains(p))
                .map(|(_, s)| *s)
                .collect();
            FrameMeasures {
                frame,
                time_s: frame as f64 / fps,
                people: people.len(),
                inside: inside.len(),
                classic_density: inside.len() as f64 / area_m,
                voronoi_density: rho_v / area_m,
                mean_speed: if inside.is_empty() {
                    f64::NAN
                } else {
                    inside.iter().sum::<f64>() / inside.len() as f64
                },
                voronoi_speed: v_v / area_m,
            }
        })
        .collect()
}

/// Each site's Voronoi cell clipped to `area` (None for a site outside it, or one that shares
/// another's position).
pub fn voronoi_cells(sites: &[Vector2<f64>], area: &ConvexPolygon) -> Vec<Option<ConvexPolygon>> {
    // Others by distance: a site farther than twice the cell's farthest vertex cannot cut it.
    sites
        .iter()
        .enumerate()
        .map(|(i, p)| {
            if !area.contains(p) {
                return None;
            }
            let mut others: Vec<(f64, &Vector2<f64>)> = sites
                .iter()
                .enumerate()
                .filter(|&(j, _)| j != i)
                .map(|(_, q)| ((q - p).norm_squared(), q))
                .collect();
            others.sort_by(|a, b| a.0.total_cmp(&b.0));
            let mut cell = area.clone();
            for (d2, q) in others {
                if d2 == 0.0 {
                    return None;
                }
                let reach2 = cell
                    .vertices()
                    .iter()
                    .map(|v| (v - p).norm_squared())
                    .fold(0.0, f64::max);
                if d2 > 4.0 * reach2 {
                    break;
                }
                // The half-plane nearer p than q.
                let normal = q - p;
                let offset = normal.dot(&((p + q) / 2.0));
                cell = cell.cut(&normal, offset)?;
            }
            Some(cell)
        })
        .collect()
}

/// Counts of `values` in `bins` equal bins from `lo` to `hi` (values outside are left out).
pub fn histogram(values: impl Iterator<Item = f64>, lo: f64, hi: f64, bins: usize) -> Vec<usize> {
    let mut counts = vec![0usize; bins];
    let width = (hi - lo) / bins as f64;
    for v in values {
        if v.is_finite() && v >= lo && v <= hi && width > 0.0 {
            let k = (((v - lo) / width) as usize).min(bins - 1);
            counts[k] += 1;
        }
    }
    counts
}

/// The `q` quantile (0 to 1) of `values` (sorted here), by linear interpolation; NaN when empty.
pub fn quantile(values: &mut [f64], q: f64) -> f64 {
    if values.is_empty() {
        return f64::NAN;
    }
    values.sort_by(f64::total_cmp);
    let x = q.clamp(0.0, 1.0) * (values.len() - 1) as f64;
    let (i, f) = (x.floor() as usize, x.fract());
    let j = (i + 1).min(values.len() - 1);
    values[i] * (1.0 - f) + values[j] * f
}

/// Gives every `(group, value)` once for each call: one pass over data read back from disk.
pub type EachValue<'a, E> = dyn FnMut(&mut dyn FnMut(usize, f64)) -> Result<(), E> + 'a;

/// How many values each of `groups` groups has, in one pass (values of other groups are not
/// counted).
pub fn count_groups<E>(groups: usize, each: &mut EachValue<E>) -> Result<Vec<u64>, E> {
    let mut counts = vec![0u64; groups];
    each(&mut |g, _| {
        if let Some(c) = counts.get_mut(g) {
            *c += 1;
        }
    })?;
    Ok(counts)
}

/// The values at the given ranks (`(group, rank)`, from 0 in `f64::total_cmp`'s order among
/// the group's `counts[group]` values; None past the last), in a few passes over values read
/// afresh by `each` and in little memory whatever their number: radix selection on the
/// values' order-keeping bits, 12 bits a pass, until few enough are left to sort.
pub fn select_ranks<E>(
    counts: &[u64],
    queries: &[(usize, u64)],
    each: &mut EachValue<E>,
) -> Result<Vec<Option<f64>>, E> {
    const SORT_AT_MOST: u64 = 1 << 20;
    const DIGIT: u32 = 12;
    // total_cmp's order as unsigned integers.
    let key = |x: f64| {
        let b = x.to_bits();
        if b >> 63 == 1 { !b } else { b | 1 << 63 }
    };
    let within = |k: u64, prefix: u64, bits: u32| bits == 0 || k >> (64 - bits) == prefix;
    /// A rank being narrowed: the keys left share their top `bits` bits, `prefix`; `left` of
    /// them, the wanted one `rank`-th among them.
    struct Narrowing {
        rank: u64,
        left: u64,
        prefix: u64,
        bits: u32,
    }
    let groups = counts.len();
    let mut of_group: Vec<Vec<usize>> = vec![Vec::new(); groups];
    let mut q: Vec<Narrowing> = Vec::with_capacity(queries.len());
    for (i, &(g, rank)) in queries.iter().enumerate() {
        let n = counts.get(g).copied().unwrap_or(0);
        if rank < n {
            of_group[g].push(i);
        }
        q.push(Narrowing {
            rank,
            left: n,
            prefix: 0,
            bits: 0,
        });
    }
    let active = |q: &[Narrowing], i: usize| {
        let (g, rank) = queries[i];
        rank < counts.get(g).copied().unwrap_or(0) && q[i].bits < 64
    };
    loop {
        let narrowing: Vec<usize> = (0..q.len()).filter(|&i| active(&q, i)).collect();
        let left: u64 = narrowing.iter().map(|&i| q[i].left).sum();
        if narrowing.is_empty() || left <= SORT_AT_MOST {
            break;
        }
        let mut hist = vec![vec![0u64; 1 << DIGIT]; q.len()];
        {
            let q = &q;
            each(&mut |g, x| {
                let k = key(x);
                for &i in of_group.get(g).map_or(&[][..], |v| &v[..]) {
                    let n = &q[i];
                    if n.bits < 64 && within(k, n.prefix, n.bits) {
                        let digit = DIGIT.min(64 - n.bits);
                        hist[i][((k << n.bits) >> (64 - digit)) as usize] += 1;
                    }
                }
            })?;
        }
        for i in narrowing {
            let n = &mut q[i];
            let digit = DIGIT.min(64 - n.bits);
            let h = &hist[i];
            let mut b = 0;
            while n.rank >= h[b] {
                n.rank -= h[b];
                b += 1;
            }
            n.left = h[b];
            n.prefix = (n.prefix << digit) | b as u64;
            n.bits += digit;
        }
    }
    let mut rest: Vec<Vec<f64>> = vec![Vec::new(); q.len()];
    {
        let q = &q;
        each(&mut |g, x| {
            let k = key(x);
            for &i in of_group.get(g).map_or(&[][..], |v| &v[..]) {
                if within(k, q[i].prefix, q[i].bits) {
                    rest[i].push(x);
                }
            }
        })?;
    }
    Ok(rest
        .into_iter()
        .zip(&q)
        .enumerate()
        .map(|(i, (mut r, n))| {
            let (g, rank) = queries[i];
            if rank >= counts.get(g).copied().unwrap_or(0) {
                return None;
            }
            r.sort_by(f64::total_cmp);
            r.get(n.rank as usize).copied()
        })
        .collect())
}

/// The `q` quantiles of each group's values as [`quantile`] gives them (linear interpolation;
/// NaN for a group without values) by [`select_ranks`]: `(group, q)` each; with the groups'
/// counts.
pub fn quantiles_by_passes<E>(
    groups: usize,
    queries: &[(usize, f64)],
    each: &mut EachValue<E>,
) -> Result<(Vec<f64>, Vec<u64>), E> {
    let counts = count_groups(groups, each)?;
    let at: Vec<(u64, u64, f64)> = queries
        .iter()
        .map(|&(g, q)| {
            let n = counts.get(g).copied().unwrap_or(0);
            let x = q.clamp(0.0, 1.0) * n.saturating_sub(1) as f64;
            let i = x.floor() as u64;
            (i, (i + 1).min(n.saturating_sub(1)), x.fract())
        })
        .collect();
    let ranks: Vec<(usize, u64)> = queries
        .iter()
        .zip(&at)
        .flat_map(|(&(g, _), &(i, j, _))| [(g, i), (g, j)])
        .collect();
    let values = select_ranks(&counts, &ranks, each)?;
    let out = at
        .iter()
        .enumerate()
        .map(|(k, &(_, _, f))| match (values[2 * k], values[2 * k + 1]) {
            (Some(a), Some(b)) => a * (1.0 - f) + b * f,
            _ => f64::NAN,
        })
        .collect();
    Ok((out, counts))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::export::{PointCov, TrajectoryPoint};
    use nalgebra::Vector3;

    fn rect(x0: f64, y0: f64, x1: f64, y1: f64) -> ConvexPolygon {
        ConvexPolygon::new(vec![
            Vector2::new(x0, y0),
            Vector2::new(x1, y0),
            Vector2::new(x1, y1),
            Vector2::new(x0, y1),
        ])
        .unwrap()
    }

    /// The straight walkers of a PedPy 1.5.1 session (`pedpy.compute_voronoi_density` and
    /// `compute_voronoi_speed` printed 0.070867 and 0.546305 at frame 0, each cell checked by
    /// hand: 5.6875, 6.25, 14.9625 and 13.1 m²).
    #[test]
    fn frame_zero_of_four_walkers_gives_pedpys_figures() {
        let starts = [
            (1.0, 1.0, 1.0),
            (2.0, 3.0, 1.25),
            (4.0, 2.0, 0.5),
            (9.0, 0.5, -0.75),
        ];
        let trajs: Vec<Trajectory> = starts
            .iter()
            .enumerate()
            .map(|(k, &(x, y, v))| Trajectory {
                id: k + 1,
                height_m: 1.7,
                height_source: String::new(),
                points: vec![TrajectoryPoint {
                    frame: 0,
                    time_s: 0.0,
                    local: Vector3::new(x, y, 1.7),
                    crs: Vector3::zeros(),
                    velocity: Vector2::new(v, 0.0),
                    sigma_m: Vector2::zeros(),
                    cov: PointCov::default(),
                    observed: true,
                    score: Some(0.9),
                }],
            })
            .collect();
        let walkable = rect(0.0, 0.0, 10.0, 4.0);
        let cells = voronoi_cells(
            &starts
                .iter()
                .map(|s| Vector2::new(s.0, s.1))
                .collect::<Vec<_>>(),
            &walkable,
        );
        let areas: Vec<f64> = cells.iter().map(|c| c.as_ref().unwrap().area()).collect();
        for (a, want) in areas.iter().zip([5.6875, 6.25, 14.9625, 13.1]) {
            assert!((a - want).abs() < 1e-9, "{areas:?}");
        }
        let m = measures(&trajs, 25.0, &walkable, &rect(3.0, 0.0, 7.0, 4.0));
        assert_eq!(m.len(), 1);
        assert!((m[0].voronoi_density - 0.070867).abs() < 1e-6, "{m:?}");
        assert!((m[0].voronoi_speed - 0.546305).abs() < 1e-6, "{m:?}");
        // One person (x = 4) strictly inside 3..7: 1/16.
        assert_eq!(m[0].inside, 1);
        assert!((m[0].classic_density - 0.0625).abs() < 1e-12);
        assert!((m[0].mean_speed - 0.5).abs() < 1e-12);
    }

    #[test]
    fn cells_tile_the_area() {
        let area = rect(-5.0, -3.0, 7.0, 4.0);
        let mut s = 7u64;
        let mut next = || {
            s = s
                .wrapping_mul(6364136223846793005)
                .wrapping_add(1442695040888963407);
            (s >> 11) as f64 / (1u64 << 53) as f64
        };
        let sites: Vec<Vector2<f64>> = (0..60)
            .map(|_| Vector2::new(-5.0 + 12.0 * next(), -3.0 + 7.0 * next()))
            .collect();
        let cells = voronoi_cells(&sites, &area);
        let total: f64 = cells.iter().map(|c| c.as_ref().unwrap().area()).sum();
        assert!((total - area.area()).abs() < 1e-9, "{total}");
        // Each site in its own cell, nearer its site than any other.
        for (i, c) in cells.iter().enumerate() {
            let c = c.as_ref().unwrap();
            assert!(c.contains(&sites[i]));
            for v in c.vertices() {
                let own = (v - sites[i]).norm();
                assert!(sites.iter().all(|q| (v - q).norm() >= own - 1e-9));
            }
        }
    }

    #[test]
    fn histogram_and_quantiles() {
        let h = histogram(
            [0.0, 0.5, 0.99, 1.0, 2.0, 3.5, f64::NAN].into_iter(),
            0.0,
            2.0,
            2,
        );
        assert_eq!(h, vec![3, 2]);
        let mut v = vec![3.0, 1.0, 2.0];
        assert_eq!(quantile(&mut v, 0.5), 2.0);
        assert_eq!(quantile(&mut v, 0.25), 1.5);
        assert!(quantile(&mut [], 0.5).is_nan());
    }

    #[test]
    fn selection_by_passes_gives_the_sorted_ranks_and_quantiles() {
        use rand::{RngExt, SeedableRng};
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(11);
        // Two groups over the sorting limit together, clustered (most share their top bits),
        // with ties, a NaN and negatives; a third group empty.
        let values: Vec<(usize, f64)> = (0..(1 << 21) + 7)
            .map(|k| match k % 7 {
                0 => (0, 0.031),
                1 => (1, f64::NAN),
                2 => (1, -rng.random_range(0.0..2.0)),
                _ => (k % 2, rng.random_range(0.03..0.031)),
            })
            .collect();
        let passes = std::cell::Cell::new(0);
        let mut each = |f: &mut dyn FnMut(usize, f64)| -> Result<(), ()> {
            passes.set(passes.get() + 1);
            values.iter().for_each(|&(g, x)| f(g, x));
            Ok(())
        };
        let qs = [(0, 0.5), (1, 0.5), (1, 0.995), (0, 0.0), (1, 1.0), (2, 0.5)];
        let (got, counts) = quantiles_by_passes(3, &qs, &mut each).unwrap();
        for (k, &(g, q)) in qs.iter().enumerate() {
            let mut v: Vec<f64> = values.iter().filter(|p| p.0 == g).map(|p| p.1).collect();
            assert_eq!(counts[g], v.len() as u64);
            let want = quantile(&mut v, q);
            assert!(
                got[k].to_bits() == want.to_bits(),
                "group {g} q {q}: {} against {want}",
                got[k]
            );
        }
        assert!(
            passes.get() >= 3,
            "{} passes: the limit was not reached",
            passes.get()
        );
        // Ranks past the end: none.
        let counts = count_groups(3, &mut each).unwrap();
        let r = select_ranks(&counts, &[(2, 0), (0, counts[0])], &mut each).unwrap();
        assert_eq!(r, vec![None, None]);
    }
}
