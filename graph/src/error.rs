//! Errors of the engine: pipeline diagnostics with locations, and store/run errors.

use crate::syntax::{Origin, SyntaxError};
use std::fmt;

/// One problem found in a pipeline, with where it is and what to do about it.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Diagnostic {
    /// Where (a file position, a `--set`, a sweep point), when known.
    pub origin: Option<Origin>,
    /// What is wrong.
    pub message: String,
    /// What to do about it.
    pub hint: Option<String>,
}

impl Diagnostic {
    /// A diagnostic at `origin`.
    pub fn at(origin: &Origin, message: impl Into<String>) -> Self {
        Diagnostic {
            origin: Some(origin.clone()),
            message: message.into(),
            hint: None,
        }
    }
    /// A diagnostic without a location.
    pub fn bare(message: impl Into<String>) -> Self {
        Diagnostic {
            origin: None,
            message: message.into(),
            hint: None,
        }
    }
    /// Adds a hint.
    pub fn hint(mut self, hint: impl Into<String>) -> Self {
        self.hint = Some(hint.into());
        self
    }
}

impl From<SyntaxError> for Diagnostic {
    fn from(e: SyntaxError) -> Self {
        Diagnostic {
            origin: Some(e.origin),
            hint: Some(if e.message.contains("written twice") {
                "keep one of them (a file that `extends` another replaces the base's entries; within one map or struct each name appears once)".into()
            } else {
                "RON: structs `(name: value, ..)`, maps `{\"key\": value}`, lists `[a, b]`, strings in double quotes, commas between items"
                    .into()
            }),
            message: format!("syntax error: {}", e.message),
        }
    }
}

impl fmt::Display for Diagnostic {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match &self.origin {
            Some(o) => write!(f, "{o}: {}", self.message)?,
            None => f.write_str(&self.message)?,
        }
        if let Some(Origin::File { path, line, col }) = &self.origin {
            if let Ok(text) = std::fs::read_to_string(path) {
                if let Some(src) = text.lines().nth(*line as usize - 1) {
                    let n = line.to_string();
                    write!(
                        f,
                        "\n {:w$} |\n {n} | {src}\n {:w$} | {:c$}^",
                        "",
                        "",
                        "",
                        w = n.len(),
                        c = *col as usize - 1
                    )?;
                }
            }
        }
        if let Some(h) = &self.hint {
            write!(f, "\n  hint: {h}")?;
        }
        Ok(())
    }
}

/// Every problem found in a pipeline (nothing runs when there is one).
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct PipelineError(pub Vec<Diagnostic>);

impl fmt::Display for PipelineError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        for (i, d) in self.0.iter().enumerate() {
            if i > 0 {
                f.write_str("\n")?;
            }
            write!(f, "{d}")?;
        }
        Ok(())
    }
}

impl std::error::Error for PipelineError {}

impl From<Diagnostic> for PipelineError {
    fn from(d: Diagnostic) -> Self {
        PipelineError(vec![d])
    }
}

/// An error of the store or the executor.
#[derive(Debug, thiserror::Error)]
pub enum EngineError {
    /// The pipeline is invalid.
    #[error("{0}")]
    Pipeline(#[from] PipelineError),
    /// A file operation failed.
    #[error("{what} {}: {source}", path.display())]
    Io {
        /// What was being done.
        what: &'static str,
        /// On which path.
        path: std::path::PathBuf,
        /// The cause.
        #[source]
        source: std::io::Error,
    },
    /// A store file is damaged.
    #[error("store file {} is damaged: {message}", path.display())]
    Corrupt {
        /// The file.
        path: std::path::PathBuf,
        /// What is wrong.
        message: String,
    },
    /// The store is busy (e.g. `gc` while a run uses it).
    #[error("{0}")]
    Busy(String),
    /// A command that reads a store was pointed at a path that holds none (only `run`
    /// creates a store).
    #[error("{} holds no augsplat store (check --cache or AUGSPLAT_CACHE; `augsplat run` creates a store)", .0.display())]
    NoStore(std::path::PathBuf),
    /// Anything else, explained.
    #[error("{0}")]
    Other(String),
}

/// Builds an [`EngineError::Io`] mapper: `.map_err(io("reading", &path))`.
pub fn io<'a>(
    what: &'static str,
    path: &'a std::path::Path,
) -> impl FnOnce(std::io::Error) -> EngineError + 'a {
    move |source| EngineError::Io {
        what,
        path: path.to_path_buf(),
        source,
    }
}
