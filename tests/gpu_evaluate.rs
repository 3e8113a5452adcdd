//! `Evaluate` with `backend: Gpu` through the CLI on the tiny demo: the same metrics as the
//! CPU backend (to rounding), the adapter recorded in `metrics.json`, the same bytes from two
//! fresh runs, and — where wgpu finds no adapter — a clear error and no cache entry. Skips
//! with a message when the machine has no GPU adapter (fails under `CI=true`).

use serde_json::Value;
use std::path::{Path, PathBuf};
use std::process::Command;

/// Runs the tiny demo up to `eval_baseline` with `extra` `--set`s; returns (success, output,
/// the eval folder when it succeeded).
fn eval(cache: &Path, extra: &[&str], env: &[(&str, &str)]) -> (bool, String, Option<PathBuf>) {
    let summary = cache.with_extension("json");
    let mut cmd = Command::new(env!("CARGO_BIN_EXE_augsplat"));
    cmd.arg("run")
        .arg(augsplat_testkit::tiny::pipeline())
        .arg("--cache")
        .arg(cache)
        .args(["--target", "eval_baseline", "--summary-json"])
        .arg(&summary);
    for s in extra {
        cmd.arg("--set").arg(s);
    }
    for (k, v) in env {
        cmd.env(k, v);
    }
    let out = cmd.output().unwrap();
    let text = format!(
        "{}{}",
        String::from_utf8_lossy(&out.stdout),
        String::from_utf8_lossy(&out.stderr)
    );
    if !out.status.success() {
        return (false, text, None);
    }
    let v: Value = serde_json::from_slice(&std::fs::read(&summary).unwrap()).unwrap();
    let node = v["nodes"]
        .as_array()
        .unwrap()
        .iter()
        .find(|n| n["name"] == "eval_baseline")
        .unwrap();
    let store = augsplat_graph::Store::open(cache).unwrap();
    let key = augsplat_graph::store::unhex(node["key"].as_str().unwrap()).unwrap();
    let action = store.action(&key).unwrap().unwrap();
    let dir = store.output_dir(&augsplat_graph::store::unhex(&action.outputs["eval"]).unwrap());
    (true, text, Some(dir))
}

#[test]
fn evaluate_on_the_gpu_measures_what_the_cpu_measures() {
    let dir = tempfile::tempdir().unwrap();
    let cache = dir.path().join("cache");
    let (ok, text, cpu) = eval(&cache, &[], &[]);
    assert!(ok, "{text}");
    let gpu_set = ["eval_baseline.backend=Gpu"];
    if cfg!(target_os = "linux") {
        let (ok, text, _) = eval(&cache, &gpu_set, &[("WGPU_BACKEND", "metal")]);
        assert!(!ok, "{text}");
        assert!(
            text.contains("eval_baseline") && text.contains("no GPU adapter was found"),
            "{text}"
        );
    }
    let (ok, text, gpu) = eval(&cache, &gpu_set, &[]);
    if !ok && text.contains("no GPU adapter was found") {
        augsplat_testkit::skip("evaluate_on_the_gpu_measures_what_the_cpu_measures", &text);
        return;
    }
    assert!(ok, "{text}");
    let read = |d: &Path| -> Value {
        serde_json::from_slice(&std::fs::read(d.join("metrics.json")).unwrap()).unwrap()
    };
    let (c, g) = (read(&cpu.unwrap()), read(gpu.as_ref().unwrap()));
    assert!(c.get("device").is_none());
    assert!(
        g["device"]["name"].as_str().is_some_and(|n| !n.is_empty()),
        "{g}"
    );
    assert!(g["device"]["backend"].as_str().is_some());
    for (a, b) in c["views"]
        .as_array()
        .unwrap()
        .iter()
        .zip(g["views"].as_array().unwrap())
    {
        let (pa, pb) = (a["psnr"].as_f64().unwrap(), b["psnr"].as_f64().unwrap());
        assert!((pa - pb).abs() < 0.01, "PSNR {pa} (CPU) vs {pb} (GPU)");
    }
    // A second fresh run on this adapter: the same bytes.
    let (ok, text, again) = eval(&dir.path().join("cache2"), &gpu_set, &[]);
    assert!(ok, "{text}");
    for f in ["metrics.json", "metrics.csv"] {
        assert_eq!(
            std::fs::read(gpu.as_ref().unwrap().join(f)).unwrap(),
            std::fs::read(again.as_ref().unwrap().join(f)).unwrap(),
            "{f}"
        );
    }
}
