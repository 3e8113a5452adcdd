//! The `Evaluate` code path with a stand-in renderer: golden metrics, files written, best-step
//! and baseline-step selection from the model curves, LPIPS availability, clear errors.

mod common;

use augsplat_core::{image, Camera, ImageF32, Scene};
use augsplat_graph::{Node, RunContext};
use augsplat_report::evalset::{files, EvalDir};
use augsplat_report::evaluate::{
    evaluate, load_lpips, Checkpoint, EvalContext, EvaluateArgs, EvaluateNode, LpipsNet,
};
use augsplat_report::select::Criterion;
use common::*;

fn context(model: &std::path::Path, baseline: Option<&std::path::Path>) -> EvalContext<'static> {
    EvalContext {
        label: "method".into(),
        fallback_label: "node".into(),
        checkpoint: Checkpoint::Best,
        model_dir: model.to_path_buf(),
        baseline_dir: baseline.map(|p| p.to_path_buf()),
        lpips: None,
        lpips_note: Some("no LPIPS".into()),
        primitives: Some(7),
        record_wall_time: false,
        device: None,
        train: None,
    }
}

#[test]
fn golden_metrics_files_and_curve_selection() {
    let dir = tempfile::tempdir().unwrap();
    let test = dir.path().join("test");
    let gts = make_scene(&test, 2, 40, 32);
    let cams: Vec<Camera> = Scene::load(&test)
        .unwrap()
        .views
        .iter()
        .map(|v| v.camera.clone())
        .collect();
    // Method curve: lowest average error at 300, best PSNR at 400.
    let method = curve(
        "M",
        4,
        |s| 14.0 + s as f64 / 100.0,
        |s| Some([0.3, 0.25, 0.2, 0.22][(s / 100 - 1) as usize]),
    );
    let base = curve(
        "B",
        4,
        |s| 14.0 + s as f64 / 100.0,
        |s| Some([0.3, 0.2, 0.25, 0.26][(s / 100 - 1) as usize]),
    );
    let model = dir.path().join("model");
    let bmodel = dir.path().join("base");
    make_model(&model, &method, 300);
    make_model(&bmodel, &base, 200);
    let out = dir.path().join("eval");
    std::fs::create_dir_all(&out).unwrap();
    // View 0 rendered exactly; view 1 brighter by exactly 0.125 (no clamping: GT ≤ 0.85).
    let render = move |cam: &Camera| {
        let i = cams.iter().position(|c| c == cam).unwrap();
        let mut img = gts[i].clone();
        if i == 1 {
            for v in &mut img.data {
                *v += 0.125;
            }
        }
        Ok(img)
    };
    let m = evaluate(
        &context(&model, Some(&bmodel)),
        &test,
        &out,
        render,
        &|_, _| {},
    )
    .unwrap();
    assert_eq!(m.views.len(), 2);
    assert_eq!(m.views[0].metrics.psnr, f64::INFINITY);
    assert_eq!(m.views[0].metrics.mse, 0.0);
    assert!((m.views[0].metrics.ssim - 1.0).abs() < 1e-6);
    // MSE 0.125² → PSNR = 20·log10(8) = 18.0618 dB.
    assert!(
        (m.views[1].metrics.mse - 0.015625).abs() < 1e-7,
        "{}",
        m.views[1].metrics.mse
    );
    assert!((m.views[1].metrics.psnr - 18.061_799_7).abs() < 1e-4);
    assert_eq!(m.mean.psnr, f64::INFINITY);
    assert!(m.mean.lpips.is_none() && m.mean.avg_error.is_none());
    assert_eq!(m.notes, vec!["no LPIPS".to_string()]);
    assert_eq!(m.label, "method");
    assert_eq!(m.checkpoint_step, Some(300));
    assert_eq!(m.primitives, Some(7));
    assert_eq!(m.eval_seconds, None, "wall time is off by default");
    assert_eq!(m.train_seconds, Some(20.0));
    let best = m.best.as_ref().unwrap();
    assert_eq!((best.step, best.criterion), (300, Criterion::AvgError));
    let at = m.at_baseline.as_ref().unwrap();
    assert_eq!((at.baseline_best.step, at.step, at.exact), (200, 200, true));
    assert_eq!(at.baseline_label, "B");
    assert_eq!(at.point.avg_error, Some(0.25));
    // Files.
    for name in ["view00.png", "view01.png"] {
        assert!(out.join(files::RENDERS).join(name).is_file());
        assert!(out.join(files::GT).join(name).is_file());
    }
    let r1 = image::read_rgb(&out.join("renders/view01.png")).unwrap();
    let g1 = image::read_rgb(&out.join("gt/view01.png")).unwrap();
    assert!((r1.get(3, 3, 0) - g1.get(3, 3, 0) - 0.125).abs() < 1.0 / 255.0);
    let csv = std::fs::read_to_string(out.join(files::METRICS_CSV)).unwrap();
    let lines: Vec<&str> = csv.lines().collect();
    assert_eq!(lines.len(), 4);
    assert!(lines[1].starts_with("view00,40,32,inf,"), "{}", lines[1]);
    assert!(lines[3].starts_with("mean,,,inf,"), "{}", lines[3]);
    // Read back as an eval folder, curve copied.
    let back = EvalDir::load(&out).unwrap();
    // (serde_json's default float parsing may differ in the last ulp: compare loosely.)
    assert_eq!(back.metrics.views.len(), 2);
    assert_eq!(back.metrics.best.as_ref().unwrap().step, 300);
    assert_eq!(back.metrics.mean.psnr, f64::INFINITY);
    assert!((back.metrics.views[1].metrics.ssim - m.views[1].metrics.ssim).abs() < 1e-12);
    let copied = back.curve.unwrap();
    assert_eq!(copied.label, "M");
    assert_eq!(
        copied.points.iter().map(|p| p.step).collect::<Vec<_>>(),
        vec![100, 200, 300, 400]
    );
    assert_eq!(
        std::fs::read(out.join(files::CURVE)).unwrap(),
        std::fs::read(model.join("curve.json")).unwrap()
    );
}

#[test]
fn renders_are_clamped_and_bad_renders_are_clear_errors() {
    let dir = tempfile::tempdir().unwrap();
    let test = dir.path().join("test");
    let gts = make_scene(&test, 1, 40, 32);
    let model = dir.path().join("model");
    std::fs::create_dir_all(&model).unwrap();
    let out = dir.path().join("eval");
    // Values above 1 are clamped before measuring: a render of all 5.0 equals all-ones.
    let ones = ImageF32::from_vec(40, 32, 3, vec![1.0; 40 * 32 * 3]);
    let m = evaluate(
        &context(&model, None),
        &test,
        &out,
        |_| Ok(ImageF32::from_vec(40, 32, 3, vec![5.0; 40 * 32 * 3])),
        &|_, _| {},
    )
    .unwrap();
    let want = augsplat_metrics::mse(&ones, &gts[0]).unwrap();
    assert!((m.views[0].metrics.mse - want).abs() < 1e-12);
    assert!(m.best.is_none());
    assert!(
        m.notes.iter().any(|n| n.contains("no curve.json")),
        "{:?}",
        m.notes
    );
    let err = evaluate(
        &context(&model, None),
        &test,
        &out,
        |_| Ok(ImageF32::new(8, 8, 3)),
        &|_, _| {},
    )
    .unwrap_err()
    .to_string();
    assert!(err.contains("view00") && err.contains("8×8×3"), "{err}");
    let err = evaluate(
        &context(&model, None),
        &test,
        &out,
        |_| Ok(ImageF32::from_vec(40, 32, 3, vec![f32::NAN; 40 * 32 * 3])),
        &|_, _| {},
    )
    .unwrap_err()
    .to_string();
    assert!(
        err.contains("view00") && err.contains("non-finite"),
        "{err}"
    );
    let err = evaluate(
        &context(&model, None),
        &dir.path().join("nope"),
        &out,
        |_| Ok(ImageF32::new(1, 1, 3)),
        &|_, _| {},
    )
    .unwrap_err()
    .to_string();
    assert!(err.contains("scene.json"), "{err}");
}

#[test]
fn lpips_unavailable_is_reported_never_invented() {
    let dir = tempfile::tempdir().unwrap();
    let (m, note) = load_lpips(LpipsNet::Alex, Some(&dir.path().join("missing"))).unwrap();
    assert!(m.is_none());
    let note = note.unwrap();
    assert!(
        note.contains("unavailable") && note.contains("import-lpips"),
        "{note}"
    );
    let (m, note) = load_lpips(LpipsNet::None, None).unwrap();
    assert!(m.is_none() && note.unwrap().contains("lpips: None"));
    let Some(weights) = lpips_dir() else {
        eprintln!("skipping the LPIPS part: ../shared/data/lpips is absent");
        return;
    };
    // Without an `lpips` input, weights reachable through the environment are not used: the
    // node's output must depend only on what its key covers.
    std::env::set_var(augsplat_metrics::lpips::WEIGHTS_ENV, &weights);
    let (m, note) = load_lpips(LpipsNet::Alex, None).unwrap();
    std::env::remove_var(augsplat_metrics::lpips::WEIGHTS_ENV);
    assert!(m.is_none());
    let note = note.unwrap();
    assert!(
        note.contains("no `lpips` input") && note.contains("import-lpips"),
        "{note}"
    );
    let (m, note) = load_lpips(LpipsNet::Alex, Some(&weights)).unwrap();
    assert!(note.is_none());
    let (model, backbone) = m.unwrap();
    assert_eq!(backbone.name(), "alex");
    // Identical images: LPIPS 0 and average error 0; a degraded render: positive, and the
    // average error equals the formula.
    let test = dir.path().join("test");
    let gts = make_scene(&test, 1, 48, 40);
    let mdir = dir.path().join("model");
    std::fs::create_dir_all(&mdir).unwrap();
    let mut cx = context(&mdir, None);
    cx.lpips = Some((&model, backbone));
    cx.lpips_note = None;
    let g = gts[0].clone();
    let m = evaluate(
        &cx,
        &test,
        &dir.path().join("e1"),
        move |_| Ok(g.clone()),
        &|_, _| {},
    )
    .unwrap();
    assert!(m.mean.lpips.unwrap().abs() < 1e-6);
    assert!(m.mean.avg_error.unwrap().abs() < 1e-3);
    assert_eq!(m.lpips_net.as_deref(), Some("alex"));
    // Too small for AlexNet: LPIPS unavailable with a note, other metrics still measured.
    let small = dir.path().join("small");
    let sg = make_scene(&small, 1, 24, 20);
    let m = evaluate(
        &cx,
        &small,
        &dir.path().join("e3"),
        move |_| Ok(sg[0].clone()),
        &|_, _| {},
    )
    .unwrap();
    assert!(m.mean.lpips.is_none() && m.mean.avg_error.is_none());
    assert_eq!(m.mean.psnr, f64::INFINITY);
    assert!(
        m.notes.iter().any(|n| n.contains("too small")),
        "{:?}",
        m.notes
    );
    let cams = vec![Scene::load(&test).unwrap().views[0].camera.clone()];
    let m = evaluate(
        &cx,
        &test,
        &dir.path().join("e2"),
        degrading_renderer(gts, cams, 0.1, 3),
        &|_, _| {},
    )
    .unwrap();
    let v = &m.views[0].metrics;
    let lp = v.lpips.unwrap();
    assert!(lp > 0.01, "{lp}");
    let want = (v.mse * (1.0 - v.ssim).sqrt() * lp).cbrt();
    assert!((v.avg_error.unwrap() - want).abs() < 1e-12);
}

#[test]
fn node_reports_a_missing_checkpoint_by_name() {
    let dir = tempfile::tempdir().unwrap();
    let test = dir.path().join("test");
    make_scene(&test, 1, 40, 32);
    let model = dir.path().join("model");
    std::fs::create_dir_all(&model).unwrap();
    let mut ctx = RunContext::standalone(
        vec![("model".into(), vec![model]), ("test".into(), vec![test])],
        &["eval"],
        &dir.path().join("out"),
        0,
        1,
    )
    .unwrap();
    let err = EvaluateNode::run(&EvaluateArgs::default(), &mut ctx)
        .unwrap_err()
        .to_string();
    assert!(
        err.contains("best.ply") && err.contains("checkpoint: Final"),
        "{err}"
    );
    let bad = EvaluateArgs {
        background: [2.0, 0.0, 0.0],
        ..Default::default()
    };
    assert!(EvaluateNode::validate(&bad).is_err());
}
