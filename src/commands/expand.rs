//! `augsplat expand` (owned by the engine work, issue 2).

use super::CmdResult;
use augsplat_graph::Registry;

/// Arguments of `augsplat expand`.
#[derive(clap::Args)]
pub struct Args {}

/// Runs `augsplat expand`.
pub fn run(_args: Args, _registry: &Registry) -> CmdResult {
    Err("`expand` is not built yet".into())
}
