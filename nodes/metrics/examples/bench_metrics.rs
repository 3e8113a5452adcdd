//! Benchmark: SSIM, LPIPS-alex and LPIPS-vgg for one image pair (default: two 800×533 bonsai
//! photos from the shared data), on a rayon pool of `--threads N` (default 2).
//!
//! `cargo run --release -p augsplat-metrics --example bench_metrics -- [--threads N]
//! [--what psnr,ssim,alex,vgg] [A B] [--json PATH]`
//!
//! `--json PATH` also writes the best wall times as a `BenchRecord` (`docs/figures/`), its
//! value LPIPS-alex's (the metric `Evaluate` runs by default) when measured, else the first.

use augsplat_core::bench_record::{self, BenchRecord};
use augsplat_core::image::read_rgb;
use augsplat_metrics::lpips::{Backbone, Lpips};
use std::path::PathBuf;
use std::time::Instant;

/// CPU time of the whole process (all threads), in seconds.
fn cpu_seconds() -> f64 {
    let mut ts = libc::timespec {
        tv_sec: 0,
        tv_nsec: 0,
    };
    // SAFETY: clock_gettime writes into the timespec we pass.
    unsafe { libc::clock_gettime(libc::CLOCK_PROCESS_CPUTIME_ID, &mut ts) };
    ts.tv_sec as f64 + ts.tv_nsec as f64 * 1e-9
}

fn main() {
    let (mut args, json) = bench_record::args_and_json();
    let command = bench_record::example_command("augsplat-metrics", "bench_metrics", &args);
    let mut threads = 2;
    if let Some(i) = args.iter().position(|a| a == "--threads") {
        threads = args
            .get(i + 1)
            .and_then(|v| v.parse().ok())
            .expect("--threads N");
        args.drain(i..i + 2);
    }
    let mut what = "psnr,ssim,alex,vgg".to_string();
    if let Some(i) = args.iter().position(|a| a == "--what") {
        what = args.get(i + 1).cloned().expect("--what LIST");
        args.drain(i..i + 2);
    }
    let data = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../../../shared/data");
    let (pa, pb) = match args.as_slice() {
        [a, b] => (PathBuf::from(a), PathBuf::from(b)),
        _ => {
            let dir = data.join("bonsai/images");
            let mut files: Vec<_> = std::fs::read_dir(&dir)
                .unwrap_or_else(|e| panic!("{}: {e}", dir.display()))
                .filter_map(|e| e.ok().map(|e| e.path()))
                .collect();
            files.sort();
            (files[0].clone(), files[1].clone())
        }
    };
    let a = read_rgb(&pa).expect("first image");
    let b = read_rgb(&pb).expect("second image");
    println!(
        "load average: {}",
        std::fs::read_to_string("/proc/loadavg")
            .unwrap_or_default()
            .trim()
    );
    println!(
        "images {}×{} ({} / {}), {threads} threads, tier {}",
        a.width,
        a.height,
        pa.display(),
        pb.display(),
        augsplat_core::simd::active()
    );
    let pool = rayon::ThreadPoolBuilder::new()
        .num_threads(threads)
        .build()
        .expect("thread pool");
    // (metric, best wall seconds)
    let mut results: Vec<(String, f64)> = Vec::new();
    pool.install(|| {
        let mut time = |name: &str, reps: usize, f: &dyn Fn() -> f64| {
            let v = f(); // warm-up
            let mut best = f64::INFINITY;
            let mut total = 0.0;
            let mut best_cpu = f64::INFINITY;
            for _ in 0..reps {
                let (t, c) = (Instant::now(), cpu_seconds());
                let _ = f();
                let s = t.elapsed().as_secs_f64();
                best_cpu = best_cpu.min(cpu_seconds() - c);
                best = best.min(s);
                total += s;
            }
            println!(
                "{name:<12} value {v:.6}  wall best {:.2} ms  mean {:.2} ms  cpu best {:.2} ms  ({reps} runs)",
                best * 1e3,
                total / reps as f64 * 1e3,
                best_cpu * 1e3
            );
            results.push((name.to_string(), best));
        };
        if what.contains("psnr") {
            time("psnr", 20, &|| augsplat_metrics::psnr(&a, &b).unwrap());
        }
        if what.contains("ssim") {
            time("ssim", 20, &|| augsplat_metrics::ssim(&a, &b).unwrap());
        }
        for bb in [Backbone::Alex, Backbone::Vgg] {
            if !what.contains(bb.name()) {
                continue;
            }
            let w = data.join("lpips").join(bb.file_name());
            let Ok(model) = Lpips::load(&w) else {
                println!("lpips-{bb}: weights not found at {}", w.display());
                continue;
            };
            let reps = if bb == Backbone::Alex { 5 } else { 2 };
            time(&format!("lpips-{bb}"), reps, &|| {
                model.distance(&a, &b).unwrap()
            });
        }
    });
    let Some(&(ref name, best)) = results
        .iter()
        .find(|(n, _)| n == "lpips-alex")
        .or(results.first())
    else {
        return;
    };
    let figure: Vec<String> = results
        .iter()
        .map(|(n, s)| format!("{n} {:.2} ms", s * 1e3))
        .collect();
    let record = BenchRecord::now(
        format!(
            "{name} of one {}×{} image pair, {threads} threads",
            a.width, a.height
        ),
        command,
        format!("{} (best wall time)", figure.join(", ")),
        best * 1e3,
        "ms",
    );
    record.write_or_exit(json.as_deref());
}
