//! Stage 3, `track`: the chunks' image tracks joined into one set.

use std::collections::BTreeMap;
use std::time::Instant;

use serde::{Deserialize, Serialize};

use super::{Env, RunError, RunInputs, StageRecord, StageStatus, cached_seq};
use crate::cache::{cache_gone, stage_key};
use crate::pipeline::settings::TrackSection;
use crate::track::link::{ChunkTracks, Closed, LinkSettings, Linker, canonical_order};
use crate::track::{ImageTrack, TrackPoint};

/// What the track stage's cache holds besides the tracks themselves (`track.bin`, in order of
/// identity, read back a track at a time).
#[derive(Clone, Debug, Serialize, Deserialize)]
pub(super) struct TrackSummary {
    pub tracks: usize,
    pub points: usize,
    pub mean_length_s: f64,
}

/// A joined track set aside in the spill file until every track is known and they can be
/// numbered: its place there and what orders it.
struct Spilled {
    first: TrackPoint,
    len: usize,
    begun: usize,
    offset: u64,
}

/// Stage 3: image tracks. The chunks are read back a chunk at a time and each joined track is
/// set aside on disk as soon as no later chunk can extend it; the tracks are then numbered in
/// their canonical order and cached in that order. Memory: the tracks under way and a small
/// index per track, whatever the video's length.
pub(super) fn track_stage(
    env: &Env,
    x: &RunInputs,
    settings: &TrackSection,
    scan_key: &str,
    frames: usize,
) -> Result<(TrackSummary, String, StageRecord), RunError> {
    let track_key = stage_key("track", &[scan_key], settings);
    let t0 = Instant::now();
    let mut joined = (0.0, 0.0);
    let (summary, status) = cached_seq(&env.cache, env.progress, "track", &track_key, || {
        let (summary, stats) = link_to_cache(env, x, settings, &track_key, frames)?;
        joined = (stats.joined as f64, stats.unmatched as f64);
        Ok(summary)
    })?;
    let mut counts = BTreeMap::from([
        ("tracks".into(), summary.tracks as f64),
        ("points".into(), summary.points as f64),
        ("mean_length_s".into(), summary.mean_length_s),
    ]);
    if status == StageStatus::Computed {
        counts.insert("joined_at_chunk_borders".into(), joined.0);
        counts.insert("unmatched_at_chunk_borders".into(), joined.1);
    }
    let record = StageRecord {
        name: "track".into(),
        status,
        seconds: t0.elapsed().as_secs_f64(),
        counts,
    };
    Ok((summary, track_key, record))
}

/// Links the chunks' tracks into the track stage's cache; its summary and what linking did.
fn link_to_cache(
    env: &Env,
    x: &RunInputs,
    settings: &TrackSection,
    track_key: &str,
    frames: usize,
) -> Result<(TrackSummary, crate::track::link::LinkStats), RunError> {
    use std::io::{Seek, SeekFrom, Write};
    let fps = x.fps;
    let overlap = x.grid.overlap_frames;
    let mut linker = Linker::new(LinkSettings {
        // The same detection in both chunks: within 5 cm at head height, or within the points'
        // covariances (a smoothing tracker's chunks end and begin apart).
        same_px: (0.05 * x.px_per_m).max(0.5),
        min_shared: overlap.clamp(1, 3),
    });
    // Short tracks are mostly false alarms, unless the video's start or end cut them.
    let min_frames = (settings.min_length_s() * fps).round() as usize;
    let last = frames.saturating_sub(1);
    let spill_path = crate::io::temp_path(&env.cache.path("track"), ".spill");
    let io_err = |source: std::io::Error| RunError::Io {
        path: spill_path.clone(),
        source,
    };
    let result = (|| {
        let codec = bincode::DefaultOptions::new();
        use bincode::Options;
        // Written, then read back in the tracks' order.
        let file = std::fs::OpenOptions::new()
            .read(true)
            .write(true)
            .create(true)
            .truncate(true)
            .open(&spill_path)
            .map_err(io_err)?;
        let mut spill = std::io::BufWriter::with_capacity(1 << 20, file);
        let mut index: Vec<Spilled> = Vec::new();
        let mut offset = 0u64;
        let mut set_aside = |c: Closed| -> Result<(), RunError> {
            let (a, b) = (
                c.points.first().map_or(0, |q| q.frame),
                c.points.last().map_or(0, |q| q.frame),
            );
            if c.points.is_empty() || !(b - a + 1 >= min_frames || a == 0 || b == last) {
                return Ok(());
            }
            let bytes = codec
                .serialize(&c.points)
                .map_err(|e| RunError::Failed(format!("cannot set tracks aside: {e}")))?;
            spill.write_all(&bytes).map_err(io_err)?;
            index.push(Spilled {
                first: c.points[0].clone(),
                len: c.points.len(),
                begun: c.begun,
                offset,
            });
            offset += bytes.len() as u64;
            Ok(())
        };
        for c in 0..x.grid.chunks() {
            let chunk = super::scan_stage::load_chunk(&env.cache, &x.scan_key, c)
                .ok_or_else(|| cache_gone(&env.cache, &super::scan_stage::chunk_stage(c)))?;
            linker.push(
                ChunkTracks {
                    decode_from: chunk.decode_from,
                    start: chunk.start,
                    end: chunk.end,
                    tracks: chunk.image_tracks,
                },
                &mut set_aside,
            )?;
        }
        let stats = linker.finish(&mut set_aside)?;
        let mut spill = spill.into_inner().map_err(|e| io_err(e.into_error()))?;
        index.sort_by(|a, b| {
            canonical_order((&a.first, a.len, a.begun), (&b.first, b.len, b.begun))
        });
        let summary = TrackSummary {
            tracks: index.len(),
            points: index.iter().map(|t| t.len).sum(),
            mean_length_s: index.iter().map(|t| t.len as f64 / fps).sum::<f64>()
                / index.len().max(1) as f64,
        };
        env.cache
            .store_seq::<_, RunError>("track", track_key, index.len(), |push| {
                for (k, t) in index.iter().enumerate() {
                    spill.seek(SeekFrom::Start(t.offset)).map_err(io_err)?;
                    let points: Vec<TrackPoint> = codec
                        .deserialize_from(std::io::BufReader::new(&mut spill))
                        .map_err(|e| {
                            RunError::Failed(format!("cannot read tracks set aside: {e}"))
                        })?;
                    push(&ImageTrack { id: k + 1, points })?;
                }
                Ok(())
            })?;
        Ok((summary, stats))
    })();
    let _ = std::fs::remove_file(&spill_path);
    result
}
