//! `augsplat verify`: prove what the store holds.

use super::run::open_existing_engine;
use super::CmdResult;
use augsplat_graph::Registry;
use std::path::PathBuf;

/// Arguments of `augsplat verify`.
#[derive(clap::Args)]
pub struct Args {
    /// Remove the damaged entries, manifests, output folders and blobs (never a blob whose
    /// content matches its name), so that the next run recomputes them.
    #[arg(long)]
    pub repair: bool,
    /// The store (default: $AUGSPLAT_CACHE, else ./cache).
    #[arg(long, value_name = "DIR")]
    pub cache: Option<PathBuf>,
}

/// Runs `augsplat verify`: exit status 0 when the store is sound (or was repaired), 1 when
/// damage was found and left in place.
pub fn run(args: Args, registry: &Registry) -> CmdResult {
    let engine = open_existing_engine(registry, args.cache)?;
    let r = engine.verify(args.repair).map_err(|e| e.to_string())?;
    println!(
        "checked {} blobs ({:.1} MiB), {} manifests, {} action entries in {:.2} s",
        r.blobs,
        r.bytes as f64 / (1024.0 * 1024.0),
        r.manifests,
        r.actions,
        r.seconds
    );
    for p in &r.damage {
        println!("damaged: {p}");
    }
    for p in &r.broken_actions {
        println!("broken entry: {p}");
    }
    for p in &r.removed {
        println!("removed: {p}");
    }
    if r.clean() {
        println!("the store is sound");
        Ok(())
    } else if args.repair {
        println!(
            "repaired: {} damaged, {} broken entries removed; the next run recomputes them",
            r.damage.len(),
            r.broken_actions.len()
        );
        Ok(())
    } else {
        Err(format!(
            "{} damaged item(s), {} broken entr{}; run `augsplat verify --repair` to remove them (the next run recomputes them)",
            r.damage.len(),
            r.broken_actions.len(),
            if r.broken_actions.len() == 1 { "y" } else { "ies" }
        ))
    }
}
