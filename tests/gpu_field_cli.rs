//! The radiance field on the GPU through the CLI: the tiny demo with `fragments/gpu.ron`
//! (every field, render, splatting and evaluation node on the GPU) runs end to end with a
//! complete report; two fresh stores hold the same field bytes; the adapter is recorded; a
//! device lost mid-training ends the field node with the device's message and no cache entry;
//! an adapter that is not there is an error, never a fall-back to the CPU.
//! Skips with a message when the machine has no GPU adapter (fails under `CI=true`).

mod common;

use serde_json::Value;
use std::path::{Path, PathBuf};

/// A pipeline file: the tiny demo with the GPU fragment.
fn pipeline(dir: &Path) -> PathBuf {
    let root = augsplat_testkit::workspace_root();
    let p = dir.join("tiny_gpu.ron");
    std::fs::write(
        &p,
        format!(
            "(extends: [{:?}, {:?}])",
            augsplat_testkit::tiny::pipeline(),
            root.join("pipelines/fragments/gpu.ron")
        ),
    )
    .unwrap();
    p
}

/// Runs `pipe` in `cache` up to `targets`; returns (success, output, summary).
fn run(pipe: &Path, cache: &Path, targets: &[&str], env: &[(&str, &str)]) -> (bool, String, Value) {
    let mut cmd = common::augsplat();
    cmd.arg("run").arg(pipe).arg("--cache").arg(cache).arg("-q");
    for t in targets {
        cmd.arg("--target").arg(t);
    }
    cmd.envs(env.iter().copied());
    common::run_summarised(cmd, &cache.with_extension("json"))
}

/// The status of node `name` in a run summary (`Null` when it is not there).
fn status(summary: &Value, name: &str) -> Value {
    summary["nodes"]
        .as_array()
        .and_then(|nodes| nodes.iter().find(|n| n["name"] == name))
        .map(|n| n["status"].clone())
        .unwrap_or(Value::Null)
}

#[test]
fn the_demo_runs_on_the_gpu_end_to_end() {
    let dir = tempfile::tempdir().unwrap();
    let pipe = pipeline(dir.path());
    let (ok, text, a) = run(&pipe, &dir.path().join("a"), &["report"], &[]);
    if !ok && text.contains("no GPU adapter was found") {
        augsplat_testkit::skip("the_demo_runs_on_the_gpu_end_to_end", &text);
        return;
    }
    assert!(ok, "{text}");
    let report = common::node_output(&dir.path().join("a"), &a, "report", "report");
    let html = std::fs::read_to_string(report.join("index.html")).unwrap();
    for label in ["3DGS", "Staged", "Dual"] {
        assert!(html.contains(label), "the report lacks {label}");
    }
    for (node, out) in [
        ("field[0]", "weights"),
        ("render[0]", "renders"),
        ("baseline", "model"),
    ] {
        let d = common::node_output(&dir.path().join("a"), &a, node, out);
        let device: Value =
            serde_json::from_slice(&std::fs::read(d.join("device.json")).unwrap()).unwrap();
        assert!(
            device["name"].as_str().is_some_and(|s| !s.is_empty()),
            "{node}: {device}"
        );
    }
    // A second fresh store: the same field and render bytes.
    let (ok, text, b) = run(&pipe, &dir.path().join("b"), &["render[0]"], &[]);
    assert!(ok, "{text}");
    for (node, out, file) in [
        ("field[0]", "weights", "field.safetensors"),
        ("render[0]", "renders", "view_0000.exr"),
    ] {
        assert_eq!(
            std::fs::read(common::node_output(&dir.path().join("a"), &a, node, out).join(file))
                .unwrap(),
            std::fs::read(common::node_output(&dir.path().join("b"), &b, node, out).join(file))
                .unwrap(),
            "{node}/{file} differs between two GPU runs"
        );
    }
    // An adapter that is not there is an error naming the adapters there are, never a
    // fall-back to the CPU, and the field node leaves nothing behind.
    let none = dir.path().join("none");
    let (ok, text, summary) = run(
        &pipe,
        &none,
        &["field[0]"],
        &[("WGPU_ADAPTER_NAME", "no-such-gpu-anywhere")],
    );
    assert!(!ok, "{text}");
    assert!(text.contains("no-such-gpu-anywhere"), "{text}");
    assert_ne!(
        status(&summary, "field[0]"),
        Value::from("ran"),
        "{summary}"
    );
    // A device lost after 5 field steps ends the node with the device's message and no
    // cache entry: the rerun trains it and gets the bytes of the first store.
    let lost = dir.path().join("lost");
    let (ok, text, _) = run(
        &pipe,
        &lost,
        &["field[0]"],
        &[("AUGSPLAT_TEST_LOSE_GPU_AFTER", "5")],
    );
    assert!(!ok, "{text}");
    assert!(text.contains("the GPU device was lost"), "{text}");
    let (ok, text, again) = run(&pipe, &lost, &["field[0]"], &[]);
    assert!(ok, "{text}");
    assert_eq!(status(&again, "field[0]"), Value::from("ran"), "{again}");
    assert_eq!(
        std::fs::read(
            common::node_output(&lost, &again, "field[0]", "weights").join("field.safetensors")
        )
        .unwrap(),
        std::fs::read(
            common::node_output(&dir.path().join("a"), &a, "field[0]", "weights")
                .join("field.safetensors")
        )
        .unwrap()
    );
}
