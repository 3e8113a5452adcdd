//! The scene gate end to end (`pipelines/fragments/gate.ron` mixed into the demo): its decision never
//! depends on a held-out view, it picks at most one of Staged and Dual, a "skip" decision ends
//! the ensemble and both methods at once (marked gated) while the baseline and the report run,
//! and the report shows the decision.

mod common;

use augsplat_testkit::tiny;
use common::{augsplat, output_dir, run_with_summary};
use serde_json::Value;
use std::path::{Path, PathBuf};

struct Fixture {
    _tmp: tempfile::TempDir,
    dir: PathBuf,
    pipeline: PathBuf,
    cache: PathBuf,
}

impl Fixture {
    /// A generated 12-view scene exported to COLMAP text in `src/`, imported by the gated
    /// demo.
    fn new() -> Fixture {
        let tmp = tempfile::tempdir().unwrap();
        let dir = tmp.path().to_path_buf();
        let demo_gated = Path::new(env!("CARGO_MANIFEST_DIR")).join("pipelines/demo_gated.ron");
        let pipeline = dir.join("p.ron");
        std::fs::create_dir_all(dir.join("src")).unwrap();
        std::fs::write(
            &pipeline,
            format!(
                r#"(
    extends: {:?},
    nodes: {{
        "syn": (kind: "SyntheticScene", args: (width: 48, height: 40, views: 12, points: 400, supersample: 1)),
        "export": (kind: "ExportScene", args: (format: ColmapText), inputs: {{ "scene": "syn" }}),
        "scene": (kind: "ImportScene", args: (format: Colmap), inputs: {{ "source": Path("src") }}),
    }},
)"#,
                demo_gated.display().to_string()
            ),
        )
        .unwrap();
        let f = Fixture {
            cache: dir.join("cache"),
            dir,
            pipeline,
            _tmp: tmp,
        };
        let out = f.command(&["--target", "export"]).output().unwrap();
        assert!(out.status.success(), "{out:?}");
        let export = std::fs::read_dir(f.cache.join("outputs"))
            .unwrap()
            .map(|e| e.unwrap().path())
            .find(|p| p.join("sparse/0/cameras.txt").is_file())
            .expect("the export folder in the store");
        augsplat_testkit::copy_dir(&export, &f.dir.join("src"));
        f
    }

    /// `augsplat run p.ron` at the tiny sizes (the demo's, less the generated scene's, and
    /// the gate's rehearsal), plus `extra`.
    fn command(&self, extra: &[&str]) -> std::process::Command {
        let mut cmd = augsplat();
        cmd.arg("run")
            .arg(&self.pipeline)
            .arg("-q")
            .env("AUGSPLAT_CACHE", &self.cache)
            .current_dir(&self.dir);
        for s in tiny::sets_without_scene().chain(tiny::GATE_SETS.iter().copied()) {
            cmd.arg("--set").arg(s);
        }
        cmd.args(extra);
        cmd
    }

    /// A full run with a summary: per instance (name, status, key, gated reason).
    fn summary(&self, extra: &[&str]) -> Vec<(String, String, String, Option<String>)> {
        run_with_summary(self.command(extra), &self.dir.join("summary.json"))
            .iter()
            .map(|n| {
                (
                    n["name"].as_str().unwrap().to_string(),
                    n["status"].as_str().unwrap().to_string(),
                    n["key"].as_str().unwrap().to_string(),
                    n["gated"].as_str().map(str::to_string),
                )
            })
            .collect()
    }

    /// File `file` of the first output of the computation whose key is `key`.
    fn output(&self, key: &str, file: &str) -> Vec<u8> {
        std::fs::read(output_dir(&self.cache, key, None).join(file)).unwrap()
    }
}

fn find<'a>(
    s: &'a [(String, String, String, Option<String>)],
    name: &str,
) -> &'a (String, String, String, Option<String>) {
    s.iter()
        .find(|e| e.0 == name)
        .unwrap_or_else(|| panic!("no node {name}"))
}

#[test]
fn the_gate_reads_no_held_out_view_and_a_skip_ends_the_ensemble() {
    let f = Fixture::new();
    let first = f.summary(&[]);
    let gate = find(&first, "gate");
    let decision = f.output(&gate.2, "gate.json");
    let d: Value = serde_json::from_slice(&decision).unwrap();
    assert!(d["run"].is_boolean() && d["reason"].is_string(), "{d}");
    // The gate picks at most one of Staged and Dual (each reads its own output), and the
    // ensemble runs exactly when one is picked.
    let mut runs = 0;
    for method in ["staged", "dual"] {
        let path = output_dir(&f.cache, &gate.2, Some(method)).join("gate.json");
        let m: Value = serde_json::from_slice(&std::fs::read(path).unwrap()).unwrap();
        let run = m["run"].as_bool().unwrap();
        runs += usize::from(run);
        assert_eq!(find(&first, method).3.is_none(), run, "{method}: {m}");
    }
    assert!(runs <= 1, "the gate picked both methods");
    assert_eq!(d["run"].as_bool(), Some(runs == 1), "{d}");

    // Which images are held out: the test split's views.
    let split_test = std::fs::read_dir(f.cache.join("outputs"))
        .unwrap()
        .map(|e| e.unwrap().path())
        .filter(|p| p.join("scene.json").is_file())
        .map(|p| {
            std::fs::read_dir(p.join("images"))
                .unwrap()
                .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
                .collect::<Vec<_>>()
        })
        .min_by_key(|v| v.len())
        .unwrap();
    assert_eq!(split_test.len(), 2, "{split_test:?}");
    // Swap the two held-out photos' contents (and darken one): the scene changes, the
    // held-out evaluation changes, the gate's inputs do not.
    let images = f.dir.join("src/images");
    let a = std::fs::read(images.join(&split_test[0])).unwrap();
    let b = std::fs::read(images.join(&split_test[1])).unwrap();
    std::fs::write(images.join(&split_test[0]), &b).unwrap();
    let mut dark = image::load_from_memory(&a).unwrap().to_rgb8();
    dark.pixels_mut().for_each(|p| p.0 = p.0.map(|c| c / 3));
    dark.save(images.join(&split_test[1])).unwrap();

    let second = f.summary(&[]);
    assert_eq!(
        find(&second, "scene").1,
        "ran",
        "the swap changes the scene"
    );
    assert_ne!(
        find(&second, "eval_baseline").2,
        find(&first, "eval_baseline").2,
        "the held-out evaluation reads the swapped views"
    );
    for node in [
        "gate_split",
        "gate_field",
        "gate_dual",
        "gate_staged",
        "gate",
    ] {
        let (_, status, key, _) = find(&second, node);
        assert_eq!(status, "cached", "{node} must not see held-out views");
        assert_eq!(key, &find(&first, node).2);
    }
    assert_eq!(f.output(&find(&second, "gate").2, "gate.json"), decision);

    // A skip: the ensemble and both methods end at once; the baseline and report run.
    let skip = f.summary(&["--set", "gate.force=Some(false)"]);
    for (name, _, _, gated) in &skip {
        let expect_gated = name.starts_with("field[")
            || name.starts_with("render")
            || [
                "aggregate",
                "eval_ensemble",
                "staged",
                "dual",
                "eval_staged",
                "eval_dual",
            ]
            .contains(&name.as_str());
        assert_eq!(gated.is_some(), expect_gated, "{name}: {gated:?}");
        if let Some(r) = gated {
            assert!(r.starts_with("forced to skip"), "{r}");
        }
    }
    let report = find(&skip, "report");
    let summary = String::from_utf8(f.output(&report.2, "summary.md")).unwrap();
    assert!(summary.contains("## Gate: skip"), "{summary}");
    assert!(
        summary.contains("2 evaluation(s) skipped by the gate"),
        "{summary}"
    );
    assert!(summary.contains("| 3DGS ("), "{summary}");
    let html = String::from_utf8(f.output(&report.2, "index.html")).unwrap();
    assert!(html.contains("Scene gate") && html.contains("Decision: skip"));

    // The decision the engine reads holds no measured number: a rehearsal that changes but
    // still says run leaves the ensemble's keys (and entries) as they were.
    let open = f.summary(&["--set", "gate.force=Some(true)"]);
    let moved = f.summary(&[
        "--set",
        "gate.force=Some(true)",
        "--set",
        "params.gate_gs_steps=30",
    ]);
    assert_ne!(find(&open, "gate").2, find(&moved, "gate").2);
    for node in ["field[0]", "staged", "dual", "eval_dual"] {
        assert_eq!(find(&open, node).2, find(&moved, node).2, "{node}");
        assert_eq!(find(&moved, node).1, "cached", "{node}");
    }
}
