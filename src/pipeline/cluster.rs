//! A run split across a cluster: the manifest `geostride split` writes, the segments' chunks,
//! the index a batch engine gives each task, and the Slurm scripts. The work itself is
//! [`run_segment`](super::run::run_segment) and [`run_with`](super::run::run_with); a split
//! run's folder is a run's output folder, so `merge` gives what `run` gives, byte for byte.

use std::ops::Range;
use std::path::{Path, PathBuf};

use serde::{Deserialize, Serialize};

use super::run::ChunkPlan;

/// The manifest's file name in a split run's folder.
pub const MANIFEST: &str = "split.json";

/// The manifest of a split run.
#[derive(Clone, Debug, Serialize, Deserialize, PartialEq)]
pub struct Manifest {
    /// `geostride-split/1`.
    pub format: String,
    /// The project file, absolute, and its SHA-256 when split.
    pub project: PathBuf,
    pub project_sha256: String,
    /// The build that split it (a chunk made by another build is not used).
    pub geostride: String,
    pub plan: ChunkPlan,
    /// Each segment's chunks, in order.
    pub segments: Vec<Range<usize>>,
}

pub const FORMAT: &str = "geostride-split/1";

/// `chunks` cut into `n` contiguous segments as even as can be; `None` when there are fewer
/// chunks than segments.
pub fn segments(chunks: usize, n: usize) -> Option<Vec<Range<usize>>> {
    if n == 0 || n > chunks {
        return None;
    }
    Some(
        (0..n)
            .map(|i| i * chunks / n..(i + 1) * chunks / n)
            .collect(),
    )
}

impl Manifest {
    /// The segments holding any of `chunks`, ascending.
    pub fn segments_of(&self, chunks: &[usize]) -> Vec<usize> {
        let mut out: Vec<usize> = chunks
            .iter()
            .filter_map(|c| self.segments.iter().position(|r| r.contains(c)))
            .collect();
        out.dedup();
        out
    }

    pub fn read(dir: &Path) -> Result<Manifest, ClusterError> {
        let path = dir.join(MANIFEST);
        let text = std::fs::read_to_string(&path).map_err(|e| ClusterError::NoManifest {
            path: path.clone(),
            dir: dir.to_path_buf(),
            message: e.to_string(),
        })?;
        let m: Manifest = serde_json::from_str(&text).map_err(|e| ClusterError::NotAManifest {
            path: path.clone(),
            message: e.to_string(),
        })?;
        if m.format != FORMAT {
            return Err(ClusterError::Format {
                path,
                format: m.format,
            });
        }
        Ok(m)
    }
}

/// Why a split folder or a task's index cannot be used.
#[derive(Debug, PartialEq, thiserror::Error)]
pub enum ClusterError {
    #[error("{}: {message}; is {} a folder made by 'geostride split'?", path.display(), dir.display())]
    NoManifest {
        path: PathBuf,
        dir: PathBuf,
        message: String,
    },
    #[error("{}: not a split manifest: {message}", path.display())]
    NotAManifest { path: PathBuf, message: String },
    #[error("{}: format '{format}', expected '{FORMAT}' (split again with this geostride)", path.display())]
    Format { path: PathBuf, format: String },
    #[error("{variable}='{value}' is not a segment index (0, 1, ...)")]
    BadIndex {
        variable: &'static str,
        value: String,
    },
    #[error("no --index and none of {} is set: give the segment's index", INDEX_VARIABLES.join(", "))]
    NoIndex,
}

/// The variables batch engines give each task of an array its index in: Slurm's job arrays,
/// Kubernetes Indexed Jobs, AWS Batch array jobs.
pub const INDEX_VARIABLES: [&str; 3] = [
    "SLURM_ARRAY_TASK_ID",
    "JOB_COMPLETION_INDEX",
    "AWS_BATCH_JOB_ARRAY_INDEX",
];

/// The task's index from the first of [`INDEX_VARIABLES`] that is set (`get` reads a
/// variable); an error names them when none is, or the value when it is not a number.
pub fn index_from(get: impl Fn(&str) -> Option<String>) -> Result<usize, ClusterError> {
    for v in INDEX_VARIABLES {
        if let Some(s) = get(v) {
            return s.trim().parse().map_err(|_| ClusterError::BadIndex {
                variable: v,
                value: s,
            });
        }
    }
    Err(ClusterError::NoIndex)
}

/// The batch resources of the Slurm jobs.
#[derive(Clone, Debug, PartialEq)]
pub struct SlurmOptions {
    pub partition: Option<String>,
    /// `sbatch --time` of a segment and of the merge (e.g. `2:00:00`).
    pub time: String,
    pub merge_time: String,
    /// `sbatch --mem` of a segment and of the merge (e.g. `8G`).
    pub mem: String,
    pub merge_mem: String,
    pub cpus: u32,
    /// Extra `#SBATCH` lines (an account, a QOS), verbatim.
    pub extra: Vec<String>,
}

/// The most CPUs a task may ask for.
pub const MAX_CPUS: u32 = 4096;

impl SlurmOptions {
    /// Every value is one `#SBATCH` word that Slurm reads as meant: no value can end its line
    /// (a newline would make the rest a shell command of every task), split into more options,
    /// start a comment or open a quote. Gives the option and what is wrong.
    pub fn check(&self) -> Result<(), (&'static str, String)> {
        let digits = |s: &str| !s.is_empty() && s.bytes().all(|b| b.is_ascii_digit());
        for (flag, t) in [("--time", &self.time), ("--merge-time", &self.merge_time)] {
            let (days, clock) = match t.split_once('-') {
                Some((d, c)) => (Some(d), c),
                None => (None, t.as_str()),
            };
            let parts: Vec<&str> = clock.split(':').collect();
            let ok = ["unlimited", "infinite"].contains(&t.to_ascii_lowercase().as_str())
                || (days.is_none_or(digits) && parts.len() <= 3 && parts.iter().all(|p| digits(p)));
            if !ok {
                return Err((
                    flag,
                    format!(
                        "'{}': expected a Slurm time: MINUTES, HH:MM:SS, D-HH[:MM[:SS]] or UNLIMITED",
                        crate::io::clip(&t.escape_debug().to_string(), 40)
                    ),
                ));
            }
        }
        for (flag, m) in [("--mem", &self.mem), ("--merge-mem", &self.merge_mem)] {
            let number = m.trim_end_matches(['K', 'M', 'G', 'T', 'k', 'm', 'g', 't']);
            if !digits(number) || m.len() > number.len() + 1 {
                return Err((
                    flag,
                    format!(
                        "'{}': expected a Slurm memory size: a whole number with K, M, G or T (e.g. 8G)",
                        crate::io::clip(&m.escape_debug().to_string(), 40)
                    ),
                ));
            }
        }
        if let Some(p) = &self.partition
            && (p.is_empty()
                || !p
                    .chars()
                    .all(|c| c.is_ascii_alphanumeric() || "_.,-".contains(c)))
        {
            return Err((
                "--partition",
                format!(
                    "'{}': expected partition names (letters, digits, '_', '.', '-', comma-separated)",
                    crate::io::clip(&p.escape_debug().to_string(), 40)
                ),
            ));
        }
        if !(1..=MAX_CPUS).contains(&self.cpus) {
            return Err((
                "--cpus",
                format!("{}: expected 1 to {MAX_CPUS} CPUs a task", self.cpus),
            ));
        }
        for e in &self.extra {
            let bad = e
                .chars()
                .find(|c| c.is_control() || c.is_whitespace() || "#'\"\\`$;".contains(*c));
            if !e.starts_with('-') || e.len() < 2 || bad.is_some() {
                return Err((
                    "--sbatch",
                    format!(
                        "'{}': expected one sbatch option such as --account=crowd{}",
                        crate::io::clip(&e.escape_debug().to_string(), 40),
                        match bad {
                            Some(c) => format!(
                                ", without '{}' (Slurm would read it as more than the option)",
                                c.escape_debug()
                            ),
                            None => String::new(),
                        }
                    ),
                ));
            }
        }
        Ok(())
    }
}

/// A path Slurm can take in `#SBATCH --output=`: its file-name patterns (`%`) and escapes (`\`)
/// written literally; `None` for a path with a control character (no line can hold it).
pub(crate) fn slurm_path(path: &Path) -> Option<String> {
    let s = path.to_str()?;
    if s.chars().any(char::is_control) {
        return None;
    }
    Some(shell_quote(&s.replace('\\', "\\\\").replace('%', "%%")))
}

/// A word for a shell script, quoted.
pub fn shell_quote(s: &str) -> String {
    if !s.is_empty()
        && s.chars()
            .all(|c| c.is_ascii_alphanumeric() || "-_./=:,+@%".contains(c))
    {
        s.to_string()
    } else {
        format!("'{}'", s.replace('\'', "'\\''"))
    }
}

/// The scripts' head; `log` is a file name pattern of Slurm's (`%a`, the task), `dir` the
/// folder it is in.
fn header(name: &str, o: &SlurmOptions, time: &str, mem: &str, dir: &str, log: &str) -> String {
    let mut s = format!(
        "#!/bin/bash\n#SBATCH --job-name={name}\n#SBATCH --time={time}\n#SBATCH --mem={mem}\n#SBATCH --cpus-per-task={}\n#SBATCH --ntasks=1\n#SBATCH --output={dir}{log}\n",
        o.cpus,
    );
    if let Some(p) = &o.partition {
        s.push_str(&format!("#SBATCH --partition={p}\n"));
    }
    for e in &o.extra {
        s.push_str(&format!("#SBATCH {e}\n"));
    }
    s
}

/// Why Slurm scripts cannot be written.
#[derive(Debug, thiserror::Error)]
pub enum SlurmError {
    #[error("{flag} {message}")]
    Option { flag: &'static str, message: String },
    #[error(
        "{}: a Slurm script cannot name this folder (a control character, or not UTF-8); choose another --out",
        .0.escape_debug()
    )]
    Path(String),
}

/// The segments' array script and the merge's script for the split run in `dir`, run with the
/// executable `exe`. The options are checked ([`SlurmOptions::check`]) and every path quoted.
pub fn slurm_scripts(
    exe: &Path,
    dir: &Path,
    segments: usize,
    o: &SlurmOptions,
) -> Result<(String, String), SlurmError> {
    o.check()
        .map_err(|(flag, message)| SlurmError::Option { flag, message })?;
    let refused = |p: &Path| SlurmError::Path(p.display().to_string());
    let quoted = |p: &Path| match p.to_str() {
        Some(s) if !s.chars().any(char::is_control) => Ok(shell_quote(s)),
        _ => Err(refused(p)),
    };
    let (exe, d) = (quoted(exe)?, quoted(dir)?);
    // The log's folder as Slurm reads it, the pattern after it (`%a` must stay a pattern).
    let logs_dir = dir.join("slurm").join("");
    let logs = slurm_path(&logs_dir).ok_or_else(|| refused(&logs_dir))?;
    let mut seg = header(
        "geostride-segment",
        o,
        &o.time,
        &o.mem,
        &logs,
        "segment-%a.log",
    );
    seg.push_str(&format!(
        "#SBATCH --array=0-{}\n# One segment of the video per task; a segment done already is not redone.\nset -euo pipefail\nexec {exe} segment {d} -q\n",
        segments.saturating_sub(1)
    ));
    let mut merge = header(
        "geostride-merge",
        o,
        &o.merge_time,
        &o.merge_mem,
        &logs,
        "merge.log",
    );
    merge.push_str(&format!(
        "# After every segment (submitted with --dependency=afterok on the array).\nset -euo pipefail\nexec {exe} merge {d} -q\n"
    ));
    Ok((seg, merge))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn segments_cover_the_chunks_in_order_and_evenly() {
        assert_eq!(segments(7, 3).unwrap(), vec![0..2, 2..4, 4..7]);
        assert_eq!(segments(5, 5).unwrap(), vec![0..1, 1..2, 2..3, 3..4, 4..5]);
        assert_eq!(segments(4, 5), None);
        assert_eq!(segments(4, 0), None);
    }

    #[test]
    fn the_index_comes_from_whichever_engine_set_it() {
        let env = |k: &str, v: &str| {
            let (k, v) = (k.to_string(), v.to_string());
            move |q: &str| (q == k).then(|| v.clone())
        };
        assert_eq!(index_from(env("SLURM_ARRAY_TASK_ID", "3")), Ok(3));
        assert_eq!(index_from(env("JOB_COMPLETION_INDEX", "0")), Ok(0));
        assert_eq!(index_from(env("AWS_BATCH_JOB_ARRAY_INDEX", "12")), Ok(12));
        assert!(
            index_from(env("SLURM_ARRAY_TASK_ID", "x"))
                .unwrap_err()
                .to_string()
                .contains("'x'")
        );
        assert!(
            index_from(|_| None)
                .unwrap_err()
                .to_string()
                .contains("SLURM_ARRAY_TASK_ID")
        );
    }

    #[test]
    fn slurm_scripts_run_the_array_then_the_merge() {
        let o = SlurmOptions {
            partition: Some("short".into()),
            time: "1:00:00".into(),
            merge_time: "0:30:00".into(),
            mem: "4G".into(),
            merge_mem: "8G".into(),
            cpus: 2,
            extra: vec!["--account=crowd".into()],
        };
        let (s, m) =
            slurm_scripts(Path::new("/opt/gs"), Path::new("/scratch/my run"), 5, &o).unwrap();
        assert!(s.contains("#SBATCH --array=0-4\n"));
        assert!(s.contains("exec /opt/gs segment '/scratch/my run' -q"));
        assert!(s.contains("#SBATCH --partition=short\n#SBATCH --account=crowd\n"));
        assert!(s.contains("#SBATCH --output='/scratch/my run/slurm/'segment-%a.log\n"));
        assert!(m.contains("exec /opt/gs merge '/scratch/my run' -q"));
        assert!(m.contains("#SBATCH --mem=8G"));
        // A '%' of the folder is not a pattern of Slurm's.
        let (s, _) = slurm_scripts(Path::new("/opt/gs"), Path::new("/runs/100%"), 2, &o).unwrap();
        assert!(
            s.contains("--output=/runs/100%%/slurm/segment-%a.log"),
            "{s}"
        );
    }

    #[test]
    fn a_value_that_would_end_its_line_or_split_is_refused() {
        let good = SlurmOptions {
            partition: Some("short,long".into()),
            time: "2-12:00:00".into(),
            merge_time: "90".into(),
            mem: "16G".into(),
            merge_mem: "512".into(),
            cpus: 8,
            extra: vec!["--qos=high".into()],
        };
        good.check().unwrap();
        let bad: Vec<(&str, Box<dyn Fn(&mut SlurmOptions)>)> = vec![
            ("--time", Box::new(|o| o.time = "1:00\nrm -rf ~".into())),
            (
                "--merge-time",
                Box::new(|o| o.merge_time = "1:00 --exclusive".into()),
            ),
            ("--mem", Box::new(|o| o.mem = "8G\ntouch x".into())),
            ("--merge-mem", Box::new(|o| o.merge_mem = "8GB#".into())),
            (
                "--partition",
                Box::new(|o| o.partition = Some("a\nb".into())),
            ),
            (
                "--partition",
                Box::new(|o| o.partition = Some(String::new())),
            ),
            ("--cpus", Box::new(|o| o.cpus = 0)),
            (
                "--sbatch",
                Box::new(|o| o.extra = vec!["--account=x\necho".into()]),
            ),
            ("--sbatch", Box::new(|o| o.extra = vec!["account=x".into()])),
            (
                "--sbatch",
                Box::new(|o| o.extra = vec!["--comment='a".into()]),
            ),
            ("--sbatch", Box::new(|o| o.extra = vec!["--x=$(id)".into()])),
        ];
        for (flag, f) in bad {
            let mut o = good.clone();
            f(&mut o);
            assert_eq!(o.check().unwrap_err().0, flag);
            assert!(slurm_scripts(Path::new("/g"), Path::new("/r"), 2, &o).is_err());
        }
        assert!(slurm_scripts(Path::new("/g"), Path::new("/r\nx"), 2, &good).is_err());
    }
}
