//! `backward_add` (a render's gradients added straight into a step's running sum) gives the
//! same values as adding `backward`'s fresh buffers, for any thread count.
#![allow(clippy::needless_range_loop)]

#[path = "../../render/tests/raster_common/mod.rs"]
mod raster_common;

use augsplat_core::linalg;
use augsplat_splat::adam::ParamGrads;
use augsplat_splat::train::add_grads;
use augsplat_splat::{backward, backward_add, render, Gaussians, RenderSettings};
use raster_common::*;

/// Two cameras looking at the same scene from slightly different places and sizes.
fn cameras() -> [augsplat_core::Camera; 2] {
    let a = camera(96, 70);
    let mut b = camera(64, 52);
    let t = linalg::mat4_from_rt(
        &[[0.995, 0.0, 0.0998], [0.0, 1.0, 0.0], [-0.0998, 0.0, 0.995]],
        [0.2, -0.1, 0.0],
    );
    b.world_to_camera = linalg::mat4_mul(&t, &b.world_to_camera);
    [a, b]
}

fn upstream(n: usize, seed: usize) -> Vec<f32> {
    (0..n)
        .map(|i| (((i + seed) * 7919) % 13) as f32 * 0.01 - 0.06)
        .collect()
}

/// The step sum by fresh buffers: a copy of `start`, plus each render's `backward` output on
/// the Gaussians it saw (the trainer's former path).
fn by_fresh_buffers(g: &Gaussians, s: &RenderSettings, start: &ParamGrads) -> ParamGrads {
    let mut acc = start.clone();
    for (k, cam) in cameras().iter().enumerate() {
        let out = render(g, cam, s);
        let gr = backward(g, cam, s, &out, &upstream(out.rgb.len(), k), None, None);
        let sh_active = acc.sh_active;
        add_grads(&mut acc, &gr, sh_active);
    }
    acc
}

fn by_adding(g: &Gaussians, s: &RenderSettings, start: &ParamGrads, threads: usize) -> ParamGrads {
    let pool = rayon::ThreadPoolBuilder::new()
        .num_threads(threads)
        .build()
        .unwrap();
    pool.install(|| {
        let mut acc = start.clone();
        for (k, cam) in cameras().iter().enumerate() {
            let out = render(g, cam, s);
            backward_add(g, cam, &out, &upstream(out.rgb.len(), k), &mut acc);
        }
        acc
    })
}

/// Equal as values (−0 and +0 compare equal: both paths add the same numbers, but one adds
/// a zero gradient where the other skips it).
fn assert_same(a: &ParamGrads, b: &ParamGrads) {
    let flat = |p: &ParamGrads| -> Vec<f32> {
        let mut v: Vec<f32> = p.means.iter().flatten().copied().collect();
        v.extend(p.log_scales.iter().flatten());
        v.extend(p.quats.iter().flatten());
        v.extend(&p.opacity_logits);
        v.extend(&p.sh);
        v
    };
    let (fa, fb) = (flat(a), flat(b));
    assert_eq!(fa.len(), fb.len());
    for (i, (x, y)) in fa.iter().zip(&fb).enumerate() {
        assert!(x == y, "value {i}: {x} vs {y}");
    }
    assert_eq!(a.visible, b.visible);
}

#[test]
fn adding_into_a_running_sum_equals_adding_fresh_buffers() {
    let cam = camera(96, 70);
    let g = random_scene(7, 3000, 2, &cam, (-3.0, 6.0));
    let s = RenderSettings {
        sh_degree: 1,
        background: [0.1, 0.2, 0.3],
        ..Default::default()
    };
    let n = g.len();
    let sh_active = 3 * 4; // degree 1 of a degree-2 model
                           // From zero (Staged warm-up) and from a non-zero sum (Dual: the real view's gradients).
    let zero = ParamGrads {
        sh_active,
        ..ParamGrads::zeros(n, g.coeffs())
    };
    let mut start = zero.clone();
    for i in 0..n {
        if i % 3 == 0 {
            start.visible[i] = true;
            start.means[i] = [0.5, -0.25, 1e-3];
            start.opacity_logits[i] = -0.125;
            start.sh[i * g.coeffs() * 3] = 0.75;
        }
    }
    for init in [&zero, &start] {
        let want = by_fresh_buffers(&g, &s, init);
        assert!(want.visible.iter().filter(|v| **v).count() > n / 3);
        assert!(want.means.iter().any(|m| m[0] != 0.0 && m[0] != 0.5));
        for threads in [1, 2] {
            assert_same(&by_adding(&g, &s, init, threads), &want);
        }
        // SH values above the render's degree stay as they were.
        let got = by_adding(&g, &s, init, 2);
        let k3 = g.coeffs() * 3;
        for i in 0..n {
            assert_eq!(
                &got.sh[i * k3 + sh_active..(i + 1) * k3],
                &init.sh[i * k3 + sh_active..(i + 1) * k3]
            );
        }
    }
}

#[test]
fn mismatched_sums_are_left_unchanged() {
    let cam = camera(32, 24);
    let g = random_scene(3, 200, 1, &cam, (-3.0, 6.0));
    let s = RenderSettings::default();
    let out = render(&g, &cam, &s);
    let mut acc = ParamGrads::zeros(g.len() + 1, g.coeffs());
    let before = acc.clone();
    backward_add(&g, &cam, &out, &upstream(out.rgb.len(), 0), &mut acc);
    assert_eq!(acc, before);
}
