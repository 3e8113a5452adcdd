//! The error types of the shared formats: [`FileError`], the one error of a named file that
//! every crate's error enum carries, and [`CoreError`], the error of this crate.

use std::path::{Path, PathBuf};

/// A file (or folder) that could not be read or written, or whose contents are not what its
/// format requires. The message names the file: `"{path}: {what went wrong}"`.
///
/// The error enums of the other crates carry it as a transparent variant
/// (`#[error(transparent)] File(#[from] FileError)`), so a file error reads the same whichever
/// crate reports it.
#[derive(Debug, thiserror::Error)]
pub enum FileError {
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
        /// What is wrong, in words (naming the entry where there is one).
        message: String,
    },
}

impl FileError {
    /// An I/O error on `path`.
    pub fn io(path: impl Into<PathBuf>, source: std::io::Error) -> Self {
        FileError::Io {
            path: path.into(),
            source,
        }
    }
    /// A format error in `path`.
    pub fn format(path: impl Into<PathBuf>, message: impl Into<String>) -> Self {
        FileError::Format {
            path: path.into(),
            message: message.into(),
        }
    }
    /// A "not found" I/O error for a required file or folder: `"{path}: {what} not found"`.
    pub fn missing(path: &Path, what: &str) -> Self {
        FileError::io(
            path,
            std::io::Error::new(std::io::ErrorKind::NotFound, format!("{what} not found")),
        )
    }
    /// The file concerned.
    pub fn path(&self) -> &Path {
        match self {
            FileError::Io { path, .. } | FileError::Format { path, .. } => path,
        }
    }
}

/// Errors reading or writing the shared artifact formats. Every variant names the file.
#[derive(Debug, thiserror::Error)]
pub enum CoreError {
    /// A file could not be read or written, or has the wrong contents.
    #[error(transparent)]
    File(#[from] FileError),
}

impl CoreError {
    /// Shorthand for an I/O error on `path`.
    pub fn io(path: impl Into<PathBuf>, source: std::io::Error) -> Self {
        FileError::io(path, source).into()
    }
    /// Shorthand for a format error on `path`.
    pub fn format(path: impl Into<PathBuf>, message: impl Into<String>) -> Self {
        FileError::format(path, message).into()
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::error::Error as _;

    /// The message names the file and says what went wrong; the I/O error stays the source.
    #[test]
    fn file_errors_name_the_file() {
        let e = CoreError::io(
            "a/b.png",
            std::io::Error::new(std::io::ErrorKind::NotFound, "gone"),
        );
        assert_eq!(e.to_string(), "a/b.png: gone");
        assert_eq!(e.source().map(|s| s.to_string()).as_deref(), Some("gone"));
        let e = CoreError::format("c.json", "bad entry");
        assert_eq!(e.to_string(), "c.json: bad entry");
        assert!(e.source().is_none());
        let e = FileError::missing(Path::new("d"), "scene folder");
        assert_eq!(e.to_string(), "d: scene folder not found");
        assert_eq!(e.path(), Path::new("d"));
    }
}
