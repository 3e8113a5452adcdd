//! Times each AlexNet / VGG16 convolution of LPIPS for an 800×533 input with random weights
//! and reports GFLOP/s (2 threads by default; `--threads N`).
//!
//! `cargo run --release -p augsplat-metrics --example bench_conv -- [--threads N] [--vgg]
//! [--json PATH]` (`--json`: the total as a `BenchRecord`, for `docs/figures/`)

use augsplat_core::bench_record::{self, BenchRecord};
use augsplat_metrics::gemm::{conv2d_relu, out_size, PackedWeights};
use std::time::Instant;

fn main() {
    let (args, json) = bench_record::args_and_json();
    let threads = args
        .iter()
        .position(|a| a == "--threads")
        .and_then(|i| args.get(i + 1)?.parse().ok())
        .unwrap_or(2);
    let vgg = args.iter().any(|a| a == "--vgg");
    // (c_in, h, w, m, k, stride, pad)
    let layers: Vec<(usize, usize, usize, usize, usize, usize, usize)> = if vgg {
        vec![
            (3, 533, 800, 64, 3, 1, 1),
            (64, 533, 800, 64, 3, 1, 1),
            (64, 266, 400, 128, 3, 1, 1),
            (128, 266, 400, 128, 3, 1, 1),
            (128, 133, 200, 256, 3, 1, 1),
            (256, 133, 200, 256, 3, 1, 1),
            (256, 66, 100, 512, 3, 1, 1),
            (512, 66, 100, 512, 3, 1, 1),
            (512, 33, 50, 512, 3, 1, 1),
        ]
    } else {
        vec![
            (3, 533, 800, 64, 11, 4, 2),
            (64, 65, 99, 192, 5, 1, 2),
            (192, 32, 49, 384, 3, 1, 1),
            (384, 32, 49, 256, 3, 1, 1),
            (256, 32, 49, 256, 3, 1, 1),
        ]
    };
    let pool = rayon::ThreadPoolBuilder::new()
        .num_threads(threads)
        .build()
        .expect("pool");
    let (total, flops) = pool.install(|| {
        let (mut total, mut all_flops) = (0.0, 0.0);
        for (c_in, h, w, m, k, s, p) in layers {
            let mut rng = augsplat_core::Rng::new(1);
            let input: Vec<f32> = (0..c_in * h * w).map(|_| rng.next_f32()).collect();
            let wts: Vec<f32> = (0..m * c_in * k * k)
                .map(|_| rng.next_f32() - 0.5)
                .collect();
            let bias = vec![0.0; m];
            let packed = PackedWeights::new(&wts, &bias, m, c_in, k, k);
            let n = out_size(h, k, s, p).unwrap() * out_size(w, k, s, p).unwrap();
            let flops = 2.0 * (m * c_in * k * k * n) as f64;
            let _ = conv2d_relu(&input, h, w, &packed, s, p);
            let mut best = f64::INFINITY;
            for _ in 0..3 {
                let t = Instant::now();
                let _ = conv2d_relu(&input, h, w, &packed, s, p);
                best = best.min(t.elapsed().as_secs_f64());
            }
            total += best;
            all_flops += flops;
            println!(
                "{c_in:>4}→{m:<4} k{k} {h}×{w}: {:7.2} ms  {:6.1} GFLOP/s",
                best * 1e3,
                flops / best * 1e-9
            );
        }
        println!("total (one image) {:.1} ms", total * 1e3);
        (total, all_flops)
    });
    let net = if vgg { "VGG16" } else { "AlexNet" };
    let record = BenchRecord::now(
        format!("LPIPS {net} convolutions of one 800×533 image, {threads} threads"),
        bench_record::example_command("augsplat-metrics", "bench_conv", &args),
        format!(
            "{:.1} ms, {:.1} GFLOP/s over the layers (best of 3 each)",
            total * 1e3,
            flops / total * 1e-9
        ),
        total * 1e3,
        "ms",
    );
    record.write_or_exit(json.as_deref());
}
