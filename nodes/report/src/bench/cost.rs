//! Cost attribution of `augsplat bench`: from a run of the bench's sweep, which evaluated
//! method of which configuration cost what, and what error it reached.
//!
//! Per sweep point and per evaluation (every `Evaluate` and `EvaluateEnsemble` instance), the
//! cost is the sum of the compute seconds the run's results give (this run's for a node that
//! ran, its cache record's for a cached one) for every node the evaluation needs, upstream
//! included: a node shared by several configurations counts in each. The error is the
//! held-out average error when every evaluation has one (LPIPS weights connected), else the
//! MSE. What the evaluated training skipped (an early stop, Dual's synthetic branch switching
//! off) is estimated from its cache record's measures ([`Savings::from_measures`]). A scene
//! gate's rehearsal evaluations measure the gate, not a method, and are left out; an
//! evaluation the gate skipped has no error and is listed with the cost of what ran for it.

use super::{BenchPoint, BenchTable, Machine, Savings};
use crate::error::ReportError;
use augsplat_graph::resolve::Source;
use augsplat_graph::{Plan, RunReport, Store};
use serde_json::Value;
use std::collections::BTreeSet;
use std::path::Path;

/// The node kinds whose evaluations are bench points.
pub const EVALUATION_KINDS: [&str; 2] = ["Evaluate", "EvaluateEnsemble"];

/// The held-out errors of one evaluation, from its `metrics.json`.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct HeldOut {
    /// The average error (`None` without LPIPS weights).
    pub avg_error: Option<f64>,
    /// The MSE (NaN when the file has none).
    pub mse: f64,
    /// The PSNR, dB (NaN when the file has none).
    pub psnr: f64,
}

/// One evaluation of one configuration, before the error measure is chosen.
#[derive(Clone, Debug, PartialEq)]
pub struct Measured {
    /// The sweep point's label (`steps=100,members=3`).
    pub config: String,
    /// The method's label (the evaluation's `label`, else its kind).
    pub method: String,
    /// Compute seconds of every node the evaluation needs, itself included.
    pub seconds: f64,
    /// Its held-out errors.
    pub held_out: HeldOut,
    /// The nodes counted in `seconds`.
    pub nodes: usize,
    /// What the evaluated training skipped.
    pub saved: Savings,
}

/// Every evaluation of a bench run: measured ones, and those a scene gate skipped as
/// (configuration, evaluation instance, compute seconds of what it needed).
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Attribution {
    /// Evaluations with an error, in sweep-point order, then instance order.
    pub measured: Vec<Measured>,
    /// Evaluations a gate skipped, in the same order.
    pub gated: Vec<(String, String, f64)>,
}

impl Attribution {
    /// Attributes the costs of a finished run of `plan` (`report`), reading the evaluations'
    /// `metrics.json` and the trainings' cache records from `store`. Fails when an
    /// evaluation did not run or its metrics cannot be read.
    pub fn of_run(plan: &Plan, report: &RunReport, store: &Store) -> Result<Self, ReportError> {
        let rehearsals = gate_inputs(plan);
        let mut out = Attribution::default();
        for point in &plan.points {
            for &i in &point.instances {
                let c = plan.instances[i].comp;
                let kind = plan.comps[c].node.kind();
                if !EVALUATION_KINDS.contains(&kind) || rehearsals.contains(&c) {
                    continue;
                }
                let r = report.results[c]
                    .as_ref()
                    .ok_or_else(|| message("internal: an evaluation did not run"))?;
                if r.gated.is_some() {
                    let seconds = cost_seconds(plan, report, c);
                    let name = plan.instances[i].name.clone();
                    out.gated.push((point.label.clone(), name, seconds));
                    continue;
                }
                let manifest = r
                    .outputs
                    .get("eval")
                    .ok_or_else(|| message(format!("{kind} has no `eval` output")))?;
                let metrics = read_json(&store.output_dir(manifest).join("metrics.json"))?;
                let (method, held_out) = held_out(kind, &metrics);
                out.measured.push(Measured {
                    config: point.label.clone(),
                    method,
                    seconds: cost_seconds(plan, report, c),
                    held_out,
                    nodes: plan.closure(c).len(),
                    saved: training_savings(plan, report, store, c),
                });
            }
        }
        Ok(out)
    }

    /// Whether every measured evaluation has an average error (so the bench's error is it,
    /// not the MSE).
    pub fn all_average_error(&self) -> bool {
        self.measured.iter().all(|m| m.held_out.avg_error.is_some())
    }

    /// The error measure's name: `average error` or `MSE` (see
    /// [`Attribution::all_average_error`]).
    pub fn error_name(&self) -> &'static str {
        if self.all_average_error() {
            "average error"
        } else {
            "MSE"
        }
    }

    /// The bench points: each measured evaluation with the error chosen for all of them.
    pub fn points(&self) -> Vec<BenchPoint> {
        let avg = self.all_average_error();
        self.measured
            .iter()
            .map(|m| BenchPoint {
                config: m.config.clone(),
                method: m.method.clone(),
                seconds: m.seconds,
                error: match m.held_out.avg_error {
                    Some(e) if avg => e,
                    _ => m.held_out.mse,
                },
                psnr: m.held_out.psnr,
                nodes: m.nodes,
                saved: m.saved.clone(),
            })
            .collect()
    }

    /// The bench of `pipeline` over `grid` on `machine`. Fails when nothing was measured
    /// (the pipeline has no evaluation outside a gate's rehearsal).
    pub fn table(
        &self,
        pipeline: &Path,
        grid: &[String],
        machine: Machine,
    ) -> Result<BenchTable, ReportError> {
        if self.measured.is_empty() {
            return Err(message(format!(
                "{} has no `Evaluate` or `EvaluateEnsemble` node: nothing to measure the error of",
                pipeline.display()
            )));
        }
        Ok(BenchTable {
            pipeline: pipeline.display().to_string(),
            grid: grid.to_vec(),
            error_name: self.error_name().into(),
            machine,
            points: self.points(),
            gated: self.gated.clone(),
        })
    }
}

/// The compute seconds of computation `c` and of everything it needs: the sum of
/// `computed_seconds` over its closure (0 for a computation without a result).
pub fn cost_seconds(plan: &Plan, report: &RunReport, c: usize) -> f64 {
    plan.closure(c)
        .iter()
        .map(|&k| {
            report.results[k]
                .as_ref()
                .map_or(0.0, |r| r.computed_seconds)
        })
        .sum()
}

/// The computations a `Gate` reads (its rehearsal evaluations, among others).
pub fn gate_inputs(plan: &Plan) -> BTreeSet<usize> {
    plan.comps
        .iter()
        .filter(|c| c.node.kind() == "Gate")
        .flat_map(|c| c.inputs.iter().flat_map(|s| s.sources.iter()))
        .filter_map(|(s, _)| match s {
            Source::Node { comp, .. } => Some(*comp),
            _ => None,
        })
        .collect()
}

/// The method label and held-out errors in an evaluation's `metrics.json`: the `mean` of an
/// `Evaluate`, the median's `mean` of an `EvaluateEnsemble`; the label falls back to the kind.
pub fn held_out(kind: &str, metrics: &Value) -> (String, HeldOut) {
    let mean = if kind == "Evaluate" {
        &metrics["mean"]
    } else {
        &metrics["median"]["mean"]
    };
    let label = metrics["label"].as_str().unwrap_or(kind).to_string();
    let held = HeldOut {
        avg_error: mean["avg_error"].as_f64(),
        mse: mean["mse"].as_f64().unwrap_or(f64::NAN),
        psnr: mean["psnr"].as_f64().unwrap_or(f64::NAN),
    };
    (label, held)
}

/// What the training evaluated by computation `c` (its `model` input) skipped, from that
/// training's cache record; empty when there is none.
fn training_savings(plan: &Plan, report: &RunReport, store: &Store, c: usize) -> Savings {
    plan.comps[c]
        .inputs
        .iter()
        .filter(|s| s.name == "model")
        .flat_map(|s| s.sources.iter())
        .find_map(|(s, _)| match s {
            Source::Node { comp, .. } => Some(*comp),
            _ => None,
        })
        .and_then(|m| report.results[m].as_ref()?.key)
        .and_then(|k| store.action(&k).ok().flatten())
        .map(|entry| Savings::from_measures(&entry.measures))
        .unwrap_or_default()
}

/// A JSON file, its errors naming it.
fn read_json(path: &Path) -> Result<Value, ReportError> {
    let bytes = std::fs::read(path).map_err(|e| message(format!("{}: {e}", path.display())))?;
    serde_json::from_slice(&bytes).map_err(|e| message(format!("{}: {e}", path.display())))
}

fn message(text: impl Into<String>) -> ReportError {
    ReportError::Message(text.into())
}

#[cfg(test)]
mod tests {
    use super::super::sweep::sweep_file;
    use super::*;
    use augsplat_graph::{Engine, InputDecl, Node, NodeError, Registry, RunContext, RunOptions};
    use serde::{Deserialize, Serialize};

    /// Writes `value.txt`, after `sleep_ms` (so that its seconds are not nothing).
    struct Source;
    #[derive(Clone, Default, Serialize, Deserialize)]
    #[serde(default, deny_unknown_fields)]
    struct SourceArgs {
        value: u32,
        sleep_ms: u64,
    }
    impl Node for Source {
        const KIND: &'static str = "Source";
        const VERSION: u32 = 1;
        type Args = SourceArgs;
        fn inputs(_: &SourceArgs) -> Vec<InputDecl> {
            Vec::new()
        }
        fn outputs(_: &SourceArgs) -> Vec<String> {
            vec!["out".into()]
        }
        fn run(args: &SourceArgs, ctx: &mut RunContext) -> Result<(), NodeError> {
            std::thread::sleep(std::time::Duration::from_millis(args.sleep_ms));
            std::fs::write(ctx.output("out")?.join("value.txt"), args.value.to_string())?;
            Ok(())
        }
    }

    /// A training that stops early when `stop_at < steps`, recording the measures a splat
    /// training records (0.01 s per step).
    struct Train;
    #[derive(Clone, Default, Serialize, Deserialize)]
    #[serde(default, deny_unknown_fields)]
    struct TrainArgs {
        steps: u32,
        stop_at: u32,
    }
    impl Node for Train {
        const KIND: &'static str = "Train";
        const VERSION: u32 = 1;
        type Args = TrainArgs;
        fn inputs(_: &TrainArgs) -> Vec<InputDecl> {
            vec![InputDecl::one("scene")]
        }
        fn outputs(_: &TrainArgs) -> Vec<String> {
            vec!["model".into()]
        }
        fn run(args: &TrainArgs, ctx: &mut RunContext) -> Result<(), NodeError> {
            let run = args.stop_at.min(args.steps) as f64;
            for (k, v) in [
                ("steps_requested", args.steps as f64),
                ("steps_run", run),
                ("synthetic_steps", 0.0),
                ("synthetic_step_seconds", 0.0),
                ("real_only_steps", run),
                ("real_only_step_seconds", 0.01 * run),
            ] {
                ctx.measure(k, v);
            }
            let scene = std::fs::read_to_string(ctx.input("scene")?.join("value.txt"))?;
            let text = format!("{scene}+{}", args.steps);
            std::fs::write(ctx.output("model")?.join("value.txt"), text)?;
            Ok(())
        }
    }

    /// An evaluation writing `metrics.json` as `Evaluate` does (`mean`), or as
    /// `EvaluateEnsemble` does (`median.mean`); the error falls as the steps rise.
    #[derive(Clone, Default, Serialize, Deserialize)]
    #[serde(default, deny_unknown_fields)]
    struct EvalArgs {
        label: String,
        lpips: bool,
    }
    fn write_metrics(
        args: &EvalArgs,
        ctx: &mut RunContext,
        ensemble: bool,
    ) -> Result<(), NodeError> {
        let model = std::fs::read_to_string(ctx.input("model")?.join("value.txt"))?;
        let steps: f64 = model.rsplit('+').next().unwrap().parse().unwrap();
        let mut mean = serde_json::json!({ "mse": 1.0 / steps, "psnr": 10.0 * steps.log10() });
        if args.lpips {
            mean["avg_error"] = (0.5 / steps).into();
        }
        let metrics = if ensemble {
            serde_json::json!({ "label": args.label, "median": { "mean": mean } })
        } else {
            serde_json::json!({ "label": args.label, "mean": mean })
        };
        std::fs::write(
            ctx.output("eval")?.join("metrics.json"),
            metrics.to_string(),
        )?;
        Ok(())
    }
    struct Evaluate;
    impl Node for Evaluate {
        const KIND: &'static str = "Evaluate";
        const VERSION: u32 = 1;
        type Args = EvalArgs;
        fn inputs(_: &EvalArgs) -> Vec<InputDecl> {
            vec![InputDecl::one("model")]
        }
        fn outputs(_: &EvalArgs) -> Vec<String> {
            vec!["eval".into()]
        }
        fn run(args: &EvalArgs, ctx: &mut RunContext) -> Result<(), NodeError> {
            write_metrics(args, ctx, false)
        }
    }
    struct Ensemble;
    impl Node for Ensemble {
        const KIND: &'static str = "EvaluateEnsemble";
        const VERSION: u32 = 1;
        type Args = EvalArgs;
        fn inputs(_: &EvalArgs) -> Vec<InputDecl> {
            vec![InputDecl::one("model")]
        }
        fn outputs(_: &EvalArgs) -> Vec<String> {
            vec!["eval".into()]
        }
        fn run(args: &EvalArgs, ctx: &mut RunContext) -> Result<(), NodeError> {
            write_metrics(args, ctx, true)
        }
    }

    /// A scene gate reading a rehearsal evaluation; it says no.
    struct Gate;
    impl Node for Gate {
        const KIND: &'static str = "Gate";
        const VERSION: u32 = 1;
        type Args = EvalArgs;
        fn inputs(_: &EvalArgs) -> Vec<InputDecl> {
            vec![InputDecl::one("rehearsal")]
        }
        fn outputs(_: &EvalArgs) -> Vec<String> {
            vec!["decision".into()]
        }
        fn run(_: &EvalArgs, ctx: &mut RunContext) -> Result<(), NodeError> {
            let text = r#"{"run": false, "reason": "not worth it"}"#;
            std::fs::write(ctx.output("decision")?.join("gate.json"), text)?;
            Ok(())
        }
    }

    const PIPELINE: &str = r#"(
    params: { "lpips": false },
    nodes: {
        "scene": (kind: "Source", args: (value: 7, sleep_ms: 30)),
        "train": (kind: "Train", args: (steps: 100, stop_at: 1000), inputs: { "scene": "scene" }),
        "eval": (kind: "Evaluate", args: (label: "3DGS", lpips: Param("lpips")), inputs: { "model": "train" }),
        "ensemble": (kind: "EvaluateEnsemble", args: (label: "Ensemble median", lpips: Param("lpips")), inputs: { "model": "train" }),
        "rehearsal_train": (kind: "Train", args: (steps: 5), inputs: { "scene": "scene" }),
        "rehearsal": (kind: "Evaluate", args: (label: "rehearsal", lpips: Param("lpips")), inputs: { "model": "rehearsal_train" }),
        "gate": (kind: "Gate", inputs: { "rehearsal": "rehearsal" }),
        "costly": (kind: "Train", args: (steps: 50), gate: "gate.decision", inputs: { "scene": "scene" }),
        "eval_costly": (kind: "Evaluate", args: (label: "Dual"), inputs: { "model": "costly" }),
    },
)"#;

    /// Runs the bench of [`PIPELINE`] over `grid` in `dir`: (plan, report, engine).
    fn bench(dir: &Path, grid: &[&str]) -> (Plan, RunReport, Engine) {
        let mut registry = Registry::new();
        registry
            .register::<Source>()
            .register::<Train>()
            .register::<Evaluate>()
            .register::<Ensemble>()
            .register::<Gate>();
        let engine = Engine::new(registry, dir.join("cache")).unwrap();
        let pipeline = dir.join("p.ron");
        std::fs::write(&pipeline, PIPELINE).unwrap();
        let grid: Vec<String> = grid.iter().map(|g| g.to_string()).collect();
        let sweep = dir.join("bench.ron");
        std::fs::write(&sweep, sweep_file(&pipeline, &grid).unwrap()).unwrap();
        let plan = engine.load(&sweep, &[]).unwrap_or_else(|e| panic!("{e}"));
        let opts = RunOptions {
            jobs: 2,
            ..Default::default()
        };
        let report = engine.run(&plan, &opts).unwrap();
        assert!(report.success(), "{:?}", report.failures(&plan));
        (plan, report, engine)
    }

    fn machine() -> Machine {
        Machine {
            cpu: "cpu".into(),
            cores: 2,
            isa: Vec::new(),
            date: "2026-11-28".into(),
        }
    }

    #[test]
    fn each_evaluation_costs_the_recorded_seconds_of_everything_it_needs() {
        let dir = tempfile::tempdir().unwrap();
        let grid = ["train.stop_at=[1000, 60]"];
        let (plan, report, engine) = bench(dir.path(), &grid);
        let a = Attribution::of_run(&plan, &report, engine.store()).unwrap();
        // Two configurations × (3DGS, the ensemble); the rehearsal is the gate's, not a method.
        let got: Vec<(&str, &str)> = a
            .measured
            .iter()
            .map(|m| (m.config.as_str(), m.method.as_str()))
            .collect();
        assert_eq!(
            got,
            [
                ("stop_at=1000", "3DGS"),
                ("stop_at=1000", "Ensemble median"),
                ("stop_at=60", "3DGS"),
                ("stop_at=60", "Ensemble median"),
            ]
        );
        // The cost is the sum over the closure of each node's recorded seconds: the scene
        // (slept 30 ms), shared by both configurations, counts in each.
        let store = engine.store();
        let recorded = |name: &str, point: usize| -> f64 {
            let i = plan.points[point]
                .instances
                .iter()
                .copied()
                .find(|&i| plan.instances[i].base == name)
                .unwrap();
            let key = report.results[plan.instances[i].comp]
                .as_ref()
                .unwrap()
                .key
                .unwrap();
            store.action(&key).unwrap().unwrap().seconds
        };
        for (k, m) in a.measured.iter().enumerate() {
            let point = k / 2;
            let eval = if k % 2 == 0 { "eval" } else { "ensemble" };
            let want = recorded("scene", point) + recorded("train", point) + recorded(eval, point);
            assert!((m.seconds - want).abs() < 1e-9, "{m:?}: {want}");
            assert!(m.seconds >= 0.03, "{m:?}");
            assert_eq!(m.nodes, 3);
        }
        // The early stop at step 60 of 100 saved 40 steps × 0.01 s, from the measures.
        assert_eq!(a.measured[0].saved, Savings::default());
        let saved = a.measured[2].saved.early_stop.unwrap();
        assert!((saved - 0.4).abs() < 1e-9, "{saved}");
        // The gate skipped `eval_costly` in each configuration: listed with the cost of what
        // ran for it (the scene and the gate's branch), with no error.
        assert_eq!(a.gated.len(), 2);
        assert_eq!(a.gated[0].0, "stop_at=1000");
        assert_eq!(a.gated[0].1, "eval_costly");
        assert!(a.gated[0].2 >= 0.03);

        // No LPIPS: the error is the MSE; the table names it and carries everything.
        assert_eq!(a.error_name(), "MSE");
        let t = a
            .table(Path::new("p.ron"), &["g".into()], machine())
            .unwrap();
        assert_eq!(t.error_name, "MSE");
        assert_eq!(t.points.len(), 4);
        assert_eq!(t.points[0].error, 0.01);
        assert_eq!(t.points[0].psnr, 20.0);
        assert_eq!(t.gated, a.gated);
    }

    #[test]
    fn the_average_error_is_the_error_only_when_every_evaluation_has_one() {
        let dir = tempfile::tempdir().unwrap();
        let (plan, report, engine) = bench(dir.path(), &["params.lpips=[true]"]);
        let a = Attribution::of_run(&plan, &report, engine.store()).unwrap();
        assert_eq!(a.error_name(), "average error");
        assert!(a.points().iter().all(|p| p.error == 0.005));
        // One evaluation without it: the MSE for all.
        let mut b = a.clone();
        b.measured[1].held_out.avg_error = None;
        assert_eq!(b.error_name(), "MSE");
        assert!(b.points().iter().all(|p| p.error == 0.01));
    }

    #[test]
    fn held_out_errors_per_kind_and_an_empty_bench() {
        let m = serde_json::json!({ "label": "Dual", "mean": { "mse": 0.5, "psnr": 3.0, "avg_error": 0.2 } });
        let (label, h) = held_out("Evaluate", &m);
        assert_eq!(label, "Dual");
        assert_eq!(h.avg_error, Some(0.2));
        assert_eq!((h.mse, h.psnr), (0.5, 3.0));
        // An ensemble's errors are its median's; a missing label is the kind.
        let m = serde_json::json!({ "median": { "mean": { "mse": 0.25 } } });
        let (label, h) = held_out("EvaluateEnsemble", &m);
        assert_eq!(label, "EvaluateEnsemble");
        assert_eq!(h.avg_error, None);
        assert_eq!(h.mse, 0.25);
        assert!(h.psnr.is_nan());
        let e = Attribution::default()
            .table(Path::new("/p/x.ron"), &[], machine())
            .unwrap_err();
        assert_eq!(
            e.to_string(),
            "/p/x.ron has no `Evaluate` or `EvaluateEnsemble` node: nothing to measure the error of"
        );
    }
}
