//! Tracks (pure): the matches of every image pair joined by union–find into features seen in
//! several images. Pairs are joined in the order given (the best-verified first): a match that
//! would put two features of one image in a track is refused, and the track keeps the
//! features it already has.

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
    /// Per root, the images of its features (a bit set, `words` words a set).
    images: Vec<u64>,
    words: usize,
}

impl UnionFind {
    fn new(features: &[FeatureId], n_images: usize) -> Self {
        let words = n_images.div_ceil(64).max(1);
        let mut images = vec![0u64; features.len() * words];
        for (k, f) in features.iter().enumerate() {
            images[k * words + f.0 / 64] |= 1 << (f.0 % 64);
        }
        UnionFind {
            parent: (0..features.len()).collect(),
            size: vec![1; features.len()],
            images,
            words,
        }
    }

    fn find(&mut self, mut a: usize) -> usize {
        while self.parent[a] != a {
            self.parent[a] = self.parent[self.parent[a]];
            a = self.parent[a];
        }
        a
    }

    /// Joins the tracks of `a` and `b` unless they share an image; `false` when refused.
    fn union(&mut self, a: usize, b: usize) -> bool {
        let (mut a, mut b) = (self.find(a), self.find(b));
        if a == b {
            return true;
        }
        let w = self.words;
        if (0..w).any(|k| self.images[a * w + k] & self.images[b * w + k] != 0) {
            return false;
        }
        if self.size[a] < self.size[b] {
            std::mem::swap(&mut a, &mut b);
        }
        self.parent[b] = a;
        self.size[a] += self.size[b];
        for k in 0..w {
            self.images[a * w + k] |= self.images[b * w + k];
        }
        true
    }
}

/// The tracks of `pairs` (each at least two features, images in ascending order), and how many
/// matches were refused for joining two features of one image. Deterministic: tracks ordered by
/// their first feature.
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
    let n_images = features.iter().map(|f| f.0 + 1).max().unwrap_or(0);
    let mut uf = UnionFind::new(&features, n_images);
    let mut refused = 0;
    for (a, b) in edges {
        refused += usize::from(!uf.union(a, b));
    }
    let mut groups: HashMap<usize, Vec<FeatureId>> = HashMap::new();
    for (k, f) in features.iter().enumerate() {
        groups.entry(uf.find(k)).or_default().push(*f);
    }
    let mut tracks: Vec<Vec<FeatureId>> = groups
        .into_values()
        .filter(|t| t.len() >= 2)
        .map(|mut t| {
            t.sort_unstable();
            t
        })
        .collect();
    tracks.sort_unstable();
    (tracks, refused)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn matches_join_into_tracks_and_conflicting_matches_are_refused() {
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
        let (tracks, refused) = build_tracks(&pairs);
        // (0,2)–(2,10) would join (0,2)'s track with (0,1)'s through (1,6)–(2,10): refused.
        assert_eq!(
            tracks,
            vec![
                vec![(0, 0), (1, 5), (2, 9)],
                vec![(0, 1), (1, 6), (2, 10)],
                vec![(0, 2), (1, 7)],
            ]
        );
        assert_eq!(refused, 1);
    }
}
