//! `augsplat bench` on a tiny grid of the demo: each configuration's cost is the sum of the
//! recorded compute seconds of every node its evaluation needs (shared upstream counted in
//! every configuration that needs it), the tables are written, a rerun computes nothing and
//! gives the same table, and a malformed grid is a readable error.

use augsplat_graph::store::hex;
use serde_json::Value;
use std::path::Path;
use std::process::Command;

const BIN: &str = env!("CARGO_BIN_EXE_augsplat");

fn bench(cache: &Path, out: &Path, grid: &[&str]) -> std::process::Output {
    bench_pipeline(&augsplat_testkit::tiny::pipeline(), cache, out, grid, &[])
}

/// `augsplat bench PIPELINE` with `--grid`s and `--set`s.
fn bench_pipeline(
    pipeline: &Path,
    cache: &Path,
    out: &Path,
    grid: &[&str],
    sets: &[&str],
) -> std::process::Output {
    let mut c = Command::new(BIN);
    c.arg("bench")
        .arg(pipeline)
        .arg("--cache")
        .arg(cache)
        .arg("--out")
        .arg(out)
        .arg("-q");
    for g in grid {
        c.arg("--grid").arg(g);
    }
    for s in sets {
        c.arg("--set").arg(s);
    }
    c.output().unwrap()
}

fn count_actions(cache: &Path) -> usize {
    std::fs::read_dir(cache.join("actions"))
        .unwrap()
        .flatten()
        .map(|d| std::fs::read_dir(d.path()).unwrap().count())
        .sum()
}

#[test]
fn bench_costs_are_the_recorded_seconds_of_what_each_configuration_needs() {
    let tmp = tempfile::tempdir().unwrap();
    let (cache, out) = (tmp.path().join("cache"), tmp.path().join("out"));
    let grid = ["params.gs_steps=[10, 20]", "field.steps=[5, 10]"];
    let o = bench(&cache, &out, &grid);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let json = std::fs::read(out.join("bench.json")).unwrap();
    let table: Value = serde_json::from_slice(&json).unwrap();
    let points = table["points"].as_array().unwrap();
    assert_eq!(
        points.len(),
        4 * 4,
        "4 configurations × (3 methods + ensemble)"
    );
    assert_eq!(
        table["error_name"], "MSE",
        "no LPIPS weights in the tiny demo"
    );
    for f in ["bench.md", "bench.html", "bench.ron"] {
        assert!(out.join(f).is_file(), "{f}");
    }
    let md = std::fs::read_to_string(out.join("bench.md")).unwrap();
    assert_eq!(
        md.matches("* knee |").count(),
        4,
        "one knee per method:\n{md}"
    );

    // Recompute each cost from the store's action entries, independently of the bench.
    let registry = augsplat::builtin_registry();
    let engine = augsplat_graph::Engine::new(registry, &cache).unwrap();
    let plan = engine.load(&out.join("bench.ron"), &[]).unwrap();
    let keys = augsplat_graph::exec::plan_keys(&plan, engine.store()).unwrap();
    let entry_seconds = |c: usize| {
        keys[c]
            .as_ref()
            .and_then(|(_, e)| e.as_ref())
            .map(|e| e.seconds)
            .expect("every node is cached after the bench")
    };
    let scene = plan
        .instances
        .iter()
        .find(|i| i.base == "scene")
        .unwrap()
        .comp;
    let mut checked = 0;
    for point in &plan.points {
        for &i in &point.instances {
            let c = plan.instances[i].comp;
            if !matches!(plan.comps[c].node.kind(), "Evaluate" | "EvaluateEnsemble") {
                continue;
            }
            let closure = plan.closure(c);
            assert!(
                closure.contains(&scene),
                "the shared scene counts in every cost"
            );
            let want: f64 = closure.iter().map(|&k| entry_seconds(k)).sum();
            let row = points
                .iter()
                .find(|p| {
                    p["config"] == point.label.as_str()
                        && p["nodes"].as_u64() == Some(closure.len() as u64)
                        && (p["seconds"].as_f64().unwrap() - want).abs() < 1e-9
                })
                .unwrap_or_else(|| {
                    panic!(
                        "no row of {} with cost {want} over {} nodes ({})",
                        point.label,
                        closure.len(),
                        hex(&plan.comps[c].sid)
                    )
                });
            assert!(row["error"].as_f64().unwrap() > 0.0);
            checked += 1;
        }
    }
    assert_eq!(checked, 16);

    // A rerun computes nothing and gives the same table.
    let before = count_actions(&cache);
    let o = bench(&cache, &tmp.path().join("again"), &grid);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    assert_eq!(count_actions(&cache), before);
    let again: Value =
        serde_json::from_slice(&std::fs::read(tmp.path().join("again/bench.json")).unwrap())
            .unwrap();
    assert_eq!(again["points"], table["points"]);

    // A malformed axis is a readable error.
    let o = bench(&cache, &out, &["field.steps=100"]);
    assert!(!o.status.success());
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(
        err.contains("PATH=[V, ..]") && err.contains("field.steps=100"),
        "{err}"
    );
}

#[test]
fn bench_lists_what_a_gate_skipped_and_measures_the_rest() {
    let tmp = tempfile::tempdir().unwrap();
    let (cache, out) = (tmp.path().join("cache"), tmp.path().join("out"));
    // The tiny demo with the gate, forced either way.
    let p = tmp.path().join("gated.ron");
    let root = Path::new(env!("CARGO_MANIFEST_DIR"));
    std::fs::write(
        &p,
        format!(
            "(extends: [{:?}, {:?}])",
            root.join("tests/tiny.ron").display().to_string(),
            root.join("pipelines/fragments/gate.ron")
                .display()
                .to_string()
        ),
    )
    .unwrap();
    let o = bench_pipeline(
        &p,
        &cache,
        &out,
        &["gate.force=[Some(true), Some(false)]"],
        augsplat_testkit::tiny::GATE_SETS,
    );
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let table: Value =
        serde_json::from_slice(&std::fs::read(out.join("bench.json")).unwrap()).unwrap();
    // Open: 3 methods + the ensemble; closed: the baseline only.
    assert_eq!(table["points"].as_array().unwrap().len(), 4 + 1);
    let gated: Vec<&str> = table["gated"]
        .as_array()
        .unwrap()
        .iter()
        .map(|g| g[1].as_str().unwrap())
        .collect();
    assert_eq!(gated.len(), 3, "{gated:?}");
    for g in table["gated"].as_array().unwrap() {
        assert!(g[0].as_str().unwrap().contains("false"), "{g}");
        assert!(
            g[2].as_f64().unwrap() > 0.0,
            "the gate's own cost counts: {g}"
        );
    }
    let md = std::fs::read_to_string(out.join("bench.md")).unwrap();
    assert!(md.contains("Skipped by the scene gate"), "{md}");
}

/// 40 steps, patience 1, and a baseline that cannot improve (no learning, no densification):
/// it stops at its second evaluation, step 20, whatever the other results.
const SAVING_SETS: &[&str] = &[
    "params.gs_steps=40",
    "params.patience=Some(1)",
    "baseline.learning_rates=(means: 0.0, scales: 0.0, quats: 0.0, opacities: 0.0, sh0: 0.0, shn: 0.0)",
    "baseline.densify.enabled=false",
];

#[test]
fn bench_estimates_what_the_branch_off_and_the_early_stop_saved() {
    let tmp = tempfile::tempdir().unwrap();
    let (cache, out) = (tmp.path().join("cache"), tmp.path().join("out"));
    let o = bench_pipeline(
        &augsplat_testkit::tiny::pipeline(),
        &cache,
        &out,
        &["params.quarter_decay=[3.0, 100.0]"],
        SAVING_SETS,
    );
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let table: Value =
        serde_json::from_slice(&std::fs::read(out.join("bench.json")).unwrap()).unwrap();
    let points = table["points"].as_array().unwrap();

    // Each training's measures, from the store, independently of the bench.
    let registry = augsplat::builtin_registry();
    let engine = augsplat_graph::Engine::new(registry, &cache).unwrap();
    let sets: Vec<String> = SAVING_SETS.iter().map(|s| s.to_string()).collect();
    let plan = engine.load(&out.join("bench.ron"), &sets).unwrap();
    let keys = augsplat_graph::exec::plan_keys(&plan, engine.store()).unwrap();
    let mut early_stops = 0;
    for point in &plan.points {
        for &i in &point.instances {
            let inst = &plan.instances[i];
            if plan.comps[inst.comp].node.kind() != "OptimizeSplats" {
                continue;
            }
            let entry = keys[inst.comp].as_ref().unwrap().1.as_ref().unwrap();
            let m = &entry.measures;
            let label = match inst.base.as_str() {
                "baseline" => "3DGS",
                "staged" => "Staged",
                "dual" => "Dual",
                _ => continue,
            };
            let row = points
                .iter()
                .find(|p| p["config"] == point.label.as_str() && p["method"] == label)
                .unwrap_or_else(|| panic!("no {label} row for {}", point.label));
            let saved = &row["saved"];
            let (req, run) = (m["steps_requested"], m["steps_run"]);
            assert_eq!(req, 40.0);
            assert_eq!(
                m["synthetic_steps"] + m["real_only_steps"],
                run,
                "{label}: every step run is timed"
            );
            let mean = |t: &str, n: &str| m[t] / m[n];
            if label == "3DGS" {
                assert_eq!(
                    run, 20.0,
                    "the frozen baseline stops at its second evaluation"
                );
            }
            if run < req {
                early_stops += 1;
                let rate = if m["last_step_synthetic"] == 1.0 {
                    mean("synthetic_step_seconds", "synthetic_steps")
                } else {
                    mean("real_only_step_seconds", "real_only_steps")
                };
                let want = (req - run) * rate;
                let got = saved["early_stop"].as_f64().expect("an early-stop saving");
                assert!(
                    (got - want).abs() <= 1e-9 * want.max(1.0),
                    "{got} vs {want}"
                );
            } else {
                assert!(saved.get("early_stop").is_none(), "{label}: {saved}");
            }
            let qd = if point.label.contains("3.0") {
                3.0
            } else {
                100.0
            };
            if label == "Dual" && qd == 3.0 {
                // Off at the first step whose raw weight is below `off_below` (0.1).
                let off = (0u64..)
                    .find(|&t| augsplat_splat::train::dual_raw_weight(2.0, qd, t) < 0.1)
                    .unwrap();
                assert_eq!(m["synthetic_off_step"], off as f64);
                let want = (run - off as f64)
                    * (mean("synthetic_step_seconds", "synthetic_steps")
                        - mean("real_only_step_seconds", "real_only_steps"));
                // The steps' wall times decide the sign (on a loaded machine a synthetic step
                // may time no slower than a real one): the saving is the formula, never negative.
                let got = saved["branch_off"].as_f64().expect("a branch-off saving");
                assert!(
                    got >= 0.0 && (got - want.max(0.0)).abs() <= 1e-9,
                    "{got} vs {want}"
                );
            } else {
                // Staged's switch is its method, and Dual with D = 100 stays on for 40 steps.
                assert!(!m.contains_key("synthetic_off_step"), "{label} {qd}: {m:?}");
                assert!(saved.get("branch_off").is_none(), "{label}: {saved}");
            }
        }
    }
    assert!(
        early_stops >= 2,
        "the frozen baseline stops early in both configurations"
    );
    let md = std::fs::read_to_string(out.join("bench.md")).unwrap();
    assert!(
        md.contains("branch off") && md.contains("saved (est.)"),
        "{md}"
    );
}
