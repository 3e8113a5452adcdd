//! Node-level tests on generated scenes: export/import round trips, the split, sparse depth,
//! determinism across thread counts, and bad inputs.

mod common;

use augsplat_core::{Camera, Scene};
use augsplat_scene::export::ExportFormat;
use augsplat_scene::node::{
    ExportScene, ExportSceneArgs, ImportScene, ImportSceneArgs, SparseDepth, SparseDepthArgs,
    SplitScene, SplitSceneArgs,
};
use common::{run_node, small_synthetic, tree};
use std::path::Path;

fn assert_cameras_close(a: &Camera, b: &Camera, tol: f64, what: &str) {
    assert_eq!((a.width, a.height), (b.width, b.height), "{what}");
    for (x, y) in [(a.fx, b.fx), (a.fy, b.fy), (a.cx, b.cx), (a.cy, b.cy)] {
        assert!((x - y).abs() < tol, "{what}: intrinsics {x} vs {y}");
    }
    for r in 0..4 {
        for c in 0..4 {
            let (x, y) = (a.world_to_camera[r][c], b.world_to_camera[r][c]);
            assert!((x - y).abs() < tol, "{what}: pose [{r}][{c}] {x} vs {y}");
        }
    }
}

#[test]
fn export_and_reimport_round_trips_cameras() {
    let tmp = tempfile::tempdir().unwrap();
    let syn = small_synthetic(tmp.path(), 8);
    let scene = Scene::load(&syn).unwrap();
    let cloud = scene.load_points(&syn).unwrap();
    for (format, model) in [
        (ExportFormat::ColmapText, Some("sparse/0")),
        (ExportFormat::ColmapBinary, Some("sparse/0")),
        (ExportFormat::Transforms, None),
    ] {
        let root = tmp.path().join(format!("{format:?}"));
        run_node::<ExportScene>(&ExportSceneArgs { format }, &[("scene", &syn)], &root, 1).unwrap();
        let exported = root.join("export");
        let args = ImportSceneArgs {
            model: model.map(String::from),
            ..Default::default()
        };
        let back_root = root.join("back");
        run_node::<ImportScene>(&args, &[("source", &exported)], &back_root, 2).unwrap();
        let out = back_root.join("scene");
        let back = Scene::load(&out).unwrap();
        assert_eq!(back.views.len(), scene.views.len());
        for (a, b) in scene.views.iter().zip(&back.views) {
            assert_eq!(a.name, b.name);
            assert_cameras_close(
                &a.camera,
                &b.camera,
                1e-6,
                &format!("{format:?} {}", a.name),
            );
        }
        let n = (&scene.normalization, &back.normalization);
        assert!((n.0.scale - n.1.scale).abs() < 1e-9, "{format:?}");
        // Images survive byte-exactly through the copy + PNG re-encode of identical pixels.
        let a = scene.load_image(&syn, 2).unwrap();
        let b = back.load_image(&out, 2).unwrap();
        assert_eq!(a, b, "{format:?}");
        if format != ExportFormat::Transforms {
            // Points and their tracks come back too (f32 storage).
            let pc = back.load_points(&out).unwrap();
            assert_eq!(pc.len(), cloud.len());
            assert_eq!(pc.track_views, cloud.track_views);
            for i in 0..pc.len() {
                for k in 0..3 {
                    assert!((pc.positions[i][k] - cloud.positions[i][k]).abs() < 1e-5);
                }
            }
            // The exported keypoints are exact projections: the model's error is ~0.
            let report = augsplat_scene::inspect::inspect(&exported).unwrap();
            assert!(report.mean_reprojection_error.unwrap() < 1e-6);
        }
    }
}

#[test]
fn split_is_seeded_and_leaks_nothing_from_test_views() {
    let tmp = tempfile::tempdir().unwrap();
    let syn = small_synthetic(tmp.path(), 40);
    let scene = Scene::load(&syn).unwrap();
    let mut cloud = scene.load_points(&syn).unwrap();
    // Orbit points are seen by many views; add points seen mostly by test views (the split
    // of 40 views with the default args is computed independently below by name).
    let split = augsplat_scene::split::split_indices(40, Some(30), 8, 42).unwrap();
    let (t, r) = (&split.test, &split.train);
    for track in [
        vec![t[0], t[1]],
        vec![r[0], t[1], t[2]],
        vec![r[0], r[5], t[3]],
    ] {
        let mut track: Vec<u32> = track.into_iter().map(|v| v as u32).collect();
        track.sort();
        cloud.positions.push([0.01, 0.02, 0.03]);
        cloud.colors.push([0.5; 3]);
        cloud.errors.push(0.3);
        cloud.track_views.extend(track);
        cloud.track_offsets.push(cloud.track_views.len() as u32);
    }
    cloud.save(&syn.join("points.safetensors")).unwrap();
    let args = SplitSceneArgs::default();
    let r1 = tmp.path().join("s1");
    let r2 = tmp.path().join("s2");
    run_node::<SplitScene>(&args, &[("scene", &syn)], &r1, 1).unwrap();
    run_node::<SplitScene>(&args, &[("scene", &syn)], &r2, 2).unwrap();
    assert_eq!(tree(&r1.join("train")), tree(&r2.join("train")));
    assert_eq!(tree(&r1.join("test")), tree(&r2.join("test")));
    let train = Scene::load(&r1.join("train")).unwrap();
    let test = Scene::load(&r1.join("test")).unwrap();
    assert_eq!((train.views.len(), test.views.len()), (26, 4));
    let train_names: Vec<_> = train.views.iter().map(|v| v.name.clone()).collect();
    for v in &test.views {
        assert!(!train_names.contains(&v.name), "{} is in both", v.name);
    }
    // A different seed gives a different split.
    let r3 = tmp.path().join("s3");
    let other = SplitSceneArgs {
        seed: 7,
        ..Default::default()
    };
    run_node::<SplitScene>(&other, &[("scene", &syn)], &r3, 1).unwrap();
    let train3 = Scene::load(&r3.join("train")).unwrap();
    assert_ne!(
        train3.views.iter().map(|v| &v.name).collect::<Vec<_>>(),
        train_names.iter().collect::<Vec<_>>()
    );
    // Every kept point is seen by ≥ 2 train views (by name, in the original tracks), and
    // every point seen by ≥ 2 train views is kept.
    let tp = train.load_points(&r1.join("train")).unwrap();
    assert!(test.load_points(&r1.join("test")).unwrap().is_empty());
    let is_train = |v: u32| train_names.contains(&scene.views[v as usize].name);
    let expected: Vec<usize> = (0..cloud.len())
        .filter(|&i| cloud.track(i).iter().filter(|&&v| is_train(v)).count() >= 2)
        .collect();
    assert_eq!(tp.len(), expected.len());
    assert_eq!(
        tp.len() + 2,
        cloud.len(),
        "exactly the two test-dominated points are dropped"
    );
    for (k, &i) in expected.iter().enumerate() {
        assert_eq!(tp.positions[k], cloud.positions[i]);
        let names: Vec<_> = tp
            .track(k)
            .iter()
            .map(|&v| train.views[v as usize].name.clone())
            .collect();
        let want: Vec<_> = cloud
            .track(i)
            .iter()
            .filter(|&&v| is_train(v))
            .map(|&v| scene.views[v as usize].name.clone())
            .collect();
        assert_eq!(names, want);
    }
}

#[test]
fn sparse_depth_agrees_with_exact_depth() {
    let tmp = tempfile::tempdir().unwrap();
    let syn = small_synthetic(tmp.path(), 8);
    let root = tmp.path().join("d");
    run_node::<SparseDepth>(&SparseDepthArgs::default(), &[("scene", &syn)], &root, 2).unwrap();
    let out = root.join("scene");
    let scene = Scene::load(&out).unwrap();
    let mut rel = Vec::new();
    for i in 0..scene.views.len() {
        let (z, w) = scene.load_depth(&out, i).unwrap().expect("depth");
        let exact = augsplat_core::image::read_exr(
            &syn.join(format!("exact_depth/{}.exr", scene.views[i].name)),
        )
        .unwrap();
        let ez = exact.channel("Z").unwrap();
        for k in 0..z.len() {
            if w[k] > 0.0 {
                assert!(z[k] > 0.0 && w[k] <= 1.0);
                rel.push(((z[k] - ez[k]) / ez[k]).abs());
            } else {
                assert_eq!(z[k], 0.0);
            }
        }
    }
    assert!(rel.len() > 500, "{} depth pixels", rel.len());
    rel.sort_by(f32::total_cmp);
    let median = rel[rel.len() / 2];
    assert!(median < 0.01, "median relative depth error {median}");
    // Images and points were carried along.
    assert!(scene.has_points);
    assert_eq!(
        scene.load_image(&out, 0).unwrap(),
        Scene::load(&syn).unwrap().load_image(&syn, 0).unwrap()
    );
}

#[test]
fn dense_depth_input_is_used_where_present() {
    let tmp = tempfile::tempdir().unwrap();
    let syn = small_synthetic(tmp.path(), 4);
    let scene = Scene::load(&syn).unwrap();
    // Dense maps (original units) for view_001 only: the exact depth / scale.
    let dense = tmp.path().join("dense");
    std::fs::create_dir_all(&dense).unwrap();
    let exact = augsplat_core::image::read_exr(&syn.join("exact_depth/view_001.exr")).unwrap();
    let z: Vec<f32> = exact
        .channel("Z")
        .unwrap()
        .iter()
        .map(|&z| z / scene.normalization.scale as f32)
        .collect();
    augsplat_core::image::write_exr(
        &dense.join("view_001.exr"),
        exact.width,
        exact.height,
        &[("Z", &z)],
    )
    .unwrap();
    let root = tmp.path().join("d");
    run_node::<SparseDepth>(
        &SparseDepthArgs::default(),
        &[("scene", &syn), ("dense", &dense)],
        &root,
        1,
    )
    .unwrap();
    let out = root.join("scene");
    let s = Scene::load(&out).unwrap();
    let (z1, w1) = s.load_depth(&out, 1).unwrap().unwrap();
    let ez = exact.channel("Z").unwrap();
    for k in 0..z1.len() {
        assert!((z1[k] - ez[k]).abs() <= 1e-5 * ez[k]);
        assert_eq!(w1[k], 1.0);
    }
    // The other views fall back to sparse depth.
    let (_, w0) = s.load_depth(&out, 0).unwrap().unwrap();
    assert!(w0.iter().filter(|&&w| w > 0.0).count() < w0.len() / 2);
}

#[test]
fn import_is_identical_for_one_and_two_threads() {
    let tmp = tempfile::tempdir().unwrap();
    let syn = small_synthetic(tmp.path(), 6);
    let root = tmp.path().join("e");
    run_node::<ExportScene>(&ExportSceneArgs::default(), &[("scene", &syn)], &root, 1).unwrap();
    let src = root.join("export");
    let a = tmp.path().join("a");
    let b = tmp.path().join("b");
    run_node::<ImportScene>(&ImportSceneArgs::default(), &[("source", &src)], &a, 1).unwrap();
    run_node::<ImportScene>(&ImportSceneArgs::default(), &[("source", &src)], &b, 2).unwrap();
    assert_eq!(tree(&a.join("scene")), tree(&b.join("scene")));
    // The same source content at another path gives the same bytes (no absolute paths).
    let moved = tmp.path().join("elsewhere/source");
    std::fs::create_dir_all(moved.parent().unwrap()).unwrap();
    std::fs::rename(&src, &moved).unwrap();
    let c = tmp.path().join("c");
    run_node::<ImportScene>(&ImportSceneArgs::default(), &[("source", &moved)], &c, 2).unwrap();
    assert_eq!(tree(&a.join("scene")), tree(&c.join("scene")));
}

/// A valid COLMAP text source exported from a generated scene, for corrupting.
fn colmap_source(tmp: &Path) -> std::path::PathBuf {
    let syn = small_synthetic(tmp, 4);
    let root = tmp.join("e");
    run_node::<ExportScene>(&ExportSceneArgs::default(), &[("scene", &syn)], &root, 1).unwrap();
    root.join("export")
}

fn import_err(src: &Path, args: &ImportSceneArgs, root: &Path) -> String {
    let e =
        run_node::<ImportScene>(args, &[("source", src)], root, 1).expect_err("import must fail");
    e.message().to_string()
}

#[test]
fn bad_inputs_give_clear_errors_naming_the_file() {
    let tmp = tempfile::tempdir().unwrap();
    let good = colmap_source(tmp.path());
    let fresh = |name: &str| {
        let d = tmp.path().join(name);
        augsplat_testkit::copy_dir(&good, &d);
        d
    };
    let args = ImportSceneArgs::default();
    let mut n = 0;
    let mut root = || {
        n += 1;
        tmp.path().join(format!("out{n}"))
    };

    // Missing folder.
    let e = import_err(&tmp.path().join("nope"), &args, &root());
    assert!(e.contains("nope") && e.contains("not found"), "{e}");

    // Missing file.
    let d = fresh("missing_file");
    std::fs::remove_file(d.join("sparse/0/points3D.txt")).unwrap();
    let e = import_err(&d, &args, &root());
    assert!(e.contains("points3D.txt"), "{e}");

    // Truncated binary model.
    let d = fresh("truncated");
    let m = augsplat_scene::colmap::ColmapModel::load(&d.join("sparse/0")).unwrap();
    for f in ["cameras.txt", "images.txt", "points3D.txt"] {
        std::fs::remove_file(d.join("sparse/0").join(f)).unwrap();
    }
    m.save_binary(&d.join("sparse/0")).unwrap();
    let p = d.join("sparse/0/images.bin");
    let bytes = std::fs::read(&p).unwrap();
    std::fs::write(&p, &bytes[..bytes.len() / 2]).unwrap();
    let e = import_err(&d, &args, &root());
    assert!(
        e.contains("images.bin") && e.contains("truncated") && e.contains("image entry"),
        "{e}"
    );

    // NaN in a pose.
    let d = fresh("nan");
    edit(&d.join("sparse/0/images.txt"), |l| {
        if l.starts_with("2 ") {
            let mut t: Vec<String> = l.split(' ').map(String::from).collect();
            t[5] = "nan".into();
            t.join(" ")
        } else {
            l.to_string()
        }
    });
    let e = import_err(&d, &args, &root());
    assert!(
        e.contains("images.txt") && e.contains("image 2") && e.contains("non-finite"),
        "{e}"
    );

    // Unknown camera model.
    let d = fresh("model");
    edit(&d.join("sparse/0/cameras.txt"), |l| {
        l.replace("PINHOLE", "THIN_PRISM_FISHEYE")
    });
    let e = import_err(&d, &args, &root());
    assert!(
        e.contains("cameras.txt") && e.contains("camera 1") && e.contains("THIN_PRISM_FISHEYE"),
        "{e}"
    );

    // An image whose size disagrees with its camera.
    let d = fresh("size");
    augsplat_core::image::write_png(
        &d.join("images/view_002.png"),
        &augsplat_core::ImageF32::new(10, 7, 3),
    )
    .unwrap();
    let e = import_err(&d, &args, &root());
    assert!(e.contains("view_002.png") && e.contains("10×7"), "{e}");

    // A non-image file.
    let d = fresh("notimage");
    std::fs::write(d.join("images/view_001.png"), b"this is not a PNG").unwrap();
    let e = import_err(&d, &args, &root());
    assert!(
        e.contains("view_001.png") && e.contains("not a readable image"),
        "{e}"
    );

    // A registered view whose photo is missing is an error by default...
    let d = fresh("one_missing");
    std::fs::remove_file(d.join("images/view_001.png")).unwrap();
    let e = import_err(&d, &args, &root());
    assert!(
        e.contains("view_001.png") && e.contains("allow_missing_images: true"),
        "{e}"
    );
    // ...and skipped (with the list on the terminal and in the log) when allowed.
    let allow = ImportSceneArgs {
        allow_missing_images: true,
        ..Default::default()
    };
    run_node::<ImportScene>(&allow, &[("source", &d)], &root(), 1).unwrap();

    // A truncated photo (its last rows missing) is an error, not rows of grey.
    let d = fresh("truncated_png");
    let p = d.join("images/view_002.png");
    let bytes = std::fs::read(&p).unwrap();
    std::fs::write(&p, &bytes[..bytes.len() * 2 / 3]).unwrap();
    let e = import_err(&d, &args, &root());
    assert!(e.contains("view_002.png") && e.contains("truncated"), "{e}");

    // Zero views left after filtering (every image missing).
    let d = fresh("noviews");
    std::fs::remove_dir_all(d.join("images")).unwrap();
    std::fs::create_dir_all(d.join("images")).unwrap();
    let e = import_err(&d, &args, &root());
    assert!(e.contains("no views left") && e.contains("sparse/0"), "{e}");

    // Path arguments must stay inside the source.
    let bad = ImportSceneArgs {
        model: Some("../elsewhere".into()),
        ..Default::default()
    };
    let e = import_err(&good, &bad, &root());
    assert!(e.contains("model"), "{e}");

    // Split and depth of a scene folder that is not one.
    let e = run_node::<SplitScene>(&SplitSceneArgs::default(), &[("scene", &good)], &root(), 1)
        .unwrap_err()
        .message()
        .to_string();
    assert!(e.contains("scene.json"), "{e}");
}

fn edit(path: &Path, f: impl Fn(&str) -> String) {
    let text = std::fs::read_to_string(path).unwrap();
    let out: Vec<String> = text.lines().map(f).collect();
    std::fs::write(path, out.join("\n") + "\n").unwrap();
}
