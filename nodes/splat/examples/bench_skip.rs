//! What skipping low-confidence synthetic pixels saves: for each threshold, the
//! synthetic part of a training step — masked render, confidence-weighted L2, backward — over
//! every view of an `AggregateEnsemble` output, with a trained model.
//!
//! ```text
//! cargo run --release -p augsplat-splat --example bench_skip -- MODEL.ply SYNTHETIC_DIR [T ...] [--rounds R] [--json PATH]
//! ```
//!
//! Defaults: thresholds 0 0.05 0.2 0.5, 5 rounds. The thresholds are timed interleaved (round
//! r runs every threshold once), and the median round is reported, so a busy machine biases
//! no threshold. Also printed: the fraction of pixels and of 16×16 tiles skipped and of the
//! composited (Gaussian, pixel) pairs saved — machine-independent measures of the work.

use augsplat_core::artifacts::{self, SyntheticSet};
use augsplat_core::bench_record::{self, BenchRecord};
use augsplat_core::Camera;
use augsplat_splat::loss::{self, WeightNorm};
use augsplat_splat::train::SynthView;
use augsplat_splat::{backward, read_ply, render_masked, RenderSettings};
use std::path::{Path, PathBuf};
use std::time::Instant;

fn load(dir: &Path, skip_below: f64) -> Vec<SynthView> {
    let set: SyntheticSet =
        artifacts::read_json(&dir.join(artifacts::files::SYNTHETIC)).expect("synthetic.json");
    set.views
        .iter()
        .map(|v| {
            let px = v.read(dir).expect("synthetic view");
            SynthView::new(
                v.name.clone(),
                v.camera.clone(),
                px.target.data,
                px.weight,
                skip_below,
            )
        })
        .collect()
}

fn skipped_tiles(cam: &Camera, mask: Option<&[u8]>) -> (usize, usize) {
    let (w, h) = (cam.width as usize, cam.height as usize);
    let (tx, ty) = (w.div_ceil(16), h.div_ceil(16));
    let Some(m) = mask else { return (0, tx * ty) };
    let mut empty = 0;
    for by in 0..ty {
        for bx in 0..tx {
            let any = (by * 16..(by * 16 + 16).min(h))
                .any(|y| (bx * 16..(bx * 16 + 16).min(w)).any(|x| m[y * w + x] != 0));
            empty += (!any) as usize;
        }
    }
    (empty, tx * ty)
}

fn main() {
    let (argv, json) = bench_record::args_and_json();
    let mut args = argv.clone().into_iter();
    let model = PathBuf::from(args.next().expect("MODEL.ply"));
    let dir = PathBuf::from(args.next().expect("SYNTHETIC_DIR"));
    let mut thresholds: Vec<f64> = Vec::new();
    let mut rounds = 5usize;
    while let Some(a) = args.next() {
        if a == "--rounds" {
            rounds = args
                .next()
                .and_then(|v| v.parse().ok())
                .expect("--rounds R");
        } else {
            thresholds.push(a.parse().expect("a threshold"));
        }
    }
    if thresholds.is_empty() {
        thresholds = vec![0.0, 0.05, 0.2, 0.5];
    }
    let g = read_ply(&model).expect("model PLY");
    let s = RenderSettings::default();
    let sets: Vec<Vec<SynthView>> = thresholds.iter().map(|&t| load(&dir, t)).collect();
    println!(
        "{} Gaussians, {} synthetic views of {}×{}, {} threads, {rounds} interleaved rounds",
        g.len(),
        sets[0].len(),
        sets[0].first().map_or(0, |v| v.camera.width),
        sets[0].first().map_or(0, |v| v.camera.height),
        rayon::current_num_threads()
    );
    let mut times = vec![Vec::new(); thresholds.len()];
    let mut pairs = vec![0u64; thresholds.len()];
    for round in 0..rounds + 1 {
        for (k, views) in sets.iter().enumerate() {
            let t0 = Instant::now();
            let mut p = 0u64;
            for v in views {
                if v.weight_sum <= 0.0 {
                    continue;
                }
                let out = render_masked(&g, &v.camera, &s, v.mask.as_deref());
                let mut grad = vec![0f32; out.rgb.len()];
                loss::weighted_l2(
                    &out.rgb,
                    &v.target,
                    &v.weight,
                    WeightNorm::WeightSum,
                    1.0,
                    &mut grad,
                );
                let gr = backward(&g, &v.camera, &s, &out, &grad, None, None);
                std::hint::black_box(&gr);
                p += out.stats.pairs;
            }
            // Round 0 warms caches and is not timed.
            if round > 0 {
                times[k].push(t0.elapsed().as_secs_f64());
            }
            pairs[k] = p;
        }
    }
    let base = {
        let mut t = times[0].clone();
        t.sort_by(f64::total_cmp);
        t[t.len() / 2]
    };
    let mut rows = Vec::new();
    println!("threshold | pixels skipped | tiles skipped | pairs saved | ms per view (median round) | time saved");
    for (k, &thr) in thresholds.iter().enumerate() {
        let mut t = times[k].clone();
        t.sort_by(f64::total_cmp);
        let med = t[t.len() / 2];
        let (mut px_skip, mut px_all, mut tl_skip, mut tl_all) = (0usize, 0usize, 0usize, 0usize);
        for v in &sets[k] {
            px_all += v.weight.len();
            px_skip += v
                .mask
                .as_ref()
                .map_or(0, |m| m.iter().filter(|&&x| x == 0).count());
            let (e, a) = skipped_tiles(&v.camera, v.mask.as_deref());
            tl_skip += e;
            tl_all += a;
        }
        rows.push((
            thr,
            1e3 * med / sets[k].len().max(1) as f64,
            100.0 * (1.0 - med / base),
        ));
        println!(
            "{thr:9} | {:13.1}% | {:12.1}% | {:10.1}% | {:26.3} | {:8.1}%",
            100.0 * px_skip as f64 / px_all.max(1) as f64,
            100.0 * tl_skip as f64 / tl_all.max(1) as f64,
            100.0 * (1.0 - pairs[k] as f64 / pairs[0].max(1) as f64),
            1e3 * med / sets[k].len().max(1) as f64,
            100.0 * (1.0 - med / base)
        );
    }
    // The headline: the time saved at the last (largest) threshold, against no skipping.
    if let Some(&(thr, ms, saved)) = rows.last() {
        BenchRecord::now(
            format!(
                "synthetic part of a step, skipping pixels below confidence {thr}, {} views",
                sets[0].len()
            ),
            bench_record::example_command("augsplat-splat", "bench_skip", &argv),
            format!(
                "{ms:.3} ms per view (median of {rounds} interleaved rounds), {saved:.1} % saved against no skipping"
            ),
            saved,
            "%",
        )
        .write_or_exit(json.as_deref());
    }
}
