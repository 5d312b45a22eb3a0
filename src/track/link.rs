//! Tracks of consecutive chunks of a video joined into one set (pure): chunk `c` was tracked
//! afresh from a few frames before the frames it owns, so each of its tracks that was already
//! under way shares those overlap frames' detections with a track of chunk `c − 1`. Tracks that
//! share the most are joined, one to one; the chunk before gives the points of the frames it
//! owns. The joined tracks are numbered canonically (by first frame, then position), so that
//! the numbers do not depend on how the chunks were run.

use std::cmp::Ordering;

use super::{ImageTrack, TrackPoint};

/// One chunk's tracks and the frames it owns; `decode_from..start` is its overlap with the
/// chunk before.
pub struct ChunkTracks {
    pub decode_from: usize,
    pub start: usize,
    pub end: usize,
    pub tracks: Vec<ImageTrack>,
}

/// How strictly two tracks must agree to be one person.
#[derive(Clone, Copy, Debug)]
pub struct LinkSettings {
    /// Points closer than this in a frame are the same detection, pixels.
    pub same_px: f64,
    /// Fewest shared frames for a join.
    pub min_shared: usize,
}

/// What linking did, for the report.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct LinkStats {
    /// Tracks joined across a chunk border.
    pub joined: usize,
    /// Tracks of a later chunk that were under way in its overlap but matched nothing.
    pub unmatched: usize,
}

/// Frames in which `a` and `b` are within `same_px` of each other, among `frames`.
fn shared(
    a: &[TrackPoint],
    b: &[TrackPoint],
    frames: std::ops::Range<usize>,
    same_px: f64,
) -> usize {
    let (mut i, mut j, mut n) = (0, 0, 0);
    while i < a.len() && j < b.len() {
        let (fa, fb) = (a[i].frame, b[j].frame);
        match fa.cmp(&fb) {
            Ordering::Less => i += 1,
            Ordering::Greater => j += 1,
            Ordering::Equal => {
                if frames.contains(&fa) && (a[i].uv - b[j].uv).norm() <= same_px {
                    n += 1;
                }
                i += 1;
                j += 1;
            }
        }
    }
    n
}

/// Joins the chunks' tracks (given in chunk order) and numbers them from 1.
pub fn link_chunks(chunks: Vec<ChunkTracks>, s: &LinkSettings) -> (Vec<ImageTrack>, LinkStats) {
    let mut stats = LinkStats::default();
    // Every track so far, as its points; `open` indexes those that reach the current chunk's
    // overlap.
    let mut all: Vec<Vec<TrackPoint>> = Vec::new();
    for chunk in chunks {
        let overlap = chunk.decode_from..chunk.start;
        let open: Vec<usize> = (0..all.len())
            .filter(|&k| {
                all[k]
                    .last()
                    .is_some_and(|p| p.frame >= overlap.start && !overlap.is_empty())
            })
            .collect();
        // Every pair that shares frames, most shared first (ties in a fixed order).
        let mut pairs: Vec<(usize, usize, usize)> = Vec::new();
        for (b, t) in chunk.tracks.iter().enumerate() {
            for &a in &open {
                let n = shared(&all[a], &t.points, overlap.clone(), s.same_px);
                if n >= s.min_shared {
                    pairs.push((n, a, b));
                }
            }
        }
        pairs.sort_by(|x, y| y.0.cmp(&x.0).then(x.1.cmp(&y.1)).then(x.2.cmp(&y.2)));
        let mut a_taken = vec![false; all.len()];
        let mut b_to: Vec<Option<usize>> = vec![None; chunk.tracks.len()];
        for (_, a, b) in pairs {
            if !a_taken[a] && b_to[b].is_none() {
                a_taken[a] = true;
                b_to[b] = Some(a);
            }
        }
        for (b, t) in chunk.tracks.into_iter().enumerate() {
            // The chunk before gives the points of the frames it owns.
            let own: Vec<TrackPoint> = t
                .points
                .into_iter()
                .filter(|p| p.frame >= chunk.start && p.frame < chunk.end)
                .collect();
            match b_to[b] {
                Some(a) => {
                    stats.joined += 1;
                    all[a].extend(own);
                }
                None => {
                    if !overlap.is_empty() && own.first().is_some_and(|p| p.frame == chunk.start) {
                        stats.unmatched += 1;
                    }
                    if !own.is_empty() {
                        all.push(own);
                    }
                }
            }
        }
    }
    all.retain(|p| !p.is_empty());
    all.sort_by(|a, b| {
        let (p, q) = (&a[0], &b[0]);
        p.frame
            .cmp(&q.frame)
            .then(p.uv.x.total_cmp(&q.uv.x))
            .then(p.uv.y.total_cmp(&q.uv.y))
            .then(a.len().cmp(&b.len()))
    });
    let tracks = all
        .into_iter()
        .enumerate()
        .map(|(k, points)| ImageTrack { id: k + 1, points })
        .collect();
    (tracks, stats)
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::{Matrix2, Vector2};

    fn track(id: usize, frames: std::ops::Range<usize>, x0: f64, vx: f64) -> ImageTrack {
        ImageTrack {
            id,
            points: frames
                .map(|f| TrackPoint {
                    frame: f,
                    uv: Vector2::new(x0 + vx * f as f64, 100.0),
                    cov: Matrix2::identity(),
                    bbox: [0.0; 4],
                })
                .collect(),
        }
    }

    const S: LinkSettings = LinkSettings {
        same_px: 0.5,
        min_shared: 3,
    };

    #[test]
    fn a_person_crossing_a_border_stays_one_track_and_crossers_are_not_swapped() {
        // Two people crossing at frame 10 (x = 50), the border at frame 10, overlap 6..10.
        let c0 = ChunkTracks {
            decode_from: 0,
            start: 0,
            end: 10,
            tracks: vec![track(7, 0..10, 0.0, 5.0), track(3, 0..10, 100.0, -5.0)],
        };
        let c1 = ChunkTracks {
            decode_from: 6,
            start: 10,
            end: 20,
            tracks: vec![track(1, 6..20, 100.0, -5.0), track(2, 6..20, 0.0, 5.0)],
        };
        let (t, stats) = link_chunks(vec![c0, c1], &S);
        assert_eq!(stats.joined, 2);
        assert_eq!(t.len(), 2);
        // Numbered by first frame then position: the one from x = 0 is 1.
        assert_eq!(t[0].id, 1);
        assert_eq!(t[0].points.len(), 20);
        assert!(
            t[0].points
                .iter()
                .all(|p| (p.uv.x - 5.0 * p.frame as f64).abs() < 1e-9)
        );
        assert!(
            t[1].points
                .iter()
                .all(|p| (p.uv.x - (100.0 - 5.0 * p.frame as f64)).abs() < 1e-9)
        );
    }

    #[test]
    fn a_person_first_seen_after_the_border_is_a_new_track_and_one_that_left_ends() {
        let c0 = ChunkTracks {
            decode_from: 0,
            start: 0,
            end: 10,
            tracks: vec![track(1, 0..5, 0.0, 1.0)],
        };
        let c1 = ChunkTracks {
            decode_from: 6,
            start: 10,
            end: 20,
            tracks: vec![track(1, 12..20, 300.0, 1.0)],
        };
        let (t, stats) = link_chunks(vec![c0, c1], &S);
        assert_eq!(stats, LinkStats::default());
        assert_eq!(t.len(), 2);
        assert_eq!(t[1].points[0].frame, 12);
    }

    #[test]
    fn too_few_shared_frames_do_not_join() {
        let c0 = ChunkTracks {
            decode_from: 0,
            start: 0,
            end: 10,
            tracks: vec![track(1, 0..8, 0.0, 1.0)],
        };
        let c1 = ChunkTracks {
            decode_from: 6,
            start: 10,
            end: 20,
            tracks: vec![track(1, 6..20, 0.0, 1.0)],
        };
        let (t, stats) = link_chunks(vec![c0, c1], &S);
        assert_eq!(stats.joined, 0);
        assert_eq!(stats.unmatched, 1);
        assert_eq!(t.len(), 2);
    }
}
