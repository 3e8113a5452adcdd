//! The report of the demo pipeline: runs the demo at the test suite's tiny sizes
//! (`tests/tiny.ron`) through the CLI, then checks the `report` node's page — well-formed enough for a browser, the three
//! methods in the results table, the plots — and that headless Chromium loads it without
//! errors and shows the table and SVG plots. The screenshot is kept under the tests' temp
//! dir (`target/tmp/report_demo/shot.png`) as a CI artefact. The browser part skips with a
//! message when `chromium` is not installed (and fails under `CI=true`).

use augsplat_graph::store::unhex;
use augsplat_graph::Store;
use serde_json::Value;
use std::path::{Path, PathBuf};
use std::process::Command;
use std::time::Duration;

/// Timing records on, so the report shows its time plots (not part of any key).
const WALL_TIME: &[&str] = &[
    "baseline.record_wall_time=true",
    "staged.record_wall_time=true",
    "dual.record_wall_time=true",
    "eval_baseline.record_wall_time=true",
    "eval_staged.record_wall_time=true",
    "eval_dual.record_wall_time=true",
];

fn shared_lpips() -> Option<PathBuf> {
    let p = Path::new(env!("CARGO_MANIFEST_DIR")).join("../shared/data/lpips");
    p.join("lpips_alex_v0.1.safetensors").is_file().then_some(p)
}

/// Runs the demo and returns the `report` node's output folder.
fn run_demo(cache: &Path) -> PathBuf {
    let summary = cache.with_extension("summary.json");
    let mut cmd = Command::new(env!("CARGO_BIN_EXE_augsplat"));
    cmd.arg("run")
        .arg(augsplat_testkit::tiny::pipeline())
        .arg("--cache")
        .arg(cache)
        .arg("--summary-json")
        .arg(&summary)
        .arg("--quiet");
    for s in WALL_TIME {
        cmd.arg("--set").arg(s);
    }
    match shared_lpips() {
        Some(dir) => {
            cmd.env("AUGSPLAT_LPIPS_WEIGHTS", dir)
                .arg("--set")
                .arg("params.lpips=Alex");
        }
        None => {
            eprintln!("../shared/data/lpips absent: the demo report is made without LPIPS");
        }
    }
    let out = cmd.output().expect("runs the augsplat binary");
    assert!(
        out.status.success(),
        "augsplat run demo failed:\n{}\n{}",
        String::from_utf8_lossy(&out.stdout),
        String::from_utf8_lossy(&out.stderr)
    );
    let v: Value = serde_json::from_str(&std::fs::read_to_string(&summary).unwrap()).unwrap();
    let node = v["nodes"]
        .as_array()
        .unwrap()
        .iter()
        .find(|n| n["name"] == "report")
        .expect("the summary lists the report node");
    let store = Store::open(cache).unwrap();
    let key = unhex(node["key"].as_str().unwrap()).unwrap();
    let action = store
        .action(&key)
        .unwrap()
        .expect("the report's action entry");
    let manifest = unhex(&action.outputs["report"]).unwrap();
    store.output_dir(&manifest)
}

/// Runs headless Chromium with `extra` arguments (killed after two minutes); returns
/// (stdout, stderr).
fn chrome(exe: &Path, profile: &Path, extra: &[String]) -> (String, String) {
    let mut cmd = augsplat_testkit::browser::headless(exe, profile);
    cmd.args(extra);
    augsplat_testkit::browser::run_limited(cmd, Duration::from_secs(120))
}

#[test]
fn demo_report_renders_in_headless_chromium() {
    let dir = tempfile::tempdir().unwrap();
    let report = run_demo(&dir.path().join("cache"));
    let index = report.join("index.html");
    let html = std::fs::read_to_string(&index).expect("the report has index.html");
    let md = std::fs::read_to_string(report.join("summary.md")).expect("and summary.md");
    assert!(html.starts_with("<!DOCTYPE html>") && html.trim_end().ends_with("</html>"));
    assert!(!html.contains("<script"), "the page is script-free");
    for label in ["3DGS", "Staged", "Dual"] {
        assert!(
            html.contains(&format!("<th scope=\"row\">{label}")),
            "{label} row missing"
        );
        assert!(
            md.contains(&format!("| {label} (")),
            "{label} missing from summary.md"
        );
    }
    assert!(html.contains("All methods at the baseline&#39;s best step"));
    assert!(html.matches("<svg").count() >= 7);
    assert!(
        html.contains("confidence"),
        "synthetic views with confidence maps"
    );

    let Some(exe) = augsplat_testkit::browser::chromium("the demo report's browser check") else {
        return;
    };
    let keep = PathBuf::from(env!("CARGO_TARGET_TMPDIR")).join("report_demo");
    std::fs::create_dir_all(&keep).unwrap();
    std::fs::copy(&index, keep.join("index.html")).unwrap();
    let shot = keep.join("shot.png");
    let _ = std::fs::remove_file(&shot);
    let url = format!("file://{}", keep.join("index.html").display());
    let (dom, log) = chrome(
        &exe,
        &dir.path().join("p1"),
        &["--dump-dom".into(), url.clone()],
    );
    assert!(
        dom.contains("<table class=\"metrics\">"),
        "the DOM lacks the table; stderr:\n{log}"
    );
    assert!(dom.matches("<svg").count() >= 7, "the DOM lacks the plots");
    for bad in [
        "Uncaught",
        "ERR_FILE_NOT_FOUND",
        "Failed to load resource",
        "CONSOLE",
    ] {
        assert!(!log.contains(bad), "chromium reported `{bad}`:\n{log}");
    }
    let (_, log) = chrome(
        &exe,
        &dir.path().join("p2"),
        &[
            format!("--screenshot={}", shot.display()),
            "--window-size=1280,2000".into(),
            "--hide-scrollbars".into(),
            url,
        ],
    );
    let img = augsplat_core::image::read_rgb(&shot)
        .unwrap_or_else(|e| panic!("no screenshot ({e}); stderr:\n{log}"));
    assert_eq!((img.width, img.height), (1280, 2000));
    let colours: std::collections::BTreeSet<[u8; 3]> = img
        .data
        .chunks_exact(3)
        .map(|p| [0, 1, 2].map(|k| augsplat_core::image::to_u8(p[k])))
        .collect();
    assert!(colours.len() > 50, "the screenshot looks blank");
    eprintln!("screenshot: {}", shot.display());
}
