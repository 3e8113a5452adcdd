//! GPU forward and backward passes against the CPU's: the median time of `render_gpu`
//! (uploads, kernels and read-back of the image: a whole render as `augsplat render` or
//! `Evaluate` does it), of `backward_gpu` (forward kernels, backward kernels and read-back of
//! the gradients, the model already uploaded) and of the CPU's `render` and
//! `render` + `backward`, for the scene of `train_step_bench` (a box 4 units in front of the
//! camera, footprints of 1–3 pixels' scale, SH degree 3).
//!
//! `cargo run --release -p augsplat-render --example gpu_raster [-- N,N,... [WxH,...] [REPS]]`
//! Defaults: 10000 at 256x256, 5 repetitions. `WGPU_BACKEND` picks the API.

use augsplat_render::gpu::{backward_gpu, render_gpu, GpuScene};
use augsplat_render::{backward, render, Gaussians, RenderSettings};
use std::time::Instant;

#[path = "common/gpu_bench.rs"]
mod gpu_bench;
use gpu_bench::median;

fn main() {
    let a = gpu_bench::args(5);
    let (counts, sizes, reps) = (a.counts.clone(), a.sizes.clone(), a.reps);
    let mut headline = None;
    let ctx = gpu_bench::context();
    println!("adapter: {}", ctx.adapter());
    println!("CPU threads: {}", rayon::current_num_threads());
    println!(
        "{:>9} {:>10} {:>11} {:>11} {:>11} {:>11} {:>10} {:>12} {:>9}",
        "N",
        "image",
        "GPU f ms",
        "CPU f ms",
        "GPU f+b ms",
        "CPU f+b ms",
        "pairs",
        "max |Δ| rgb",
        "> 1e-4"
    );
    let s = RenderSettings::default();
    for &(w, h) in &sizes {
        let cam = gpu_bench::bench_camera(w, h);
        for &n in &counts {
            let g = Gaussians::random_cloud(n, 4.0 / cam.fx, 7);
            let warm = render_gpu(&ctx, &g, &cam, &s).expect("GPU render");
            let mut tg = Vec::new();
            let mut tc = Vec::new();
            let scene = GpuScene::upload(&ctx, &g).expect("upload");
            let d_rgb = vec![1e-3f32; 3 * w as usize * h as usize];
            let mut tgb = Vec::new();
            let mut tcb = Vec::new();
            let mut worst = 0.0f32;
            let mut over = 0usize;
            for _ in 0..reps {
                let t = Instant::now();
                let f = render_gpu(&ctx, &g, &cam, &s).expect("GPU render");
                tg.push(t.elapsed().as_secs_f64() * 1e3);
                let t = Instant::now();
                let c = render(&g, &cam, &s);
                tc.push(t.elapsed().as_secs_f64() * 1e3);
                let t = Instant::now();
                backward_gpu(&ctx, &scene, &cam, &s, &d_rgb).expect("GPU backward");
                tgb.push(t.elapsed().as_secs_f64() * 1e3);
                let t = Instant::now();
                let out = render(&g, &cam, &s);
                let _ = backward(&g, &cam, &s, &out, &d_rgb, None, None);
                tcb.push(t.elapsed().as_secs_f64() * 1e3);
                let d: Vec<f32> = f
                    .rgb
                    .iter()
                    .zip(&c.rgb)
                    .map(|(a, b)| (a - b).abs())
                    .collect();
                worst = d.iter().copied().fold(worst, f32::max);
                over = d.iter().filter(|v| **v > 1e-4).count();
            }
            let (gf, cf, gb, cb) = (median(tg), median(tc), median(tgb), median(tcb));
            headline.get_or_insert((n, w, h, gf, cf, gb, cb));
            println!(
                "{n:>9} {:>10} {:>11.2} {:>11.2} {:>11.2} {:>11.2} {:>10} {:>12.2e} {:>9}",
                format!("{w}x{h}"),
                gf,
                cf,
                gb,
                cb,
                warm.stats.pairs,
                worst,
                over
            );
        }
    }
    if let Some((n, w, h, gf, cf, gb, cb)) = headline {
        gpu_bench::record(
            &ctx,
            &a,
            ("augsplat-render", "gpu_raster"),
            (
                format!("GPU render and backward, {n} Gaussians at {w}×{h}"),
                format!(
                    "render {gf:.2} ms, render+backward {gb:.2} ms (medians of {reps}); CPU {cf:.2} / {cb:.2} ms"
                ),
            ),
            (gf, "ms"),
        );
    }
}
