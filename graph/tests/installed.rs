//! `Installed("name")` input references: a resource the registry locates on this machine is
//! content-hashed like a `Path(..)`; one that is not installed leaves an optional input
//! unconnected (the same key as not writing the input) and fails a required one with the
//! resource's install hint; an unknown name is an error listing the known ones.

mod common;

use augsplat_graph::{Engine, Registry, RunOptions};
use std::path::{Path, PathBuf};
use std::sync::{Arc, Mutex};

/// The toy registry plus resource `weights`, installed wherever `at` says.
fn registry(at: Arc<Mutex<Option<PathBuf>>>) -> Registry {
    let mut r = common::registry(common::Recorder::new());
    r.register_resource(
        "weights",
        move || at.lock().unwrap().clone(),
        "install them with `toy fetch-weights`",
    );
    r
}

/// Runs pipeline `text` and returns the key of node `name` (hex).
fn key_of(engine: &Engine, dir: &Path, text: &str, name: &str) -> Result<String, String> {
    let file = dir.join("p.ron");
    std::fs::write(&file, text).unwrap();
    let plan = engine.load(&file, &[]).map_err(|e| e.to_string())?;
    let report = engine
        .run(
            &plan,
            &RunOptions {
                jobs: 1,
                ..Default::default()
            },
        )
        .map_err(|e| e.to_string())?;
    assert!(report.success());
    let inst = plan.instances.iter().find(|i| i.name == name).unwrap();
    let r = report.results[inst.comp].as_ref().unwrap();
    Ok(augsplat_graph::store::hex(&r.key.unwrap()))
}

const OPTIONAL: &str =
    r#"(nodes: { "n": (kind: "Seeded", args: (seed: 1), inputs: { "a": Installed("weights") }) })"#;
const UNWRITTEN: &str = r#"(nodes: { "n": (kind: "Seeded", args: (seed: 1)) })"#;

#[test]
fn an_installed_resource_is_content_hashed_and_a_missing_one_leaves_the_input_unconnected() {
    let dir = tempfile::tempdir().unwrap();
    let at = Arc::new(Mutex::new(None));
    let engine = Engine::new(registry(at.clone()), dir.path().join("cache")).unwrap();

    // Not installed: the optional input is unconnected, as if it were not written.
    let missing = key_of(&engine, dir.path(), OPTIONAL, "n").unwrap();
    assert_eq!(
        missing,
        key_of(&engine, dir.path(), UNWRITTEN, "n").unwrap()
    );

    // Installed: connected and content-hashed; same content, same key; new content, new key.
    let w = dir.path().join("w");
    std::fs::create_dir_all(&w).unwrap();
    std::fs::write(w.join("value.txt"), "v1").unwrap();
    *at.lock().unwrap() = Some(w.clone());
    let v1 = key_of(&engine, dir.path(), OPTIONAL, "n").unwrap();
    assert_ne!(v1, missing, "installing the resource changes the key");
    let copy = dir.path().join("w_copy");
    std::fs::create_dir_all(&copy).unwrap();
    std::fs::write(copy.join("value.txt"), "v1").unwrap();
    *at.lock().unwrap() = Some(copy);
    assert_eq!(key_of(&engine, dir.path(), OPTIONAL, "n").unwrap(), v1);
    std::fs::write(w.join("value.txt"), "v2").unwrap();
    *at.lock().unwrap() = Some(w);
    let v2 = key_of(&engine, dir.path(), OPTIONAL, "n").unwrap();
    assert_ne!(v2, v1, "new content, new key");

    // A path that does not exist counts as not installed.
    *at.lock().unwrap() = Some(dir.path().join("gone"));
    assert_eq!(key_of(&engine, dir.path(), OPTIONAL, "n").unwrap(), missing);
}

#[test]
fn a_required_input_needs_the_resource_and_unknown_names_are_errors() {
    let dir = tempfile::tempdir().unwrap();
    let engine = Engine::new(
        registry(Arc::new(Mutex::new(None))),
        dir.path().join("cache"),
    )
    .unwrap();
    let err = key_of(
        &engine,
        dir.path(),
        r#"(nodes: { "n": (kind: "Len", inputs: { "a": Installed("weights") }) })"#,
        "n",
    )
    .unwrap_err();
    assert!(err.contains("`weights` is not installed"), "{err}");
    assert!(err.contains("toy fetch-weights"), "{err}");
    let err = key_of(
        &engine,
        dir.path(),
        r#"(nodes: { "n": (kind: "Seeded", inputs: { "a": Installed("wieghts") }) })"#,
        "n",
    )
    .unwrap_err();
    assert!(
        err.contains("no installed resource is called `wieghts`"),
        "{err}"
    );
    assert!(err.contains("known: weights"), "{err}");
    let err = key_of(
        &engine,
        dir.path(),
        r#"(nodes: { "n": (kind: "Seeded", inputs: { "a": Installed(3) }) })"#,
        "n",
    )
    .unwrap_err();
    assert!(err.contains("Installed(\"name\")"), "{err}");
}
