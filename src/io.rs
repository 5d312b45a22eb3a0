//! Reading and writing files safely: the input limits and field checks every reader shares, and
//! the output path every writer shares (checked against the inputs, written to a temporary file,
//! flushed, renamed).

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
        // Readers quote short pieces of the input; this bounds whatever a message holds.
        write!(f, ": {}", clip(&self.message, 1000))
    }
}

/// Builds [`FileError`]s for one file.
#[derive(Clone, Copy)]
pub struct FileCtx<'a> {
    pub path: &'a Path,
}

/// The longest token an error message quotes whole.
const QUOTE_CHARS: usize = 40;

/// The largest text input read, MiB, unless `GEOSTRIDE_MAX_INPUT_MB` says otherwise: text files of
/// surveys, calibrations, boxes and projects are kilobytes to tens of megabytes; a bigger one is
/// more likely a wrong file, and reading it would take memory in proportion.
pub const MAX_INPUT_MB: u64 = 512;

/// The longest line of a line-based file (CSV and the like), bytes.
pub const MAX_LINE_BYTES: usize = 1 << 20;

/// `GEOSTRIDE_MAX_INPUT_MB`, or [`MAX_INPUT_MB`].
pub fn max_input_bytes() -> u64 {
    std::env::var("GEOSTRIDE_MAX_INPUT_MB")
        .ok()
        .and_then(|v| v.trim().parse::<u64>().ok())
        .unwrap_or(MAX_INPUT_MB)
        .saturating_mul(1 << 20)
}

impl FileCtx<'_> {
    /// Reads the file as UTF-8 text (a byte-order mark is dropped); `what` says what the file
    /// should be, for the message when it is not text. A folder, or a file beyond
    /// [`max_input_bytes`], is an error.
    pub fn read_text(&self, what: &str) -> Result<String, FileError> {
        let limit = max_input_bytes();
        self.read_text_up_to(what, limit, "set GEOSTRIDE_MAX_INPUT_MB to raise the limit")
    }

    /// [`read_text`](Self::read_text) for a file of settings (a project, a scene, a
    /// calibration), which is never more than `max_bytes`.
    pub fn read_small_text(&self, what: &str, max_bytes: u64) -> Result<String, FileError> {
        self.read_text_up_to(what, max_bytes, "is it the right file?")
    }

    fn read_text_up_to(&self, what: &str, limit: u64, hint: &str) -> Result<String, FileError> {
        let meta = std::fs::metadata(self.path)
            .map_err(|e| self.err(None, None, format!("cannot read: {e}")))?;
        if meta.is_dir() {
            return Err(self.err(None, None, format!("is a folder; expected {what}")));
        }
        if meta.len() > limit {
            return Err(self.err(
                None,
                None,
                format!(
                    "{} bytes is more than the {} KiB geostride reads as {what} ({hint})",
                    meta.len(),
                    limit >> 10
                ),
            ));
        }
        let bytes = std::fs::read(self.path)
            .map_err(|e| self.err(None, None, format!("cannot read: {e}")))?;
        let text = String::from_utf8(bytes).map_err(|e| {
            let line = e.utf8_error().valid_up_to();
            self.err(
                None,
                None,
                format!("not UTF-8 text (a bad byte at offset {line}); expected {what}"),
            )
        })?;
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

    /// The lines of a line-based file with their numbers from 1; a line beyond
    /// [`MAX_LINE_BYTES`] is an error.
    pub fn lines<'t>(
        &self,
        text: &'t str,
    ) -> impl Iterator<Item = Result<(usize, &'t str), FileError>> + use<'t, '_> {
        let ctx = *self;
        text.lines().enumerate().map(move |(i, l)| {
            if l.len() > MAX_LINE_BYTES {
                Err(ctx.at(
                    i + 1,
                    format!(
                        "the line is {} KiB long; a line of this file is at most {} KiB (is it the right file?)",
                        l.len() >> 10,
                        MAX_LINE_BYTES >> 10
                    ),
                ))
            } else {
                Ok((i + 1, l))
            }
        })
    }

    /// Parses a finite number, naming the line and field on failure (NaN, infinity and values
    /// beyond a double's range are errors).
    pub fn number(&self, text: &str, line: usize, field: &str) -> Result<f64, FileError> {
        let t = text.trim();
        match t.parse::<f64>() {
            Ok(v) if v.is_finite() => Ok(v),
            Ok(_) => Err(self.err(
                Some(line),
                Some(field),
                format!("expected a finite number, found '{}'", clip(t, QUOTE_CHARS)),
            )),
            Err(_) => Err(self.err(
                Some(line),
                Some(field),
                format!(
                    "expected a number, found '{}'{}",
                    clip(t, QUOTE_CHARS),
                    decimal_comma_hint(t)
                ),
            )),
        }
    }

    /// A finite number, or NaN where the format writes `nan` for "unknown" (OpenDroneMap's
    /// heights); infinity is an error.
    pub fn number_or_nan(&self, text: &str, line: usize, field: &str) -> Result<f64, FileError> {
        if text.trim().eq_ignore_ascii_case("nan") {
            Ok(f64::NAN)
        } else {
            self.number(text, line, field)
        }
    }

    /// A standard deviation or other positive quantity: finite and > 0.
    pub fn positive(&self, text: &str, line: usize, field: &str) -> Result<f64, FileError> {
        let v = self.number(text, line, field)?;
        if v > 0.0 {
            Ok(v)
        } else {
            Err(self.err(
                Some(line),
                Some(field),
                format!("expected a positive number, found {v}"),
            ))
        }
    }

    /// A count or index: a whole number from 0 to 2^53 (written `12` or `12.0`).
    pub fn whole(&self, text: &str, line: usize, field: &str) -> Result<u64, FileError> {
        let v = self.number(text, line, field)?;
        if v >= 0.0 && v.fract() == 0.0 && v < 9.007_199_254_740_992e15 {
            Ok(v as u64)
        } else {
            Err(self.err(
                Some(line),
                Some(field),
                format!("expected a whole number ≥ 0, found {v}"),
            ))
        }
    }

    /// Checks a row's number of fields against `min..=max`, with a hint when decimal commas may
    /// have split numbers into two fields.
    pub fn field_count(
        &self,
        fields: &[&str],
        line: usize,
        min: usize,
        max: usize,
        layout: &str,
    ) -> Result<(), FileError> {
        let n = fields.len();
        if (min..=max).contains(&n) {
            return Ok(());
        }
        let hint = if n > max && fields.iter().any(|f| looks_like_decimal_part(f)) {
            " (decimal commas? a number such as 12,5 splits into two fields where the delimiter is a comma: write 12.5, or use ';' between fields)"
        } else {
            ""
        };
        let expected = if min == max {
            format!("{min}")
        } else if max == usize::MAX {
            format!("at least {min}")
        } else {
            format!("{min} to {max}")
        };
        Err(self.at(
            line,
            format!("expected {expected} fields ({layout}), found {n}{hint}"),
        ))
    }
}

/// Whether a field looks like the digits after a decimal comma (all digits, as `5` in `12,5`).
fn looks_like_decimal_part(f: &str) -> bool {
    let t = f.trim();
    !t.is_empty() && t.len() <= 12 && t.bytes().all(|b| b.is_ascii_digit())
}

/// A hint for a number written with a decimal comma (`12,5`).
fn decimal_comma_hint(t: &str) -> &'static str {
    let Some((a, b)) = t.split_once(',') else {
        return "";
    };
    let digits = |s: &str| {
        !s.is_empty()
            && s.trim_start_matches('-')
                .bytes()
                .all(|c| c.is_ascii_digit())
    };
    if digits(a) && digits(b) {
        " (a decimal comma? write 12.5, not 12,5)"
    } else {
        ""
    }
}

/// The first key (`section.key`, or `key` at the top) of a TOML document whose value holds a
/// number that is not finite: TOML allows `nan` and `inf`, which no setting of geostride means.
pub fn toml_nonfinite_key(text: &str) -> Option<(String, String)> {
    fn finite(v: &toml::Value) -> bool {
        match v {
            toml::Value::Float(f) => f.is_finite(),
            toml::Value::Array(a) => a.iter().all(finite),
            toml::Value::Table(t) => t.values().all(finite),
            _ => true,
        }
    }
    fn walk(prefix: &str, t: &toml::Table) -> Option<(String, String)> {
        for (k, v) in t {
            match v {
                toml::Value::Table(sub) => {
                    let section = if prefix.is_empty() {
                        k.clone()
                    } else {
                        format!("{prefix}.{k}")
                    };
                    if let Some(hit) = walk(&section, sub) {
                        return Some(hit);
                    }
                }
                v if !finite(v) => return Some((prefix.to_string(), k.clone())),
                _ => {}
            }
        }
        None
    }
    walk("", &text.parse::<toml::Table>().ok()?)
}

/// `text` for a message: at most `max` characters, the rest replaced by how long it was, so that a
/// 200 MB token is not printed whole.
pub fn clip(text: &str, max: usize) -> String {
    match text.char_indices().nth(max) {
        None => text.to_string(),
        Some((cut, _)) => format!("{}… ({} bytes in all)", &text[..cut], text.len()),
    }
}

/// The temporary file an atomic write fills beside `path` before renaming it into place:
/// `.NAME.tmp-PID` and then `ext` (for writers that choose a format by the extension, such as
/// `.gpkg`). A killed run can leave one behind: [`remove_stale_temps`] clears them.
pub fn temp_path(path: &Path, ext: &str) -> PathBuf {
    let name = path
        .file_name()
        .map(|n| n.to_string_lossy().into_owned())
        .unwrap_or_default();
    path.with_file_name(format!(".{name}{TEMP_TAG}{}{ext}", std::process::id()))
}

const TEMP_TAG: &str = ".tmp-";

fn folder_of(path: &Path) -> PathBuf {
    match path.parent() {
        Some(p) if !p.as_os_str().is_empty() => p.to_path_buf(),
        _ => PathBuf::from("."),
    }
}

/// Puts a finished temporary file in place: flushes it to disk, renames it over `path` and
/// flushes the folder, so that after a crash either the old file or the whole new one is there.
pub fn commit_temp(tmp: &Path, path: &Path) -> std::io::Result<()> {
    std::fs::File::open(tmp)?.sync_all()?;
    std::fs::rename(tmp, path)?;
    // A folder cannot be flushed everywhere (some file systems refuse): the rename is done.
    if let Ok(d) = std::fs::File::open(folder_of(path)) {
        let _ = d.sync_all();
    }
    Ok(())
}

/// [`write_atomic`] for a library that writes a file by its name (GDAL, libhdf5, SQLite):
/// `fill` writes the temporary [`temp_path`]`(path, ext)` (any one left before is removed),
/// which is then committed (its error through `io_error`). On failure the temporary and its
/// SQLite journal are removed; the target is never touched.
pub fn write_atomic_by_name<E>(
    path: &Path,
    ext: &str,
    fill: impl FnOnce(&Path) -> Result<(), E>,
    io_error: impl FnOnce(std::io::Error) -> E,
) -> Result<(), E> {
    let tmp = temp_path(path, ext);
    let _ = std::fs::remove_file(&tmp);
    let result = fill(&tmp).and_then(|()| commit_temp(&tmp, path).map_err(io_error));
    if result.is_err() {
        let _ = std::fs::remove_file(&tmp);
        let _ = std::fs::remove_file(temp_path(path, &format!("{ext}-journal")));
    }
    result
}

/// Writes `bytes` to `path` atomically: a temporary file in the same folder, flushed to disk, then
/// renamed over the target. A failed write leaves no partial file and never touches the target.
pub fn write_atomic(path: &Path, bytes: &[u8]) -> std::io::Result<()> {
    write_atomic_with(path, |w| w.write_all(bytes))
}

/// [`write_atomic`] for a file written piece by piece through `fill` (buffered): a long video's
/// outputs never stand whole in memory.
pub fn write_atomic_with(
    path: &Path,
    fill: impl FnOnce(&mut dyn Write) -> std::io::Result<()>,
) -> std::io::Result<()> {
    write_atomic_file(path, |f| fill(f))
}

/// [`write_atomic_with`] given the buffered file itself: a writer that must go back (a length
/// stated before data whose size is known only at the end) can seek.
pub fn write_atomic_file(
    path: &Path,
    fill: impl FnOnce(&mut std::io::BufWriter<std::fs::File>) -> std::io::Result<()>,
) -> std::io::Result<()> {
    if path.file_name().is_none() {
        return Err(std::io::Error::new(
            std::io::ErrorKind::InvalidInput,
            "no file name",
        ));
    }
    let tmp = temp_path(path, "");
    let result = (|| {
        let mut f = std::io::BufWriter::with_capacity(1 << 20, std::fs::File::create(&tmp)?);
        fill(&mut f)?;
        f.into_inner().map_err(|e| e.into_error())?;
        commit_temp(&tmp, path)
    })();
    if result.is_err() {
        let _ = std::fs::remove_file(&tmp);
    }
    result
}

/// Whether a process with this id is running.
fn process_alive(pid: u32) -> bool {
    #[cfg(unix)]
    {
        let Ok(pid) = libc::pid_t::try_from(pid) else {
            return false;
        };
        // Signal 0 checks existence; EPERM means it exists under another user.
        // SAFETY: signal 0 sends nothing: it only asks whether `pid` exists.
        let r = unsafe { libc::kill(pid, 0) };
        r == 0 || std::io::Error::last_os_error().raw_os_error() == Some(libc::EPERM)
    }
    #[cfg(not(unix))]
    {
        let _ = pid;
        true
    }
}

/// Removes the temporaries (`.NAME.tmp-PID…`, see [`temp_path`]) that a geostride process which
/// no longer runs left in `dir`; returns how many. A missing folder has none.
pub fn remove_stale_temps(dir: &Path) -> std::io::Result<usize> {
    remove_stale(dir, None)
}

/// [`remove_stale_temps`] of the one output `path` (the temporaries of its name in its folder).
pub fn remove_stale_temps_of(path: &Path) -> std::io::Result<usize> {
    let name = path
        .file_name()
        .map(|n| format!(".{}{TEMP_TAG}", n.to_string_lossy()));
    match name {
        Some(n) => remove_stale(&folder_of(path), Some(&n)),
        None => Ok(0),
    }
}

fn remove_stale(dir: &Path, prefix: Option<&str>) -> std::io::Result<usize> {
    let entries = match std::fs::read_dir(dir) {
        Ok(e) => e,
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => return Ok(0),
        Err(e) => return Err(e),
    };
    let mut removed = 0;
    for entry in entries.flatten() {
        let name = entry.file_name().to_string_lossy().into_owned();
        if prefix.is_some_and(|p| !name.starts_with(p)) {
            continue;
        }
        let Some(pid) = name
            .strip_prefix('.')
            .and_then(|n| n.rfind(TEMP_TAG).map(|i| &n[i + TEMP_TAG.len()..]))
            .map(|tail| {
                tail.split(|c: char| !c.is_ascii_digit())
                    .next()
                    .unwrap_or("")
            })
            .and_then(|digits| digits.parse::<u32>().ok())
        else {
            continue;
        };
        if pid != std::process::id()
            && !process_alive(pid)
            && entry.file_type().is_ok_and(|t| t.is_file())
            && std::fs::remove_file(entry.path()).is_ok()
        {
            removed += 1;
        }
    }
    Ok(removed)
}

/// Why an output path cannot be used. Found before any work, so nothing is lost.
#[derive(Debug, thiserror::Error)]
pub enum OutputError {
    #[error("{path}: the output would overwrite the input {input}; choose another name")]
    IsInput { path: PathBuf, input: PathBuf },
    #[error(
        "{path}: this output folder holds the input {input}, which an output could overwrite; choose a folder that holds no input (a new sub-folder, say)"
    )]
    HoldsInput { path: PathBuf, input: PathBuf },
    #[error(
        "{path}: inside the input folder {folder}, which geostride only reads (a model, photos); choose a place outside it"
    )]
    InsideInput { path: PathBuf, folder: PathBuf },
    #[error("{path}: is a folder; expected a file name for the output")]
    IsFolder { path: PathBuf },
    #[error("{path}: is a file; expected a folder for the outputs")]
    IsFile { path: PathBuf },
    #[error("{path}: the output folder {folder} does not exist; create it first")]
    NoFolder { path: PathBuf, folder: PathBuf },
    #[error("{path}: {source}")]
    Io {
        path: PathBuf,
        source: std::io::Error,
    },
}

/// The files and folders a command reads, so that no output replaces one, whatever the paths
/// given (links and `..` included).
#[derive(Debug, Default)]
pub struct Inputs {
    /// (as given, resolved)
    paths: Vec<(PathBuf, PathBuf)>,
    /// Folders that are inputs as a whole (a model, a folder of photos): nothing is written
    /// inside them. (as given, resolved)
    folders: Vec<(PathBuf, PathBuf)>,
}

/// `path` with links and `..` resolved as far as it exists, the rest appended: what it will be.
fn resolve(path: &Path) -> PathBuf {
    let abs = if path.is_absolute() {
        path.to_path_buf()
    } else {
        std::env::current_dir().unwrap_or_default().join(path)
    };
    let mut tail = Vec::new();
    let mut head = abs.as_path();
    loop {
        if let Ok(c) = head.canonicalize() {
            return tail.iter().rev().fold(c, |acc, t| acc.join(t));
        }
        match (head.parent(), head.file_name()) {
            (Some(p), Some(n)) => {
                tail.push(n.to_os_string());
                head = p;
            }
            _ => return abs,
        }
    }
}

/// The same file (a hard link too) or the same resolved path.
fn same_file(a: &Path, b: &Path) -> bool {
    #[cfg(unix)]
    {
        use std::os::unix::fs::MetadataExt;
        if let (Ok(x), Ok(y)) = (std::fs::metadata(a), std::fs::metadata(b)) {
            return x.dev() == y.dev() && x.ino() == y.ino();
        }
    }
    resolve(a) == resolve(b)
}

impl Inputs {
    pub fn new<P: AsRef<Path>>(paths: impl IntoIterator<Item = P>) -> Inputs {
        Inputs {
            paths: paths
                .into_iter()
                .map(|p| (p.as_ref().to_path_buf(), resolve(p.as_ref())))
                .collect(),
            folders: Vec::new(),
        }
    }

    /// The inputs `paths`, a folder among them read as a whole ([`Inputs::add_folder`]).
    pub fn with_folders<P: AsRef<Path>>(paths: impl IntoIterator<Item = P>) -> Inputs {
        let mut inputs = Inputs::default();
        for p in paths {
            if p.as_ref().is_dir() {
                inputs.add_folder(p);
            } else {
                inputs.add(p);
            }
        }
        inputs
    }

    pub fn add(&mut self, path: impl AsRef<Path>) {
        let p = path.as_ref();
        self.paths.push((p.to_path_buf(), resolve(p)));
    }

    /// A folder read as a whole (a model, a folder of photos): no output goes inside it, and it
    /// is an input itself.
    pub fn add_folder(&mut self, folder: impl AsRef<Path>) {
        let p = folder.as_ref();
        self.add(p);
        self.folders.push((p.to_path_buf(), resolve(p)));
    }

    /// Refuses a path inside an input folder.
    fn outside_folders(&self, out: &Path) -> Result<(), OutputError> {
        let r = resolve(out);
        match self
            .folders
            .iter()
            .find(|(_, f)| r.starts_with(f) && r != *f)
        {
            Some((folder, _)) => Err(OutputError::InsideInput {
                path: out.to_path_buf(),
                folder: folder.clone(),
            }),
            None => Ok(()),
        }
    }

    /// An output file: not a folder, in a folder that exists, not an input. Stale temporaries
    /// of the same name are removed.
    pub fn check_file(&self, out: &Path) -> Result<(), OutputError> {
        if out.is_dir() {
            return Err(OutputError::IsFolder {
                path: out.to_path_buf(),
            });
        }
        let folder = folder_of(out);
        if !folder.is_dir() {
            return Err(OutputError::NoFolder {
                path: out.to_path_buf(),
                folder,
            });
        }
        if let Some((input, _)) = self.paths.iter().find(|(p, _)| same_file(p, out)) {
            return Err(OutputError::IsInput {
                path: out.to_path_buf(),
                input: input.clone(),
            });
        }
        self.outside_folders(out)?;
        remove_stale_temps_of(out).map_err(|source| OutputError::Io {
            path: out.to_path_buf(),
            source,
        })?;
        Ok(())
    }

    /// An output folder (it may not exist yet): not a file, and neither an input nor holding one.
    pub fn check_dir(&self, out: &Path) -> Result<(), OutputError> {
        if out.exists() && !out.is_dir() {
            return Err(OutputError::IsFile {
                path: out.to_path_buf(),
            });
        }
        let dir = resolve(out);
        if let Some((input, _)) = self.paths.iter().find(|(_, r)| r.starts_with(&dir)) {
            return Err(OutputError::HoldsInput {
                path: out.to_path_buf(),
                input: input.clone(),
            });
        }
        self.outside_folders(out)
    }

    /// [`check_dir`](Self::check_dir), then creates the folder and clears the temporaries a
    /// killed run left in it.
    pub fn create_dir(&self, out: &Path) -> Result<(), OutputError> {
        self.check_dir(out)?;
        let io = |source| OutputError::Io {
            path: out.to_path_buf(),
            source,
        };
        std::fs::create_dir_all(out).map_err(io)?;
        remove_stale_temps(out).map_err(io)?;
        Ok(())
    }
}

/// This process's resident memory, bytes (Linux; `None` elsewhere).
pub fn resident_bytes() -> Option<u64> {
    let statm = std::fs::read_to_string("/proc/self/statm").ok()?;
    let pages: u64 = statm.split_whitespace().nth(1)?.parse().ok()?;
    // SAFETY: sysconf reads a constant of the system.
    let page = unsafe { libc::sysconf(libc::_SC_PAGESIZE) };
    u64::try_from(page).ok().map(|p| pages * p)
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

/// A CSV with a header: its columns, where each of `columns` is, and its data rows (blank lines
/// skipped, each with the header's field count) as (line, fields).
pub(crate) fn csv_rows<'t>(
    ctx: FileCtx<'_>,
    text: &'t str,
    columns: &[&str],
    mut each: impl FnMut(usize, &[&'t str], &[usize], &[&'t str]) -> Result<(), FileError>,
) -> Result<usize, FileError> {
    let mut lines = ctx.lines(text);
    let (_, header) = lines
        .next()
        .transpose()?
        .ok_or_else(|| ctx.err(None, None, "empty file: expected a header line"))?;
    let header: Vec<&str> = header.split(',').map(str::trim).collect();
    let idx: Vec<usize> = columns
        .iter()
        .map(|w| {
            header.iter().position(|h| h == w).ok_or_else(|| {
                ctx.at(
                    1,
                    format!(
                        "no column '{}' in the header ({})",
                        crate::io::clip(w, 40),
                        crate::io::clip(&header.join(","), 200)
                    ),
                )
            })
        })
        .collect::<Result<_, _>>()?;
    let mut rows = 0;
    for row in lines {
        let (line, l) = row?;
        if l.trim().is_empty() {
            continue;
        }
        let f: Vec<&str> = l.split(',').collect();
        ctx.field_count(&f, line, header.len(), header.len(), "the header's columns")?;
        each(line, &f, &idx, &header)?;
        rows += 1;
    }
    Ok(rows)
}

/// The frame `N` of an image name `NAME#N` (a video's frame, as picks and `sfm register` name
/// them): `None` without a `#`, an error when what follows the last `#` is not a frame number.
pub fn frame_of_name(name: &str) -> Option<Result<usize, std::num::ParseIntError>> {
    name.rsplit_once('#').map(|(_, n)| n.parse::<usize>())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_frame_is_read_from_the_end_of_a_name() {
        assert_eq!(frame_of_name("video.mp4#120"), Some(Ok(120)));
        assert_eq!(frame_of_name("a#b.mp4#7"), Some(Ok(7)));
        assert!(matches!(frame_of_name("video.mp4#x"), Some(Err(_))));
        assert_eq!(frame_of_name("IMG_0001.JPG"), None);
    }

    #[test]
    fn iso8601_known_dates() {
        assert_eq!(iso8601_from_unix(0), "1970-01-01T00:00:00Z");
        assert_eq!(iso8601_from_unix(951_782_400), "2000-02-29T00:00:00Z");
        assert_eq!(iso8601_from_unix(1_795_255_200), "2026-11-21T10:00:00Z");
    }

    #[test]
    fn numbers_are_finite_and_messages_short() {
        let ctx = FileCtx {
            path: Path::new("f.csv"),
        };
        assert_eq!(ctx.number(" 1.5 ", 3, "x").unwrap(), 1.5);
        for bad in ["nan", "inf", "-infinity", "1e400", "abc", "12,5"] {
            let e = ctx.number(bad, 3, "x").unwrap_err();
            assert_eq!((e.line, e.field.as_deref()), (Some(3), Some("x")), "{bad}");
        }
        assert!(
            ctx.number("12,5", 3, "x")
                .unwrap_err()
                .message
                .contains("decimal comma")
        );
        let long = "9".repeat(1_000_000) + "x";
        assert!(ctx.number(&long, 1, "x").unwrap_err().to_string().len() < 200);
        assert!(ctx.number_or_nan("NaN", 1, "z").unwrap().is_nan());
        assert!(ctx.number_or_nan("inf", 1, "z").is_err());
        assert!(ctx.positive("0", 1, "s").is_err() && ctx.positive("-1", 1, "s").is_err());
        assert_eq!(ctx.whole("12.0", 1, "frame").unwrap(), 12);
        for bad in ["1.5", "-1", "1e300"] {
            assert!(ctx.whole(bad, 1, "frame").is_err(), "{bad}");
        }
        let e = ctx
            .field_count(&["A", "3", "7", "51", "0"], 4, 3, 3, "name,x,y")
            .unwrap_err();
        assert!(e.message.contains("decimal commas"), "{e}");
        assert!(ctx.field_count(&["A", "b"], 4, 2, usize::MAX, "x").is_ok());
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

    #[test]
    fn a_file_written_in_pieces_that_fails_leaves_the_old_one() {
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("out.txt");
        write_atomic(&p, b"old").unwrap();
        let big = vec![b'x'; 3 << 20];
        let failed = write_atomic_with(&p, |w| {
            w.write_all(&big)?;
            Err(std::io::Error::other("the writer stopped"))
        });
        assert!(failed.is_err());
        assert_eq!(std::fs::read_to_string(&p).unwrap(), "old");
        assert_eq!(std::fs::read_dir(dir.path()).unwrap().count(), 1);
        write_atomic_with(&p, |w| {
            for _ in 0..3 {
                w.write_all(&big)?;
            }
            Ok(())
        })
        .unwrap();
        assert_eq!(std::fs::metadata(&p).unwrap().len(), 9 << 20);
    }

    #[test]
    fn stale_temps_of_dead_processes_are_removed() {
        let dir = tempfile::tempdir().unwrap();
        // No process has this id (beyond the kernel's largest).
        let dead = dir.path().join(".a.csv.tmp-4194999");
        let dead_gpkg = dir.path().join(".t.gpkg.tmp-4194999.gpkg-journal");
        let ours = temp_path(&dir.path().join("b.csv"), "");
        let other = dir.path().join(".hidden-file");
        for p in [&dead, &dead_gpkg, &ours, &other] {
            std::fs::write(p, b"x").unwrap();
        }
        assert_eq!(remove_stale_temps(dir.path()).unwrap(), 2);
        assert!(!dead.exists() && !dead_gpkg.exists());
        assert!(ours.exists() && other.exists());
        assert_eq!(remove_stale_temps(&dir.path().join("none")).unwrap(), 0);
        // An output file's own: only its name's temporaries go, when its path is checked.
        let mine = dir.path().join(".out.txt.tmp-4194999");
        let theirs = dir.path().join(".other.txt.tmp-4194999");
        std::fs::write(&mine, b"x").unwrap();
        std::fs::write(&theirs, b"x").unwrap();
        Inputs::default()
            .check_file(&dir.path().join("out.txt"))
            .unwrap();
        assert!(!mine.exists() && theirs.exists());
    }

    #[test]
    fn outputs_never_replace_inputs() {
        let dir = tempfile::tempdir().unwrap();
        let d = dir.path();
        std::fs::create_dir(d.join("proj")).unwrap();
        let gcps = d.join("proj/gcps.csv");
        std::fs::write(&gcps, b"x").unwrap();
        std::fs::hard_link(&gcps, d.join("link.csv")).unwrap();
        let inputs = Inputs::new([&gcps]);
        // The same file by any path.
        for out in [
            gcps.clone(),
            d.join("proj/../proj/gcps.csv"),
            d.join("link.csv"),
        ] {
            assert!(
                matches!(inputs.check_file(&out), Err(OutputError::IsInput { .. })),
                "{}",
                out.display()
            );
        }
        assert!(inputs.check_file(&d.join("proj/other.csv")).is_ok());
        assert!(matches!(
            inputs.check_file(&d.join("proj")),
            Err(OutputError::IsFolder { .. })
        ));
        assert!(matches!(
            inputs.check_file(&d.join("missing/x.csv")),
            Err(OutputError::NoFolder { .. })
        ));
        // A folder holding an input, at any depth, or the input itself.
        for out in [d.join("proj"), d.to_path_buf(), d.join("proj/./")] {
            assert!(
                matches!(inputs.check_dir(&out), Err(OutputError::HoldsInput { .. })),
                "{}",
                out.display()
            );
        }
        assert!(matches!(
            inputs.check_dir(&gcps),
            Err(OutputError::IsFile { .. })
        ));
        assert!(inputs.check_dir(&d.join("proj/out/run")).is_ok());
        inputs.create_dir(&d.join("proj/out/run")).unwrap();
        assert!(d.join("proj/out/run").is_dir());
    }
}
