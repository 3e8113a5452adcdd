//! The `*_fast.ron` pipelines are the knee configurations of the run-time-against-error
//! sweeps in `docs/notes/benchmarks.md`, with the fast prior: each plans to exactly the
//! computations of its scene's pipeline with the benches' `--set`s, so `augsplat run
//! pipelines/bonsai_fast.ron` after the bench (or the bench after it) recomputes nothing, and
//! the figures quoted in its header are the ones its run reproduces. The fast-prior fragment
//! likewise plans, at the reduced bonsai sizes, exactly the run its header quotes. Also which
//! pipelines are long enough for the opacity reset and the large-Gaussian prune to act. Real
//! captures need the shared data folder (skipped without it outside CI).

mod common;

use augsplat_graph::Engine;
use common::{args_of, extended, pipeline, sids_of};
use std::collections::BTreeSet;

/// The knee of each sweep with the fast prior (48 marching steps, 1.5 times the knee's 200
/// field steps), as the `--set`s of the benches its header quotes.
const KNEE_SETS: [&str; 4] = [
    "field.steps=300",
    "field.march_steps=48",
    "params.gs_steps=1500",
    "params.max_gaussians=60000",
];

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
        assert_eq!(field["steps"], 300, "{scene}: {}", field);
        assert_eq!(field["march_steps"], 48, "{scene}: {}", field);
    }
}

/// `--set`s of the fast-prior run whose figures `pipelines/fragments/fast_prior.ron` and
/// docs/notes/benchmarks.md quote: the README's reduced bonsai run with 600-step, 48-step fields.
const FAST_PRIOR_SETS: [&str; 4] = [
    "field.steps=600",
    "params.gs_steps=1500",
    "params.max_gaussians=60000",
    "field.march_steps=48",
];

#[test]
fn the_fast_prior_fragment_changes_the_fields_and_is_what_was_measured() {
    let tmp = tempfile::tempdir().unwrap();
    let engine = Engine::new(augsplat::builtin_registry(), tmp.path().join("cache")).unwrap();
    for scene in ["demo", "bonsai"] {
        if scene != "demo"
            && augsplat_testkit::data::shared_data("fragments/fast_prior.ron", "lpips").is_none()
        {
            continue;
        }
        let mixed = extended(tmp.path(), scene, &["fragments/fast_prior"]);
        let sized: Vec<String> = FAST_PRIOR_SETS[..3].iter().map(|s| s.to_string()).collect();
        let fast = engine
            .load(&mixed, &sized)
            .unwrap_or_else(|e| panic!("{scene} + fast_prior: {e}"));
        let plain = engine.load(&pipeline(scene), &sized).unwrap();
        // Every member marches 48 steps; nothing upstream of the fields moves.
        let members: Vec<_> = fast
            .comps
            .iter()
            .filter(|c| c.node.kind() == "TrainField")
            .collect();
        assert!(!members.is_empty(), "{scene}: no fields");
        for c in &members {
            assert_eq!(c.args_json["march_steps"], 48, "{scene}: {}", c.args_json);
            assert_eq!(c.args_json["steps"], 600, "{scene}: {}", c.args_json);
        }
        for base in ["scene", "baseline", "eval_baseline"] {
            assert_eq!(
                sids_of(&fast, base),
                sids_of(&plain, base),
                "{scene}: the fast prior moved {base}"
            );
        }
        for base in ["field", "render", "staged", "dual"] {
            let (a, b) = (sids_of(&fast, base), sids_of(&plain, base));
            assert!(!a.is_empty(), "{scene}: no {base}");
            assert!(
                a.is_disjoint(&b),
                "{scene}: {base} unchanged by the fast prior"
            );
        }
        if scene == "bonsai" {
            // The measured run: the same computations as the `--set`s quoted in the fragment.
            let all: Vec<String> = FAST_PRIOR_SETS.iter().map(|s| s.to_string()).collect();
            let measured = engine.load(&pipeline(scene), &all).unwrap();
            assert_eq!(
                sids(&fast),
                sids(&measured),
                "the fast prior is not the measured run"
            );
        }
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
/// same bytes; docs/notes/results.md, *The large-Gaussian prune*); the 3,000-step paper pipelines
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
