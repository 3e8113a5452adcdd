//! Every gradient group of the analytic backward pass against central finite differences of
//! the independent f64 reference renderer. Both sides use the C¹ smooth alpha cutoff
//! (`Cutoff::Smooth`, a hidden render entry point used only by tests) so the loss is
//! differentiable.
#![allow(clippy::needless_range_loop)]

mod raster_common;

use augsplat_core::{Camera, Rng};
use augsplat_render::reference::{render_reference, RefGaussians, RefImage};
use augsplat_render::render::{render_with_cutoff, Cutoff};
use augsplat_render::{backward, Gaussians, RenderSettings};
use raster_common::*;

struct Weights {
    rgb: Vec<f64>,
    alpha: Vec<f64>,
    depth: Vec<f64>,
}

fn loss(img: &RefImage, w: &Weights) -> f64 {
    let mut l = 0.0;
    for (a, b) in img.rgb.iter().zip(&w.rgb) {
        l += a * b;
    }
    for (a, b) in img.alpha.iter().zip(&w.alpha) {
        l += a * b;
    }
    for (a, b) in img.depth.iter().zip(&w.depth) {
        l += a * b;
    }
    l
}

/// The test scene: random Gaussians in view plus a near-plane one, two whose centres lie
/// beyond the Jacobian clamp (x and −y) but whose footprints reach the image, and one far
/// off-screen (culled: zero gradient).
fn scene(cam: &Camera, seed: u64) -> Gaussians {
    let mut g = random_scene(seed, 9, 3, cam, (-1.5, 1.5));
    let mut rng = Rng::new(seed + 100);
    push(&mut g, &mut rng, cam, [0.0, 0.01, 0.06], -5.3, 0.5); // near plane
    push(&mut g, &mut rng, cam, [0.95 * 3.0, 0.1, 3.0], -0.3, 0.8); // clamped in x
    push(&mut g, &mut rng, cam, [-0.2, -2.5, 2.5], -0.4, 0.3); // clamped in −y
    push(&mut g, &mut rng, cam, [30.0, 0.0, 2.0], -2.0, 0.0); // off-screen
    g
}

fn check_grads(s: &RenderSettings, seed: u64) {
    let cam = camera(26, 19);
    let g = scene(&cam, seed);
    // The clamp really is active for Gaussians 10 and 11.
    let lim_x = (cam.width as f64 - cam.cx) / cam.fx + 0.3 * 0.5 * cam.width as f64 / cam.fx;
    let lim_y = cam.cy / cam.fy + 0.3 * 0.5 * cam.height as f64 / cam.fy;
    let p10 = cam.to_camera(g.means[10].map(|v| v as f64));
    let p11 = cam.to_camera(g.means[11].map(|v| v as f64));
    assert!(p10[0] / p10[2] > lim_x && -p11[1] / p11[2] > lim_y);

    let out = render_with_cutoff(&g, &cam, s, None, Cutoff::Smooth);
    let dropped = s
        .opacity_scale
        .as_deref()
        .map_or(0, |f| f.iter().filter(|&&x| x == 0.0).count());
    assert!(
        out.stats.visible + dropped >= 11,
        "visible {}",
        out.stats.visible
    );
    let npix = 26 * 19;
    let mut rng = Rng::new(seed ^ 0xabc);
    let w = Weights {
        rgb: (0..npix * 3).map(|_| rng.uniform(-1.0, 1.0)).collect(),
        alpha: (0..npix).map(|_| rng.uniform(-1.0, 1.0)).collect(),
        depth: (0..npix)
            .map(|i| {
                if out.alpha[i] > 0.05 {
                    rng.uniform(-0.2, 0.2)
                } else {
                    0.0
                }
            })
            .collect(),
    };
    let f32v = |v: &[f64]| v.iter().map(|x| *x as f32).collect::<Vec<_>>();
    let grads = backward(
        &g,
        &cam,
        s,
        &out,
        &f32v(&w.rgb),
        Some(&f32v(&w.alpha)),
        Some(&f32v(&w.depth)),
    );
    // The reference at the same point agrees with the fast forward.
    let base = RefGaussians::from(&g);
    let r0 = render_reference(&base, &cam, s, true);
    assert!(max_abs_diff(&out.rgb, &r0.rgb) < 1e-5);

    let h = 1e-5;
    let fd = |edit: &dyn Fn(&mut RefGaussians, f64)| {
        let mut gp = base.clone();
        edit(&mut gp, h);
        let mut gm = base.clone();
        edit(&mut gm, -h);
        (loss(&render_reference(&gp, &cam, s, true), &w)
            - loss(&render_reference(&gm, &cam, s, true), &w))
            / (2.0 * h)
    };
    let n = g.len();
    let mut groups: Vec<(&str, Vec<f64>, Vec<f64>)> = Vec::new();
    let (mut a, mut f) = (vec![], vec![]);
    for i in 0..n {
        for k in 0..3 {
            a.push(grads.means[i][k] as f64);
            f.push(fd(&|r, d| r.means[i][k] += d));
        }
    }
    groups.push(("means", a, f));
    let (mut a, mut f) = (vec![], vec![]);
    for i in 0..n {
        for k in 0..3 {
            a.push(grads.log_scales[i][k] as f64);
            f.push(fd(&|r, d| r.log_scales[i][k] += d));
        }
    }
    groups.push(("log_scales", a, f));
    let (mut a, mut f) = (vec![], vec![]);
    for i in 0..n {
        for k in 0..4 {
            a.push(grads.quats[i][k] as f64);
            f.push(fd(&|r, d| r.quats[i][k] += d));
        }
    }
    groups.push(("quats", a, f));
    let (mut a, mut f) = (vec![], vec![]);
    for i in 0..n {
        a.push(grads.opacity_logits[i] as f64);
        f.push(fd(&|r, d| r.logits[i] += d));
    }
    groups.push(("opacity_logits", a, f));
    let (mut a, mut f) = (vec![], vec![]);
    for j in 0..g.sh.len() {
        a.push(grads.sh[j] as f64);
        f.push(fd(&|r, d| r.sh[j] += d));
    }
    groups.push(("sh", a, f));

    for (name, an, fdv) in &groups {
        let scale = fdv.iter().fold(0.0f64, |m, v| m.max(v.abs()));
        assert!(scale > 1e-3, "{name}: gradients vanish ({scale})");
        let mut worst = 0.0f64;
        for (j, (x, y)) in an.iter().zip(fdv).enumerate() {
            let err = (x - y).abs() / (y.abs() + 1e-3 * scale);
            worst = worst.max(err);
            assert!(
                err < 2e-3,
                "{name}[{j}] (Gaussian {}): analytic {x} vs finite difference {y}",
                j / (an.len() / n)
            );
        }
        eprintln!("{name}: scale {scale:.3e}, worst relative error {worst:.2e}");
    }
    // Culled Gaussian: exactly zero and not visible.
    assert!(!grads.visible[12] && grads.means[12] == [0.0; 3]);
    assert!(grads.visible[10] && grads.visible[11] && grads.visible[9]);
}

#[test]
fn gradients_match_finite_differences() {
    check_grads(&RenderSettings::default(), 1);
}

#[test]
fn gradients_match_finite_differences_antialiased_with_background() {
    let s = RenderSettings {
        antialiased: true,
        background: [0.3, 0.7, 0.1],
        ..Default::default()
    };
    check_grads(&s, 2);
}

#[test]
fn gradients_match_finite_differences_with_dropgaussian_opacity_factors() {
    // DropGaussian's factors: a dropped Gaussian (0: culled, zero gradients), survivors at
    // 1/(1 − 0.2) and one at 1/(1 − 0.375), lifted above opacity 1 (the per-pixel clamp then
    // decides), and the others at 1.
    let cam = camera(26, 19);
    let n = scene(&cam, 3).len();
    let mut f = vec![1.0f32; n];
    f[2] = 0.0;
    for i in [0, 1, 3, 4, 9] {
        f[i] = 1.25;
    }
    f[5] = 1.6;
    let s = RenderSettings {
        opacity_scale: Some(f.into()),
        ..Default::default()
    };
    check_grads(&s, 3);
    // The dropped Gaussian is culled: not visible, zero gradients.
    let g = scene(&cam, 3);
    let out = render_with_cutoff(&g, &cam, &s, None, Cutoff::Smooth);
    let grads = backward(&g, &cam, &s, &out, &vec![1.0; 26 * 19 * 3], None, None);
    assert!(!grads.visible[2] && grads.opacity_logits[2] == 0.0 && grads.means[2] == [0.0; 3]);
    // Some survivor's opacity really is above 1.
    let sig = |l: f32| 1.0 / (1.0 + (-l).exp());
    assert!(
        1.6 * sig(g.opacity_logits[5]) > 1.0,
        "{:?}",
        g.opacity_logits
    );
}
