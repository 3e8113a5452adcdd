//! Throughput benchmarks of the field (run with `cargo run --release -p augsplat-field
//! --example bench -- [threads] [what] [steps] [chunk rays] [--json PATH]`):
//! - `step`: forward+backward samples per second and time per step (16 levels × 2 features,
//!   2^17 table, 64-wide MLPs) for 1024- and 4096-ray steps on a random scene: median, best
//!   and mean of `steps` timed steps (default 10), chunks of `chunk rays` (default 64);
//! - `kernels`: per-kernel timings on one chunk (best of 30);
//! - `gpu`: the same steps on the GPU (`gpu/`: the whole step on the device, one wait per
//!   step, for the next step's sample count while the device runs this one), forward+backward
//!   samples per second over `steps` steps after one warm-up, and
//!   rays per second rendering the 8 views (128×96) on the GPU and on the CPU;
//! - `mlp`: GFLOP/s of the dense-layer kernels (forward, weight gradient, input gradient) on
//!   chunk-sized batches, best of 300, next to a register-only FMA peak probe (one thread, then
//!   `threads` threads at once: the machine's ceiling for the dense layers).
//!
//! `--json PATH` (anywhere among the arguments) also writes the headline figure as a
//! [`BenchRecord`] (`docs/figures/`): the median samples/s of 1,024-ray steps, the
//! single-thread samples/s of one chunk, or the 64 → 64 forward GFLOP/s.
#![allow(clippy::needless_range_loop)]

use augsplat_core::bench_record::{self, BenchRecord};
use augsplat_core::{Camera, Rng};
use augsplat_field::field::{ChunkState, Field, FieldConfig, RayInput};
use augsplat_field::hashgrid::{HashGridConfig, PointBatch};
use augsplat_field::occupancy::OccupancyGrid;
use augsplat_field::train::{self, Adam, TrainOptions, TrainState, ViewData};
use std::time::Instant;

fn camera(k: usize) -> Camera {
    let a = k as f64 * 0.7;
    let c = [1.2 * a.cos(), -0.3, 1.2 * a.sin()];
    let f = augsplat_core::linalg::normalize(augsplat_core::linalg::scale(c, -1.0));
    let right = augsplat_core::linalg::normalize(augsplat_core::linalg::cross([0.0, 1.0, 0.0], f));
    let down = augsplat_core::linalg::cross(f, right);
    let r = [right, down, f];
    let t = augsplat_core::linalg::scale(augsplat_core::linalg::mat3_vec(&r, c), -1.0);
    Camera {
        width: 128,
        height: 96,
        fx: 110.0,
        fy: 110.0,
        cx: 64.0,
        cy: 48.0,
        world_to_camera: augsplat_core::linalg::mat4_from_rt(&r, t),
    }
}

/// CPU seconds (user + system, stolen time excluded) used by this process so far (0 where
/// `/proc` is unavailable); the machine is shared, so wall time alone overstates the cost.
fn cpu_seconds() -> f64 {
    augsplat_core::cputime::process_cpu_seconds().unwrap_or(0.0)
}

/// A headline figure: (what, the figure in words, its value, its unit).
type Headline = (String, String, f64, &'static str);

fn main() {
    let (args, json) = bench_record::args_and_json();
    let threads: usize = args.first().and_then(|s| s.parse().ok()).unwrap_or(2);
    let what = args.get(1).cloned().unwrap_or_else(|| "step".into());
    // `step` options: timed steps per ray count (default 10) and rays per chunk (default 64,
    // TrainField's default).
    let steps: usize = args
        .get(2)
        .and_then(|s| s.parse().ok())
        .unwrap_or(10)
        .max(1);
    let chunk: u32 = args
        .get(3)
        .and_then(|s| s.parse().ok())
        .unwrap_or(64)
        .max(1);
    let pool = rayon::ThreadPoolBuilder::new()
        .num_threads(threads)
        .build()
        .unwrap();
    let cfg = FieldConfig {
        grid: HashGridConfig {
            log2_table_size: std::env::var("LOG2T")
                .ok()
                .and_then(|v| v.parse().ok())
                .unwrap_or(17),
            ..HashGridConfig::default()
        },
        hidden_width: 64,
        appearance_dim: 0,
        n_images: 8,
        center: [0.0; 3],
        radius: 1.2,
        near: 0.05,
        far: 4.5,
        march_steps: 128,
        occupancy_resolution: 64,
    };
    let field = Field::new(cfg).unwrap();
    let mut rng = Rng::new(0);
    let views: Vec<ViewData> = (0..8)
        .map(|k| ViewData {
            name: format!("v{k}"),
            camera: camera(k),
            rgb: (0..128 * 96 * 3).map(|_| rng.next_f32()).collect(),
            depth: None,
        })
        .collect();
    println!("threads {threads}; params {}", field.n_params);
    let (what, figure, value, unit) = pool.install(|| match what.as_str() {
        "kernels" => kernels(&field),
        "mlp" => mlp_kernels(threads),
        "gpu" => gpu_bench(&field, &views, steps, chunk),
        _ => {
            let mut medians = Vec::new();
            for rays in [1024u32, 4096] {
                let opts = TrainOptions {
                    seed: 1,
                    steps: 100,
                    rays_per_step: rays,
                    chunk_rays: chunk,
                    learning_rate: 1e-2,
                    lr_final_factor: 0.1,
                    depth_loss_weight: 0.0,
                    depth_sigma: 0.02,
                    distortion_loss_weight: 0.0,
                    random_background: true,
                    background: [0.0; 3],
                    occupancy_warmup: 1000,
                    eval_every: 0,
                };
                let mut state = TrainState {
                    params: field.init_params(1),
                    occupancy: OccupancyGrid::full(64),
                    skipped_steps: 0,
                    nonfinite_values: 0,
                };
                let mut adam = Adam::new(field.n_params);
                let mut grad = Vec::new();
                train::train_step(&field, &mut state, &mut adam, &views, &opts, 0, &mut grad).unwrap();
                // Per-step wall times: the machine is shared, so the median (and the best)
                // step says more than the mean.
                let n = steps;
                let t0 = Instant::now();
                let c0 = cpu_seconds();
                let usage = augsplat_core::cputime::Usage::start();
                let mut samples = 0;
                let mut color = 0;
                let mut rates = Vec::with_capacity(n);
                for s in 1..=n as u32 {
                    let ts = Instant::now();
                    let st = train::train_step(&field, &mut state, &mut adam, &views, &opts, s, &mut grad).unwrap();
                    rates.push(st.samples as f64 / ts.elapsed().as_secs_f64());
                    samples += st.samples;
                    color += st.color_samples;
                }
                let dt = t0.elapsed().as_secs_f64();
                let cpu = cpu_seconds() - c0;
                let steal = usage.stop().steal_share.unwrap_or(0.0);
                rates.sort_by(f64::total_cmp);
                let median = rates[n / 2];
                let best = rates[n - 1];
                medians.push(median);
                println!(
                    "{rays} rays/step, chunks of {chunk} rays: {:.3} s/step wall, {:.0} samples/step ({:.0} with colour); \
                     forward+backward samples/s over {n} steps: median {:.0}, best {:.0}, mean {:.0}; \
                     CPU {:.3} s/step, i.e. {:.0} samples/s if the {threads} threads had their cores to themselves \
                     (host steal {:.0} % of the machine's CPU time meanwhile)",
                    dt / n as f64,
                    samples as f64 / n as f64,
                    color as f64 / n as f64,
                    median,
                    best,
                    samples as f64 / dt,
                    cpu / n as f64,
                    samples as f64 / (cpu / threads as f64),
                    100.0 * steal
                );
            }
            (
                format!("hash-grid field, forward+backward, {threads} threads"),
                format!(
                    "{:.2} M samples/s with 1,024-ray steps, {:.2} M with 4,096 (median of {steps} steps, chunks of {chunk} rays)",
                    medians[0] / 1e6,
                    medians[1] / 1e6
                ),
                medians[0],
                "samples/s",
            )
        }
    });
    let command = bench_record::example_command("augsplat-field", "bench", &args);
    BenchRecord::now(what, command, figure, value, unit).write_or_exit(json.as_deref());
}

fn kernels(field: &Field) -> Headline {
    let params = field.init_params(3);
    let occ = OccupancyGrid::full(64);
    let mut rng = Rng::new(5);
    let rays: Vec<RayInput> = (0..64)
        .map(|_| {
            let d = augsplat_core::linalg::normalize([
                rng.uniform(-0.3, 0.3),
                rng.uniform(-0.3, 0.3),
                1.0,
            ]);
            RayInput {
                origin: [0.0, 0.0, -1.2],
                dir: d.map(|v| v as f32),
                image: 0,
                background: [0.0; 3],
            }
        })
        .collect();
    let mut st = ChunkState::default();
    let mean = field.mean_embedding(&params);
    // Best of `reps` timings of each part (the machine is shared: the minimum is the clean run).
    let reps = 30;
    let best = |f: &mut dyn FnMut()| {
        let mut b = f64::INFINITY;
        for _ in 0..reps {
            let t0 = Instant::now();
            f();
            b = b.min(t0.elapsed().as_secs_f64());
        }
        b
    };
    let fwd = best(&mut || field.forward_chunk(&params, &occ, &rays, &|_| 0.5, &mean, &mut st));
    let n = st.n();
    let (px, py, pz, ld) = (st.px.clone(), st.py.clone(), st.pz.clone(), st.ld);
    let mut enc = vec![0f32; field.grid.output_dim() * ld];
    let pts = PointBatch {
        px: &px,
        py: &py,
        pz: &pz,
        n,
        ld,
    };
    let enc_t = best(&mut || {
        field
            .grid
            .encode(&params[..field.density_offset], pts, &mut enc)
    });
    for r in 0..rays.len() {
        field.add_ray_output_grad(&mut st, &rays, r, [0.1, 0.1, 0.1], 0.0, 0.0);
    }
    let mut grad = vec![0f32; field.n_params - field.density_offset];
    let bwd = best(&mut || field.backward_chunk(&params, &rays, &mut st, &mut grad));
    let mut g = vec![0f32; field.density_offset];
    let gb = best(&mut || {
        for l in 0..field.grid.levels() {
            let r = field.grid.level_range(l);
            field
                .grid
                .backward_level(l, st.points(), &st.d_enc, &mut g[r]);
        }
    });
    println!(
        "chunk of {n} samples ({} with colour), best of {reps}:",
        st.alive.len()
    );
    println!(
        "  forward {:.2} ms (hash encode {:.2} ms)",
        fwd * 1e3,
        enc_t * 1e3
    );
    println!(
        "  backward MLPs {:.2} ms, hash backward {:.2} ms",
        bwd * 1e3,
        gb * 1e3
    );
    let rate = n as f64 / (fwd + bwd + gb);
    println!("  => {rate:.0} samples/s single thread fwd+bwd");
    (
        "hash-grid field kernels, one 64-ray chunk, 1 thread".into(),
        format!(
            "{rate:.0} samples/s forward+backward (forward {:.2} ms, backward MLPs {:.2} ms, hash backward {:.2} ms; best of {reps})",
            fwd * 1e3,
            bwd * 1e3,
            gb * 1e3
        ),
        rate,
        "samples/s",
    )
}

/// GFLOP/s of the three dense-layer kernels on one thread (64-wide layers, a chunk-sized batch),
/// after the FMA peak on one thread and on `threads` threads.
fn mlp_kernels(threads: usize) -> Headline {
    use augsplat_field::mlp::{
        linear_backward_input, linear_backward_weights, linear_forward, padded, LayerShape,
    };
    let n = 6826;
    let ld = padded(n);
    // Peak: 12 independent AVX2 FMA chains of 8 lanes run 4·iters times (counted as 24 × 16
    // lanes per iteration), no memory traffic; nothing runs in the portable tier.
    let mut acc = [[0f32; 16]; 24];
    let iters = 2_000_000_000usize / 24;
    let c0 = cpu_seconds();
    peak(&mut acc, iters);
    let cpu = cpu_seconds() - c0;
    let peak_one = (iters * 24 * 16 * 2) as f64 / cpu / 1e9;
    println!(
        "FMA peak probe: {peak_one:.1} GFLOP/s (checksum {})",
        acc.iter().flatten().sum::<f32>()
    );
    // The same probe on `threads` threads at once, by the wall clock.
    let threads = threads.max(1);
    let t0 = Instant::now();
    std::thread::scope(|s| {
        for _ in 0..threads {
            s.spawn(|| {
                let mut acc = [[0f32; 16]; 24];
                peak(&mut acc, iters);
                std::hint::black_box(acc);
            });
        }
    });
    let peak_all = (threads * iters * 24 * 16 * 2) as f64 / t0.elapsed().as_secs_f64() / 1e9;
    println!("FMA peak probe, {threads} threads at once: {peak_all:.1} GFLOP/s");
    let mut square = (0.0, 0.0, 0.0);
    let mut rng = Rng::new(9);
    for (inp, out) in [(32usize, 64usize), (64, 64), (64, 16), (64, 3)] {
        let w: Vec<f32> = (0..inp * out)
            .map(|_| rng.uniform(-0.2, 0.2) as f32)
            .collect();
        let b: Vec<f32> = (0..out).map(|_| rng.uniform(-0.2, 0.2) as f32).collect();
        let x: Vec<f32> = (0..inp * ld)
            .map(|_| rng.uniform(-1.0, 1.0) as f32)
            .collect();
        let dy: Vec<f32> = (0..out * ld)
            .map(|_| rng.uniform(-1.0, 1.0) as f32)
            .collect();
        let mut y = vec![0f32; out * ld];
        let mut dx = vec![0f32; inp * ld];
        let mut dw = vec![0f32; inp * out];
        let mut db = vec![0f32; out];
        let mut wt = Vec::new();
        let flops = 2.0 * (inp * out * n) as f64;
        // Best of many short repetitions: the machine is shared, the minimum is the clean run.
        let time = |f: &mut dyn FnMut()| {
            f();
            let mut best = f64::INFINITY;
            for _ in 0..300 {
                let t0 = Instant::now();
                f();
                best = best.min(t0.elapsed().as_secs_f64());
            }
            (flops / best / 1e9, 0.0)
        };
        let shape = LayerShape { inp, out };
        let f = time(&mut || linear_forward(&w, Some(&b), &x, &mut y, shape, ld, true));
        let g = time(&mut || linear_backward_weights(&dy, &x, &mut dw, &mut db, shape, ld));
        let h = time(&mut || linear_backward_input(&w, &dy, &mut dx, shape, ld, &mut wt));
        println!(
            "{inp:>3} -> {out:>3}: GFLOP/s (best of 300) forward {:.1}, dW {:.1}, dX {:.1}",
            f.0, g.0, h.0
        );
        if (inp, out) == (64, 64) {
            square = (f.0, g.0, h.0);
        }
    }
    (
        "dense 64 → 64 layer on a chunk-sized batch, 1 thread".into(),
        format!(
            "forward {:.1}, dW {:.1}, dX {:.1} GFLOP/s (best of 300); FMA peak {peak_one:.1}, {threads} threads at once {peak_all:.1}",
            square.0, square.1, square.2
        ),
        square.0,
        "GFLOP/s",
    )
}

#[inline(never)]
fn peak(acc: &mut [[f32; 16]; 24], iters: usize) {
    #[cfg(target_arch = "x86_64")]
    {
        if augsplat_core::simd::active() == augsplat_core::simd::Isa::Avx2 {
            // 12 chains of 8 lanes on each half of `acc` (16 ymm registers: 12 accumulators
            // and the two operands); counted as the same 24 × 16 lanes per iteration.
            #[target_feature(enable = "avx2,fma,bmi1,popcnt")]
            unsafe fn run(acc: &mut [[f32; 16]; 24], iters: usize) {
                use std::arch::x86_64::*;
                let mut a: [__m256; 12] = [_mm256_setzero_ps(); 12];
                let x = _mm256_set1_ps(0.999_999);
                let y = _mm256_set1_ps(1e-7);
                for _ in 0..4 * iters {
                    for k in 0..12 {
                        a[k] = _mm256_fmadd_ps(a[k], x, y);
                    }
                }
                for k in 0..12 {
                    _mm256_storeu_ps(acc[k].as_mut_ptr(), a[k]);
                }
            }
            // SAFETY: `active` returns `Avx2` only on CPUs with its features.
            unsafe { run(acc, iters) };
        }
    }
    #[cfg(not(target_arch = "x86_64"))]
    let _ = (acc, iters);
}

/// Forward+backward samples/s of GPU training steps and rays/s of GPU renders, beside the
/// CPU's render of the same views.
fn gpu_bench(field: &Field, views: &[ViewData], steps: usize, chunk: u32) -> Headline {
    use augsplat_field::gpu::render::render_cameras_gpu;
    use augsplat_field::gpu::train::GpuTrainer;
    let ctx = augsplat_render::gpu::GpuContext::new().unwrap_or_else(|e| {
        eprintln!("{e}");
        std::process::exit(2)
    });
    println!("GPU: {}", ctx.adapter());
    let mut rates = Vec::new();
    for rays in [1024u32, 4096] {
        let opts = TrainOptions {
            seed: 1,
            steps: 100,
            rays_per_step: rays,
            chunk_rays: chunk,
            learning_rate: 1e-2,
            lr_final_factor: 0.1,
            depth_loss_weight: 0.0,
            depth_sigma: 0.02,
            distortion_loss_weight: 0.0,
            random_background: true,
            background: [0.0; 3],
            occupancy_warmup: 1000,
            eval_every: 0,
        };
        let state = TrainState {
            params: field.init_params(1),
            occupancy: OccupancyGrid::full(64),
            skipped_steps: 0,
            nonfinite_values: 0,
        };
        let mut trainer = GpuTrainer::new(&ctx, field, &state, &Adam::new(field.n_params)).unwrap();
        trainer.step(views, &opts, 0, Some(1)).unwrap();
        trainer.settle().unwrap();
        let waits = ctx.host_waits();
        let draining = ctx.draining_waits();
        let recorded = ctx.recording_stats();
        let t0 = Instant::now();
        let mut samples = 0u64;
        for s in 1..=steps as u32 {
            // The next step's samples are counted while this one runs, as in training.
            if let Some((_, done)) = trainer.step(views, &opts, s, Some(s + 1)).unwrap() {
                samples += done.stats.samples;
            }
        }
        if let Some((_, done)) = trainer.settle().unwrap() {
            samples += done.stats.samples;
        }
        let dt = t0.elapsed().as_secs_f64();
        let rate = samples as f64 / dt;
        rates.push(rate);
        println!(
            "GPU, {rays} rays/step: {:.3} s/step, {:.0} samples/step, {:.0} forward+backward samples/s over {steps} steps, {:.2} host waits per step ({:.2} draining the device); {:.1} dispatches in {:.1} compute passes and {:.1} queue writes per step",
            dt / steps as f64,
            samples as f64 / steps as f64,
            rate,
            (ctx.host_waits() - waits) as f64 / steps as f64,
            (ctx.draining_waits() - draining) as f64 / steps as f64,
            (ctx.recording_stats().dispatches - recorded.dispatches) as f64 / steps as f64,
            (ctx.recording_stats().passes - recorded.passes) as f64 / steps as f64,
            (ctx.recording_stats().queue_writes - recorded.queue_writes) as f64 / steps as f64
        );
    }
    let params = field.init_params(1);
    let occ = OccupancyGrid::full(64);
    let cams: Vec<Camera> = views.iter().map(|v| v.camera.clone()).collect();
    let rays: usize = cams.iter().map(|c| (c.width * c.height) as usize).sum();
    render_cameras_gpu(&ctx, field, &params, &occ, &cams[..1], [0.0; 3]).unwrap();
    let t0 = Instant::now();
    render_cameras_gpu(&ctx, field, &params, &occ, &cams, [0.0; 3]).unwrap();
    let gpu_render = rays as f64 / t0.elapsed().as_secs_f64();
    let t0 = Instant::now();
    for c in &cams {
        train::render_camera(field, &params, &occ, c, [0.0; 3], 256);
    }
    let cpu_render = rays as f64 / t0.elapsed().as_secs_f64();
    println!(
        "render, {} views of 128×96 (untrained field, every cell occupied): GPU {gpu_render:.0} rays/s, CPU {cpu_render:.0} rays/s",
        cams.len()
    );
    (
        "hash-grid field on the GPU, forward+backward".into(),
        format!(
            "{:.2} M samples/s with 1,024-ray steps, {:.2} M with 4,096; renders {:.0} rays/s (CPU {:.0})",
            rates[0] / 1e6,
            rates[1] / 1e6,
            gpu_render,
            cpu_render
        ),
        rates[0],
        "samples/s",
    )
}
