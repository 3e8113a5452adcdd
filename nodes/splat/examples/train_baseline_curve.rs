//! The baseline acceptance run of issue 4: the generated scene (all 30 views, 128×96, every
//! 8th view held out) optimised with `OptimizeSplats` (Baseline schedule), printing the
//! held-out curve.
//!
//! `cargo run --release -p augsplat-splat --example train_baseline_curve -- [STEPS] [EVAL_EVERY] [WxH]`
//! (defaults 3000, 250, 128x96).

use augsplat_core::artifacts::{self, TrainingCurve};
use augsplat_core::Scene;
use augsplat_graph::{Node, RunContext};
use augsplat_scene::split;
use augsplat_scene::synthetic::{self, SyntheticParams};
use augsplat_splat::train::TrainArgs;
use augsplat_splat::OptimizeSplats;

fn main() {
    let a: Vec<String> = std::env::args().skip(1).collect();
    let steps: u64 = a.first().map_or(3000, |s| s.parse().unwrap());
    let eval: u64 = a.get(1).map_or(250, |s| s.parse().unwrap());
    let (w, h) = a.get(2).map_or((128, 96), |s| {
        let (x, y) = s.split_once('x').unwrap();
        (x.parse().unwrap(), y.parse().unwrap())
    });
    let tmp = std::env::temp_dir().join(format!("augsplat_baseline_{w}x{h}"));
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
