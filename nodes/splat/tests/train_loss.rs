//! Loss kernels against f64 references and central finite differences.

#![allow(clippy::needless_range_loop)]

use augsplat_core::Rng;
use augsplat_splat::loss::{self, reference, PixelLoss, WeightNorm};

fn random_image(rng: &mut Rng, w: usize, h: usize) -> Vec<f32> {
    (0..w * h * 3).map(|_| rng.next_f32()).collect()
}

fn to64(v: &[f32]) -> Vec<f64> {
    v.iter().map(|&x| x as f64).collect()
}

/// Central difference of `f` at index `i` of `x` (f64).
fn fd(f: &dyn Fn(&[f64]) -> f64, x: &[f64], i: usize, h: f64) -> f64 {
    let mut a = x.to_vec();
    a[i] += h;
    let fp = f(&a);
    a[i] -= 2.0 * h;
    let fm = f(&a);
    (fp - fm) / (2.0 * h)
}

#[test]
fn ssim_matches_direct_f64_window_sums() {
    let mut rng = Rng::new(3);
    for &(w, h) in &[(11usize, 11usize), (23, 17), (40, 31)] {
        let p = random_image(&mut rng, w, h);
        // A correlated target so SSIM is far from 0.
        let t: Vec<f32> = p
            .iter()
            .map(|&v| (0.7 * v + 0.3 * rng.next_f32()).min(1.0))
            .collect();
        let mut g = vec![0.0; p.len()];
        let s = loss::ssim(&p, &t, w, h, 0.0, &mut g);
        let r = reference::ssim(&to64(&p), &to64(&t), w, h);
        assert!((s - r).abs() < 2e-5, "{w}x{h}: fused {s} vs reference {r}");
        assert!(g.iter().all(|&v| v == 0.0), "scale 0 must add no gradient");
        // Identical images give exactly SSIM ≈ 1.
        let s1 = loss::ssim(&p, &p, w, h, 0.0, &mut g);
        assert!((s1 - 1.0).abs() < 1e-5, "self-SSIM {s1}");
    }
}

#[test]
fn ssim_gradient_matches_finite_differences() {
    let mut rng = Rng::new(11);
    let (w, h) = (19usize, 14usize);
    let p = random_image(&mut rng, w, h);
    let t: Vec<f32> = p
        .iter()
        .map(|&v| (0.5 * v + 0.5 * rng.next_f32()).min(1.0))
        .collect();
    let mut g = vec![0.0f32; p.len()];
    loss::ssim(&p, &t, w, h, 1.0, &mut g);
    let t64 = to64(&t);
    let f = |x: &[f64]| reference::ssim(x, &t64, w, h);
    let x = to64(&p);
    let gmax = g.iter().fold(0f32, |m, v| m.max(v.abs())) as f64;
    assert!(gmax > 0.0);
    // Corners, edges and interior pixels of each channel.
    let mut idx = vec![
        0,
        1,
        2,
        (w - 1) * 3,
        (w * h - 1) * 3 + 2,
        ((h / 2) * w + w / 2) * 3 + 1,
    ];
    for _ in 0..30 {
        idx.push(rng.below((w * h * 3) as u64) as usize);
    }
    for &i in &idx {
        let num = fd(&f, &x, i, 1e-4);
        let err = (g[i] as f64 - num).abs();
        assert!(
            err <= 2e-3 * gmax + 1e-7,
            "pixel value {i}: analytic {} vs fd {num}",
            g[i]
        );
    }
}

#[test]
fn ssim_of_images_smaller_than_window_is_one_without_gradient() {
    let mut rng = Rng::new(1);
    for &(w, h) in &[(1usize, 1usize), (10, 40), (40, 10)] {
        let p = random_image(&mut rng, w, h);
        let t = random_image(&mut rng, w, h);
        let mut g = vec![0.0; p.len()];
        assert_eq!(loss::ssim(&p, &t, w, h, 1.0, &mut g), 1.0);
        assert!(g.iter().all(|&v| v == 0.0));
    }
}

#[test]
fn l2_l1_and_weighted_l2_gradients_match_finite_differences() {
    let mut rng = Rng::new(5);
    let (w, h) = (7usize, 5usize);
    let p = random_image(&mut rng, w, h);
    let t = random_image(&mut rng, w, h);
    let wts: Vec<f32> = (0..w * h)
        .map(|i| if i % 7 == 0 { 0.0 } else { rng.next_f32() })
        .collect();
    let x = to64(&p);
    let t64 = to64(&t);
    let w64 = to64(&wts);
    let n = p.len() as f64;
    // L2.
    let mut g = vec![0.0f32; p.len()];
    let v = loss::l2(&p, &t, 1.5, &mut g);
    let f = |x: &[f64]| {
        x.iter()
            .zip(&t64)
            .map(|(a, b)| (a - b) * (a - b))
            .sum::<f64>()
            / n
    };
    assert!((v - f(&x)).abs() < 1e-7);
    for i in 0..p.len() {
        let num = 1.5 * fd(&f, &x, i, 1e-5);
        assert!(
            (g[i] as f64 - num).abs() < 1e-5,
            "l2 {i}: {} vs {num}",
            g[i]
        );
    }
    // L1 (away from kinks: random values differ by ≫ h).
    let mut g = vec![0.0f32; p.len()];
    let v = loss::l1(&p, &t, 1.0, &mut g);
    let f = |x: &[f64]| x.iter().zip(&t64).map(|(a, b)| (a - b).abs()).sum::<f64>() / n;
    assert!((v - f(&x)).abs() < 1e-7);
    for i in 0..p.len() {
        let num = fd(&f, &x, i, 1e-6);
        assert!((g[i] as f64 - num).abs() < 1e-5, "l1 {i}");
    }
    // Weighted L2 with both normalisations.
    for norm in [WeightNorm::WeightSum, WeightNorm::PixelCount] {
        let mut g = vec![0.0f32; p.len()];
        let v = loss::weighted_l2(&p, &t, &wts, norm, 2.0, &mut g);
        let f = |x: &[f64]| reference::weighted_l2(x, &t64, &w64, norm);
        assert!((v - f(&x)).abs() < 1e-7, "{norm:?}: {v} vs {}", f(&x));
        for i in 0..p.len() {
            let num = 2.0 * fd(&f, &x, i, 1e-5);
            assert!(
                (g[i] as f64 - num).abs() < 1e-5,
                "wl2 {norm:?} {i}: {} vs {num}",
                g[i]
            );
        }
    }
    // Unit weights reduce to the MSE under both normalisations.
    let ones = vec![1.0f32; w * h];
    let mut g = vec![0.0f32; p.len()];
    let mse = loss::l2(&p, &t, 0.0, &mut g);
    for norm in [WeightNorm::WeightSum, WeightNorm::PixelCount] {
        let v = loss::weighted_l2(&p, &t, &ones, norm, 0.0, &mut g);
        assert!((v - mse).abs() < 1e-9);
    }
}

#[test]
fn weighted_l2_with_zero_or_bad_weights_is_clean() {
    let p = vec![0.2f32; 12];
    let t = vec![0.7f32; 12];
    let mut g = vec![0.0f32; 12];
    let v = loss::weighted_l2(&p, &t, &[0.0; 4], WeightNorm::WeightSum, 1.0, &mut g);
    assert_eq!(v, 0.0);
    assert!(g.iter().all(|&x| x == 0.0));
    let v = loss::weighted_l2(
        &p,
        &t,
        &[f32::NAN, f32::INFINITY, -1.0, 1.0],
        WeightNorm::WeightSum,
        1.0,
        &mut g,
    );
    assert!((v - 0.25).abs() < 1e-6, "only the last pixel counts: {v}");
    assert!(g.iter().all(|x| x.is_finite()));
    assert!(g[..9].iter().all(|&x| x == 0.0));
}

#[test]
fn photometric_loss_combines_terms_and_is_thread_count_invariant() {
    let mut rng = Rng::new(9);
    let (w, h) = (70usize, 45usize);
    let p = random_image(&mut rng, w, h);
    let t = random_image(&mut rng, w, h);
    let run = |threads: usize| {
        augsplat_testkit::with_threads(threads, || {
            let mut g = vec![0.0f32; p.len()];
            let r = loss::photometric(&p, &t, w, h, PixelLoss::L2, 0.2, 1.0, &mut g);
            (r, g)
        })
    };
    let (a, ga) = run(1);
    let (b, gb) = run(2);
    assert_eq!(a.0.to_bits(), b.0.to_bits());
    assert_eq!(
        ga.iter().map(|v| v.to_bits()).collect::<Vec<_>>(),
        gb.iter().map(|v| v.to_bits()).collect::<Vec<_>>()
    );
    let (loss_v, pix, s) = a;
    assert!((loss_v - (0.8 * pix + 0.2 * (1.0 - s))).abs() < 1e-7);
    // The gradient is the sum of the two scaled terms.
    let mut g2 = vec![0.0f32; p.len()];
    loss::l2(&p, &t, 0.8, &mut g2);
    loss::ssim(&p, &t, w, h, -0.2, &mut g2);
    for i in 0..p.len() {
        assert!((ga[i] - g2[i]).abs() <= 1e-9 + 1e-6 * g2[i].abs());
    }
}
