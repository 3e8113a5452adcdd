//! Rasteriser benchmark: forward and forward+backward for 10k, 100k and 500k Gaussians at
//! 256×256 and 800×533, with the time per composited (Gaussian, pixel) pair.
//!
//! `cargo run --release -p augsplat-splat --example bench_raster [-- N,N,... [REPS]]`
//! (threads: `RAYON_NUM_THREADS`, default all cores).

use augsplat_core::linalg::mat4_from_rt;
use augsplat_core::{Camera, Rng};
use augsplat_splat::{backward, render, Gaussians, RenderSettings};
use std::time::Instant;

/// Gaussians filling a box in front of the camera, sized to the mean spacing (as a trained
/// scene roughly is), SH degree 3.
fn scene(n: usize, seed: u64) -> Gaussians {
    let mut rng = Rng::new(seed);
    let mut g = Gaussians::empty(3);
    let spacing = (48.0 / n as f64).cbrt();
    for _ in 0..n {
        g.means.push([
            rng.uniform(-2.0, 2.0) as f32,
            rng.uniform(-1.5, 1.5) as f32,
            rng.uniform(3.0, 7.0) as f32,
        ]);
        let base = (0.6 * spacing).ln();
        g.log_scales.push([
            (base + rng.uniform(-0.7, 0.7)) as f32,
            (base + rng.uniform(-0.7, 0.7)) as f32,
            (base + rng.uniform(-0.7, 0.7)) as f32,
        ]);
        g.quats.push([
            rng.normal() as f32,
            rng.normal() as f32,
            rng.normal() as f32,
            rng.normal() as f32,
        ]);
        g.opacity_logits.push(rng.uniform(-2.0, 3.0) as f32);
        for j in 0..48 {
            g.sh.push((rng.normal() * if j < 3 { 0.8 } else { 0.15 }) as f32);
        }
    }
    g
}

fn camera(w: u32, h: u32) -> Camera {
    Camera {
        width: w,
        height: h,
        fx: 0.9 * w as f64,
        fy: 0.9 * w as f64,
        cx: 0.5 * w as f64,
        cy: 0.5 * h as f64,
        world_to_camera: mat4_from_rt(
            &[[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]],
            [0.0, 0.0, 0.0],
        ),
    }
}

/// CPU time (ns) consumed so far by all threads of this process (Linux schedstat), to see
/// through a machine shared with other jobs; `None` elsewhere.
fn cpu_ns() -> Option<u64> {
    let mut total = 0u64;
    for entry in std::fs::read_dir("/proc/self/task").ok()? {
        let path = entry.ok()?.path().join("schedstat");
        let text = std::fs::read_to_string(path).ok()?;
        total += text.split_whitespace().next()?.parse::<u64>().ok()?;
    }
    Some(total)
}

fn main() {
    let args: Vec<String> = std::env::args().collect();
    let sizes: Vec<usize> = args
        .get(1)
        .map(|s| s.split(',').filter_map(|v| v.parse().ok()).collect())
        .unwrap_or_else(|| vec![10_000, 100_000, 500_000]);
    let reps: usize = args.get(2).and_then(|v| v.parse().ok()).unwrap_or(5);
    println!("threads: {}", rayon::current_num_threads());
    println!(
        "{:>8} {:>9} {:>10} {:>10} {:>12} {:>10} {:>10} {:>10} {:>12}",
        "N",
        "image",
        "fwd ms",
        "bwd ms",
        "fwd+bwd ms",
        "pairs",
        "ns/pair f",
        "ns/pair fb",
        "cpu ms f+b"
    );
    for &n in &sizes {
        let g = scene(n, 7);
        for (w, h) in [(256u32, 256u32), (800, 533)] {
            let cam = camera(w, h);
            let s = RenderSettings::default();
            let npix = (w * h) as usize;
            let d_rgb: Vec<f32> = (0..npix * 3)
                .map(|i| ((i % 11) as f32 - 5.0) * 1e-3)
                .collect();
            // Warm-up.
            let out = render(&g, &cam, &s);
            let _ = backward(&g, &cam, &s, &out, &d_rgb, None, None);
            let (mut tf, mut tb) = (f64::MAX, f64::MAX);
            let mut pairs = 0;
            let c0 = cpu_ns();
            for _ in 0..reps {
                let t0 = Instant::now();
                let out = render(&g, &cam, &s);
                let t1 = Instant::now();
                let gr = backward(&g, &cam, &s, &out, &d_rgb, None, None);
                let t2 = Instant::now();
                std::hint::black_box(&gr);
                pairs = out.stats.pairs;
                tf = tf.min((t1 - t0).as_secs_f64());
                tb = tb.min((t2 - t1).as_secs_f64());
            }
            let cpu = match (c0, cpu_ns()) {
                (Some(a), Some(b)) => format!("{:.2}", (b - a) as f64 / 1e6 / reps as f64),
                _ => "n/a".into(),
            };
            println!(
                "{:>8} {:>9} {:>10.2} {:>10.2} {:>12.2} {:>10} {:>10.2} {:>10.2} {:>12}",
                n,
                format!("{w}x{h}"),
                tf * 1e3,
                tb * 1e3,
                (tf + tb) * 1e3,
                pairs,
                tf * 1e9 / pairs.max(1) as f64,
                (tf + tb) * 1e9 / pairs.max(1) as f64,
                cpu,
            );
        }
    }
}
