//! Tests of the Adam optimiser.

use super::*;
use augsplat_core::Rng;

/// `n` Gaussians of SH degree 3 with random parameters.
fn gaussians(n: usize, rng: &mut Rng) -> Gaussians {
    let mut g = Gaussians::empty(3);
    let mut r = || rng.uniform(-1.0, 1.0) as f32;
    for _ in 0..n {
        g.means.push([r(), r(), r()]);
        g.log_scales.push([r(), r(), r()]);
        g.quats.push([r(), r(), r(), r()]);
        g.opacity_logits.push(r());
        for _ in 0..48 {
            g.sh.push(r());
        }
    }
    g
}

/// Random gradients; visibility in runs of random length (some long, some single).
fn grads(n: usize, rng: &mut Rng, sh_active: usize) -> ParamGrads {
    let mut p = ParamGrads::zeros(n, 16);
    let mut i = 0;
    let mut vis = false;
    while i < n {
        let run = 1 + rng.below(if vis { 300 } else { 40 }) as usize;
        for v in p.visible.iter_mut().skip(i).take(run) {
            *v = vis;
        }
        i += run;
        vis = !vis;
    }
    let mut r = || (rng.uniform(-1.0, 1.0) * 1e-3) as f32;
    for i in 0..n {
        p.means[i] = [r(), r(), r()];
        p.log_scales[i] = [r(), r(), r()];
        p.quats[i] = [r(), r(), r(), r()];
        p.opacity_logits[i] = r();
        for k in 0..48 {
            p.sh[i * 48 + k] = if k < sh_active { r() } else { 0.0 };
        }
    }
    p.sh_active = sh_active;
    p
}

#[test]
fn update_matches_an_f64_reference_over_runs_and_chunks() {
    // SH degree 3 (48 values: whole blocks) and degree 2 (27: a block and a tail).
    for sh_active in [48, 27] {
        update_matches_reference(sh_active);
    }
}

fn update_matches_reference(sh_active: usize) {
    let mut rng = Rng::new(17);
    let n = 2 * CHUNK + 777;
    let g0 = gaussians(n, &mut rng);
    let mut g = g0.clone();
    let lr = LearningRates::default();
    let mut adam = Adam::new(n, 16);
    let steps: Vec<ParamGrads> = (0..3).map(|_| grads(n, &mut rng, sh_active)).collect();
    for s in &steps {
        adam.step(&mut g, s, &lr, 2e-3);
    }
    // f64 reference, value by value: (param, grads of one value per step, visible per step, lr).
    let check = |name: &str, p0: f32, p: f32, gs: &[f64], vis: &[bool], lr: f64| {
        let (b1, b2, eps) = (0.9f64, 0.999f64, 1e-15f64);
        let (mut m, mut v, mut x) = (0.0f64, 0.0f64, p0 as f64);
        for (t, (&gv, &on)) in gs.iter().zip(vis).enumerate() {
            if !on {
                continue;
            }
            let t = (t + 1) as i32;
            m = b1 * m + (1.0 - b1) * gv;
            v = b2 * v + (1.0 - b2) * gv * gv;
            x -= lr / (1.0 - b1.powi(t)) * m / (v.sqrt() / (1.0 - b2.powi(t)).sqrt() + eps);
        }
        if vis.iter().all(|&v| !v) {
            assert_eq!(p.to_bits(), p0.to_bits(), "{name}: invisible value moved");
        }
        assert!(
            (p as f64 - x).abs() <= 1e-6 * (1.0 + x.abs()),
            "{name}: {p} vs reference {x}"
        );
    };
    for i in 0..n {
        let vis: Vec<bool> = steps.iter().map(|s| s.visible[i]).collect();
        for k in 0..3 {
            let gs: Vec<f64> = steps.iter().map(|s| s.means[i][k] as f64).collect();
            check("mean", g0.means[i][k], g.means[i][k], &gs, &vis, 2e-3);
            let gs: Vec<f64> = steps.iter().map(|s| s.log_scales[i][k] as f64).collect();
            check(
                "scale",
                g0.log_scales[i][k],
                g.log_scales[i][k],
                &gs,
                &vis,
                lr.scales,
            );
        }
        let gs: Vec<f64> = steps.iter().map(|s| s.quats[i][3] as f64).collect();
        check("quat", g0.quats[i][3], g.quats[i][3], &gs, &vis, lr.quats);
        let gs: Vec<f64> = steps.iter().map(|s| s.opacity_logits[i] as f64).collect();
        check(
            "opacity",
            g0.opacity_logits[i],
            g.opacity_logits[i],
            &gs,
            &vis,
            lr.opacities,
        );
        for k in 0..48 {
            let gs: Vec<f64> = steps.iter().map(|s| s.sh[i * 48 + k] as f64).collect();
            let rate = if k < 3 { lr.sh0 } else { lr.shn };
            check("sh", g0.sh[i * 48 + k], g.sh[i * 48 + k], &gs, &vis, rate);
        }
    }
}

#[test]
fn inactive_sh_values_are_skipped_exactly() {
    let mut rng = Rng::new(5);
    let n = CHUNK + 100;
    let g0 = gaussians(n, &mut rng);
    let lr = LearningRates::default();
    // Degree-1 gradients (12 values), declared once as all 48 and once as 12 active.
    let steps: Vec<ParamGrads> = (0..3).map(|_| grads(n, &mut rng, 12)).collect();
    let run = |declared: usize| {
        let mut g = g0.clone();
        let mut adam = Adam::new(n, 16);
        for s in &steps {
            let s = ParamGrads {
                sh_active: declared,
                ..s.clone()
            };
            adam.step(&mut g, &s, &lr, 1e-3);
        }
        (g, adam)
    };
    let (ga, aa) = run(48);
    let (gb, ab) = run(12);
    assert_eq!(
        ga, gb,
        "skipping zero-gradient, zero-moment values changes nothing"
    );
    assert_eq!(aa.moments(Group::Sh), ab.moments(Group::Sh));
    // Once values were touched, a smaller declaration still updates them.
    let mut g = g0.clone();
    let mut adam = Adam::new(n, 16);
    adam.step(&mut g, &steps[0], &lr, 1e-3);
    let decay = ParamGrads {
        sh: vec![0.0; n * 48],
        sh_active: 3,
        ..steps[1].clone()
    };
    let before = g.sh.clone();
    adam.step(&mut g, &decay, &lr, 1e-3);
    let i = (0..n)
        .find(|&i| steps[0].visible[i] && steps[1].visible[i])
        .unwrap();
    assert_ne!(
        g.sh[i * 48 + 5],
        before[i * 48 + 5],
        "momentum keeps moving value 5"
    );
}

/// Every parameter and moment as raw bits.
fn bits(g: &Gaussians, a: &Adam) -> Vec<u32> {
    let mut out: Vec<u32> = g
        .means
        .as_flattened()
        .iter()
        .chain(g.log_scales.as_flattened())
        .chain(g.quats.as_flattened())
        .chain(&g.opacity_logits)
        .chain(&g.sh)
        .map(|v| v.to_bits())
        .collect();
    for grp in [
        Group::Means,
        Group::Scales,
        Group::Quats,
        Group::Opacities,
        Group::Sh,
    ] {
        let (m, v) = a.moments(grp);
        out.extend(m.iter().chain(v).map(|x| x.to_bits()));
    }
    out
}

#[test]
fn update_is_bit_identical_for_every_instruction_set_and_thread_count() {
    let mut rng = Rng::new(9);
    let n = 3 * CHUNK + 5;
    let g0 = gaussians(n, &mut rng);
    let steps: Vec<ParamGrads> = (0..2).map(|_| grads(n, &mut rng, 27)).collect();
    let lr = LearningRates::default();
    let run = |threads: usize| {
        augsplat_testkit::with_threads(threads, || {
            let mut g = g0.clone();
            let mut adam = Adam::new(n, 16);
            for s in &steps {
                adam.step(&mut g, s, &lr, 1e-3);
            }
            bits(&g, &adam)
        })
    };
    let results = augsplat_core::simd::for_each_isa("adam", |_| [run(1), run(2), run(3)]);
    let first = &results[0].1[0];
    for (level, rs) in &results {
        for (k, r) in rs.iter().enumerate() {
            assert!(r == first, "level {level}, run {k} differs");
        }
    }
}
