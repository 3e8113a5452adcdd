//! The error type of the shared formats.

use std::path::PathBuf;

/// Errors reading or writing the shared artifact formats. Every variant names the file.
#[derive(Debug, thiserror::Error)]
pub enum CoreError {
    /// The file could not be read or written.
    #[error("{path}: {source}")]
    Io {
        /// The file concerned.
        path: PathBuf,
        /// The underlying I/O error.
        source: std::io::Error,
    },
    /// The file exists but its contents are not what the format requires.
    #[error("{path}: {message}")]
    Format {
        /// The file concerned.
        path: PathBuf,
        /// What is wrong, in words.
        message: String,
    },
}

impl CoreError {
    /// Shorthand for an I/O error on `path`.
    pub fn io(path: impl Into<PathBuf>, source: std::io::Error) -> Self {
        CoreError::Io {
            path: path.into(),
            source,
        }
    }
    /// Shorthand for a format error on `path`.
    pub fn format(path: impl Into<PathBuf>, message: impl Into<String>) -> Self {
        CoreError::Format {
            path: path.into(),
            message: message.into(),
        }
    }
}
