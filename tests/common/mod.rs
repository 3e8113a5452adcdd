//! Helpers shared by the CLI tests of this folder: run `augsplat` with a run summary, find a
//! computation's output folder in the store by its key, and name the ready pipelines and
//! their computations.
#![allow(dead_code)]

use augsplat_graph::store::unhex;
use augsplat_graph::Store;
use serde_json::Value;
use std::path::{Path, PathBuf};
use std::process::Command;

/// `augsplat` with `args`, plus `--summary-json SUMMARY`; asserts success and returns the
/// summary's nodes (`name`, `kind`, `key`, `status`, optional `gated`).
pub fn run_with_summary(mut cmd: Command, summary: &Path) -> Vec<Value> {
    let out = cmd.arg("--summary-json").arg(summary).output().unwrap();
    assert!(
        out.status.success(),
        "{cmd:?} failed:\n{}{}",
        String::from_utf8_lossy(&out.stdout),
        String::from_utf8_lossy(&out.stderr)
    );
    let v: Value = serde_json::from_str(&std::fs::read_to_string(summary).unwrap()).unwrap();
    v["nodes"].as_array().unwrap().clone()
}

/// `cmd` (an `augsplat run`) with `--summary-json SUMMARY`, whether or not it succeeds:
/// (success, stdout and stderr together, the summary or `Value::Null` where none was written).
pub fn run_summarised(mut cmd: Command, summary: &Path) -> (bool, String, Value) {
    let out = cmd.arg("--summary-json").arg(summary).output().unwrap();
    let text = format!(
        "{}{}",
        String::from_utf8_lossy(&out.stdout),
        String::from_utf8_lossy(&out.stderr)
    );
    let v = std::fs::read(summary)
        .ok()
        .and_then(|b| serde_json::from_slice(&b).ok())
        .unwrap_or(Value::Null);
    (out.status.success(), text, v)
}

/// The folder of output `output` of the node called `name` in a run summary.
pub fn node_output(cache: &Path, summary: &Value, name: &str, output: &str) -> PathBuf {
    let nodes = summary["nodes"].as_array().expect("a run summary");
    let key = node(nodes, name)["key"].as_str().expect("a key");
    output_dir(cache, key, Some(output))
}

/// The `augsplat` binary as a command.
pub fn augsplat() -> Command {
    Command::new(env!("CARGO_BIN_EXE_augsplat"))
}

/// The folder of output `output` (`None`: the first, by name) of the computation whose key
/// (hex) is `key`, in the store at `cache`.
pub fn output_dir(cache: &Path, key: &str, output: Option<&str>) -> PathBuf {
    let store = Store::open(cache).unwrap();
    let entry = store
        .action(&unhex(key).expect("a hex key"))
        .unwrap()
        .unwrap_or_else(|| panic!("no action entry for {key}"));
    let manifest = match output {
        Some(o) => &entry.outputs[o],
        None => entry.outputs.values().next().expect("an output"),
    };
    store.output_dir(&unhex(manifest).expect("a hex manifest"))
}

/// The log the computation whose key is `key` left in the store.
pub fn log_of(cache: &Path, key: &str) -> String {
    let store = Store::open(cache).unwrap();
    let entry = store.action(&unhex(key).unwrap()).unwrap().unwrap();
    std::fs::read_to_string(store.blob(&entry.log.expect("a log")).unwrap()).unwrap()
}

/// The summary node called `name`.
pub fn node<'a>(nodes: &'a [Value], name: &str) -> &'a Value {
    nodes
        .iter()
        .find(|n| n["name"] == name)
        .unwrap_or_else(|| panic!("no node {name}"))
}

/// The resolved arguments of the computation of node `base` in `plan` (the first instance
/// when a sweep has several).
pub fn args_of<'a>(plan: &'a augsplat_graph::Plan, base: &str) -> &'a Value {
    &plan
        .comps
        .iter()
        .find(|c| plan.instances[c.instances[0]].base == base)
        .unwrap_or_else(|| panic!("no computation of node {base}"))
        .args_json
}

/// `pipelines/NAME.ron` of this repository (`NAME` may name a fragment, `fragments/…`).
pub fn pipeline(name: &str) -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("pipelines")
        .join(format!("{name}.ron"))
}

/// A one-line pipeline in `dir` extending `pipelines/NAME.ron` with `fragments` (names as
/// [`pipeline`] takes them).
pub fn extended(dir: &Path, name: &str, fragments: &[&str]) -> PathBuf {
    let mut parts = vec![format!("{:?}", pipeline(name).display().to_string())];
    parts.extend(
        fragments
            .iter()
            .map(|f| format!("{:?}", pipeline(f).display().to_string())),
    );
    let tag: Vec<String> = fragments.iter().map(|f| f.replace('/', "_")).collect();
    let file = dir.join(format!("{name}+{}.ron", tag.join("+")));
    std::fs::write(&file, format!("(extends: [{}])", parts.join(", "))).unwrap();
    file
}

/// The computation ids of every instance of node `base` in `plan`.
pub fn sids_of(plan: &augsplat_graph::Plan, base: &str) -> std::collections::BTreeSet<[u8; 32]> {
    plan.comps
        .iter()
        .filter(|c| plan.instances[c.instances[0]].base == base)
        .map(|c| c.sid)
        .collect()
}
