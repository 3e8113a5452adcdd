//! `pipelines/capture.ron` on a user's own folder, through the documented two-line pipeline
//! (`extends` capture.ron, `source` pointed at the folder): end to end at a tiny size on a
//! generated COLMAP export, a generated transforms.json export and an LLFF folder (a copy of
//! the shared fern, skipped without the shared data folder outside CI). The format is
//! detected, the photos are downscaled to `max_side`, and the gate decides for the ensemble.

use serde_json::Value;
use std::path::{Path, PathBuf};
use std::process::Command;

const BIN: &str = env!("CARGO_BIN_EXE_augsplat");

/// Beside the test suite's tiny sizes (less the generated scene's) and the gate's: photos at
/// most 48 px, 2 members.
const SETS: &[&str] = &[
    "scene.max_side=Some(48)",
    "params.members=2",
    "field.occupancy_warmup=4",
];

fn run(dir: &Path, pipeline: &Path, extra: &[&str]) -> (bool, String) {
    let mut cmd = Command::new(BIN);
    cmd.arg("run")
        .arg(pipeline)
        .arg("-q")
        .env("AUGSPLAT_CACHE", dir.join("cache"))
        .current_dir(dir);
    let tiny = augsplat_testkit::tiny::sets_without_scene();
    for s in SETS
        .iter()
        .copied()
        .chain(tiny)
        .chain(augsplat_testkit::tiny::GATE_SETS.iter().copied())
    {
        cmd.arg("--set").arg(s);
    }
    cmd.args(extra);
    let out = cmd.output().unwrap();
    (
        out.status.success(),
        format!(
            "{}{}",
            String::from_utf8_lossy(&out.stdout),
            String::from_utf8_lossy(&out.stderr)
        ),
    )
}

/// A generated 12-view 64×48 scene exported as `format` into `dir/src`.
fn generated_export(dir: &Path, format: &str) {
    let p = dir.join("export.ron");
    std::fs::write(
        &p,
        format!(
            r#"(nodes: {{
        "syn": (kind: "SyntheticScene", args: (width: 64, height: 48, views: 12, points: 400, supersample: 1)),
        "export": (kind: "ExportScene", args: (format: {format}), inputs: {{ "scene": "syn" }}),
    }})"#
        ),
    )
    .unwrap();
    let out = Command::new(BIN)
        .args(["run", p.to_str().unwrap(), "-q", "--out"])
        .arg(dir.join("exported"))
        .env("AUGSPLAT_CACHE", dir.join("cache"))
        .output()
        .unwrap();
    assert!(out.status.success(), "{out:?}");
    augsplat_testkit::copy_dir(&dir.join("exported/export/export"), &dir.join("src"));
}

/// Runs the user's two-line pipeline on `dir/src`; returns the summary's nodes and what the
/// run printed.
fn run_capture(dir: &Path) -> (Vec<Value>, String) {
    let capture = Path::new(env!("CARGO_MANIFEST_DIR")).join("pipelines/capture.ron");
    let mine = dir.join("my_capture.ron");
    std::fs::write(
        &mine,
        format!(
            "(extends: {:?},\n nodes: {{ \"scene\": (inputs: {{ \"source\": Path(\"src\") }}) }})\n",
            capture.display().to_string()
        ),
    )
    .unwrap();
    let summary = dir.join("summary.json");
    let (ok, out) = run(
        dir,
        &mine,
        &["--summary-json", summary.to_str().unwrap(), "--out", "res"],
    );
    assert!(ok, "{out}");
    let v: Value = serde_json::from_str(&std::fs::read_to_string(summary).unwrap()).unwrap();
    let nodes = v["nodes"].as_array().unwrap().clone();
    for n in &nodes {
        assert_ne!(n["status"], "failed", "{n}");
    }
    let gate = nodes
        .iter()
        .find(|n| n["name"] == "gate")
        .expect("the gate");
    assert_eq!(gate["gated"], Value::Null);
    // Whatever the gate said, the ensemble and the methods follow it: it skips both methods
    // or runs the one it picked.
    let gated = |name: &str| nodes.iter().find(|n| n["name"] == name).unwrap()["gated"].is_string();
    let report = std::fs::read_to_string(dir.join("res/report/report/summary.md")).unwrap();
    assert!(report.contains("## Gate: "), "{report}");
    assert_eq!(
        report.contains("## Gate: skip"),
        gated("staged") && gated("dual"),
        "{report}"
    );
    assert!(
        gated("staged") || gated("dual"),
        "one method at most: {report}"
    );
    (nodes, out)
}

/// The imported scene's image width: any scene folder in the store that the generated scene
/// did not write (the import and its splits share the size).
fn imported_width(dir: &Path) -> u64 {
    let mut folders: Vec<PathBuf> = std::fs::read_dir(dir.join("cache/outputs"))
        .unwrap()
        .flatten()
        .map(|e| e.path().join("scene.json"))
        .filter(|p| p.is_file())
        .collect();
    folders.sort();
    let scene = folders
        .iter()
        .map(|p| std::fs::read_to_string(p).unwrap())
        .find(|t| !t.contains("SyntheticScene"))
        .expect("an imported scene");
    let v: Value = serde_json::from_str(&scene).unwrap();
    v["views"][0]["camera"]["width"].as_u64().unwrap()
}

#[test]
fn capture_runs_on_a_generated_colmap_export() {
    let tmp = tempfile::tempdir().unwrap();
    generated_export(tmp.path(), "ColmapText");
    run_capture(tmp.path());
    // 64 px wide photos, at most 48 px: downscaled by 2.
    assert_eq!(imported_width(tmp.path()), 32);
}

#[test]
fn capture_runs_on_a_generated_transforms_json_export() {
    let tmp = tempfile::tempdir().unwrap();
    generated_export(tmp.path(), "Transforms");
    assert!(tmp.path().join("src/transforms.json").is_file());
    // The export keeps its points as nerfstudio does: the import reads them, so the
    // triangulation passes the scene through.
    assert!(tmp.path().join("src/sparse_pc.ply").is_file());
    let (nodes, _) = run_capture(tmp.path());
    assert_eq!(imported_width(tmp.path()), 32);
    assert!(nodes.iter().any(|n| n["name"] == "points"));
    // The evaluations measured the training views too.
    let (ok, out) = run(
        tmp.path(),
        &tmp.path().join("my_capture.ron"),
        &["--target", "eval_baseline", "--out", "res2"],
    );
    assert!(ok, "{out}");
    let m: Value = serde_json::from_str(
        &std::fs::read_to_string(tmp.path().join("res2/eval_baseline/eval/metrics.json")).unwrap(),
    )
    .unwrap();
    assert!(m["train_psnr"].as_f64().is_some_and(|p| p > 0.0), "{m}");
}

#[test]
fn capture_runs_on_an_llff_folder() {
    let Some(data) = augsplat_testkit::data::shared_data("capture on LLFF", "fern") else {
        return;
    };
    let tmp = tempfile::tempdir().unwrap();
    augsplat_testkit::copy_dir(&data.join("fern"), &tmp.path().join("src"));
    let (_, out) = run_capture(tmp.path());
    // 504×378 photos, at most 48 px: downscaled by 11 → 45 px wide.
    assert_eq!(imported_width(tmp.path()), 504 / 11);
    // LLFF has no points: at 45 px the triangulation finds (next to) none, and says so on
    // the terminal and in the report.
    assert!(
        out.contains("warning: TriangulatePoints: triangulation found only"),
        "{out}"
    );
    let report = std::fs::read_to_string(tmp.path().join("res/report/report/summary.md")).unwrap();
    assert!(
        report.contains("**Warnings**") && report.contains("triangulation found only"),
        "{report}"
    );
}

/// An LLFF folder that ships `images_4/` only (no `images_8/`, the importer's default factor)
/// imports through `capture.ron` unchanged: the folder whose image count matches the poses is
/// read, and the log says so.
#[test]
fn capture_runs_on_an_llff_folder_with_only_images_4() {
    let Some(data) = augsplat_testkit::data::shared_data("capture on LLFF images_4", "fern") else {
        return;
    };
    let tmp = tempfile::tempdir().unwrap();
    let src = tmp.path().join("src");
    std::fs::create_dir_all(&src).unwrap();
    std::fs::copy(
        data.join("fern/poses_bounds.npy"),
        src.join("poses_bounds.npy"),
    )
    .unwrap();
    augsplat_testkit::copy_dir(&data.join("fern/images_8"), &src.join("images_4"));
    let (nodes, _) = run_capture(tmp.path());
    assert_eq!(imported_width(tmp.path()), 504 / 11);
    let scene = nodes.iter().find(|n| n["name"] == "scene").unwrap();
    let key = scene["key"].as_str().unwrap();
    let store = augsplat_graph::Store::open(tmp.path().join("cache")).unwrap();
    let entry = store
        .action(&augsplat_graph::store::unhex(key).unwrap())
        .unwrap()
        .unwrap();
    let log = std::fs::read_to_string(store.blob(&entry.log.expect("a log")).unwrap()).unwrap();
    assert!(
        log.contains("images_8") && log.contains("images_4"),
        "{log}"
    );
}
