//! Tracks (pure): the matches of every image pair joined by union–find into features seen in
//! several images; a track that would hold two features of one image is a conflict and is
//! dropped whole.

use std::collections::HashMap;

/// A feature: image and keypoint index.
pub type FeatureId = (usize, usize);

/// The matches between images `i < j`: keypoint of `i`, keypoint of `j`.
#[derive(Clone, Debug, Default)]
pub struct PairMatches {
    pub i: usize,
    pub j: usize,
    pub matches: Vec<(usize, usize)>,
}

struct UnionFind {
    parent: Vec<usize>,
    size: Vec<usize>,
}

impl UnionFind {
    fn new(n: usize) -> Self {
        UnionFind {
            parent: (0..n).collect(),
            size: vec![1; n],
        }
    }

    fn find(&mut self, mut a: usize) -> usize {
        while self.parent[a] != a {
            self.parent[a] = self.parent[self.parent[a]];
            a = self.parent[a];
        }
        a
    }

    fn union(&mut self, a: usize, b: usize) {
        let (mut a, mut b) = (self.find(a), self.find(b));
        if a == b {
            return;
        }
        if self.size[a] < self.size[b] {
            std::mem::swap(&mut a, &mut b);
        }
        self.parent[b] = a;
        self.size[a] += self.size[b];
    }
}

/// The tracks of `pairs` (each at least two features, images in ascending order), and how many
/// were dropped for holding two features of one image. Deterministic: tracks ordered by their
/// first feature.
pub fn build_tracks(pairs: &[PairMatches]) -> (Vec<Vec<FeatureId>>, usize) {
    let mut ids: HashMap<FeatureId, usize> = HashMap::new();
    let mut features: Vec<FeatureId> = Vec::new();
    let mut id = |f: FeatureId, features: &mut Vec<FeatureId>| -> usize {
        *ids.entry(f).or_insert_with(|| {
            features.push(f);
            features.len() - 1
        })
    };
    let mut edges = Vec::new();
    for p in pairs {
        for &(a, b) in &p.matches {
            let ia = id((p.i, a), &mut features);
            let ib = id((p.j, b), &mut features);
            edges.push((ia, ib));
        }
    }
    let mut uf = UnionFind::new(features.len());
    for (a, b) in edges {
        uf.union(a, b);
    }
    let mut groups: HashMap<usize, Vec<FeatureId>> = HashMap::new();
    for (k, f) in features.iter().enumerate() {
        groups.entry(uf.find(k)).or_default().push(*f);
    }
    let mut tracks = Vec::new();
    let mut conflicts = 0;
    for mut t in groups.into_values() {
        t.sort_unstable();
        if t.windows(2).any(|w| w[0].0 == w[1].0) {
            conflicts += 1;
            continue;
        }
        tracks.push(t);
    }
    tracks.sort_unstable();
    (tracks, conflicts)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn matches_join_into_tracks_and_conflicts_are_dropped() {
        let pairs = vec![
            PairMatches {
                i: 0,
                j: 1,
                matches: vec![(0, 5), (1, 6), (2, 7)],
            },
            PairMatches {
                i: 1,
                j: 2,
                matches: vec![(5, 9), (6, 10)],
            },
            // Closes 0-1-2 for feature (0,0); makes (0,1) and (0,2) one track: a conflict.
            PairMatches {
                i: 0,
                j: 2,
                matches: vec![(0, 9), (2, 10)],
            },
        ];
        let (tracks, conflicts) = build_tracks(&pairs);
        assert_eq!(tracks, vec![vec![(0, 0), (1, 5), (2, 9)]]);
        assert_eq!(conflicts, 1);
    }
}
