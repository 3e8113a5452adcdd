//! `augsplat status`: per node of the latest run on a store — waiting, queued, running
//! (where: this machine's pid, or the Slurm job and its node), ran, cached, failed (with the
//! tail of its log) — read from the status file the run keeps up to date.

use super::CmdResult;
use augsplat_graph::exec::status::{latest_status, RunStatus};
use augsplat_graph::Registry;
use std::path::PathBuf;

/// Arguments of `augsplat status`.
#[derive(clap::Args)]
pub struct Args {
    /// The store (default: $AUGSPLAT_CACHE, else ./cache).
    #[arg(long, value_name = "DIR")]
    pub cache: Option<PathBuf>,
    /// Print the status file (JSON) instead of the table.
    #[arg(long)]
    pub json: bool,
    /// List the last runs the store keeps (newest first), one line each.
    #[arg(long)]
    pub all: bool,
}

/// Runs `augsplat status`.
pub fn run(args: Args, registry: &Registry) -> CmdResult {
    let engine = super::run::open_existing_engine(registry, args.cache)?;
    if args.all {
        let runs = augsplat_graph::exec::status::recent_statuses(engine.store());
        if args.json {
            println!(
                "{}",
                serde_json::to_string_pretty(&runs).map_err(|e| e.to_string())?
            );
        } else if runs.is_empty() {
            return Err(format!(
                "no run has been recorded in {} yet",
                engine.store().root().display()
            ));
        } else {
            for st in &runs {
                println!("{}", format_run_line(st, driver_alive(st)));
            }
        }
        return Ok(());
    }
    let Some(st) = latest_status(engine.store()).map_err(|e| e.to_string())? else {
        return Err(format!(
            "no run has been recorded in {} yet",
            engine.store().root().display()
        ));
    };
    if args.json {
        println!(
            "{}",
            serde_json::to_string_pretty(&st).map_err(|e| e.to_string())?
        );
    } else {
        print!("{}", format_status(&st, driver_alive(&st)));
    }
    Ok(())
}

/// Whether the run's driver still runs (`None`: it ran on another host, so this cannot tell).
fn driver_alive(st: &RunStatus) -> Option<bool> {
    if st.host != augsplat_graph::store::hostname() {
        return None;
    }
    Some(std::path::Path::new(&format!("/proc/{}", st.pid)).exists())
}

/// One run in a line: its id, when it started, its pipeline, its outcome and its node counts.
pub fn format_run_line(st: &RunStatus, alive: Option<bool>) -> String {
    let now = augsplat_graph::store::now_unix();
    let outcome = if st.finished {
        if st.nodes.iter().any(|n| n.state == "failed") {
            "finished with failures"
        } else {
            "finished"
        }
    } else {
        match alive {
            Some(false) => "interrupted",
            Some(true) => "in progress",
            None => "in progress (driver on another host)",
        }
    };
    let mut counts = std::collections::BTreeMap::new();
    for n in &st.nodes {
        *counts.entry(n.state.as_str()).or_insert(0usize) += 1;
    }
    let counts: Vec<String> = counts.iter().map(|(k, v)| format!("{v} {k}")).collect();
    format!(
        "{}  {} s ago  {}  {} ({} executor): {}",
        st.run_id,
        now.saturating_sub(st.started_unix),
        st.pipeline,
        outcome,
        st.executor,
        counts.join(", ")
    )
}

/// The status as a table.
pub fn format_status(st: &RunStatus, alive: Option<bool>) -> String {
    let now = augsplat_graph::store::now_unix();
    let mut out = format!(
        "run {} of {} ({} executor, driver pid {} on {})\n",
        st.run_id, st.pipeline, st.executor, st.pid, st.host
    );
    let state = if st.finished {
        "finished".to_string()
    } else {
        match alive {
            Some(false) => "interrupted: its driver is gone (rerun to resume)".into(),
            Some(true) => "in progress".into(),
            None => "in progress (driver on another host)".into(),
        }
    };
    out.push_str(&format!(
        "started {} s ago, updated {} s ago: {state}\n",
        now.saturating_sub(st.started_unix),
        now.saturating_sub(st.updated_unix)
    ));
    let mut counts = std::collections::BTreeMap::new();
    for n in &st.nodes {
        *counts.entry(n.state.as_str()).or_insert(0usize) += 1;
    }
    let summary: Vec<String> = counts.iter().map(|(k, v)| format!("{v} {k}")).collect();
    out.push_str(&format!("{}\n\n", summary.join(", ")));
    let w = st
        .nodes
        .iter()
        .map(|n| n.name.len())
        .max()
        .unwrap_or(4)
        .max(4);
    let kw = st
        .nodes
        .iter()
        .map(|n| n.kind.len())
        .max()
        .unwrap_or(4)
        .max(4);
    out.push_str(&format!(
        "{:w$}  {:kw$}  {:8}  where / seconds\n",
        "node", "kind", "state"
    ));
    for n in &st.nodes {
        let detail = match (&n.place, n.seconds) {
            (Some(p), _) => p.clone(),
            (None, Some(s)) => format!("{s:.1} s"),
            _ => String::new(),
        };
        out.push_str(&format!(
            "{:w$}  {:kw$}  {:8}  {detail}\n",
            n.name, n.kind, n.state
        ));
        if let Some(m) = &n.message {
            for l in m.lines().take(25) {
                out.push_str(&format!("    {l}\n"));
            }
        }
    }
    out
}
