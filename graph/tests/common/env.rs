//! A test's environment: a temporary folder, an engine on a cache inside it, and the test's
//! own recorder; plus the pipeline texts and helpers several test files share.

use super::{registry, Recorder};
use augsplat_graph::{Engine, RunOptions};
use std::path::{Path, PathBuf};
use std::sync::Arc;

/// A temporary folder with an engine whose toy kinds record into `rec`.
pub struct Env {
    /// The folder pipelines are written to (the cache is `cache/` inside it).
    pub dir: tempfile::TempDir,
    /// The engine.
    pub engine: Engine,
    /// What this test's toy nodes did.
    pub rec: Arc<Recorder>,
}

impl Env {
    pub fn new() -> Env {
        let dir = tempfile::tempdir().unwrap();
        let rec = Recorder::new();
        let engine = Engine::new(registry(rec.clone()), dir.path().join("cache")).unwrap();
        Env { dir, engine, rec }
    }
    /// The nodes run since the last `take`, sorted.
    pub fn take(&self) -> Vec<String> {
        self.rec.take()
    }
    pub fn write(&self, name: &str, text: &str) -> PathBuf {
        let p = self.dir.path().join(name);
        std::fs::write(&p, text).unwrap();
        p
    }
    pub fn run(
        &self,
        file: &Path,
        sets: &[&str],
    ) -> (augsplat_graph::Plan, augsplat_graph::RunReport) {
        self.run_opts(
            file,
            sets,
            &RunOptions {
                jobs: 2,
                ..Default::default()
            },
        )
    }
    pub fn run_opts(
        &self,
        file: &Path,
        sets: &[&str],
        opts: &RunOptions,
    ) -> (augsplat_graph::Plan, augsplat_graph::RunReport) {
        let sets: Vec<String> = sets.iter().map(|s| s.to_string()).collect();
        let plan = self
            .engine
            .load(file, &sets)
            .unwrap_or_else(|e| panic!("{e}"));
        let report = self.engine.run(&plan, opts).unwrap();
        (plan, report)
    }
    pub fn keys(&self, file: &Path, sets: &[&str]) -> Vec<(String, String)> {
        let (plan, report) = self.run(file, sets);
        let s = report.summary_json(&plan);
        s["nodes"]
            .as_array()
            .unwrap()
            .iter()
            .map(|n| {
                (
                    n["name"].as_str().unwrap().to_string(),
                    n["key"].as_str().unwrap().to_string(),
                )
            })
            .collect()
    }
    pub fn read(
        &self,
        plan: &augsplat_graph::Plan,
        report: &augsplat_graph::RunReport,
        inst: &str,
        out: &str,
    ) -> String {
        let d = report
            .output_dir(plan, self.engine.store(), inst, out)
            .unwrap_or_else(|| panic!("no output {inst}.{out}"));
        std::fs::read_to_string(d.join("value.txt")).unwrap()
    }
}

pub const CHAIN: &str = r#"// a small chain with a fan-out
(
    nodes: {
        "src": (kind: "Source", args: (value: "ab", count: 2)),
        "app": (kind: "Append", args: (suffix: "!"), inputs: { "a": "src" }),
        "len": (kind: "Len", inputs: { "a": "app.out" }),
        "other": (kind: "Append", args: (suffix: "?"), inputs: { "a": "src.out" }),
    },
)
"#;

/// Sorted (instance, status) pairs of a run.
pub fn statuses(
    plan: &augsplat_graph::Plan,
    report: &augsplat_graph::RunReport,
) -> Vec<(String, String)> {
    let s = report.summary_json(plan);
    let mut v: Vec<(String, String)> = s["nodes"]
        .as_array()
        .unwrap()
        .iter()
        .map(|n| {
            (
                n["name"].as_str().unwrap().into(),
                n["status"].as_str().unwrap().into(),
            )
        })
        .collect();
    v.sort();
    v
}

/// The error message of loading pipeline text `text` (written to `name`), which must fail.
pub fn load_err(env: &Env, name: &str, text: &str) -> String {
    let f = env.write(name, text);
    match env.engine.load(&f, &[]) {
        Ok(_) => panic!("{name} should not load"),
        Err(e) => e.to_string(),
    }
}
