//! Where a run's inputs came from: each input file's checksum (`report.json`'s `inputs`), and
//! the checksums an earlier process recorded, taken again while a file's size and time match.

use std::io::Read as _;
use std::path::Path;

use serde::{Deserialize, Serialize};
use sha2::{Digest, Sha256};

use super::error::RunError;

/// An input's checksum as recorded by an earlier process with the file's size and modification
/// time: a later one takes it while both still match, without reading the file again (`split`
/// hashes the video once for all its segments and the merge: hours of 4K are tens of GB).
#[derive(Clone, Debug, Serialize, Deserialize, PartialEq)]
pub struct KnownInput {
    pub path: String,
    pub bytes: u64,
    /// Modification time, nanoseconds since 1970.
    pub modified_ns: u64,
    pub sha256: String,
}

/// A file's size and modification time (nanoseconds since 1970).
pub(crate) fn size_and_time(path: &Path) -> Option<(u64, u64)> {
    let m = std::fs::metadata(path).ok()?;
    let t = m
        .modified()
        .ok()?
        .duration_since(std::time::UNIX_EPOCH)
        .ok()?;
    Some((m.len(), u64::try_from(t.as_nanos()).ok()?))
}

impl KnownInput {
    /// The record of `r` with its file's size and time now; None when they cannot be read.
    pub fn of(r: &InputRecord) -> Option<KnownInput> {
        let (bytes, modified_ns) = size_and_time(Path::new(&r.path))?;
        (bytes == r.bytes).then(|| KnownInput {
            path: r.path.clone(),
            bytes,
            modified_ns,
            sha256: r.sha256.clone(),
        })
    }
}

pub(crate) fn file_record(
    role: &str,
    path: &Path,
    known: &[KnownInput],
) -> Result<InputRecord, RunError> {
    let shown = path.display().to_string();
    if let Some((bytes, modified_ns)) = size_and_time(path)
        && let Some(k) = known
            .iter()
            .find(|k| k.path == shown && k.bytes == bytes && k.modified_ns == modified_ns)
    {
        return Ok(InputRecord {
            role: role.into(),
            path: shown,
            bytes,
            sha256: k.sha256.clone(),
        });
    }
    let mut f = std::fs::File::open(path)
        .map_err(|e| RunError::Unusable(format!("{}: {e}", path.display())))?;
    let mut h = Sha256::new();
    let mut buf = vec![0u8; 1 << 20];
    let mut bytes = 0u64;
    loop {
        let n = f.read(&mut buf).map_err(|source| RunError::Io {
            path: path.to_path_buf(),
            source,
        })?;
        if n == 0 {
            break;
        }
        h.update(&buf[..n]);
        bytes += n as u64;
    }
    Ok(InputRecord {
        role: role.into(),
        path: path.display().to_string(),
        bytes,
        sha256: h.finalize().iter().map(|b| format!("{b:02x}")).collect(),
    })
}

/// One input file of a run, with its checksum.
#[derive(Clone, Debug, Serialize, Deserialize, PartialEq)]
pub struct InputRecord {
    pub role: String,
    pub path: String,
    pub bytes: u64,
    pub sha256: String,
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_known_checksum_is_taken_only_while_size_and_time_match() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("video.bin");
        std::fs::write(&path, b"frames").unwrap();
        let hashed = file_record("video", &path, &[]).unwrap();
        let mut known = KnownInput::of(&hashed).unwrap();
        // Taken as recorded, without reading the file: a made-up checksum shows it.
        known.sha256 = "recorded".into();
        let r = file_record("video", &path, std::slice::from_ref(&known)).unwrap();
        assert_eq!(r.sha256, "recorded");
        // Another modification time: the file is read again.
        known.modified_ns += 1;
        let r = file_record("video", &path, std::slice::from_ref(&known)).unwrap();
        assert_eq!(r.sha256, hashed.sha256);
        // Another size (the same time): read again.
        known.modified_ns -= 1;
        known.bytes += 1;
        let r = file_record("video", &path, &[known]).unwrap();
        assert_eq!(r.sha256, hashed.sha256);
    }
}
