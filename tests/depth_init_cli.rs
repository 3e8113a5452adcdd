//! `pipelines/fragments/depth_init.ron`: on a scene without SfM points, Staged and Dual start
//! from the radiance field's depth at the training views while the baseline starts from
//! random points; with points, every method starts from the points.

use augsplat_graph::store::unhex;
use augsplat_graph::Store;
use serde_json::Value;
use std::path::Path;
use std::process::Command;

/// Runs the tiny demo with the fragment (`points` SfM points) and returns each training
/// node's log.
fn logs(dir: &Path, points: u32) -> Vec<(String, String)> {
    let root = Path::new(env!("CARGO_MANIFEST_DIR"));
    let p = dir.join("p.ron");
    std::fs::write(
        &p,
        format!(
            "(extends: [{:?}, {:?}], nodes: {{ \"scene\": (args: (points: {points})) }})",
            root.join("tests/tiny.ron").display().to_string(),
            root.join("pipelines/fragments/depth_init.ron")
                .display()
                .to_string()
        ),
    )
    .unwrap();
    let cache = dir.join("cache");
    let summary = dir.join("summary.json");
    let out = Command::new(env!("CARGO_BIN_EXE_augsplat"))
        .args(["run", p.to_str().unwrap(), "-q", "--cache"])
        .arg(&cache)
        .arg("--summary-json")
        .arg(&summary)
        .output()
        .unwrap();
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let s: Value = serde_json::from_str(&std::fs::read_to_string(&summary).unwrap()).unwrap();
    let store = Store::open(&cache).unwrap();
    s["nodes"]
        .as_array()
        .unwrap()
        .iter()
        .filter(|n| n["kind"] == "OptimizeSplats")
        .map(|n| {
            let e = store
                .action(&unhex(n["key"].as_str().unwrap()).unwrap())
                .unwrap()
                .unwrap();
            let log = std::fs::read_to_string(store.blob(&e.log.unwrap()).unwrap()).unwrap();
            (n["name"].as_str().unwrap().to_string(), log)
        })
        .collect()
}

#[test]
fn without_points_the_methods_start_from_the_priors_depth() {
    let tmp = tempfile::tempdir().unwrap();
    let logs = logs(tmp.path(), 0);
    assert_eq!(logs.len(), 3);
    for (name, log) in &logs {
        let from_prior = log.contains("back-projected from the radiance field's depth");
        assert_eq!(from_prior, name != "baseline", "{name}: {log}");
        if name == "baseline" {
            assert!(log.contains("random Gaussians on training rays"), "{log}");
        }
    }
}

#[test]
fn with_points_every_method_starts_from_them() {
    let tmp = tempfile::tempdir().unwrap();
    for (name, log) in logs(tmp.path(), 400) {
        assert!(!log.contains("no sparse points"), "{name}: {log}");
    }
}
