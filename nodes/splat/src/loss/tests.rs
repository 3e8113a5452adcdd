//! Tests of the losses: the fused kernels against the f64 references, and the same bits for
//! every instruction-set tier and thread count.

use super::fused::HALO;
use super::*;
use augsplat_core::simd::for_each_isa;
use augsplat_core::Rng;

fn image(rng: &mut Rng, w: usize, h: usize) -> Vec<f32> {
    (0..w * h * 3).map(|_| rng.next_f32()).collect()
}

/// A target correlated with `p` (so SSIM is far from 0 and the partials are varied).
fn correlated(rng: &mut Rng, p: &[f32], mix: f32) -> Vec<f32> {
    p.iter()
        .map(|&v| (mix * v + (1.0 - mix) * rng.next_f32()).min(1.0))
        .collect()
}

fn to64(v: &[f32]) -> Vec<f64> {
    v.iter().map(|&x| x as f64).collect()
}

/// Mean SSIM and its gradient in f64, window by window (no separability, no bands),
/// with the partials in their textbook form (four divisions).
fn reference_with_grad(p: &[f64], t: &[f64], w: usize, h: usize) -> (f64, Vec<f64>) {
    let w1 = gaussian_window();
    let (ow, oh) = (w - HALO, h - HALO);
    let count = (ow * oh * 3) as f64;
    let mut total = 0.0;
    let mut grad = vec![0.0; p.len()];
    for ch in 0..3 {
        for oy in 0..oh {
            for ox in 0..ow {
                let idx = |ky: usize, kx: usize| ((oy + ky) * w + ox + kx) * 3 + ch;
                let (mut mx, mut my, mut exx, mut eyy, mut exy) = (0.0, 0.0, 0.0, 0.0, 0.0);
                for ky in 0..SSIM_WINDOW {
                    for kx in 0..SSIM_WINDOW {
                        let wt = w1[ky] * w1[kx];
                        let (x, y) = (p[idx(ky, kx)], t[idx(ky, kx)]);
                        mx += wt * x;
                        my += wt * y;
                        exx += wt * x * x;
                        eyy += wt * y * y;
                        exy += wt * x * y;
                    }
                }
                let n1 = 2.0 * mx * my + SSIM_C1;
                let n2 = 2.0 * (exy - mx * my) + SSIM_C2;
                let d1 = mx * mx + my * my + SSIM_C1;
                let d2 = exx - mx * mx + eyy - my * my + SSIM_C2;
                let s = n1 * n2 / (d1 * d2);
                total += s;
                let a = s * (2.0 * my / n1 - 2.0 * my / n2 - 2.0 * mx / d1 + 2.0 * mx / d2);
                let b = -s / d2;
                let c = 2.0 * s / n2;
                for ky in 0..SSIM_WINDOW {
                    for kx in 0..SSIM_WINDOW {
                        let i = idx(ky, kx);
                        grad[i] += w1[ky] * w1[kx] * (a + 2.0 * p[i] * b + t[i] * c) / count;
                    }
                }
            }
        }
    }
    (total / count, grad)
}

#[test]
fn fused_ssim_and_gradient_match_the_f64_window_reference_across_bands() {
    let mut rng = Rng::new(21);
    // Widths with map rows that are and are not multiples of 16; one band (11 rows), two
    // bands, and six bands (530 rows).
    for &(w, h, mix) in &[
        (11usize, 11usize, 0.6f32),
        (16, 75, 0.8),
        (27, 138, 0.5),
        (12, 530, 0.9),
        (43, 66, 0.3),
    ] {
        let p = image(&mut rng, w, h);
        let t = correlated(&mut rng, &p, mix);
        let mut g = vec![0f32; p.len()];
        let s = ssim(&p, &t, w, h, 1.0, &mut g);
        let (r, rg) = reference_with_grad(&to64(&p), &to64(&t), w, h);
        assert!((s - r).abs() < 2e-6, "{w}x{h}: fused {s} vs reference {r}");
        let gmax = rg.iter().fold(0f64, |m, v| m.max(v.abs()));
        let worst = g
            .iter()
            .zip(&rg)
            .map(|(&a, &b)| (a as f64 - b).abs())
            .fold(0f64, f64::max);
        assert!(
            worst <= 2e-5 * gmax,
            "{w}x{h}: worst gradient error {worst:e} vs max {gmax:e}"
        );
        // The reference gradient itself against central differences of the reference SSIM
        // at a few values (band edges included).
        let x = to64(&p);
        let t64 = to64(&t);
        for &i in &[
            0,
            3 * w * (h / 2) + 1,
            3 * (w * 64 + 5) % p.len(),
            p.len() - 1,
        ] {
            let hstep = 1e-5;
            let mut a = x.clone();
            a[i] += hstep;
            let fp = reference::ssim(&a, &t64, w, h);
            a[i] -= 2.0 * hstep;
            let fm = reference::ssim(&a, &t64, w, h);
            let num = (fp - fm) / (2.0 * hstep);
            assert!(
                (num - rg[i]).abs() <= 1e-6 * gmax + 1e-10,
                "{w}x{h} value {i}: reference gradient {} vs fd {num}",
                rg[i]
            );
        }
    }
}

#[test]
fn photometric_fused_equals_its_separate_terms_bit_for_bit() {
    let mut rng = Rng::new(8);
    let (w, h) = (37usize, 141usize);
    let p = image(&mut rng, w, h);
    let t = correlated(&mut rng, &p, 0.7);
    let g0: Vec<f32> = (0..p.len()).map(|_| rng.next_f32() - 0.5).collect();
    for kind in [PixelLoss::L2, PixelLoss::L1] {
        let mut fused_g = g0.clone();
        let (lv, pix, s) = photometric(&p, &t, w, h, kind, 0.2, 1.5, &mut fused_g);
        let mut sep_g = g0.clone();
        let pix2 = match kind {
            PixelLoss::L2 => l2(&p, &t, 1.5 * 0.8, &mut sep_g),
            PixelLoss::L1 => l1(&p, &t, 1.5 * 0.8, &mut sep_g),
        };
        let s2 = ssim(&p, &t, w, h, -1.5 * 0.2, &mut sep_g);
        assert!(
            (pix - pix2).abs() <= 1e-12 * pix2.abs(),
            "{kind:?}: {pix} vs {pix2}"
        );
        assert!((s - s2).abs() <= 1e-12, "{kind:?}: {s} vs {s2}");
        let lam = 0.2f32 as f64;
        assert!((lv - ((1.0 - lam) * pix + lam * (1.0 - s))).abs() < 1e-12);
        for (i, (a, b)) in fused_g.iter().zip(&sep_g).enumerate() {
            assert_eq!(a.to_bits(), b.to_bits(), "{kind:?} value {i}: {a} vs {b}");
        }
    }
    // Scale 0: values only, the buffer untouched.
    let mut g = g0.clone();
    let (_, pix, s) = photometric(&p, &t, w, h, PixelLoss::L2, 0.2, 0.0, &mut g);
    assert_eq!(g, g0);
    let mut scratch = vec![0f32; p.len()];
    assert!((pix - l2(&p, &t, 0.0, &mut scratch)).abs() < 1e-12);
    assert!((s - ssim(&p, &t, w, h, 0.0, &mut scratch)).abs() < 1e-12);
}

#[test]
fn losses_are_bit_identical_for_every_instruction_set_and_thread_count() {
    let mut rng = Rng::new(4);
    let (w, h) = (45usize, 130usize);
    let p = image(&mut rng, w, h);
    let t = correlated(&mut rng, &p, 0.6);
    let run = |threads: usize| {
        augsplat_testkit::with_threads(threads, || {
            let mut g = vec![0f32; p.len()];
            let a = photometric(&p, &t, w, h, PixelLoss::L2, 0.2, 1.0, &mut g);
            let b = photometric(&p, &t, w, h, PixelLoss::L1, 0.3, 0.5, &mut g);
            let c = l2(&p, &t, 0.7, &mut g);
            let d = l1(&p, &t, 0.7, &mut g);
            let bits = |v: (f64, f64, f64)| [v.0.to_bits(), v.1.to_bits(), v.2.to_bits()];
            let vals = [bits(a), bits(b), [c.to_bits(), d.to_bits(), 0]];
            (vals, g.iter().map(|v| v.to_bits()).collect::<Vec<_>>())
        })
    };
    let results = for_each_isa("losses", |_| [run(1), run(2), run(3)]);
    let first = &results[0].1[0];
    for (level, per_threads) in &results {
        for (k, r) in per_threads.iter().enumerate() {
            assert!(
                r == first,
                "level {level}, run {k} differs from baseline 1-thread"
            );
        }
    }
}

#[test]
fn non_finite_inputs_do_not_panic_and_stay_local() {
    let mut rng = Rng::new(2);
    let (w, h) = (30usize, 90usize);
    let mut p = image(&mut rng, w, h);
    let t = image(&mut rng, w, h);
    p[3 * (w * 5 + 5)] = f32::NAN;
    let mut g = vec![0f32; p.len()];
    let (lv, _, _) = photometric(&p, &t, w, h, PixelLoss::L2, 0.2, 1.0, &mut g);
    assert!(lv.is_nan());
    // Far from the bad value (more than a window away) the gradient is clean.
    let far = 3 * (w * 60 + 20);
    assert!(g[far].is_finite() && g[far] != 0.0);
}
