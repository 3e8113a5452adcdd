//! Benchmark of whole training steps through the trainer (`Trainer::advance`, as a training
//! node runs them: a step's losses come back while the GPU runs the next), on the GPU
//! (`backend: Gpu`: render, L2 + SSIM loss, backward, gradient sums, Adam and the
//! densification statistics all on the GPU, the state kept there) and on the CPU, for N
//! Gaussians at W×H.
//!
//! `cargo run --release -p augsplat-splat --example gpu_train_step -- [N,N,... [WxH,... [STEPS]]] [--no-cpu] [--synthetic B] [--resolved]`
//! Defaults: 20000 at 256×256, 20 timed steps after 3 warm-up steps. Prints per case the
//! median and best step time on each backend and their ratio, and the median time the host
//! spent per GPU step outside its waits for the device (recording and submitting: with
//! `--resolved`, time in which a device that finished its work sits idle; otherwise the
//! device runs the step before meanwhile, unless a wait drained it; a software adapter such as lavapipe may
//! run a large submission's work before `submit` returns, which then counts here too), then
//! per case the GPU context's waits (and of them the draining ones, after which the device had
//! nothing queued), submissions, pooled and created buffers, and the dispatches recorded, the
//! compute passes they began and the queue writes made (uploads), per step. `--resolved` resolves
//! each step before the next is recorded (`Trainer::step`), for a comparison. `--no-cpu` times the GPU alone (the CPU
//! at 1 M Gaussians and 1080p takes seconds a step); `--synthetic B` adds B synthetic views
//! of an eighth of the size to every step (Dual at constant weights), as Staged's and Dual's
//! batches.
//!
//! The Gaussians are a random cloud in front of one camera (footprints of a few pixels, SH
//! degree 3, all bands active), the target a smooth colour ramp; densification is off so
//! that every timed step sees the same N.

#[path = "../../render/examples/common/gpu_bench.rs"]
mod gpu_bench;

use augsplat_splat::densify::DensifyArgs;
use augsplat_splat::loss::WeightNorm;
use augsplat_splat::supervision::{Supervision, SynthView, SyntheticImages};
use augsplat_splat::train::{RealImages, RealView, Schedule, TrainArgs, Trainer};
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

/// Seconds per step of `steps` steps after 3 warm-up steps, with `synthetic` synthetic views
/// of an eighth of the size beside the real view in every step (Dual at constant weights).
fn time_steps(
    n: usize,
    (w, h): (u32, u32),
    steps: usize,
    synthetic: usize,
    gpu: Option<Arc<augsplat_splat::gpu::GpuContext>>,
    resolved: bool,
) -> StepTimes {
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
    let (sw, sh) = ((w / 8).max(1), (h / 8).max(1));
    let synth = SyntheticImages {
        views: (0..synthetic)
            .map(|k| {
                let v = view(sw, sh);
                let weight = vec![1.0; (sw * sh) as usize];
                SynthView::new(format!("synthetic {k}"), v.camera, v.image, weight, 0.0)
            })
            .collect(),
        norm: WeightNorm::WeightSum,
    };
    let args = TrainArgs {
        schedule: if synthetic > 0 {
            Schedule::Dual {
                w_nerf0: 1.0,
                w_real: 1.0,
                quarter_decay: 1e12,
                off_below: None,
                synthetic_batch: synthetic,
                reset_at_off: false,
            }
        } else {
            Schedule::Baseline
        },
        ..args
    };
    let synth = (synthetic > 0).then_some(&synth as &dyn Supervision);
    let mut trainer = Trainer::new(args, g, 1.0, &real, synth);
    if let Some(gpu) = gpu.clone() {
        trainer.on_device(&augsplat_splat::Device::gpu(gpu));
    }
    let mut times = Vec::with_capacity(steps);
    let mut host = Vec::with_capacity(steps);
    let mut counts_at_start = None;
    for i in 0..steps + 3 {
        if i == 3 {
            counts_at_start = gpu.as_ref().map(|g| DeviceCounts::of(g));
        }
        let waited = gpu.as_ref().map_or(0.0, |g| g.host_wait_seconds());
        let t = Instant::now();
        if resolved {
            // The step's loss came back to the host: the GPU's work for it is done.
            std::hint::black_box(trainer.step().loss);
        } else {
            // The step before came back; this one runs on the GPU meanwhile.
            std::hint::black_box(trainer.advance());
        }
        if i >= 3 {
            let wall = t.elapsed().as_secs_f64();
            times.push(wall);
            let waits = gpu.as_ref().map_or(0.0, |g| g.host_wait_seconds()) - waited;
            host.push(wall - waits);
        }
    }
    std::hint::black_box(trainer.finish_steps());
    let best = times.iter().copied().fold(f64::INFINITY, f64::min);
    let per_step = match (&gpu, counts_at_start) {
        (Some(g), Some(start)) => DeviceCounts::of(g).since(&start, steps as f64),
        _ => DeviceCounts::default(),
    };
    StepTimes {
        median: gpu_bench::median(times),
        best,
        host: gpu_bench::median(host),
        per_step,
    }
}

/// The GPU context's counters: host waits, submissions, buffers taken from the pool and
/// buffers created (absolute, or per timed step after [`DeviceCounts::since`]).
#[derive(Clone, Copy, Default)]
struct DeviceCounts {
    waits: f64,
    draining: f64,
    submissions: f64,
    reused: f64,
    created: f64,
    dispatches: f64,
    passes: f64,
    queue_writes: f64,
}

impl DeviceCounts {
    fn of(g: &augsplat_splat::gpu::GpuContext) -> DeviceCounts {
        let pool = g.pool_stats();
        let rec = g.recording_stats();
        DeviceCounts {
            dispatches: rec.dispatches as f64,
            passes: rec.passes as f64,
            queue_writes: rec.queue_writes as f64,
            waits: g.host_waits() as f64,
            draining: g.draining_waits() as f64,
            submissions: g.submissions() as f64,
            reused: pool.reused as f64,
            created: pool.created as f64,
        }
    }

    fn since(&self, start: &DeviceCounts, steps: f64) -> DeviceCounts {
        DeviceCounts {
            waits: (self.waits - start.waits) / steps,
            draining: (self.draining - start.draining) / steps,
            submissions: (self.submissions - start.submissions) / steps,
            reused: (self.reused - start.reused) / steps,
            created: (self.created - start.created) / steps,
            dispatches: (self.dispatches - start.dispatches) / steps,
            passes: (self.passes - start.passes) / steps,
            queue_writes: (self.queue_writes - start.queue_writes) / steps,
        }
    }
}

/// Seconds per step: the median and best wall time, and the median of the time the host
/// spent outside its waits for the device (recording and submitting the step: on the GPU,
/// the time in which a device that finished its work sits idle; on the CPU, all of it).
struct StepTimes {
    median: f64,
    best: f64,
    host: f64,
    /// The GPU's counters per timed step (zeros on the CPU).
    per_step: DeviceCounts,
}

fn main() {
    let no_cpu = std::env::args().any(|a| a == "--no-cpu");
    let resolved = std::env::args().any(|a| a == "--resolved");
    let synthetic = {
        let argv: Vec<String> = std::env::args().collect();
        argv.iter()
            .position(|a| a == "--synthetic")
            .and_then(|i| argv.get(i + 1))
            .and_then(|b| b.parse().ok())
            .unwrap_or(0)
    };
    let a = gpu_bench::args(20);
    let ctx = Arc::new(gpu_bench::context());
    println!("adapter: {}", ctx.adapter());
    if synthetic > 0 {
        println!("each step: the real view and {synthetic} synthetic views of 1/8 its size");
    }
    println!(
        "| N | size | GPU step (median / best) | GPU host outside waits | CPU step (median / best) | CPU / GPU |\n|---:|---|---:|---:|---:|---:|"
    );
    let mut headline = None;
    let mut counts = Vec::new();
    for &(w, h) in &a.sizes {
        for &n in &a.counts {
            let gpu = time_steps(n, (w, h), a.reps, synthetic, Some(ctx.clone()), resolved);
            headline.get_or_insert((n, w, h, gpu.median, gpu.best));
            let cpu = if no_cpu {
                "— | —".to_string()
            } else {
                let cpu = time_steps(n, (w, h), a.reps, synthetic, None, resolved);
                format!(
                    "{:.1} / {:.1} ms | {:.1}×",
                    cpu.median * 1e3,
                    cpu.best * 1e3,
                    cpu.median / gpu.median
                )
            };
            println!(
                "| {n} | {w}×{h} | {:.2} / {:.2} ms | {:.2} ms | {cpu} |",
                gpu.median * 1e3,
                gpu.best * 1e3,
                gpu.host * 1e3
            );
            let c = gpu.per_step;
            counts.push(format!(
                "{n} at {w}×{h}, per GPU step: {:.2} waits ({:.2} draining), {:.2} submissions, \
                 {:.1} buffers from the pool, {:.1} created; {:.1} dispatches in {:.1} compute \
                 passes, {:.1} queue writes",
                c.waits,
                c.draining,
                c.submissions,
                c.reused,
                c.created,
                c.dispatches,
                c.passes,
                c.queue_writes
            ));
        }
    }
    for line in counts {
        println!("{line}");
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
