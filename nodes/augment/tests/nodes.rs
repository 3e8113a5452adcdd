//! The augmentation nodes run on real folders: outputs, determinism across thread counts,
//! and clear errors on bad inputs.

use augsplat_augment::aggregate::{aggregate_view, AggregateParams, Workspace};
use augsplat_augment::node::ScenePosesArgs;
use augsplat_augment::node::{AggregateReport, AGGREGATE_REPORT, POSES_REPORT};
use augsplat_augment::poses::{PoseParams, PosesReport};
use augsplat_augment::{AggregateEnsemble, ScenePoses, SynthesizePoses};
use augsplat_core::artifacts::{self, files, PoseSet, RenderSet, RenderedView, SyntheticSet};
use augsplat_core::{image, Camera, Rng, Scene, SceneView};
use augsplat_graph::{Node, RunContext};
use std::path::{Path, PathBuf};

fn camera(i: usize, n: usize, w: u32, h: u32) -> Camera {
    let a = i as f64 / n as f64 * std::f64::consts::TAU;
    let eye = [3.0 * a.cos(), 0.2, 3.0 * a.sin()];
    augsplat_testkit::cameras::looking_at_origin(eye, w, h)
}

fn write_scene(dir: &Path, n: usize) {
    std::fs::create_dir_all(dir).unwrap();
    let scene = Scene {
        source: "test ring".into(),
        views: (0..n)
            .map(|i| SceneView {
                name: format!("img{i}"),
                image: format!("images/img{i}.png"),
                depth: None,
                camera: camera(i, n, 80, 60),
            })
            .collect(),
        near: 0.1,
        far: 10.0,
        normalization: Default::default(),
        has_points: false,
    };
    scene.save(dir).unwrap();
}

/// Member renders: a shared smooth image plus member-specific noise whose amplitude grows to
/// the right, so the variance (and weight) has structure.
fn write_members(root: &Path, m: usize, views: usize, w: u32, h: u32) -> Vec<PathBuf> {
    (0..m)
        .map(|k| {
            let dir = root.join(format!("member{k}"));
            std::fs::create_dir_all(&dir).unwrap();
            let mut rng = Rng::stream(11, k as u64);
            let mut set = RenderSet::default();
            for v in 0..views {
                let n = (w * h) as usize;
                let mut planes = vec![vec![0f32; n]; 5];
                for p in 0..n {
                    let x = (p % w as usize) as f32 / w as f32;
                    for (c, plane) in planes.iter_mut().take(3).enumerate() {
                        plane[p] = 0.3
                            + 0.2 * c as f32
                            + 0.1 * v as f32 * x
                            + x * 0.3 * (rng.next_f32() - 0.5);
                    }
                    planes[3][p] = 2.0;
                    planes[4][p] = 1.0;
                }
                let file = format!("view{v}.exr");
                image::write_exr(
                    &dir.join(&file),
                    w,
                    h,
                    &[
                        ("R", &planes[0]),
                        ("G", &planes[1]),
                        ("B", &planes[2]),
                        ("D", &planes[3]),
                        ("A", &planes[4]),
                    ],
                )
                .unwrap();
                set.views.push(RenderedView {
                    name: format!("syn{v:04}"),
                    camera: camera(v, views, w, h),
                    file,
                });
            }
            artifacts::write_json(&dir.join(files::RENDERS), &set).unwrap();
            dir
        })
        .collect()
}

fn run_in_pool<N: Node>(
    args: &N::Args,
    inputs: Vec<(String, Vec<PathBuf>)>,
    outputs: &[&str],
    root: &Path,
    threads: usize,
) -> Result<(), String> {
    let mut ctx = RunContext::standalone(inputs, outputs, root, 0, threads).unwrap();
    augsplat_testkit::with_threads(threads, || N::run(args, &mut ctx)).map_err(|e| e.to_string())
}

/// Every file under `dir` with its bytes, by relative path.
fn tree(dir: &Path) -> Vec<(String, Vec<u8>)> {
    let mut out = Vec::new();
    let mut stack = vec![dir.to_path_buf()];
    while let Some(d) = stack.pop() {
        for e in std::fs::read_dir(&d).unwrap() {
            let p = e.unwrap().path();
            if p.is_dir() {
                stack.push(p);
            } else {
                let rel = p.strip_prefix(dir).unwrap().display().to_string();
                out.push((rel, std::fs::read(&p).unwrap()));
            }
        }
    }
    out.sort();
    out
}

#[test]
fn synthesize_poses_writes_pose_set_and_report() {
    let tmp = tempfile::tempdir().unwrap();
    let scene = tmp.path().join("train");
    write_scene(&scene, 9);
    let args = PoseParams {
        count: 40,
        seed: 7,
        ..PoseParams::default()
    };
    let inputs = vec![("train".to_string(), vec![scene.clone()])];
    run_in_pool::<SynthesizePoses>(&args, inputs.clone(), &["poses"], &tmp.path().join("a"), 1)
        .unwrap();
    run_in_pool::<SynthesizePoses>(&args, inputs, &["poses"], &tmp.path().join("b"), 2).unwrap();
    let a = tree(&tmp.path().join("a/poses"));
    assert_eq!(a, tree(&tmp.path().join("b/poses")), "deterministic");
    let set: PoseSet =
        artifacts::read_json(&tmp.path().join("a/poses").join(files::POSES)).unwrap();
    assert_eq!(set.views.len(), 40);
    for v in &set.views {
        assert_eq!((v.camera.width, v.camera.height), (10, 8));
        assert!(v.origin.starts_with("jitter:img") || v.origin.starts_with("interp:img"));
    }
    let rep: PosesReport =
        artifacts::read_json(&tmp.path().join("a/poses").join(POSES_REPORT)).unwrap();
    assert_eq!(rep.drawn, 40);
    assert_eq!(rep.training_views, 9);
    assert!(rep.nearest_distance_rel.max <= 1.0);
    assert!(rep.nearest_view_angle_deg.max < 45.0);
}

#[test]
fn scene_poses_lists_every_view_at_the_asked_resolution() {
    let tmp = tempfile::tempdir().unwrap();
    let scene = tmp.path().join("test");
    write_scene(&scene, 3);
    for downscale in [1u32, 3] {
        let root = tmp.path().join(format!("o{downscale}"));
        run_in_pool::<ScenePoses>(
            &ScenePosesArgs { downscale },
            vec![("scene".to_string(), vec![scene.clone()])],
            &["poses"],
            &root,
            1,
        )
        .unwrap();
        let set: PoseSet = artifacts::read_json(&root.join("poses").join(files::POSES)).unwrap();
        assert_eq!(set.views.len(), 3);
        let stored = Scene::load(&scene).unwrap();
        for (i, v) in set.views.iter().enumerate() {
            let cam = &stored.views[i].camera;
            assert_eq!(v.name, format!("img{i}"));
            assert_eq!(v.origin, format!("scene:img{i}"));
            assert_eq!(v.camera.world_to_camera, cam.world_to_camera);
            assert_eq!(
                (v.camera.width, v.camera.height),
                (80u32.div_ceil(downscale), 60u32.div_ceil(downscale))
            );
            let (sx, sy) = (v.camera.width as f64 / 80.0, v.camera.height as f64 / 60.0);
            assert!(
                (v.camera.fx - cam.fx * sx).abs() < 1e-9
                    && (v.camera.fy - cam.fy * sy).abs() < 1e-9
            );
        }
    }
    // Bad inputs: a zero downscale is rejected before running; an empty scene names its file.
    assert!(ScenePoses::validate(&ScenePosesArgs { downscale: 0 }).is_err());
    let empty = tmp.path().join("empty");
    write_scene(&empty, 0);
    let err = run_in_pool::<ScenePoses>(
        &ScenePosesArgs::default(),
        vec![("scene".to_string(), vec![empty])],
        &["poses"],
        &tmp.path().join("oe"),
        1,
    )
    .unwrap_err();
    assert!(
        err.contains("scene.json") && err.contains("no views"),
        "{err}"
    );
}

#[test]
fn synthesize_poses_reports_a_broken_scene() {
    let tmp = tempfile::tempdir().unwrap();
    let scene = tmp.path().join("train");
    std::fs::create_dir_all(&scene).unwrap();
    std::fs::write(scene.join("scene.json"), "{ not json").unwrap();
    let err = run_in_pool::<SynthesizePoses>(
        &PoseParams::default(),
        vec![("train".to_string(), vec![scene])],
        &["poses"],
        &tmp.path().join("o"),
        1,
    )
    .unwrap_err();
    assert!(err.contains("scene.json"), "{err}");
}

#[test]
fn aggregate_is_bit_identical_across_threads_and_matches_kernel() {
    let tmp = tempfile::tempdir().unwrap();
    let (w, h) = (17, 11);
    let members = write_members(tmp.path(), 4, 5, w, h);
    let args = AggregateParams {
        blur: Some(3),
        floor: Some(0.1),
        ..AggregateParams::default()
    };
    let inputs = vec![("members".to_string(), members.clone())];
    run_in_pool::<AggregateEnsemble>(
        &args,
        inputs.clone(),
        &["synthetic"],
        &tmp.path().join("a"),
        1,
    )
    .unwrap();
    run_in_pool::<AggregateEnsemble>(&args, inputs, &["synthetic"], &tmp.path().join("b"), 2)
        .unwrap();
    let out = tmp.path().join("a/synthetic");
    assert_eq!(tree(&out), tree(&tmp.path().join("b/synthetic")));
    let set: SyntheticSet = artifacts::read_json(&out.join(files::SYNTHETIC)).unwrap();
    assert_eq!(set.views.len(), 5);
    let report: AggregateReport = artifacts::read_json(&out.join(AGGREGATE_REPORT)).unwrap();
    assert_eq!(report.members, 4);
    for (i, v) in set.views.iter().enumerate() {
        assert_eq!(v.name, format!("syn{i:04}"));
        assert!(out
            .join(format!("previews/{}_target.png", v.name))
            .is_file());
        assert!(out
            .join(format!("previews/{}_weight.png", v.name))
            .is_file());
        // The files hold exactly what the kernel computes from the members' RGB.
        let planes: Vec<Vec<f32>> = members
            .iter()
            .map(|d| {
                let e = image::read_exr(&d.join(format!("view{i}.exr"))).unwrap();
                ["R", "G", "B"]
                    .iter()
                    .flat_map(|c| e.channel(c).unwrap().to_vec())
                    .collect()
            })
            .collect();
        let refs: Vec<&[f32]> = planes.iter().map(|p| p.as_slice()).collect();
        let agg = aggregate_view(
            &refs,
            w as usize,
            h as usize,
            &args,
            &mut Workspace::default(),
        );
        let t = image::read_exr(&out.join(&v.target)).unwrap();
        let n = (w * h) as usize;
        assert_eq!(t.channel("R").unwrap(), &agg.target[..n]);
        assert_eq!(t.channel("B").unwrap(), &agg.target[2 * n..]);
        let px = v.read(&out).unwrap();
        assert_eq!(px.weight, agg.weight);
        let sum: f64 = agg.weight.iter().map(|&x| x as f64).sum();
        assert!((v.weight_sum - sum).abs() < 1e-9);
        assert!(agg.weight.iter().all(|&x| (0.1..=1.0).contains(&x)));
        // Noise grows to the right, so the left column is more trusted than the right one.
        let col_mean = |x: usize| {
            (0..h as usize)
                .map(|y| agg.weight[y * w as usize + x])
                .sum::<f32>()
        };
        assert!(col_mean(0) > col_mean(w as usize - 1));
    }
}

#[test]
fn aggregate_rejects_mismatched_members_and_bad_values() {
    let tmp = tempfile::tempdir().unwrap();
    let a = write_members(&tmp.path().join("a"), 2, 3, 8, 6);
    let b = write_members(&tmp.path().join("b"), 1, 2, 8, 6);
    let err = run_in_pool::<AggregateEnsemble>(
        &AggregateParams::default(),
        vec![("members".to_string(), vec![a[0].clone(), b[0].clone()])],
        &["synthetic"],
        &tmp.path().join("o1"),
        1,
    )
    .unwrap_err();
    assert!(err.contains("member 1") && err.contains("2 views"), "{err}");
    // A NaN in one render: the error names the file and the pixel.
    let n = 48;
    let mut r = vec![0.5f32; n];
    r[9] = f32::NAN;
    let ones = vec![1.0f32; n];
    image::write_exr(
        &a[1].join("view2.exr"),
        8,
        6,
        &[
            ("R", &r),
            ("G", &ones),
            ("B", &ones),
            ("D", &ones),
            ("A", &ones),
        ],
    )
    .unwrap();
    let err = run_in_pool::<AggregateEnsemble>(
        &AggregateParams::default(),
        vec![("members".to_string(), a.clone())],
        &["synthetic"],
        &tmp.path().join("o2"),
        2,
    )
    .unwrap_err();
    assert!(err.contains("view2.exr") && err.contains("(1, 1)"), "{err}");
}

#[test]
fn single_member_gives_weight_one() {
    let tmp = tempfile::tempdir().unwrap();
    let a = write_members(tmp.path(), 1, 2, 8, 6);
    run_in_pool::<AggregateEnsemble>(
        &AggregateParams {
            blur: Some(9),
            ..AggregateParams::default()
        },
        vec![("members".to_string(), a)],
        &["synthetic"],
        &tmp.path().join("o"),
        1,
    )
    .unwrap();
    let out = tmp.path().join("o/synthetic");
    let set: SyntheticSet = artifacts::read_json(&out.join(files::SYNTHETIC)).unwrap();
    for v in &set.views {
        let px = v.read(&out).unwrap();
        assert!(px.weight.iter().all(|&x| x == 1.0));
        assert_eq!(v.weight_sum, 48.0);
    }
}

#[test]
fn args_parse_from_ron_with_defaults_and_reject_typos() {
    let mut registry = augsplat_graph::Registry::new();
    augsplat_augment::register(&mut registry);
    let poses = registry.get("SynthesizePoses").expect("registered");
    let args = poses
        .parse_args("(count: 50, jitter: (copies: 10), interpolation: (fractions: [0.5]))")
        .unwrap();
    let json = poses.args_json(&args);
    assert_eq!(json["count"], 50);
    assert_eq!(json["jitter"]["copies"], 10);
    assert_eq!(json["jitter"]["yaw_deg"], 10.0);
    assert_eq!(json["interpolation"]["neighbours"], 3);
    assert_eq!(json["downscale"], 8);
    let err = poses.parse_args("(jitter: (yaw: 3.0))").unwrap_err();
    assert!(err.path.contains("jitter"), "{err:?}");
    // Default-vs-explicit does not change the canonical encoding (hence the key).
    let a = poses.parse_args("()").unwrap();
    let b = poses.parse_args("(count: 200, downscale: 8)").unwrap();
    assert_eq!(poses.canonical_args(&a), poses.canonical_args(&b));

    let agg = registry.get("AggregateEnsemble").expect("registered");
    let args = agg
        .parse_args("(gamma: 2.0, blur: Some(9), floor: Some(0.1))")
        .unwrap();
    assert!(agg.validate(&args).is_ok());
    let json = agg.args_json(&args);
    assert_eq!(json["percentiles"], serde_json::json!([5.0, 95.0]));
    let bad = agg.parse_args("(blur: Some(4))").unwrap();
    assert!(agg.validate(&bad).unwrap_err().contains("odd"));
}
