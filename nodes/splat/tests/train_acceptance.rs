//! Issue 4's baseline acceptance run: the generated scene, all 30 views at 128×96 (every 8th
//! held out), Baseline schedule with default arguments; held-out PSNR must exceed 30 dB.
//! 2,000 steps (about 1.5–2.5 minutes of CPU on the 2-core CI machine; it reached 32.4 dB when
//! measured). Run it alone with
//! `cargo test -p augsplat-splat --test train_acceptance -- --nocapture`
//! (`AUGSPLAT_ACCEPT_STEPS` overrides the 2,000 steps). The 3,000-step run with a printed curve:
//! `cargo run --release -p augsplat-splat --example train_baseline_curve`.

mod train_util;

use augsplat_core::artifacts::{self, TrainingCurve};
use augsplat_graph::{Node, RunContext};
use augsplat_splat::node::BestRecord;
use augsplat_splat::train::TrainArgs;
use augsplat_splat::OptimizeSplats;

#[test]
fn baseline_on_generated_scene_exceeds_30_db() {
    let steps: u64 = std::env::var("AUGSPLAT_ACCEPT_STEPS")
        .ok()
        .and_then(|s| s.parse().ok())
        .unwrap_or(2000);
    let tmp = tempfile::tempdir().unwrap();
    let (train, test) = train_util::make_scene(tmp.path(), 128, 96, 30, 3000);
    let args = TrainArgs {
        steps,
        eval_every: 250,
        record_wall_time: true,
        ..Default::default()
    };
    let inputs = vec![
        ("train".to_string(), vec![train]),
        ("test".to_string(), vec![test]),
    ];
    let out = tmp.path().join("out");
    let mut ctx =
        RunContext::standalone(inputs, &["model"], &out, 0, rayon::current_num_threads()).unwrap();
    OptimizeSplats::run(&args, &mut ctx).unwrap();
    let curve: TrainingCurve = artifacts::read_json(&out.join("model/curve.json")).unwrap();
    for p in &curve.points {
        eprintln!(
            "step {:5}: PSNR {:6.2} SSIM {:.4} Gaussians {:7} {:7.1} s",
            p.step, p.psnr, p.ssim, p.primitives, p.seconds
        );
    }
    let best: BestRecord = artifacts::read_json(&out.join("model/best.json")).unwrap();
    assert!(
        best.point.psnr > 30.0,
        "best held-out PSNR {:.2} dB at step {}",
        best.point.psnr,
        best.step
    );
}
