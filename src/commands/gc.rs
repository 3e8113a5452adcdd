//! `augsplat gc`: remove what no root needs.

use super::run::open_existing_engine;
use super::CmdResult;
use augsplat_graph::Registry;
use std::path::PathBuf;

/// Arguments of `augsplat gc`.
#[derive(clap::Args)]
pub struct Args {
    /// Report what would be removed, remove nothing.
    #[arg(long)]
    pub dry_run: bool,
    /// Drop kept entries and manifests that cannot be read (instead of stopping with an
    /// error); their nodes are recomputed by the next run.
    #[arg(long)]
    pub repair: bool,
    /// The store (default: $AUGSPLAT_CACHE, else ./cache).
    #[arg(long, value_name = "DIR")]
    pub cache: Option<PathBuf>,
}

/// Runs `augsplat gc`.
pub fn run(args: Args, registry: &Registry) -> CmdResult {
    let engine = open_existing_engine(registry, args.cache)?;
    let r = engine
        .gc(args.dry_run, args.repair)
        .map_err(|e| e.to_string())?;
    let verb = if args.dry_run {
        "would remove"
    } else {
        "removed"
    };
    println!(
        "roots: {} keys from {} root file(s) (latest run of each pipeline, pins)",
        r.roots,
        r.root_files.len()
    );
    for f in &r.root_files {
        println!("  {f}");
    }
    for f in &r.repaired {
        println!("repair: dropped unreadable {f}");
    }
    println!(
        "kept: {} actions, {} outputs, {} blobs",
        r.actions_kept, r.outputs_kept, r.blobs_kept
    );
    if !r.broken.is_empty() {
        println!(
            "broken (kept, recomputed by the next run that needs them): {}",
            r.broken.len()
        );
        for b in &r.broken {
            println!("  {b}");
        }
    }
    println!(
        "{verb}: {} actions, {} outputs, {} blobs ({:.1} MiB), {} scratch/claim files, {} \
         checkpoints no pipeline will resume",
        r.actions_removed,
        r.outputs_removed,
        r.blobs_removed,
        r.bytes_removed as f64 / (1024.0 * 1024.0),
        r.scratch_removed,
        r.checkpoints_removed
    );
    Ok(())
}
