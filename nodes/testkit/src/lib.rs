//! Helpers shared by augsplat's tests and examples (a dev-dependency only).
//!
//! - [`data`]: the shared data folder beside the repository (`../shared/data`), found the same
//!   way from every crate, with one skip rule;
//! - [`browser`]: headless Chromium for the report tests;
//! - [`cameras`]: test cameras (facing the origin, on a ring);
//! - [`copy_dir`]: a writable copy of a folder (to corrupt or edit in a test);
//! - [`with_threads`]: run a closure on a fresh pool of a given size (determinism tests);
//! - [`tiny`]: the tiny sizes at which the test suite runs the method pipelines (the same
//!   values as `tests/tiny.ron`, checked by a test of the CLI).
//!
//! The skip rule: outside CI a test whose external requirement (the shared data, Chromium) is
//! missing prints what it skips and passes; under `CI=true` — where `.ci/run` provides every
//! requirement — it fails instead, so a broken CI set-up cannot turn into silent passes.

pub mod browser;
pub mod cameras;
pub mod data;
pub mod tiny;

use std::path::PathBuf;

/// The workspace root (the folder of the top-level `Cargo.toml`).
pub fn workspace_root() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../..")
}

/// Whether the tests run under CI (`CI=true`), where missing requirements fail.
pub fn under_ci() -> bool {
    std::env::var("CI").is_ok_and(|v| v == "true")
}

/// Reports a missing requirement: panics under CI, else prints `skipping <test>: <why>`.
pub fn skip(test: &str, why: &str) {
    assert!(
        !under_ci(),
        "{test}: {why} — required under CI=true (.ci/run provides it)"
    );
    eprintln!("skipping {test}: {why}");
}

/// Runs `f` on a fresh rayon pool of `threads` threads (the determinism tests compare the
/// bits of one computation at several thread counts).
///
/// Panics if the pool cannot be built (a test set-up failure).
pub fn with_threads<R: Send>(threads: usize, f: impl FnOnce() -> R + Send) -> R {
    rayon::ThreadPoolBuilder::new()
        .num_threads(threads)
        .build()
        .expect("a rayon pool for the test")
        .install(f)
}

/// Copies the folder `from` to `to` recursively as writable files (sources in the store or the
/// shared data folder are read-only). Panics on I/O errors (a test set-up failure).
pub fn copy_dir(from: &std::path::Path, to: &std::path::Path) {
    std::fs::create_dir_all(to).expect("creating the copy's folder");
    for e in std::fs::read_dir(from).expect("listing the folder to copy") {
        let p = e.expect("a folder entry").path();
        let dst = to.join(p.file_name().expect("an entry name"));
        if p.is_dir() {
            copy_dir(&p, &dst);
        } else {
            std::fs::copy(&p, &dst).expect("copying a file");
            let mut perm = std::fs::metadata(&dst).expect("the copy").permissions();
            #[allow(clippy::permissions_set_readonly_false)]
            perm.set_readonly(false);
            std::fs::set_permissions(&dst, perm).expect("making the copy writable");
        }
    }
}
