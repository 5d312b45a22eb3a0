//! Stage 3, `track`: the chunks' image tracks joined into one set.

use super::*;
use crate::track::link::{ChunkTracks, LinkSettings, link_chunks};

/// Stage 3: image tracks. The chunks' tracks are taken from `scan_data` (nothing later needs
/// them: the merge of a long video holds each point once).
pub(super) fn track_stage(
    ctx: &Ctx,
    scan_key: &str,
    scan_data: &mut ScanData,
) -> Result<(Vec<ImageTrack>, String, StageRecord), RunError> {
    let fps = ctx.fps;
    let p = &ctx.l.project;
    let track_key = stage_key("track", &[scan_key], &p.track);
    let t0 = Instant::now();
    let mut joined = (0.0, 0.0);
    let chunk_tracks = std::mem::take(&mut scan_data.chunk_tracks);
    let frames = scan_data.frames;
    let (tracks, status) = cached(&ctx.cache, ctx.progress, "track", &track_key, true, || {
        let chunks = chunk_tracks
            .into_iter()
            .map(|c| ChunkTracks {
                decode_from: c.decode_from,
                start: c.start,
                end: c.end,
                tracks: c.tracks,
            })
            .collect();
        let overlap = ctx.grid.overlap_frames;
        let (tracks, stats) = link_chunks(
            chunks,
            &LinkSettings {
                // The same detection in both chunks: within 5 cm at head height.
                same_px: (0.05 * ctx.px_per_m).max(0.5),
                min_shared: overlap.clamp(1, 3),
            },
        );
        joined = (stats.joined as f64, stats.unmatched as f64);
        // Short tracks are mostly false alarms, unless the video's start or end cut them.
        let min_frames = (p.track.min_length_s() * fps).round() as usize;
        let last = frames.saturating_sub(1);
        let tracks: Vec<ImageTrack> = tracks
            .into_iter()
            .filter(|t| {
                let (a, b) = (
                    t.points.first().map_or(0, |q| q.frame),
                    t.points.last().map_or(0, |q| q.frame),
                );
                b - a + 1 >= min_frames || a == 0 || b == last
            })
            .enumerate()
            .map(|(k, mut t)| {
                t.id = k + 1;
                t
            })
            .collect();
        Ok(tracks)
    })?;
    let lengths: Vec<f64> = tracks.iter().map(|t| t.points.len() as f64 / fps).collect();
    let mut counts = BTreeMap::from([
        ("tracks".into(), tracks.len() as f64),
        (
            "points".into(),
            tracks.iter().map(|t| t.points.len()).sum::<usize>() as f64,
        ),
        (
            "mean_length_s".into(),
            lengths.iter().sum::<f64>() / lengths.len().max(1) as f64,
        ),
    ]);
    if status == "computed" {
        counts.insert("joined_at_chunk_borders".into(), joined.0);
        counts.insert("unmatched_at_chunk_borders".into(), joined.1);
    }
    let record = StageRecord {
        name: "track".into(),
        status: status.into(),
        seconds: t0.elapsed().as_secs_f64(),
        counts,
    };

    Ok((tracks, track_key, record))
}
