//! Errors of the splatting crate.

use std::path::PathBuf;

/// What can go wrong reading or writing splats.
#[derive(Debug, thiserror::Error)]
pub enum SplatError {
    /// A file could not be read or written.
    #[error("{path}: {source}")]
    Io {
        /// The file.
        path: PathBuf,
        /// The underlying error.
        #[source]
        source: std::io::Error,
    },
    /// A PLY file is malformed or not in the Inria layout.
    #[error("{path}: {message}")]
    Ply {
        /// The file.
        path: PathBuf,
        /// What is wrong with it.
        message: String,
    },
    /// Inputs are inconsistent (sizes, degrees, parameters).
    #[error("{0}")]
    Invalid(String),
}
