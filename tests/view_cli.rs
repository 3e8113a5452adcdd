//! `augsplat view`: the report's viewer as a page of its own. On a model of the tiny demo with
//! its training and held-out scene folders: the page draws every camera, starts at the first
//! held-out one with its ground truth, and its canvas (read back from headless Chromium)
//! matches `augsplat render --sh-degree 0` at the camera the page reports. Cameras also come
//! from a capture folder (LLFF fern, when the shared data is present), and bad arguments are
//! readable errors.

use serde_json::Value;
use std::path::{Path, PathBuf};
use std::process::Command;
use std::time::Duration;

fn augsplat(args: &[&std::ffi::OsStr]) -> (bool, String) {
    let out = Command::new(env!("CARGO_BIN_EXE_augsplat"))
        .args(args)
        .output()
        .unwrap();
    (
        out.status.success(),
        format!(
            "{}{}",
            String::from_utf8_lossy(&out.stdout),
            String::from_utf8_lossy(&out.stderr)
        ),
    )
}

/// Output `output` of node `name` after running the tiny demo up to `eval_baseline`.
fn demo_outputs(cache: &Path) -> (PathBuf, PathBuf, PathBuf) {
    let summary = cache.with_extension("json");
    let out = Command::new(env!("CARGO_BIN_EXE_augsplat"))
        .arg("run")
        .arg(augsplat_testkit::tiny::pipeline())
        .arg("--cache")
        .arg(cache)
        .args(["--target", "eval_baseline", "-q", "--summary-json"])
        .arg(&summary)
        .output()
        .unwrap();
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let v: Value = serde_json::from_slice(&std::fs::read(&summary).unwrap()).unwrap();
    let store = augsplat_graph::Store::open(cache).unwrap();
    let get = |name: &str, output: &str| {
        let node = v["nodes"]
            .as_array()
            .unwrap()
            .iter()
            .find(|n| n["name"] == name)
            .unwrap();
        let key = augsplat_graph::store::unhex(node["key"].as_str().unwrap()).unwrap();
        let action = store.action(&key).unwrap().unwrap();
        store.output_dir(&augsplat_graph::store::unhex(&action.outputs[output]).unwrap())
    };
    (
        get("eval_baseline", "eval").join("model.ply"),
        get("split", "train"),
        get("split", "test"),
    )
}

#[test]
fn view_writes_a_viewer_that_draws_what_render_draws() {
    let dir = tempfile::tempdir().unwrap();
    let (model, train, test) = demo_outputs(&dir.path().join("cache"));
    let page = dir.path().join("view.html");
    let (ok, text) = augsplat(&[
        "view".as_ref(),
        model.as_os_str(),
        "--label".as_ref(),
        "3DGS".as_ref(),
        "--scene".as_ref(),
        train.as_os_str(),
        "--held-out".as_ref(),
        test.as_os_str(),
        "--out".as_ref(),
        page.as_os_str(),
    ]);
    assert!(ok, "{text}");
    assert!(
        text.contains("1 pane(s)") && text.contains("12 camera(s)"),
        "{text}"
    );
    let html = std::fs::read_to_string(&page).unwrap();
    assert!(html.starts_with("<!DOCTYPE html>") && html.contains("id=\"augsplat-viewer\""));

    // Readable errors.
    let (ok, text) = augsplat(&[
        "view".as_ref(),
        model.as_os_str(),
        "--label".as_ref(),
        "a".as_ref(),
        "--label".as_ref(),
        "b".as_ref(),
    ]);
    assert!(
        !ok && text.contains("2 --label values for 1 models"),
        "{text}"
    );
    let missing = dir.path().join("missing.ply");
    let (ok, text) = augsplat(&["view".as_ref(), missing.as_os_str()]);
    assert!(!ok && text.contains("missing.ply"), "{text}");
    let (ok, text) = augsplat(&[
        "view".as_ref(),
        model.as_os_str(),
        "--scene".as_ref(),
        dir.path().as_os_str(),
    ]);
    assert!(
        !ok && text.contains("neither an augsplat scene folder"),
        "{text}"
    );

    let Some(exe) = augsplat_testkit::browser::chromium("the view page's browser check") else {
        return;
    };
    let mut cmd = augsplat_testkit::browser::headless(&exe, &dir.path().join("profile"));
    cmd.arg("--dump-dom")
        .arg(format!("file://{}#readback", page.display()));
    let (dom, log) = augsplat_testkit::browser::run_limited(cmd, Duration::from_secs(120));
    assert!(!log.contains("Uncaught"), "{log}");
    assert!(
        dom.contains("viewer-status\">held-out camera "),
        "stderr:\n{log}"
    );
    let view = augsplat_testkit::browser::text_in_dom(&dom, "viewer-view").expect("the camera");
    let camera = dir.path().join("camera.json");
    std::fs::write(&camera, &view).unwrap();
    let png = augsplat_testkit::browser::data_url_in_dom(&dom, "viewer-readback-0").unwrap();
    let shown = dir.path().join("shown.png");
    std::fs::write(&shown, png).unwrap();
    let rendered = dir.path().join("rendered.png");
    let (ok, text) = augsplat(&[
        "render".as_ref(),
        "--splats".as_ref(),
        model.as_os_str(),
        "--camera".as_ref(),
        camera.as_os_str(),
        "--out".as_ref(),
        rendered.as_os_str(),
        "--sh-degree".as_ref(),
        "0".as_ref(),
    ]);
    assert!(ok, "{text}");
    let a = augsplat_core::image::read_rgb(&shown).unwrap();
    let b = augsplat_core::image::read_rgb(&rendered).unwrap();
    let mse = a
        .data
        .iter()
        .zip(&b.data)
        .map(|(x, y)| f64::from(x - y).powi(2))
        .sum::<f64>()
        / a.data.len() as f64;
    let psnr = -10.0 * mse.log10();
    eprintln!("augsplat view vs render: {psnr:.2} dB");
    assert!(psnr >= 30.0, "{psnr} dB");
}

#[test]
fn view_takes_the_cameras_of_a_capture_folder() {
    let Some(data) = augsplat_testkit::data::shared_data("view with LLFF fern", "fern") else {
        return;
    };
    let dir = tempfile::tempdir().unwrap();
    let model = dir.path().join("g.ply");
    augsplat_splat::write_ply(
        &model,
        &augsplat_splat::Gaussians::random_cloud(500, 0.01, 3),
    )
    .unwrap();
    let page = dir.path().join("fern.html");
    let (ok, text) = augsplat(&[
        "view".as_ref(),
        model.as_os_str(),
        "--scene".as_ref(),
        data.join("fern").as_os_str(),
        "--out".as_ref(),
        page.as_os_str(),
    ]);
    assert!(ok, "{text}");
    assert!(text.contains("20 camera(s)"), "{text}");
}
