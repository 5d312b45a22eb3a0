//! The stage cache of `geostride run` and what `geostride sfm` shares with it: files keyed by the
//! build ([`build_id`]), the inputs' checksums and the settings, written whole or not at all and
//! read back only under their key. Plain std, serde and bincode: no project, no stage, no
//! adapter; the pipeline's runner (`pipeline::run`) and `sfm::cache` sit above it.

use std::path::{Path, PathBuf};

use serde::Serialize;
use serde::de::DeserializeOwned;
use sha2::{Digest, Sha256};

/// A stage cache that cannot be written or read back while a run goes on.
#[derive(Debug, thiserror::Error)]
pub enum CacheError {
    /// Writing or reading the cache's file failed.
    #[error("{}: {source}", path.display())]
    Io {
        path: PathBuf,
        #[source]
        source: std::io::Error,
    },
    /// The data could not be encoded (or a sequence's length was not what was stated).
    #[error("cannot cache {stage}: {reason}")]
    Encode { stage: String, reason: String },
    /// A stage's file that a later stage found missing or damaged.
    #[error("{}: gone or damaged while the run went on: run again", path.display())]
    Gone { path: PathBuf },
    /// An element of a cached sequence is damaged (the file is removed).
    #[error("{0}")]
    Damaged(String),
    /// A path that is not `DIR/STAGE.bin`.
    #[error("{}: not a stage cache's name (DIR/STAGE.bin)", path.display())]
    NotACacheName { path: PathBuf },
}

fn encode(stage: &str, e: bincode::Error) -> CacheError {
    CacheError::Encode {
        stage: stage.to_string(),
        reason: e.to_string(),
    }
}

/// Bytes as lower-case hexadecimal.
pub fn hex(bytes: &[u8]) -> String {
    bytes.iter().map(|b| format!("{b:02x}")).collect()
}

/// The cached stage artifacts, each `DIR/STAGE.bin`: `CACHE_MAGIC`, the length of the rest
/// (u64, little-endian), then the key it was made under and its data in bincode's compact
/// binary form (JSON took 136 MB and most of a second for the smoothed trajectories of 2 minutes
/// of a 220-person crowd; binary keeps NaN too, which JSON cannot).
pub struct StageCache {
    dir: PathBuf,
}

impl StageCache {
    /// The cache in folder `dir` (`OUT/.stages`).
    pub fn new(dir: PathBuf) -> StageCache {
        StageCache { dir }
    }
}

const CACHE_MAGIC: &[u8; 8] = b"GSCACHE1";

/// A cache file's stated payload length and what follows its header (all of the payload, or
/// its start); None without the magic.
fn cache_header(bytes: &[u8]) -> Option<(u64, &[u8])> {
    let rest = bytes.strip_prefix(CACHE_MAGIC)?;
    let (len, payload) = rest.split_first_chunk::<8>()?;
    Some((u64::from_le_bytes(*len), payload))
}

/// The elements of a cached sequence, read as they are asked for ([`StageCache::load_seq`]).
pub struct CachedSeq<T> {
    reader: std::io::BufReader<std::fs::File>,
    /// No element can ask for more memory than the file holds.
    limit: u64,
    left: u64,
    path: PathBuf,
    element: std::marker::PhantomData<T>,
}

impl<T: DeserializeOwned> Iterator for CachedSeq<T> {
    type Item = std::io::Result<T>;

    fn next(&mut self) -> Option<std::io::Result<T>> {
        use bincode::Options;
        if self.left == 0 {
            return None;
        }
        self.left -= 1;
        let codec = bincode::DefaultOptions::new()
            .with_limit(self.limit)
            .allow_trailing_bytes();
        Some(codec.deserialize_from(&mut self.reader).map_err(|e| {
            // Damaged inside a whole file: removed, so that the next run computes it again.
            self.left = 0;
            let _ = std::fs::remove_file(&self.path);
            std::io::Error::other(format!(
                "{}: damaged ({e}); removed: run again to compute it anew",
                self.path.display()
            ))
        }))
    }
}

/// The payload of a cache file when the file is whole (its magic and its stated length).
fn cache_payload(bytes: &[u8]) -> Option<&[u8]> {
    let (len, payload) = cache_header(bytes)?;
    (len == payload.len() as u64).then_some(payload)
}

/// The cache at `path` (`DIR/STAGE.bin`) as the run reads it: whole, made under `key`, its data
/// a `T`; `None` otherwise (for tests and the fuzzing of the format).
pub fn read_stage_file<T: DeserializeOwned>(path: &Path, key: &str) -> Option<T> {
    let (cache, stage) = cache_of(path)?;
    cache.load(&stage, key)
}

/// The cached sequence at `path` read an element at a time, as the later stages read it:
/// `None` when the file is not whole under `key` or an element is damaged.
pub fn read_stage_seq_file<T: DeserializeOwned>(path: &Path, key: &str) -> Option<Vec<T>> {
    let (cache, stage) = cache_of(path)?;
    cache
        .load_seq::<T>(&stage, key)?
        .collect::<Result<_, _>>()
        .ok()
}

/// Writes `data` at `path` as a stage cache made under `key`.
pub fn write_stage_file<T: Serialize>(path: &Path, key: &str, data: &T) -> Result<(), CacheError> {
    let (cache, stage) = cache_of(path).ok_or_else(|| CacheError::NotACacheName {
        path: path.to_path_buf(),
    })?;
    cache.store(&stage, key, data)
}

fn cache_of(path: &Path) -> Option<(StageCache, String)> {
    let stage = path
        .file_name()?
        .to_str()?
        .strip_suffix(".bin")?
        .to_string();
    Some((
        StageCache {
            dir: path.parent()?.to_path_buf(),
        },
        stage,
    ))
}

/// Whether `path` is a whole stage cache file (a test that a killed run left none half-written).
pub fn cache_file_whole(path: &Path) -> bool {
    std::fs::read(path).is_ok_and(|b| cache_payload(&b).is_some())
}

impl StageCache {
    pub fn path(&self, stage: &str) -> PathBuf {
        self.dir.join(format!("{stage}.bin"))
    }

    /// The data cached under `key`; None when there is none, it was made under another key, or
    /// it cannot be read back (cut short, or written by another build).
    pub fn load<T: DeserializeOwned>(&self, stage: &str, key: &str) -> Option<T> {
        use bincode::Options;
        use std::io::Read;
        let (mut reader, limit) = self.open_under(stage, key, 1 << 20)?;
        let codec = bincode::DefaultOptions::new()
            .with_limit(limit)
            .allow_trailing_bytes();
        let data: T = codec.deserialize_from(&mut reader).ok()?;
        let mut rest = [0u8; 1];
        matches!(reader.read(&mut rest), Ok(0)).then_some(data)
    }

    /// A cached sequence (a `Vec<T>` stored whole) read back one element at a time: what reads
    /// a long video's tracks this way never holds them all. None as for [`StageCache::load`] (a
    /// damaged element shows as an error when it is reached).
    pub fn load_seq<T: DeserializeOwned>(&self, stage: &str, key: &str) -> Option<CachedSeq<T>> {
        use bincode::Options;
        let (mut reader, limit) = self.open_under(stage, key, 1 << 20)?;
        // bincode writes a sequence as its length, then its elements.
        let left: u64 = bincode::DefaultOptions::new()
            .with_limit(limit)
            .allow_trailing_bytes()
            .deserialize_from(&mut reader)
            .ok()?;
        Some(CachedSeq {
            reader,
            limit,
            left,
            path: self.path(stage),
            element: std::marker::PhantomData,
        })
    }

    /// The stage's file, whole (its stated length) and made under `key`: a reader at its data
    /// with a buffer of `buffer` bytes (read through a buffer, not whole: an hour's stage would
    /// stand in memory twice) and the most any length in it may ask for (the file's size: no
    /// damaged length can ask for more memory than the file holds).
    fn open_under(
        &self,
        stage: &str,
        key: &str,
        buffer: usize,
    ) -> Option<(std::io::BufReader<std::fs::File>, u64)> {
        use bincode::Options;
        use std::io::Read;
        let f = std::fs::File::open(self.path(stage)).ok()?;
        let size = f.metadata().ok()?.len();
        let mut reader = std::io::BufReader::with_capacity(buffer, f);
        let mut head = [0u8; 16];
        reader.read_exact(&mut head).ok()?;
        let (len, _) = cache_header(&head)?;
        if len != size.saturating_sub(16) {
            return None;
        }
        let stored_key: String = bincode::DefaultOptions::new()
            .with_limit(len)
            .allow_trailing_bytes()
            .deserialize_from(&mut reader)
            .ok()?;
        (stored_key == key).then_some((reader, len))
    }

    /// Whether a whole artifact made under `key` is cached, without reading its data.
    pub fn has(&self, stage: &str, key: &str) -> bool {
        // A buffer the size of a header and a key: the data are not read.
        self.open_under(stage, key, 16 + 4096).is_some()
    }

    pub fn store<T: Serialize>(&self, stage: &str, key: &str, data: &T) -> Result<(), CacheError> {
        use bincode::Options;
        let failed = |e: bincode::Error| encode(stage, e);
        let codec = bincode::DefaultOptions::new();
        // Sized first and then written through a buffer: never whole in memory.
        let len = codec.serialized_size(key).map_err(failed)?
            + codec.serialized_size(data).map_err(failed)?;
        let path = self.path(stage);
        crate::io::write_atomic_with(&path, |w| {
            w.write_all(CACHE_MAGIC)?;
            w.write_all(&len.to_le_bytes())?;
            let io = |e: bincode::Error| std::io::Error::other(e.to_string());
            codec.serialize_into(&mut *w, key).map_err(io)?;
            codec.serialize_into(&mut *w, data).map_err(io)
        })
        .map_err(|source| CacheError::Io { path, source })
    }
    /// A sequence of `count` elements cached as [`StageCache::store`] stores a `Vec<T>` (read back
    /// with [`StageCache::load_seq`] or [`StageCache::load`]), but given to `fill`'s `push` one element
    /// at a time: a long video's stage is never whole in memory. The file's stated length is
    /// written last; a `fill` that fails, or pushes another number of elements, leaves no file.
    pub fn store_seq<T: Serialize, E: From<CacheError>>(
        &self,
        stage: &str,
        key: &str,
        count: usize,
        fill: impl FnOnce(&mut dyn FnMut(&T) -> Result<(), E>) -> Result<(), E>,
    ) -> Result<(), E> {
        use bincode::Options;
        use std::io::{Seek, SeekFrom, Write};
        let codec = bincode::DefaultOptions::new();
        let path = self.path(stage);
        let io = |e: bincode::Error| std::io::Error::other(e.to_string());
        let mut failed: Option<E> = None;
        let written = crate::io::write_atomic_file(&path, |f| {
            f.write_all(CACHE_MAGIC)?;
            f.write_all(&0u64.to_le_bytes())?;
            codec.serialize_into(&mut *f, key).map_err(io)?;
            codec.serialize_into(&mut *f, &(count as u64)).map_err(io)?;
            let mut pushed = 0usize;
            let outcome = {
                let mut push = |t: &T| -> Result<(), E> {
                    if pushed == count {
                        return Err(E::from(CacheError::Encode {
                            stage: stage.to_string(),
                            reason: format!("more than the {count} elements stated"),
                        }));
                    }
                    pushed += 1;
                    codec
                        .serialize_into(&mut *f, t)
                        .map_err(|e| E::from(encode(stage, e)))
                };
                fill(&mut push)
            };
            let outcome = outcome.and_then(|()| {
                if pushed == count {
                    Ok(())
                } else {
                    Err(E::from(CacheError::Encode {
                        stage: stage.to_string(),
                        reason: format!("{pushed} elements given, {count} stated"),
                    }))
                }
            });
            if let Err(e) = outcome {
                failed = Some(e);
                return Err(std::io::Error::other("stopped"));
            }
            let end = f.stream_position()?;
            f.seek(SeekFrom::Start(CACHE_MAGIC.len() as u64))?;
            f.write_all(&(end - 16).to_le_bytes())
        });
        if let Some(e) = failed {
            return Err(e);
        }
        written.map_err(|source| E::from(CacheError::Io { path, source }))
    }

    /// [`StageCache::load_seq`], or the error that the stage's file is gone (a later stage reads a
    /// stage that was cached a moment ago).
    pub fn read_seq<T: DeserializeOwned>(
        &self,
        stage: &str,
        key: &str,
    ) -> Result<CachedSeq<T>, CacheError> {
        self.load_seq(stage, key)
            .ok_or_else(|| cache_gone(self, stage))
    }

    /// A cached sequence of tracks given to `f` in order, in batches of about [`BATCH_POINTS`]
    /// points (`points` counts a track's).
    pub fn read_batches<T: DeserializeOwned, E: From<CacheError>>(
        &self,
        stage: &str,
        key: &str,
        points: impl Fn(&T) -> usize,
        f: impl FnMut(Vec<T>) -> Result<(), E>,
    ) -> Result<(), E> {
        let seq = self
            .read_seq::<T>(stage, key)
            .map_err(E::from)?
            .map(|t| t.map_err(|e| E::from(CacheError::Damaged(e.to_string()))));
        in_batches(seq, points, f)
    }
}

/// The build: geostride's version and a fingerprint of the running executable, so that a cache
/// made by another build is never reused. The fingerprint is the executable's size and
/// modification time to the nanosecond (a rebuilt executable never keeps both): hashing the
/// whole 70 MB file cost 0.2 s at the start of every run.
pub fn build_id() -> &'static str {
    static ID: std::sync::OnceLock<String> = std::sync::OnceLock::new();
    ID.get_or_init(|| {
        let stamp = std::env::current_exe()
            .ok()
            .and_then(|p| std::fs::metadata(p).ok())
            .map(|m| {
                let ns = m
                    .modified()
                    .ok()
                    .and_then(|t| t.duration_since(std::time::UNIX_EPOCH).ok())
                    .map_or(0, |d| d.as_nanos());
                sha256_hex(format!("{}|{ns}", m.len()).as_bytes())
            })
            .unwrap_or_default();
        format!(
            "{}+{}",
            env!("CARGO_PKG_VERSION"),
            &stamp[..stamp.len().min(16)]
        )
    })
}

pub fn stage_key(stage: &str, parents: &[&str], params: &impl Serialize) -> String {
    let mut text = format!("{stage}|{}|", build_id());
    for p in parents {
        text.push_str(p);
        text.push('|');
    }
    text.push_str(&serde_json::to_string(params).unwrap_or_default());
    sha256_hex(text.as_bytes())
}

/// A stage cache that a later stage found missing or damaged (removed while the run went on).
pub fn cache_gone(cache: &StageCache, stage: &str) -> CacheError {
    CacheError::Gone {
        path: cache.path(stage),
    }
}

/// The most points of tracks a stage holds at once: a batch of tracks is read, worked on side by
/// side and written before the next is read.
pub const BATCH_POINTS: usize = 1 << 16;

/// `items` (tracks, in order) given to `f` in batches of about [`BATCH_POINTS`] points
/// (`points` counts an item's); the first error stops it.
pub fn in_batches<T, E>(
    items: impl IntoIterator<Item = Result<T, E>>,
    points: impl Fn(&T) -> usize,
    mut f: impl FnMut(Vec<T>) -> Result<(), E>,
) -> Result<(), E> {
    let (mut batch, mut n) = (Vec::new(), 0);
    for t in items {
        let t = t?;
        n += points(&t);
        batch.push(t);
        if n >= BATCH_POINTS {
            f(std::mem::take(&mut batch))?;
            n = 0;
        }
    }
    if !batch.is_empty() {
        f(batch)?;
    }
    Ok(())
}

/// The SHA-256 of `bytes` in hexadecimal.
pub fn sha256_hex(bytes: &[u8]) -> String {
    hex(&Sha256::digest(bytes))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_stage_cache_reads_back_only_whole_and_under_its_key() {
        let dir = tempfile::tempdir().unwrap();
        let cache = StageCache {
            dir: dir.path().to_path_buf(),
        };
        // Larger than the writer's and the reader's buffers.
        let data: Vec<(usize, f64)> = (0..300_000).map(|k| (k, k as f64 * 0.5)).collect();
        cache.store("smooth", "key-1", &data).unwrap();
        let path = cache.path("smooth");
        assert!(cache_file_whole(&path) && cache.has("smooth", "key-1"));
        assert_eq!(
            cache.load::<Vec<(usize, f64)>>("smooth", "key-1"),
            Some(data)
        );
        assert_eq!(cache.load::<Vec<(usize, f64)>>("smooth", "key-2"), None);
        let bytes = std::fs::read(&path).unwrap();
        // Cut short, or a byte more: not read.
        std::fs::write(&path, &bytes[..bytes.len() - 1]).unwrap();
        assert_eq!(cache.load::<Vec<(usize, f64)>>("smooth", "key-1"), None);
        assert!(cache.load_seq::<(usize, f64)>("smooth", "key-1").is_none());
        let mut longer = bytes.clone();
        longer.push(0);
        std::fs::write(&path, &longer).unwrap();
        assert_eq!(cache.load::<Vec<(usize, f64)>>("smooth", "key-1"), None);
        // A length inside that asks for more than the file holds: refused, not allocated.
        let mut lying = bytes.clone();
        let at = 16 + 1 + "key-1".len();
        lying[at..at + 9].copy_from_slice(&[253, 255, 255, 255, 255, 255, 255, 255, 15]);
        std::fs::write(&path, &lying).unwrap();
        assert_eq!(cache.load::<Vec<(usize, f64)>>("smooth", "key-1"), None);
    }

    #[test]
    fn a_sequence_cached_an_element_at_a_time_is_the_whole_vector_cached() {
        let dir = tempfile::tempdir().unwrap();
        let cache = StageCache {
            dir: dir.path().to_path_buf(),
        };
        let data: Vec<(usize, f64)> = (0..300_000).map(|k| (k * 7, k as f64 * 0.5)).collect();
        cache.store("whole", "k", &data).unwrap();
        cache
            .store_seq::<_, CacheError>("seq", "k", data.len(), |push| {
                data.iter().try_for_each(push)
            })
            .unwrap();
        let (whole, seq) = (
            std::fs::read(cache.path("whole")).unwrap(),
            std::fs::read(cache.path("seq")).unwrap(),
        );
        assert!(whole == seq, "the same bytes as a Vec stored whole");
        let back: Vec<(usize, f64)> = cache
            .load_seq("seq", "k")
            .unwrap()
            .collect::<std::io::Result<_>>()
            .unwrap();
        assert_eq!(back, data);
        // Fewer or more elements than stated, or a failing source: an error and no file, the
        // old one kept.
        for n in [data.len() + 1, data.len() - 1] {
            assert!(
                cache
                    .store_seq::<_, CacheError>("seq", "other", n, |push| data
                        .iter()
                        .try_for_each(push))
                    .is_err()
            );
        }
        let failing = cache.store_seq::<(usize, f64), CacheError>("seq", "other", 1, |_| {
            Err(CacheError::Damaged("no".into()))
        });
        assert!(matches!(failing, Err(CacheError::Damaged(m)) if m == "no"));
        assert_eq!(std::fs::read(cache.path("seq")).unwrap(), seq);
        assert_eq!(std::fs::read_dir(dir.path()).unwrap().count(), 2);
    }
}
