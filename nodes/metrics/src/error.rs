//! The error type of every metric and of the weight importer.

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
    /// A file could not be read or written.
    #[error("{path}: {source}")]
    Io {
        /// The file.
        path: PathBuf,
        /// The underlying error.
        source: std::io::Error,
    },
    /// A weight file or archive has unexpected content.
    #[error("{path}: {message}")]
    Format {
        /// The file.
        path: PathBuf,
        /// What is wrong with it.
        message: String,
    },
}

impl MetricsError {
    /// An I/O error on `path`.
    pub fn io(path: impl Into<PathBuf>, source: std::io::Error) -> Self {
        MetricsError::Io {
            path: path.into(),
            source,
        }
    }
    /// A format error in `path`.
    pub fn format(path: impl Into<PathBuf>, message: impl Into<String>) -> Self {
        MetricsError::Format {
            path: path.into(),
            message: message.into(),
        }
    }
}
