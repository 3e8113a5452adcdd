//! What the GPU tests share: a context on the first adapter, or a skip when there is none.

use augsplat_render::gpu::{GpuContext, GpuError};

/// A context on the first adapter (named on stderr), or `None` after a skip message when no
/// GPU adapter is found — a failure under `CI=true`, where `.ci/run` installs lavapipe. Any
/// other error opening the device fails `test`.
pub fn context(test: &str) -> Option<GpuContext> {
    match GpuContext::new() {
        Ok(c) => {
            eprintln!("{test}: on {}", c.adapter());
            Some(c)
        }
        Err(e @ GpuError::NoAdapter { .. }) => {
            augsplat_testkit::skip(test, &e.to_string());
            None
        }
        Err(e) => panic!("{test}: {e}"),
    }
}
