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

/// A squared Mahalanobis distance within which two tracks' points are one person's (the χ²
/// of two degrees of freedom's 99 %).
const SAME_CHI2: f64 = 9.21;

/// Frames among `frames` in which `a` and `b` are one person's points, and their squared
/// distances summed, px². The same detection gives the same point in both chunks only for a
/// tracker that keeps its detections; a smoothing one (`klt`) ends a chunk's track and begins
/// the next one's from different frames, so their points differ by up to their uncertainty:
/// within `same_px`, or within the two points' covariances.
fn shared(
    a: &[TrackPoint],
    b: &[TrackPoint],
    frames: std::ops::Range<usize>,
    same_px: f64,
) -> (usize, f64) {
    let (mut i, mut j, mut n, mut sum_d2) = (0, 0, 0, 0.0);
    while i < a.len() && j < b.len() {
        let (fa, fb) = (a[i].frame, b[j].frame);
        match fa.cmp(&fb) {
            Ordering::Less => i += 1,
            Ordering::Greater => j += 1,
            Ordering::Equal => {
                let d = a[i].uv - b[j].uv;
                let near = d.norm() <= same_px
                    || (a[i].cov + b[j].cov)
                        .try_inverse()
                        .is_some_and(|inv| (d.transpose() * inv * d)[(0, 0)] <= SAME_CHI2);
                if frames.contains(&fa) && near {
                    n += 1;
                    sum_d2 += d.norm_squared();
                }
                i += 1;
                j += 1;
            }
        }
    }
    (n, sum_d2)
}

/// A joined track that can grow no more, with its number in the order tracks were begun (the
/// last key of [`canonical_order`]).
pub struct Closed {
    pub begun: usize,
    pub points: Vec<TrackPoint>,
}

/// The canonical order of joined tracks: by first frame, then first position, then length,
/// then the order they were begun. `(first point, length, begun)` of each.
pub fn canonical_order(a: (&TrackPoint, usize, usize), b: (&TrackPoint, usize, usize)) -> Ordering {
    let ((p, na, ka), (q, nb, kb)) = (a, b);
    p.frame
        .cmp(&q.frame)
        .then(p.uv.x.total_cmp(&q.uv.x))
        .then(p.uv.y.total_cmp(&q.uv.y))
        .then(na.cmp(&nb))
        .then(ka.cmp(&kb))
}

/// Joins the chunks' tracks a chunk at a time (chunks in order, their overlaps starting later
/// and later) and gives away each joined track as soon as no later chunk can extend it: a long
/// video's tracks are never all in memory, only those under way.
pub struct Linker {
    s: LinkSettings,
    /// The tracks that may still grow, in the order they were begun, with that number.
    live: Vec<(usize, Vec<TrackPoint>)>,
    begun: usize,
    stats: LinkStats,
}

impl Linker {
    pub fn new(s: LinkSettings) -> Linker {
        Linker {
            s,
            live: Vec::new(),
            begun: 0,
            stats: LinkStats::default(),
        }
    }

    /// Adds the next chunk's tracks; the tracks that ended before its overlap go to `closed`.
    pub fn push<E>(
        &mut self,
        chunk: ChunkTracks,
        closed: &mut dyn FnMut(Closed) -> Result<(), E>,
    ) -> Result<(), E> {
        let s = &self.s;
        let overlap = chunk.decode_from..chunk.start;
        // Tracks that end before this overlap are never reached again.
        let (keep, gone): (Vec<_>, Vec<_>) = std::mem::take(&mut self.live)
            .into_iter()
            .partition(|(_, p)| p.last().is_some_and(|p| p.frame >= overlap.start));
        self.live = keep;
        for (begun, points) in gone {
            closed(Closed { begun, points })?;
        }
        let live = &mut self.live;
        let open: Vec<usize> = if overlap.is_empty() {
            Vec::new()
        } else {
            (0..live.len()).collect()
        };
        // Every pair that shares frames, most shared first, then nearest (mean squared
        // distance), then in a fixed order: the order the tracks were begun, then the chunk's.
        let mut pairs: Vec<(usize, f64, usize, usize)> = Vec::new();
        for (b, t) in chunk.tracks.iter().enumerate() {
            for &a in &open {
                let (n, sum_d2) = shared(&live[a].1, &t.points, overlap.clone(), s.same_px);
                if n >= s.min_shared {
                    pairs.push((n, sum_d2 / n as f64, a, b));
                }
            }
        }
        pairs.sort_by(|x, y| {
            y.0.cmp(&x.0)
                .then(x.1.total_cmp(&y.1))
                .then(x.2.cmp(&y.2))
                .then(x.3.cmp(&y.3))
        });
        let mut a_taken = vec![false; live.len()];
        let mut b_to: Vec<Option<usize>> = vec![None; chunk.tracks.len()];
        for (_, _, a, b) in pairs {
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
                    self.stats.joined += 1;
                    live[a].1.extend(own);
                }
                None => {
                    if !overlap.is_empty() && own.first().is_some_and(|p| p.frame == chunk.start) {
                        self.stats.unmatched += 1;
                    }
                    if !own.is_empty() {
                        live.push((self.begun, own));
                        self.begun += 1;
                    }
                }
            }
        }
        Ok(())
    }

    /// The tracks still under way go to `closed`; what linking did.
    pub fn finish<E>(
        self,
        closed: &mut dyn FnMut(Closed) -> Result<(), E>,
    ) -> Result<LinkStats, E> {
        for (begun, points) in self.live {
            closed(Closed { begun, points })?;
        }
        Ok(self.stats)
    }
}

/// Joins the chunks' tracks (given in chunk order) and numbers them from 1 in the
/// [`canonical_order`].
pub fn link_chunks(chunks: Vec<ChunkTracks>, s: &LinkSettings) -> (Vec<ImageTrack>, LinkStats) {
    let mut linker = Linker::new(*s);
    let mut all: Vec<Closed> = Vec::new();
    let mut keep = |c: Closed| -> Result<(), std::convert::Infallible> {
        all.push(c);
        Ok(())
    };
    for chunk in chunks {
        let Ok(()) = linker.push(chunk, &mut keep);
    }
    let Ok(stats) = linker.finish(&mut keep);
    all.sort_by(|a, b| {
        canonical_order(
            (&a.points[0], a.points.len(), a.begun),
            (&b.points[0], b.points.len(), b.begun),
        )
    });
    let tracks = all
        .into_iter()
        .enumerate()
        .map(|(k, c)| ImageTrack {
            id: k + 1,
            points: c.points,
        })
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
                    score: Some(1.0),
                })
                .collect(),
        }
    }

    /// Chunk 0 owns frames 0..10, chunk 1 frames 10..20 and is tracked from frame 6.
    fn two_chunks(first: Vec<ImageTrack>, second: Vec<ImageTrack>) -> [ChunkTracks; 2] {
        [
            ChunkTracks {
                decode_from: 0,
                start: 0,
                end: 10,
                tracks: first,
            },
            ChunkTracks {
                decode_from: 6,
                start: 10,
                end: 20,
                tracks: second,
            },
        ]
    }

    const S: LinkSettings = LinkSettings {
        same_px: 0.5,
        min_shared: 3,
    };

    #[test]
    fn a_person_crossing_a_border_stays_one_track_and_crossers_are_not_swapped() {
        // Two people crossing at frame 10 (x = 50), the border at frame 10, overlap 6..10.
        let [c0, c1] = two_chunks(
            vec![track(7, 0..10, 0.0, 5.0), track(3, 0..10, 100.0, -5.0)],
            vec![track(1, 6..20, 100.0, -5.0), track(2, 6..20, 0.0, 5.0)],
        );
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
        let [c0, c1] = two_chunks(
            vec![track(1, 0..5, 0.0, 1.0)],
            vec![track(1, 12..20, 300.0, 1.0)],
        );
        // Streamed: the track that ended at frame 4 is given away when the next chunk comes
        // (its overlap starts later), the other at the end.
        let mut linker = Linker::new(S);
        let mut closed: Vec<(usize, usize)> = Vec::new();
        let copy = |c: &ChunkTracks| ChunkTracks {
            tracks: c.tracks.clone(),
            ..*c
        };
        let take = |closed: &mut Vec<(usize, usize)>, c: Closed| -> Result<(), ()> {
            closed.push((c.begun, c.points[0].frame));
            Ok(())
        };
        linker
            .push(copy(&c0), &mut |c| take(&mut closed, c))
            .unwrap();
        assert!(closed.is_empty());
        linker
            .push(copy(&c1), &mut |c| take(&mut closed, c))
            .unwrap();
        assert_eq!(closed, vec![(0, 0)]);
        linker.finish(&mut |c| take(&mut closed, c)).unwrap();
        assert_eq!(closed, vec![(0, 0), (1, 12)]);
        let (t, stats) = link_chunks(vec![c0, c1], &S);
        assert_eq!(stats, LinkStats::default());
        assert_eq!(t.len(), 2);
        assert_eq!(t[1].points[0].frame, 12);
    }

    /// A track along x at height `y`, each point of covariance `var_px2`·I.
    fn track_at(frames: std::ops::Range<usize>, x0: f64, y: f64, var_px2: f64) -> ImageTrack {
        let mut t = track(0, frames, x0, 2.0);
        for p in &mut t.points {
            p.uv.y = y;
            p.cov = Matrix2::identity() * var_px2;
        }
        t
    }

    #[test]
    fn smoothed_tracks_that_differ_by_their_uncertainty_join_to_the_nearest() {
        // A smoothing tracker ends chunk 0's track and begins chunk 1's a few pixels apart
        // (σ 2 px each): one person, though farther apart than `same_px`.
        let [c0, c1] = two_chunks(
            vec![track_at(0..10, 0.0, 100.0, 4.0)],
            vec![track_at(6..20, 0.0, 103.0, 4.0)],
        );
        let (t, stats) = link_chunks(vec![c0, c1], &S);
        assert_eq!((stats.joined, stats.unmatched, t.len()), (1, 0, 1));
        assert_eq!(t[0].points.len(), 20);
        // Two people side by side, 6 px apart (σ 3 px): each of chunk 1's tracks is within
        // both gates and shares all the overlap with both; each joins the nearer.
        let [c0, c1] = two_chunks(
            vec![
                track_at(0..10, 0.0, 100.0, 9.0),
                track_at(0..10, 0.0, 106.0, 9.0),
            ],
            vec![
                track_at(6..20, 0.0, 104.0, 9.0),
                track_at(6..20, 0.0, 101.0, 9.0),
            ],
        );
        let (t, stats) = link_chunks(vec![c0, c1], &S);
        assert_eq!((stats.joined, t.len()), (2, 2));
        for t in &t {
            let (first, last) = (t.points[0].uv.y, t.points[19].uv.y);
            assert!(
                (first, last) == (100.0, 101.0) || (first, last) == (106.0, 104.0),
                "joined {first} to {last}"
            );
        }
    }

    #[test]
    fn too_few_shared_frames_do_not_join() {
        let [c0, c1] = two_chunks(
            vec![track(1, 0..8, 0.0, 1.0)],
            vec![track(1, 6..20, 0.0, 1.0)],
        );
        let (t, stats) = link_chunks(vec![c0, c1], &S);
        assert_eq!(stats.joined, 0);
        assert_eq!(stats.unmatched, 1);
        assert_eq!(t.len(), 2);
    }
}
