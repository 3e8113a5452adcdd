//! Tests on the real captures in ../shared/data (skipped with a message when absent).

mod common;

use augsplat_core::linalg;
use augsplat_core::Scene;
use augsplat_scene::import::{build_scene, ImportOptions};
use augsplat_scene::node::{read_source, ImportScene, ImportSceneArgs, SourceFormat};
use common::{data_dir, run_node};

fn bonsai_args(model: &str) -> ImportSceneArgs {
    ImportSceneArgs {
        format: SourceFormat::Colmap,
        model: Some(model.into()),
        images: Some("images".into()),
        ..Default::default()
    }
}

#[test]
fn bonsai_binary_and_text_models_give_identical_scenes() {
    let Some(d) = data_dir("bonsai_binary_and_text_models_give_identical_scenes") else {
        return;
    };
    let src = d.join("bonsai");
    let bin = read_source(&src, &bonsai_args("colmap30/sparse/0")).unwrap();
    let txt = read_source(&src, &bonsai_args("colmap30/sparse_txt")).unwrap();
    // The text model prints numbers with ~16 significant digits: identical up to that.
    let close = |a: f64, b: f64| (a - b).abs() <= 1e-12 * (1.0 + a.abs().max(b.abs()));
    assert_eq!(bin.views.len(), txt.views.len());
    for (a, b) in bin.views.iter().zip(&txt.views) {
        assert_eq!(
            (&a.name, &a.image_path, a.intrinsics.kind),
            (&b.name, &b.image_path, b.intrinsics.kind)
        );
        let (ia, ib) = (a.intrinsics, b.intrinsics);
        for (x, y) in [
            (ia.fx, ib.fx),
            (ia.fy, ib.fy),
            (ia.cx, ib.cx),
            (ia.cy, ib.cy),
            (ia.distortion.k1, ib.distortion.k1),
            (ia.distortion.p2, ib.distortion.p2),
        ] {
            assert!(close(x, y), "{}: {x} vs {y}", a.name);
        }
        for r in 0..4 {
            for c in 0..4 {
                assert!(
                    close(a.world_to_camera[r][c], b.world_to_camera[r][c]),
                    "{}",
                    a.name
                );
            }
        }
    }
    let (pb, pt) = (&bin.points, &txt.points);
    assert_eq!(pb.positions.len(), pt.positions.len());
    for i in 0..pb.positions.len() {
        for k in 0..3 {
            assert!(close(pb.positions[i][k], pt.positions[i][k]), "point {i}");
        }
        assert_eq!(pb.colors[i], pt.colors[i]);
        assert!(close(pb.errors[i], pt.errors[i]), "point {i}");
        assert_eq!(pb.tracks[i].len(), pt.tracks[i].len());
        for (oa, ob) in pb.tracks[i].iter().zip(&pt.tracks[i]) {
            assert_eq!(oa.view, ob.view);
            let (ka, kb) = (oa.keypoint.unwrap(), ob.keypoint.unwrap());
            assert!(close(ka[0], kb[0]) && close(ka[1], kb[1]), "point {i}");
        }
    }
    assert_eq!(bin.views.len(), 25);
    assert_eq!(bin.points.positions.len(), 6478);
    // The 5 photos COLMAP did not register are reported.
    let w = bin.warnings.join("\n");
    assert!(
        w.contains("5 of 30 photos") && w.contains("did not register"),
        "{w}"
    );
    let (sb, cb) = build_scene(&bin, &ImportOptions::default()).unwrap();
    let (st, ct) = build_scene(&txt, &ImportOptions::default()).unwrap();
    assert_eq!(sb.views, st.views);
    assert_eq!(
        (sb.near, sb.far, &sb.normalization),
        (st.near, st.far, &st.normalization)
    );
    assert_eq!(cb, ct);
    // Views are sorted by name and carry the undistorted pinhole intrinsics.
    let names: Vec<_> = sb.views.iter().map(|v| v.name.clone()).collect();
    let mut sorted = names.clone();
    sorted.sort();
    assert_eq!(names, sorted);
    let c = &sb.views[0].camera;
    assert_eq!((c.width, c.height), (800, 533));
    assert!((c.fx - 796.71).abs() < 0.01 && (c.fy - 794.41).abs() < 0.01);
    assert!((c.cx - 400.0).abs() < 1e-9 && (c.cy - 266.5).abs() < 1e-9);
}

#[test]
fn bonsai_inspect_reprojection_error_matches_colmap() {
    let Some(d) = data_dir("bonsai_inspect_reprojection_error_matches_colmap") else {
        return;
    };
    for (model, want, obs) in [
        ("bonsai/colmap30/sparse/0", 0.326190, 22916),
        ("bonsai/colmap30/sparse_txt", 0.326190, 22916),
        ("bonsai/colmap30_undistorted/sparse/0", 0.3305, 22916),
        ("bonsai/colmap98/sparse/0", 0.463099, 50918),
    ] {
        let r = augsplat_scene::inspect::inspect(&d.join(model)).unwrap();
        let e = r.mean_reprojection_error.unwrap();
        assert!((e - want).abs() < 0.01, "{model}: {e} vs {want}");
        assert!((e - want).abs() < 1e-4, "{model}: {e} vs {want} (tighter)");
        assert_eq!(r.observations, obs, "{model}");
    }
    let r = augsplat_scene::inspect::inspect(&d.join("bonsai/colmap30")).unwrap();
    assert_eq!((r.registered_images, r.points, r.cameras), (25, 6478, 1));
}

#[test]
fn bonsai_import_undistorts_and_points_reproject_below_one_pixel() {
    let Some(d) = data_dir("bonsai_import_undistorts_and_points_reproject_below_one_pixel") else {
        return;
    };
    let src = d.join("bonsai");
    let tmp = tempfile::tempdir().unwrap();
    let args = bonsai_args("colmap30/sparse/0");
    run_node::<ImportScene>(&args, &[("source", &src)], tmp.path(), 2).unwrap();
    let out = tmp.path().join("scene");
    let scene = Scene::load(&out).unwrap();
    let cloud = scene.load_points(&out).unwrap();
    assert_eq!(scene.views.len(), 25);
    assert_eq!(cloud.len(), 6478);
    // Reprojection against the undistorted images: undistort each keypoint with the source
    // camera, project the stored (normalised, f32) point with the scene's pinhole camera.
    let raw = read_source(&src, &args).unwrap();
    let (mut sum, mut n) = (0.0, 0usize);
    for (i, track) in raw.points.tracks.iter().enumerate() {
        let q = cloud.positions[i];
        let p = [q[0] as f64, q[1] as f64, q[2] as f64];
        let (mut s, mut k) = (0.0, 0);
        for o in track {
            let kp = o.keypoint.unwrap();
            let intr = &raw.views[o.view].intrinsics;
            let (ku, kv) = intr.undistort_pixel(kp[0], kp[1]).unwrap();
            let (u, v, z) = scene.views[o.view].camera.project(p);
            assert!(z > 0.0);
            s += ((u - ku).powi(2) + (v - kv).powi(2)).sqrt();
            k += 1;
        }
        sum += s / k as f64;
        n += 1;
    }
    let mean = sum / n as f64;
    assert!(
        mean < 1.0,
        "mean reprojection error after undistortion {mean}"
    );
    assert!(
        (mean - 0.3305).abs() < 0.002,
        "mean {mean} should match the 0.3305 px recomputed on COLMAP's own undistorted model"
    );
    // Our undistorted image is close to COLMAP's undistorted image, and closer than the
    // distorted original (JPEG re-encoding bounds how close).
    let name = &scene.views[3].name;
    let ours = scene.load_image(&out, 3).unwrap();
    let colmap = augsplat_core::image::read_rgb(
        &src.join(format!("colmap30_undistorted/images/{name}.JPG")),
    )
    .unwrap();
    let orig = augsplat_core::image::read_rgb(&src.join(format!("images/{name}.JPG"))).unwrap();
    let mad = |a: &augsplat_core::ImageF32, b: &augsplat_core::ImageF32| {
        // Interior only (COLMAP's border handling differs).
        let (w, h) = (a.width as usize, a.height as usize);
        let mut s = 0.0;
        let mut n = 0;
        for i in 20..h - 20 {
            for j in 20..w - 20 {
                for c in 0..3 {
                    let k = (i * w + j) * 3 + c;
                    s += (a.data[k] - b.data[k]).abs() as f64;
                    n += 1;
                }
            }
        }
        s / n as f64
    };
    let (to_colmap, to_orig) = (mad(&ours, &colmap), mad(&orig, &colmap));
    println!("{name}: mean abs diff to COLMAP's undistorted image {to_colmap:.5}, distorted original {to_orig:.5}; mean reprojection error after undistortion {mean:.5} px");
    assert!(
        to_colmap < 0.02,
        "mean abs diff to COLMAP's undistortion {to_colmap}"
    );
    assert!(
        to_colmap < 0.6 * to_orig,
        "ours {to_colmap} vs distorted {to_orig}"
    );
}

#[test]
fn fern_llff_imports_forward_facing() {
    let Some(d) = data_dir("fern_llff_imports_forward_facing") else {
        return;
    };
    let src = d.join("fern");
    let tmp = tempfile::tempdir().unwrap();
    let args = ImportSceneArgs {
        format: SourceFormat::Auto,
        downscale: 2,
        ..Default::default()
    };
    run_node::<ImportScene>(&args, &[("source", &src)], tmp.path(), 2).unwrap();
    let out = tmp.path().join("scene");
    let scene = Scene::load(&out).unwrap();
    assert_eq!(scene.views.len(), 20);
    assert!(!scene.has_points);
    // Intrinsics follow images_8 and the downscale: f = 3260.5 · 504/4032 / 2.
    let c = &scene.views[0].camera;
    assert_eq!((c.width, c.height), (252, 189));
    let img = scene.load_image(&out, 0).unwrap();
    assert_eq!((img.width, img.height), (252, 189));
    // Independent reading of the raw file for the expected values.
    let (shape, a) = augsplat_core::image::read_npy_array(&src.join("poses_bounds.npy")).unwrap();
    assert_eq!(shape, vec![20, 17]);
    let f_full = a[14];
    assert!(
        (c.fx - f_full * 504.0 / 4032.0 / 2.0).abs() < 1e-9,
        "{}",
        c.fx
    );
    // Forward-facing: every camera looks within ~25° of the mean direction.
    let mut mean = [0.0; 3];
    for v in &scene.views {
        mean = linalg::add(mean, v.camera.forward());
    }
    let mean = linalg::normalize(mean);
    for v in &scene.views {
        assert!(linalg::dot(v.camera.forward(), mean) > 0.9, "{}", v.name);
    }
    // The raw LLFF "back" axis (column 2) is minus our forward axis.
    for (i, v) in scene.views.iter().enumerate() {
        let back = [a[i * 17 + 2], a[i * 17 + 7], a[i * 17 + 12]];
        assert!(linalg::dot(linalg::normalize(back), v.camera.forward()) < -0.999);
    }
    // Centres on a shallow arc across the view direction: their spread along the viewing
    // direction is much smaller than across it.
    let centres: Vec<_> = scene.views.iter().map(|v| v.camera.center()).collect();
    let (mut along, mut across) = (0.0f64, 0.0f64);
    for c in &centres {
        let a = linalg::dot(*c, mean);
        along = along.max(a.abs());
        across = across.max(linalg::norm(linalg::sub(*c, linalg::scale(mean, a))));
    }
    assert!(along < 0.5 * across, "along {along} across {across}");
    // The scene lies in front of every camera, and near/far are the raw bounds scaled.
    let near_raw = (0..20)
        .map(|i| a[i * 17 + 15])
        .fold(f64::INFINITY, f64::min);
    let far_raw = (0..20).map(|i| a[i * 17 + 16]).fold(0.0, f64::max);
    let s = scene.normalization.scale;
    assert!(scene.near > 0.0 && scene.far > scene.near);
    assert!((scene.near - near_raw * s).abs() < 1e-9 && (scene.far - far_raw * s).abs() < 1e-9);
    // Farthest camera at distance 1 (camera normalisation).
    let far_cam = centres.iter().map(|c| linalg::norm(*c)).fold(0.0, f64::max);
    assert!((far_cam - 1.0).abs() < 1e-9);
}

#[test]
fn bonsai_split_keeps_only_points_seen_by_two_train_views() {
    let Some(d) = data_dir("bonsai_split_keeps_only_points_seen_by_two_train_views") else {
        return;
    };
    let raw = read_source(&d.join("bonsai"), &bonsai_args("colmap30/sparse/0")).unwrap();
    let (scene, cloud) = build_scene(&raw, &ImportOptions::default()).unwrap();
    let split = augsplat_scene::split::split_indices(scene.views.len(), Some(30), 8, 42).unwrap();
    assert_eq!((split.train.len(), split.test.len()), (21, 4));
    let (train, tp) = augsplat_scene::split::subset(&scene, &cloud, &split.train, 2);
    // Every kept point has ≥ 2 train views; every dropped point has < 2.
    let mut kept = 0;
    for i in 0..cloud.len() {
        let n_train = cloud
            .track(i)
            .iter()
            .filter(|t| split.train.contains(&(**t as usize)))
            .count();
        if n_train >= 2 {
            kept += 1;
        }
    }
    assert_eq!(tp.len(), kept);
    assert!(kept < cloud.len());
    for i in 0..tp.len() {
        assert!(tp.track(i).len() >= 2);
        assert!(tp
            .track(i)
            .iter()
            .all(|&t| (t as usize) < train.views.len()));
    }
}

/// Scenes without points or bounds take near/far from where the cameras' axes converge.
/// - dtu_scan24 without its points: the estimate brackets the median depth of the SfM
///   points (mostly on the object), instead of the defaults 0.05–100.
/// - bonsai (360° inward, most points on the room behind the subject): the estimate covers
///   the subject, within the points' range (with a more cautious near bound).
/// - fern (forward-facing, but its cameras turn towards the subject enough; LLFF bounds
///   removed): near within 25 % of the LLFF near bound, far inside the LLFF far bound.
#[test]
fn scenes_without_points_take_bounds_from_the_cameras() {
    let Some(d) = data_dir("scenes_without_points_take_bounds_from_the_cameras") else {
        return;
    };
    let check = |raw: augsplat_scene::source::RawScene, what: &str, object_centric: bool| {
        let (with, cloud) = build_scene(&raw, &ImportOptions::default()).unwrap();
        assert!(!cloud.is_empty());
        // The points' median depth over all their observations.
        let mut depths = Vec::new();
        for i in 0..cloud.len() {
            let p = cloud.positions[i].map(|v| v as f64);
            for &t in cloud.track(i) {
                depths.push(with.views[t as usize].camera.to_camera(p)[2]);
            }
        }
        depths.sort_by(f64::total_cmp);
        let median = depths[depths.len() / 2];
        let mut bare = raw;
        bare.points = Default::default();
        let (without, cloud) = build_scene(&bare, &ImportOptions::default()).unwrap();
        assert!(cloud.is_empty());
        println!(
            "{what}: with points {:.3}–{:.3}, from the cameras {:.3}–{:.3}, median point depth {median:.3}",
            with.near, with.far, without.near, without.far
        );
        assert!(
            without.near > 0.4 * with.near && without.far < with.far,
            "{what}: {:.3}–{:.3} is not within the points' range",
            without.near,
            without.far
        );
        if !object_centric {
            return;
        }
        assert!(
            without.near < median && median < without.far,
            "{what}: {:.3}–{:.3} misses the median point depth {median:.3}",
            without.near,
            without.far
        );
        assert!(
            without.near > 0.2 * median && without.far < 5.0 * median,
            "{what}"
        );
    };
    let dtu = ImportSceneArgs {
        format: SourceFormat::Colmap,
        model: Some("sparse/0".into()),
        images: Some("images".into()),
        ..Default::default()
    };
    check(
        read_source(&d.join("dtu_scan24"), &dtu).unwrap(),
        "dtu_scan24",
        true,
    );
    check(
        read_source(&d.join("bonsai"), &bonsai_args("colmap30/sparse/0")).unwrap(),
        "bonsai",
        false,
    );
    let fern = ImportSceneArgs {
        format: SourceFormat::Llff,
        images: Some("images_8".into()),
        ..Default::default()
    };
    let raw = read_source(&d.join("fern"), &fern).unwrap();
    let (with_bounds, _) = build_scene(&raw, &ImportOptions::default()).unwrap();
    let mut raw = raw;
    for v in &mut raw.views {
        v.bounds = None;
    }
    let (scene, _) = build_scene(&raw, &ImportOptions::default()).unwrap();
    println!(
        "fern: LLFF bounds {:.3}–{:.3}, from the cameras {:.3}–{:.3}",
        with_bounds.near, with_bounds.far, scene.near, scene.far
    );
    assert!(
        (scene.near / with_bounds.near - 1.0).abs() < 0.25
            && scene.far < with_bounds.far
            && scene.far > 2.0 * scene.near,
        "fern: {:.3}–{:.3} against the LLFF bounds {:.3}–{:.3}",
        scene.near,
        scene.far,
        with_bounds.near,
        with_bounds.far
    );
}
