//! `augsplat compare RUN_A RUN_B ...`: metric deltas across runs (ablation points).
//!
//! Each RUN is an `Evaluate` output folder (holding `metrics.json`) or a folder whose immediate
//! subfolders are (taken in name order). The first run is the reference unless `--reference`
//! names another (by label or position).

use super::CmdResult;
use augsplat_report::compare::{compare, Source};
use augsplat_report::evalset::{find_eval_dirs, EvalDir};
use std::path::PathBuf;

/// Arguments of `augsplat compare`.
#[derive(clap::Args)]
pub struct Args {
    /// Evaluation folders (`Evaluate` outputs), or folders holding several of them.
    #[arg(required = true)]
    pub runs: Vec<PathBuf>,
    /// The run the deltas are taken against: its label or its 1-based position (default: the
    /// first run).
    #[arg(long)]
    pub reference: Option<String>,
    /// Which numbers to compare: `eval` (the evaluated checkpoint at full resolution), `best`
    /// (each training curve's best step) or `baseline` (the curves at the baseline's best step).
    #[arg(long, default_value = "eval")]
    pub at: String,
    /// Print JSON instead of a table.
    #[arg(long)]
    pub json: bool,
}

/// Runs `augsplat compare`.
pub fn run(args: Args) -> CmdResult {
    let source = Source::parse(&args.at).map_err(|e| e.to_string())?;
    let mut runs = Vec::new();
    for path in &args.runs {
        for dir in find_eval_dirs(path).map_err(|e| e.to_string())? {
            runs.push(EvalDir::load(&dir).map_err(|e| e.to_string())?);
        }
    }
    let labels = augsplat_report::compare::display_labels(&runs);
    let reference = match &args.reference {
        None => 0,
        Some(r) => {
            if let Some(i) = labels.iter().position(|l| l == r) {
                i
            } else if let Some(i) = runs.iter().position(|e| &e.metrics.label == r) {
                i
            } else {
                match r.parse::<usize>() {
                    Ok(k) if (1..=runs.len()).contains(&k) => k - 1,
                    _ => {
                        return Err(format!(
                            "--reference {r:?} matches no run (labels: {}; or a position 1..={})",
                            labels.join(", "),
                            runs.len()
                        ))
                    }
                }
            }
        }
    };
    let cmp = compare(&runs, reference, source).map_err(|e| e.to_string())?;
    if args.json {
        let text = serde_json::to_string_pretty(&cmp.to_json()).map_err(|e| e.to_string())?;
        println!("{text}");
    } else {
        print!("{}", cmp.to_text());
    }
    Ok(())
}
