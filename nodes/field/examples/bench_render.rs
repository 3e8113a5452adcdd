//! Times `RenderField`'s renderer on a trained member:
//!
//! `cargo run --release -p augsplat-field --example bench_render -- WEIGHTS_DIR POSES_JSON
//! [views] [downscale] [--json PATH]`
//!
//! `WEIGHTS_DIR` is a `TrainField` output (`config.json` + weights), `POSES_JSON` a
//! `poses.json` (e.g. a `SynthesizePoses` or `ScenePoses` output in the store). Prints the
//! seconds per view, rays per second and the samples per ray: marched in occupied cells,
//! evaluated by the density network and by the colour network. `CHUNK=N` sets the parallel
//! chunk size (default `RENDER_CHUNK_RAYS`); `WEIGHT_STATS=1` also prints, for the first
//! view, the rays' mean opacity, how their sample weights spread over decades and how many
//! samples a ray needs to keep all but 1e-4 (1e-3) of its colour weight — the bound on what
//! any exact renderer could skip. `--json PATH` also writes the seconds of all the views as a
//! `BenchRecord` (`docs/figures/`).
#![allow(clippy::needless_range_loop)]

use augsplat_core::artifacts::{self, PoseSet};
use augsplat_core::bench_record::{self, BenchRecord};
use augsplat_field::{io, train};
use std::path::Path;
use std::time::Instant;

fn main() {
    let (args, json) = bench_record::args_and_json();
    if args.len() < 2 {
        eprintln!("usage: bench_render WEIGHTS_DIR POSES_JSON [views] [downscale] [--json PATH]");
        std::process::exit(2);
    }
    let loaded = match io::load(Path::new(&args[0])) {
        Ok(l) => l,
        Err(e) => {
            eprintln!("{}: {e}", args[0]);
            std::process::exit(1);
        }
    };
    let poses: PoseSet = match artifacts::read_json(Path::new(&args[1])) {
        Ok(p) => p,
        Err(e) => {
            eprintln!("{}: {e}", args[1]);
            std::process::exit(1);
        }
    };
    let views: usize = args
        .get(2)
        .and_then(|s| s.parse().ok())
        .unwrap_or(poses.views.len());
    let down: u32 = args.get(3).and_then(|s| s.parse().ok()).unwrap_or(1);
    let chunk: usize = std::env::var("CHUNK")
        .ok()
        .and_then(|s| s.parse().ok())
        .unwrap_or(train::RENDER_CHUNK_RAYS);
    let bg = loaded.meta.background;
    let t0 = Instant::now();
    let (mut rays, mut stats) = (0u64, train::RenderStats::default());
    for pv in poses.views.iter().take(views) {
        let cam = pv.camera.downscaled(down);
        let img = train::render_camera(
            &loaded.field,
            &loaded.params,
            &loaded.occupancy,
            &cam,
            bg,
            chunk,
        );
        rays += (cam.width * cam.height) as u64;
        stats.add(&img.stats);
    }
    let secs = t0.elapsed().as_secs_f64();
    if std::env::var("WEIGHT_STATS").is_ok() {
        weight_stats(&loaded, &poses.views[0].camera);
    }
    let n = views.min(poses.views.len()).max(1);
    let size = poses
        .views
        .first()
        .map(|v| v.camera.downscaled(down))
        .map_or(String::new(), |c| format!(" at {}×{}", c.width, c.height));
    let per_ray = |v: u64| v as f64 / rays.max(1) as f64;
    println!(
        "{n} views, {rays} rays: {secs:.2} s ({:.3} s per view, {:.0} rays/s)",
        secs / n as f64,
        rays as f64 / secs
    );
    println!(
        "samples per ray: {:.1} marched in occupied cells, {:.1} through the density network, {:.1} through the colour network; {:.1} cells stepped per ray",
        per_ray(stats.marched),
        per_ray(stats.density),
        per_ray(stats.color),
        per_ray(stats.steps),
    );
    let record = BenchRecord::now(
        format!("one radiance-field member's {n} views{size}, {chunk}-ray chunks"),
        bench_record::example_command("augsplat-field", "bench_render", &args),
        format!(
            "{secs:.2} s ({:.3} s per view, {:.0} rays/s; {:.1} samples per ray through the colour network)",
            secs / n as f64,
            rays as f64 / secs,
            per_ray(stats.color)
        ),
        secs,
        "s",
    );
    record.write_or_exit(json.as_deref());
}

/// Weight distribution of one view's rays (see the module docs).
fn weight_stats(loaded: &io::LoadedField, cam: &augsplat_core::Camera) {
    use augsplat_field::field::{ChunkState, RayInput};
    let mut st = ChunkState::default();
    st.min_color_weight = 0.0;
    let mean = loaded.field.mean_embedding(&loaded.params);
    let w = cam.width as usize;
    let n = (cam.width * cam.height) as usize;
    let (mut acc_sum, mut nrays, mut hist) = (0f64, 0usize, [0u64; 8]);
    let mut need = 0u64; // samples needed to keep all but 1e-4 of each ray's colour weight
    let mut need3 = 0u64;
    let mut tot = 0u64;
    for c in (0..n).step_by(256) {
        let rays: Vec<RayInput> = (c..(c + 256).min(n))
            .map(|p| {
                let (o, d) = cam.pixel_ray((p / w) as u32, (p % w) as u32);
                RayInput {
                    origin: o.map(|x| x as f32),
                    dir: d.map(|x| x as f32),
                    image: u32::MAX,
                    background: [0.0; 3],
                }
            })
            .collect();
        loaded.field.forward_chunk(
            &loaded.params,
            &loaded.occupancy,
            &rays,
            &|_| 0.5,
            &mean,
            &mut st,
        );
        for r in 0..rays.len() {
            acc_sum += st.out[r].acc as f64;
            nrays += 1;
            let mut ws: Vec<f32> = st.w[st.ray_start[r]..st.ray_start[r + 1]].to_vec();
            tot += ws.len() as u64;
            for &x in &ws {
                let b = if x <= 0.0 {
                    7
                } else {
                    ((-x.log10()).floor() as usize).min(7)
                };
                hist[b] += 1;
            }
            ws.sort_by(|a, b| a.total_cmp(b));
            let (mut s, mut k) = (0f32, 0usize);
            while k < ws.len() && s + ws[k] <= 1e-4 {
                s += ws[k];
                k += 1;
            }
            need += (ws.len() - k) as u64;
            let (mut s, mut k) = (0f32, 0usize);
            while k < ws.len() && s + ws[k] <= 1e-3 {
                s += ws[k];
                k += 1;
            }
            need3 += (ws.len() - k) as u64;
        }
    }
    println!("mean acc {:.5}; samples/ray {:.1}; needed for 1e-4 colour: {:.1}, for 1e-3: {:.1}; weight decades (1e0,1e-1,..): {:?}",
        acc_sum / nrays as f64, tot as f64 / nrays as f64, need as f64 / nrays as f64, need3 as f64 / nrays as f64, hist);
}
