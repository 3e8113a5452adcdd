//! The hash encoding on the GPU (`hashgrid/gpu.rs`, on CI Mesa's lavapipe) against the CPU's:
//! the encoding within 1e-4, the table gradient within 1e-3 of each level's largest
//! magnitude (in practice the same values: the GPU adds each entry's pairs in the CPU's
//! order), finite differences on the GPU path itself, identical bytes run to run, on random
//! points and adversarial ones (outside the cube, NaN, infinite, on the faces), dense and
//! hashed levels and a table so small that most corners collide. Skips with a message when
//! no GPU adapter is found (fails under `CI=true`).

use augsplat_core::Rng;
use augsplat_field::hashgrid::gpu::{backward_gpu, encode_gpu};
use augsplat_field::hashgrid::{HashGrid, HashGridConfig, PointBatch};
use augsplat_render::gpu::{GpuContext, GpuError};

fn context(test: &str) -> Option<GpuContext> {
    match GpuContext::new() {
        Ok(c) => Some(c),
        Err(e @ GpuError::NoAdapter { .. }) => {
            augsplat_testkit::skip(test, &e.to_string());
            None
        }
        Err(e) => panic!("{test}: {e}"),
    }
}

/// Points in the unit cube, a cluster in one cell (many samples on the same entries), and
/// points on the faces, outside, infinite, NaN and −0.
fn points(rng: &mut Rng, n: usize) -> [Vec<f32>; 3] {
    let mut p: [Vec<f32>; 3] = std::array::from_fn(|_| (0..n).map(|_| rng.next_f32()).collect());
    for axis in &mut p {
        for v in axis.iter_mut().take(n / 4) {
            *v = 0.3 + 0.001 * *v;
        }
    }
    let special = [
        0.0f32,
        1.0,
        -0.25,
        1.5,
        f32::NAN,
        0.999_999_9,
        -0.0,
        f32::INFINITY,
        f32::NEG_INFINITY,
    ];
    for (k, &v) in special.iter().enumerate() {
        let i = n / 2 + 3 * k;
        if i < n {
            p[k % 3][i] = v;
        }
    }
    p
}

/// Grids: 2 features with dense coarse levels and hashed fine ones; 4 features; and a 16-entry
/// table where nearly every corner collides.
fn grids() -> Vec<HashGrid> {
    [(2u32, 12u32, 4u32, 300u32), (4, 10, 2, 64), (1, 4, 2, 32)]
        .into_iter()
        .map(|(f, t, base, max)| {
            HashGrid::new(HashGridConfig {
                levels: 5,
                features_per_level: f,
                log2_table_size: t,
                base_resolution: base,
                max_resolution: max,
            })
            .unwrap()
        })
        .collect()
}

fn batch(p: &[Vec<f32>; 3], n: usize, ld: usize) -> PointBatch<'_> {
    PointBatch {
        px: &p[0],
        py: &p[1],
        pz: &p[2],
        n,
        ld,
    }
}

#[test]
fn the_gpu_encoding_and_its_gradient_match_the_cpu() {
    let test = "the_gpu_encoding_and_its_gradient_match_the_cpu";
    let Some(ctx) = context(test) else { return };
    let mut rng = Rng::new(5);
    for grid in grids() {
        assert!(grid.dense.iter().any(|d| *d) || grid.config.log2_table_size == 4);
        for (n, ld) in [(1000usize, 1003usize), (37, 40), (0, 8)] {
            let p = points(&mut rng, n.max(1));
            let pts = batch(&p, n, ld);
            let mut table = vec![0.0f32; grid.n_params()];
            for v in &mut table {
                *v = rng.uniform(-1.0, 1.0) as f32;
            }
            let rows = grid.output_dim() * ld;
            let mut cpu = vec![f32::NAN; rows];
            grid.encode(&table, pts, &mut cpu);
            let gpu = encode_gpu(&ctx, &grid, &table, pts).unwrap();
            for (i, (a, b)) in cpu.iter().zip(&gpu).enumerate() {
                assert!((a - b).abs() <= 1e-4, "{test}: value {i}: CPU {a}, GPU {b}");
            }

            let d_out: Vec<f32> = (0..rows).map(|_| rng.uniform(-1.0, 1.0) as f32).collect();
            let start: Vec<f32> = (0..grid.n_params())
                .map(|_| rng.uniform(-0.1, 0.1) as f32)
                .collect();
            let mut cpu_grad = start.clone();
            for level in 0..grid.levels() {
                let r = grid.level_range(level);
                grid.backward_level(level, pts, &d_out, &mut cpu_grad[r]);
            }
            let mut gpu_grad = start.clone();
            backward_gpu(&ctx, &grid, pts, &d_out, &mut gpu_grad).unwrap();
            let mut worst = 0.0f32;
            for level in 0..grid.levels() {
                let r = grid.level_range(level);
                let scale = cpu_grad[r.clone()]
                    .iter()
                    .fold(0.0f32, |m, v| m.max(v.abs()))
                    .max(1e-30);
                for j in r {
                    let err = (cpu_grad[j] - gpu_grad[j]).abs() / scale;
                    worst = worst.max(err);
                    assert!(
                        err <= 1e-3,
                        "{test}: level {level} entry {j}: CPU {}, GPU {}",
                        cpu_grad[j],
                        gpu_grad[j]
                    );
                }
            }
            eprintln!(
                "{test}: F={} T={} n={n}: worst gradient error {worst:e} of the level's largest",
                grid.features(),
                grid.config.log2_table_size
            );
            // Run to run, the same bytes.
            let mut again = start.clone();
            backward_gpu(&ctx, &grid, pts, &d_out, &mut again).unwrap();
            assert!(
                again
                    .iter()
                    .zip(&gpu_grad)
                    .all(|(a, b)| a.to_bits() == b.to_bits()),
                "{test}: two runs differ"
            );
        }
    }
}

#[test]
fn the_gpu_table_gradient_matches_finite_differences_of_the_gpu_encoding() {
    let test = "the_gpu_table_gradient_matches_finite_differences_of_the_gpu_encoding";
    let Some(ctx) = context(test) else { return };
    let mut rng = Rng::new(9);
    let grid = &grids()[0];
    let n = 300;
    let p = points(&mut rng, n);
    let pts = batch(&p, n, n);
    let table: Vec<f32> = (0..grid.n_params())
        .map(|_| rng.uniform(-1.0, 1.0) as f32)
        .collect();
    let rows = grid.output_dim() * n;
    let d_out: Vec<f32> = (0..rows).map(|_| rng.uniform(-1.0, 1.0) as f32).collect();
    let mut grad = vec![0.0f32; grid.n_params()];
    backward_gpu(&ctx, grid, pts, &d_out, &mut grad).unwrap();
    // L = Σ d_out · encoding is linear in the table: a central difference in f64 of the GPU
    // encoding's L recovers each entry's gradient up to the encoding's rounding.
    let loss = |t: &[f32]| -> f64 {
        let e = encode_gpu(&ctx, grid, t, pts).unwrap();
        e.iter()
            .zip(&d_out)
            .map(|(a, b)| *a as f64 * *b as f64)
            .sum()
    };
    // The entries with the largest gradients of a dense and of a hashed level, and one
    // untouched entry (gradient 0).
    let mut checked = Vec::new();
    for level in [0, grid.levels() - 1] {
        let r = grid.level_range(level);
        let j = r
            .clone()
            .max_by(|&a, &b| grad[a].abs().total_cmp(&grad[b].abs()))
            .unwrap();
        checked.push(j);
        if let Some(z) = r.clone().find(|&k| grad[k] == 0.0) {
            checked.push(z);
        }
    }
    let h = 0.25f32;
    for j in checked {
        let mut plus = table.clone();
        plus[j] += h;
        let mut minus = table.clone();
        minus[j] -= h;
        let fd = (loss(&plus) - loss(&minus)) / (2.0 * h as f64);
        let tol = 1e-3 * (grad[j].abs() as f64).max(1.0);
        assert!(
            (fd - grad[j] as f64).abs() <= tol,
            "{test}: entry {j}: finite difference {fd}, gradient {}",
            grad[j]
        );
    }
}

/// The float-atomic variant kept for measuring (`determinism-cost`) adds the same terms in
/// another order: the same gradient up to rounding.
#[cfg(feature = "determinism-cost")]
#[test]
fn the_float_atomic_gradient_agrees_up_to_rounding() {
    use augsplat_field::hashgrid::gpu::{record_backward_atomic, GpuPoints};
    use augsplat_render::gpu::f32_words;
    let test = "the_float_atomic_gradient_agrees_up_to_rounding";
    let Some(ctx) = context(test) else { return };
    let mut rng = Rng::new(13);
    let grid = &grids()[2];
    let n = 2000;
    let p = points(&mut rng, n);
    let pts = batch(&p, n, n);
    let d_out: Vec<f32> = (0..grid.output_dim() * n)
        .map(|_| rng.uniform(-1.0, 1.0) as f32)
        .collect();
    let mut sorted = vec![0.0f32; grid.n_params()];
    backward_gpu(&ctx, grid, pts, &d_out, &mut sorted).unwrap();
    let points = GpuPoints::upload(&ctx, pts).unwrap();
    let d = ctx
        .storage_init("d", &f32_words(d_out.iter().copied()))
        .unwrap();
    let g = ctx.storage("g", 4 * grid.n_params() as u64).unwrap();
    let mut enc = ctx.encoder();
    record_backward_atomic(&ctx, &mut enc, grid, &points, &d, &g).unwrap();
    let words = ctx.read_after(enc, &[(&g, 0, grid.n_params())]).unwrap();
    let scale = sorted.iter().fold(0f32, |m, v| m.max(v.abs()));
    for (j, (a, w)) in sorted.iter().zip(&words[0]).enumerate() {
        let b = f32::from_bits(*w);
        assert!(
            (a - b).abs() <= 1e-4 * scale,
            "{test}: entry {j}: {a} vs {b}"
        );
    }
}

#[test]
fn the_fixed_point_gradient_is_deterministic_and_matches_the_cpu() {
    use augsplat_field::hashgrid::gpu::backward_gpu_fixed;
    let test = "the_fixed_point_gradient_is_deterministic_and_matches_the_cpu";
    let Some(ctx) = context(test) else { return };
    let mut rng = Rng::new(17);
    for grid in grids() {
        let n = 1500;
        let p = points(&mut rng, n);
        let pts = batch(&p, n, n + 5);
        // Terms over nine orders of magnitude, signed.
        let d_out: Vec<f32> = (0..grid.output_dim() * (n + 5))
            .map(|k| rng.uniform(-1.0, 1.0) as f32 * 10f32.powi((k % 10) as i32 - 8))
            .collect();
        let start: Vec<f32> = (0..grid.n_params())
            .map(|_| rng.uniform(-1e-3, 1e-3) as f32)
            .collect();
        let mut cpu = start.clone();
        for level in 0..grid.levels() {
            let r = grid.level_range(level);
            grid.backward_level(level, pts, &d_out, &mut cpu[r]);
        }
        let mut fixed = start.clone();
        backward_gpu_fixed(&ctx, &grid, pts, &d_out, &mut fixed).unwrap();
        let mut worst = 0f32;
        for level in 0..grid.levels() {
            let r = grid.level_range(level);
            let scale = cpu[r.clone()].iter().fold(0f32, |m, v| m.max(v.abs()));
            for j in r {
                let err = (cpu[j] - fixed[j]).abs() / scale;
                worst = worst.max(err);
                assert!(
                    err <= 1e-5,
                    "{test}: level {level} entry {j}: CPU {}, GPU {}",
                    cpu[j],
                    fixed[j]
                );
            }
        }
        eprintln!(
            "{test}: F={}: worst error {worst:e} of the level's largest",
            grid.features()
        );
        let mut again = start.clone();
        backward_gpu_fixed(&ctx, &grid, pts, &d_out, &mut again).unwrap();
        assert!(
            again
                .iter()
                .zip(&fixed)
                .all(|(a, b)| a.to_bits() == b.to_bits()),
            "{test}: two runs differ"
        );
    }
    // A gradient that is not finite is an error naming its level, not a silent NaN.
    let grid = &grids()[0];
    let n = 64;
    let p = points(&mut rng, n);
    let mut d_out = vec![0.5f32; grid.output_dim() * n];
    d_out[2 * grid.features() * n + 7] = f32::NAN;
    let mut g = vec![0f32; grid.n_params()];
    let err = backward_gpu_fixed(&ctx, grid, batch(&p, n, n), &d_out, &mut g).unwrap_err();
    assert!(err.to_string().contains("level 2"), "{err}");
}
