//! What the GPU backward's determinism costs: the deterministic compositing backward
//! (`backward_gpu`: each (tile, Gaussian) pair's pixels summed in a fixed order — the tile's
//! columns, then the column sums — into the pair's slot, then a second pass adding each
//! Gaussian's slots in tile order) against a float-atomic variant written only for this
//! comparison (`backward_gpu_atomic`: the same per-tile sums, then a compare-exchange float
//! add straight into the Gaussian's slot; no pair buffer, no second pass).
//!
//! Both are timed through `backward_gpu_timed`, which runs the same code as `backward_gpu` /
//! `backward_gpu_atomic` and also reports the (tile, Gaussian) pair count and the wall time
//! of the one submission where the two differ. Per row: the median of REPS runs of the
//! whole call (forward kernels, compositing backward, projection backward, read-backs; the
//! model already uploaded) and of that stage alone, the extra memory of the deterministic
//! path's pair buffer (10 f32 per pair), and whether the atomic runs gave the same bytes
//! every time. Runs alternate between the two variants after one warm-up of each. Scene and
//! camera as in `gpu_raster` (10 000 Gaussians is the `train_step_bench` scene).
//!
//! `cargo run --release -p augsplat-render --example gpu_determinism_cost [-- N,N,... [WxH,...] [REPS]]`
//! Defaults: 10000 at 256x256, 7 repetitions. `WGPU_BACKEND` picks the API.

use augsplat_render::gpu::{backward_gpu_timed, GpuScene, ParamGradsGpu};
use augsplat_render::{Gaussians, RenderSettings};
use std::time::Instant;

#[path = "common/gpu_bench.rs"]
mod gpu_bench;
use gpu_bench::median;

/// The bits of every gradient of a run, for comparing runs.
fn bits(g: &ParamGradsGpu) -> Vec<u32> {
    g.params
        .iter()
        .chain(&g.sh)
        .chain(g.means2d.iter().flatten())
        .map(|x| x.to_bits())
        .collect()
}

/// Largest |a − b| over all parameter and SH gradients, relative to the largest |b|.
fn relative(a: &ParamGradsGpu, b: &ParamGradsGpu) -> f64 {
    let (mut worst, mut scale) = (0.0f64, 0.0f64);
    for (x, y) in a
        .params
        .iter()
        .chain(&a.sh)
        .zip(b.params.iter().chain(&b.sh))
    {
        worst = worst.max((f64::from(*x) - f64::from(*y)).abs());
        scale = scale.max(f64::from(*y).abs());
    }
    if scale > 0.0 {
        worst / scale
    } else {
        worst
    }
}

fn main() {
    let a = gpu_bench::args(7);
    let (counts, sizes, reps) = (a.counts.clone(), a.sizes.clone(), a.reps);
    let mut headline = None;
    let ctx = gpu_bench::context();
    println!("adapter: {}", ctx.adapter());
    println!("median of {reps} runs; \"stage\" is the compositing backward's submission alone\n");
    println!(
        "| Gaussians | image | pairs | deterministic ms | atomic ms | det/atomic \
         | det. stage ms | atomic stage ms | stage det/atomic | pair buffer MiB \
         | atomic bit-identical | max rel. diff |"
    );
    println!("|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|:---:|---:|");
    let s = RenderSettings::default();
    for &(w, h) in &sizes {
        let cam = gpu_bench::bench_camera(w, h);
        for &n in &counts {
            let g = Gaussians::random_cloud(n, 4.0 / cam.fx, 7);
            let scene = match GpuScene::upload(&ctx, &g) {
                Ok(sc) => sc,
                Err(e) => {
                    eprintln!("{n} Gaussians: {e}");
                    std::process::exit(1);
                }
            };
            let d_rgb = vec![1e-3f32; 3 * w as usize * h as usize];
            let run = |atomic: bool| {
                let t = Instant::now();
                match backward_gpu_timed(&ctx, &scene, &cam, &s, &d_rgb, atomic) {
                    Ok((grads, stage)) => (grads, stage, t.elapsed().as_secs_f64() * 1e3),
                    Err(e) => {
                        eprintln!("{n} Gaussians at {w}x{h}, atomic {atomic}: {e}");
                        std::process::exit(1);
                    }
                }
            };
            // Warm-up: pipelines, allocator and caches.
            let (det_ref, stage, _) = run(false);
            let (atomic_ref, _, _) = run(true);
            let pairs = stage.pairs;
            let det_bits = bits(&det_ref);
            let atomic_bits = bits(&atomic_ref);
            let (mut td, mut ta, mut sd, mut sa) = (Vec::new(), Vec::new(), Vec::new(), Vec::new());
            let mut atomic_same = true;
            let mut det_same = true;
            for _ in 0..reps {
                let (gd, stg, t) = run(false);
                td.push(t);
                sd.push(stg.kernels.as_secs_f64() * 1e3);
                det_same &= bits(&gd) == det_bits;
                let (ga, sta, t) = run(true);
                ta.push(t);
                sa.push(sta.kernels.as_secs_f64() * 1e3);
                atomic_same &= bits(&ga) == atomic_bits;
            }
            assert!(det_same, "the deterministic backward changed between runs");
            let (md, ma, msd, msa) = (median(td), median(ta), median(sd), median(sa));
            let mib = 10.0 * 4.0 * f64::from(pairs) / (1024.0 * 1024.0);
            headline.get_or_insert((n, w, h, msd, msa, mib));
            println!(
                "| {n} | {w}x{h} | {pairs} | {md:.1} | {ma:.1} | {:.2} | {msd:.1} | {msa:.1} \
                 | {:.2} | {mib:.2} | {} | {:.1e} |",
                md / ma,
                msd / msa,
                if atomic_same { "yes" } else { "no" },
                relative(&atomic_ref, &det_ref)
            );
        }
    }
    if let Some((n, w, h, msd, msa, mib)) = headline {
        gpu_bench::record(
            &ctx,
            &a,
            ("augsplat-render", "gpu_determinism_cost"),
            (
                format!("cost of the deterministic GPU backward, {n} Gaussians at {w}×{h}"),
                format!(
                    "compositing backward {msd:.2} ms deterministic vs {msa:.2} ms float-atomic (medians of {reps}); pair buffer {mib:.1} MiB"
                ),
            ),
            (100.0 * (msd / msa - 1.0), "%"),
        );
    }
}
