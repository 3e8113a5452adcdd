//! The `Evaluate` node end to end with the real splat renderer: a model rendered against
//! ground truth made from the same model (only 8-bit quantisation differs), the other
//! checkpoint measured against an independent computation, the background argument honoured,
//! cameras stored at another resolution resized, and byte-identical outputs for 1 and 2
//! threads.

mod common;

use augsplat_core::artifacts::{write_json, CurvePoint, TrainingCurve};
use augsplat_core::{image, ImageF32, Scene, SceneView};
use augsplat_graph::{Node, RunContext};
use augsplat_report::evalset::EvalDir;
use augsplat_report::evaluate::{Checkpoint, EvaluateArgs, EvaluateNode, LpipsNet};
use augsplat_splat::{render, write_ply, Gaussians, RenderSettings};
use std::path::{Path, PathBuf};

const BG: [f32; 3] = [0.2, 0.3, 0.4];

fn model(shift: f32) -> Gaussians {
    let mut g = Gaussians::empty(0);
    for k in 0..36 {
        let (i, j) = ((k % 6) as f32, (k / 6) as f32);
        g.means.push([
            (i - 2.5) * 0.25,
            (j - 2.5) * 0.2,
            3.0 + 0.1 * (k % 3) as f32,
        ]);
        g.log_scales
            .push([(0.05f32).ln(), (0.04f32).ln(), (0.05f32).ln()]);
        g.quats.push([1.0, 0.1 * i, 0.0, 0.05 * j]);
        g.opacity_logits.push(1.5);
        let c0 = 0.282_094_8_f32;
        for c in 0..3 {
            let colour = 0.2 + 0.6 * (((k * (c + 2)) % 7) as f32 / 6.0) + shift;
            g.sh.push((colour - 0.5) / c0);
        }
    }
    g
}

fn settings(bg: [f32; 3]) -> RenderSettings {
    RenderSettings {
        background: bg,
        ..Default::default()
    }
}

/// A test scene whose images are renders of `g`; view 1's camera is stored at twice the
/// image resolution (the evaluator must resize it).
fn scene(dir: &Path, g: &Gaussians) -> Vec<ImageF32> {
    std::fs::create_dir_all(dir.join("images")).unwrap();
    let mut views = Vec::new();
    let mut gts = Vec::new();
    for i in 0..2 {
        let mut cam = common::camera(48, 40, 0.1 * i as f64);
        cam.world_to_camera[0][3] = 0.05 * i as f64;
        let r = render(g, &cam, &settings(BG));
        let img = ImageF32::from_vec(48, 40, 3, r.rgb);
        let rel = format!("images/v{i}.png");
        image::write_png(&dir.join(&rel), &img).unwrap();
        gts.push(image::read_rgb(&dir.join(&rel)).unwrap());
        let stored = if i == 1 { cam.resized(96, 80) } else { cam };
        views.push(SceneView {
            name: format!("v{i}"),
            image: rel,
            depth: None,
            camera: stored,
        });
    }
    Scene {
        source: "fixture".into(),
        views,
        near: 0.1,
        far: 10.0,
        normalization: Default::default(),
        has_points: false,
    }
    .save(dir)
    .unwrap();
    gts
}

fn setup(root: &Path) -> (PathBuf, PathBuf, Vec<ImageF32>) {
    let best = model(0.0);
    let test = root.join("test");
    let gts = scene(&test, &best);
    let m = root.join("model");
    std::fs::create_dir_all(&m).unwrap();
    write_ply(&m.join("best.ply"), &best).unwrap();
    write_ply(&m.join("final.ply"), &model(0.08)).unwrap();
    let curve = TrainingCurve {
        label: "fixture".into(),
        points: (1..=3)
            .map(|k| CurvePoint {
                step: k * 100,
                psnr: 20.0 + k as f64,
                ssim: 0.8,
                ..Default::default()
            })
            .collect(),
    };
    write_json(&m.join("curve.json"), &curve).unwrap();
    std::fs::write(m.join("best.json"), r#"{"step": 300, "criterion": "psnr"}"#).unwrap();
    (m, test, gts)
}

fn run(
    root: &Path,
    name: &str,
    m: &Path,
    test: &Path,
    args: &EvaluateArgs,
    threads: usize,
) -> PathBuf {
    let out = root.join(name);
    let mut ctx = RunContext::standalone(
        vec![
            ("model".into(), vec![m.to_path_buf()]),
            ("test".into(), vec![test.to_path_buf()]),
        ],
        &["eval"],
        &out,
        0,
        threads,
    )
    .unwrap();
    let pool = rayon::ThreadPoolBuilder::new()
        .num_threads(threads)
        .build()
        .unwrap();
    pool.install(|| EvaluateNode::run(args, &mut ctx)).unwrap();
    out.join("eval")
}

#[test]
fn evaluates_real_renders_of_both_checkpoints() {
    let dir = tempfile::tempdir().unwrap();
    let (m, test, gts) = setup(dir.path());
    let args = EvaluateArgs {
        label: "Fixture".into(),
        lpips: LpipsNet::None,
        background: BG,
        ..Default::default()
    };
    let e = EvalDir::load(&run(dir.path(), "best", &m, &test, &args, 2))
        .unwrap()
        .metrics;
    assert_eq!(e.label, "Fixture");
    assert_eq!(e.checkpoint_step, Some(300));
    assert_eq!(e.primitives, Some(36));
    assert_eq!((e.views[1].width, e.views[1].height), (48, 40));
    for v in &e.views {
        // Only 8-bit quantisation separates render and ground truth: uniform rounding error
        // has MSE (1/255)²/12, i.e. ≈ 58.9 dB; allow a margin.
        assert!(v.metrics.psnr > 52.0, "{}: {} dB", v.name, v.metrics.psnr);
        assert!(v.metrics.ssim > 0.999);
    }
    assert!(e.mean.lpips.is_none());
    assert!(
        e.notes.iter().any(|n| n.contains("lpips: None")),
        "{:?}",
        e.notes
    );
    assert!(
        e.notes.iter().any(|n| n.contains("wall time not recorded")),
        "{:?}",
        e.notes
    );

    // The final checkpoint, against an independent computation of the same numbers.
    let fin = EvaluateArgs {
        checkpoint: Checkpoint::Final,
        ..args.clone()
    };
    let e = EvalDir::load(&run(dir.path(), "final", &m, &test, &fin, 2))
        .unwrap()
        .metrics;
    assert_eq!(e.checkpoint_step, Some(300));
    let cams: Vec<_> = Scene::load(&test)
        .unwrap()
        .views
        .iter()
        .map(|v| v.camera.resized(48, 40))
        .collect();
    for (i, v) in e.views.iter().enumerate() {
        let r = render(&model(0.08), &cams[i], &settings(BG));
        let img = ImageF32::from_vec(48, 40, 3, r.rgb.iter().map(|x| x.clamp(0.0, 1.0)).collect());
        let mut se = 0f64;
        for (a, b) in img.data.iter().zip(&gts[i].data) {
            se += (*a as f64 - *b as f64).powi(2);
        }
        let mse = se / img.data.len() as f64;
        assert!(
            (v.metrics.mse - mse).abs() < 1e-9,
            "{} vs {mse}",
            v.metrics.mse
        );
        assert!((v.metrics.psnr - (-10.0 * mse.log10())).abs() < 1e-6);
        assert!(
            v.metrics.psnr < 40.0,
            "the final checkpoint differs: {}",
            v.metrics.psnr
        );
    }

    // The background argument is honoured: black instead of BG lowers PSNR a lot.
    let black = EvaluateArgs {
        background: [0.0; 3],
        ..args
    };
    let e = EvalDir::load(&run(dir.path(), "black", &m, &test, &black, 2))
        .unwrap()
        .metrics;
    assert!(e.mean.psnr < 30.0, "{}", e.mean.psnr);
}

#[test]
fn outputs_are_byte_identical_for_one_and_two_threads() {
    let dir = tempfile::tempdir().unwrap();
    let (m, test, _) = setup(dir.path());
    let args = EvaluateArgs {
        lpips: LpipsNet::None,
        background: BG,
        ..Default::default()
    };
    let a = run(dir.path(), "t1", &m, &test, &args, 1);
    let b = run(dir.path(), "t2", &m, &test, &args, 2);
    for f in [
        "metrics.json",
        "metrics.csv",
        "curve.json",
        "renders/v0.png",
        "renders/v1.png",
        "gt/v1.png",
    ] {
        assert_eq!(
            std::fs::read(a.join(f)).unwrap(),
            std::fs::read(b.join(f)).unwrap(),
            "{f}"
        );
    }
}
