//! The `TriangulatePoints` node: a scene without points gets them (with near/far from them and
//! a record of every stage), the same bytes for any thread count; a scene with points, or
//! `when: Never`, passes through unchanged; a scene it cannot work on is a clear error.

mod common;

use augsplat_core::Scene;
use augsplat_scene::node::{TriangulatePoints, TriangulatePointsArgs, TriangulateWhen};
use augsplat_scene::synthetic::{generate, SyntheticParams};
use augsplat_scene::triangulate::{TriangulationRecord, RECORD_FILE};
use common::{run_node, tree};

fn scene(dir: &std::path::Path, views: u32, points: u32) {
    generate(
        &SyntheticParams {
            width: 256,
            height: 192,
            views,
            points,
            supersample: 1,
            ..Default::default()
        },
        dir,
    )
    .unwrap();
}

#[test]
fn triangulate_points_fills_a_scene_without_points() {
    let tmp = tempfile::tempdir().unwrap();
    let src = tmp.path().join("src");
    scene(&src, 20, 0);
    let before = Scene::load(&src).unwrap();
    assert!(!before.has_points);
    let args = TriangulatePointsArgs::default();
    let (r1, r2) = (tmp.path().join("r1"), tmp.path().join("r2"));
    run_node::<TriangulatePoints>(&args, &[("scene", &src)], &r1, 1).unwrap();
    run_node::<TriangulatePoints>(&args, &[("scene", &src)], &r2, 2).unwrap();
    assert_eq!(
        tree(&r1.join("scene")),
        tree(&r2.join("scene")),
        "threads change bytes"
    );
    let out = r1.join("scene");
    let after = Scene::load(&out).unwrap();
    let cloud = after.load_points(&out).unwrap();
    assert!(
        after.has_points && cloud.len() >= 500,
        "{} points",
        cloud.len()
    );
    let record: TriangulationRecord =
        augsplat_core::artifacts::read_json(&out.join(RECORD_FILE)).unwrap();
    assert_eq!(record.report.points, cloud.len());
    assert_eq!(record.bounds_before, (before.near, before.far));
    let b = record.bounds.expect("bounds from the points");
    assert_eq!((after.near, after.far), (b.near, b.far));
    assert_eq!(b.per_view.len(), after.views.len());
    // The generated scene's own bounds are 0.8 × / 1.2 × its exact depth range (ground and
    // dome included): the points' bounds lie about inside them (the isolated points, wrong
    // two-view matches far behind the dome among them, do not count).
    assert!(
        after.near >= 0.9 * before.near && after.far <= before.far,
        "points {:.4}–{:.4}, exact {:.4}–{:.4}",
        after.near,
        after.far,
        before.near,
        before.far
    );
    // Images and cameras are the input's.
    assert_eq!(after.views, before.views);
    for v in &after.views {
        assert_eq!(
            std::fs::read(out.join(&v.image)).unwrap(),
            std::fs::read(src.join(&v.image)).unwrap()
        );
    }
    // Too few points for the bound: kept, with the warning in the record.
    let strict = TriangulatePointsArgs {
        min_points: 1_000_000,
        ..TriangulatePointsArgs::default()
    };
    let r3 = tmp.path().join("r3");
    run_node::<TriangulatePoints>(&strict, &[("scene", &src)], &r3, 2).unwrap();
    let record: TriangulationRecord =
        augsplat_core::artifacts::read_json(&r3.join("scene").join(RECORD_FILE)).unwrap();
    let w = record.warning.expect("a warning");
    assert!(
        w.contains("fewer than 1000000") && w.contains("keypoints"),
        "{w}"
    );
}

#[test]
fn triangulate_points_passes_through_and_refuses_clearly() {
    let tmp = tempfile::tempdir().unwrap();
    let with_points = tmp.path().join("with");
    scene(&with_points, 6, 300);
    let r = tmp.path().join("r");
    run_node::<TriangulatePoints>(
        &TriangulatePointsArgs::default(),
        &[("scene", &with_points)],
        &r,
        2,
    )
    .unwrap();
    assert_eq!(
        tree(&r.join("scene")),
        tree(&with_points),
        "a scene with points passes through"
    );
    let without = tmp.path().join("without");
    scene(&without, 6, 0);
    let never = TriangulatePointsArgs {
        when: TriangulateWhen::Never,
        ..TriangulatePointsArgs::default()
    };
    let r = tmp.path().join("never");
    run_node::<TriangulatePoints>(&never, &[("scene", &without)], &r, 2).unwrap();
    assert_eq!(
        tree(&r.join("scene")),
        tree(&without),
        "when: Never passes through"
    );
    // One view: nothing to triangulate from.
    let single = tmp.path().join("single");
    scene(&single, 1, 0);
    let e = run_node::<TriangulatePoints>(
        &TriangulatePointsArgs::default(),
        &[("scene", &single)],
        &tmp.path().join("r1"),
        2,
    )
    .unwrap_err();
    assert!(e.to_string().contains("at least two views"), "{e}");
}
