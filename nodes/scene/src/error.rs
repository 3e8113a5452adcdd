//! The error type of scene import, split, depth, export and inspection.

use augsplat_core::CoreError;
use std::path::{Path, PathBuf};

/// Errors of this crate. Every variant that concerns a file names it; parse errors also name
/// the entry (line, image or camera id) in the message.
#[derive(Debug, thiserror::Error)]
pub enum SceneError {
    /// An error of the shared formats (image, EXR, scene folder), which already names its file.
    #[error(transparent)]
    Core(#[from] CoreError),
    /// A file or folder could not be read or written.
    #[error("{path}: {source}")]
    Io {
        /// The file concerned.
        path: PathBuf,
        /// The underlying I/O error.
        source: std::io::Error,
    },
    /// A file exists but its contents are wrong.
    #[error("{path}: {message}")]
    Format {
        /// The file concerned.
        path: PathBuf,
        /// What is wrong, naming the entry.
        message: String,
    },
    /// The input as a whole is unusable (e.g. no views left), or an argument is out of range.
    #[error("{0}")]
    Invalid(String),
}

impl SceneError {
    /// An I/O error on `path`.
    pub fn io(path: impl Into<PathBuf>, source: std::io::Error) -> Self {
        SceneError::Io {
            path: path.into(),
            source,
        }
    }
    /// A format error on `path`.
    pub fn format(path: impl Into<PathBuf>, message: impl Into<String>) -> Self {
        SceneError::Format {
            path: path.into(),
            message: message.into(),
        }
    }
    /// A "not found" error for a required file or folder.
    pub fn missing(path: &Path, what: &str) -> Self {
        SceneError::Io {
            path: path.to_path_buf(),
            source: std::io::Error::new(std::io::ErrorKind::NotFound, format!("{what} not found")),
        }
    }
}

/// Shorthand result type.
pub type Result<T, E = SceneError> = std::result::Result<T, E>;
