//! The error type of every metric and of the weight importer.

use augsplat_core::FileError;
use std::path::PathBuf;

/// Why a metric could not be computed or weights could not be loaded or imported.
#[derive(Debug, thiserror::Error)]
pub enum MetricsError {
    /// The two images differ in width, height or channel count.
    #[error("image sizes differ: {a_w}×{a_h}×{a_c} vs {b_w}×{b_h}×{b_c}")]
    SizeMismatch {
        /// Width of the first image.
        a_w: u32,
        /// Height of the first image.
        a_h: u32,
        /// Channels of the first image.
        a_c: u32,
        /// Width of the second image.
        b_w: u32,
        /// Height of the second image.
        b_h: u32,
        /// Channels of the second image.
        b_c: u32,
    },
    /// An image holds NaN or ±infinity.
    #[error("{which} image has a non-finite value ({value}) at pixel (x {x}, y {y}), channel {c}")]
    NonFinite {
        /// "first" or "second".
        which: &'static str,
        /// Column of the first offending value.
        x: u32,
        /// Row of the first offending value.
        y: u32,
        /// Channel of the first offending value.
        c: u32,
        /// The value itself.
        value: f32,
    },
    /// The image cannot be measured with this metric (too small, empty, wrong channel count,
    /// buffer length not matching its size).
    #[error("{0}")]
    BadImage(String),
    /// A file could not be read or written, or a weight file or archive has unexpected
    /// content.
    #[error(transparent)]
    File(#[from] FileError),
}

impl MetricsError {
    /// An I/O error on `path`.
    pub fn io(path: impl Into<PathBuf>, source: std::io::Error) -> Self {
        FileError::io(path, source).into()
    }
    /// A format error in `path`.
    pub fn format(path: impl Into<PathBuf>, message: impl Into<String>) -> Self {
        FileError::format(path, message).into()
    }
}
