//! `augsplat gc` (owned by the engine work, issue 2).

use super::CmdResult;
use augsplat_graph::Registry;

/// Arguments of `augsplat gc`.
#[derive(clap::Args)]
pub struct Args {}

/// Runs `augsplat gc`.
pub fn run(_args: Args, _registry: &Registry) -> CmdResult {
    Err("`gc` is not built yet".into())
}
