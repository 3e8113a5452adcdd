//! The shared data folder beside the repository: `<workspace>/../shared/data`.

use std::path::PathBuf;

/// `<workspace>/../shared/data` (whether or not it exists).
pub fn shared_data_dir() -> PathBuf {
    crate::workspace_root().join("../shared/data")
}

/// The shared data folder if `required` (a path inside it, e.g. `"metrics/golden.json"`, or
/// `""` for the folder itself) exists; otherwise reports the skip for `test` (a failure under
/// `CI=true`) and returns `None`.
pub fn shared_data(test: &str, required: &str) -> Option<PathBuf> {
    let dir = shared_data_dir();
    let needed = if required.is_empty() {
        dir.clone()
    } else {
        dir.join(required)
    };
    if needed.exists() {
        Some(dir)
    } else {
        crate::skip(test, &format!("{} is absent", needed.display()));
        None
    }
}
