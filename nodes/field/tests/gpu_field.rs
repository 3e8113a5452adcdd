//! The radiance field on the GPU (`gpu/`, on CI Mesa's lavapipe) against the CPU field: a
//! training step's per-ray outputs, losses and every gradient group (hash levels, each MLP
//! layer's weights and biases, appearance embeddings), renders, finite differences of the
//! GPU path itself, identical bytes run to run and seeds that differ; on a partly occupied
//! grid, an empty one, and a 16-entry table where nearly every corner collides. Skips with a
//! message when no GPU adapter is found (fails under `CI=true`).
#![allow(clippy::needless_range_loop)]

mod common;

use augsplat_core::Rng;
use augsplat_field::field::{ChunkState, Field, FieldConfig, RayInput};
use augsplat_field::gpu::render::render_cameras_gpu;
use augsplat_field::gpu::train::{step_rays, train_gpu, GpuTrainer};
use augsplat_field::gpu::{RAY_FLOATS, RAY_OUT_FLOATS};
use augsplat_field::hashgrid::HashGridConfig;
use augsplat_field::occupancy::OccupancyGrid;
use augsplat_field::train::{
    load_views, render_camera, train, train_step, Adam, StepStats, TrainOptions, TrainState,
    ViewData,
};
use augsplat_render::gpu::{GpuContext, GpuError};
use std::path::Path;

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

fn config(log2_table: u32, appearance_dim: u32, n_images: u32) -> FieldConfig {
    FieldConfig {
        grid: HashGridConfig {
            levels: 6,
            features_per_level: 2,
            log2_table_size: log2_table,
            base_resolution: 8,
            max_resolution: 128,
        },
        hidden_width: 32,
        appearance_dim,
        n_images,
        center: [0.0; 3],
        radius: 1.2,
        near: 0.05,
        far: 4.5,
        march_steps: 48,
        occupancy_resolution: 16,
    }
}

fn options(seed: u64, steps: u32) -> TrainOptions {
    TrainOptions {
        seed,
        steps,
        rays_per_step: 96,
        chunk_rays: 32,
        learning_rate: 1e-2,
        lr_final_factor: 0.1,
        depth_loss_weight: 0.1,
        depth_sigma: 0.05,
        distortion_loss_weight: 0.01,
        random_background: true,
        background: [0.0; 3],
        occupancy_warmup: 4,
        eval_every: 0,
    }
}

/// The generated scene (16×12 views, sparse depth) in `root`, loaded.
fn scene(root: &Path) -> (Vec<ViewData>, Vec<ViewData>) {
    common::split_scene(root, 8, 16, 12, 0.3);
    let (_, train) = load_views(&root.join("train"), 1).unwrap();
    let (_, test) = load_views(&root.join("test"), 1).unwrap();
    (train, test)
}

/// An occupancy grid with about `fraction` of its cells occupied (seeded).
fn occupancy(res: u32, fraction: f64, seed: u64) -> OccupancyGrid {
    let mut occ = OccupancyGrid::full(res);
    let mut rng = Rng::new(seed);
    for o in &mut occ.occupied {
        *o = u8::from(rng.next_f64() < fraction);
    }
    occ
}

/// Max |a − b| over a group, relative to the group's largest |b|.
fn rel_err(a: &[f32], b: &[f32]) -> (f64, f64) {
    let scale = b.iter().fold(0f64, |m, v| m.max(v.abs() as f64));
    let err = a
        .iter()
        .zip(b)
        .fold(0f64, |m, (x, y)| m.max((*x as f64 - *y as f64).abs()));
    (err / scale.max(1e-30), scale)
}

/// The gradient groups of a field: hash levels, each MLP layer's weights and biases,
/// embeddings.
fn groups(field: &Field) -> Vec<(String, std::ops::Range<usize>)> {
    let mut g = Vec::new();
    for l in 0..field.grid.levels() {
        g.push((format!("hash level {l}"), field.grid.level_range(l)));
    }
    for (name, mlp, base) in [
        ("density", &field.density, field.density_offset),
        ("colour", &field.color, field.color_offset),
    ] {
        let mut off = base;
        for (l, s) in mlp.layers.iter().enumerate() {
            let w = s.inp * s.out;
            g.push((format!("{name} layer {l} weights"), off..off + w));
            g.push((format!("{name} layer {l} biases"), off + w..off + w + s.out));
            off += s.params();
        }
    }
    if field.n_params > field.embedding_offset {
        g.push(("embeddings".into(), field.embedding_offset..field.n_params));
    }
    g
}

/// One step's gradient, per-ray outputs and status on the GPU.
fn gpu_step(
    ctx: &GpuContext,
    field: &Field,
    state: &TrainState,
    views: &[ViewData],
    opts: &TrainOptions,
    step: u32,
) -> (Vec<f32>, Vec<f32>, Vec<u32>) {
    let adam = Adam::new(field.n_params);
    let trainer = GpuTrainer::new(ctx, field, state, &adam).unwrap();
    let rays = step_rays(views, opts, step);
    let (bufs, _, enc) = trainer.record_gradient(&rays, opts, &[]).unwrap();
    let words = ctx
        .read_after(
            enc,
            &[
                (&bufs.grad, 0, field.n_params),
                (&bufs.ray_out, 0, RAY_OUT_FLOATS * rays.len()),
                (&bufs.status, 0, 8),
            ],
        )
        .unwrap();
    let f = |w: &Vec<u32>| w.iter().map(|b| f32::from_bits(*b)).collect::<Vec<f32>>();
    (f(&words[0]), f(&words[1]), words[2].clone())
}

/// The CPU forward pass over the same rays (outputs only).
fn cpu_outputs(
    field: &Field,
    params: &[f32],
    occ: &OccupancyGrid,
    rays: &[[f32; RAY_FLOATS]],
) -> Vec<[f32; 5]> {
    let inputs: Vec<RayInput> = rays
        .iter()
        .map(|r| RayInput {
            origin: [r[0], r[1], r[2]],
            dir: [r[3], r[4], r[5]],
            image: r[15].to_bits(),
            background: [r[6], r[7], r[8]],
        })
        .collect();
    let mut st = ChunkState::default();
    let mean = field.mean_embedding(params);
    field.forward_chunk(params, occ, &inputs, &|r| rays[r][14], &mean, &mut st);
    st.out
        .iter()
        .map(|o| [o.rgb[0], o.rgb[1], o.rgb[2], o.acc, o.depth])
        .collect()
}

#[test]
fn a_training_step_matches_the_cpu_field() {
    let Some(ctx) = context("a_training_step_matches_the_cpu_field") else {
        return;
    };
    let dir = tempfile::tempdir().unwrap();
    let (views, _) = scene(dir.path());
    let nv = views.len() as u32;
    // Partly occupied grid with embeddings; full grid without; a 16-entry table; an empty
    // grid (every ray misses: no samples, only the background).
    for (log2_table, e, fraction) in [(12, 4, 0.6), (12, 0, 1.0), (4, 0, 0.8), (12, 4, 0.0)] {
        let field = Field::new(config(log2_table, e, nv)).unwrap();
        let opts = options(3, 10);
        let mut state = TrainState {
            params: field.init_params(5),
            occupancy: occupancy(16, fraction, 9),
            skipped_steps: 0,
            nonfinite_values: 0,
        };
        // A few CPU steps first, so the densities and gradients are not those of the start.
        let mut adam = Adam::new(field.n_params);
        let mut grad = Vec::new();
        for step in 0..3 {
            train_step(
                &field, &mut state, &mut adam, &views, &opts, step, &mut grad,
            )
            .unwrap();
        }
        let step = 3;
        let (g_gpu, out_gpu, status) = gpu_step(&ctx, &field, &state, &views, &opts, step);
        let rays = step_rays(&views, &opts, step);
        let out_cpu = cpu_outputs(&field, &state.params, &state.occupancy, &rays);
        let mut worst_out = 0f64;
        for (r, o) in out_cpu.iter().enumerate() {
            for k in 0..5 {
                let d = (out_gpu[RAY_OUT_FLOATS * r + k] - o[k]).abs() as f64;
                worst_out = worst_out.max(d / (1.0 + o[k].abs() as f64));
            }
        }
        assert!(worst_out < 1e-4, "outputs differ by {worst_out:e}");
        let mut cpu_state = state.clone();
        let mut adam2 = Adam::new(field.n_params);
        let stats = train_step(
            &field,
            &mut cpu_state,
            &mut adam2,
            &views,
            &opts,
            step,
            &mut grad,
        )
        .unwrap();
        assert!(stats.applied);
        assert_eq!(status[1], 0, "the GPU rejected the step");
        let n = opts.rays_per_step as f64;
        let rgb = f32::from_bits(status[2]) as f64 / n;
        assert!(
            (rgb - stats.rgb_loss).abs() <= 1e-4 * stats.rgb_loss.max(1e-6),
            "rgb loss {rgb} vs {}",
            stats.rgb_loss
        );
        let depth = f32::from_bits(status[3]) as f64 / n;
        assert!((depth - stats.depth_loss).abs() <= 1e-4 * stats.depth_loss.abs().max(1e-3));
        let dist = f32::from_bits(status[4]) as f64 / n;
        assert!((dist - stats.distortion_loss).abs() <= 1e-4 * stats.distortion_loss.max(1e-3));
        for (name, range) in groups(&field) {
            let (err, scale) = rel_err(&g_gpu[range.clone()], &grad[range]);
            assert!(
                err <= 1e-3,
                "table 2^{log2_table}, E {e}: {name}: error {err:e} of its largest {scale:e}"
            );
        }
    }
}

#[test]
fn finite_differences_of_the_gpu_loss_match_its_gradient() {
    let Some(ctx) = context("finite_differences_of_the_gpu_loss_match_its_gradient") else {
        return;
    };
    let dir = tempfile::tempdir().unwrap();
    let (views, _) = scene(dir.path());
    let field = Field::new(config(12, 4, views.len() as u32)).unwrap();
    let opts = options(4, 10);
    let mut state = TrainState {
        params: field.init_params(1),
        occupancy: occupancy(16, 0.7, 2),
        skipped_steps: 0,
        nonfinite_values: 0,
    };
    let mut adam = Adam::new(field.n_params);
    let mut grad = Vec::new();
    for step in 0..5 {
        train_step(
            &field, &mut state, &mut adam, &views, &opts, step, &mut grad,
        )
        .unwrap();
    }
    let loss = |params: &[f32]| -> f64 {
        let s = TrainState {
            params: params.to_vec(),
            ..state.clone()
        };
        let (_, _, status) = gpu_step(&ctx, &field, &s, &views, &opts, 5);
        let n = opts.rays_per_step as f64;
        let l = |k: usize| f32::from_bits(status[k]) as f64 / n;
        l(2) + opts.depth_loss_weight as f64 * l(3) + opts.distortion_loss_weight as f64 * l(4)
    };
    let (g, _, _) = gpu_step(&ctx, &field, &state, &views, &opts, 5);
    // The largest entry of each group (a parameter the loss depends on strongly).
    let mut checked = 0;
    for (name, range) in groups(&field) {
        let Some(i) = range
            .clone()
            .max_by(|&a, &b| g[a].abs().total_cmp(&g[b].abs()))
        else {
            continue;
        };
        if g[i].abs() < 1e-4 {
            continue;
        }
        let h = 1e-2 * state.params[i].abs().max(0.05);
        let mut p = state.params.clone();
        p[i] += h;
        let up = loss(&p);
        p[i] -= 2.0 * h;
        let down = loss(&p);
        let fd = (up - down) / (2.0 * h as f64);
        let err = (fd - g[i] as f64).abs() / (g[i] as f64).abs();
        assert!(
            err < 0.05,
            "{name}: finite difference {fd:e}, gradient {:e}",
            g[i]
        );
        checked += 1;
    }
    assert!(checked >= 8, "only {checked} groups had a gradient");
}

#[test]
fn training_repeats_to_the_byte_and_seeds_differ() {
    let Some(ctx) = context("training_repeats_to_the_byte_and_seeds_differ") else {
        return;
    };
    let dir = tempfile::tempdir().unwrap();
    let (views, test) = scene(dir.path());
    let field = Field::new(config(12, 4, views.len() as u32)).unwrap();
    // 100 steps: occupancy refreshes from step 4 on, every 16 steps.
    let run = |seed: u64| {
        let mut opts = options(seed, 100);
        opts.eval_every = 50;
        train_gpu(&ctx, &field, &views, Some(&test), &opts, None, &mut |_| {}).unwrap()
    };
    let (a, curve_a) = run(0);
    // A step's buffers go back to the context's pool: later steps reuse them, and nothing is
    // left waiting once the run is over.
    let pool = ctx.pool_stats();
    assert!(pool.reused > 10 * pool.created, "{pool:?}");
    assert_eq!(pool.quarantined, 0, "{pool:?}");
    let (b, curve_b) = run(0);
    let (c, _) = run(1);
    let bits = |v: &[f32]| v.iter().map(|x| x.to_bits()).collect::<Vec<u32>>();
    assert_eq!(bits(&a.params), bits(&b.params));
    assert_eq!(a.occupancy, b.occupancy);
    assert_eq!(curve_a, curve_b);
    assert_ne!(bits(&a.params), bits(&c.params));
    assert!(
        a.occupancy.occupied_fraction() < 1.0,
        "the occupancy grid was never refreshed"
    );
    let cams: Vec<_> = test.iter().map(|v| v.camera.clone()).collect();
    let r1 = render_cameras_gpu(&ctx, &field, &a.params, &a.occupancy, &cams, [0.2; 3]).unwrap();
    let r2 = render_cameras_gpu(&ctx, &field, &a.params, &a.occupancy, &cams, [0.2; 3]).unwrap();
    assert_eq!(r1, r2);
}

#[test]
fn counting_a_step_ahead_changes_no_bit_around_rejected_steps() {
    let test = "counting_a_step_ahead_changes_no_bit_around_rejected_steps";
    let Some(ctx) = context(test) else { return };
    let dir = tempfile::tempdir().unwrap();
    let (mut views, _) = scene(dir.path());
    // Three pixels whose colour is not a number: a step whose rays meet one has a non-finite
    // loss and is rejected, so Adam's count lags the step number.
    for p in [5, 77, 150] {
        views[0].rgb[3 * p] = f32::NAN;
    }
    let field = Field::new(config(12, 4, views.len() as u32)).unwrap();
    let opts = options(3, 40);
    let refresh = |s: u32| {
        s >= opts.occupancy_warmup
            && (s - opts.occupancy_warmup)
                .is_multiple_of(augsplat_field::constants::OCCUPANCY_UPDATE_EVERY)
    };
    let state = TrainState {
        params: field.init_params(opts.seed),
        occupancy: OccupancyGrid::full(field.config.occupancy_resolution),
        skipped_steps: 0,
        nonfinite_values: 0,
    };
    // Each step counts its own samples (a wait for an idle device), or the next step's are
    // counted while it runs (as `train_gpu` does).
    let run = |ahead: bool| {
        let draining = ctx.draining_waits();
        let mut trainer =
            GpuTrainer::new(&ctx, &field, &state, &Adam::new(field.n_params)).unwrap();
        let mut stats = Vec::new();
        for step in 0..opts.steps {
            if refresh(step) {
                trainer.update_occupancy(opts.seed, step).unwrap();
            }
            let next = Some(step + 1).filter(|&s| ahead && s < opts.steps && !refresh(s));
            stats.extend(trainer.step(&views, &opts, step, next).unwrap());
        }
        stats.extend(trainer.settle().unwrap());
        let (params, occupancy, adam) = trainer.download().unwrap();
        let stats: Vec<(u32, StepStats)> = stats.into_iter().map(|(s, d)| (s, d.stats)).collect();
        // Each step once, in order.
        let order: Vec<u32> = stats.iter().map(|(s, _)| *s).collect();
        assert_eq!(order, (0..opts.steps).collect::<Vec<_>>());
        (
            params,
            occupancy,
            adam.applied_steps(),
            stats,
            ctx.draining_waits() - draining,
        )
    };
    let (p1, o1, t1, s1, drained1) = run(false);
    let (p2, o2, t2, s2, drained2) = run(true);
    let applied: Vec<bool> = s1.iter().map(|(_, s)| s.applied).collect();
    eprintln!("{test}: applied {applied:?}; draining waits {drained1} / {drained2}");
    assert_eq!(s1.len(), opts.steps as usize);
    assert!(
        applied.windows(2).any(|w| !w[0] && w[1]),
        "a rejected step followed by an applied one: {applied:?}"
    );
    assert_eq!(t1, applied.iter().filter(|a| **a).count() as u32);
    let bits = |v: &[f32]| v.iter().map(|x| x.to_bits()).collect::<Vec<u32>>();
    assert_eq!(bits(&p1), bits(&p2));
    assert_eq!(o1, o2);
    assert_eq!(t1, t2);
    // Losses to the bit (a rejected step's is not a number).
    let stat_bits = |s: &[(u32, StepStats)]| -> Vec<[u64; 6]> {
        s.iter()
            .map(|(_, d)| {
                [
                    d.rgb_loss.to_bits(),
                    d.depth_loss.to_bits(),
                    d.distortion_loss.to_bits(),
                    d.samples,
                    d.color_samples,
                    u64::from(d.applied),
                ]
            })
            .collect()
    };
    assert_eq!(stat_bits(&s1), stat_bits(&s2));
    // Counted ahead, only the first step, those right after a refresh (3), the last read and
    // the download wait for an idle device; counted one by one, every step does.
    assert!(drained1 >= u64::from(opts.steps), "{drained1}");
    assert!(drained2 <= 6, "{drained2}");
}

#[test]
fn renders_match_the_cpu_field() {
    let Some(ctx) = context("renders_match_the_cpu_field") else {
        return;
    };
    let dir = tempfile::tempdir().unwrap();
    let (views, test) = scene(dir.path());
    let field = Field::new(config(12, 4, views.len() as u32)).unwrap();
    let (state, _) = train(&field, &views, None, &options(2, 40), &mut |_| {}).unwrap();
    let cams: Vec<_> = test.iter().map(|v| v.camera.clone()).collect();
    let empty = OccupancyGrid {
        occupied: vec![0; state.occupancy.len()],
        ..state.occupancy.clone()
    };
    // An opaque field (the density's output bias raised): rays stop early, so the densities
    // run segment by segment up to the cut-off.
    let mut opaque = state.params.clone();
    let s1 = field.density.layers[0].params();
    let last = field.density.layers[1];
    opaque[field.density_offset + s1 + last.inp * last.out] += 4.0;
    for (what, occ, params) in [
        ("trained grid", &state.occupancy, &state.params),
        ("empty grid", &empty, &state.params),
        ("opaque field", &state.occupancy, &opaque),
    ] {
        let gpu = render_cameras_gpu(&ctx, &field, params, occ, &cams, [0.2, 0.5, 0.9]).unwrap();
        for (cam, g) in cams.iter().zip(&gpu) {
            let c = render_camera(&field, params, occ, cam, [0.2, 0.5, 0.9], 64);
            let worst = |a: &[f32], b: &[f32]| {
                a.iter()
                    .zip(b)
                    .fold(0f32, |m, (x, y)| m.max((x - y).abs() / (1.0 + y.abs())))
            };
            assert!(worst(&g.rgb, &c.rgb) < 1e-4, "{what}: colour");
            assert!(worst(&g.acc, &c.acc) < 1e-4, "{what}: opacity");
            assert!(worst(&g.depth, &c.depth) < 1e-4, "{what}: depth");
            assert_eq!(g.stats.steps, c.stats.steps, "{what}: marching steps");
            assert_eq!(g.stats.marched, c.stats.marched, "{what}: samples");
            assert_eq!(g.stats.density, c.stats.density, "{what}: density samples");
            assert_eq!(g.stats.color, c.stats.color, "{what}: colour samples");
            eprintln!(
                "{what}: {} samples marched, {} through the density network, {} through the colour network",
                g.stats.marched, g.stats.density, g.stats.color
            );
            if what == "opaque field" {
                assert!(
                    g.stats.density < g.stats.marched / 2,
                    "rays did not stop early"
                );
            }
            if occ.occupied_fraction() == 0.0 {
                assert!(g.acc.iter().all(|&a| a == 0.0));
                assert!(g.rgb.chunks(3).all(|p| p == [0.2, 0.5, 0.9]));
            }
        }
    }
}

#[test]
fn a_run_continued_from_a_checkpoint_repeats_the_uninterrupted_one() {
    use augsplat_field::train::FieldCheckpoints;
    let Some(ctx) = context("a_run_continued_from_a_checkpoint_repeats_the_uninterrupted_one")
    else {
        return;
    };
    let dir = tempfile::tempdir().unwrap();
    let (views, test) = scene(dir.path());
    let field = Field::new(config(12, 4, views.len() as u32)).unwrap();
    let mut opts = options(6, 16);
    opts.eval_every = 8;
    let run = |resume: Option<Vec<u8>>, saved: &mut Vec<Vec<u8>>, every: u64| {
        let mut save = |b: Vec<u8>| {
            saved.push(b);
            Ok(())
        };
        let mut log = |_: String| {};
        let ckpt = (every > 0).then_some(FieldCheckpoints {
            every,
            resume,
            save: &mut save,
            log: &mut log,
        });
        train_gpu(&ctx, &field, &views, Some(&test), &opts, ckpt, &mut |_| {}).unwrap()
    };
    let bits = |v: &[f32]| v.iter().map(|x| x.to_bits()).collect::<Vec<u32>>();
    // Without checkpoints, and with them every 5 steps (occupancy refreshes at 4 and 20...).
    let (plain, plain_curve) = run(None, &mut Vec::new(), 0);
    let mut saved = Vec::new();
    let (full, full_curve) = run(None, &mut saved, 5);
    assert_eq!(saved.len(), 3, "checkpoints at steps 5, 10 and 15");
    assert_eq!(bits(&plain.params), bits(&full.params));
    assert_eq!(plain_curve, full_curve);
    for (i, ckpt) in saved.clone().into_iter().enumerate() {
        let mut again = Vec::new();
        let (st, curve) = run(Some(ckpt), &mut again, 5);
        assert_eq!(bits(&st.params), bits(&full.params), "checkpoint {i}");
        assert_eq!(st.occupancy, full.occupancy);
        assert_eq!(curve, full_curve);
        assert_eq!(again, saved[i + 1..].to_vec());
    }
}

/// 300 steps on the generated scene: the GPU field's held-out PSNR within 0.2 dB of the CPU
/// field's (the same rays; the sums round differently).
#[test]
fn a_300_step_field_reaches_the_cpu_fields_psnr() {
    let Some(ctx) = context("a_300_step_field_reaches_the_cpu_fields_psnr") else {
        return;
    };
    let dir = tempfile::tempdir().unwrap();
    common::split_scene(dir.path(), 12, 24, 18, 0.05);
    let (_, views) = load_views(&dir.path().join("train"), 1).unwrap();
    let (_, test) = load_views(&dir.path().join("test"), 1).unwrap();
    let mut cfg = config(14, 0, views.len() as u32);
    cfg.grid.levels = 8;
    cfg.grid.max_resolution = 256;
    cfg.march_steps = 64;
    cfg.occupancy_resolution = 32;
    let field = Field::new(cfg).unwrap();
    let mut opts = options(0, 300);
    opts.rays_per_step = 256;
    opts.occupancy_warmup = 64;
    opts.distortion_loss_weight = 0.0;
    let (_, cpu) = train(&field, &views, Some(&test), &opts, &mut |_| {}).unwrap();
    let (_, gpu) = train_gpu(&ctx, &field, &views, Some(&test), &opts, None, &mut |_| {}).unwrap();
    let (pc, pg) = (cpu.points[0].psnr, gpu.points[0].psnr);
    eprintln!("300-step field, held-out PSNR: CPU {pc:.3} dB, GPU {pg:.3} dB");
    assert!(pc > 15.0, "the CPU field did not train ({pc} dB)");
    assert!((pc - pg).abs() <= 0.2, "CPU {pc} dB, GPU {pg} dB");
}

/// The two weight-gradient kernels (one invocation per weight; workgroup tiles) give the same
/// bits, and the f64 sums to rounding, for shapes whose blocks and chunks do not divide evenly.
#[test]
fn both_weight_gradient_kernels_give_the_same_bits() {
    use augsplat_field::mlp::gpu::{record_weight_grad, GpuBatch, WeightGradKernel};
    use augsplat_field::mlp::LayerShape;
    use augsplat_render::gpu::f32_words;
    let Some(ctx) = context("both_weight_gradient_kernels_give_the_same_bits") else {
        return;
    };
    let mut rng = Rng::new(11);
    for (inp, out, cols) in [(31usize, 64usize, 2500u32), (64, 3, 1100), (32, 16, 70)] {
        let ld = cols.div_ceil(64) * 64;
        let mut gen = |rows: usize| -> Vec<f32> {
            (0..rows * ld as usize)
                .map(|k| {
                    if (k % ld as usize) < cols as usize {
                        rng.uniform(-1.0, 1.0) as f32
                    } else {
                        0.0
                    }
                })
                .collect()
        };
        let (dy, x) = (gen(out), gen(inp));
        let s = LayerShape { inp, out };
        let run = |kernel| {
            let up = |v: &[f32]| {
                ctx.storage_init("test", &f32_words(v.iter().copied()))
                    .unwrap()
            };
            let (dyb, xb) = (up(&dy), up(&x));
            let grad = up(&vec![0.0; s.params()]);
            let mut enc = ctx.encoder();
            let batch = GpuBatch {
                ld,
                cols,
                count: None,
            };
            record_weight_grad(&ctx, &mut enc, s, (&dyb, &xb), &grad, 0, batch, kernel).unwrap();
            ctx.read_after(enc, &[(&grad, 0, s.params())])
                .unwrap()
                .remove(0)
        };
        let per_weight = run(WeightGradKernel::PerWeight);
        assert_eq!(per_weight, run(WeightGradKernel::Tiled), "{inp} → {out}");
        for o in 0..out {
            for i in 0..=inp {
                let want: f64 = (0..cols as usize)
                    .map(|c| {
                        let xv = if i == inp {
                            1.0
                        } else {
                            x[i * ld as usize + c] as f64
                        };
                        dy[o * ld as usize + c] as f64 * xv
                    })
                    .sum();
                let got = f32::from_bits(if i == inp {
                    per_weight[inp * out + o]
                } else {
                    per_weight[o * inp + i]
                }) as f64;
                assert!(
                    (got - want).abs() < 1e-4 * (1.0 + want.abs()),
                    "{o},{i}: {got} vs {want}"
                );
            }
        }
    }
}

/// On an adapter that caps a shader's loop iterations (lavapipe: 65,535), a field step whose
/// per-ray loops would pass the cap is refused with the cap and the limit in the message,
/// before any work; a step within it trains. Adapters without a cap have nothing to refuse.
#[test]
fn a_step_past_the_adapters_loop_cap_is_refused() {
    let Some(ctx) = context("a_step_past_the_adapters_loop_cap_is_refused") else {
        return;
    };
    let Some(cap) = ctx.adapter().loop_cap() else {
        eprintln!("{}: no loop cap; nothing to refuse", ctx.adapter());
        return;
    };
    let dir = tempfile::tempdir().unwrap();
    let (views, _) = scene(dir.path());
    let field = Field::new(config(12, 0, views.len() as u32)).unwrap();
    let mut opts = options(0, 1);
    opts.rays_per_step = cap;
    let err = train_gpu(&ctx, &field, &views, None, &opts, None, &mut |_| {})
        .expect_err("a step past the loop cap must be refused")
        .to_string();
    assert!(
        err.contains(&cap.to_string()) && err.contains("rays_per_step") && err.contains("Cpu"),
        "{err}"
    );
    opts.rays_per_step = 96;
    train_gpu(&ctx, &field, &views, None, &opts, None, &mut |_| {}).unwrap();
}

/// The paper's field size (16 levels of 2^17 entries, 64-wide networks, 128 marching steps,
/// 1,024 rays: about 108,700 samples a step) on the generated scene for 12 steps, an
/// occupancy refresh among them: the GPU's losses follow the CPU's step by step and march the
/// same samples. About 55 s on lavapipe, so not in the default run:
/// `cargo test --release -p augsplat-field --test gpu_field -- --ignored`.
#[test]
#[ignore = "55 s on lavapipe"]
fn a_paper_size_field_follows_the_cpu_step_by_step() {
    let Some(ctx) = context("a_paper_size_field_follows_the_cpu_step_by_step") else {
        return;
    };
    let dir = tempfile::tempdir().unwrap();
    common::split_scene(dir.path(), 12, 64, 48, 0.05);
    let (_, views) = load_views(&dir.path().join("train"), 1).unwrap();
    let mut cfg = config(17, 0, views.len() as u32);
    cfg.grid.levels = 16;
    cfg.grid.max_resolution = 2048;
    cfg.hidden_width = 64;
    cfg.march_steps = 128;
    cfg.occupancy_resolution = 64;
    let field = Field::new(cfg).unwrap();
    let mut opts = options(0, 12);
    opts.rays_per_step = 1024;
    opts.chunk_rays = 1024;
    opts.occupancy_warmup = 4;
    let (mut cpu, mut gpu) = (Vec::new(), Vec::new());
    train(&field, &views, None, &opts, &mut |r| {
        cpu.push((r.stats.rgb_loss, r.stats.samples))
    })
    .unwrap();
    train_gpu(&ctx, &field, &views, None, &opts, None, &mut |r| {
        gpu.push((r.stats.rgb_loss, r.stats.samples))
    })
    .unwrap();
    assert_eq!(cpu.len(), 12);
    assert_eq!(cpu.len(), gpu.len());
    for (k, (a, b)) in cpu.iter().zip(&gpu).enumerate() {
        let rel = (a.0 - b.0).abs() / a.0;
        eprintln!(
            "step {k}: CPU {:.6} ({} samples), GPU {:.6} ({}), {rel:.1e}",
            a.0, a.1, b.0, b.1
        );
        assert!(
            a.1 > 100_000 && a.1 == b.1,
            "step {k}: samples {} and {}",
            a.1,
            b.1
        );
        assert!(rel <= 1e-5, "step {k}: CPU loss {} GPU loss {}", a.0, b.0);
    }
}
