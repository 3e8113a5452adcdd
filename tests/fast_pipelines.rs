//! The `*_fast.ron` pipelines are the knee configurations of the run-time-against-error
//! sweeps in `docs/benchmarks.md`: each plans to exactly the computations of its scene's
//! pipeline with the bench's `--set`s, so `augsplat run pipelines/bonsai_fast.ron` after the
//! bench (or the bench after it) recomputes nothing, and the figures quoted in its header are
//! the ones its run reproduces. Also which pipelines are long enough for the opacity reset and
//! the large-Gaussian prune to act. Real captures need the shared data folder (skipped without
//! it outside CI).

mod common;

use augsplat_graph::Engine;
use common::args_of;
use std::collections::BTreeSet;
use std::path::{Path, PathBuf};

/// The knee of each sweep, as the bench's configuration label and `--set`s.
const KNEE_SETS: [&str; 3] = [
    "field.steps=200",
    "params.gs_steps=1500",
    "params.max_gaussians=60000",
];

fn pipeline(name: &str) -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("pipelines")
        .join(format!("{name}.ron"))
}

fn sids(plan: &augsplat_graph::Plan) -> BTreeSet<[u8; 32]> {
    plan.comps.iter().map(|c| c.sid).collect()
}

#[test]
fn each_fast_pipeline_is_its_scenes_knee_configuration() {
    let tmp = tempfile::tempdir().unwrap();
    let engine = Engine::new(augsplat::builtin_registry(), tmp.path().join("cache")).unwrap();
    let knee: Vec<String> = KNEE_SETS.iter().map(|s| s.to_string()).collect();
    for scene in ["bonsai", "fern"] {
        if augsplat_testkit::data::shared_data(&format!("{scene}_fast.ron"), "lpips").is_none() {
            continue;
        }
        let fast = engine
            .load(&pipeline(&format!("{scene}_fast")), &[])
            .unwrap_or_else(|e| panic!("{scene}_fast: {e}"));
        let full = engine.load(&pipeline(scene), &[]).unwrap();
        let measured = engine.load(&pipeline(scene), &knee).unwrap();
        assert_eq!(sids(&fast), sids(&measured), "{scene}_fast is not the knee");
        // The sweep's shared upstream (the scene and its split) is the full pipeline's; the
        // fields and everything downstream of them are not.
        let (f, s) = (sids(&fast), sids(&full));
        assert!(
            !f.is_disjoint(&s),
            "{scene}: nothing shared with {scene}.ron"
        );
        assert_ne!(f, s, "{scene}_fast is {scene}.ron");
        let field = args_of(&fast, "field");
        assert_eq!(field["steps"], 200, "{scene}: {}", field);
    }
}

/// The scaled densification schedule of each `OptimizeSplats` node of `name`, with the
/// node's base name.
fn schedules(
    engine: &Engine,
    name: &str,
) -> Vec<(String, augsplat_splat::densify::DensifySchedule)> {
    let plan = engine
        .load(&pipeline(name), &[])
        .unwrap_or_else(|e| panic!("{name}: {e}"));
    plan.comps
        .iter()
        .filter(|c| c.node.kind() == "OptimizeSplats")
        .map(|c| {
            let args: augsplat_splat::train::TrainArgs =
                serde_json::from_value(c.args_json.clone())
                    .unwrap_or_else(|e| panic!("{name}: {e}: {}", c.args_json));
            let base = plan.instances[c.instances[0]].base.clone();
            (base, args.densify.scaled(args.steps))
        })
        .collect()
}

/// The 1,500-step pipelines (the knees and `capture.ron`) end refinement before the scaled
/// schedule's first opacity reset, so the improved presets' `reset: Never` and
/// `prune_extent: Content` cannot change them (measured on fern through `capture.ron`: the
/// same bytes; docs/results.md, *The large-Gaussian prune*); the 3,000-step paper pipelines
/// reach it, which is where those presets matter.
#[test]
fn which_pipelines_reach_the_first_opacity_reset() {
    let tmp = tempfile::tempdir().unwrap();
    let engine = Engine::new(augsplat::builtin_registry(), tmp.path().join("cache")).unwrap();
    for (name, reaches) in [
        ("capture", false),
        ("bonsai_fast", false),
        ("fern_fast", false),
        ("paper_horns", true),
        ("paper_bonsai", true),
    ] {
        if augsplat_testkit::data::shared_data(&format!("{name}.ron"), "lpips").is_none() {
            continue;
        }
        let found = schedules(&engine, name);
        // Staged, Dual and 3DGS at least (the gate's rehearsals too, in capture.ron).
        assert!(found.len() >= 3, "{name}: {found:?}");
        for (node, s) in found {
            if node.starts_with("gate_") {
                // 600-step rehearsals: never reach it.
                assert!(!s.reaches_reset(), "{name}.{node}: {s:?}");
                continue;
            }
            assert_eq!(s.reaches_reset(), reaches, "{name}.{node}: {s:?}");
        }
    }
}
