//! Errors of the renderer.

use augsplat_core::FileError;

/// What can go wrong reading or writing splats.
#[derive(Debug, thiserror::Error)]
pub enum SplatError {
    /// A file could not be read or written ([`FileError::Io`]), or a PLY file is malformed
    /// or not in the Inria layout ([`FileError::Format`]).
    #[error(transparent)]
    File(#[from] FileError),
    /// Inputs are inconsistent (sizes, degrees, parameters).
    #[error("{0}")]
    Invalid(String),
}
