//! `augsplat why` (owned by the engine work, issue 2).

use super::CmdResult;
use augsplat_graph::Registry;

/// Arguments of `augsplat why`.
#[derive(clap::Args)]
pub struct Args {}

/// Runs `augsplat why`.
pub fn run(_args: Args, _registry: &Registry) -> CmdResult {
    Err("`why` is not built yet".into())
}
