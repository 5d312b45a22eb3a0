//! The stage cache of `geostride sfm`: each image's features and each pair's matches in files
//! under the output's `cache/`, keyed by the build, the image's bytes and the settings, so that
//! a run again (after a crash, a kill, or with other reconstruction or georeferencing options)
//! redoes only what changed. A file that cannot be read back whole is recomputed.

use std::path::{Path, PathBuf};

use sha2::{Digest, Sha256};

use super::{DESCRIPTOR_LEN, Features, Keypoint};

const FEATURES_MAGIC: &[u8; 4] = b"GSF1";
const MATCHES_MAGIC: &[u8; 4] = b"GSM1";

/// A cache folder; `None` caches nothing.
#[derive(Clone, Debug)]
pub struct SfmCache {
    dir: Option<PathBuf>,
}

fn hex(bytes: &[u8]) -> String {
    bytes.iter().map(|b| format!("{b:02x}")).collect()
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

/// Features as bytes: magic, width, height, count, keypoints, descriptors.
pub fn encode_features(f: &Features) -> Vec<u8> {
    let mut b = Vec::with_capacity(20 + f.len() * (40 + 4 * DESCRIPTOR_LEN));
    b.extend_from_slice(FEATURES_MAGIC);
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
    b
}

/// The features of [`encode_features`]; `None` for anything else (cut short, another format).
pub fn decode_features(bytes: &[u8]) -> Option<Features> {
    let mut r = Reader { bytes, at: 0 };
    if r.take(4)? != FEATURES_MAGIC {
        return None;
    }
    let width = r.u32()?;
    let height = r.u32()?;
    let n = usize::try_from(r.u64()?).ok()?;
    // The exact length first: a count from a damaged file must not allocate wildly.
    if bytes.len() != 20 + n.checked_mul(40 + 4 * DESCRIPTOR_LEN)? {
        return None;
    }
    let mut keypoints = Vec::with_capacity(n);
    for _ in 0..n {
        keypoints.push(Keypoint {
            x: r.f64()?,
            y: r.f64()?,
            size: r.f64()?,
            angle_deg: r.f64()?,
            response: r.f64()?,
        });
    }
    let mut descriptors = Vec::with_capacity(n * DESCRIPTOR_LEN);
    for _ in 0..n * DESCRIPTOR_LEN {
        descriptors.push(r.f32()?);
    }
    Some(Features {
        width,
        height,
        keypoints,
        descriptors,
    })
}

/// Matches as bytes: magic, count, index pairs.
pub fn encode_matches(m: &[(usize, usize)]) -> Vec<u8> {
    let mut b = Vec::with_capacity(12 + 8 * m.len());
    b.extend_from_slice(MATCHES_MAGIC);
    b.extend_from_slice(&(m.len() as u64).to_le_bytes());
    for &(a, c) in m {
        b.extend_from_slice(&(a as u32).to_le_bytes());
        b.extend_from_slice(&(c as u32).to_le_bytes());
    }
    b
}

/// The matches of [`encode_matches`]; `None` for anything else.
pub fn decode_matches(bytes: &[u8]) -> Option<Vec<(usize, usize)>> {
    let mut r = Reader { bytes, at: 0 };
    if r.take(4)? != MATCHES_MAGIC {
        return None;
    }
    let n = usize::try_from(r.u64()?).ok()?;
    if bytes.len() != 12 + n.checked_mul(8)? {
        return None;
    }
    (0..n)
        .map(|_| Some((r.u32()? as usize, r.u32()? as usize)))
        .collect()
}

impl SfmCache {
    /// A cache in `dir` (created when first written), or none.
    pub fn new(dir: Option<&Path>) -> Self {
        SfmCache {
            dir: dir.map(Path::to_path_buf),
        }
    }

    /// Whether it keeps anything.
    pub fn is_active(&self) -> bool {
        self.dir.is_some()
    }

    fn path(&self, kind: &str, key: &str) -> Option<PathBuf> {
        Some(self.dir.as_ref()?.join(kind).join(format!("{key}.bin")))
    }

    /// The features stored under `key`, if whole.
    pub fn features(&self, key: &str) -> Option<Features> {
        decode_features(&std::fs::read(self.path("features", key)?).ok()?)
    }

    pub fn matches(&self, key: &str) -> Option<Vec<(usize, usize)>> {
        decode_matches(&std::fs::read(self.path("matches", key)?).ok()?)
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
        self.store("features", key, &encode_features(f))
    }

    pub fn store_matches(&self, key: &str, m: &[(usize, usize)]) -> std::io::Result<()> {
        self.store("matches", key, &encode_matches(m))
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
        let b = encode_features(&f);
        let back = decode_features(&b).unwrap();
        assert_eq!(back.keypoints, f.keypoints);
        assert_eq!(back.descriptors, f.descriptors);
        assert_eq!((back.width, back.height), (640, 480));
        assert!(decode_features(&b[..b.len() - 1]).is_none());
        assert!(decode_features(b"GSM1").is_none());
        let m = vec![(0, 5), (7, 1)];
        let b = encode_matches(&m);
        assert_eq!(decode_matches(&b).unwrap(), m);
        assert!(decode_matches(&b[..b.len() - 3]).is_none());
        let tmp = tempfile::tempdir().unwrap();
        let c = SfmCache::new(Some(tmp.path()));
        assert!(c.matches("k").is_none());
        c.store_matches("k", &m).unwrap();
        assert_eq!(c.matches("k").unwrap(), m);
        std::fs::write(tmp.path().join("matches/k.bin"), b"GSM1\x09").unwrap();
        assert!(c.matches("k").is_none());
    }
}
