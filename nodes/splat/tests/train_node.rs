//! The OptimizeSplats node on a tiny generated scene: outputs, byte-identical results for 1
//! and 2 threads, synthetic input handling, errors, LPIPS selection when weights exist.

#![allow(clippy::needless_range_loop)]

mod train_util;

use augsplat_core::artifacts::{self, SyntheticSet, SyntheticView, TrainingCurve};
use augsplat_core::image::read_rgb;
use augsplat_core::Scene;
use augsplat_graph::{Node, RunContext};
use augsplat_splat::node::BestRecord;
use augsplat_splat::train::{Schedule, TrainArgs};
use augsplat_splat::OptimizeSplats;
use std::path::{Path, PathBuf};

fn run_node(
    args: &TrainArgs,
    inputs: Vec<(&str, &Path)>,
    out: &Path,
    threads: usize,
) -> Result<PathBuf, String> {
    let inputs = inputs
        .into_iter()
        .map(|(n, p)| (n.to_string(), vec![p.to_path_buf()]))
        .collect();
    let mut ctx = RunContext::standalone(inputs, &["model"], out, 0, threads).unwrap();
    let pool = rayon::ThreadPoolBuilder::new()
        .num_threads(threads)
        .build()
        .unwrap();
    pool.install(|| OptimizeSplats::run(args, &mut ctx))
        .map_err(|e| e.to_string())?;
    Ok(out.join("model"))
}

fn small_args() -> TrainArgs {
    TrainArgs {
        steps: 20,
        eval_every: 10,
        sh_degree: 1,
        sh_increase_every: 10,
        ..Default::default()
    }
}

/// The Dual schedule of the tiny tests (D = 10 steps, off below 0.1, 2 synthetic views).
fn small_dual() -> Schedule {
    Schedule::Dual {
        w_nerf0: 2.0,
        w_real: 1.0,
        quarter_decay: 10.0,
        off_below: Some(0.1),
        synthetic_batch: 2,
        reset_at_off: false,
    }
}

/// A SyntheticSet made from the training views at half resolution, weights from a ramp.
fn make_synthetic(train: &Path, dir: &Path) {
    SyntheticSet::create_folders(dir).unwrap();
    let scene = Scene::load(train).unwrap();
    let mut set = SyntheticSet::default();
    for v in scene.views.iter().take(4) {
        let img = read_rgb(&train.join(&v.image)).unwrap().downscale(2);
        let cam = v.camera.resized(img.width, img.height);
        let w = img.width;
        let planar: Vec<f32> = (0..3).flat_map(|c| img.channel(c)).collect();
        let weight: Vec<f32> = (0..w * img.height)
            .map(|p| (p % w) as f32 / w as f32)
            .collect();
        set.views
            .push(SyntheticView::write(dir, &v.name, &cam, &planar, &weight).unwrap());
    }
    artifacts::write_json(&dir.join(artifacts::files::SYNTHETIC), &set).unwrap();
}

#[test]
fn node_writes_model_and_is_byte_identical_for_1_and_2_threads() {
    let tmp = tempfile::tempdir().unwrap();
    let (train, test) = train_util::make_scene(tmp.path(), 48, 40, 9, 300);
    let args = small_args();
    let a = run_node(
        &args,
        vec![("train", &train), ("test", &test)],
        &tmp.path().join("o1"),
        1,
    )
    .unwrap();
    let b = run_node(
        &args,
        vec![("train", &train), ("test", &test)],
        &tmp.path().join("o2"),
        2,
    )
    .unwrap();
    for f in ["final.ply", "best.ply", "curve.json", "best.json"] {
        let x = std::fs::read(a.join(f)).unwrap();
        let y = std::fs::read(b.join(f)).unwrap();
        assert!(x == y, "{f} differs between 1 and 2 threads");
    }
    let curve: TrainingCurve = artifacts::read_json(&a.join("curve.json")).unwrap();
    assert_eq!(curve.label, "3DGS");
    assert_eq!(
        curve.points.iter().map(|p| p.step).collect::<Vec<_>>(),
        vec![10, 20]
    );
    assert!(curve.points.iter().all(|p| p.psnr.is_finite()
        && p.ssim.is_finite()
        && p.primitives > 0
        && p.lpips.is_none()));
    assert!(
        curve.points.iter().all(|p| p.seconds == 0.0),
        "wall time is off by default"
    );
    let best: BestRecord = artifacts::read_json(&a.join("best.json")).unwrap();
    assert_eq!(best.criterion, "psnr");
    let max = curve.points.iter().map(|p| p.psnr).fold(f64::MIN, f64::max);
    assert_eq!(best.point.psnr, max);
    assert_eq!(best.steps_run, 20);
    let g = augsplat_splat::read_ply(&a.join("final.ply")).unwrap();
    assert_eq!(g.len() as u64, curve.points[1].primitives);
}

#[test]
fn node_runs_dual_with_synthetic_input_and_rejects_missing_synthetic() {
    let tmp = tempfile::tempdir().unwrap();
    let (train, test) = train_util::make_scene(tmp.path(), 48, 40, 9, 300);
    let mut args = small_args();
    args.schedule = Schedule::Staged {
        warmup_steps: 5,
        synthetic_batch: 2,
        reset_at_switch: true,
    };
    let err = run_node(
        &args,
        vec![("train", &train), ("test", &test)],
        &tmp.path().join("o0"),
        1,
    )
    .unwrap_err();
    assert!(err.contains("synthetic"), "{err}");
    let syn = tmp.path().join("syn");
    make_synthetic(&train, &syn);
    args.schedule = small_dual();
    args.synthetic.skip_below = 0.25;
    args.label = "dual-test".into();
    let m = run_node(
        &args,
        vec![("train", &train), ("test", &test), ("synthetic", &syn)],
        &tmp.path().join("o1"),
        2,
    )
    .unwrap();
    let curve: TrainingCurve = artifacts::read_json(&m.join("curve.json")).unwrap();
    assert_eq!(curve.label, "dual-test");
    assert!(curve
        .points
        .iter()
        .all(|p| p.loss.is_finite() && p.loss > 0.0));
    // A broken synthetic index is a clear error naming the file.
    std::fs::write(syn.join("synthetic.json"), "{").unwrap();
    let err = run_node(
        &args,
        vec![("train", &train), ("test", &test), ("synthetic", &syn)],
        &tmp.path().join("o2"),
        1,
    )
    .unwrap_err();
    assert!(err.contains("synthetic.json"), "{err}");
}

#[test]
fn node_selects_by_average_error_when_lpips_weights_are_given() {
    let lp = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../../shared/data/lpips");
    if !lp.join("lpips_alex_v0.1.safetensors").is_file() {
        eprintln!("skipping: {} not found", lp.display());
        return;
    }
    let tmp = tempfile::tempdir().unwrap();
    let (train, test) = train_util::make_scene(tmp.path(), 64, 64, 9, 300);
    let mut args = small_args();
    args.early_stop_patience = Some(1);
    args.steps = 40;
    let m = run_node(
        &args,
        vec![("train", &train), ("test", &test), ("lpips", &lp)],
        &tmp.path().join("o"),
        2,
    )
    .unwrap();
    let best: BestRecord = artifacts::read_json(&m.join("best.json")).unwrap();
    assert_eq!(best.criterion, "avg_error");
    let curve: TrainingCurve = artifacts::read_json(&m.join("curve.json")).unwrap();
    assert!(curve
        .points
        .iter()
        .all(|p| p.lpips.is_some() && p.avg_error.is_some()));
    let min = curve
        .points
        .iter()
        .map(|p| p.avg_error.unwrap())
        .fold(f64::MAX, f64::min);
    assert_eq!(best.point.avg_error, Some(min));
    if best.early_stopped {
        assert!(best.steps_run < 40);
    }
}

/// The curve's average error is the mean of the per-view average errors (the `Evaluate`
/// node's convention), not the average error of the mean MSE, SSIM and LPIPS.
#[test]
fn curve_average_error_is_the_mean_of_per_view_average_errors() {
    use augsplat_core::ImageF32;
    use augsplat_splat::init::{from_points, InitArgs};
    use augsplat_splat::train::{evaluate, RealView};
    use augsplat_splat::RenderSettings;
    let lp = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../../shared/data/lpips");
    let Ok(model) = augsplat_metrics::lpips::Lpips::load(&lp.join("lpips_alex_v0.1.safetensors"))
    else {
        eprintln!("skipping: no LPIPS weights under {}", lp.display());
        return;
    };
    let tmp = tempfile::tempdir().unwrap();
    let (train, test) = train_util::make_scene(tmp.path(), 48, 40, 9, 300);
    let scene = Scene::load(&train).unwrap();
    let g = from_points(
        &scene.load_points(&train).unwrap(),
        0,
        &InitArgs::default(),
        1.0,
        3,
    );
    let test_scene = Scene::load(&test).unwrap();
    let views: Vec<RealView> = test_scene
        .views
        .iter()
        .enumerate()
        .map(|(i, v)| RealView {
            name: v.name.clone(),
            camera: v.camera.clone(),
            image: test_scene.load_image(&test, i).unwrap().data,
        })
        .collect();
    assert!(views.len() >= 2);
    let s = RenderSettings::default();
    let e = evaluate(&g, &views, &s, Some(&model)).unwrap();
    let mut per_view = Vec::new();
    for v in &views {
        let (w, h) = (v.camera.width, v.camera.height);
        let out = augsplat_splat::render(&g, &v.camera, &s);
        let pred = ImageF32::from_vec(w, h, 3, out.rgb.iter().map(|x| x.clamp(0.0, 1.0)).collect());
        let gt = ImageF32::from_vec(w, h, 3, v.image.clone());
        let mse = augsplat_metrics::mse(&pred, &gt).unwrap();
        let ssim = augsplat_metrics::ssim(&pred, &gt).unwrap();
        let l = model.distance(&pred, &gt).unwrap();
        per_view.push((mse, ssim, l, augsplat_metrics::average_error(mse, ssim, l)));
    }
    let n = per_view.len() as f64;
    let want = per_view.iter().map(|p| p.3).sum::<f64>() / n;
    let got = e.avg_error.unwrap();
    assert!((got - want).abs() < 1e-12, "{got} vs {want}");
    // The other convention differs here, so the test tells them apart.
    let of_means = augsplat_metrics::average_error(
        per_view.iter().map(|p| p.0).sum::<f64>() / n,
        per_view.iter().map(|p| p.1).sum::<f64>() / n,
        per_view.iter().map(|p| p.2).sum::<f64>() / n,
    );
    assert!((got - of_means).abs() > 1e-9, "{got} vs {of_means}");
}

/// The library's training policy, called without a graph, gives the node's outputs: the same
/// curve and the same checkpoints. Early stopping and `steps = 0` follow the documented rules.
#[test]
fn fit_without_a_graph_matches_the_node() {
    use augsplat_splat::fit::{self, Criterion, FitEvent};
    use augsplat_splat::init::initial_gaussians;
    use augsplat_splat::train::{scene_scale, RealImages, RealView};
    let tmp = tempfile::tempdir().unwrap();
    let (train, test) = train_util::make_scene(tmp.path(), 48, 40, 9, 300);
    let args = small_args();
    let node = run_node(
        &args,
        vec![("train", &train), ("test", &test)],
        &tmp.path().join("o"),
        2,
    )
    .unwrap();
    let real = RealImages {
        views: augsplat_splat::inputs::load_real_views(&train, "train").unwrap(),
        loss: args.real_loss.clone(),
    };
    let held_out = augsplat_splat::inputs::load_real_views(&test, "test").unwrap();
    let scene = Scene::load(&train).unwrap();
    let cloud = scene.load_points(&train).unwrap();
    let cams: Vec<_> = real.views.iter().map(|v| &v.camera).collect();
    let sscale = scene_scale(&cams);
    let views: Vec<_> = real.views.iter().map(RealView::init_view).collect();
    let g0 = |a: &TrainArgs| {
        initial_gaussians(
            &cloud,
            &scene,
            &views,
            &[],
            a.sh_degree,
            &a.init,
            sscale,
            a.seed,
        )
        .gaussians
    };
    let pool = rayon::ThreadPoolBuilder::new()
        .num_threads(2)
        .build()
        .unwrap();
    let run = |a: &TrainArgs| {
        let mut events = Vec::new();
        let f = pool.install(|| {
            fit::fit(
                a,
                g0(a),
                sscale,
                &real,
                None,
                &held_out,
                None,
                &augsplat_splat::Device::cpu(),
                None,
                &mut |e| events.push(e),
            )
        });
        (f.unwrap(), events)
    };
    let (fitted, events) = run(&args);
    assert_eq!(fitted.criterion, Criterion::Psnr);
    let curve: TrainingCurve = artifacts::read_json(&node.join("curve.json")).unwrap();
    assert_eq!(fitted.curve, curve);
    let best: BestRecord = artifacts::read_json(&node.join("best.json")).unwrap();
    assert_eq!(fitted.best_record(), best);
    let final_ply = tmp.path().join("final.ply");
    augsplat_splat::write_ply(&final_ply, &fitted.last).unwrap();
    assert!(std::fs::read(&final_ply).unwrap() == std::fs::read(node.join("final.ply")).unwrap());
    let progress = events
        .iter()
        .filter(|e| matches!(e, FitEvent::Progress { .. }))
        .count();
    assert_eq!(progress, 20);

    // Patience p stops once p evaluations in a row did not improve: p = 0 stops at the first
    // evaluation, which is kept.
    let mut impatient = small_args();
    impatient.early_stop_patience = Some(0);
    let (stopped, _) = run(&impatient);
    assert!(stopped.early_stopped);
    assert_eq!((stopped.steps_run, stopped.curve.points.len()), (10, 1));
    assert_eq!(stopped.best_point, stopped.curve.points[0]);

    // No steps: the initialisation is evaluated and kept.
    let mut none = small_args();
    none.steps = 0;
    let (init_only, _) = run(&none);
    assert_eq!((init_only.steps_run, init_only.curve.points.len()), (0, 1));
    assert_eq!(init_only.best_point.step, 0);
    assert_eq!(init_only.best.len(), init_only.last.len());
}

/// Dual AugSplat with densification on the tiny scene, for the checkpoint tests.
fn resume_case(tmp: &Path) -> (PathBuf, PathBuf, PathBuf, TrainArgs) {
    let (train, test) = train_util::make_scene(tmp, 48, 40, 9, 300);
    let syn = tmp.join("syn");
    make_synthetic(&train, &syn);
    let mut args = small_args();
    args.steps = 60;
    // Refine at steps 10, 20, … 40 with a low threshold, so densification's statistics and
    // the grown set are part of what a checkpoint must carry.
    args.densify.scale_with_steps = false;
    args.densify.start = 10;
    args.densify.every = 10;
    args.densify.stop = 45;
    args.densify.reset_every = 30;
    args.densify.grad_threshold = 1e-5;
    args.schedule = small_dual();
    (train, test, syn, args)
}

/// A run continued from any of its checkpoints ends with the same bytes as the run that
/// never stopped: the Gaussians, the kept checkpoint, the curve and the record.
#[test]
fn fit_continued_from_a_checkpoint_is_bit_identical() {
    use augsplat_splat::fit::{self, FitCheckpoints, FitEvent};
    use augsplat_splat::init::initial_gaussians;
    use augsplat_splat::train::{scene_scale, RealImages, RealView};
    let tmp = tempfile::tempdir().unwrap();
    let (train, test, syn, args) = resume_case(tmp.path());
    let real = RealImages {
        views: augsplat_splat::inputs::load_real_views(&train, "train").unwrap(),
        loss: args.real_loss.clone(),
    };
    let synth = augsplat_splat::inputs::load_synthetic(&syn, &args.synthetic).unwrap();
    let held_out = augsplat_splat::inputs::load_real_views(&test, "test").unwrap();
    let scene = Scene::load(&train).unwrap();
    let cloud = scene.load_points(&train).unwrap();
    let cams: Vec<_> = real.views.iter().map(|v| &v.camera).collect();
    let sscale = scene_scale(&cams);
    let views: Vec<_> = real.views.iter().map(RealView::init_view).collect();
    let g0 = initial_gaussians(
        &cloud,
        &scene,
        &views,
        &[],
        1,
        &args.init,
        sscale,
        args.seed,
    )
    .gaussians;
    let run = |resume: Option<Vec<u8>>, saved: &mut Vec<Vec<u8>>| {
        let mut log = Vec::new();
        let mut save = |b: Vec<u8>| {
            saved.push(b);
            Ok(())
        };
        let f = fit::fit(
            &args,
            g0.clone(),
            sscale,
            &real,
            Some(&synth),
            &held_out,
            None,
            &augsplat_splat::Device::cpu(),
            Some(FitCheckpoints {
                every: 15,
                resume,
                save: &mut save,
            }),
            &mut |e| {
                if let FitEvent::Log(l) = e {
                    log.push(l)
                }
            },
        )
        .unwrap();
        (f, log)
    };
    let mut saved = Vec::new();
    let (full, log) = run(None, &mut saved);
    assert_eq!(saved.len(), 3, "checkpoints at steps 15, 30 and 45");
    assert!(
        log.iter()
            .any(|l| l.contains("cloned") || l.contains("split")),
        "densification ran, so its statistics are part of the state: {log:?}"
    );
    let ply = |g: &augsplat_splat::Gaussians, name: &str| {
        let p = tmp.path().join(name);
        augsplat_splat::write_ply(&p, g).unwrap();
        std::fs::read(p).unwrap()
    };
    for (i, ckpt) in saved.clone().into_iter().enumerate() {
        let mut again = Vec::new();
        let (resumed, log) = run(Some(ckpt), &mut again);
        let at = 15 * (i + 1);
        assert!(
            log.iter()
                .any(|l| l == &format!("resumed from the checkpoint at step {at}")),
            "{log:?}"
        );
        assert!(
            ply(&resumed.last, "a.ply") == ply(&full.last, "b.ply"),
            "step {at}"
        );
        assert!(
            ply(&resumed.best, "a.ply") == ply(&full.best, "b.ply"),
            "step {at}"
        );
        assert_eq!(resumed.curve, full.curve);
        assert_eq!(resumed.best_record(), full.best_record());
        // Its own later checkpoints are the uninterrupted run's.
        assert_eq!(again, saved[i + 1..].to_vec());
    }
    // A checkpoint from other data is refused and the run starts afresh (same result).
    let mut bad = saved[0].clone();
    bad.truncate(bad.len() / 2);
    let (fresh, log) = run(Some(bad), &mut Vec::new());
    assert!(log.iter().any(|l| l.contains("starting afresh")), "{log:?}");
    assert!(ply(&fresh.last, "a.ply") == ply(&full.last, "b.ply"));
    // One refused only after its trainer part was read (a byte too many at its end) leaves no
    // trace of it: the run is the uninterrupted one, its whole curve included.
    let mut trailing = saved[0].clone();
    trailing.push(0);
    let (fresh, log) = run(Some(trailing), &mut Vec::new());
    assert!(log.iter().any(|l| l.contains("starting afresh")), "{log:?}");
    assert!(ply(&fresh.last, "a.ply") == ply(&full.last, "b.ply"));
    assert_eq!(fresh.curve, full.curve);
}

/// Through the node: a run that finds a checkpoint in its folder continues from it with the
/// same outputs; a checkpoint another seed's run left in that folder is read (the outputs
/// change, so it was not ignored), while the same bytes moved into another computation's
/// folder, a checkpoint made for a longer run, and a damaged checkpoint are ignored.
#[test]
fn node_resumes_from_its_checkpoint_folder() {
    let tmp = tempfile::tempdir().unwrap();
    let (train, test, syn, args) = resume_case(tmp.path());
    let run = |args: &TrainArgs, ckpt: &Path, out: &str| {
        let inputs = [("train", &train), ("test", &test), ("synthetic", &syn)]
            .into_iter()
            .map(|(n, p)| (n.to_string(), vec![p.to_path_buf()]))
            .collect();
        let mut ctx = RunContext::standalone(inputs, &["model"], &tmp.path().join(out), 0, 1)
            .unwrap()
            .with_checkpoints(ckpt.to_path_buf(), 15);
        OptimizeSplats::run(args, &mut ctx).unwrap();
        tmp.path().join(out).join("model")
    };
    let ckpt = tmp.path().join("ckpt");
    let a = run(&args, &ckpt, "a");
    let state = ckpt.join("state.ckpt");
    assert!(
        state.is_file(),
        "the last checkpoint (step 45) is kept by a standalone run"
    );
    let b = run(&args, &ckpt, "b");
    let saved = std::fs::read(&state).unwrap();
    // Another seed's checkpoint at step 45 in the folder: the run continues from it, so its
    // outputs differ; moved into another folder (another key), it is ignored.
    let mut other = args.clone();
    other.seed += 1;
    let shared = tmp.path().join("shared");
    run(&other, &shared, "o");
    let moved = tmp.path().join("moved");
    std::fs::create_dir_all(&moved).unwrap();
    std::fs::copy(shared.join("state.ckpt"), moved.join("state.ckpt")).unwrap();
    let d = run(&args, &shared, "d");
    assert!(
        std::fs::read(a.join("final.ply")).unwrap() != std::fs::read(d.join("final.ply")).unwrap(),
        "the checkpoint in the folder was not read"
    );
    let e = run(&args, &moved, "e");
    // A checkpoint of a longer run (its steps differ) is ignored too.
    let mut longer = args.clone();
    longer.steps += 30;
    let long_dir = tmp.path().join("long");
    run(&longer, &long_dir, "l");
    let from_longer = run(&args, &long_dir, "f");
    let mut bytes = saved;
    let n = bytes.len();
    bytes[n - 5] ^= 0x40;
    std::fs::write(&state, bytes).unwrap();
    let c = run(&args, &ckpt, "c");
    for f in ["final.ply", "best.ply", "curve.json", "best.json"] {
        let x = std::fs::read(a.join(f)).unwrap();
        assert!(x == std::fs::read(b.join(f)).unwrap(), "{f} after resuming");
        assert!(
            x == std::fs::read(c.join(f)).unwrap(),
            "{f} after a damaged checkpoint"
        );
        assert!(
            x == std::fs::read(e.join(f)).unwrap(),
            "{f} after a moved checkpoint"
        );
        assert!(
            x == std::fs::read(from_longer.join(f)).unwrap(),
            "{f} after a longer run's checkpoint"
        );
    }
}
