//! The training loop end to end on small generated scenes: determinism across thread counts,
//! PSNR improvement, the Staged switch inside the trainer, the OptimizeSplats node.

#![allow(clippy::needless_range_loop)]

mod train_util;

use augsplat_core::Rng;
use augsplat_splat::adam::LearningRates;
use augsplat_splat::densify::DensifyArgs;
use augsplat_splat::train::{
    evaluate, scene_scale, RealImages, RealLoss, RealView, Schedule, Supervision, SynthView,
    SyntheticImages, TrainArgs, Trainer,
};
use augsplat_splat::{loss::WeightNorm, Gaussians};
use std::path::Path;

use train_util::{initial, load_views, param_bits as bits};

#[test]
fn training_steps_are_bit_identical_for_1_and_2_threads() {
    let tmp = tempfile::tempdir().unwrap();
    let (train, _) = train_util::make_scene(tmp.path(), 48, 40, 9, 400);
    let views = load_views(&train);
    let cams: Vec<_> = views.iter().map(|v| &v.camera).collect();
    let ss = scene_scale(&cams);
    let real = RealImages {
        views,
        loss: RealLoss::default(),
    };
    // Densify from the second step on, every step, so clone/split/prune run too.
    let args = TrainArgs {
        steps: 6,
        sh_degree: 1,
        sh_increase_every: 2,
        densify: DensifyArgs {
            start: 1,
            every: 2,
            reset_every: 4,
            scale_with_steps: false,
            grad_threshold: 1e-6,
            ..Default::default()
        },
        ..Default::default()
    };
    let run = |threads: usize| {
        augsplat_testkit::with_threads(threads, || {
            let mut t = Trainer::new(args.clone(), initial(&train, 1, ss), ss, &real, None);
            let mut reps = Vec::new();
            for _ in 0..6 {
                reps.push(t.step());
            }
            (bits(t.gaussians()), reps)
        })
    };
    let (a, ra) = run(1);
    let (b, rb) = run(2);
    assert_eq!(ra, rb);
    assert!(a == b, "parameters differ between 1 and 2 threads");
    assert!(
        ra.iter().any(|r| r.refine.cloned + r.refine.split > 0),
        "densification was exercised: {ra:?}"
    );
}

#[test]
fn short_run_improves_held_out_psnr() {
    let tmp = tempfile::tempdir().unwrap();
    let (train, test) = train_util::make_scene(tmp.path(), 64, 48, 17, 1500);
    let (real, test, ss) = train_util::real_case(&train, &test);
    let args = TrainArgs {
        steps: 300,
        sh_degree: 1,
        sh_increase_every: 100,
        ..Default::default()
    };
    let g0 = initial(&train, 1, ss);
    let before = evaluate(&g0, &test, &args.render_settings(0), None).unwrap();
    let mut t = Trainer::new(args.clone(), g0, ss, &real, None);
    for _ in 0..300 {
        t.step();
    }
    let after = evaluate(t.gaussians(), &test, &args.render_settings(300), None).unwrap();
    eprintln!(
        "held-out PSNR {:.2} → {:.2} dB, SSIM {:.3} → {:.3}, {} Gaussians",
        before.psnr,
        after.psnr,
        before.ssim,
        after.ssim,
        t.gaussians().len()
    );
    assert!(
        after.psnr > before.psnr + 3.0,
        "PSNR {} → {}",
        before.psnr,
        after.psnr
    );
    assert!(after.ssim > before.ssim);
}

#[test]
fn staged_trainer_uses_synthetic_then_real_and_resets_at_the_switch() {
    let tmp = tempfile::tempdir().unwrap();
    let (train, _) = train_util::make_scene(tmp.path(), 40, 32, 9, 300);
    let views = load_views(&train);
    let cams: Vec<_> = views.iter().map(|v| &v.camera).collect();
    let ss = scene_scale(&cams);
    // Synthetic views: the training views at half resolution, weight 1 on the left half.
    let synth = SyntheticImages {
        views: views
            .iter()
            .map(|v| {
                let cam = v.camera.resized(20, 16);
                let img =
                    augsplat_core::ImageF32::from_vec(40, 32, 3, v.image.clone()).downscale(2);
                let w: Vec<f32> = (0..20 * 16)
                    .map(|p| if p % 20 < 10 { 1.0 } else { 0.0 })
                    .collect();
                SynthView::new(v.name.clone(), cam, img.data, w, 0.5)
            })
            .collect(),
        norm: WeightNorm::WeightSum,
    };
    assert!(synth.mask(0).is_some());
    let real = RealImages {
        views,
        loss: RealLoss::default(),
    };
    let warm = 4;
    let args = TrainArgs {
        steps: 7,
        sh_degree: 0,
        densify: DensifyArgs {
            enabled: false,
            ..Default::default()
        },
        schedule: Schedule::Staged {
            warmup_steps: warm,
            synthetic_batch: 3,
            reset_at_switch: true,
        },
        learning_rates: LearningRates {
            opacities: 0.05,
            ..Default::default()
        },
        ..Default::default()
    };
    let mut g0 = initial(&train, 0, ss);
    for o in &mut g0.opacity_logits {
        *o = 2.0; // well above 0.1, so the reset is visible
    }
    let mut t = Trainer::new(args, g0, ss, &real, Some(&synth));
    for step in 0..7u64 {
        let r = t.step();
        if step < warm {
            assert!(
                r.synthetic_loss.is_some() && r.real_loss.is_none(),
                "step {step}: {r:?}"
            );
        } else {
            assert!(
                r.real_loss.is_some() && r.synthetic_loss.is_none(),
                "step {step}: {r:?}"
            );
        }
        if step == warm {
            // Clamped to logit(0.1), then one fresh-Adam step moves each by at most lr.
            let cap = (0.1f64 / 0.9).ln() + 0.05 + 1e-5;
            let max = t
                .gaussians()
                .opacity_logits
                .iter()
                .cloned()
                .fold(f32::MIN, f32::max) as f64;
            assert!(max <= cap, "max opacity logit {max} after the switch");
        }
        if step == warm - 1 {
            let min = t
                .gaussians()
                .opacity_logits
                .iter()
                .cloned()
                .fold(f32::MAX, f32::min);
            assert!(min > 1.5, "no reset before the switch");
        }
    }
}

/// A 40×32 generated scene of 9 views: its directory, the real views, the same views at
/// half resolution as synthetic ones (weight 1 everywhere) and the scene scale.
fn dual_case(root: &Path) -> (std::path::PathBuf, RealImages, SyntheticImages, f64) {
    let (train, _) = train_util::make_scene(root, 40, 32, 9, 300);
    let views = load_views(&train);
    let cams: Vec<_> = views.iter().map(|v| &v.camera).collect();
    let ss = scene_scale(&cams);
    let synth = SyntheticImages {
        views: views
            .iter()
            .map(|v| {
                let cam = v.camera.resized(20, 16);
                let img =
                    augsplat_core::ImageF32::from_vec(40, 32, 3, v.image.clone()).downscale(2);
                SynthView::new(v.name.clone(), cam, img.data, vec![1.0; 20 * 16], 0.5)
            })
            .collect(),
        norm: WeightNorm::WeightSum,
    };
    let real = RealImages {
        views,
        loss: RealLoss::default(),
    };
    (train, real, synth, ss)
}

/// Dual's real view is rendered with the loss weight `1 − λ` (1/3 at step 0 with the
/// defaults): its densification statistic is that fraction of the baseline's, unless
/// `synthetic.unweighted_stats` divides the weight back out.
#[test]
fn dual_densify_statistics_are_weighted_unless_asked_otherwise() {
    let tmp = tempfile::tempdir().unwrap();
    let (train, real, synth, ss) = dual_case(tmp.path());
    let dual = Schedule::Dual {
        w_nerf0: 2.0,
        w_real: 1.0,
        quarter_decay: 100.0,
        off_below: Some(0.1),
        synthetic_batch: 2,
        reset_at_off: false,
    };
    let lam0 = augsplat_splat::schedule::dual_lambda(2.0, 1.0, 100.0, 0);
    // One step, statistics gathered but no refinement yet.
    let stats = |schedule: Schedule, unweighted: bool| {
        let mut args = TrainArgs {
            steps: 100,
            sh_degree: 0,
            densify: DensifyArgs {
                start: 50,
                every: 50,
                scale_with_steps: false,
                ..Default::default()
            },
            schedule,
            ..Default::default()
        };
        args.synthetic.unweighted_stats = unweighted;
        let mut t = Trainer::new(args, initial(&train, 0, ss), ss, &real, Some(&synth));
        t.step();
        let (g, c) = t.densify_statistics();
        (g.to_vec(), c.to_vec())
    };
    let (base, base_count) = stats(Schedule::Baseline, false);
    let (weighted, count_w) = stats(dual.clone(), false);
    let (unweighted, count_u) = stats(dual, true);
    assert_eq!(base_count, count_w);
    assert_eq!(base_count, count_u);
    let seen = base.iter().filter(|&&x| x > 0.0).count();
    assert!(seen > 10, "only {seen} Gaussians have a statistic");
    let big = base.iter().cloned().fold(0.0f32, f32::max);
    for i in 0..base.len() {
        let w = (1.0 - lam0) as f32 * base[i];
        assert!(
            (weighted[i] - w).abs() <= 1e-4 * big,
            "Gaussian {i}: weighted {} against (1 − λ)·baseline {w}",
            weighted[i]
        );
        assert!(
            (unweighted[i] - base[i]).abs() <= 1e-4 * big,
            "Gaussian {i}: unweighted {} against baseline {}",
            unweighted[i],
            base[i]
        );
    }
}

/// Dual with `reset_at_off` clamps the opacities at its switch-off (step 2 here: w̃ = 2·4^(−t)
/// first falls below 0.5 at t = 2), as Staged does at its switch; without it, nothing is reset.
#[test]
fn dual_resets_opacities_at_its_switch_off_only_when_asked() {
    let tmp = tempfile::tempdir().unwrap();
    let (train, real, synth, ss) = dual_case(tmp.path());
    let max_logit_after = |reset: bool, steps: u64| {
        let args = TrainArgs {
            steps: 5,
            sh_degree: 0,
            densify: DensifyArgs {
                enabled: false,
                ..Default::default()
            },
            schedule: Schedule::Dual {
                w_nerf0: 2.0,
                w_real: 1.0,
                quarter_decay: 1.0,
                off_below: Some(0.5),
                synthetic_batch: 2,
                reset_at_off: reset,
            },
            learning_rates: LearningRates {
                opacities: 0.05,
                ..Default::default()
            },
            ..Default::default()
        };
        let mut g0 = initial(&train, 0, ss);
        g0.opacity_logits.fill(2.0);
        let mut t = Trainer::new(args, g0, ss, &real, Some(&synth));
        let reps: Vec<_> = (0..steps).map(|_| t.step()).collect();
        assert!(reps[1].synthetic_loss.is_some());
        assert!(reps.len() < 3 || reps[2].synthetic_loss.is_none());
        t.gaussians()
            .opacity_logits
            .iter()
            .cloned()
            .fold(f32::MIN, f32::max) as f64
    };
    // Clamped to logit(0.1), then one fresh-Adam step moves each by at most lr.
    let cap = (0.1f64 / 0.9).ln() + 0.05 + 1e-5;
    assert!(
        max_logit_after(true, 2) > 1.5,
        "no reset before the switch-off"
    );
    let reset = max_logit_after(true, 3);
    assert!(
        reset <= cap,
        "max opacity logit {reset} after the switch-off"
    );
    let kept = max_logit_after(false, 3);
    assert!(kept > 1.5, "reset without reset_at_off: {kept}");
}

#[test]
fn empty_and_degenerate_inputs_do_not_panic() {
    // No Gaussians at all, and a view with no usable synthetic weight.
    let cam = augsplat_core::Camera {
        width: 16,
        height: 12,
        fx: 20.0,
        fy: 20.0,
        cx: 8.0,
        cy: 6.0,
        world_to_camera: [
            [1.0, 0.0, 0.0, 0.0],
            [0.0, 1.0, 0.0, 0.0],
            [0.0, 0.0, 1.0, 3.0],
            [0.0, 0.0, 0.0, 1.0],
        ],
    };
    let mut rng = Rng::new(1);
    let img: Vec<f32> = (0..16 * 12 * 3).map(|_| rng.next_f32()).collect();
    let real = RealImages {
        views: vec![RealView {
            name: "a".into(),
            camera: cam.clone(),
            image: img.clone(),
        }],
        loss: RealLoss::default(),
    };
    let synth = SyntheticImages {
        views: vec![SynthView::new(
            "s".into(),
            cam,
            img,
            vec![0.0; 16 * 12],
            0.0,
        )],
        norm: WeightNorm::WeightSum,
    };
    let args = TrainArgs {
        steps: 3,
        schedule: Schedule::Dual {
            w_nerf0: 2.0,
            w_real: 1.0,
            quarter_decay: 300.0,
            off_below: None,
            synthetic_batch: 4,
            reset_at_off: false,
        },
        ..Default::default()
    };
    let mut t = Trainer::new(args, Gaussians::empty(3), 1.0, &real, Some(&synth));
    for _ in 0..3 {
        let r = t.step();
        assert!(r.loss.is_finite());
        assert_eq!(r.synthetic_loss, None, "a zero-weight view is never drawn");
    }
    assert_eq!(t.gaussians().len(), 0);
}
