//! `augsplat inspect`.

use super::CmdResult;

/// Arguments of `augsplat inspect`.
#[derive(clap::Args)]
pub struct Args {}

/// Runs `augsplat inspect`.
pub fn run(_args: Args) -> CmdResult {
    Err("`inspect` is not built yet".into())
}
