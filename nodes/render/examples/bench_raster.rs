//! Rasteriser benchmark: forward and forward+backward for 10k, 100k and 500k Gaussians at
//! 256×256 and 800×533, with the time per composited (Gaussian, pixel) pair.
//!
//! `cargo run --release -p augsplat-render --example bench_raster [-- N,N,... [REPS] [--scene box|step] [--size WxH,...]]`
//! (threads: `RAYON_NUM_THREADS`, default all cores). `--json PATH` also writes the first
//! case's forward+backward time as a [`BenchRecord`] (`docs/figures/`).
//!
//! Scenes: `box` (default) fills a box in front of the camera with Gaussians sized to the mean
//! spacing; `step` is the scene of `train_step_bench` (footprints of 1–3 pixels' scale).
//! Times are the minimum over the repetitions, both wall-clock and CPU time of all threads
//! (Linux schedstat; it sees through a machine shared with other jobs better than wall time).

use augsplat_core::bench_record::{self, BenchRecord};
use augsplat_core::linalg::mat4_from_rt;
use augsplat_core::{Camera, Rng};
use augsplat_render::{backward, render, Gaussians, RenderSettings};
use std::time::Instant;

/// Gaussians filling a box in front of the camera, sized to the mean spacing (as a trained
/// scene roughly is), SH degree 3.
fn box_scene(n: usize, seed: u64) -> Gaussians {
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

fn box_camera(w: u32, h: u32) -> Camera {
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

/// The scene of `train_step_bench`: a cube of side 4 centred 4 units in front of the camera,
/// scales of 0.7–3 pixels at that depth, random rotations near identity, SH degree 3.
fn step_scene(n: usize, w: u32, h: u32, seed: u64) -> (Gaussians, Camera) {
    let cam = Camera {
        width: w,
        height: h,
        fx: w as f64 * 0.9,
        fy: w as f64 * 0.9,
        cx: w as f64 / 2.0,
        cy: h as f64 / 2.0,
        world_to_camera: mat4_from_rt(
            &[[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]],
            [0.0, 0.0, 4.0],
        ),
    };
    // Typical 3DGS mid-training density: scales such that footprints are a few pixels.
    let px = 4.0 / (w as f64 * 0.9); // world size of one pixel at depth 4
    let g = Gaussians::random_cloud(n, px, seed);
    (g, cam)
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
    let mut sizes: Vec<usize> = vec![10_000, 100_000, 500_000];
    let mut reps = 5usize;
    let mut step = false;
    let mut images: Vec<(u32, u32)> = vec![(256, 256), (800, 533)];
    let mut positional = 0;
    let (argv, json) = bench_record::args_and_json();
    let mut args = argv.clone().into_iter();
    while let Some(a) = args.next() {
        match a.as_str() {
            "--scene" => step = args.next().as_deref() == Some("step"),
            "--size" => {
                let v = args.next().unwrap_or_default();
                images = v
                    .split(',')
                    .filter_map(|s| {
                        let (w, h) = s.split_once('x')?;
                        Some((w.parse().ok()?, h.parse().ok()?))
                    })
                    .collect();
            }
            _ => {
                if positional == 0 {
                    sizes = a.split(',').filter_map(|s| s.parse().ok()).collect();
                } else if let Ok(r) = a.parse() {
                    reps = r;
                }
                positional += 1;
            }
        }
    }
    println!(
        "threads: {}, scene: {}, min over {reps} reps",
        rayon::current_num_threads(),
        if step { "step" } else { "box" }
    );
    println!(
        "{:>8} {:>9} {:>8} {:>8} {:>10} {:>10} {:>9} {:>10} {:>10} {:>10}",
        "N",
        "image",
        "fwd ms",
        "bwd ms",
        "f+b ms",
        "pairs",
        "ns/pair f",
        "ns/pair fb",
        "cpu fwd ms",
        "cpu bwd ms"
    );
    let mut headline = None;
    for &n in &sizes {
        let box_g = (!step).then(|| box_scene(n, 7));
        for &(w, h) in &images {
            let (g, cam) = match &box_g {
                Some(g) => (g.clone(), box_camera(w, h)),
                None => step_scene(n, w, h, 1),
            };
            let s = RenderSettings::default();
            let npix = (w * h) as usize;
            let d_rgb: Vec<f32> = (0..npix * 3)
                .map(|i| ((i % 11) as f32 - 5.0) * 1e-3)
                .collect();
            // Warm-up.
            let out = render(&g, &cam, &s);
            let _ = backward(&g, &cam, &s, &out, &d_rgb, None, None);
            let (mut tf, mut tb) = (f64::MAX, f64::MAX);
            let (mut cf, mut cb) = (u64::MAX, u64::MAX);
            let mut pairs = 0;
            for _ in 0..reps {
                let c0 = cpu_ns();
                let t0 = Instant::now();
                let out = render(&g, &cam, &s);
                let t1 = Instant::now();
                let c1 = cpu_ns();
                let gr = backward(&g, &cam, &s, &out, &d_rgb, None, None);
                let t2 = Instant::now();
                let c2 = cpu_ns();
                std::hint::black_box(&gr);
                pairs = out.stats.pairs;
                tf = tf.min((t1 - t0).as_secs_f64());
                tb = tb.min((t2 - t1).as_secs_f64());
                if let (Some(c0), Some(c1), Some(c2)) = (c0, c1, c2) {
                    cf = cf.min(c1 - c0);
                    cb = cb.min(c2 - c1);
                }
            }
            let cpu = |v: u64| {
                if v == u64::MAX {
                    "n/a".to_string()
                } else {
                    format!("{:.2}", v as f64 / 1e6)
                }
            };
            headline.get_or_insert((n, w, h, (tf + tb) * 1e3, pairs));
            println!(
                "{:>8} {:>9} {:>8.2} {:>8.2} {:>10.2} {:>10} {:>9.2} {:>10.2} {:>10} {:>10}",
                n,
                format!("{w}x{h}"),
                tf * 1e3,
                tb * 1e3,
                (tf + tb) * 1e3,
                pairs,
                tf * 1e9 / pairs.max(1) as f64,
                (tf + tb) * 1e9 / pairs.max(1) as f64,
                cpu(cf),
                cpu(cb),
            );
        }
    }
    if let Some((n, w, h, ms, pairs)) = headline {
        let threads = rayon::current_num_threads();
        BenchRecord::now(
            format!("rasteriser forward+backward, {n} Gaussians at {w}×{h}, {threads} threads"),
            bench_record::example_command("augsplat-render", "bench_raster", &argv),
            format!(
                "{ms:.2} ms (minimum of {reps}), {:.2} ns per composited pair",
                ms * 1e6 / pairs.max(1) as f64
            ),
            ms,
            "ms",
        )
        .write_or_exit(json.as_deref());
    }
}
