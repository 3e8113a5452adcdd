//! The baseline acceptance run: the generated scene (all 30 views, 128×96, every
//! 8th view held out) optimised with `OptimizeSplats` (Baseline schedule), printing the
//! held-out curve.
//!
//! `cargo run --release -p augsplat-splat --example train_baseline_curve -- [STEPS] [EVAL_EVERY] [WxH]`
//! (defaults 3000, 250, 128x96).
//!
//! `... train_baseline_curve -- loop [STEPS] [WxH] [baseline|staged|dual]` instead times the
//! bare training loop (`Trainer::step`, no evaluation) on the same scene, in blocks of 100
//! steps; the Staged and Dual schedules get 200 synthetic views made from the training
//! images box-downsampled 8× (weights from a fixed pattern in [0.1, 1]), batches of 20 as in
//! the paper. Use it under `perf record` to find per-step overheads.

use augsplat_core::artifacts::{self, TrainingCurve};
use augsplat_core::Scene;
use augsplat_graph::{Node, RunContext};
use augsplat_scene::split;
use augsplat_scene::synthetic::{self, SyntheticParams};
use augsplat_splat::init;
use augsplat_splat::loss::WeightNorm;
use augsplat_splat::train::{
    scene_scale, RealImages, RealLoss, RealView, Schedule, StepReport, Supervision, SynthView,
    SyntheticImages, TrainArgs, Trainer,
};
use augsplat_splat::OptimizeSplats;
use std::path::PathBuf;
use std::time::Instant;

fn main() {
    let a: Vec<String> = std::env::args().skip(1).collect();
    if a.first().map(String::as_str) == Some("loop") {
        return time_loop(&a[1..]);
    }
    let steps: u64 = a.first().map_or(3000, |s| s.parse().unwrap());
    let eval: u64 = a.get(1).map_or(250, |s| s.parse().unwrap());
    let (w, h) = a.get(2).map_or((128, 96), |s| {
        let (x, y) = s.split_once('x').unwrap();
        (x.parse().unwrap(), y.parse().unwrap())
    });
    let (tmp, dirs, cloud) = make_scene(w, h);
    let args = TrainArgs {
        steps,
        eval_every: eval,
        record_wall_time: true,
        ..Default::default()
    };
    let inputs = vec![
        ("train".to_string(), vec![dirs[0].clone()]),
        ("test".to_string(), vec![dirs[1].clone()]),
    ];
    let out = tmp.join("out");
    let mut ctx =
        RunContext::standalone(inputs, &["model"], &out, 0, rayon::current_num_threads()).unwrap();
    let t0 = std::time::Instant::now();
    OptimizeSplats::run(&args, &mut ctx).unwrap();
    let curve: TrainingCurve = artifacts::read_json(&out.join("model/curve.json")).unwrap();
    println!(
        "{} points in the cloud; {} s total",
        cloud.len(),
        t0.elapsed().as_secs_f64()
    );
    println!("step  psnr    ssim    gaussians  seconds  loss");
    for p in &curve.points {
        println!(
            "{:5} {:6.2} {:7.4} {:9} {:8.1} {:.5}",
            p.step, p.psnr, p.ssim, p.primitives, p.seconds, p.loss
        );
    }
}

/// Generates the scene at `w`×`h` and its train/test split (every 8th view held out) in a
/// temporary folder. Returns (folder, [train, test], the full point cloud).
fn make_scene(w: u32, h: u32) -> (PathBuf, Vec<PathBuf>, augsplat_core::PointCloud) {
    let tmp =
        std::env::temp_dir().join(format!("augsplat_baseline_{w}x{h}_{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&tmp);
    let full = tmp.join("full");
    let params = SyntheticParams {
        width: w,
        height: h,
        ..Default::default()
    };
    let scene = synthetic::generate(&params, &full).unwrap();
    let cloud = scene.load_points(&full).unwrap();
    let n = scene.views.len();
    let mut dirs = Vec::new();
    for (name, ids) in [
        ("train", (0..n).filter(|i| i % 8 != 0).collect::<Vec<_>>()),
        ("test", (0..n).filter(|i| i % 8 == 0).collect()),
    ] {
        let dir = tmp.join(name);
        std::fs::create_dir_all(dir.join("images")).unwrap();
        let (sub, pts) = split::subset(&scene, &cloud, &ids, 1);
        for v in &sub.views {
            std::fs::copy(full.join(&v.image), dir.join(&v.image)).unwrap();
        }
        let sub = Scene {
            has_points: !pts.is_empty(),
            ..sub
        };
        sub.save(&dir).unwrap();
        pts.save(&dir.join(augsplat_core::scene::POINTS_FILE))
            .unwrap();
        dirs.push(dir);
    }
    (tmp, dirs, cloud)
}

/// Box-downsamples an interleaved RGB image by `f` (partial blocks at the border dropped).
fn downsample(img: &[f32], w: usize, h: usize, f: usize) -> (Vec<f32>, usize, usize) {
    let (ow, oh) = ((w / f).max(1), (h / f).max(1));
    let mut out = vec![0f32; ow * oh * 3];
    for y in 0..oh {
        for x in 0..ow {
            for c in 0..3 {
                let mut s = 0.0;
                let mut n = 0.0;
                for dy in 0..f {
                    for dx in 0..f {
                        let (sx, sy) = (x * f + dx, y * f + dy);
                        if sx < w && sy < h {
                            s += img[(sy * w + sx) * 3 + c];
                            n += 1.0;
                        }
                    }
                }
                out[(y * ow + x) * 3 + c] = s / n;
            }
        }
    }
    (out, ow, oh)
}

/// `loop [STEPS] [WxH] [baseline|staged|dual]`: times `Trainer::step` in blocks of 100.
fn time_loop(a: &[String]) {
    let steps: u64 = a.first().map_or(600, |s| s.parse().expect("STEPS"));
    let (w, h) = a.get(1).map_or((128, 96), |s| {
        let (x, y) = s.split_once('x').expect("WxH");
        (x.parse().expect("W"), y.parse().expect("H"))
    });
    let schedule = match a.get(2).map_or("baseline", String::as_str) {
        "baseline" => Schedule::Baseline,
        "staged" => Schedule::Staged {
            warmup_steps: 300,
            synthetic_batch: 20,
            reset_at_switch: true,
        },
        "dual" => Schedule::Dual {
            w_nerf0: 2.0,
            w_real: 1.0,
            quarter_decay: 300.0,
            off_below: Some(0.1),
            synthetic_batch: 20,
            reset_at_off: false,
        },
        s => panic!("unknown schedule {s}"),
    };
    let (tmp, dirs, _) = make_scene(w, h);
    let scene = Scene::load(&dirs[0]).expect("train scene");
    let views: Vec<RealView> = (0..scene.views.len())
        .map(|i| RealView {
            name: scene.views[i].name.clone(),
            camera: scene.views[i].camera.clone(),
            image: scene.load_image(&dirs[0], i).expect("image").data,
        })
        .collect();
    let mut synth = Vec::new();
    for k in 0..200 {
        let v = &views[k % views.len()];
        let (img, sw, sh) = downsample(&v.image, w as usize, h as usize, 8);
        let weight: Vec<f32> = (0..sw * sh)
            .map(|p| 0.1 + 0.9 * (((p * 7 + k * 13) % 17) as f32 / 16.0))
            .collect();
        synth.push(SynthView::new(
            format!("syn{k}"),
            v.camera.resized(sw as u32, sh as u32),
            img,
            weight,
            0.0,
        ));
    }
    let real = RealImages {
        views,
        loss: RealLoss::default(),
    };
    let synthetic = SyntheticImages {
        views: synth,
        norm: WeightNorm::WeightSum,
    };
    let args = TrainArgs {
        steps,
        schedule: schedule.clone(),
        ..Default::default()
    };
    let cloud = scene.load_points(&dirs[0]).expect("points");
    let cams: Vec<&augsplat_core::Camera> = real.views.iter().map(|v| &v.camera).collect();
    let sscale = scene_scale(&cams);
    let g0 = init::from_points(&cloud, args.sh_degree, &args.init, sscale, args.seed);
    let synth_src = schedule
        .needs_synthetic()
        .then_some(&synthetic as &dyn Supervision);
    let mut trainer = Trainer::new(args, g0, sscale, &real, synth_src);
    println!(
        "{} at {w}x{h}, {} threads: ms per step by block of 100 steps",
        schedule.name(),
        rayon::current_num_threads()
    );
    let t_all = Instant::now();
    while trainer.steps_done() < steps {
        let t0 = Instant::now();
        let first = trainer.steps_done();
        let mut pairs = 0u64;
        let mut last = StepReport::default();
        while trainer.steps_done() < (first + 100).min(steps) {
            last = trainer.step();
            pairs += last.pairs;
        }
        let n = trainer.steps_done() - first;
        println!(
            "steps {first:5}..{:5}: {:7.2} ms/step, {:6} Gaussians, {:.2} M pairs/step, loss {:.5}",
            trainer.steps_done(),
            t0.elapsed().as_secs_f64() * 1e3 / n as f64,
            last.gaussians,
            pairs as f64 / n as f64 / 1e6,
            last.loss
        );
    }
    println!("total {:.2} s", t_all.elapsed().as_secs_f64());
    let _ = std::fs::remove_dir_all(&tmp);
}
