//! `OptimizeSplats` with `backend: Gpu` (the training state on the GPU; densification and
//! evaluations on the CPU) through the CLI on the tiny demo: a 50-step baseline gives the
//! same model bytes in two fresh stores and the same held-out PSNR as the CPU backend to
//! 0.1 dB; Staged and Dual run on the GPU too; the adapter is recorded in the model folder; a
//! device lost mid-run ends the node with a clear message and no cache entry; pixel masks
//! (`skip_below`) train on the GPU.
//! Skips with a message when the machine has no GPU adapter (fails under `CI=true`).

mod common;

use serde_json::Value;
use std::path::Path;

/// Runs the tiny demo with `sets`, up to `targets`; returns (success, output, summary).
fn run(cache: &Path, sets: &[&str], targets: &[&str]) -> (bool, String, Value) {
    run_with_env(cache, sets, targets, &[])
}

/// [`run`] with extra environment variables.
fn run_with_env(
    cache: &Path,
    sets: &[&str],
    targets: &[&str],
    env: &[(&str, &str)],
) -> (bool, String, Value) {
    let mut cmd = common::augsplat();
    cmd.arg("run")
        .arg(augsplat_testkit::tiny::pipeline())
        .arg("--cache")
        .arg(cache)
        .arg("-q");
    for s in sets {
        cmd.arg("--set").arg(s);
    }
    for t in targets {
        cmd.arg("--target").arg(t);
    }
    cmd.envs(env.iter().copied());
    common::run_summarised(cmd, &cache.with_extension("json"))
}

fn psnr(dir: &Path) -> f64 {
    let m: Value =
        serde_json::from_slice(&std::fs::read(dir.join("metrics.json")).unwrap()).unwrap();
    m["mean"]["psnr"].as_f64().unwrap()
}

#[test]
fn training_on_the_gpu_is_deterministic_and_matches_the_cpu() {
    let dir = tempfile::tempdir().unwrap();
    let steps = "params.gs_steps=50";
    let (ok, text, cpu) = run(&dir.path().join("cpu"), &[steps], &["eval_baseline"]);
    assert!(ok, "{text}");
    let gpu_sets = [steps, "baseline.backend=Gpu"];
    let (ok, text, a) = run(&dir.path().join("a"), &gpu_sets, &["eval_baseline"]);
    if !ok && text.contains("no GPU adapter was found") {
        augsplat_testkit::skip(
            "training_on_the_gpu_is_deterministic_and_matches_the_cpu",
            &text,
        );
        return;
    }
    assert!(ok, "{text}");
    let (ok, text, b) = run(&dir.path().join("b"), &gpu_sets, &["eval_baseline"]);
    assert!(ok, "{text}");
    let (ma, mb) = (
        common::node_output(&dir.path().join("a"), &a, "baseline", "model"),
        common::node_output(&dir.path().join("b"), &b, "baseline", "model"),
    );
    for f in [
        "final.ply",
        "best.ply",
        "curve.json",
        "best.json",
        "device.json",
    ] {
        assert_eq!(
            std::fs::read(ma.join(f)).unwrap(),
            std::fs::read(mb.join(f)).unwrap(),
            "{f} differs between two GPU runs"
        );
    }
    let device: Value =
        serde_json::from_slice(&std::fs::read(ma.join("device.json")).unwrap()).unwrap();
    assert!(
        device["name"].as_str().is_some_and(|s| !s.is_empty()),
        "{device}"
    );
    let (pc, pg) = (
        psnr(&common::node_output(
            &dir.path().join("cpu"),
            &cpu,
            "eval_baseline",
            "eval",
        )),
        psnr(&common::node_output(
            &dir.path().join("a"),
            &a,
            "eval_baseline",
            "eval",
        )),
    );
    eprintln!("50-step baseline, held-out PSNR: CPU {pc:.4} dB, GPU {pg:.4} dB");
    assert!((pc - pg).abs() <= 0.1, "CPU {pc} dB, GPU {pg} dB");

    // Staged and Dual on the GPU (the tiny demo's 20 steps).
    let (ok, text, s) = run(
        &dir.path().join("a"),
        &["staged.backend=Gpu", "dual.backend=Gpu"],
        &["eval_staged", "eval_dual"],
    );
    assert!(ok, "{text}");
    for n in ["staged", "dual"] {
        assert!(common::node_output(&dir.path().join("a"), &s, n, "model")
            .join("device.json")
            .is_file());
    }

    // A device lost mid-training (destroyed after 5 steps through the fault tests' hook)
    // ends the node with the device's message and leaves no cache entry: a rerun without
    // the fault trains it from scratch and gets the same model as before.
    let lost = dir.path().join("lost");
    let (ok, text, _) = run_with_env(
        &lost,
        &gpu_sets,
        &["baseline"],
        &[("AUGSPLAT_TEST_LOSE_GPU_AFTER", "5")],
    );
    assert!(!ok, "{text}");
    assert!(text.contains("the GPU device was lost"), "{text}");
    let (ok, text, again) = run(&lost, &gpu_sets, &["baseline"]);
    assert!(ok, "{text}");
    let status = again["nodes"]
        .as_array()
        .unwrap()
        .iter()
        .find(|n| n["name"] == "baseline")
        .map(|n| n["status"].clone());
    assert_eq!(
        status,
        Some(Value::from("ran")),
        "a failed node must leave no cache entry: {again}"
    );
    assert_eq!(
        std::fs::read(common::node_output(&lost, &again, "baseline", "model").join("final.ply"))
            .unwrap(),
        std::fs::read(ma.join("final.ply")).unwrap()
    );

    // Pixel masks (skip_below > 0) train on the GPU too.
    let (ok, text, _) = run(
        &dir.path().join("a"),
        &["staged.backend=Gpu", "params.skip_below=0.2"],
        &["staged"],
    );
    assert!(ok, "{text}");
}
