//! Benchmark of one full training step (render → loss (L2 + SSIM) → backward → gradient sum →
//! Adam → densification statistics) and of its parts, for N Gaussians at W×H.
//!
//! `cargo run --release -p augsplat-splat --example train_step_bench -- [N ...] [--size WxH] [--steps S] [--threads T] [--kernels]`
//! Defaults: N = 20000 100000 500000, 256×256, 10 timed steps after 2 warm-up steps, all threads.
//! The whole step's median and best time are printed first (the machine is shared: the
//! median resists other load), then the mean time of each part, then the CPU time per step
//! (stolen time excluded) and the share of the host's CPU time stolen meanwhile.
//! With `--kernels`, the loss (L2 + 0.2·SSIM) and the Adam step are also timed in isolation
//! (`--steps` repetitions each on a fixed render and fixed gradients; min and median
//! reported, which is robust to a loaded machine).
//! With `--accumulate K`, the gradient sum of K renders of the view (a Staged/Dual synthetic
//! batch) is also timed both ways: `backward` into fresh buffers then added to the sum with
//! `train::add_grads` (the trainer's former path), vs `backward_add` straight into the sum
//! (min and median of `--steps` repetitions).
//! With `--json PATH`, the first N's step median is also written as a
//! [`BenchRecord`] (`docs/figures/`).
//! Gaussians are random in a box in front of the camera (isotropic-ish, scale ~ 1–3 px),
//! the target image a smooth gradient.

use augsplat_core::bench_record::{self, BenchRecord};
use augsplat_core::cputime::Usage;
use augsplat_core::Camera;
use augsplat_splat::adam::{Adam, LearningRates, ParamGrads};
use augsplat_splat::densify::Densifier;
use augsplat_splat::loss::{self, PixelLoss};
use augsplat_splat::train::add_grads;
use augsplat_splat::{backward, backward_add, render, Gaussians, RenderSettings};
use std::time::Instant;

fn scene(n: usize, w: u32, h: u32, seed: u64) -> (Gaussians, Camera, Vec<f32>) {
    let cam = Camera {
        width: w,
        height: h,
        fx: w as f64 * 0.9,
        fy: w as f64 * 0.9,
        cx: w as f64 / 2.0,
        cy: h as f64 / 2.0,
        world_to_camera: [
            [1.0, 0.0, 0.0, 0.0],
            [0.0, 1.0, 0.0, 0.0],
            [0.0, 0.0, 1.0, 4.0],
            [0.0, 0.0, 0.0, 1.0],
        ],
    };
    // Typical 3DGS mid-training density: scales such that footprints are a few pixels.
    let px = 4.0 / (w as f64 * 0.9); // world size of one pixel at depth 4
    let g = Gaussians::random_cloud(n, px, seed);
    let target: Vec<f32> = (0..(w * h) as usize)
        .flat_map(|p| {
            let (x, y) = (
                (p % w as usize) as f32 / w as f32,
                (p / w as usize) as f32 / h as f32,
            );
            [x, y, 0.5 * (x + y)]
        })
        .collect();
    (g, cam, target)
}

fn main() {
    let mut ns: Vec<usize> = Vec::new();
    let (mut w, mut h, mut steps, mut threads) = (256u32, 256u32, 10usize, 0usize);
    let mut kernels = false;
    let mut accumulate = 0usize;
    let (argv, json) = bench_record::args_and_json();
    let mut it = argv.clone().into_iter();
    while let Some(a) = it.next() {
        match a.as_str() {
            "--size" => {
                let v = it.next().expect("--size WxH");
                let (a, b) = v.split_once('x').expect("WxH");
                w = a.parse().unwrap();
                h = b.parse().unwrap();
            }
            "--steps" => steps = it.next().unwrap().parse().unwrap(),
            "--threads" => threads = it.next().unwrap().parse().unwrap(),
            "--kernels" => kernels = true,
            "--accumulate" => accumulate = it.next().unwrap().parse().unwrap(),
            n => ns.push(n.parse().expect("a Gaussian count")),
        }
    }
    if ns.is_empty() {
        ns = vec![20_000, 100_000, 500_000];
    }
    let pool = rayon::ThreadPoolBuilder::new()
        .num_threads(threads)
        .build()
        .unwrap();
    let mut headline: Option<(usize, f64)> = None;
    pool.install(|| {
        println!("{} threads, {w}×{h}, {steps} timed steps", rayon::current_num_threads());
        for &n in &ns {
            let (mut g, cam, target) = scene(n, w, h, 1);
            let s = RenderSettings::default();
            let lr = LearningRates::default();
            let mut adam = Adam::new(n, g.coeffs());
            let mut dens = Densifier::new(n);
            let mut d_rgb = vec![0f32; target.len()];
            let mut t = [0f64; 6];
            let mut pairs = 0u64;
            let mut step_ms: Vec<f64> = Vec::with_capacity(steps);
            let mut usage = None;
            for step in 0..steps + 2 {
                if step == 2 {
                    usage = Some(Usage::start());
                }
                let t0 = Instant::now();
                let out = render(&g, &cam, &s);
                let t1 = Instant::now();
                d_rgb.iter_mut().for_each(|v| *v = 0.0);
                loss::photometric(&out.rgb, &target, w as usize, h as usize, PixelLoss::L2, 0.2, 1.0, &mut d_rgb);
                let t2 = Instant::now();
                let gr = backward(&g, &cam, &s, &out, &d_rgb, None, None);
                let t3 = Instant::now();
                let pg = ParamGrads {
                    means: gr.means,
                    log_scales: gr.log_scales,
                    quats: gr.quats,
                    opacity_logits: gr.opacity_logits,
                    sh: gr.sh,
                    visible: gr.visible.clone(),
                    sh_active: usize::MAX,
                };
                let t4 = Instant::now();
                adam.step(&mut g, &pg, &lr, 1.6e-4);
                let t5 = Instant::now();
                dens.accumulate(&gr.means2d_abs, &gr.visible);
                let t6 = Instant::now();
                if step >= 2 {
                    step_ms.push((t6 - t0).as_secs_f64() * 1e3);
                    for (k, (a, b)) in [(t0, t1), (t1, t2), (t2, t3), (t3, t4), (t4, t5), (t5, t6)].iter().enumerate() {
                        t[k] += (*b - *a).as_secs_f64();
                    }
                    pairs += out.stats.pairs;
                }
            }
            let used = usage.map(|u| u.stop());
            let ms = |v: f64| v / steps as f64 * 1e3;
            let total: f64 = t.iter().sum();
            step_ms.sort_by(f64::total_cmp);
            headline.get_or_insert((n, step_ms[step_ms.len() / 2]));
            println!(
                "N={n:>7}: step median {:.2} ms, best {:.2} ms; means: step {:7.2} ms | forward {:6.2} | loss(L2+SSIM) {:5.2} | backward {:7.2} | grad move {:4.2} | adam {:5.2} | densify stat {:4.2} ms | {:.1} M pairs/step, {:.2} ns/pair (fwd+bwd)",
                step_ms[step_ms.len() / 2],
                step_ms[0],
                ms(total),
                ms(t[0]),
                ms(t[1]),
                ms(t[2]),
                ms(t[3]),
                ms(t[4]),
                ms(t[5]),
                pairs as f64 / steps as f64 / 1e6,
                (t[0] + t[2]) / pairs.max(1) as f64 * 1e9
            );
            if let Some(u) = used {
                // The host may run other guests on our virtual CPUs: CPU time per step (stolen
                // time excluded) says what the code costs; over `threads` it is the step time
                // those threads would take with their cores to themselves, if fully parallel.
                let threads = rayon::current_num_threads() as f64;
                if let Some(cpu) = u.cpu_s {
                    println!(
                        "    CPU {:.2} ms/step over all threads, i.e. {:.2} ms/step on {threads} unshared cores if fully parallel; {}",
                        cpu / steps as f64 * 1e3,
                        cpu / steps as f64 / threads * 1e3,
                        u.describe()
                    );
                }
            }
            if kernels {
                kernel_times(&g, &cam, &target, &s, &lr, steps);
            }
            if accumulate > 0 {
                accumulate_times(&g, &cam, &target, &s, accumulate, steps);
            }
        }
    });
    if let Some((n, median)) = headline {
        let threads = pool.current_num_threads();
        BenchRecord::now(
            format!("splat training step, {n} Gaussians, {w}×{h}"),
            bench_record::example_command("augsplat-splat", "train_step_bench", &argv),
            format!("median {median:.2} ms per step over {steps} steps, {threads} threads"),
            median,
            "ms",
        )
        .write_or_exit(json.as_deref());
    }
}

/// Min and median of `reps` timings of `f`, in ms.
fn time_min_median(reps: usize, mut f: impl FnMut()) -> (f64, f64) {
    let mut v: Vec<f64> = (0..reps.max(1))
        .map(|_| {
            let t = Instant::now();
            f();
            t.elapsed().as_secs_f64() * 1e3
        })
        .collect();
    v.sort_by(|a, b| a.total_cmp(b));
    (v[0], v[v.len() / 2])
}

/// Times the loss and the Adam step in isolation on one render of `g`.
fn kernel_times(
    g: &Gaussians,
    cam: &Camera,
    target: &[f32],
    s: &RenderSettings,
    lr: &LearningRates,
    reps: usize,
) {
    let (w, h) = (cam.width as usize, cam.height as usize);
    let out = render(g, cam, s);
    let mut d_rgb = vec![0f32; target.len()];
    let (lmin, lmed) = time_min_median(reps * 5, || {
        loss::photometric(&out.rgb, target, w, h, PixelLoss::L2, 0.2, 1.0, &mut d_rgb);
    });
    d_rgb.iter_mut().for_each(|v| *v = 0.0);
    loss::photometric(&out.rgb, target, w, h, PixelLoss::L2, 0.2, 1.0, &mut d_rgb);
    let gr = backward(g, cam, s, &out, &d_rgb, None, None);
    let visible = gr.visible.iter().filter(|&&v| v).count();
    let pg = ParamGrads {
        means: gr.means,
        log_scales: gr.log_scales,
        quats: gr.quats,
        opacity_logits: gr.opacity_logits,
        sh: gr.sh,
        visible: gr.visible,
        sh_active: usize::MAX,
    };
    let mut g2 = g.clone();
    let mut adam = Adam::new(g.len(), g.coeffs());
    let (amin, amed) = time_min_median(reps * 5, || {
        adam.step(&mut g2, &pg, lr, 1.6e-4);
    });
    println!(
        "    kernels: loss min {lmin:.3} ms, median {lmed:.3} | adam min {amin:.3} ms, median {amed:.3} ({visible} of {} visible, {:.2} M parameters updated)",
        g.len(),
        visible as f64 * (10 + g.coeffs() * 3) as f64 / 1e6
    );
}

/// Times the gradient sum of `k` renders of `cam` (render + loss + backward each): fresh
/// buffers added to the sum vs `backward_add`.
fn accumulate_times(
    g: &Gaussians,
    cam: &Camera,
    target: &[f32],
    s: &RenderSettings,
    k: usize,
    reps: usize,
) {
    let (w, h) = (cam.width as usize, cam.height as usize);
    let n = g.len();
    let mut d_rgb = vec![0f32; target.len()];
    let mut one = |acc: &mut ParamGrads, fresh: bool| {
        let out = render(g, cam, s);
        d_rgb.iter_mut().for_each(|v| *v = 0.0);
        loss::photometric(&out.rgb, target, w, h, PixelLoss::L2, 0.0, 1.0, &mut d_rgb);
        if fresh {
            let gr = backward(g, cam, s, &out, &d_rgb, None, None);
            add_grads(acc, &gr, usize::MAX);
        } else {
            backward_add(g, cam, &out, &d_rgb, acc);
        }
    };
    // Interleaved (rep r times both ways), so a busy machine biases neither.
    let mut samples = [Vec::new(), Vec::new()];
    for _ in 0..reps.max(1) {
        for (v, fresh) in samples.iter_mut().zip([true, false]) {
            let t = Instant::now();
            let mut acc = ParamGrads::zeros(n, g.coeffs());
            for _ in 0..k {
                one(&mut acc, fresh);
            }
            v.push(t.elapsed().as_secs_f64() * 1e3);
        }
    }
    let times: Vec<(f64, f64)> = samples
        .iter_mut()
        .map(|v| {
            v.sort_by(|a, b| a.total_cmp(b));
            (v[0], v[v.len() / 2])
        })
        .collect();
    println!(
        "    sum of {k} renders: fresh buffers + add min {:.2} ms, median {:.2} | backward_add min {:.2} ms, median {:.2} (per render {:.2} vs {:.2} ms)",
        times[0].0,
        times[0].1,
        times[1].0,
        times[1].1,
        times[0].0 / k as f64,
        times[1].0 / k as f64
    );
}
