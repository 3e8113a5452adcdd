//! The demo's held-out metrics at the test suite's tiny size, pinned to recorded values
//! (`tests/pinned/tiny_demo_metrics.json`): a change that moves any result — even in the last
//! bits — fails here until the values are regenerated on purpose, together with the figures
//! in the docs built on them:
//!
//!   AUGSPLAT_REPIN=1 cargo test --test pinned_metrics
//!
//! Values are compared exactly on the instruction-set tier they were recorded with (the
//! kernels give identical bytes for any thread count there); on another tier the SIMD
//! kernels round differently, so they are compared to 1e-4 relative.

mod common;

use common::{augsplat, output_dir, run_with_summary};
use serde_json::{json, Value};
use std::path::{Path, PathBuf};

const PINNED: &str = "tests/pinned/tiny_demo_metrics.json";

fn root() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
}

/// Runs the tiny demo into `cache` and returns, per evaluation node, its mean metrics.
fn measure(cache: &Path) -> Value {
    let mut cmd = augsplat();
    cmd.arg("run")
        .arg(augsplat_testkit::tiny::pipeline())
        .args(["-q", "--cache"])
        .arg(cache);
    let nodes = run_with_summary(cmd, &cache.with_extension("summary.json"));
    let mut metrics = serde_json::Map::new();
    for n in &nodes {
        let name = n["name"].as_str().unwrap();
        if !name.starts_with("eval_") {
            continue;
        }
        let dir = output_dir(cache, n["key"].as_str().unwrap(), Some("eval"));
        let m: Value =
            serde_json::from_str(&std::fs::read_to_string(dir.join("metrics.json")).unwrap())
                .unwrap();
        let mean = if name == "eval_ensemble" {
            &m["median"]["mean"]
        } else {
            &m["mean"]
        };
        metrics.insert(
            name.to_string(),
            json!({ "psnr": mean["psnr"], "ssim": mean["ssim"], "mse": mean["mse"] }),
        );
    }
    Value::Object(metrics)
}

#[test]
fn the_tiny_demos_held_out_metrics_equal_the_recorded_values() {
    let tmp = tempfile::tempdir().unwrap();
    let got = measure(&tmp.path().join("cache"));
    let isa = augsplat_core::simd::active().name();
    let path = root().join(PINNED);
    if std::env::var_os("AUGSPLAT_REPIN").is_some() {
        let v = json!({
            "about": "held-out mean metrics of `augsplat run tests/tiny.ron`; regenerate with AUGSPLAT_REPIN=1 cargo test --test pinned_metrics",
            "isa": isa,
            "metrics": got,
        });
        std::fs::create_dir_all(path.parent().unwrap()).unwrap();
        std::fs::write(&path, serde_json::to_string_pretty(&v).unwrap() + "\n").unwrap();
        return;
    }
    let pinned: Value = serde_json::from_str(&std::fs::read_to_string(&path).unwrap()).unwrap();
    let exact = pinned["isa"] == isa;
    let want = pinned["metrics"].as_object().unwrap();
    let got = got.as_object().unwrap();
    assert_eq!(
        want.keys().collect::<Vec<_>>(),
        got.keys().collect::<Vec<_>>(),
        "the evaluated nodes changed"
    );
    let mut moved = Vec::new();
    for (node, w) in want {
        for metric in ["psnr", "ssim", "mse"] {
            let a = w[metric].as_f64().unwrap();
            let b = got[node][metric].as_f64().unwrap();
            let same = if exact {
                a.to_bits() == b.to_bits()
            } else {
                (a - b).abs() <= 1e-4 * a.abs().max(1e-12)
            };
            if !same {
                moved.push(format!("{node}.{metric}: recorded {a:?}, now {b:?}"));
            }
        }
    }
    assert!(
        moved.is_empty(),
        "results moved ({} comparison on {isa}):\n{}\nIf this is intended, regenerate {PINNED} \
         (AUGSPLAT_REPIN=1 cargo test --test pinned_metrics) and rerun the figures \
         in docs/ that depend on it",
        if exact { "exact" } else { "1e-4" },
        moved.join("\n")
    );
}
