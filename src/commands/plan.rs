//! `augsplat plan`: per node, cached or will run; per sweep point, new vs cached.

use super::run::PipelineArgs;
use super::CmdResult;
use augsplat_graph::Registry;

/// Arguments of `augsplat plan`.
#[derive(clap::Args)]
pub struct Args {
    /// Pipeline, overrides, store.
    #[command(flatten)]
    pub pipeline: PipelineArgs,
    /// Only what these nodes need. Repeatable.
    #[arg(long = "target", value_name = "NODE")]
    pub targets: Vec<String>,
}

/// Runs `augsplat plan`.
pub fn run(args: Args, registry: &Registry) -> CmdResult {
    let (engine, plan) = args.pipeline.load(registry)?;
    let text = engine
        .plan_text(&plan, &args.targets)
        .map_err(|e| e.to_string())?;
    print!("{text}");
    Ok(())
}
