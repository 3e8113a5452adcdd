//! `augsplat plan` (owned by the engine work, issue 2).

use super::CmdResult;
use augsplat_graph::Registry;

/// Arguments of `augsplat plan`.
#[derive(clap::Args)]
pub struct Args {}

/// Runs `augsplat plan`.
pub fn run(_args: Args, _registry: &Registry) -> CmdResult {
    Err("`plan` is not built yet".into())
}
