//! The stage cache of `geostride sfm`: each image's features and each pair's matches in files
//! under the output's `cache/`, keyed by the build, the image's bytes and the settings, so that
//! a run again (after a crash, a kill, or with other reconstruction or georeferencing options)
//! redoes only what changed. A file that cannot be read back whole, or that another key's file
//! replaced, is recomputed: every file holds its key and a digest of its payload.

use std::path::{Path, PathBuf};

use sha2::{Digest, Sha256};

use crate::cache::hex;

use super::{DESCRIPTOR_LEN, Features, Keypoint};

const FEATURES_MAGIC: &[u8; 4] = b"GSF2";
const MATCHES_MAGIC: &[u8; 4] = b"GSM2";

/// A cache folder; `None` caches nothing. A second folder may be read but is never written (a
/// model's own cache, an input).
#[derive(Clone, Debug)]
pub struct SfmCache {
    dir: Option<PathBuf>,
    read_only: Option<PathBuf>,
}

/// A key from its parts (32 hex digits).
pub fn key_of(parts: &[&[u8]]) -> String {
    let mut h = Sha256::new();
    for p in parts {
        h.update((p.len() as u64).to_le_bytes());
        h.update(p);
    }
    hex(&h.finalize()[..16])
}

struct Reader<'a> {
    bytes: &'a [u8],
    at: usize,
}

impl Reader<'_> {
    fn take(&mut self, n: usize) -> Option<&[u8]> {
        let end = self.at.checked_add(n)?;
        let s = self.bytes.get(self.at..end)?;
        self.at = end;
        Some(s)
    }
    fn u32(&mut self) -> Option<u32> {
        Some(u32::from_le_bytes(self.take(4)?.try_into().ok()?))
    }
    fn u64(&mut self) -> Option<u64> {
        Some(u64::from_le_bytes(self.take(8)?.try_into().ok()?))
    }
    fn f64(&mut self) -> Option<f64> {
        Some(f64::from_le_bytes(self.take(8)?.try_into().ok()?))
    }
    fn f32(&mut self) -> Option<f32> {
        Some(f32::from_le_bytes(self.take(4)?.try_into().ok()?))
    }
}

/// The header every cache file starts with: magic, the key it was stored under, and a digest of
/// the payload after it, so that a file copied under another key's name, or damaged, is a miss.
fn with_header(magic: &[u8; 4], key: &str, payload: Vec<u8>) -> Vec<u8> {
    let mut b = Vec::with_capacity(payload.len() + 24 + key.len());
    b.extend_from_slice(magic);
    b.extend_from_slice(&(key.len() as u32).to_le_bytes());
    b.extend_from_slice(key.as_bytes());
    b.extend_from_slice(&Sha256::digest(&payload)[..16]);
    b.extend_from_slice(&payload);
    b
}

/// The payload of a file made by [`with_header`] for `magic` and `key`.
fn payload<'a>(bytes: &'a [u8], magic: &[u8; 4], key: &str) -> Option<&'a [u8]> {
    let mut r = Reader { bytes, at: 0 };
    if r.take(4)? != magic {
        return None;
    }
    let n = r.u32()? as usize;
    if r.take(n)? != key.as_bytes() {
        return None;
    }
    let digest: [u8; 16] = r.take(16)?.try_into().ok()?;
    let rest = &bytes[r.at..];
    (Sha256::digest(rest)[..16] == digest).then_some(rest)
}

/// Features as bytes: the header, then width, height, count, keypoints, descriptors.
pub fn encode_features(f: &Features, key: &str) -> Vec<u8> {
    let mut b = Vec::with_capacity(16 + f.len() * (40 + 4 * DESCRIPTOR_LEN));
    b.extend_from_slice(&f.width.to_le_bytes());
    b.extend_from_slice(&f.height.to_le_bytes());
    b.extend_from_slice(&(f.keypoints.len() as u64).to_le_bytes());
    for k in &f.keypoints {
        for v in [k.x, k.y, k.size, k.angle_deg, k.response] {
            b.extend_from_slice(&v.to_le_bytes());
        }
    }
    for d in &f.descriptors {
        b.extend_from_slice(&d.to_le_bytes());
    }
    with_header(FEATURES_MAGIC, key, b)
}

/// The features of [`encode_features`] stored under `key`; `None` for anything else (cut short,
/// damaged, another key's, another format, keypoints that are not numbers inside the image).
pub fn decode_features(bytes: &[u8], key: &str) -> Option<Features> {
    let bytes = payload(bytes, FEATURES_MAGIC, key)?;
    let mut r = Reader { bytes, at: 0 };
    let width = r.u32()?;
    let height = r.u32()?;
    if !(1..=crate::camera::MAX_IMAGE_SIDE).contains(&width)
        || !(1..=crate::camera::MAX_IMAGE_SIDE).contains(&height)
    {
        return None;
    }
    let n = usize::try_from(r.u64()?).ok()?;
    // The exact length first: a count from a damaged file must not allocate wildly.
    if bytes.len() != 16 + n.checked_mul(40 + 4 * DESCRIPTOR_LEN)? {
        return None;
    }
    let mut keypoints = Vec::with_capacity(n);
    for _ in 0..n {
        let k = Keypoint {
            x: r.f64()?,
            y: r.f64()?,
            size: r.f64()?,
            angle_deg: r.f64()?,
            response: r.f64()?,
        };
        let inside = |v: f64, side: u32| v >= -1.0 && v <= side as f64;
        if !(inside(k.x, width)
            && inside(k.y, height)
            && k.size.is_finite()
            && k.angle_deg.is_finite()
            && k.response.is_finite())
        {
            return None;
        }
        keypoints.push(k);
    }
    let mut descriptors = Vec::with_capacity(n * DESCRIPTOR_LEN);
    for _ in 0..n * DESCRIPTOR_LEN {
        descriptors.push(r.f32().filter(|d| d.is_finite())?);
    }
    Some(Features {
        width,
        height,
        keypoints,
        descriptors,
    })
}

/// Matches as bytes: the header, then count and index pairs.
pub fn encode_matches(m: &[(usize, usize)], key: &str) -> Vec<u8> {
    let mut b = Vec::with_capacity(8 + 8 * m.len());
    b.extend_from_slice(&(m.len() as u64).to_le_bytes());
    for &(a, c) in m {
        b.extend_from_slice(&(a as u32).to_le_bytes());
        b.extend_from_slice(&(c as u32).to_le_bytes());
    }
    with_header(MATCHES_MAGIC, key, b)
}

/// The matches of [`encode_matches`] stored under `key`; `None` for anything else.
pub fn decode_matches(bytes: &[u8], key: &str) -> Option<Vec<(usize, usize)>> {
    let bytes = payload(bytes, MATCHES_MAGIC, key)?;
    let mut r = Reader { bytes, at: 0 };
    let n = usize::try_from(r.u64()?).ok()?;
    if bytes.len() != 8 + n.checked_mul(8)? {
        return None;
    }
    (0..n)
        .map(|_| Some((r.u32()? as usize, r.u32()? as usize)))
        .collect()
}

impl SfmCache {
    /// A cache in `dir` (created when first written), or none. Temporaries a killed run left
    /// there are cleared.
    pub fn new(dir: Option<&Path>) -> Self {
        for d in dir.iter() {
            for kind in ["features", "matches"] {
                let _ = crate::io::remove_stale_temps(&d.join(kind));
            }
        }
        SfmCache {
            dir: dir.map(Path::to_path_buf),
            read_only: None,
        }
    }

    /// The same cache, reading also from `dir` (where it misses) without ever writing there.
    pub fn reading_also(self, dir: &Path) -> Self {
        SfmCache {
            read_only: Some(dir.to_path_buf()),
            ..self
        }
    }

    /// Whether it keeps or reads anything.
    pub fn is_active(&self) -> bool {
        self.dir.is_some() || self.read_only.is_some()
    }

    fn path(&self, kind: &str, key: &str) -> Option<PathBuf> {
        Some(self.dir.as_ref()?.join(kind).join(format!("{key}.bin")))
    }

    /// The file stored under `key` that holds that key, from the cache or else the read-only
    /// folder.
    fn load<T>(&self, kind: &str, key: &str, decode: fn(&[u8], &str) -> Option<T>) -> Option<T> {
        [&self.dir, &self.read_only]
            .into_iter()
            .flatten()
            .find_map(|d| {
                decode(
                    &std::fs::read(d.join(kind).join(format!("{key}.bin"))).ok()?,
                    key,
                )
            })
    }

    /// The features stored under `key`, if whole and stored under that key.
    pub fn features(&self, key: &str) -> Option<Features> {
        self.load("features", key, decode_features)
    }

    pub fn matches(&self, key: &str) -> Option<Vec<(usize, usize)>> {
        self.load("matches", key, decode_matches)
    }

    fn store(&self, kind: &str, key: &str, bytes: &[u8]) -> std::io::Result<()> {
        let Some(path) = self.path(kind, key) else {
            return Ok(());
        };
        if let Some(parent) = path.parent() {
            std::fs::create_dir_all(parent)?;
        }
        crate::io::write_atomic(&path, bytes)
    }

    pub fn store_features(&self, key: &str, f: &Features) -> std::io::Result<()> {
        self.store("features", key, &encode_features(f, key))
    }

    pub fn store_matches(&self, key: &str, m: &[(usize, usize)]) -> std::io::Result<()> {
        self.store("matches", key, &encode_matches(m, key))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn features_and_matches_read_back_and_damage_is_a_miss() {
        let f = Features {
            width: 640,
            height: 480,
            keypoints: vec![
                Keypoint {
                    x: 1.5,
                    y: -0.25,
                    size: 3.0,
                    angle_deg: 90.0,
                    response: 0.01,
                };
                2
            ],
            descriptors: (0..2 * DESCRIPTOR_LEN).map(|i| i as f32 / 7.0).collect(),
        };
        let b = encode_features(&f, "k1");
        let back = decode_features(&b, "k1").unwrap();
        assert_eq!(back.keypoints, f.keypoints);
        assert_eq!(back.descriptors, f.descriptors);
        assert_eq!((back.width, back.height), (640, 480));
        assert!(decode_features(&b[..b.len() - 1], "k1").is_none());
        assert!(decode_features(b"GSM2", "k1").is_none());
        // Another key's valid file, a flipped payload byte, a keypoint off the image.
        assert!(decode_features(&b, "k2").is_none());
        let mut flipped = b.clone();
        *flipped.last_mut().unwrap() ^= 1;
        assert!(decode_features(&flipped, "k1").is_none());
        let mut off = f.clone();
        off.keypoints[1].x = 700.0;
        assert!(decode_features(&encode_features(&off, "k1"), "k1").is_none());
        let mut nan = f.clone();
        nan.descriptors[3] = f32::NAN;
        assert!(decode_features(&encode_features(&nan, "k1"), "k1").is_none());
        let m = vec![(0, 5), (7, 1)];
        let b = encode_matches(&m, "k");
        assert_eq!(decode_matches(&b, "k").unwrap(), m);
        assert!(decode_matches(&b[..b.len() - 3], "k").is_none());
        assert!(decode_matches(&b, "j").is_none());
        let tmp = tempfile::tempdir().unwrap();
        let c = SfmCache::new(Some(tmp.path()));
        assert!(c.matches("k").is_none());
        c.store_matches("k", &m).unwrap();
        assert_eq!(c.matches("k").unwrap(), m);
        std::fs::write(tmp.path().join("matches/k.bin"), b"GSM2\x09").unwrap();
        assert!(c.matches("k").is_none());
        // A file swapped for another key's valid one is a miss.
        c.store_matches("other", &[(1, 1)]).unwrap();
        std::fs::copy(
            tmp.path().join("matches/other.bin"),
            tmp.path().join("matches/k.bin"),
        )
        .unwrap();
        assert!(c.matches("k").is_none());
    }

    #[test]
    fn a_read_only_folder_is_read_and_never_written() {
        let ro = tempfile::tempdir().unwrap();
        let rw = tempfile::tempdir().unwrap();
        SfmCache::new(Some(ro.path()))
            .store_matches("k", &[(2, 3)])
            .unwrap();
        let c = SfmCache::new(Some(rw.path())).reading_also(ro.path());
        assert_eq!(c.matches("k").unwrap(), vec![(2, 3)]);
        c.store_matches("n", &[(4, 5)]).unwrap();
        assert!(rw.path().join("matches/n.bin").is_file());
        assert!(!ro.path().join("matches/n.bin").exists());
    }
}
