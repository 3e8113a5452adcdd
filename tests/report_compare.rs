//! `augsplat compare`: metric deltas across evaluation folders, as a table and as JSON;
//! folders of folders; clear errors.

use augsplat_core::artifacts::write_json;
use augsplat_report::evalset::{EvalMetrics, Metrics, FORMAT_VERSION};
use std::path::Path;
use std::process::Command;

fn eval_dir(dir: &Path, label: &str, psnr: f64, ssim: f64, lpips: Option<f64>, seconds: f64) {
    std::fs::create_dir_all(dir).unwrap();
    let mse = 10f64.powf(-psnr / 10.0);
    let m = EvalMetrics {
        format: FORMAT_VERSION,
        label: label.into(),
        checkpoint: "best".into(),
        checkpoint_step: Some(300),
        train_psnr: None,
        lpips_net: lpips.map(|_| "alex".into()),
        mean: Metrics {
            psnr,
            ssim,
            mse,
            lpips,
            avg_error: lpips.map(|l| (mse * (1.0 - ssim).sqrt() * l).cbrt()),
        },
        views: vec![],
        best: None,
        at_baseline: None,
        train_seconds: Some(seconds),
        primitives: None,
        eval_seconds: Some(1.0),
        device: None,
        notes: vec![],
    };
    write_json(&dir.join("metrics.json"), &m).unwrap();
}

fn augsplat(args: &[&str]) -> (bool, String, String) {
    let out = Command::new(env!("CARGO_BIN_EXE_augsplat"))
        .args(args)
        .output()
        .unwrap();
    (
        out.status.success(),
        String::from_utf8_lossy(&out.stdout).into_owned(),
        String::from_utf8_lossy(&out.stderr).into_owned(),
    )
}

#[test]
fn compare_prints_deltas_against_the_reference() {
    let dir = tempfile::tempdir().unwrap();
    let base = dir.path().join("baseline");
    eval_dir(&base, "3DGS", 17.88, 0.622, Some(0.625), 100.0);
    // A sweep folder holding two ablation points (taken in name order).
    let sweep = dir.path().join("sweep");
    eval_dir(
        &sweep.join("gamma_1.0"),
        "Dual",
        18.10,
        0.628,
        Some(0.640),
        120.0,
    );
    eval_dir(
        &sweep.join("gamma_1.5"),
        "Dual",
        18.37,
        0.630,
        Some(0.631),
        121.0,
    );
    std::fs::create_dir_all(sweep.join("not_an_eval")).unwrap();
    let (ok, out, err) = augsplat(&["compare", base.to_str().unwrap(), sweep.to_str().unwrap()]);
    assert!(ok, "{err}");
    let lines: Vec<&str> = out.lines().collect();
    assert_eq!(lines.len(), 5, "{out}");
    assert!(lines[2].starts_with("* 3DGS"), "{out}");
    assert!(
        lines[3].contains("Dual [gamma_1.0]") && lines[3].contains("18.10 (+0.22▲)"),
        "{out}"
    );
    assert!(
        lines[4].contains("Dual [gamma_1.5]") && lines[4].contains("18.37 (+0.49▲)"),
        "{out}"
    );
    assert!(lines[4].contains("0.631 (+0.006▼)"), "{out}");

    let (ok, out, err) = augsplat(&[
        "compare",
        "--json",
        "--reference",
        "2",
        base.to_str().unwrap(),
        sweep.to_str().unwrap(),
    ]);
    assert!(ok, "{err}");
    let v: serde_json::Value = serde_json::from_str(&out).unwrap();
    assert_eq!(v["reference"], "Dual [gamma_1.0]");
    assert_eq!(v["source"], "eval");
    let runs = v["runs"].as_array().unwrap();
    assert_eq!(runs.len(), 3);
    let d = runs[0]["metrics"]["psnr"]["delta"].as_f64().unwrap();
    assert!((d - (17.88 - 18.10)).abs() < 1e-9, "{d}");
    assert_eq!(runs[1]["metrics"]["psnr"]["delta"].as_f64().unwrap(), 0.0);
    assert!(runs[2]["path"].as_str().unwrap().ends_with("gamma_1.5"));
}

#[test]
fn compare_errors_are_clear() {
    let dir = tempfile::tempdir().unwrap();
    let (ok, _, err) = augsplat(&["compare", dir.path().to_str().unwrap()]);
    assert!(!ok);
    assert!(err.contains("holds no metrics.json"), "{err}");
    let a = dir.path().join("a");
    eval_dir(&a, "A", 20.0, 0.7, None, 10.0);
    let (ok, _, err) = augsplat(&["compare", "--reference", "Z", a.to_str().unwrap()]);
    assert!(!ok && err.contains("matches no run"), "{err}");
    let (ok, _, err) = augsplat(&["compare", "--at", "baseline", a.to_str().unwrap()]);
    assert!(!ok && err.contains("baseline"), "{err}");
    let (ok, _, err) = augsplat(&["compare", "--at", "nope", a.to_str().unwrap()]);
    assert!(!ok && err.contains("unknown metric source"), "{err}");
}
