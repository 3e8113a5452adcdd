//! Benchmark of whole training steps through the trainer (`Trainer::step`), on the GPU
//! (`backend: Gpu`: render, L2 + SSIM loss, backward, gradient sums, Adam and the
//! densification statistics all on the GPU, the state kept there) and on the CPU, for N
//! Gaussians at W×H.
//!
//! `cargo run --release -p augsplat-splat --example gpu_train_step -- [N,N,... [WxH,... [STEPS]]] [--no-cpu]`
//! Defaults: 20000 at 256×256, 20 timed steps after 3 warm-up steps. Prints per case the
//! median and best step time on each backend and their ratio, and the GPU state's size.
//! `--no-cpu` times the GPU alone (the CPU at 1 M Gaussians and 1080p takes seconds a step).
//!
//! The Gaussians are a random cloud in front of one camera (footprints of a few pixels, SH
//! degree 3, all bands active), the target a smooth colour ramp; densification is off so
//! that every timed step sees the same N.

#[path = "../../render/examples/common/gpu_bench.rs"]
mod gpu_bench;

use augsplat_splat::densify::DensifyArgs;
use augsplat_splat::train::{RealImages, RealView, TrainArgs, Trainer};
use augsplat_splat::Gaussians;
use std::sync::Arc;
use std::time::Instant;

fn view(w: u32, h: u32) -> RealView {
    let camera = gpu_bench::bench_camera(w, h);
    let image = (0..(w * h) as usize)
        .flat_map(|p| {
            let (x, y) = (
                (p % w as usize) as f32 / w as f32,
                (p / w as usize) as f32 / h as f32,
            );
            [x, y, 0.5 * (x + y)]
        })
        .collect();
    RealView {
        name: "ramp".into(),
        camera,
        image,
    }
}

/// Median and best seconds per step of `steps` steps after 3 warm-up steps.
fn time_steps(
    n: usize,
    w: u32,
    h: u32,
    steps: usize,
    gpu: Option<Arc<augsplat_splat::gpu::GpuContext>>,
) -> (f64, f64) {
    let real = RealImages {
        views: vec![view(w, h)],
        loss: Default::default(),
    };
    // Footprints of a few pixels at depth 4, as mid-training.
    let px = 4.0 / (w as f64 * 0.9);
    let g = Gaussians::random_cloud(n, px, 7);
    let args = TrainArgs {
        steps: 1_000_000,
        // Every band active after the warm-up steps.
        sh_increase_every: 1,
        densify: DensifyArgs {
            enabled: false,
            ..Default::default()
        },
        ..Default::default()
    };
    let mut trainer = Trainer::new(args, g, 1.0, &real, None);
    if let Some(gpu) = gpu {
        trainer.on_device(&augsplat_splat::Device::gpu(gpu));
    }
    let mut times = Vec::with_capacity(steps);
    for i in 0..steps + 3 {
        let t = Instant::now();
        let rep = trainer.step();
        // The step's loss came back to the host: the GPU's work for it is done.
        std::hint::black_box(rep.loss);
        if i >= 3 {
            times.push(t.elapsed().as_secs_f64());
        }
    }
    let best = times.iter().copied().fold(f64::INFINITY, f64::min);
    (gpu_bench::median(times), best)
}

fn main() {
    let no_cpu = std::env::args().any(|a| a == "--no-cpu");
    let a = gpu_bench::args(20);
    let ctx = Arc::new(gpu_bench::context());
    println!("adapter: {}", ctx.adapter());
    println!(
        "| N | size | GPU step (median / best) | CPU step (median / best) | CPU / GPU |\n|---:|---|---:|---:|---:|"
    );
    let mut headline = None;
    for &(w, h) in &a.sizes {
        for &n in &a.counts {
            let (gm, gb) = time_steps(n, w, h, a.reps, Some(ctx.clone()));
            headline.get_or_insert((n, w, h, gm, gb));
            let cpu = if no_cpu {
                "—".to_string()
            } else {
                let (cm, cb) = time_steps(n, w, h, a.reps, None);
                format!("{:.1} / {:.1} ms | {:.1}×", cm * 1e3, cb * 1e3, cm / gm)
            };
            let cpu = if no_cpu { format!("{cpu} | —") } else { cpu };
            println!(
                "| {n} | {w}×{h} | {:.2} / {:.2} ms | {cpu} |",
                gm * 1e3,
                gb * 1e3
            );
        }
    }
    if let Some((n, w, h, gm, gb)) = headline {
        gpu_bench::record(
            &ctx,
            &a,
            ("augsplat-splat", "gpu_train_step"),
            (
                format!("GPU training step, {n} Gaussians at {w}×{h}"),
                format!(
                    "{:.2} ms median, {:.2} ms best, over {} steps",
                    gm * 1e3,
                    gb * 1e3,
                    a.reps
                ),
            ),
            (gm * 1e3, "ms"),
        );
    }
}
