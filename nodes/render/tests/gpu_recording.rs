//! Recording on the GPU context (wgpu; on CI Mesa's lavapipe): the dispatches of one encoder
//! share a compute pass until something else is recorded, small uploads go up in one queue
//! write per submission, and neither changes what the work computes or the order it runs in.
//! Skips with a message when no GPU adapter is found (fails under `CI=true`, where `.ci/run`
//! installs lavapipe).

use augsplat_render::gpu::{pipelines, GpuContext, RecordingStats, BATCHED_UPLOAD_BYTES};

mod gpu_common;
use gpu_common::context;

/// `x ← x·mul + add` over the first `n` words: dispatches in another order give other words.
const KERNEL: &str = "
struct Params { mul: u32, add: u32, n: u32, pad: u32 }
@group(0) @binding(0) var<uniform> p: Params;
@group(0) @binding(1) var<storage, read_write> data: array<u32>;
@compute @workgroup_size(64)
fn main(@builtin(global_invocation_id) g: vec3<u32>) {
    if g.x < p.n { data[g.x] = data[g.x] * p.mul + p.add + g.x; }
}
";

const WORDS: u32 = 100;

/// [`KERNEL`] compiled on `ctx`.
fn compiled(ctx: &GpuContext) -> std::sync::Arc<[wgpu::ComputePipeline; 1]> {
    ctx.kernels_of(|setup| pipelines(setup, "recording test", KERNEL, ["main"]))
        .unwrap()
}

/// The kernel's parameters for dispatch `i`.
fn params(i: u32) -> [u32; 4] {
    [i % 3 + 1, 7 * i + 1, WORDS, 0]
}

/// The host's words after dispatches `range` on `words`.
fn on_host(mut words: Vec<u32>, range: std::ops::Range<u32>) -> Vec<u32> {
    for i in range {
        let [mul, add, ..] = params(i);
        for (x, w) in words.iter_mut().enumerate() {
            *w = w.wrapping_mul(mul).wrapping_add(add).wrapping_add(x as u32);
        }
    }
    words
}

fn since(before: RecordingStats, after: RecordingStats) -> RecordingStats {
    RecordingStats {
        dispatches: after.dispatches - before.dispatches,
        passes: after.passes - before.passes,
        gathered_uploads: after.gathered_uploads - before.gathered_uploads,
        queue_writes: after.queue_writes - before.queue_writes,
    }
}

#[test]
fn dispatches_share_a_pass_until_a_copy_and_uploads_go_up_together() {
    let Some(ctx) = context("dispatches_share_a_pass_until_a_copy_and_uploads_go_up_together")
    else {
        return;
    };
    let kernels = compiled(&ctx);
    let [kernel] = &*kernels;
    let start: Vec<u32> = (0..WORDS).map(|x| x * 31 + 5).collect();
    // Past the batch's limit: a queue write of its own.
    let large: Vec<u32> = (0..(BATCHED_UPLOAD_BYTES as u32 / 4 + 10)).collect();
    let before = ctx.recording_stats();
    let data = ctx.storage_init("data", &start).unwrap();
    let large_buf = ctx.storage_init("large", &large).unwrap();
    let snapshot = ctx.storage("snapshot", 4 * u64::from(WORDS)).unwrap();
    let mut enc = ctx.encoder();
    for i in 0..40 {
        let p = ctx.uniform("params", &params(i));
        ctx.dispatch(&mut enc, kernel, &[(0, &p), (1, &data)], [2, 1]);
        // Dropped at once: the kept upload and encoder still hold it until submitted.
        drop(p);
        if i == 24 {
            enc.copy_buffer_to_buffer(&data, 0, &snapshot, 0, 4 * u64::from(WORDS));
        }
    }
    ctx.defer(enc).unwrap();
    // Nothing reclaimed while an encoder is kept: the dropped blocks are not reused yet.
    ctx.reclaim();
    let words = ctx
        .read_after(
            ctx.encoder(),
            &[
                (&data, 0, WORDS as usize),
                (&snapshot, 0, WORDS as usize),
                (&large_buf, 0, large.len()),
            ],
        )
        .unwrap();
    assert_eq!(words[0], on_host(start.clone(), 0..40), "all 40, in order");
    assert_eq!(words[1], on_host(start, 0..25), "the copy after the 25th");
    assert_eq!(words[2], large);
    assert_eq!(
        since(before, ctx.recording_stats()),
        RecordingStats {
            dispatches: 40,
            passes: 2,
            // The data and the 40 parameter blocks.
            gathered_uploads: 41,
            // Their batch, and the large array's own.
            queue_writes: 2,
        }
    );
}

#[test]
fn uploads_land_before_their_submission_and_their_staging_is_reused() {
    let Some(ctx) = context("uploads_land_before_their_submission_and_their_staging_is_reused")
    else {
        return;
    };
    let kernels = compiled(&ctx);
    let [kernel] = &*kernels;
    let start: Vec<u32> = (0..WORDS).collect();
    let data = ctx.storage_init("data", &start).unwrap();
    let mut created = Vec::new();
    // Each round submits without waiting, the staging of the round before reclaimed and
    // handed out again while its submission may still be queued.
    for round in 0..6 {
        let mut enc = ctx.encoder();
        for i in 3 * round..3 * round + 3 {
            let p = ctx.uniform("params", &params(i));
            ctx.dispatch(&mut enc, kernel, &[(0, &p), (1, &data)], [2, 1]);
        }
        ctx.submit_no_wait(enc).unwrap();
        ctx.reclaim();
        created.push(ctx.pool_stats().created);
    }
    assert_eq!(
        ctx.read_words(&data, WORDS as usize).unwrap(),
        on_host(start, 0..18)
    );
    assert!(
        created[2..].iter().all(|&c| c == created[1]),
        "no buffer created after the first rounds: {created:?}"
    );
}

#[test]
fn a_gathered_upload_holds_back_the_reclaim_of_what_it_writes() {
    let Some(ctx) = context("a_gathered_upload_holds_back_the_reclaim_of_what_it_writes") else {
        return;
    };
    // Nothing but the upload is pending: the block stays in quarantine, so no later request
    // can be handed it (and cleared or written) before the upload's copy has run.
    let block = ctx.uniform("params", &params(1));
    drop(block);
    ctx.reclaim();
    assert!(ctx.has_deferred());
    assert_eq!(ctx.pool_stats().quarantined, 1);
    ctx.flush().unwrap();
    ctx.reclaim();
    assert!(!ctx.has_deferred());
    assert_eq!(ctx.pool_stats().quarantined, 0, "the block and the staging");
}
