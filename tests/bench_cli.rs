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
    let mut c = Command::new(BIN);
    c.arg("bench")
        .arg(augsplat_testkit::tiny::pipeline())
        .arg("--cache")
        .arg(cache)
        .arg("--out")
        .arg(out)
        .arg("-q");
    for g in grid {
        c.arg("--grid").arg(g);
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
    let o = Command::new(BIN)
        .arg("bench")
        .arg(&p)
        .arg("--cache")
        .arg(&cache)
        .arg("--out")
        .arg(&out)
        .arg("-q")
        .args(["--grid", "gate.force=[Some(true), Some(false)]"])
        .args(
            augsplat_testkit::tiny::GATE_SETS
                .iter()
                .flat_map(|s| ["--set", s]),
        )
        .output()
        .unwrap();
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
