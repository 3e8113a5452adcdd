//! `pipelines/fragments/depth_init.ron`: on a scene without SfM points, Staged and Dual start
//! from the radiance field's depth at the training views while the baseline starts from
//! random points; with points, every method starts from the points.

mod common;

use common::{augsplat, log_of, run_with_summary};
use std::path::Path;

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
    let mut cmd = augsplat();
    cmd.args(["run", p.to_str().unwrap(), "-q", "--cache"])
        .arg(&cache);
    run_with_summary(cmd, &dir.join("summary.json"))
        .iter()
        .filter(|n| n["kind"] == "OptimizeSplats")
        .map(|n| {
            let name = n["name"].as_str().unwrap().to_string();
            (name, log_of(&cache, n["key"].as_str().unwrap()))
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
