//! File output helpers shared by every writer.

use std::io::Write;
use std::path::{Path, PathBuf};

/// An input file that cannot be used: which file, where (line, field or column), what was
/// expected. Every reader reports through this.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub struct FileError {
    pub path: PathBuf,
    pub line: Option<usize>,
    pub field: Option<String>,
    pub message: String,
}

impl std::fmt::Display for FileError {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "{}", self.path.display())?;
        if let Some(l) = self.line {
            write!(f, ":{l}")?;
        }
        if let Some(field) = &self.field {
            write!(f, ": field '{field}'")?;
        }
        write!(f, ": {}", self.message)
    }
}

/// Builds [`FileError`]s for one file.
#[derive(Clone, Copy)]
pub struct FileCtx<'a> {
    pub path: &'a Path,
}

impl FileCtx<'_> {
    /// Reads the file as UTF-8 text (a byte-order mark is dropped); `what` says what the file
    /// should be, for the message when it is not text.
    pub fn read_text(&self, what: &str) -> Result<String, FileError> {
        let bytes = std::fs::read(self.path)
            .map_err(|e| self.err(None, None, format!("cannot read: {e}")))?;
        let text = String::from_utf8(bytes)
            .map_err(|e| self.err(None, None, format!("not UTF-8 text ({e}); expected {what}")))?;
        Ok(match text.strip_prefix('\u{feff}') {
            Some(t) => t.to_string(),
            None => text,
        })
    }

    pub fn err(
        &self,
        line: Option<usize>,
        field: Option<&str>,
        message: impl Into<String>,
    ) -> FileError {
        FileError {
            path: self.path.to_path_buf(),
            line,
            field: field.map(str::to_string),
            message: message.into(),
        }
    }

    pub fn at(&self, line: usize, message: impl Into<String>) -> FileError {
        self.err(Some(line), None, message)
    }

    /// Parses a number, naming the line and field on failure.
    pub fn number(&self, text: &str, line: usize, field: &str) -> Result<f64, FileError> {
        let t = text.trim();
        t.parse::<f64>().map_err(|_| {
            self.err(
                Some(line),
                Some(field),
                format!("expected a number, found '{t}'"),
            )
        })
    }
}

/// `text` for a message: at most `max` characters, the rest replaced by how long it was, so that a
/// 200 MB token is not printed whole.
pub fn clip(text: &str, max: usize) -> String {
    match text.char_indices().nth(max) {
        None => text.to_string(),
        Some((cut, _)) => format!("{}… ({} bytes in all)", &text[..cut], text.len()),
    }
}

/// Writes `bytes` to `path` atomically: a temporary file in the same folder, flushed to disk, then
/// renamed over the target. A failed write leaves no partial file and never touches the target.
pub fn write_atomic(path: &Path, bytes: &[u8]) -> std::io::Result<()> {
    let dir = match path.parent() {
        Some(p) if !p.as_os_str().is_empty() => p.to_path_buf(),
        _ => PathBuf::from("."),
    };
    let name = path
        .file_name()
        .ok_or_else(|| std::io::Error::new(std::io::ErrorKind::InvalidInput, "no file name"))?;
    let tmp = dir.join(format!(
        ".{}.tmp-{}",
        name.to_string_lossy(),
        std::process::id()
    ));
    let result = (|| {
        let mut f = std::fs::File::create(&tmp)?;
        f.write_all(bytes)?;
        f.sync_all()?;
        std::fs::rename(&tmp, path)
    })();
    if result.is_err() {
        let _ = std::fs::remove_file(&tmp);
    }
    result
}

/// The current UTC time as ISO 8601 (`2026-11-21T10:00:00Z`), without a date-time dependency.
pub fn utc_now_iso8601() -> String {
    let secs = std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .map(|d| d.as_secs() as i64)
        .unwrap_or(0);
    iso8601_from_unix(secs)
}

/// Formats Unix seconds as ISO 8601 UTC (proleptic Gregorian calendar).
pub fn iso8601_from_unix(secs: i64) -> String {
    let days = secs.div_euclid(86_400);
    let rem = secs.rem_euclid(86_400);
    // Civil date from days since 1970-01-01 (Howard Hinnant's algorithm).
    let z = days + 719_468;
    let era = z.div_euclid(146_097);
    let doe = z - era * 146_097;
    let yoe = (doe - doe / 1460 + doe / 36_524 - doe / 146_096) / 365;
    let doy = doe - (365 * yoe + yoe / 4 - yoe / 100);
    let mp = (5 * doy + 2) / 153;
    let day = doy - (153 * mp + 2) / 5 + 1;
    let month = if mp < 10 { mp + 3 } else { mp - 9 };
    let year = yoe + era * 400 + i64::from(month <= 2);
    format!(
        "{year:04}-{month:02}-{day:02}T{:02}:{:02}:{:02}Z",
        rem / 3600,
        (rem / 60) % 60,
        rem % 60
    )
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn iso8601_known_dates() {
        assert_eq!(iso8601_from_unix(0), "1970-01-01T00:00:00Z");
        assert_eq!(iso8601_from_unix(951_782_400), "2000-02-29T00:00:00Z");
        assert_eq!(iso8601_from_unix(1_795_255_200), "2026-11-21T10:00:00Z");
    }

    #[test]
    fn clip_cuts_long_tokens_only() {
        assert_eq!(clip("short", 10), "short");
        assert_eq!(clip("abcdefghij", 10), "abcdefghij");
        assert_eq!(clip("abcdefghijk", 4), "abcd… (11 bytes in all)");
        assert_eq!(clip("ééé", 1), "é… (6 bytes in all)");
    }

    #[test]
    fn atomic_write_replaces_and_leaves_no_temp() {
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("out.txt");
        write_atomic(&p, b"one").unwrap();
        write_atomic(&p, b"two").unwrap();
        assert_eq!(std::fs::read_to_string(&p).unwrap(), "two");
        assert_eq!(std::fs::read_dir(dir.path()).unwrap().count(), 1);
        assert!(write_atomic(&dir.path().join("missing/dir/x"), b"x").is_err());
    }
}
