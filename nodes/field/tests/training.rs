//! End-to-end training on the generated scene: determinism across thread counts and seeds,
//! held-out quality against a constant-colour baseline, and the effect of the depth loss.
#![allow(clippy::needless_range_loop)]

mod common;

use augsplat_core::artifacts::{read_json, PoseSet, PoseView, RenderSet, TrainingCurve};
use augsplat_field::node::{RenderFieldArgs, TrainFieldArgs};
use augsplat_field::{RenderField, TrainField};
use augsplat_graph::{Node, RunContext};
use std::path::{Path, PathBuf};

fn quick_args(seed: u64, steps: u32) -> TrainFieldArgs {
    TrainFieldArgs {
        seed,
        steps,
        rays_per_step: 256,
        chunk_rays: 32,
        levels: 8,
        log2_table_size: 14,
        base_resolution: 8,
        max_resolution: 256,
        hidden_width: 32,
        march_steps: 96,
        occupancy_resolution: 32,
        occupancy_warmup: 64,
        eval_every: 50,
        learning_rate: 1e-2,
        ..TrainFieldArgs::default()
    }
}

fn train(root: &Path, out: &Path, args: &TrainFieldArgs, threads: usize) -> PathBuf {
    let mut ctx = RunContext::standalone(
        vec![
            ("train".into(), vec![root.join("train")]),
            ("test".into(), vec![root.join("test")]),
        ],
        &["weights"],
        out,
        args.seed,
        threads,
    )
    .unwrap();
    TrainField::validate(args).unwrap();
    let pool = rayon::ThreadPoolBuilder::new()
        .num_threads(threads)
        .build()
        .unwrap();
    pool.install(|| TrainField::run(args, &mut ctx)).unwrap();
    out.join("weights")
}

fn render(weights: &Path, poses: &Path, out: &Path, threads: usize) -> PathBuf {
    let mut ctx = RunContext::standalone(
        vec![
            ("weights".into(), vec![weights.to_path_buf()]),
            ("poses".into(), vec![poses.to_path_buf()]),
        ],
        &["renders"],
        out,
        0,
        threads,
    )
    .unwrap();
    let args = RenderFieldArgs {
        chunk_rays: 97,
        ..Default::default()
    };
    let pool = rayon::ThreadPoolBuilder::new()
        .num_threads(threads)
        .build()
        .unwrap();
    pool.install(|| RenderField::run(&args, &mut ctx)).unwrap();
    out.join("renders")
}

fn dir_bytes(dir: &Path) -> Vec<(String, Vec<u8>)> {
    let mut v: Vec<(String, Vec<u8>)> = std::fs::read_dir(dir)
        .unwrap()
        .map(|e| e.unwrap().path())
        .filter(|p| p.is_file())
        .map(|p| {
            (
                p.file_name().unwrap().to_string_lossy().into_owned(),
                std::fs::read(&p).unwrap(),
            )
        })
        .collect();
    v.sort();
    v
}

fn write_poses(dir: &Path, cams: &[augsplat_core::Camera]) -> PathBuf {
    let p = dir.join("poses");
    std::fs::create_dir_all(&p).unwrap();
    let set = PoseSet {
        views: cams
            .iter()
            .enumerate()
            .map(|(i, c)| PoseView {
                name: format!("p{i}"),
                camera: c.clone(),
                origin: "test".into(),
            })
            .collect(),
    };
    augsplat_core::artifacts::write_json(&p.join("poses.json"), &set).unwrap();
    p
}

#[test]
fn same_seed_is_bit_identical_across_threads_and_seeds_differ() {
    let tmp = tempfile::tempdir().unwrap();
    let root = tmp.path();
    let (_, test) = common::split_scene(root, 8, 24, 18, 0.05);
    let mut args = quick_args(11, 24);
    args.occupancy_warmup = 4; // exercise occupancy updates too
    args.appearance_embedding = true;
    args.distortion_loss_weight = 0.01;
    let w1 = train(root, &root.join("a"), &args, 1);
    let w2 = train(root, &root.join("b"), &args, 2);
    assert_eq!(
        dir_bytes(&w1),
        dir_bytes(&w2),
        "weights differ between 1 and 2 threads"
    );
    args.seed = 12;
    let w3 = train(root, &root.join("c"), &args, 2);
    let a = dir_bytes(&w1);
    let c = dir_bytes(&w3);
    let st = |v: &[(String, Vec<u8>)]| {
        v.iter()
            .find(|(n, _)| n == "field.safetensors")
            .unwrap()
            .1
            .clone()
    };
    assert_ne!(st(&a), st(&c), "different seeds gave the same weights");
    let poses = write_poses(root, &test);
    let r1 = render(&w1, &poses, &root.join("r1"), 1);
    let r2 = render(&w1, &poses, &root.join("r2"), 2);
    assert_eq!(
        dir_bytes(&r1),
        dir_bytes(&r2),
        "renders differ between 1 and 2 threads"
    );
    let set: RenderSet = read_json(&r1.join("renders.json")).unwrap();
    assert_eq!(set.views.len(), test.len());
    // Views render in parallel: each file holds its own pose's image, in the poses' order.
    let loaded = augsplat_field::io::load(&w1).unwrap();
    for (i, (view, cam)) in set.views.iter().zip(&test).enumerate() {
        assert_eq!(
            (view.name.as_str(), view.file.as_str()),
            (
                format!("p{i}").as_str(),
                format!("view_{i:04}.exr").as_str()
            )
        );
        let alone = augsplat_field::train::render_camera(
            &loaded.field,
            &loaded.params,
            &loaded.occupancy,
            cam,
            loaded.meta.background,
            RenderFieldArgs::default().chunk_rays as usize,
        );
        let exr = augsplat_core::image::read_exr(&r2.join(&view.file)).unwrap();
        let red: Vec<f32> = alone.rgb.iter().step_by(3).copied().collect();
        assert_eq!(exr.channel("R").unwrap(), &red[..], "view {i}");
        assert_eq!(exr.channel("D").unwrap(), &alone.depth[..], "view {i}");
    }
    let exr = augsplat_core::image::read_exr(&r1.join(&set.views[0].file)).unwrap();
    let mut names = exr.names();
    names.sort();
    assert_eq!(names, vec!["A", "B", "D", "G", "R"]);
    assert!(exr
        .channels
        .iter()
        .all(|(_, v)| v.iter().all(|x| x.is_finite())));
}

fn mean_psnr_constant_baseline(root: &Path) -> f64 {
    // The best constant colour (mean of the training images) evaluated on the test images.
    let load = |d: &Path| {
        let s = augsplat_core::Scene::load(d).unwrap();
        (0..s.views.len())
            .map(|i| s.load_image(d, i).unwrap())
            .collect::<Vec<_>>()
    };
    let train = load(&root.join("train"));
    let test = load(&root.join("test"));
    let mut mean = [0f64; 3];
    let mut n = 0f64;
    for im in &train {
        for p in im.data.chunks(3) {
            for k in 0..3 {
                mean[k] += p[k] as f64;
            }
            n += 1.0;
        }
    }
    let mean = mean.map(|v| v / n);
    let mut ps = 0.0;
    for im in &test {
        let mse: f64 = im
            .data
            .chunks(3)
            .map(|p| (0..3).map(|k| (p[k] as f64 - mean[k]).powi(2)).sum::<f64>())
            .sum::<f64>()
            / im.data.len() as f64;
        ps += 10.0 * (1.0 / mse).log10();
    }
    ps / test.len() as f64
}

#[test]
fn short_run_beats_constant_colour_baseline() {
    let tmp = tempfile::tempdir().unwrap();
    let root = tmp.path();
    common::split_scene(root, 24, 64, 48, 0.0);
    let baseline = mean_psnr_constant_baseline(root);
    let mut args = quick_args(1, 200);
    args.eval_every = 100;
    let start = std::time::Instant::now();
    let w = train(root, &root.join("run"), &args, 2);
    let curve: TrainingCurve = read_json(&w.join("curve.json")).unwrap();
    let last = curve.points.last().unwrap();
    eprintln!(
        "baseline {baseline:.2} dB; curve {:?}; {:.1} s",
        curve
            .points
            .iter()
            .map(|p| (p.step, (p.psnr * 100.0).round() / 100.0))
            .collect::<Vec<_>>(),
        start.elapsed().as_secs_f64()
    );
    assert!(
        last.psnr > baseline + 5.0,
        "held-out PSNR {:.2} vs constant baseline {baseline:.2}",
        last.psnr
    );
    assert!(
        curve.points.first().unwrap().loss > last.loss,
        "training loss did not decrease"
    );
}

/// Median relative error `|d − z| / z` of rendered depth (optical axis) against the exact
/// depth on the given cameras.
fn depth_error(weights: &Path, cams: &[augsplat_core::Camera]) -> f64 {
    let f = augsplat_field::io::load(weights).unwrap();
    let mut errs = Vec::new();
    for cam in cams {
        let img = augsplat_field::train::render_camera(
            &f.field,
            &f.params,
            &f.occupancy,
            cam,
            [0.0; 3],
            1024,
        );
        let (_, exact) = common::render(cam);
        for (d, z) in img.depth.iter().zip(&exact) {
            errs.push(((*d as f64 - *z as f64) / *z as f64).abs());
        }
    }
    errs.sort_by(|a, b| a.total_cmp(b));
    errs[errs.len() / 2]
}

#[test]
fn depth_loss_reduces_depth_error() {
    let tmp = tempfile::tempdir().unwrap();
    let root = tmp.path();
    let (train_cams, test_cams) = common::split_scene(root, 8, 48, 36, 0.05);
    let mut args = quick_args(3, 120);
    args.eval_every = 0;
    args.depth_loss_weight = 0.0;
    let plain = train(root, &root.join("plain"), &args, 2);
    args.depth_loss_weight = 0.3;
    let with_depth = train(root, &root.join("depth"), &args, 2);
    let all: Vec<_> = train_cams.iter().chain(&test_cams).cloned().collect();
    let (e0, e1) = (depth_error(&plain, &all), depth_error(&with_depth, &all));
    eprintln!("median relative depth error: without depth loss {e0:.4}, with {e1:.4}");
    assert!(
        e1 < 0.8 * e0,
        "depth loss did not reduce the depth error enough ({e1:.4} vs {e0:.4})"
    );
}

/// Stress: absurd parameters, a learning-rate spike, rays that see nothing. Outcome: finite
/// outputs, or a clear divergence error — never NaN weights or a panic.
#[test]
fn stress_inputs_stay_finite_or_fail_cleanly() {
    use augsplat_field::field::{ChunkState, Field, RayInput};
    use augsplat_field::occupancy::OccupancyGrid;
    let tmp = tempfile::tempdir().unwrap();
    let root = tmp.path();
    common::split_scene(root, 8, 16, 12, 0.2);
    // A learning-rate spike with huge depth and distortion weights.
    let mut args = quick_args(5, 12);
    args.learning_rate = 1.0;
    args.depth_loss_weight = 1e6;
    args.distortion_loss_weight = 1e6;
    args.occupancy_warmup = 2;
    let mut ctx = RunContext::standalone(
        vec![("train".into(), vec![root.join("train")])],
        &["weights"],
        &root.join("spike"),
        5,
        2,
    )
    .unwrap();
    match TrainField::run(&args, &mut ctx) {
        Ok(()) => {
            let f = augsplat_field::io::load(&root.join("spike/weights")).unwrap();
            assert!(f.params.iter().all(|p| p.is_finite()));
        }
        Err(e) => assert!(
            e.message().contains("diverged"),
            "unexpected error: {}",
            e.message()
        ),
    }
    // Huge and NaN parameters: renders stay finite.
    let cfg = TrainFieldArgs {
        levels: 4,
        log2_table_size: 10,
        max_resolution: 64,
        hidden_width: 16,
        ..quick_args(0, 1)
    };
    let scene = augsplat_core::Scene::load(&root.join("train")).unwrap();
    let field = Field::new(cfg.field_config(&scene, scene.views.len()).unwrap()).unwrap();
    let cam = &scene.views[0].camera;
    for fill in [1e30f32, -1e30, f32::NAN, f32::INFINITY] {
        let mut params = field.init_params(1);
        for (i, p) in params.iter_mut().enumerate() {
            if i % 3 == 0 {
                *p = fill;
            }
        }
        let img = augsplat_field::train::render_camera(
            &field,
            &params,
            &OccupancyGrid::full(8),
            cam,
            [0.2; 3],
            50,
        );
        assert!(
            img.rgb
                .iter()
                .chain(&img.depth)
                .chain(&img.acc)
                .all(|v| v.is_finite()),
            "fill {fill}"
        );
    }
    // An empty occupancy grid: every ray misses; the output is the background.
    let params = field.init_params(1);
    let mut occ = OccupancyGrid::full(8);
    occ.occupied.iter_mut().for_each(|o| *o = 0);
    let mut st = ChunkState::default();
    let rays = [RayInput {
        origin: [0.0, 0.0, -1.0],
        dir: [0.0, 0.0, 1.0],
        image: 0,
        background: [0.1, 0.2, 0.3],
    }];
    field.forward_chunk(&params, &occ, &rays, &|_| 0.5, &[], &mut st);
    assert_eq!(st.n(), 0);
    assert_eq!(st.out[0].rgb, [0.1, 0.2, 0.3]);
    let mut grad = vec![0f32; field.n_params - field.density_offset];
    field.backward_chunk(&params, &rays, &mut st, &mut grad);
    assert!(grad.iter().all(|g| *g == 0.0));
}

/// Field training continued from any of its checkpoints ends with the same parameters,
/// occupancy grid and curve, bit for bit, as the run that never stopped; through the node, a
/// run finding a checkpoint in its folder continues from it with the same weights file.
#[test]
fn training_continued_from_a_checkpoint_is_bit_identical() {
    use augsplat_field::field::Field;
    use augsplat_field::train::{self, FieldCheckpoints};
    let tmp = tempfile::tempdir().unwrap();
    let root = tmp.path();
    common::split_scene(root, 8, 24, 18, 0.05);
    let mut args = quick_args(5, 30);
    args.occupancy_warmup = 4; // occupancy updates before and after the checkpoints
    args.eval_every = 10;
    let (scene, views) = train::load_views(&root.join("train"), args.downscale).unwrap();
    let test = train::load_views(&root.join("test"), args.downscale)
        .unwrap()
        .1;
    let field = Field::new(args.field_config(&scene, views.len()).unwrap()).unwrap();
    let opts = args.options();
    let run = |resume: Option<Vec<u8>>, saved: &mut Vec<Vec<u8>>, log: &mut Vec<String>| {
        let mut save = |b: Vec<u8>| {
            saved.push(b);
            Ok(())
        };
        let mut log_line = |l: String| log.push(l);
        train::train_resumable(
            &field,
            &views,
            Some(&test),
            &opts,
            Some(FieldCheckpoints {
                every: 8,
                resume,
                save: &mut save,
                log: &mut log_line,
            }),
            &mut |_| {},
        )
        .unwrap()
    };
    let mut saved = Vec::new();
    let (full, full_curve) = run(None, &mut saved, &mut Vec::new());
    assert_eq!(saved.len(), 3, "checkpoints at steps 8, 16 and 24");
    let bits = |v: &[f32]| v.iter().map(|x| x.to_bits()).collect::<Vec<_>>();
    for (i, ckpt) in saved.clone().into_iter().enumerate() {
        let (mut again, mut log) = (Vec::new(), Vec::new());
        let (st, curve) = run(Some(ckpt), &mut again, &mut log);
        assert_eq!(
            log[0],
            format!("resumed from the checkpoint at step {}", 8 * (i + 1))
        );
        assert_eq!(bits(&st.params), bits(&full.params), "checkpoint {i}");
        assert_eq!(bits(&st.occupancy.ema), bits(&full.occupancy.ema));
        assert_eq!(st.occupancy.occupied, full.occupancy.occupied);
        assert_eq!(curve, full_curve);
        assert_eq!(again, saved[i + 1..].to_vec());
    }
    // Through the node and the engine's checkpoint folder.
    let node = |args: &TrainFieldArgs, ckpt: &Path, out: &str| {
        let mut ctx = RunContext::standalone(
            vec![
                ("train".into(), vec![root.join("train")]),
                ("test".into(), vec![root.join("test")]),
            ],
            &["weights"],
            &root.join(out),
            args.seed,
            2,
        )
        .unwrap()
        .with_checkpoints(ckpt.to_path_buf(), 8);
        TrainField::run(args, &mut ctx).unwrap();
        root.join(out).join("weights")
    };
    let ckpt = root.join("ckpt");
    let a = node(&args, &ckpt, "a");
    assert!(ckpt.join("state.ckpt").is_file());
    let b = node(&args, &ckpt, "b");
    assert_eq!(dir_bytes(&a), dir_bytes(&b));
    // A checkpoint in the node's own folder is read: one that another seed's run left there
    // changes the weights. The same bytes moved into another computation's folder are
    // ignored (checkpoints carry the key they were made for: here, their folder).
    let mut other = args.clone();
    other.seed = 6;
    let shared = root.join("shared");
    node(&other, &shared, "o");
    let moved = root.join("moved");
    std::fs::create_dir_all(&moved).unwrap();
    std::fs::copy(shared.join("state.ckpt"), moved.join("state.ckpt")).unwrap();
    let d = node(&args, &shared, "d");
    assert_ne!(dir_bytes(&a), dir_bytes(&d), "the checkpoint was not read");
    let e = node(&args, &moved, "e");
    assert_eq!(dir_bytes(&a), dir_bytes(&e), "a moved checkpoint was read");
    // A checkpoint made for a longer run (step 56 of 60) is refused: the node starts afresh
    // and stores what an uninterrupted run stores.
    let mut longer = args.clone();
    longer.steps = 60;
    let long_dir = root.join("long");
    node(&longer, &long_dir, "l");
    let f = node(&args, &long_dir, "f");
    assert_eq!(
        dir_bytes(&a),
        dir_bytes(&f),
        "a longer run's checkpoint was used"
    );
}
