//! The `augsplat` command-line interface, as a library so a user's own crate can register extra
//! node kinds and reuse every subcommand:
//!
//! ```no_run
//! fn main() -> std::process::ExitCode {
//!     let mut registry = augsplat::builtin_registry();
//!     // registry.register::<MyNode>();
//!     augsplat::main_with(registry)
//! }
//! ```

pub mod commands;

use augsplat_graph::Registry;
use clap::{Parser, Subcommand};
use std::process::ExitCode;

/// Every built-in node kind (the engine's own `Command` kind included).
pub fn builtin_registry() -> Registry {
    let mut registry = Registry::with_engine_kinds();
    augsplat_nodes::register_builtin(&mut registry);
    registry
}

/// augsplat: radiance-field-informed Gaussian splatting for sparse views, as a content-hashed
/// dataflow pipeline.
#[derive(Parser)]
#[command(name = "augsplat", version, about, long_about = None)]
pub struct Cli {
    /// The subcommand.
    #[command(subcommand)]
    pub command: Command,
}

/// The subcommands.
#[derive(Subcommand)]
pub enum Command {
    /// Run a pipeline (every run is a resume: finished nodes are found in the cache).
    Run(commands::run::Args),
    /// Show, per node, whether it is cached or will run (per sweep point for sweeps).
    Plan(commands::plan::Args),
    /// Explain why a node will rerun: the arg or input that changed since its last run.
    Why(commands::why::Args),
    /// Print the fully resolved pipeline(s): extends merged, overrides applied, sweeps expanded.
    Expand(commands::expand::Args),
    /// Remove cache entries that no root (pinned result, latest run of a pipeline) needs.
    Gc(commands::gc::Args),
    /// Re-hash every blob and output folder of the store; name damaged entries (`--repair`
    /// removes them so the next run recomputes them).
    Verify(commands::verify::Args),
    /// Describe a scene on disk (COLMAP, transforms.json, LLFF or an augsplat scene folder).
    Inspect(commands::inspect::Args),
    /// Render a Gaussian splat PLY from a camera (and optionally its gradients for a loss).
    Render(commands::render::Args),
    /// Write the interactive 3-D viewer (WebGL2, one self-contained HTML page) for splat PLYs.
    View(commands::view::Args),
    /// Compare two images: PSNR, SSIM, LPIPS and the average error.
    Metrics(commands::metrics::Args),
    /// Manage model weights (LPIPS).
    Weights(commands::weights::Args),
    /// Compare the metrics of several runs (ablation points).
    Compare(commands::compare::Args),
    /// Run time against error over a grid of settings: Pareto front and knee per method.
    Bench(commands::bench::Args),
    /// Show the latest run's nodes: waiting, queued, running (where), done, failed (why).
    Status(commands::status::Args),
    /// Compute one node of a pipeline by key into the store (what a Slurm job runs).
    #[command(hide = true)]
    ComputeNode(commands::compute_node::Args),
}

/// Parses the command line and runs it with `registry`; errors are printed as readable
/// reports and give exit code 1 (2 for usage errors, from clap).
pub fn main_with(registry: Registry) -> ExitCode {
    let cli = Cli::parse();
    let result = match cli.command {
        Command::Run(a) => commands::run::run(a, &registry),
        Command::Plan(a) => commands::plan::run(a, &registry),
        Command::Why(a) => commands::why::run(a, &registry),
        Command::Expand(a) => commands::expand::run(a, &registry),
        Command::Gc(a) => commands::gc::run(a, &registry),
        Command::Verify(a) => commands::verify::run(a, &registry),
        Command::Inspect(a) => commands::inspect::run(a),
        Command::Render(a) => commands::render::run(a),
        Command::View(a) => commands::view::run(a),
        Command::Metrics(a) => commands::metrics::run(a),
        Command::Weights(a) => commands::weights::run(a),
        Command::Compare(a) => commands::compare::run(a),
        Command::Status(a) => commands::status::run(a, &registry),
        Command::Bench(a) => commands::bench::run(a, &registry),
        Command::ComputeNode(a) => commands::compute_node::run(a, &registry),
    };
    match result {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("error: {e}");
            ExitCode::FAILURE
        }
    }
}
