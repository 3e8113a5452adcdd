//! `augsplat run` (owned by the engine work, issue 2).

use super::CmdResult;
use augsplat_graph::Registry;

/// Arguments of `augsplat run`.
#[derive(clap::Args)]
pub struct Args {}

/// Runs `augsplat run`.
pub fn run(_args: Args, _registry: &Registry) -> CmdResult {
    Err("`run` is not built yet".into())
}
