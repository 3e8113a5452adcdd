//! `augsplat bench FILE --grid 'PATH=[V, ..]'…`: run time against error over a grid of
//! settings. The grid becomes the pipeline's sweep (written to `OUT/bench.ron`, which extends
//! FILE), so the normal engine runs it: upstream shared by several configurations is computed
//! once and everything is cached, and a rerun computes nothing. Per configuration and per
//! evaluated method (every `Evaluate` and `EvaluateEnsemble` instance), the cost is the sum of
//! the compute seconds its cache records give for every node the evaluation needs, upstream
//! included, and the error is the held-out average error (the MSE without LPIPS weights).
//! The seconds a training skipped (an early stop, Dual's synthetic branch switching off) are
//! estimated from the step times its node measured (its cache record's `measures`).
//! Writes `bench.md`, `bench.json` and `bench.html` (Pareto front and knee per method).
//! The sweep file and the attribution are [`augsplat_report::bench::sweep`] and
//! [`augsplat_report::bench::cost`]; this command parses its arguments, runs the sweep and
//! prints.

use super::run::open_engine;
use super::CmdResult;
use augsplat_graph::{Plan, Registry, RunOptions, RunReport};
use augsplat_report::bench::cost::Attribution;
use augsplat_report::bench::sweep::sweep_file;
use augsplat_report::bench::Machine;
use std::io::IsTerminal;
use std::path::PathBuf;

/// Arguments of `augsplat bench`.
#[derive(clap::Args)]
pub struct Args {
    /// The pipeline file (.ron).
    pub file: PathBuf,
    /// One axis of the grid: `NODE.ARG=[V, ..]` or `params.NAME=[V, ..]` (RON values).
    /// Repeatable; the grid is every combination.
    #[arg(long = "grid", value_name = "PATH=[V,..]", required = true)]
    pub grid: Vec<String>,
    /// Override a value in every configuration (as `run --set`). Repeatable.
    #[arg(long = "set", value_name = "PATH=VALUE")]
    pub sets: Vec<String>,
    /// The store (default: $AUGSPLAT_CACHE, else ./cache).
    #[arg(long, value_name = "DIR")]
    pub cache: Option<PathBuf>,
    /// Cores to use in total (default: all).
    #[arg(long, short = 'j')]
    pub jobs: Option<usize>,
    /// Where the tables go (default: `bench/<pipeline name>`).
    #[arg(long, value_name = "DIR")]
    pub out: Option<PathBuf>,
    /// No progress bars and no table on stdout.
    #[arg(long, short = 'q')]
    pub quiet: bool,
}

/// Runs `augsplat bench`: writes the sweep, runs it, and hands the run to the cost
/// attribution of [`augsplat_report::bench::cost`].
pub fn run(args: Args, registry: &Registry) -> CmdResult {
    let file =
        std::fs::canonicalize(&args.file).map_err(|e| format!("{}: {e}", args.file.display()))?;
    let stem = file
        .file_stem()
        .map(|s| s.to_string_lossy().into_owned())
        .unwrap_or_else(|| "pipeline".into());
    let out = args
        .out
        .clone()
        .unwrap_or_else(|| PathBuf::from("bench").join(&stem));
    std::fs::create_dir_all(&out).map_err(|e| format!("creating {}: {e}", out.display()))?;
    let bench_file = out.join("bench.ron");
    let sweep = sweep_file(&file, &args.grid).map_err(|e| e.to_string())?;
    std::fs::write(&bench_file, sweep)
        .map_err(|e| format!("writing {}: {e}", bench_file.display()))?;
    let engine = open_engine(registry, args.cache.clone())?;
    let plan = engine
        .load(&bench_file, &args.sets)
        .map_err(|e| e.to_string())?;
    let mut opts = RunOptions {
        progress: !args.quiet && std::io::stderr().is_terminal(),
        ..Default::default()
    };
    if let Some(j) = args.jobs {
        opts.jobs = j.max(1);
    }
    let report = engine.run(&plan, &opts).map_err(|e| e.to_string())?;
    failures(&plan, &report)?;
    let md = Attribution::of_run(&plan, &report, engine.store())
        .and_then(|a| a.table(&file, &args.grid, Machine::this()))
        .and_then(|table| table.write_files(&out))
        .map_err(|e| e.to_string())?;
    if !args.quiet {
        print!("{md}");
        println!(
            "\nwritten: {} (bench.md, bench.json, bench.html)",
            out.display()
        );
    }
    Ok(())
}

/// The run's failures as one message (`Ok` when nothing failed).
fn failures(plan: &Plan, report: &RunReport) -> CmdResult {
    let failures = report.failures(plan);
    if failures.is_empty() {
        return Ok(());
    }
    let mut msg = format!("{} node(s) failed:", failures.len());
    for (_, m) in failures {
        msg.push_str("\n  ");
        msg.push_str(&m.replace('\n', "\n  "));
    }
    Err(msg)
}
