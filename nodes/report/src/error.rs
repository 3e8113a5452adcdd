//! The error type of evaluation, reports and comparisons.

use augsplat_core::CoreError;
use std::path::PathBuf;

/// Errors of this crate. Every variant that concerns a file names it.
#[derive(Debug, thiserror::Error)]
pub enum ReportError {
    /// Reading or writing a shared artifact failed (the message names the file).
    #[error(transparent)]
    Core(#[from] CoreError),
    /// A metric could not be computed (sizes, non-finite pixels, LPIPS weights).
    #[error(transparent)]
    Metrics(#[from] augsplat_metrics::MetricsError),
    /// A splat model could not be read.
    #[error(transparent)]
    Splat(#[from] augsplat_splat::SplatError),
    /// A file or folder exists but its contents are not usable.
    #[error("{path}: {message}")]
    Invalid {
        /// The file or folder concerned.
        path: PathBuf,
        /// What is wrong, in words.
        message: String,
    },
    /// An error that concerns no single file (e.g. bad arguments).
    #[error("{0}")]
    Message(String),
}

impl ReportError {
    /// Shorthand for [`ReportError::Invalid`].
    pub fn invalid(path: impl Into<PathBuf>, message: impl Into<String>) -> Self {
        ReportError::Invalid {
            path: path.into(),
            message: message.into(),
        }
    }
    /// Shorthand for an I/O failure on `path`.
    pub fn io(path: impl Into<PathBuf>, source: std::io::Error) -> Self {
        ReportError::Core(CoreError::io(path, source))
    }
}
