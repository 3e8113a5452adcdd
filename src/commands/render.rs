//! `augsplat render`.

use super::CmdResult;

/// Arguments of `augsplat render`.
#[derive(clap::Args)]
pub struct Args {}

/// Runs `augsplat render`.
pub fn run(_args: Args) -> CmdResult {
    Err("`render` is not built yet".into())
}
