//! Benchmark: planning + key computation for a 1,000-node pipeline whose results are all
//! cached (target: under 200 ms).
//!
//! ```text
//! cargo run --release -p augsplat-graph --example bench_plan [-- NODES]
//! ```

use augsplat_graph::{
    exec::plan_keys, Engine, InputDecl, Node, NodeError, Registry, RunContext, RunOptions,
};
use serde::{Deserialize, Serialize};
use std::fmt::Write as _;
use std::time::Instant;

#[derive(Clone, Default, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
struct StepArgs {
    index: u64,
    scale: f64,
    label: String,
}

/// Writes a tiny file derived from its args and its (optional) input.
struct Step;
impl Node for Step {
    const KIND: &'static str = "Step";
    const VERSION: u32 = 1;
    type Args = StepArgs;
    fn inputs(_: &StepArgs) -> Vec<InputDecl> {
        vec![InputDecl::optional("a")]
    }
    fn outputs(_: &StepArgs) -> Vec<String> {
        vec!["out".into()]
    }
    fn run(args: &StepArgs, ctx: &mut RunContext) -> Result<(), NodeError> {
        let prev = match ctx.optional_input("a") {
            Some(p) => std::fs::read_to_string(p.join("v"))?,
            None => String::new(),
        };
        std::fs::write(
            ctx.output("out")?.join("v"),
            format!("{}{}:{}", prev.len(), args.index, args.scale),
        )?;
        Ok(())
    }
}

fn main() {
    let n: usize = std::env::args()
        .nth(1)
        .and_then(|s| s.parse().ok())
        .unwrap_or(1000);
    let dir = tempfile::tempdir().expect("tempdir");
    let mut text = String::from("(\n  nodes: {\n");
    for i in 0..n {
        // A binary tree: node i reads node (i - 1) / 2.
        let input = if i == 0 {
            String::new()
        } else {
            format!(", inputs: {{ \"a\": \"n{}\" }}", (i - 1) / 2)
        };
        let _ = writeln!(
            text,
            "    \"n{i}\": (kind: \"Step\", args: (index: {i}, scale: 0.5, label: \"node {i}\"){input}),"
        );
    }
    text.push_str("  },\n)\n");
    let file = dir.path().join("big.ron");
    std::fs::write(&file, &text).expect("write");
    let mut registry = Registry::with_engine_kinds();
    registry.register::<Step>();
    let engine = Engine::new(registry, dir.path().join("cache")).expect("store");
    let t = Instant::now();
    let plan = engine.load(&file, &[]).expect("load");
    let report = engine.run(&plan, &RunOptions::default()).expect("run");
    assert!(report.success());
    println!(
        "first run of {n} nodes (all ran): {:.3} s",
        t.elapsed().as_secs_f64()
    );
    let mut times = Vec::new();
    for _ in 0..10 {
        let t = Instant::now();
        let plan = engine.load(&file, &[]).expect("load");
        let keys = plan_keys(&plan, engine.store()).expect("keys");
        assert!(
            keys.iter().all(|k| matches!(k, Some((_, Some(_))))),
            "everything must be cached"
        );
        times.push(t.elapsed().as_secs_f64() * 1e3);
    }
    times.sort_by(f64::total_cmp);
    println!(
        "plan + keys, {n} cached nodes ({} bytes of RON): min {:.1} ms, median {:.1} ms, max {:.1} ms",
        text.len(),
        times[0],
        times[5],
        times[9]
    );
    let t = Instant::now();
    let plan = engine.load(&file, &[]).expect("load");
    let report = engine.run(&plan, &RunOptions::default()).expect("run");
    assert!(report
        .results
        .iter()
        .flatten()
        .all(|r| r.status == augsplat_graph::Status::Cached));
    println!(
        "full cached `run` (plan, keys, records): {:.1} ms",
        t.elapsed().as_secs_f64() * 1e3
    );
}
