//! The AugSplat schedules as pure functions: Dual's λ(t) against the closed form, the Staged
//! switch step, D = 0, and the args' serde defaults.

#![allow(clippy::needless_range_loop)]

use augsplat_splat::train::{dual_lambda, dual_raw_weight, Schedule, TrainArgs};

fn dual(d: f64, off: Option<f64>) -> Schedule {
    Schedule::Dual {
        w_nerf0: 2.0,
        w_real: 1.0,
        quarter_decay: d,
        off_below: off,
        synthetic_batch: 20,
        reset_at_off: false,
    }
}

#[test]
fn dual_lambda_matches_closed_form_at_0_d_2d() {
    let d = 300.0;
    // λ = w̃/(w̃ + 1), w̃ = 2·4^(−t/D): 2/3, 0.5/1.5, 0.125/1.125.
    for (t, want) in [(0u64, 2.0 / 3.0), (300, 1.0 / 3.0), (600, 1.0 / 9.0)] {
        let l = dual_lambda(2.0, 1.0, d, t);
        assert!((l - want).abs() < 1e-12, "t={t}: {l} vs {want}");
        let p = dual(d, None).plan(t);
        assert!((p.synthetic_weight - want).abs() < 1e-12);
        assert!((p.real_weight - (1.0 - want)).abs() < 1e-12);
        assert_eq!(p.synthetic_batch, 20);
    }
    // Off below 0.1 (the raw weight): 2·4^(−t/300) < 0.1 ⇔ t > 300·log4(20) ≈ 648.3.
    assert!(dual(d, Some(0.1)).plan(648).synthetic_weight > 0.0);
    let p = dual(d, Some(0.1)).plan(649);
    assert_eq!(
        (p.synthetic_weight, p.real_weight, p.synthetic_batch),
        (0.0, 1.0, 0)
    );
    // The switch-off is flagged once, at step 649 (where `reset_at_off` acts); D = 0 has no
    // synthetic step to switch from.
    let switches: Vec<u64> = (0..3000)
        .filter(|&t| dual(d, Some(0.1)).plan(t).switch)
        .collect();
    assert_eq!(switches, [649]);
    assert!((0..100).all(|t| !dual(0.0, Some(0.1)).plan(t).switch));
    assert!((0..3000).all(|t| !dual(d, None).plan(t).switch));
    // Never off without a threshold.
    assert!(dual(d, None).plan(100_000).synthetic_weight >= 0.0);
    assert!(dual(d, None).plan(3000).synthetic_weight > 0.0);
}

#[test]
fn dual_with_zero_decay_is_real_only_and_finite() {
    for t in [0u64, 1, 1000] {
        assert_eq!(dual_raw_weight(2.0, 0.0, t), 0.0);
        let l = dual_lambda(2.0, 1.0, 0.0, t);
        assert_eq!(l, 0.0);
        let p = dual(0.0, None).plan(t);
        assert_eq!((p.real_weight, p.synthetic_weight), (1.0, 0.0));
    }
}

#[test]
fn staged_switches_exactly_at_the_warmup_step() {
    let s = Schedule::Staged {
        warmup_steps: 300,
        synthetic_batch: 20,
        reset_at_switch: true,
    };
    for t in [0u64, 1, 150, 299] {
        let p = s.plan(t);
        assert_eq!(
            (
                p.real_weight,
                p.synthetic_weight,
                p.synthetic_batch,
                p.switch
            ),
            (0.0, 1.0, 20, false),
            "t={t}"
        );
    }
    let p = s.plan(300);
    assert_eq!(
        (p.real_weight, p.synthetic_weight, p.switch),
        (1.0, 0.0, true)
    );
    let p = s.plan(301);
    assert_eq!(
        (p.real_weight, p.synthetic_weight, p.switch),
        (1.0, 0.0, false)
    );
    // No warm-up: real from the start, no switch event.
    let s0 = Schedule::Staged {
        warmup_steps: 0,
        synthetic_batch: 20,
        reset_at_switch: true,
    };
    assert!(!s0.plan(0).switch && s0.plan(0).real_weight == 1.0);
    assert_eq!(Schedule::Baseline.plan(7).real_weight, 1.0);
}

#[test]
fn args_parse_with_defaults_and_reject_typos() {
    let a: TrainArgs =
        serde_json::from_str(r#"{"steps": 10, "schedule": {"Dual": {"quarter_decay": 100.0}}}"#)
            .unwrap();
    assert_eq!(a.steps, 10);
    assert_eq!(a.eval_every, 100);
    assert_eq!(a.real_loss.ssim_lambda, 0.2);
    assert_eq!(
        a.schedule,
        Schedule::Dual {
            w_nerf0: 2.0,
            w_real: 1.0,
            quarter_decay: 100.0,
            off_below: Some(0.1),
            synthetic_batch: 20,
            reset_at_off: false,
        }
    );
    let s: TrainArgs = serde_json::from_str(r#"{"schedule": {"Staged": {}}}"#).unwrap();
    assert_eq!(
        s.schedule,
        Schedule::Staged {
            warmup_steps: 300,
            synthetic_batch: 20,
            reset_at_switch: true
        }
    );
    assert!(serde_json::from_str::<TrainArgs>(r#"{"stepz": 10}"#).is_err());
    assert!(
        serde_json::from_str::<TrainArgs>(r#"{"schedule": {"Dual": {"w_nerf": 1.0}}}"#).is_err()
    );
    assert!(TrainArgs::default().validate().is_ok());
    let bad = TrainArgs {
        sh_degree: 4,
        ..Default::default()
    };
    assert!(bad.validate().is_err());
    let bad = TrainArgs {
        schedule: dual(-1.0, None),
        ..Default::default()
    };
    assert!(bad.validate().unwrap_err().contains("quarter_decay"));
    // Active SH degree grows every 1000 steps up to the maximum.
    let a = TrainArgs::default();
    assert_eq!(
        [0, 999, 1000, 2500, 9000].map(|t| a.active_sh_degree(t)),
        [0, 0, 1, 2, 3]
    );
}
