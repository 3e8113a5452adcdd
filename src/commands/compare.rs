//! `augsplat compare`.

use super::CmdResult;

/// Arguments of `augsplat compare`.
#[derive(clap::Args)]
pub struct Args {}

/// Runs `augsplat compare`.
pub fn run(_args: Args) -> CmdResult {
    Err("`compare` is not built yet".into())
}
