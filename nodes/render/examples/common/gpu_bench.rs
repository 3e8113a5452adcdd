//! What the GPU benchmark examples share: their command line (`N,N,... WxH,... REPS`), the
//! GPU context, and the median.

use augsplat_render::gpu::GpuContext;

/// The parsed command line: Gaussian counts, image sizes, repetitions.
pub struct Args {
    /// Gaussian counts to measure.
    pub counts: Vec<usize>,
    /// Image sizes (width, height).
    pub sizes: Vec<(u32, u32)>,
    /// Repetitions per case (at least 1).
    pub reps: usize,
}

/// Parses `[N,N,... [WxH,... [REPS]]]` (defaults: 10000, 256x256, `default_reps`).
pub fn args(default_reps: usize) -> Args {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let counts = args.first().map_or(vec![10_000], |a| {
        a.split(',').filter_map(|s| s.parse().ok()).collect()
    });
    let sizes = args.get(1).map_or(vec![(256, 256)], |a| {
        a.split(',')
            .filter_map(|s| {
                let (w, h) = s.split_once('x')?;
                Some((w.parse().ok()?, h.parse().ok()?))
            })
            .collect()
    });
    let reps = args
        .get(2)
        .and_then(|s| s.parse().ok())
        .unwrap_or(default_reps)
        .max(1);
    Args {
        counts,
        sizes,
        reps,
    }
}

/// The GPU context, or exit with wgpu's message.
pub fn context() -> GpuContext {
    match GpuContext::new() {
        Ok(c) => c,
        Err(e) => {
            eprintln!("{e}");
            std::process::exit(1);
        }
    }
}

/// The median of `v` (the upper one for an even count).
pub fn median(mut v: Vec<f64>) -> f64 {
    v.sort_by(f64::total_cmp);
    v[v.len() / 2]
}

/// The camera of `train_step_bench` and the GPU benchmarks: 4 units behind the Gaussians'
/// box, focal length 0.9·width, centred principal point.
pub fn bench_camera(w: u32, h: u32) -> augsplat_core::Camera {
    augsplat_core::Camera {
        width: w,
        height: h,
        fx: w as f64 * 0.9,
        fy: w as f64 * 0.9,
        cx: w as f64 / 2.0,
        cy: h as f64 / 2.0,
        world_to_camera: augsplat_core::linalg::mat4_from_rt(
            &[[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]],
            [0.0, 0.0, 4.0],
        ),
    }
}
