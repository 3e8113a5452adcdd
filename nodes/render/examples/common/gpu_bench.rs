//! What the GPU benchmark examples share: their command line (`N,N,... WxH,... REPS`, and
//! `--json PATH` anywhere for a [`BenchRecord`] of the headline), the GPU context, the
//! median, and the record (the machine named by its adapter).

use augsplat_core::bench_record::{self, BenchRecord};
use augsplat_render::gpu::GpuContext;

/// The parsed command line: Gaussian counts, image sizes, repetitions.
pub struct Args {
    /// Gaussian counts to measure.
    pub counts: Vec<usize>,
    /// Image sizes (width, height).
    pub sizes: Vec<(u32, u32)>,
    /// Repetitions per case (at least 1).
    pub reps: usize,
    /// The arguments without `--json PATH` (for the record's command).
    pub argv: Vec<String>,
    /// Where to write the headline's record, if asked.
    pub json: Option<std::path::PathBuf>,
}

/// Parses `[N,N,... [WxH,... [REPS]]]` (defaults: 10000, 256x256, `default_reps`).
pub fn args(default_reps: usize) -> Args {
    let (args, json) = bench_record::args_and_json();
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
        argv: args,
        json,
    }
}

/// Writes the headline of example `example` of `package` as a record when `--json` asked for
/// one, naming the machine by the GPU adapter that measured it.
pub fn record(
    ctx: &GpuContext,
    a: &Args,
    (package, example): (&str, &str),
    (what, figure): (String, String),
    (value, unit): (f64, &str),
) {
    if a.json.is_none() {
        return;
    }
    let command = bench_record::example_command(package, example, &a.argv);
    let mut r = BenchRecord::now(what, command, figure, value, unit);
    r.machine = format!("{} ({})", ctx.adapter().name, ctx.adapter().backend);
    r.write_or_exit(a.json.as_deref());
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
