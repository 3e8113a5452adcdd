//! The error type of scene import, split, depth, export and inspection.

use augsplat_core::{CoreError, FileError};
use std::path::{Path, PathBuf};

/// Errors of this crate. Every variant that concerns a file names it; parse errors also name
/// the entry (line, image or camera id) in the message.
#[derive(Debug, thiserror::Error)]
pub enum SceneError {
    /// An error of the shared formats (image, EXR, scene folder), which already names its file.
    #[error(transparent)]
    Core(#[from] CoreError),
    /// A file or folder could not be read or written, or a file's contents are wrong (the
    /// message names the file, and for parse errors the entry: line, image or camera id).
    #[error(transparent)]
    File(#[from] FileError),
    /// The input as a whole is unusable (e.g. no views left), or an argument is out of range.
    #[error("{0}")]
    Invalid(String),
}

impl SceneError {
    /// An I/O error on `path`.
    pub fn io(path: impl Into<PathBuf>, source: std::io::Error) -> Self {
        FileError::io(path, source).into()
    }
    /// A format error on `path`.
    pub fn format(path: impl Into<PathBuf>, message: impl Into<String>) -> Self {
        FileError::format(path, message).into()
    }
    /// A "not found" error for a required file or folder.
    pub fn missing(path: &Path, what: &str) -> Self {
        FileError::missing(path, what).into()
    }
}

/// Shorthand result type.
pub type Result<T, E = SceneError> = std::result::Result<T, E>;
