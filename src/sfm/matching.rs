//! Descriptor matching (pure): mutual nearest neighbours with Lowe's ratio test, by brute force
//! over unit-length descriptors (`Features::descriptors`), on the rayon pool.

use rayon::prelude::*;

use super::{DESCRIPTOR_LEN, Features};

/// How two images' features are matched.
#[derive(Clone, Debug)]
pub struct MatchSettings {
    /// Keep a match only when its distance is below this fraction of the second nearest's.
    pub ratio: f64,
    /// Keep a match only when each feature is the other's nearest.
    pub mutual: bool,
}

impl Default for MatchSettings {
    fn default() -> Self {
        MatchSettings {
            ratio: 0.8,
            mutual: true,
        }
    }
}

/// Feature `a` of the first image matched to feature `b` of the second, at Euclidean distance
/// `distance` (descriptors of unit length: 0 to 2).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Match {
    pub a: usize,
    pub b: usize,
    pub distance: f32,
}

/// `x·y` of two descriptors, in eight independent lanes (so that the compiler may use vector
/// registers: floating-point sums are otherwise kept in order).
#[inline(always)]
fn dot(x: &[f32], y: &[f32]) -> f32 {
    let mut acc = [0.0f32; 8];
    for (cx, cy) in x.chunks_exact(8).zip(y.chunks_exact(8)) {
        for l in 0..8 {
            acc[l] += cx[l] * cy[l];
        }
    }
    acc.iter().sum()
}

/// `x·y` for four descriptors `x` at once, each summed exactly as [`dot`] sums it (so bit for
/// bit its result), `y` read once for the four.
#[inline(always)]
fn dot4(x: [&[f32]; 4], y: &[f32]) -> [f32; 4] {
    let mut acc = [[0.0f32; 8]; 4];
    for (k, cy) in y.chunks_exact(8).enumerate() {
        for (r, acc) in acc.iter_mut().enumerate() {
            let cx = &x[r][8 * k..8 * k + 8];
            for l in 0..8 {
                acc[l] += cx[l] * cy[l];
            }
        }
    }
    acc.map(|a| a.iter().sum())
}

/// Rows of `a` per task.
const BLOCK: usize = 64;
/// Descriptors of `b` per tile: 128 KiB, within a core's L2 cache.
const TILE: usize = 256;

/// A row's best and second-best dot product and the best's index.
type RowBest = (f32, f32, usize);
/// A column's best dot product and its index.
type ColBest = (f32, usize);

/// For each row of `a` its `RowBest` among the rows of `b`, and for each row of `b` its
/// `ColBest` among the rows of `a`.
struct Nearest {
    row_best: Vec<RowBest>,
    col_best: Vec<ColBest>,
}

/// One block of `a`'s rows against every row of `b`: their `RowBest`s, and each row of `b`'s
/// `ColBest` among them.
#[inline(always)]
fn block_portable(
    a: &Features,
    b: &Features,
    rows: std::ops::Range<usize>,
) -> (Vec<RowBest>, Vec<ColBest>) {
    let nb = b.len();
    let mut col = vec![(f32::NEG_INFINITY, usize::MAX); nb];
    let mut out = vec![(f32::NEG_INFINITY, f32::NEG_INFINITY, 0); rows.len()];
    // Every row meets the columns in order and every column the rows in order, as a plain
    // double loop would: ties go to the first, whatever the grouping.
    let update = |o: &mut RowBest, c: &mut ColBest, i: usize, j: usize, d: f32| {
        if d > o.0 {
            o.1 = o.0;
            o.0 = d;
            o.2 = j;
        } else if d > o.1 {
            o.1 = d;
        }
        if d > c.0 {
            *c = (d, i);
        }
    };
    // `b` in tiles that stay in the cache while the block's rows pass over them.
    for tile in (0..nb).step_by(TILE) {
        let cols = tile..(tile + TILE).min(nb);
        // Four rows at a time, then the rest one by one.
        let mut i = rows.start;
        while i + 4 <= rows.end {
            let x = [0, 1, 2, 3].map(|r| a.descriptor(i + r));
            for j in cols.clone() {
                let d = dot4(x, b.descriptor(j));
                for (r, &d) in d.iter().enumerate() {
                    update(&mut out[i + r - rows.start], &mut col[j], i + r, j, d);
                }
            }
            i += 4;
        }
        for i in i..rows.end {
            let da = a.descriptor(i);
            for j in cols.clone() {
                let d = dot(da, b.descriptor(j));
                update(&mut out[i - rows.start], &mut col[j], i, j, d);
            }
        }
    }
    (out, col)
}

/// [`block_portable`] compiled for AVX2: the eight lanes of [`dot`] in one register. Multiply
/// and add stay separate (no FMA), so every dot product, and so every match, is bit for bit
/// the portable build's.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
fn block_avx2(
    a: &Features,
    b: &Features,
    rows: std::ops::Range<usize>,
) -> (Vec<RowBest>, Vec<ColBest>) {
    block_portable(a, b, rows)
}

/// [`block_portable`] on the widest vector unit this processor has.
fn block(a: &Features, b: &Features, rows: std::ops::Range<usize>) -> (Vec<RowBest>, Vec<ColBest>) {
    #[cfg(target_arch = "x86_64")]
    if std::arch::is_x86_feature_detected!("avx2") {
        // SAFETY: the processor has AVX2 (checked just above).
        return unsafe { block_avx2(a, b, rows) };
    }
    block_portable(a, b, rows)
}

fn nearest(a: &Features, b: &Features) -> Nearest {
    let nb = b.len();
    let blocks: Vec<(Vec<RowBest>, Vec<ColBest>)> = (0..a.len().div_ceil(BLOCK))
        .into_par_iter()
        .map(|blk| block(a, b, blk * BLOCK..((blk + 1) * BLOCK).min(a.len())))
        .collect();
    let mut row_best = Vec::with_capacity(a.len());
    let mut col_best = vec![(f32::NEG_INFINITY, usize::MAX); nb];
    for (rows, col) in blocks {
        row_best.extend(rows);
        // Blocks in row order, ties to the first row: the same result whatever the threads.
        for (c, d) in col_best.iter_mut().zip(col) {
            if d.0 > c.0 {
                *c = d;
            }
        }
    }
    Nearest { row_best, col_best }
}

/// Distance of unit vectors from their dot product.
fn distance(dot: f32) -> f32 {
    (2.0 - 2.0 * dot).max(0.0).sqrt()
}

/// The matches of `a`'s features to `b`'s, in the order of `a`.
pub fn match_features(a: &Features, b: &Features, s: &MatchSettings) -> Vec<Match> {
    if a.is_empty() || b.is_empty() {
        return Vec::new();
    }
    debug_assert_eq!(a.descriptors.len(), a.len() * DESCRIPTOR_LEN);
    let n = nearest(a, b);
    n.row_best
        .iter()
        .enumerate()
        .filter_map(|(i, &(best, second, j))| {
            let d1 = distance(best);
            let d2 = distance(second);
            let ratio_ok = b.len() < 2 || f64::from(d1) < s.ratio * f64::from(d2);
            let mutual_ok = !s.mutual || n.col_best[j].1 == i;
            (ratio_ok && mutual_ok).then_some(Match {
                a: i,
                b: j,
                distance: d1,
            })
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::super::{Keypoint, root_sift};
    use super::*;

    fn features(descriptors: Vec<Vec<f32>>) -> Features {
        let mut f = Features {
            width: 100,
            height: 100,
            ..Features::default()
        };
        for mut d in descriptors {
            root_sift(&mut d);
            f.keypoints.push(Keypoint {
                x: 0.0,
                y: 0.0,
                size: 1.0,
                angle_deg: 0.0,
                response: 1.0,
            });
            f.descriptors.extend(d);
        }
        f
    }

    fn random_descriptors(seed: u64, n: usize) -> Vec<Vec<f32>> {
        let mut state = seed;
        (0..n)
            .map(|_| {
                (0..DESCRIPTOR_LEN)
                    .map(|_| {
                        state = state
                            .wrapping_mul(6_364_136_223_846_793_005)
                            .wrapping_add(1_442_695_040_888_963_407);
                        ((state >> 40) % 256) as f32
                    })
                    .collect()
            })
            .collect()
    }

    /// The kernel by rows of four and one by one, portable and for AVX2: every block's bests
    /// bit for bit the same as a plain double loop of [`dot`] (and so every match, whatever
    /// the processor), ties included (duplicated descriptors).
    #[test]
    fn every_kernel_finds_the_same_bests_bit_for_bit() {
        let mut da = random_descriptors(3, 203);
        da[7] = da[5].clone();
        let mut db = random_descriptors(4, 300);
        db[11] = db[10].clone();
        db[299] = da[6].clone();
        let (a, b) = (features(da), features(db));
        // 198 rows: 49 groups of four and two left over.
        let rows = 3..201;
        let mut want_rows = Vec::new();
        let mut want_cols = vec![(f32::NEG_INFINITY, usize::MAX); b.len()];
        for i in rows.clone() {
            let mut o = (f32::NEG_INFINITY, f32::NEG_INFINITY, 0);
            for (j, c) in want_cols.iter_mut().enumerate() {
                let d = dot(a.descriptor(i), b.descriptor(j));
                if d > o.0 {
                    o = (d, o.0, j);
                } else if d > o.1 {
                    o.1 = d;
                }
                if d > c.0 {
                    *c = (d, i);
                }
            }
            want_rows.push(o);
        }
        let bits = |v: &[RowBest]| {
            v.iter()
                .map(|o| (o.0.to_bits(), o.1.to_bits(), o.2))
                .collect::<Vec<_>>()
        };
        let col_bits = |v: &[ColBest]| v.iter().map(|c| (c.0.to_bits(), c.1)).collect::<Vec<_>>();
        let (r, c) = block_portable(&a, &b, rows.clone());
        assert_eq!(bits(&r), bits(&want_rows));
        assert_eq!(col_bits(&c), col_bits(&want_cols));
        let (r, c) = block(&a, &b, rows.clone());
        assert_eq!(bits(&r), bits(&want_rows));
        assert_eq!(col_bits(&c), col_bits(&want_cols));
    }

    /// The brute-force matcher against a plain double loop: the same matches.
    #[test]
    fn matches_are_the_mutual_nearest_that_pass_the_ratio() {
        let da = random_descriptors(1, 300);
        // b: a shuffled, slightly perturbed copy of the first 200 of a, and 100 others.
        let mut db: Vec<Vec<f32>> = (0..200)
            .map(|i| {
                let src = &da[(i * 7) % 200];
                src.iter()
                    .enumerate()
                    .map(|(k, v)| v + ((k + i) % 5) as f32)
                    .collect()
            })
            .collect();
        db.extend(random_descriptors(2, 100));
        let (a, b) = (features(da), features(db));
        let s = MatchSettings::default();
        let got = match_features(&a, &b, &s);
        // Reference.
        let d = |i: usize, j: usize| -> f32 {
            let x = a.descriptor(i);
            let y = b.descriptor(j);
            x.iter()
                .zip(y)
                .map(|(p, q)| (p - q) * (p - q))
                .sum::<f32>()
                .sqrt()
        };
        let mut expect = Vec::new();
        for i in 0..a.len() {
            let mut ds: Vec<(f32, usize)> = (0..b.len()).map(|j| (d(i, j), j)).collect();
            ds.sort_by(|x, y| x.0.total_cmp(&y.0));
            let j = ds[0].1;
            let back = (0..a.len())
                .min_by(|&p, &q| d(p, j).total_cmp(&d(q, j)))
                .unwrap();
            if f64::from(ds[0].0) < 0.8 * f64::from(ds[1].0) && back == i {
                expect.push((i, j));
            }
        }
        let got_pairs: Vec<(usize, usize)> = got.iter().map(|m| (m.a, m.b)).collect();
        assert_eq!(got_pairs, expect);
        // The planted pairs are found.
        assert!(got_pairs.len() >= 190, "{}", got_pairs.len());
        for (i, j) in &got_pairs {
            if *j < 200 {
                assert_eq!(*i, (j * 7) % 200);
            }
        }
    }

    #[test]
    fn nothing_to_match() {
        let a = features(random_descriptors(3, 5));
        assert!(match_features(&a, &Features::default(), &MatchSettings::default()).is_empty());
    }
}
