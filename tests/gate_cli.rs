//! The scene gate end to end (`pipelines/fragments/gate.ron` mixed into the demo): its decision never
//! depends on a held-out view, a "skip" decision ends the ensemble and both methods at once
//! (marked gated) while the baseline and the report run, and the report shows the decision.

use serde_json::Value;
use std::path::{Path, PathBuf};
use std::process::Command;

const BIN: &str = env!("CARGO_BIN_EXE_augsplat");

/// Tiny sizes for the imported scene's pipeline (the demo's tiny sizes, less the generated
/// scene's, plus the gate's rehearsal).
const SETS: &[&str] = &[
    "split.count=None",
    "field.steps=10",
    "field.rays_per_step=64",
    "field.chunk_rays=32",
    "field.levels=4",
    "field.log2_table_size=10",
    "field.max_resolution=64",
    "field.march_steps=16",
    "field.occupancy_resolution=16",
    "poses.count=6",
    "poses.downscale=2",
    "params.gs_steps=20",
    "params.eval_every=10",
    "params.warmup=10",
    "params.synthetic_batch=2",
    "params.lpips=None",
    "params.gate_field_steps=10",
    "params.gate_gs_steps=20",
    "params.gate_eval_every=10",
    "params.gate_synthetic=4",
    "params.gate_synthetic_batch=2",
    "gate_field.rays_per_step=64",
    "gate_field.chunk_rays=32",
    "gate_field.levels=4",
    "gate_field.log2_table_size=10",
    "gate_field.max_resolution=64",
    "gate_field.march_steps=16",
    "gate_field.occupancy_resolution=16",
    "gate_field.occupancy_warmup=4",
];

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
        let (ok, out) = f.run(&["--target", "export"]);
        assert!(ok, "{out}");
        let export = std::fs::read_dir(f.cache.join("outputs"))
            .unwrap()
            .map(|e| e.unwrap().path())
            .find(|p| p.join("sparse/0/cameras.txt").is_file())
            .expect("the export folder in the store");
        augsplat_testkit::copy_dir(&export, &f.dir.join("src"));
        f
    }

    /// `augsplat run p.ron --set …` plus `extra`; (success, stdout + stderr).
    fn run(&self, extra: &[&str]) -> (bool, String) {
        let mut cmd = Command::new(BIN);
        cmd.arg("run")
            .arg(&self.pipeline)
            .arg("-q")
            .env("AUGSPLAT_CACHE", &self.cache)
            .current_dir(&self.dir);
        for s in SETS {
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

    /// A full run with a summary: per instance (status, key, gated reason).
    fn summary(&self, extra: &[&str]) -> Vec<(String, String, String, Option<String>)> {
        let path = self.dir.join("summary.json");
        let mut args = vec!["--summary-json", path.to_str().unwrap()];
        args.extend_from_slice(extra);
        let (ok, out) = self.run(&args);
        assert!(ok, "{out}");
        let v: Value = serde_json::from_str(&std::fs::read_to_string(&path).unwrap()).unwrap();
        v["nodes"]
            .as_array()
            .unwrap()
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

    fn output(&self, key: &str, file: &str) -> Vec<u8> {
        let store = augsplat_graph::Store::open(&self.cache).unwrap();
        let entry = store
            .action(&augsplat_graph::store::unhex(key).unwrap())
            .unwrap()
            .expect("an action entry");
        let m = entry.outputs.values().next().unwrap();
        let dir = store.output_dir(&augsplat_graph::store::unhex(m).unwrap());
        std::fs::read(dir.join(file)).unwrap()
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
    for node in ["gate_split", "gate_field", "gate_dual", "gate"] {
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
