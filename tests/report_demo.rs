//! The report of the demo pipeline: runs the demo at the test suite's tiny sizes
//! (`tests/tiny.ron`, LPIPS on) through the CLI with a fresh HOME and no weights installed,
//! then checks the `report` node's page — well-formed enough for a browser, the three
//! methods in the results table with every metric (the shipped LPIPS weights are found), the
//! plots — and that headless Chromium loads it without
//! errors and shows the table and SVG plots; its 3-D viewer draws each method's model at a
//! held-out camera (and after an orbit, on the panes' shared camera) as `augsplat render`
//! does, read back from the page's canvases. The screenshot is kept under the tests' temp
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

/// The folder of output `output` of node `name` in the run summarised by `summary`.
fn node_output(cache: &Path, summary: &Value, name: &str, output: &str) -> PathBuf {
    let node = summary["nodes"]
        .as_array()
        .unwrap()
        .iter()
        .find(|n| n["name"] == name)
        .unwrap_or_else(|| panic!("the summary lists node {name}"));
    let store = Store::open(cache).unwrap();
    let key = unhex(node["key"].as_str().unwrap()).unwrap();
    let action = store
        .action(&key)
        .unwrap()
        .expect("the node's action entry");
    store.output_dir(&unhex(&action.outputs[output]).unwrap())
}

/// Runs the demo and returns the run summary.
fn run_demo(cache: &Path) -> Value {
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
    // A fresh HOME with nothing installed: `Installed("lpips")` finds the LPIPS-alex weights
    // that ship with augsplat, so LPIPS is on as in the README's demo (tiny.ron turns it off).
    let home = cache.with_extension("home");
    std::fs::create_dir_all(&home).unwrap();
    cmd.env("HOME", &home)
        .env_remove("XDG_DATA_HOME")
        .env_remove("AUGSPLAT_LPIPS_WEIGHTS")
        .arg("--set")
        .arg("params.lpips=Alex");
    let out = cmd.output().expect("runs the augsplat binary");
    assert!(
        out.status.success(),
        "augsplat run demo failed:\n{}\n{}",
        String::from_utf8_lossy(&out.stdout),
        String::from_utf8_lossy(&out.stderr)
    );
    serde_json::from_str(&std::fs::read_to_string(&summary).unwrap()).unwrap()
}

/// PSNR of two images of equal size, dB.
fn psnr(a: &augsplat_core::ImageF32, b: &augsplat_core::ImageF32) -> f64 {
    assert_eq!((a.width, a.height, a.channels), (b.width, b.height, 3));
    let mse = a
        .data
        .iter()
        .zip(&b.data)
        .map(|(x, y)| f64::from(x - y).powi(2))
        .sum::<f64>()
        / a.data.len() as f64;
    -10.0 * mse.log10()
}

/// Loads the report at `url` + `hash` in Chromium with the viewer reading its canvases back,
/// and checks every pane against `augsplat render --sh-degree 0` (the viewer shows degree-0
/// colour) of its model at the camera the page reports: PSNR ≥ 30 dB. Returns the DOM.
fn check_viewer_panes(
    exe: &Path,
    profile: &Path,
    url: &str,
    hash: &str,
    models: &[PathBuf],
) -> String {
    let (dom, log) = chrome(
        exe,
        profile,
        &["--dump-dom".into(), format!("{url}#readback{hash}")],
    );
    let log = page_log(&log);
    for bad in ["Uncaught", "CONSOLE"] {
        assert!(!log.contains(bad), "chromium reported `{bad}`:\n{log}");
    }
    assert!(
        !dom.contains("viewer-status\">The 3-D viewer cannot start"),
        "the viewer did not start"
    );
    let view = augsplat_testkit::browser::text_in_dom(&dom, "viewer-view")
        .unwrap_or_else(|| panic!("the viewer wrote no camera; stderr:\n{log}"));
    let work = profile.with_extension("work");
    std::fs::create_dir_all(&work).unwrap();
    let camera = work.join("camera.json");
    std::fs::write(&camera, &view).unwrap();
    for (k, model) in models.iter().enumerate() {
        let png = augsplat_testkit::browser::data_url_in_dom(&dom, &format!("viewer-readback-{k}"))
            .unwrap_or_else(|| panic!("pane {k} was not read back; stderr:\n{log}"));
        let shown = work.join(format!("pane{k}.png"));
        std::fs::write(&shown, png).unwrap();
        let rendered = work.join(format!("render{k}.png"));
        let out = Command::new(env!("CARGO_BIN_EXE_augsplat"))
            .arg("render")
            .arg("--splats")
            .arg(model)
            .arg("--camera")
            .arg(&camera)
            .arg("--out")
            .arg(&rendered)
            .args(["--sh-degree", "0"])
            .output()
            .unwrap();
        assert!(
            out.status.success(),
            "{}",
            String::from_utf8_lossy(&out.stderr)
        );
        let a = augsplat_core::image::read_rgb(&shown).unwrap();
        let b = augsplat_core::image::read_rgb(&rendered).unwrap();
        let p = psnr(&a, &b);
        eprintln!("viewer pane {k} ({hash:?}) vs augsplat render: {p:.2} dB");
        assert!(
            p >= 30.0,
            "pane {k} at {view}: {p:.2} dB against augsplat render"
        );
    }
    dom
}

/// The log without the one console message that is not the page's: the software WebGL
/// driver's performance notice when the compositor reads a WebGL canvas back ("GPU stall due
/// to ReadPixels"). Every other console line stays and fails the checks.
fn page_log(log: &str) -> String {
    log.lines()
        .filter(|l| {
            !(l.contains("INFO:CONSOLE")
                && l.contains("GL Driver Message (OpenGL, Performance")
                && l.contains("GPU stall due to ReadPixels"))
        })
        .collect::<Vec<_>>()
        .join("\n")
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
    let cache = dir.path().join("cache");
    let summary = run_demo(&cache);
    let report = node_output(&cache, &summary, "report", "report");
    let evals: Vec<PathBuf> = ["eval_baseline", "eval_staged", "eval_dual"]
        .iter()
        .map(|n| node_output(&cache, &summary, n, "eval"))
        .collect();
    let index = report.join("index.html");
    let html = std::fs::read_to_string(&index).expect("the report has index.html");
    let md = std::fs::read_to_string(report.join("summary.md")).expect("and summary.md");
    assert!(html.starts_with("<!DOCTYPE html>") && html.trim_end().ends_with("</html>"));
    // The one script is the 3-D viewer's (its data and its code), with a pane per method.
    assert_eq!(
        html.matches("<script").count(),
        2,
        "only the viewer's scripts"
    );
    assert!(html.contains("id=\"augsplat-viewer\""));
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
    // Every column, LPIPS and the average error included, with nothing installed: the
    // shipped weights are found.
    let method_rows: Vec<&str> = md
        .lines()
        .filter(|l| {
            ["| 3DGS (", "| Staged (", "| Dual ("]
                .iter()
                .any(|p| l.starts_with(p))
        })
        .collect();
    assert_eq!(method_rows.len(), 9, "three tables of three methods:\n{md}");
    for row in &method_rows {
        assert!(!row.contains('—'), "a column is missing: {row}");
    }
    assert!(!md.contains("LPIPS weights"), "{md}");
    let header = md
        .lines()
        .find(|l| l.starts_with("| Method"))
        .unwrap_or_else(|| panic!("a table header:\n{md}"));
    assert!(
        header.contains("LPIPS") && header.contains("Avg. error"),
        "{header}"
    );
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
    let log = page_log(&log);
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

    // The viewer: at the first held-out camera, then after an orbit (the panes share the
    // camera, so each still matches its model rendered at the one camera the page reports).
    let models: Vec<PathBuf> = evals.iter().map(|e| e.join("model.ply")).collect();
    let url = format!("file://{}", keep.join("index.html").display());
    let dom = check_viewer_panes(&exe, &dir.path().join("p3"), &url, "", &models);
    let held_out: Value =
        serde_json::from_slice(&std::fs::read(evals[0].join("cameras.json")).unwrap()).unwrap();
    let first = held_out[0]["name"].as_str().unwrap();
    assert!(
        dom.contains(&format!("viewer-status\">held-out camera {first}<")),
        "the viewer starts at the first held-out camera"
    );
    // Its ground-truth pane shows that view's ground truth.
    let gt = std::fs::read(evals[0].join("gt").join(format!("{first}.png"))).unwrap();
    assert!(dom.contains(&format!(
        "src=\"data:image/png;base64,{}",
        augsplat_report::html::base64(&gt)
    )));
    let dom = check_viewer_panes(&exe, &dir.path().join("p4"), &url, "&orbit=40,-15", &models);
    assert!(
        dom.contains("viewer-status\">free camera<"),
        "the orbit moved the camera"
    );
}
