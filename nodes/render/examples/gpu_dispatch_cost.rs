//! What one small kernel launch costs the host to record: a parameter block and a dispatch,
//! as every kernel of a training step is recorded, in three ways.
//!
//! - `shared pass, batched upload`: the context's way ([`GpuContext::uniform`] gathers the
//!   block into the submission's one upload; [`GpuContext::dispatch`] keeps one compute pass
//!   open across dispatches);
//! - `pass per dispatch`: the same with the pass ended after each dispatch;
//! - `pass per dispatch, queue write each`: as the context recorded before, each block in a
//!   `queue.write_buffer` of its own (a staging buffer each) and a pass per dispatch.
//!
//! `cargo run --release -p augsplat-render --example gpu_dispatch_cost -- [DISPATCHES [ROUNDS]]`
//! (defaults 600 and 6). Prints per round the microseconds per dispatch from the first
//! record to the finished command buffer (the submission and the device's work are not
//! counted), then the median of each way over the rounds after the first.

use augsplat_render::gpu::{pipelines, words_to_bytes, GpuContext};
use std::time::Instant;

const KERNEL: &str = "
struct Params { add: u32, n: u32, pad0: u32, pad1: u32 }
@group(0) @binding(0) var<uniform> p: Params;
@group(0) @binding(1) var<storage, read_write> data: array<u32>;
@compute @workgroup_size(64)
fn main(@builtin(global_invocation_id) g: vec3<u32>) {
    if g.x < p.n { data[g.x] += p.add; }
}
";

/// How the blocks and passes are recorded.
#[derive(Clone, Copy)]
enum Way {
    Shared,
    PassEach,
    WriteEach,
}

/// Microseconds per dispatch to record `n` dispatches `way` (`plain`: `n` parameter buffers
/// of the device's own for the queue writes, as pooled ones would be, never cleared).
fn record(
    ctx: &GpuContext,
    pipeline: &wgpu::ComputePipeline,
    plain: &[wgpu::Buffer],
    way: Way,
) -> f64 {
    let n = plain.len();
    let data = ctx.storage("data", 4096).expect("a 4 kB buffer");
    let started = Instant::now();
    let mut enc = ctx.encoder();
    let mut blocks = Vec::with_capacity(n);
    for (i, own) in plain.iter().enumerate() {
        let words = [i as u32, 1024, 0, 0];
        let pooled;
        let block = match way {
            Way::WriteEach => {
                ctx.queue.write_buffer(own, 0, &words_to_bytes(&words));
                own
            }
            _ => {
                pooled = ctx.uniform("params", &words);
                blocks.push(pooled);
                &blocks[blocks.len() - 1]
            }
        };
        ctx.dispatch(&mut enc, pipeline, &[(0, block), (1, &data)], [16, 1]);
        if !matches!(way, Way::Shared) {
            // Borrowing the encoder mutably ends the open pass.
            let _: &mut wgpu::CommandEncoder = &mut enc;
        }
    }
    // Finished and kept (where wgpu encodes the passes), then submitted after the uploads.
    ctx.defer(enc).expect("the encoder finishes");
    let micros = started.elapsed().as_secs_f64() * 1e6 / n as f64;
    ctx.wait().expect("the dispatches run");
    drop(blocks);
    drop(data);
    ctx.reclaim();
    micros
}

fn median(mut v: Vec<f64>) -> f64 {
    v.sort_by(f64::total_cmp);
    v[v.len() / 2]
}

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let mut args = std::env::args().skip(1);
    let n: usize = args.next().map(|a| a.parse()).transpose()?.unwrap_or(600);
    let rounds: usize = args.next().map(|a| a.parse()).transpose()?.unwrap_or(6);
    let ctx = GpuContext::new()?;
    println!("adapter: {}", ctx.adapter());
    let kernels = ctx.kernels_of(|setup| pipelines(setup, "add", KERNEL, ["main"]))?;
    let [pipeline] = &*kernels;
    let plain: Vec<wgpu::Buffer> = (0..n)
        .map(|_| {
            ctx.device.create_buffer(&wgpu::BufferDescriptor {
                label: Some("params"),
                size: 16,
                usage: wgpu::BufferUsages::UNIFORM
                    | wgpu::BufferUsages::STORAGE
                    | wgpu::BufferUsages::COPY_DST,
                mapped_at_creation: false,
            })
        })
        .collect();
    let ways = [
        ("shared pass, batched upload", Way::Shared),
        ("pass per dispatch", Way::PassEach),
        ("pass per dispatch, queue write each", Way::WriteEach),
    ];
    let mut times = vec![Vec::new(); ways.len()];
    for round in 0..rounds.max(2) {
        let line: Vec<String> = ways
            .iter()
            .zip(&mut times)
            .map(|(&(name, way), t)| {
                let us = record(&ctx, pipeline, &plain, way);
                if round > 0 {
                    t.push(us);
                }
                format!("{name} {us:.2} µs")
            })
            .collect();
        println!("round {round}, {n} dispatches: {}", line.join(", "));
    }
    for ((name, _), t) in ways.iter().zip(times) {
        println!("{name}: median {:.2} µs per dispatch", median(t));
    }
    Ok(())
}
