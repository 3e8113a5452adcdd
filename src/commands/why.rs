//! `augsplat why`: what changed for a node since its previous run.

use super::run::PipelineArgs;
use super::CmdResult;
use augsplat_graph::Registry;

/// Arguments of `augsplat why`.
#[derive(clap::Args)]
pub struct Args {
    /// Pipeline, overrides, store.
    #[command(flatten)]
    pub pipeline: PipelineArgs,
    /// The node (a name matches all its instances; `field[2]` or `agg@gamma=0.5` one).
    pub node: String,
}

/// Runs `augsplat why`.
pub fn run(args: Args, registry: &Registry) -> CmdResult {
    let (engine, plan) = args.pipeline.load(registry)?;
    let text = engine
        .why_text(&plan, &args.node)
        .map_err(|e| e.to_string())?;
    print!("{text}");
    Ok(())
}
