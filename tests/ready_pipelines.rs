//! Every ready pipeline in `pipelines/` loads (and plans) with the built-in node kinds, with
//! no warning: a pipeline that no longer loads after an edit of `base.ron` is caught here, not
//! by a user. Pipelines on the real captures need the shared data folder (skipped without it
//! outside CI). `custom_augment_rust.ron` needs the example crate's kind and is run by
//! `examples/custom_augment/tests/pipeline.rs`.

use augsplat_graph::Engine;
use std::path::Path;

#[test]
fn every_ready_pipeline_loads_and_plans_without_warnings() {
    let dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("pipelines");
    let mut files: Vec<_> = std::fs::read_dir(&dir)
        .unwrap()
        .flatten()
        .map(|e| e.path())
        .filter(|p| p.extension().is_some_and(|x| x == "ron"))
        .collect();
    files.sort();
    assert!(files.len() >= 10, "{files:?}");
    let cache = tempfile::tempdir().unwrap();
    let engine = Engine::new(augsplat::builtin_registry(), cache.path()).unwrap();
    let mut loaded = 0;
    for f in &files {
        let text = std::fs::read_to_string(f).unwrap();
        let name = f.file_name().unwrap().to_string_lossy().to_string();
        // Kinds from the custom-augmentation example crate: its own test runs this pipeline.
        if text.contains("kind: \"EnsembleMean\"") {
            continue;
        }
        if text.contains("shared/data")
            && augsplat_testkit::data::shared_data(&format!("ready pipeline {name}"), "").is_none()
        {
            continue;
        }
        let plan = engine
            .load(f, &[])
            .unwrap_or_else(|e| panic!("{name} does not load:\n{e}"));
        assert!(plan.warnings.is_empty(), "{name}: {:?}", plan.warnings);
        engine
            .plan_text(&plan, &[])
            .unwrap_or_else(|e| panic!("{name} does not plan: {e}"));
        loaded += 1;
    }
    assert!(loaded >= 10, "only {loaded} pipelines loaded");
}

/// Each fragment of `pipelines/fragments/` (not a pipeline alone) mixes into the demo, and a
/// fragment alone does not load: its nodes only add fields to the pipeline's.
#[test]
fn every_fragment_mixes_into_the_demo() {
    let root = Path::new(env!("CARGO_MANIFEST_DIR")).join("pipelines");
    let cache = tempfile::tempdir().unwrap();
    let engine = Engine::new(augsplat::builtin_registry(), cache.path()).unwrap();
    let mut n = 0;
    for e in std::fs::read_dir(root.join("fragments")).unwrap().flatten() {
        let name = e.file_name().to_string_lossy().to_string();
        let mixed = cache.path().join(format!("demo_{name}"));
        std::fs::write(
            &mixed,
            format!(
                "(extends: [{:?}, {:?}])",
                root.join("demo.ron").display().to_string(),
                e.path().display().to_string()
            ),
        )
        .unwrap();
        let plan = engine
            .load(&mixed, &[])
            .unwrap_or_else(|err| panic!("demo + {name} does not load:\n{err}"));
        assert!(plan.warnings.is_empty(), "{name}: {:?}", plan.warnings);
        engine.plan_text(&plan, &[]).unwrap();
        assert!(engine.load(&e.path(), &[]).is_err(), "{name} loads alone");
        n += 1;
    }
    assert!(n >= 1);
}
