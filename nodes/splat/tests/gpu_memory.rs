//! GPU memory stays flat over long runs: a training run on a generated cloud (resident memory
//! after 100 and after 250 steps), and 300 renders from a view of the demo scene (after 50 and
//! after 300). One test, so that no other test's allocations move the figures. Before the
//! fix in `loss/loss.wgsl`'s `ssim_grad`, lavapipe grew by about 400 kB per training step
//! here; before the kernels read their parameters from storage buffers on software adapters,
//! it grew by about 380 kB per render of the demo view (lavapipe recompiled every dispatch
//! whose uniform values it could inline, and kept the copies). Linux only (reads
//! `/proc/self/status`); skips without a GPU adapter (fails under `CI=true`).

use augsplat_splat::gpu::{render_scene, GpuContext, GpuError, GpuScene};
use augsplat_splat::train::{RealImages, RealLoss, RealView, TrainArgs, Trainer};
use augsplat_splat::{Gaussians, RenderSettings};
use std::sync::Arc;

/// Resident memory of this process, kB.
fn rss_kb() -> Option<u64> {
    let s = std::fs::read_to_string("/proc/self/status").ok()?;
    s.lines()
        .find(|l| l.starts_with("VmRSS"))?
        .split_whitespace()
        .nth(1)?
        .parse()
        .ok()
}

#[test]
fn gpu_training_and_rendering_memory_stays_flat() {
    let test = "gpu_training_and_rendering_memory_stays_flat";
    if rss_kb().is_none() {
        eprintln!("skipping {test}: no /proc/self/status on this system");
        return;
    }
    let gpu = match GpuContext::new() {
        Ok(c) => Arc::new(c),
        Err(e @ GpuError::NoAdapter { .. }) => {
            augsplat_testkit::skip(test, &e.to_string());
            return;
        }
        Err(e) => panic!("{test}: {e}"),
    };
    let cam = augsplat_testkit::cameras::square_pixels(
        64,
        48,
        [
            [1.0, 0.0, 0.0, 0.0],
            [0.0, 1.0, 0.0, 0.0],
            [0.0, 0.0, 1.0, 4.0],
            [0.0, 0.0, 0.0, 1.0],
        ],
    );
    let image: Vec<f32> = (0..64 * 48 * 3).map(|i| (i % 7) as f32 / 7.0).collect();
    let real = RealImages {
        views: vec![RealView {
            name: "v".into(),
            camera: cam,
            image,
        }],
        loss: RealLoss::default(),
    };
    let mut args = TrainArgs {
        steps: 250,
        ..Default::default()
    };
    args.densify.enabled = false;
    let g = Gaussians::random_cloud(2000, 0.02, 1);
    let mut t = Trainer::new(args, g, 1.0, &real, None);
    t.on_device(&augsplat_splat::Device::gpu(gpu.clone()));
    let mut at = Vec::new();
    for step in 1..=250 {
        // As a training node steps: each step's results come back during the next.
        t.advance();
        if step == 100 || step == 250 {
            at.push(rss_kb().unwrap_or(0));
        }
    }
    let growth = at[1] as i64 - at[0] as i64;
    eprintln!(
        "resident memory after 100 steps {} kB, after 250 steps {} kB ({growth:+} kB)",
        at[0], at[1]
    );
    assert!(
        growth < 16 * 1024,
        "memory grew by {growth} kB over 150 GPU training steps"
    );

    // The demo scene's first training view (128×96), whose pose made lavapipe recompile the
    // forward kernels at every render.
    let demo_view = augsplat_core::Camera {
        width: 128,
        height: 96,
        fx: 110.85125168440815,
        fy: 110.85125168440815,
        cx: 64.0,
        cy: 48.0,
        world_to_camera: [
            [
                -0.2079116908177593,
                0.9781476007338056,
                0.0,
                6.846176867277807e-17,
            ],
            [
                0.4971904410316386,
                0.10568109064088697,
                -0.8611812657203578,
                -0.41823345183279576,
            ],
            [
                -0.8423623888612699,
                -0.17904965305649764,
                -0.5082979712454917,
                0.8094292859958812,
            ],
            [0.0, 0.0, 0.0, 1.0],
        ],
    };
    // A context of its own: lavapipe stops inlining a kernel's uniforms for good once an
    // inlined copy does not shrink enough, which the training above may have caused.
    let gpu = GpuContext::new().unwrap();
    let scene = GpuScene::upload(&gpu, &Gaussians::random_cloud(3000, 0.02, 1)).unwrap();
    let settings = RenderSettings::default();
    let mut at = Vec::new();
    for render in 1..=300 {
        render_scene(&gpu, &scene, &demo_view, &settings).unwrap();
        if render == 50 || render == 300 {
            at.push(rss_kb().unwrap_or(0));
        }
    }
    let growth = at[1] as i64 - at[0] as i64;
    eprintln!(
        "resident memory after 50 renders {} kB, after 300 renders {} kB ({growth:+} kB)",
        at[0], at[1]
    );
    assert!(
        growth < 8 * 1024,
        "memory grew by {growth} kB over 250 GPU renders"
    );
}
