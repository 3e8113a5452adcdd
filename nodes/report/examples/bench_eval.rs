//! Benchmark of evaluation and report building at the paper's evaluation size.
//!
//! `cargo run -p augsplat-report --example bench_eval --profile test -- [GAUSSIANS] [VIEWS]
//! [--json PATH]`
//!
//! Builds a random splat model (default 50 000 Gaussians) and a test scene of VIEWS (default
//! 4) 800×533 views whose ground truth is the mip-NeRF 360 bonsai photos when
//! `../shared/data/bonsai/images` exists (random noise otherwise), then times per stage:
//! render, MSE+SSIM, LPIPS-alex (when `../shared/data/lpips` exists), the whole `evaluate`
//! (renders + metrics + PNG writing), and `build_report` over three such evaluations.
//! `--json PATH` also writes the best of the three evaluations as a `BenchRecord`
//! (`docs/figures/`).

use augsplat_core::bench_record::{self, BenchRecord};
use augsplat_core::{image, Camera, ImageF32, Scene, SceneView};
use augsplat_report::evalset::EvalDir;
use augsplat_report::evaluate::{evaluate, Checkpoint, EvalContext};
use augsplat_report::report::{build_report, ReportOptions};
use augsplat_splat::{render, Gaussians, RenderSettings};
use std::path::{Path, PathBuf};
use std::time::Instant;

fn rng(state: &mut u64) -> f32 {
    *state = state
        .wrapping_mul(6364136223846793005)
        .wrapping_add(1442695040888963407);
    ((*state >> 40) as f32) / (1u64 << 24) as f32
}

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let (args, json) = bench_record::args_and_json();
    let n: usize = args
        .first()
        .map(|s| s.parse())
        .transpose()?
        .unwrap_or(50_000);
    let views: usize = args.get(1).map(|s| s.parse()).transpose()?.unwrap_or(4);
    let (w, h) = (800u32, 533u32);
    let shared = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../../../shared/data");
    let mut s = 7u64;
    let mut g = Gaussians::empty(3);
    for _ in 0..n {
        g.means.push([
            rng(&mut s) * 4.0 - 2.0,
            rng(&mut s) * 3.0 - 1.5,
            3.0 + rng(&mut s) * 4.0,
        ]);
        let ls = (0.01 + 0.04 * rng(&mut s)).ln();
        g.log_scales.push([ls, ls + 0.3 * (rng(&mut s) - 0.5), ls]);
        g.quats
            .push([1.0, rng(&mut s) - 0.5, rng(&mut s) - 0.5, rng(&mut s) - 0.5]);
        g.opacity_logits.push(rng(&mut s) * 4.0 - 2.0);
        for _ in 0..16 * 3 {
            g.sh.push((rng(&mut s) - 0.5) * 0.5);
        }
    }
    let dir = tempfile::tempdir()?;
    let test = dir.path().join("test");
    std::fs::create_dir_all(test.join("images"))?;
    let photos: Vec<PathBuf> = match std::fs::read_dir(shared.join("bonsai/images")) {
        Ok(rd) => {
            let mut v: Vec<PathBuf> = rd.filter_map(|e| e.ok().map(|e| e.path())).collect();
            v.sort();
            v
        }
        Err(_) => vec![],
    };
    let mut scene_views = Vec::new();
    for i in 0..views {
        let gt = match photos.get(i) {
            Some(p) => image::read_rgb(p)?,
            None => ImageF32::from_vec(w, h, 3, (0..w * h * 3).map(|_| rng(&mut s)).collect()),
        };
        let rel = format!("images/v{i}.png");
        image::write_png(&test.join(&rel), &gt)?;
        let cam = Camera {
            width: gt.width,
            height: gt.height,
            fx: 700.0,
            fy: 700.0,
            cx: gt.width as f64 / 2.0,
            cy: gt.height as f64 / 2.0,
            world_to_camera: [
                [1.0, 0.0, 0.0, 0.1 * i as f64],
                [0.0, 1.0, 0.0, 0.0],
                [0.0, 0.0, 1.0, 0.0],
                [0.0, 0.0, 0.0, 1.0],
            ],
        };
        scene_views.push(SceneView {
            name: format!("v{i}"),
            image: rel,
            depth: None,
            camera: cam,
        });
    }
    let scene = Scene {
        source: "bench".into(),
        views: scene_views,
        near: 0.1,
        far: 100.0,
        normalization: Default::default(),
        has_points: false,
    };
    scene.save(&test)?;
    let lp = augsplat_metrics::lpips::find_weights(
        Some(&shared.join("lpips")),
        augsplat_metrics::lpips::Backbone::Alex,
    )
    .map(|p| augsplat_metrics::lpips::Lpips::load(&p))
    .transpose()?;
    println!(
        "{} Gaussians (SH 3), {} views of {}×{}, {} rayon threads, LPIPS-alex {}",
        n,
        views,
        scene.views[0].camera.width,
        scene.views[0].camera.height,
        rayon::current_num_threads(),
        if lp.is_some() {
            "on"
        } else {
            "off (no weights)"
        }
    );
    // Stage timings on view 0.
    let cam = &scene.views[0].camera;
    let settings = RenderSettings::default();
    let gt = scene.load_image(&test, 0)?;
    let t = Instant::now();
    let r = render(&g, cam, &settings);
    let t_render = t.elapsed().as_secs_f64();
    let img = ImageF32::from_vec(
        r.width,
        r.height,
        3,
        r.rgb.iter().map(|v| v.clamp(0.0, 1.0)).collect(),
    );
    let t = Instant::now();
    let mse = augsplat_metrics::mse(&img, &gt)?;
    let ssim = augsplat_metrics::ssim(&img, &gt)?;
    let t_ms = t.elapsed().as_secs_f64();
    let t_lp = match &lp {
        Some(m) => {
            let t = Instant::now();
            let d = m.distance(&img, &gt)?;
            println!("view 0: MSE {mse:.5}, SSIM {ssim:.4}, LPIPS {d:.4}");
            Some(t.elapsed().as_secs_f64())
        }
        None => None,
    };
    println!(
        "render {:.3} s | MSE+SSIM {:.3} s | LPIPS-alex {}",
        t_render,
        t_ms,
        t_lp.map(|v| format!("{v:.3} s")).unwrap_or("—".into())
    );
    // Whole evaluation, three times (three "methods"), then the report.
    let model = dir.path().join("model");
    std::fs::create_dir_all(&model)?;
    let mut evals = Vec::new();
    let mut best_eval = f64::INFINITY;
    for k in 0..3 {
        let out = dir.path().join(format!("eval{k}"));
        std::fs::create_dir_all(&out)?;
        let cx = EvalContext {
            label: format!("method{k}"),
            fallback_label: "bench".into(),
            checkpoint: Checkpoint::Final,
            model_dir: model.clone(),
            baseline_dir: None,
            lpips: lp
                .as_ref()
                .map(|m| (m, augsplat_metrics::lpips::Backbone::Alex)),
            lpips_note: None,
            primitives: Some(n as u64),
            record_wall_time: true,
            device: None,
            train: None,
        };
        let t = Instant::now();
        let gg = &g;
        evaluate(
            &cx,
            &test,
            &out,
            |c: &Camera| {
                let r = render(gg, c, &settings);
                Ok(ImageF32::from_vec(r.width, r.height, 3, r.rgb))
            },
            &|_, _| {},
        )?;
        let secs = t.elapsed().as_secs_f64();
        best_eval = best_eval.min(secs);
        println!("evaluate ({views} views, renders + metrics + PNGs): {secs:.2} s");
        evals.push(EvalDir::load(&out)?);
    }
    let t = Instant::now();
    let built = build_report(
        &ReportOptions {
            title: "bench".into(),
            ..Default::default()
        },
        &evals,
        None::<&Path>,
    )?;
    let t_report = t.elapsed().as_secs_f64();
    println!(
        "build_report (3 evaluations): {t_report:.2} s, index.html {} KiB",
        built.html.len() / 1024
    );
    let lpips = t_lp.map_or("LPIPS off (no weights)".to_string(), |v| {
        format!("LPIPS-alex {v:.3} s")
    });
    // Its usage line runs it with the test profile, not --release.
    let mut command =
        "cargo run -p augsplat-report --example bench_eval --profile test".to_string();
    if !args.is_empty() {
        command = format!("{command} -- {}", args.join(" "));
    }
    let record = BenchRecord::now(
        format!("evaluation of {n} Gaussians on {views} views at {w}×{h}"),
        command,
        format!(
            "{best_eval:.2} s, best of 3 (view 0: render {t_render:.3} s, MSE+SSIM {t_ms:.3} s, {lpips}); build_report over 3: {t_report:.2} s"
        ),
        best_eval,
        "s",
    );
    record.write_or_exit(json.as_deref());
    Ok(())
}
