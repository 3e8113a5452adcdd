//! A nerfstudio-style transforms.json with its points in `sparse_pc.ply` (`ply_file_path`):
//! written from the generated scene by `ExportScene`, imported back, the points land on the
//! scene's ray-traced surfaces.

use augsplat_core::image::read_exr;
use augsplat_core::Scene;
use augsplat_scene::export::{export_scene, ExportFormat, SPARSE_PLY};
use augsplat_scene::import::{import_scene, ImportOptions};
use augsplat_scene::node::{read_source, ImportSceneArgs};
use augsplat_scene::synthetic::{generate, surface_error, SyntheticParams};

#[test]
fn transforms_ply_points_import_onto_the_surfaces() {
    let tmp = tempfile::tempdir().unwrap();
    let (gen, exported, imported) = (
        tmp.path().join("gen"),
        tmp.path().join("ns"),
        tmp.path().join("imp"),
    );
    let params = SyntheticParams {
        width: 192,
        height: 144,
        views: 12,
        points: 800,
        supersample: 1,
        ..Default::default()
    };
    let original = generate(&params, &gen).unwrap();
    export_scene(&gen, &exported, ExportFormat::Transforms).unwrap();
    let json: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(exported.join("transforms.json")).unwrap())
            .unwrap();
    assert_eq!(json["ply_file_path"], SPARSE_PLY);
    let raw = read_source(&exported, &ImportSceneArgs::default()).unwrap();
    assert!(
        raw.warnings.iter().any(|w| w.contains("800 points from")),
        "{:?}",
        raw.warnings
    );
    import_scene(&raw, &ImportOptions::default(), &imported, &|_| {}).unwrap();
    let scene = Scene::load(&imported).unwrap();
    let cloud = scene.load_points(&imported).unwrap();
    assert!(scene.has_points);
    assert_eq!(cloud.len(), 800);
    // The normalisation depends on the cameras only: the imported points are the generated
    // ones (to the PLY's float precision), seen by the views that see them.
    let gen_cloud = original.load_points(&gen).unwrap();
    for (a, b) in cloud.positions.iter().zip(&gen_cloud.positions) {
        for k in 0..3 {
            assert!((a[k] - b[k]).abs() < 1e-4, "{a:?} {b:?}");
        }
    }
    let depths: Vec<Vec<f32>> = scene
        .views
        .iter()
        .map(|view| {
            let exr = read_exr(&gen.join(format!("exact_depth/{}.exr", view.name))).unwrap();
            exr.channel("Z").unwrap().to_vec()
        })
        .collect();
    let (mut on_surface, mut observations) = (0, 0);
    for i in 0..cloud.len() {
        let p = cloud.positions[i].map(f64::from);
        for &v in cloud.track(i) {
            let view = &scene.views[v as usize];
            let best = surface_error(&depths[v as usize], &view.camera, p).unwrap_or(f64::INFINITY);
            observations += 1;
            on_surface += (best < 0.02) as usize;
        }
    }
    // Most points are seen by two views or more (the generator kept points two views see), and
    // what the visibility test calls seen lies on the visible surface: the coarse depth buffer
    // lets a few hidden points through and hides a few visible ones (measured: 703 of 800 seen
    // twice, 93.8 % of the observations on the surface).
    let seen_twice = (0..cloud.len())
        .filter(|&i| cloud.track(i).len() >= 2)
        .count();
    eprintln!("{seen_twice} points seen twice; {on_surface} of {observations} on the surface");
    assert!(seen_twice >= 680);
    assert!(
        on_surface as f64 >= 0.92 * observations as f64,
        "{on_surface} of {observations}"
    );
    // Near/far from the points, as for a COLMAP model with points.
    assert!(
        scene.near > 0.0 && scene.far > scene.near && scene.far < 20.0,
        "{} {}",
        scene.near,
        scene.far
    );
}
