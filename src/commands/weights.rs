//! `augsplat weights`.

use super::CmdResult;

/// Arguments of `augsplat weights`.
#[derive(clap::Args)]
pub struct Args {}

/// Runs `augsplat weights`.
pub fn run(_args: Args) -> CmdResult {
    Err("`weights` is not built yet".into())
}
