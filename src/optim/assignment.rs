//! Optimal assignment (pure): the Hungarian method (Kuhn–Munkres, in the shortest augmenting path
//! form, O(n² m)) on a rectangular cost matrix, with a gate: pairs dearer than the gate are never
//! matched, and leaving a row unmatched costs the gate.

/// Assigns rows to columns minimising the total cost; `None` for a row left unmatched. Costs
/// above `gate` (or not finite) forbid a pair.
pub fn assign(cost: &[Vec<f64>], gate: f64) -> Vec<Option<usize>> {
    let n = cost.len();
    if n == 0 {
        return Vec::new();
    }
    let m = cost[0].len();
    // Columns: the real ones, then one private "unmatched" column per row at the gate's cost.
    let cols = m + n;
    let big = 1e18;
    let c = |i: usize, j: usize| -> f64 {
        if j < m {
            let v = cost[i][j];
            if v.is_finite() && v <= gate { v } else { big }
        } else if j - m == i {
            gate
        } else {
            big
        }
    };
    // Potentials u (rows, 1-based), v (columns), p[j] = row matched to column j, way = path.
    let mut u = vec![0.0; n + 1];
    let mut v = vec![0.0; cols + 1];
    let mut p = vec![0usize; cols + 1];
    let mut way = vec![0usize; cols + 1];
    for i in 1..=n {
        p[0] = i;
        let mut j0 = 0;
        let mut minv = vec![f64::INFINITY; cols + 1];
        let mut used = vec![false; cols + 1];
        loop {
            used[j0] = true;
            let i0 = p[j0];
            let mut delta = f64::INFINITY;
            let mut j1 = 0;
            for j in 1..=cols {
                if !used[j] {
                    let cur = c(i0 - 1, j - 1) - u[i0] - v[j];
                    if cur < minv[j] {
                        minv[j] = cur;
                        way[j] = j0;
                    }
                    if minv[j] < delta {
                        delta = minv[j];
                        j1 = j;
                    }
                }
            }
            for j in 0..=cols {
                if used[j] {
                    u[p[j]] += delta;
                    v[j] -= delta;
                } else {
                    minv[j] -= delta;
                }
            }
            j0 = j1;
            if p[j0] == 0 {
                break;
            }
        }
        loop {
            let j1 = way[j0];
            p[j0] = p[j1];
            j0 = j1;
            if j0 == 0 {
                break;
            }
        }
    }
    let mut out = vec![None; n];
    for j in 1..=m {
        if p[j] != 0 && c(p[j] - 1, j - 1) < big {
            out[p[j] - 1] = Some(j - 1);
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Brute force over all injective partial assignments.
    fn brute(cost: &[Vec<f64>], gate: f64) -> f64 {
        fn rec(i: usize, cost: &[Vec<f64>], gate: f64, used: &mut Vec<bool>) -> f64 {
            if i == cost.len() {
                return 0.0;
            }
            let mut best = gate + rec(i + 1, cost, gate, used);
            for j in 0..used.len() {
                if !used[j] && cost[i][j] <= gate {
                    used[j] = true;
                    best = best.min(cost[i][j] + rec(i + 1, cost, gate, used));
                    used[j] = false;
                }
            }
            best
        }
        rec(0, cost, gate, &mut vec![false; cost[0].len()])
    }

    fn total(cost: &[Vec<f64>], a: &[Option<usize>], gate: f64) -> f64 {
        a.iter()
            .enumerate()
            .map(|(i, j)| j.map_or(gate, |j| cost[i][j]))
            .sum()
    }

    #[test]
    fn matches_brute_force_on_random_matrices() {
        let mut state = 12345u64;
        let mut next = || {
            state = state
                .wrapping_mul(6364136223846793005)
                .wrapping_add(1442695040888963407);
            (state >> 33) as f64 / (1u64 << 31) as f64
        };
        for (n, m) in [(1, 1), (3, 3), (4, 6), (6, 4), (5, 5), (7, 3)] {
            for _ in 0..30 {
                let cost: Vec<Vec<f64>> = (0..n)
                    .map(|_| (0..m).map(|_| 10.0 * next()).collect())
                    .collect();
                let gate = 6.0;
                let a = assign(&cost, gate);
                let mut cols: Vec<usize> = a.iter().flatten().copied().collect();
                cols.sort();
                cols.dedup();
                assert_eq!(
                    cols.len(),
                    a.iter().flatten().count(),
                    "a column used twice"
                );
                assert!(
                    a.iter()
                        .enumerate()
                        .all(|(i, j)| j.is_none_or(|j| cost[i][j] <= gate))
                );
                assert!(
                    (total(&cost, &a, gate) - brute(&cost, gate)).abs() < 1e-9,
                    "{n}x{m}"
                );
            }
        }
        assert!(assign(&[], 1.0).is_empty());
        assert_eq!(assign(&[vec![]], 1.0), vec![None]);
    }
}
