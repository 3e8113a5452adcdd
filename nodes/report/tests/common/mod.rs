//! Fixtures shared by the integration tests: tiny scenes, training curves, eval folders made
//! through the real `evaluate` code path with a deterministic stand-in renderer, and a
//! synthetic set.
#![allow(dead_code)]

use augsplat_core::artifacts::{self, CurvePoint, SyntheticSet, SyntheticView, TrainingCurve};
use augsplat_core::{image, Camera, ImageF32, Scene, SceneView};
use augsplat_report::evaluate::{evaluate, Checkpoint, EvalContext};
use augsplat_report::ReportError;
use std::path::{Path, PathBuf};

/// The shared LPIPS weights folder, when present (reports the skip otherwise; a failure under
/// `CI=true`).
pub fn lpips_dir() -> Option<PathBuf> {
    augsplat_testkit::data::shared_data("LPIPS", "lpips/lpips_alex_v0.1.safetensors")
        .map(|d| d.join("lpips"))
}

pub use augsplat_testkit::cameras::facing as camera;

/// A smooth colourful pattern with an edge, values within [0.1, 0.85].
pub fn pattern(w: u32, h: u32, phase: f32) -> ImageF32 {
    let mut img = ImageF32::new(w, h, 3);
    for y in 0..h {
        for x in 0..w {
            let (fx, fy) = (x as f32, y as f32);
            let edge = if x * 3 > w + y { 0.2 } else { 0.0 };
            img.set(
                x,
                y,
                0,
                0.45 + 0.3 * (fx / 5.0 + phase).sin() * (fy / 7.0).cos() + edge * 0.5,
            );
            img.set(x, y, 1, 0.45 + 0.3 * (fy / 4.0 - phase).sin());
            img.set(x, y, 2, 0.4 + 0.25 * ((fx + fy) / 9.0).cos() - edge * 0.5);
        }
    }
    img
}

/// Writes a scene folder with `n` views of `w × h` pattern images; returns the images as
/// read back (8-bit quantised).
pub fn make_scene(dir: &Path, n: usize, w: u32, h: u32) -> Vec<ImageF32> {
    std::fs::create_dir_all(dir.join("images")).unwrap();
    let mut views = Vec::new();
    let mut imgs = Vec::new();
    for i in 0..n {
        let name = format!("view{i:02}");
        let rel = format!("images/{name}.png");
        image::write_png(&dir.join(&rel), &pattern(w, h, i as f32)).unwrap();
        imgs.push(image::read_rgb(&dir.join(&rel)).unwrap());
        views.push(SceneView {
            name,
            image: rel,
            depth: None,
            camera: camera(w, h, 2.0 + i as f64),
        });
    }
    let scene = Scene {
        source: "test fixture".into(),
        views,
        near: 0.1,
        far: 10.0,
        normalization: Default::default(),
        has_points: false,
    };
    scene.save(dir).unwrap();
    imgs
}

/// A curve over steps 100..=100·n whose average error follows `avg(step)`.
pub fn curve(
    label: &str,
    n: u64,
    psnr: impl Fn(u64) -> f64,
    avg: impl Fn(u64) -> Option<f64>,
) -> TrainingCurve {
    TrainingCurve {
        label: label.into(),
        points: (1..=n)
            .map(|k| {
                let step = k * 100;
                CurvePoint {
                    step,
                    psnr: psnr(step),
                    ssim: 0.5 + step as f64 / 4000.0,
                    lpips: avg(step).map(|a| a * 2.0),
                    mse: 10f64.powf(-psnr(step) / 10.0),
                    avg_error: avg(step),
                    primitives: 1000 + step,
                    seconds: step as f64 * 0.05,
                    loss: 0.1,
                }
            })
            .collect(),
    }
}

/// Writes a model folder holding only `curve.json` (and `best.json`).
pub fn make_model(dir: &Path, c: &TrainingCurve, best_step: u64) {
    std::fs::create_dir_all(dir).unwrap();
    artifacts::write_json(&dir.join("curve.json"), c).unwrap();
    std::fs::write(dir.join("best.json"), format!("{{\"step\": {best_step}}}")).unwrap();
}

/// Deterministic per-pixel noise in [−1, 1].
pub fn noise(i: usize, seed: u64) -> f32 {
    let mut z = (i as u64).wrapping_add(seed.wrapping_mul(0x9E37_79B9_7F4A_7C15));
    z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
    z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
    z ^= z >> 31;
    (z >> 40) as f32 / (1u64 << 23) as f32 - 1.0
}

/// A stand-in renderer: looks the camera up among the scene's views and returns its ground
/// truth degraded by noise of amplitude `amp` (plus a brighter blotch in the lower right).
pub fn degrading_renderer(
    gts: Vec<ImageF32>,
    cams: Vec<Camera>,
    amp: f32,
    seed: u64,
) -> impl Fn(&Camera) -> Result<ImageF32, ReportError> {
    move |cam: &Camera| {
        let i = cams
            .iter()
            .position(|c| c.world_to_camera == cam.world_to_camera)
            .ok_or_else(|| ReportError::Message("unknown camera".into()))?;
        let mut img = gts[i].clone();
        let w = img.width;
        for (k, v) in img.data.iter_mut().enumerate() {
            let p = k / 3;
            let (x, y) = ((p as u32) % w, (p as u32) / w);
            let blotch = if x > w * 3 / 4 && y > img.height * 2 / 3 {
                2.0
            } else {
                1.0
            };
            *v += amp * blotch * noise(k, seed);
        }
        Ok(img)
    }
}

/// Builds three eval folders (3DGS baseline, Staged, Dual) under `root` through `evaluate`,
/// with LPIPS when the shared weights are present. Returns their paths in that order.
pub fn make_evals(root: &Path) -> Vec<PathBuf> {
    let test = root.join("test");
    let gts = make_scene(&test, 3, 96, 64);
    let scene = Scene::load(&test).unwrap();
    let cams: Vec<Camera> = scene.views.iter().map(|v| v.camera.clone()).collect();
    let lp = lpips_dir().map(|d| {
        augsplat_metrics::lpips::Lpips::load(&d.join("lpips_alex_v0.1.safetensors")).unwrap()
    });
    let base_curve = curve(
        "3DGS",
        6,
        |s| 14.0 + (s as f64 / 100.0).min(4.0),
        |s| Some(0.3 - 0.02 * (s as f64 / 100.0).min(4.0)),
    );
    let methods: [(&str, f32, TrainingCurve); 3] = [
        ("3DGS", 0.08, base_curve.clone()),
        (
            "Staged",
            0.05,
            curve(
                "Staged",
                6,
                |s| 14.5 + (s as f64 / 100.0).min(5.0),
                |s| Some(0.29 - 0.02 * (s as f64 / 100.0).min(5.0)),
            ),
        ),
        (
            "Dual",
            0.06,
            curve(
                "Dual",
                6,
                |s| 14.3 + s as f64 / 150.0,
                |s| Some(0.3 - s as f64 / 4000.0),
            ),
        ),
    ];
    let mut out = Vec::new();
    for (k, (label, amp, c)) in methods.iter().enumerate() {
        let model = root.join(format!("model_{label}"));
        make_model(&model, c, 400);
        let base_model = root.join("model_3DGS");
        let eval_dir = root.join(format!("eval_{label}"));
        std::fs::create_dir_all(&eval_dir).unwrap();
        let cx = EvalContext {
            label: String::new(),
            fallback_label: "node".into(),
            checkpoint: Checkpoint::Best,
            model_dir: model,
            baseline_dir: (k > 0).then_some(base_model),
            lpips: lp
                .as_ref()
                .map(|m| (m, augsplat_metrics::lpips::Backbone::Alex)),
            lpips_note: lp
                .is_none()
                .then(|| "LPIPS weights absent in this test run".to_string()),
            primitives: Some(1234 + k as u64),
            record_wall_time: true,
            device: None,
            train: None,
        };
        let render = degrading_renderer(gts.clone(), cams.clone(), *amp, k as u64 + 1);
        evaluate(&cx, &test, &eval_dir, render, &|_, _| {}).unwrap();
        out.push(eval_dir);
    }
    out
}

/// Writes a synthetic set of `n` 24×16 views (targets and weight maps) into `dir`.
pub fn make_synthetic(dir: &Path, n: usize) {
    SyntheticSet::create_folders(dir).unwrap();
    let mut set = SyntheticSet::default();
    for i in 0..n {
        let (w, h) = (24u32, 16u32);
        let t = pattern(w, h, i as f32 * 0.3);
        let weight: Vec<f32> = (0..w * h)
            .map(|p| ((p % w) as f32 / (w - 1) as f32).powf(1.5))
            .collect();
        let planar: Vec<f32> = (0..3).flat_map(|c| t.channel(c)).collect();
        let name = format!("syn{i:03}");
        let view = SyntheticView::write(dir, &name, &camera(w, h, 1.0), &planar, &weight);
        set.views.push(view.unwrap());
    }
    artifacts::write_json(&dir.join("synthetic.json"), &set).unwrap();
}
