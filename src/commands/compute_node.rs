//! `augsplat compute-node` (hidden): what a Slurm job of `augsplat run --executor slurm`
//! runs. It resolves the same pipeline, finds the computation whose key is line `--index` of
//! `--keys-file`, and computes it into the shared store (or finds it there).

use super::run::PipelineArgs;
use super::CmdResult;
use augsplat_graph::{Registry, Status};
use std::path::PathBuf;

/// Arguments of `augsplat compute-node`.
#[derive(clap::Args)]
pub struct Args {
    /// Pipeline, overrides, store.
    #[command(flatten)]
    pub pipeline: PipelineArgs,
    /// The submission's keys file: one `KEY THREADS` line per array task.
    #[arg(long, value_name = "FILE")]
    pub keys_file: PathBuf,
    /// Which line (the array task id; 0 for a single job).
    #[arg(long, default_value_t = 0)]
    pub index: usize,
    /// Checkpoint cadence of long nodes, in their steps (0: never).
    #[arg(long, default_value_t = augsplat_graph::exec::DEFAULT_CHECKPOINT_EVERY)]
    pub checkpoint_every: u64,
}

/// Runs `augsplat compute-node`.
pub fn run(args: Args, registry: &Registry) -> CmdResult {
    let text = std::fs::read_to_string(&args.keys_file)
        .map_err(|e| format!("reading {}: {e}", args.keys_file.display()))?;
    let line = text.lines().nth(args.index).ok_or_else(|| {
        format!(
            "{} has no line {} (array task id)",
            args.keys_file.display(),
            args.index
        )
    })?;
    let mut parts = line.split_whitespace();
    let key = parts.next().unwrap_or("");
    let threads: usize = parts
        .next()
        .and_then(|t| t.parse().ok())
        .ok_or_else(|| format!("{}: bad line {line:?}", args.keys_file.display()))?;
    let (engine, plan) = args.pipeline.load(registry)?;
    eprintln!(
        "augsplat compute-node: key {key} of {} with {threads} thread(s)",
        plan.file.display()
    );
    let r = augsplat_graph::exec::compute_by_key(
        &plan,
        engine.store(),
        key,
        threads,
        args.checkpoint_every,
    )
    .map_err(|e| e.to_string())?;
    match r.status {
        Status::Ran => {
            eprintln!("computed in {:.1} s", r.seconds);
            Ok(())
        }
        Status::Cached => {
            eprintln!("already in the store");
            Ok(())
        }
        Status::Failed(m) => Err(m),
        Status::Skipped => Err("skipped".into()),
    }
}
