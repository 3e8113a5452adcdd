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

use super::run::open_engine;
use super::CmdResult;
use augsplat_graph::{Registry, RunOptions};
use augsplat_report::bench::{BenchPoint, BenchTable, Machine, Savings};
use std::io::IsTerminal;
use std::path::{Path, PathBuf};

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

/// The text of the sweep file for `file` over `grid`.
fn sweep_file(file: &Path, grid: &[String]) -> Result<String, String> {
    let mut axes = Vec::new();
    for g in grid {
        let (path, values) = g
            .split_once('=')
            .ok_or_else(|| format!("--grid {g}: write PATH=[V, ..]"))?;
        let (path, values) = (path.trim(), values.trim());
        if path.is_empty() || !values.starts_with('[') || !values.ends_with(']') {
            return Err(format!(
                "--grid {g}: write PATH=[V, ..], e.g. 'field.steps=[100, 200]'"
            ));
        }
        axes.push(format!("{path:?}: {values}"));
    }
    Ok(format!(
        "// Written by `augsplat bench`: {} with the grid as its sweep.\n(\n    extends: {:?},\n    sweep: Grid({{ {} }}),\n)\n",
        file.display(),
        file.display().to_string(),
        axes.join(", ")
    ))
}

/// Runs `augsplat bench`.
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
    std::fs::write(&bench_file, sweep_file(&file, &args.grid)?)
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
    let failures = report.failures(&plan);
    if !failures.is_empty() {
        let mut msg = format!("{} node(s) failed:", failures.len());
        for (_, m) in failures {
            msg.push_str("\n  ");
            msg.push_str(&m.replace('\n', "\n  "));
        }
        return Err(msg);
    }
    let store = engine.store();
    let mut points = Vec::new();
    let mut all_avg = true;
    let mut raw = Vec::new();
    let mut gated = Vec::new();
    // A scene gate's rehearsal evaluations measure the gate, not a method: left out.
    let feeds_gate: std::collections::BTreeSet<usize> = plan
        .comps
        .iter()
        .filter(|c| c.node.kind() == "Gate")
        .flat_map(|c| c.inputs.iter().flat_map(|s| s.sources.iter()))
        .filter_map(|(s, _)| match s {
            augsplat_graph::resolve::Source::Node { comp, .. } => Some(*comp),
            _ => None,
        })
        .collect();
    for point in &plan.points {
        for &i in &point.instances {
            let c = plan.instances[i].comp;
            let kind = plan.comps[c].node.kind();
            if (kind != "Evaluate" && kind != "EvaluateEnsemble") || feeds_gate.contains(&c) {
                continue;
            }
            let r = report.results[c]
                .as_ref()
                .ok_or("internal: an evaluation did not run")?;
            let closure_seconds = |c: usize| -> f64 {
                plan.closure(c)
                    .iter()
                    .map(|&k| {
                        report.results[k]
                            .as_ref()
                            .map_or(0.0, |r| r.computed_seconds)
                    })
                    .sum()
            };
            if r.gated.is_some() {
                gated.push((
                    point.label.clone(),
                    plan.instances[i].name.clone(),
                    closure_seconds(c),
                ));
                continue;
            }
            let manifest = r
                .outputs
                .get("eval")
                .ok_or_else(|| format!("{kind} has no `eval` output"))?;
            let path = store.output_dir(manifest).join("metrics.json");
            let m: serde_json::Value = serde_json::from_slice(
                &std::fs::read(&path).map_err(|e| format!("{}: {e}", path.display()))?,
            )
            .map_err(|e| format!("{}: {e}", path.display()))?;
            let mean = if kind == "Evaluate" {
                &m["mean"]
            } else {
                &m["median"]["mean"]
            };
            let label = m["label"].as_str().unwrap_or(kind).to_string();
            let closure = plan.closure(c);
            let seconds = closure_seconds(c);
            let avg = mean["avg_error"].as_f64();
            all_avg &= avg.is_some();
            // What the evaluated training skipped, from its cache record's measures.
            let saved = plan.comps[c]
                .inputs
                .iter()
                .filter(|s| s.name == "model")
                .flat_map(|s| s.sources.iter())
                .find_map(|(s, _)| match s {
                    augsplat_graph::resolve::Source::Node { comp, .. } => Some(*comp),
                    _ => None,
                })
                .and_then(|m| report.results[m].as_ref()?.key)
                .and_then(|k| store.action(&k).ok().flatten())
                .map(|entry| Savings::from_measures(&entry.measures))
                .unwrap_or_default();
            raw.push((
                point.label.clone(),
                label,
                seconds,
                avg,
                mean["mse"].as_f64().unwrap_or(f64::NAN),
                mean["psnr"].as_f64().unwrap_or(f64::NAN),
                closure.len(),
                saved,
            ));
        }
    }
    for (config, method, seconds, avg, mse, psnr, nodes, saved) in raw {
        points.push(BenchPoint {
            config,
            method,
            seconds,
            error: if all_avg { avg.unwrap_or(mse) } else { mse },
            psnr,
            nodes,
            saved,
        });
    }
    if points.is_empty() {
        return Err(format!(
            "{} has no `Evaluate` or `EvaluateEnsemble` node: nothing to measure the error of",
            file.display()
        ));
    }
    let table = BenchTable {
        pipeline: file.display().to_string(),
        grid: args.grid.clone(),
        error_name: if all_avg {
            "average error".into()
        } else {
            "MSE".into()
        },
        machine: Machine::this(),
        points,
        gated,
    };
    let write = |name: &str, text: String| {
        let p = out.join(name);
        std::fs::write(&p, text).map_err(|e| format!("writing {}: {e}", p.display()))
    };
    let md = table.markdown();
    write("bench.md", md.clone())?;
    write("bench.html", table.html())?;
    write(
        "bench.json",
        serde_json::to_string_pretty(&table).map_err(|e| e.to_string())?,
    )?;
    if !args.quiet {
        print!("{md}");
        println!(
            "\nwritten: {} (bench.md, bench.json, bench.html)",
            out.display()
        );
    }
    Ok(())
}
