//! Helpers shared by the scene integration tests.
#![allow(dead_code)]

use augsplat_graph::{Node, NodeError, RunContext};
use std::path::{Path, PathBuf};

/// `<workspace root>/../shared/data`, or `None` (with a printed message) when absent.
pub fn data_dir(test: &str) -> Option<PathBuf> {
    augsplat_testkit::data::shared_data(test, "")
}

/// Runs node `N` standalone with `inputs` (name, folder) and returns the output root
/// (outputs at `<root>/<name>`).
pub fn run_node<N: Node>(
    args: &N::Args,
    inputs: &[(&str, &Path)],
    root: &Path,
    threads: usize,
) -> Result<(), NodeError> {
    let outputs = N::outputs(args);
    let names: Vec<&str> = outputs.iter().map(String::as_str).collect();
    let mut ctx = RunContext::standalone(
        inputs
            .iter()
            .map(|(n, p)| (n.to_string(), vec![p.to_path_buf()]))
            .collect(),
        &names,
        root,
        7,
        threads,
    )
    .expect("context");
    rayon::ThreadPoolBuilder::new()
        .num_threads(threads)
        .build()
        .expect("pool")
        .install(|| N::run(args, &mut ctx))
}

/// Every file under `dir` (relative path, bytes), sorted.
pub fn tree(dir: &Path) -> Vec<(String, Vec<u8>)> {
    let mut out = Vec::new();
    fn walk(base: &Path, d: &Path, out: &mut Vec<(String, Vec<u8>)>) {
        let mut entries: Vec<_> = std::fs::read_dir(d)
            .unwrap()
            .map(|e| e.unwrap().path())
            .collect();
        entries.sort();
        for p in entries {
            if p.is_dir() {
                walk(base, &p, out);
            } else {
                let rel = p.strip_prefix(base).unwrap().to_string_lossy().into_owned();
                out.push((rel, std::fs::read(&p).unwrap()));
            }
        }
    }
    walk(dir, dir, &mut out);
    out
}

/// A small generated scene in `dir` (folder `dir/syn`).
pub fn small_synthetic(dir: &Path, views: u32) -> PathBuf {
    let p = augsplat_scene::synthetic::SyntheticParams {
        width: 48,
        height: 36,
        views,
        points: 400,
        supersample: 2,
        ..Default::default()
    };
    let out = dir.join("syn");
    augsplat_scene::synthetic::generate(&p, &out).expect("generate");
    out
}
