//! The paper's protocol pipelines (`pipelines/paper_<scene>.ron`): each plans on its real
//! files, its three seed points share the scene, the ensemble and its renders, and its draw
//! (26 / 4 views; 17 / 3 on fern) is reproducible and leak-free — no view is both trained on
//! and held out, and the test scene carries no SfM point. Real captures need the shared data
//! folder (skipped without it outside CI).

mod common;

use augsplat_graph::Engine;
use common::{args_of, augsplat, extended, output_dir, pipeline, run_with_summary};
use serde_json::Value;
use std::collections::BTreeSet;
use std::path::Path;

const SCENES: &[(&str, usize, usize)] = &[
    ("paper_generated", 26, 4),
    ("paper_bonsai", 26, 4),
    ("paper_fern", 17, 3),
    ("paper_horns", 26, 4),
    ("paper_dtu_scan24", 26, 4),
    ("paper_maryrose", 26, 4),
];

/// Whether the shared data folder is there (its absence is reported as a skip).
fn data_present(name: &str) -> bool {
    augsplat_testkit::data::shared_data(&format!("paper pipeline {name}"), "lpips").is_some()
}

#[test]
fn each_paper_pipeline_plans_and_its_seeds_share_the_upstream() {
    let cache = tempfile::tempdir().unwrap();
    let engine = Engine::new(augsplat::builtin_registry(), cache.path()).unwrap();
    for (name, _, _) in SCENES {
        if !data_present(name) {
            continue;
        }
        let plan = engine
            .load(&pipeline(name), &[])
            .unwrap_or_else(|e| panic!("{name}: {e}"));
        assert_eq!(plan.points.len(), 3, "{name}: three seeds");
        let count = |kind: &str| plan.comps.iter().filter(|c| c.node.kind() == kind).count();
        // One scene, one ensemble of 5 and its renders for the three points …
        assert_eq!(count("ImportScene") + count("SyntheticScene"), 1, "{name}");
        assert_eq!(count("TrainField"), 5, "{name}");
        assert_eq!(count("RenderField"), 10, "{name}");
        assert_eq!(count("AggregateEnsemble"), 1, "{name}");
        // … and each point's own three trainings.
        assert_eq!(count("OptimizeSplats"), 9, "{name}");
        engine.plan_text(&plan, &[]).unwrap();
    }
}

/// Runs `--target split` and returns (train view names, test view names, the split's key,
/// whether the test scene has points).
fn draw(name: &str, cache: &Path) -> (Vec<String>, Vec<String>, String, bool) {
    let mut cmd = augsplat();
    cmd.arg("run")
        .arg(pipeline(name))
        .args(["-q", "--target", "split", "--cache"])
        .arg(cache);
    let nodes = run_with_summary(cmd, &cache.with_extension("json"));
    let key = nodes
        .iter()
        .find(|n| n["name"].as_str().unwrap().starts_with("split"))
        .unwrap()["key"]
        .as_str()
        .unwrap()
        .to_string();
    let views = |output: &str| -> (Vec<String>, bool) {
        let dir = output_dir(cache, &key, Some(output));
        let scene: Value =
            serde_json::from_str(&std::fs::read_to_string(dir.join("scene.json")).unwrap())
                .unwrap();
        let names = scene["views"]
            .as_array()
            .unwrap()
            .iter()
            .map(|v| v["name"].as_str().unwrap().to_string())
            .collect();
        (names, dir.join("points.safetensors").is_file())
    };
    let (train, _) = views("train");
    let (test, test_points) = views("test");
    (train, test, key, test_points)
}

#[test]
fn each_paper_draw_is_reproducible_and_leak_free() {
    let tmp = tempfile::tempdir().unwrap();
    for (i, (name, n_train, n_test)) in SCENES.iter().enumerate() {
        if !data_present(name) {
            continue;
        }
        let (train, test, key, test_points) = draw(name, &tmp.path().join(format!("a{i}")));
        assert_eq!((train.len(), test.len()), (*n_train, *n_test), "{name}");
        let a: BTreeSet<_> = train.iter().collect();
        let b: BTreeSet<_> = test.iter().collect();
        assert!(
            a.is_disjoint(&b),
            "{name}: a view is both trained on and held out"
        );
        assert_eq!(
            a.len() + b.len(),
            n_train + n_test,
            "{name}: duplicate views"
        );
        assert!(
            !test_points,
            "{name}: the test scene must carry no SfM point"
        );
        // The same draw, bit for bit, from a fresh store.
        let again = draw(name, &tmp.path().join(format!("b{i}")));
        assert_eq!((train, test, key), (again.0, again.1, again.2), "{name}");
    }
}

/// The `--set`s of the study that `docs/results.md` reports for the improved Dual (with the
/// content prune: *The improved Dual with the content prune too*).
const IMPROVED_DUAL_SETS: [&str; 4] = [
    "dual.densify.reset=Never",
    "dual.densify.prune_extent=Content",
    "dual.synthetic.unweighted_stats=true",
    "dual.schedule=Dual(w_nerf0:2.0,w_real:1.0,quarter_decay:1000.0,off_below:None,synthetic_batch:20)",
];

/// Structural ids of a plan's computations, split into those of the nodes named in `bases`
/// and all the others.
fn sids_by(
    plan: &augsplat_graph::Plan,
    bases: &[&str],
) -> (BTreeSet<[u8; 32]>, BTreeSet<[u8; 32]>) {
    let (mut named, mut rest) = (BTreeSet::new(), BTreeSet::new());
    for c in &plan.comps {
        let base = &plan.instances[c.instances[0]].base;
        if bases.contains(&base.as_str()) {
            named.insert(c.sid);
        } else {
            rest.insert(c.sid);
        }
    }
    (named, rest)
}

/// Plans the scene's paper pipeline, the pipeline extended with `fragment`, and the paper
/// pipeline with the study's `sets`; checks that the fragment moves the computations of the
/// nodes in `movers` — and no other — and gives them exactly the measured runs' keys (a
/// finished paper run is reused, and the results page's figures are the fragment's). Returns
/// the extended plan.
fn check_fragment(
    engine: &Engine,
    dir: &Path,
    name: &str,
    fragment: &str,
    sets: &[&str],
    movers: &[&str],
) -> augsplat_graph::Plan {
    let sets: Vec<String> = sets.iter().map(|s| s.to_string()).collect();
    let paper = engine.load(&pipeline(name), &[]).unwrap();
    let improved = engine
        .load(&extended(dir, name, &[fragment]), &[])
        .unwrap_or_else(|e| panic!("{name}: {e}"));
    let measured = engine.load(&pipeline(name), &sets).unwrap();
    let (paper_moved, paper_rest) = sids_by(&paper, movers);
    let (improved_moved, improved_rest) = sids_by(&improved, movers);
    let (measured_moved, _) = sids_by(&measured, movers);
    assert_eq!(
        improved_rest, paper_rest,
        "{name}: {fragment} moved a node outside {movers:?}"
    );
    assert!(
        improved_moved.is_disjoint(&paper_moved),
        "{name}: {fragment} left {movers:?} unchanged"
    );
    assert_eq!(improved_moved, measured_moved, "{name}: {fragment}");
    improved
}

#[test]
fn the_improved_dual_fragment_changes_only_dual_and_is_what_the_study_measured() {
    let tmp = tempfile::tempdir().unwrap();
    let engine = Engine::new(augsplat::builtin_registry(), tmp.path().join("cache")).unwrap();
    for (name, _, _) in SCENES {
        if !data_present(name) {
            continue;
        }
        let improved = check_fragment(
            &engine,
            tmp.path(),
            name,
            "fragments/improved_dual",
            &IMPROVED_DUAL_SETS,
            &["dual", "eval_dual", "report"],
        );
        let a = args_of(&improved, "dual");
        assert_eq!(a["densify"]["reset"], "Never", "{name}: {a}");
        assert_eq!(a["densify"]["prune_extent"], "Content", "{name}: {a}");
        assert_eq!(a["synthetic"]["unweighted_stats"], true, "{name}: {a}");
        assert_eq!(
            a["schedule"]["Dual"]["quarter_decay"], 1000.0,
            "{name}: {a}"
        );
        assert!(a["schedule"]["Dual"]["off_below"].is_null(), "{name}: {a}");
    }
}

/// The `--set`s of the improved-baseline runs whose figures docs/results.md reports.
const IMPROVED_BASELINE_SETS: [&str; 2] = [
    "baseline.densify.reset=Never",
    "baseline.densify.prune_extent=Content",
];

#[test]
fn the_improved_baseline_fragment_reruns_only_what_reads_the_baseline() {
    let tmp = tempfile::tempdir().unwrap();
    let engine = Engine::new(augsplat::builtin_registry(), tmp.path().join("cache")).unwrap();
    // The baseline, and what reads its curve: every evaluation ("at the baseline's best
    // step") and the report.
    let readers = [
        "baseline",
        "eval_baseline",
        "eval_staged",
        "eval_dual",
        "report",
    ];
    for (name, _, _) in SCENES {
        if !data_present(name) {
            continue;
        }
        let improved = check_fragment(
            &engine,
            tmp.path(),
            name,
            "fragments/improved_baseline",
            &IMPROVED_BASELINE_SETS,
            &readers,
        );
        let d = &args_of(&improved, "baseline")["densify"];
        assert_eq!(d["reset"], "Never", "{name}: {d}");
        assert_eq!(d["prune_extent"], "Content", "{name}: {d}");
        // With both fragments, the improved Dual is the one measured alone.
        let both = extended(
            tmp.path(),
            name,
            &["fragments/improved_baseline", "fragments/improved_dual"],
        );
        let both = engine.load(&both, &[]).unwrap();
        let dual_only = engine
            .load(
                &extended(tmp.path(), name, &["fragments/improved_dual"]),
                &[],
            )
            .unwrap();
        let dual = |p: &augsplat_graph::Plan| sids_by(p, &["dual"]).0;
        assert_eq!(dual(&both), dual(&dual_only), "{name}");
    }
}

/// The `--set`s of the improved-Staged runs whose figures docs/notes/results.md reports (*Staged
/// with the improved baseline's settings*).
const IMPROVED_STAGED_SETS: [&str; 2] = [
    "staged.densify.reset=Never",
    "staged.densify.prune_extent=Content",
];

#[test]
fn the_improved_staged_fragment_changes_only_staged_and_is_what_the_study_measured() {
    let tmp = tempfile::tempdir().unwrap();
    let engine = Engine::new(augsplat::builtin_registry(), tmp.path().join("cache")).unwrap();
    let measured_sets: Vec<String> = IMPROVED_STAGED_SETS.iter().map(|s| s.to_string()).collect();
    for (name, _, _) in SCENES {
        if !data_present(name) {
            continue;
        }
        let improved = check_fragment(
            &engine,
            tmp.path(),
            name,
            "fragments/improved_staged",
            &IMPROVED_STAGED_SETS,
            &["staged", "eval_staged", "report"],
        );
        let a = args_of(&improved, "staged");
        assert_eq!(a["densify"]["reset"], "Never", "{name}: {a}");
        assert_eq!(a["densify"]["prune_extent"], "Content", "{name}: {a}");
        // Still the paper's Staged schedule (its switch and the reset there).
        assert!(a["schedule"]["Staged"].is_object(), "{name}: {a}");
        // With all three improved presets, Staged is the one measured alone.
        let all = extended(
            tmp.path(),
            name,
            &[
                "fragments/improved_baseline",
                "fragments/improved_dual",
                "fragments/improved_staged",
            ],
        );
        let all = engine.load(&all, &[]).unwrap();
        let measured = engine.load(&pipeline(name), &measured_sets).unwrap();
        let staged_of = |p: &augsplat_graph::Plan| sids_by(p, &["staged"]).0;
        assert_eq!(staged_of(&all), staged_of(&measured), "{name}");
    }
}
