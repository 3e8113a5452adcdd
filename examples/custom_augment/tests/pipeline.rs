//! The custom augmentation example end to end at the test suite's tiny sizes: its binary runs
//! `pipelines/custom_augment_rust.ron`, the custom node's synthetic set feeds OptimizeSplats,
//! and the report has a row for the custom method; the upstream nodes are the demo's.

use std::path::Path;
use std::process::Command;

#[test]
fn the_custom_prior_trains_dual_augsplat_and_reaches_the_report() {
    let root = Path::new(env!("CARGO_MANIFEST_DIR")).join("../..");
    let cache = tempfile::tempdir().unwrap();
    let summary = cache.path().join("summary.json");
    let mut cmd = Command::new(env!("CARGO_BIN_EXE_augsplat-custom-augment"));
    cmd.arg("run")
        .arg(root.join("pipelines/custom_augment_rust.ron"))
        .arg("--cache")
        .arg(cache.path().join("store"))
        .arg("--summary-json")
        .arg(&summary)
        .arg("-q");
    for s in augsplat_testkit::tiny::SETS {
        cmd.arg("--set").arg(s);
    }
    let out = cmd.output().unwrap();
    assert!(
        out.status.success(),
        "{}{}",
        String::from_utf8_lossy(&out.stdout),
        String::from_utf8_lossy(&out.stderr)
    );
    let s: serde_json::Value = serde_json::from_slice(&std::fs::read(&summary).unwrap()).unwrap();
    let nodes = s["nodes"].as_array().unwrap();
    let status = |name: &str| {
        nodes
            .iter()
            .find(|n| n["name"] == name)
            .unwrap_or_else(|| panic!("no node {name}"))["status"]
            .as_str()
            .unwrap()
            .to_string()
    };
    for n in ["mean", "dual_mean", "eval_dual_mean", "report"] {
        assert_eq!(status(n), "ran", "{n}");
    }
    // The report lists the custom method by its label.
    let report = nodes.iter().find(|n| n["name"] == "report").unwrap();
    let key = report["key"].as_str().unwrap();
    let entry = cache
        .path()
        .join("store/actions")
        .join(&key[..2])
        .join(format!("{key}.json"));
    let entry: serde_json::Value = serde_json::from_slice(&std::fs::read(entry).unwrap()).unwrap();
    let dir = cache
        .path()
        .join("store/outputs")
        .join(entry["outputs"]["report"].as_str().unwrap());
    let md = std::fs::read_to_string(dir.join("summary.md")).unwrap();
    assert!(md.contains("Dual (mean prior)"), "{md}");
}
