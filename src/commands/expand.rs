//! `augsplat expand`: print the fully resolved pipeline(s).

use super::run::PipelineArgs;
use super::CmdResult;
use augsplat_graph::Registry;

/// Arguments of `augsplat expand`.
#[derive(clap::Args)]
pub struct Args {
    /// Pipeline, overrides, store (the store caches hashes of external inputs).
    #[command(flatten)]
    pub pipeline: PipelineArgs,
}

/// Runs `augsplat expand`.
pub fn run(args: Args, registry: &Registry) -> CmdResult {
    let (_engine, plan, _scratch) = args.pipeline.load_anywhere(registry)?;
    print!("{}", augsplat_graph::expand_text(&plan));
    Ok(())
}
