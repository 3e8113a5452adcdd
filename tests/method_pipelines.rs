//! End-to-end tests of the AugSplat method pipelines through the `augsplat` CLI:
//! which nodes an edit reruns (from `--summary-json`), that a sweep shares the ensemble, and
//! that the demo pipeline writes the metrics of all three methods. Every run uses its own
//! temporary cache and tiny sizes set with `--set`.

use augsplat_graph::store::unhex;
use augsplat_graph::Store;
use serde_json::Value;
use std::collections::BTreeSet;
use std::path::{Path, PathBuf};
use std::process::Command;

/// The tiny sizes of the test suite (the same as `tests/tiny.ron`).
const TINY: &[&str] = augsplat_testkit::tiny::SETS;

fn pipeline(name: &str) -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("pipelines")
        .join(name)
}

/// One node instance of a run summary.
#[derive(Clone, Debug)]
struct Entry {
    name: String,
    kind: String,
    key: String,
    status: String,
}

/// Runs `augsplat run FILE --cache CACHE --summary-json … --set …` and returns the summary.
fn run(file: &str, cache: &Path, sets: &[&str]) -> Vec<Entry> {
    let summary = cache.with_extension(format!(
        "summary-{}.json",
        std::time::SystemTime::now()
            .duration_since(std::time::UNIX_EPOCH)
            .unwrap()
            .as_nanos()
    ));
    let mut cmd = Command::new(env!("CARGO_BIN_EXE_augsplat"));
    cmd.arg("run")
        .arg(pipeline(file))
        .arg("--cache")
        .arg(cache)
        .arg("--summary-json")
        .arg(&summary);
    for s in TINY.iter().chain(sets) {
        cmd.arg("--set").arg(s);
    }
    let out = cmd.output().expect("runs the augsplat binary");
    assert!(
        out.status.success(),
        "augsplat run {file} {sets:?} failed:\n{}\n{}",
        String::from_utf8_lossy(&out.stdout),
        String::from_utf8_lossy(&out.stderr)
    );
    let text = std::fs::read_to_string(&summary).expect("the summary JSON was written");
    let v: Value = serde_json::from_str(&text).expect("the summary is JSON");
    v["nodes"]
        .as_array()
        .expect("summary has a nodes list")
        .iter()
        .map(|n| Entry {
            name: n["name"].as_str().unwrap_or_default().to_string(),
            kind: n["kind"].as_str().unwrap_or_default().to_string(),
            key: n["key"].as_str().unwrap_or_default().to_string(),
            status: n["status"].as_str().unwrap_or_default().to_string(),
        })
        .collect()
}

/// The instance names that ran.
fn ran(entries: &[Entry]) -> BTreeSet<String> {
    entries
        .iter()
        .filter(|e| e.status == "ran")
        .map(|e| e.name.clone())
        .collect()
}

fn set(names: &[&str]) -> BTreeSet<String> {
    names.iter().map(|s| s.to_string()).collect()
}

/// The folder of output `output` of the instance `name`, through the store's action entry.
fn output_dir(cache: &Path, entries: &[Entry], name: &str, output: &str) -> PathBuf {
    let e = entries
        .iter()
        .find(|e| e.name == name)
        .unwrap_or_else(|| panic!("no instance {name} in the summary"));
    let store = Store::open(cache).unwrap();
    let key = unhex(&e.key).expect("a hex key");
    let action = store
        .action(&key)
        .unwrap()
        .unwrap_or_else(|| panic!("no action entry for {name}"));
    let manifest = unhex(&action.outputs[output]).expect("a hex manifest");
    store.output_dir(&manifest)
}

#[test]
fn demo_runs_end_to_end_and_edits_rerun_exactly_what_they_touch() {
    let tmp = tempfile::tempdir().unwrap();
    let cache = tmp.path().join("cache");
    let m5 = "params.members=5";

    // 1. The demo end to end: everything runs, and the metrics of all three methods exist.
    let first = run("demo.ron", &cache, &[m5]);
    assert!(first.iter().all(|e| e.status == "ran"), "{first:?}");
    let fields = first.iter().filter(|e| e.kind == "TrainField").count();
    assert_eq!(fields, 5);
    for (node, label) in [
        ("eval_baseline", "3DGS"),
        ("eval_staged", "Staged"),
        ("eval_dual", "Dual"),
    ] {
        let dir = output_dir(&cache, &first, node, "eval");
        let text = std::fs::read_to_string(dir.join("metrics.json"))
            .unwrap_or_else(|e| panic!("{node}: metrics.json: {e}"));
        let m: Value = serde_json::from_str(&text).unwrap();
        assert_eq!(m["label"].as_str(), Some(label), "{node}: {text}");
        let psnr = m["mean"]["psnr"].as_f64();
        let ssim = m["mean"]["ssim"].as_f64();
        assert!(
            psnr.is_some_and(|p| p.is_finite() && p > 0.0),
            "{node}: {text}"
        );
        assert!(
            ssim.is_some_and(|s| s.is_finite() && s <= 1.0),
            "{node}: {text}"
        );
        if node != "eval_baseline" {
            // Every method is also reported at the baseline's best step.
            assert!(m["at_baseline"].is_object(), "{node}: {text}");
        }
    }
    // The ensemble's own held-out quality: every member and the median, on the test views.
    let dir = output_dir(&cache, &first, "eval_ensemble", "eval");
    let text = std::fs::read_to_string(dir.join("metrics.json")).unwrap();
    let m: Value = serde_json::from_str(&text).unwrap();
    assert_eq!(m["members"].as_u64(), Some(5), "{text}");
    assert_eq!(m["member"].as_array().map(Vec::len), Some(5), "{text}");
    assert!(
        m["median"]["mean"]["psnr"]
            .as_f64()
            .is_some_and(|p| p.is_finite() && p > 0.0),
        "{text}"
    );
    let report = output_dir(&cache, &first, "report", "report");
    let summary = std::fs::read_to_string(report.join("summary.md")).unwrap();
    for label in ["3DGS", "Staged", "Dual"] {
        assert!(summary.contains(label), "{summary}");
    }

    // 2. Same pipeline again: nothing runs.
    let again = run("demo.ron", &cache, &[m5]);
    assert!(ran(&again).is_empty(), "{:?}", ran(&again));

    // 3. γ: aggregation → the two methods that use it → their evaluations → the report.
    let gamma = run("demo.ron", &cache, &[m5, "params.gamma=0.5"]);
    assert_eq!(
        ran(&gamma),
        set(&[
            "aggregate",
            "staged",
            "dual",
            "eval_staged",
            "eval_dual",
            "report"
        ])
    );

    // 4. D: only the Dual optimisation, its evaluation and the report.
    let decay = run(
        "demo.ron",
        &cache,
        &[m5, "params.gamma=0.5", "params.quarter_decay=250.0"],
    );
    assert_eq!(ran(&decay), set(&["dual", "eval_dual", "report"]));

    // 5. M 5 → 6: exactly one new field (and its renders), then everything the ensemble feeds.
    let six = run(
        "demo.ron",
        &cache,
        &[
            "params.members=6",
            "params.gamma=0.5",
            "params.quarter_decay=250.0",
        ],
    );
    let trained: Vec<&Entry> = six
        .iter()
        .filter(|e| e.kind == "TrainField" && e.status == "ran")
        .collect();
    assert_eq!(trained.len(), 1, "{trained:?}");
    assert_eq!(trained[0].name, "field[5]");
    assert_eq!(
        ran(&six),
        set(&[
            "field[5]",
            "render[5]",
            "render_test[5]",
            "eval_ensemble",
            "aggregate",
            "staged",
            "dual",
            "eval_staged",
            "eval_dual",
            "report"
        ])
    );
}

#[test]
fn gamma_sweep_trains_the_ensemble_once() {
    let tmp = tempfile::tempdir().unwrap();
    let cache = tmp.path().join("cache");
    let entries = run("sweep_gamma.ron", &cache, &["params.members=2"]);
    // Five points, each with its own aggregation, but one ensemble.
    let keys_of = |kind: &str| -> BTreeSet<String> {
        entries
            .iter()
            .filter(|e| e.kind == kind && e.status == "ran")
            .map(|e| e.key.clone())
            .collect()
    };
    assert_eq!(keys_of("TrainField").len(), 2, "{entries:?}");
    // Each member renders the synthetic poses and the test views once for all points.
    assert_eq!(keys_of("RenderField").len(), 4);
    assert_eq!(keys_of("EvaluateEnsemble").len(), 1);
    assert_eq!(keys_of("AggregateEnsemble").len(), 5);
    // The baseline does not depend on γ either.
    assert_eq!(
        entries
            .iter()
            .filter(|e| e.kind == "OptimizeSplats" && e.name.starts_with("baseline"))
            .map(|e| e.key.clone())
            .collect::<BTreeSet<_>>()
            .len(),
        1
    );
    // Every point's aggregation instance is listed (one per point).
    assert_eq!(
        entries
            .iter()
            .filter(|e| e.kind == "AggregateEnsemble")
            .count(),
        5
    );
    // Running the sweep again computes nothing.
    let again = run("sweep_gamma.ron", &cache, &["params.members=2"]);
    assert!(ran(&again).is_empty());
}

/// `augsplat plan FILE --cache CACHE` (no --set): its stdout.
fn plan(file: &str, cache: &Path) -> String {
    let out = Command::new(env!("CARGO_BIN_EXE_augsplat"))
        .arg("plan")
        .arg(pipeline(file))
        .arg("--cache")
        .arg(cache)
        .output()
        .expect("runs the augsplat binary");
    assert!(
        out.status.success(),
        "augsplat plan {file} failed:\n{}",
        String::from_utf8_lossy(&out.stderr)
    );
    String::from_utf8_lossy(&out.stdout).into_owned()
}

/// The real-data pipelines and their sweeps load and plan (keys from the real files in
/// ../shared/data), and each bonsai sweep point shares everything upstream of its parameter
/// with bonsai.ron: the scene, the 5 fields and their renders, the baseline.
#[test]
fn real_data_pipelines_plan_and_their_sweeps_share_the_ensemble() {
    let data = Path::new(env!("CARGO_MANIFEST_DIR")).join("../shared/data");
    if !data.join("bonsai/colmap30").is_dir() || !data.join("fern").is_dir() {
        eprintln!("skipping: no real data under {}", data.display());
        return;
    }
    let tmp = tempfile::tempdir().unwrap();
    let cache = tmp.path().join("cache");
    // An empty store (only `run` creates one; `plan` refuses a path that holds none).
    Store::open(&cache).unwrap();
    let unique = |text: &str| -> usize {
        let line = text
            .lines()
            .find(|l| l.contains("unique computations"))
            .unwrap_or_else(|| panic!("no totals line in:\n{text}"));
        let inner = line.split('(').nth(1).unwrap();
        inner.split_whitespace().next().unwrap().parse().unwrap()
    };
    let bonsai = unique(&plan("bonsai.ron", &cache));
    assert_eq!(unique(&plan("fern.ron", &cache)), bonsai);
    // Per point, only the point's own nodes are new: γ → aggregate, staged, dual, their two
    // evaluations, report; D → dual, eval_dual, report; warm-up → staged, eval_staged, report;
    // seed → the three optimisations, their evaluations, report. The point equal to the
    // default shares every node with bonsai.ron.
    for (file, points, per_point) in [
        ("bonsai_sweep_gamma.ron", 5, 6),
        ("bonsai_sweep_decay.ron", 3, 3),
        ("bonsai_sweep_warmup.ron", 3, 3),
        ("bonsai_sweep_seed.ron", 3, 7),
    ] {
        assert_eq!(
            unique(&plan(file, &cache)),
            bonsai + (points - 1) * per_point,
            "{file}"
        );
    }
}

/// `tests/tiny.ron` and the testkit's `--set` list describe the same pipeline: expanding the
/// file equals expanding the demo with the overrides, so the two cannot drift apart.
#[test]
fn tiny_pipeline_file_equals_the_demo_with_the_tiny_overrides() {
    let expand = |file: &Path, sets: &[&str]| {
        let mut cmd = Command::new(env!("CARGO_BIN_EXE_augsplat"));
        cmd.arg("expand").arg(file);
        for s in sets {
            cmd.arg("--set").arg(s);
        }
        let out = cmd.output().expect("runs the augsplat binary");
        assert!(
            out.status.success(),
            "expand {}: {}",
            file.display(),
            String::from_utf8_lossy(&out.stderr)
        );
        String::from_utf8(out.stdout).expect("UTF-8")
    };
    let from_file = expand(&augsplat_testkit::tiny::pipeline(), &[]);
    let from_sets = expand(&pipeline("demo.ron"), TINY);
    assert_eq!(from_file, from_sets);
    assert!(from_file.contains("width: 48"), "{from_file}");
}
