//! The error type of the field crate.

use std::path::PathBuf;

/// Errors of training, loading or rendering a field. Messages name the file or value at fault.
#[derive(Debug, thiserror::Error)]
pub enum FieldError {
    /// A shared-format read or write failed.
    #[error(transparent)]
    Core(#[from] augsplat_core::CoreError),
    /// An argument or configuration value is out of range.
    #[error("invalid configuration: {0}")]
    Config(String),
    /// Input data is unusable (empty scene, size mismatch, ...).
    #[error("invalid input: {0}")]
    Data(String),
    /// A weights file is missing pieces or disagrees with its config.
    #[error("{path}: {message}")]
    Weights {
        /// The file concerned.
        path: PathBuf,
        /// What is wrong.
        message: String,
    },
    /// The GPU backend failed: no adapter, a lost device, out of memory (the message names
    /// the adapter).
    #[error(transparent)]
    Gpu(#[from] augsplat_render::gpu::GpuError),
    /// Training produced non-finite values for too long.
    #[error("training diverged: {0}")]
    Diverged(String),
}
