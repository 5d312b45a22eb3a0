//! The error of a run (`geostride run`, `segment`, `merge`, `render`): the user's input at fault
//! (exit status 2) or a failure while running (1).

use std::path::PathBuf;

use crate::cache::CacheError;

/// A failure of a run: bad input (the user's to fix: [`RunError::is_input`]) or a failure while
/// running.
#[derive(Debug, thiserror::Error)]
pub enum RunError {
    /// An input file, or a key of the project file, is wrong: the file, line and key named.
    #[error(transparent)]
    Input(#[from] crate::io::FileError),
    /// The inputs cannot give a result (no pose from these picks, say), in words.
    #[error("{0}")]
    Unusable(String),
    /// An output path that cannot be used (it would overwrite an input, say).
    #[error(transparent)]
    OutputPath(crate::io::OutputError),
    /// Reading or writing a file failed while running.
    #[error("{}: {source}", path.display())]
    Io {
        path: PathBuf,
        #[source]
        source: std::io::Error,
    },
    /// The pose stage's files could not be written.
    #[error(transparent)]
    PoseOutputs(#[from] super::pose_outputs::PoseOutputError),
    /// A GeoPackage or GeoJSON file could not be written.
    #[error(transparent)]
    Gis(#[from] crate::gis::GisError),
    /// A coordinate conversion failed while running.
    #[error(transparent)]
    Crs(#[from] crate::survey::crs::CrsError),
    /// Chunks of the video are not done (a cluster's segments that failed or did not run).
    #[error("{} of the video's chunks are missing or were made from other inputs or by another build: {}", .0.len(), chunk_list(.0))]
    MissingChunks(Vec<usize>),
    /// The stage cache could not be written or read back.
    #[error(transparent)]
    Cache(#[from] CacheError),
    /// Anything else that failed while running.
    #[error("{0}")]
    Failed(String),
}

/// Chunk numbers for a message, runs of them as ranges.
pub fn chunk_list(chunks: &[usize]) -> String {
    let mut parts: Vec<String> = Vec::new();
    let mut i = 0;
    while i < chunks.len() {
        let mut j = i;
        while j + 1 < chunks.len() && chunks[j + 1] == chunks[j] + 1 {
            j += 1;
        }
        parts.push(if i == j {
            chunks[i].to_string()
        } else {
            format!("{}-{}", chunks[i], chunks[j])
        });
        i = j + 1;
    }
    parts.join(", ")
}

impl RunError {
    /// Whether the inputs are at fault (exit status 2), rather than the run.
    pub fn is_input(&self) -> bool {
        matches!(
            self,
            RunError::Input(_) | RunError::Unusable(_) | RunError::OutputPath(_)
        )
    }

    /// An input's error that names its own file.
    pub(crate) fn from_input(e: impl std::fmt::Display) -> RunError {
        RunError::Unusable(e.to_string())
    }
}

/// A failure described in words (an adapter's, say), while running.
impl From<String> for RunError {
    fn from(s: String) -> RunError {
        RunError::Failed(s)
    }
}

/// An output path that cannot be used is the project's to fix; an I/O failure is not.
pub(crate) fn output_error(e: crate::io::OutputError) -> RunError {
    match e {
        crate::io::OutputError::Io { path, source } => RunError::Io { path, source },
        e => RunError::OutputPath(e),
    }
}
