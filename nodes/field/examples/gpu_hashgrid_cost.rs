//! What the hash table's deterministic GPU gradients cost: the sorted sum of
//! `hashgrid/gpu.rs` (each level's (point, corner) pairs sorted by table entry, each entry
//! adding its run in the CPU's order) and the 64-bit fixed-point sum (integer atomics, order-
//! free) against a float-atomic variant written only for this comparison (`record_backward_atomic`: every term added straight into its entry with a
//! compare-exchange loop), beside the encoding's forward and the CPU's backward.
//!
//! Per row: the median wall time of REPS runs of each (after one warm-up; the points, table
//! and gradients already on the device, one submission and one wait each), samples per second,
//! the extra memory of the sorted sum (five u32/f32 words per pair and two per entry of the
//! largest level), and whether the atomic runs gave the same bytes every time. Points are
//! uniform in the cube, a quarter of them in one coarse cell (samples crowd the same entries,
//! as they do on a surface); the grid is the field's default (16 levels, 2 features, 2^17
//! entries, resolutions 16 to 2048).
//!
//! `cargo run --release -p augsplat-field --features determinism-cost --example gpu_hashgrid_cost [-- N [REPS]]`
//! Defaults: 262144 points, 5 repetitions. `WGPU_BACKEND` picks the API.

use augsplat_core::Rng;
use augsplat_field::hashgrid::gpu::{
    record_backward, record_backward_atomic, record_backward_fixed, record_encode, GpuPoints,
};
use augsplat_field::hashgrid::{HashGrid, HashGridConfig, PointBatch};
use augsplat_render::gpu::{f32_words, GpuContext};
use std::time::Instant;

/// Wall times of the runs and each run's gradient words.
type Timed = (Vec<f64>, Vec<Vec<u32>>);

fn median(mut v: Vec<f64>) -> f64 {
    v.sort_by(f64::total_cmp);
    v[v.len() / 2]
}

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let n: usize = args
        .first()
        .map(|a| a.parse())
        .transpose()?
        .unwrap_or(1 << 18);
    let reps: usize = args
        .get(1)
        .map(|a| a.parse())
        .transpose()?
        .unwrap_or(5)
        .max(1);
    let ctx = GpuContext::new()?;
    let grid = HashGrid::new(HashGridConfig::default())?;
    let mut rng = Rng::new(1);
    let mut p: [Vec<f32>; 3] = std::array::from_fn(|_| (0..n).map(|_| rng.next_f32()).collect());
    for axis in &mut p {
        for v in axis.iter_mut().take(n / 4) {
            *v = 0.4 + 0.05 * *v;
        }
    }
    let ld = n.div_ceil(16) * 16;
    let pts = PointBatch {
        px: &p[0],
        py: &p[1],
        pz: &p[2],
        n,
        ld,
    };
    let mut table = vec![0f32; grid.n_params()];
    grid.init(&mut table, &mut rng);
    let rows = grid.output_dim() * ld;
    let d_out: Vec<f32> = (0..rows).map(|_| rng.uniform(-1.0, 1.0) as f32).collect();

    // The CPU's encoding and backward (levels one after another, one thread).
    let mut enc_cpu = vec![0f32; rows];
    let mut cpu_fwd = Vec::new();
    let mut cpu_bwd = Vec::new();
    let mut cpu_grad = vec![0f32; grid.n_params()];
    for _ in 0..reps {
        let t = Instant::now();
        grid.encode(&table, pts, &mut enc_cpu);
        cpu_fwd.push(t.elapsed().as_secs_f64());
        cpu_grad.iter_mut().for_each(|g| *g = 0.0);
        let t = Instant::now();
        for level in 0..grid.levels() {
            let r = grid.level_range(level);
            grid.backward_level(level, pts, &d_out, &mut cpu_grad[r]);
        }
        cpu_bwd.push(t.elapsed().as_secs_f64());
    }

    let points = GpuPoints::upload(&ctx, pts)?;
    let table_buf = ctx.storage_init("table", &f32_words(table.iter().copied()))?;
    let d_buf = ctx.storage_init("encoding gradient", &f32_words(d_out.iter().copied()))?;
    let out = ctx.storage("encoding", 4 * rows as u64)?;
    let grad = ctx.storage("gradient", 4 * grid.n_params() as u64)?;
    let time = |record: &dyn Fn(
        &mut augsplat_render::gpu::Encoder,
    ) -> Result<(), augsplat_render::gpu::GpuError>|
     -> Result<Timed, Box<dyn std::error::Error>> {
        let mut times = Vec::new();
        let mut results = Vec::new();
        for rep in 0..=reps {
            let mut enc = ctx.encoder();
            enc.clear_buffer(&grad, 0, None);
            ctx.submit(enc)?;
            let mut enc = ctx.encoder();
            record(&mut enc)?;
            let t = Instant::now();
            ctx.submit(enc)?;
            let dt = t.elapsed().as_secs_f64();
            ctx.reclaim();
            if rep > 0 {
                times.push(dt);
                results.push(ctx.read_words(&grad, grid.n_params())?);
            }
        }
        Ok((times, results))
    };
    let (fwd, _) = time(&|enc| record_encode(&ctx, enc, &grid, &table_buf, &points, &out))?;
    let (sorted, sorted_bits) =
        time(&|enc| record_backward(&ctx, enc, &grid, &points, &d_buf, &grad))?;
    let (fixed, fixed_bits) =
        time(&|enc| record_backward_fixed(&ctx, enc, &grid, &points, &d_buf, &grad).map(|_| ()))?;
    let (atomic, atomic_bits) =
        time(&|enc| record_backward_atomic(&ctx, enc, &grid, &points, &d_buf, &grad))?;

    let same = |runs: &[Vec<u32>]| runs.iter().all(|r| r == &runs[0]);
    let equal_cpu = sorted_bits[0]
        .iter()
        .zip(&cpu_grad)
        .all(|(a, b)| *a == b.to_bits());
    let worst_atomic = atomic_bits[0]
        .iter()
        .zip(&cpu_grad)
        .map(|(a, b)| (f32::from_bits(*a) - b).abs())
        .fold(0f32, f32::max);
    let worst_fixed = fixed_bits[0]
        .iter()
        .zip(&cpu_grad)
        .map(|(a, b)| (f32::from_bits(*a) - b).abs())
        .fold(0f32, f32::max);
    println!(
        "fixed point: same bytes every run {}, largest difference from the CPU {worst_fixed:e}",
        same(&fixed_bits)
    );
    let extra = (5 * 8 * n as u64 + 2 * grid.sizes.iter().max().copied().unwrap_or(0) as u64) * 4;
    let rate = |t: f64| n as f64 / t;
    println!("adapter: {}", ctx.adapter());
    println!(
        "{n} points, {} levels x {} features, 2^{} entries; medians of {reps}",
        grid.levels(),
        grid.features(),
        grid.config.log2_table_size
    );
    println!("| path | median ms | points/s |");
    println!("|---|---|---|");
    for (name, t) in [
        ("CPU encode (1 thread)", median(cpu_fwd)),
        ("CPU backward (1 thread)", median(cpu_bwd)),
        ("GPU encode", median(fwd)),
        ("GPU backward, sorted (deterministic)", median(sorted)),
        (
            "GPU backward, 64-bit fixed point (deterministic)",
            median(fixed),
        ),
        ("GPU backward, float atomics", median(atomic)),
    ] {
        println!("| {name} | {:.2} | {:.3e} |", 1e3 * t, rate(t));
    }
    println!(
        "sorted: same bytes every run {}, equal to the CPU's bits {}; atomic: same bytes every run {}, largest difference from the CPU {worst_atomic:e}; the sorted sum's extra memory {:.1} MiB",
        same(&sorted_bits),
        equal_cpu,
        same(&atomic_bits),
        extra as f64 / (1 << 20) as f64
    );
    Ok(())
}
