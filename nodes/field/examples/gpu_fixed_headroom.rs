//! How far the hash table's fixed-point gradient sums stay from overflow on a real capture:
//! trains a field on the GPU on a scene folder for a few steps and, at every step, compares
//! each level's largest entry with the 2^62 its 64-bit accumulators hold.
//!
//! The scale of a level is 2^s with s = 62 − ⌈log2 n⌉ − (e + 1), where n is the step's
//! sample count and 2^e ≤ max |d_out| < 2^(e+1) (`hashgrid/hashgrid_fixed.wgsl`): no entry can
//! pass 2^62 by construction. The headroom of a level is 62 − log2(max |entry| · 2^s) bits:
//! how many doublings the worst entry could still take.
//!
//! `cargo run --release -p augsplat-field --example gpu_fixed_headroom -- SCENE_DIR [STEPS]`
//! (SCENE_DIR: a scene folder, e.g. a `SplitScene` node's `train` output; default 20 steps;
//! the paper's field settings: 1,024 rays a step, 16 levels × 2 features, 2^17 entries).

use augsplat_field::field::Field;
use augsplat_field::gpu::train::{step_rays, GpuTrainer};
use augsplat_field::node::TrainFieldArgs;
use augsplat_field::occupancy::OccupancyGrid;
use augsplat_field::train::{load_views, Adam, TrainState};
use augsplat_render::gpu::GpuContext;

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let dir = args
        .first()
        .ok_or("usage: gpu_fixed_headroom SCENE_DIR [STEPS]")?;
    let steps: u32 = args.get(1).map(|s| s.parse()).transpose()?.unwrap_or(20);
    let ctx = GpuContext::new()?;
    println!("GPU: {}", ctx.adapter());
    let targs = TrainFieldArgs {
        rays_per_step: 1024,
        log2_table_size: 17,
        max_resolution: 2048,
        march_steps: 128,
        occupancy_warmup: 256,
        ..TrainFieldArgs::default()
    };
    let (scene, views) = load_views(std::path::Path::new(dir), 1)?;
    let field = Field::new(targs.field_config(&scene, views.len())?)?;
    let opts = targs.options();
    let state = TrainState {
        params: field.init_params(opts.seed),
        occupancy: OccupancyGrid::full(field.config.occupancy_resolution),
        skipped_steps: 0,
        nonfinite_values: 0,
    };
    let mut trainer = GpuTrainer::new(&ctx, &field, &state, &Adam::new(field.n_params))?;
    let levels = field.grid.levels();
    let mut worst = f64::INFINITY;
    for step in 0..steps {
        // The step's gradient (before Adam), then the step itself.
        let rays = step_rays(&views, &opts, step);
        let (bufs, _, enc) = trainer.record_gradient(&rays, &opts, &[])?;
        let words = ctx.read_after(
            enc,
            &[
                (&bufs.grad, 0, field.density_offset),
                (&bufs.levels, 0, 2 * levels),
            ],
        )?;
        let n = bufs.n.max(1);
        let mut line = Vec::new();
        for l in 0..levels {
            let range = field.grid.level_range(l);
            let max_entry = words[0][range]
                .iter()
                .map(|w| f32::from_bits(*w).abs() as f64)
                .fold(0.0, f64::max);
            let bits = words[1][2 * l];
            if bits == 0 || max_entry == 0.0 {
                continue;
            }
            let e = ((bits >> 23) & 0xff) as i64 - 127;
            let s = 62 - (u32::BITS - (n - 1).leading_zeros()) as i64 - (e + 1);
            let headroom = 62.0 - (max_entry.log2() + s as f64);
            worst = worst.min(headroom);
            line.push(format!("{headroom:.1}"));
        }
        println!(
            "step {step}: {n} samples; headroom bits per level: {}",
            line.join(" ")
        );
        trainer.step(&views, &opts, step, None)?;
    }
    trainer.settle()?;
    println!("worst headroom over {steps} steps: {worst:.1} bits (of 62)");
    Ok(())
}
