//! A longer run on the tests' generated scene (24 orbit views at 64×48, every 4th held out):
//! held-out PSNR curve with wall time, against the constant-colour baseline.
//!
//! `cargo run --release -p augsplat-field --example synthetic_curve -- [steps] [rays] [eval_every]`
#![allow(clippy::needless_range_loop)]

#[path = "../tests/common/mod.rs"]
mod common;

use augsplat_field::field::Field;
use augsplat_field::node::TrainFieldArgs;
use augsplat_field::train;
use std::time::Instant;

fn main() {
    let args: Vec<String> = std::env::args().collect();
    let steps: u32 = args.get(1).and_then(|s| s.parse().ok()).unwrap_or(1000);
    let rays: u32 = args.get(2).and_then(|s| s.parse().ok()).unwrap_or(1024);
    let every: u32 = args.get(3).and_then(|s| s.parse().ok()).unwrap_or(100);
    let tmp = std::env::temp_dir().join(format!("augsplat_field_curve_{}", std::process::id()));
    common::split_scene(&tmp, 24, 64, 48, 0.05);
    let (scene, views) = train::load_views(&tmp.join("train"), 1).expect("train views");
    let (_, test) = train::load_views(&tmp.join("test"), 1).expect("test views");
    let a = TrainFieldArgs {
        seed: 0,
        steps,
        rays_per_step: rays,
        eval_every: every,
        ..TrainFieldArgs::default()
    };
    let field = Field::new(a.field_config(&scene, views.len()).expect("config")).expect("field");
    let t0 = Instant::now();
    let mut times = Vec::new();
    let mut on_step = |r: train::StepReport<'_>| {
        if r.step.is_multiple_of(every) || r.step == steps {
            times.push((r.step, t0.elapsed().as_secs_f64()));
        }
    };
    let (_, curve) =
        train::train(&field, &views, Some(&test), &a.options(), &mut on_step).expect("training");
    println!("{} train / {} test views, {steps} steps × {rays} rays, default field (16×2, 2^17, 64 wide)", views.len(), test.len());
    for p in &curve.points {
        let t = times
            .iter()
            .find(|(s, _)| *s as u64 == p.step)
            .map(|x| x.1)
            .unwrap_or(0.0);
        println!("step {:5}: held-out PSNR {:.2} dB, train loss {:.5}, {:.1} s wall since start (earlier evaluations included)", p.step, p.psnr, p.loss, t);
    }
    println!(
        "total {:.1} s including evaluations",
        t0.elapsed().as_secs_f64()
    );
    let _ = std::fs::remove_dir_all(&tmp);
}
