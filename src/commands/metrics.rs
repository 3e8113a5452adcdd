//! `augsplat metrics`.

use super::CmdResult;

/// Arguments of `augsplat metrics`.
#[derive(clap::Args)]
pub struct Args {}

/// Runs `augsplat metrics`.
pub fn run(_args: Args) -> CmdResult {
    Err("`metrics` is not built yet".into())
}
