//! Stress inputs: degenerate and non-finite parameters, extreme poses and image sizes.
//! Outcome must be a clean image and clean gradients (no panic, no NaN), with invalid
//! Gaussians culled and counted.
#![allow(clippy::needless_range_loop)]

mod raster_common;

use augsplat_core::{Camera, Rng};
use augsplat_render::{backward, render, Gaussians, RenderSettings};
use raster_common::*;

fn assert_clean(g: &Gaussians, cam: &Camera, s: &RenderSettings) -> augsplat_render::RenderStats {
    let out = render(g, cam, s);
    let npix = (cam.width * cam.height) as usize;
    assert_eq!(out.rgb.len(), npix * 3);
    assert!(out.rgb.iter().all(|v| v.is_finite()), "NaN/Inf in rgb");
    assert!(out
        .alpha
        .iter()
        .all(|v| v.is_finite() && (0.0..=1.0).contains(v)));
    assert!(out.depth.iter().all(|v| v.is_finite()));
    let d_rgb: Vec<f32> = (0..npix * 3)
        .map(|i| ((i % 7) as f32 - 3.0) * 0.1)
        .collect();
    let d_a: Vec<f32> = (0..npix).map(|i| ((i % 5) as f32 - 2.0) * 0.1).collect();
    let gr = backward(g, cam, s, &out, &d_rgb, Some(&d_a), Some(&d_a));
    let all_finite = gr.means.iter().flatten().all(|v| v.is_finite())
        && gr.log_scales.iter().flatten().all(|v| v.is_finite())
        && gr.quats.iter().flatten().all(|v| v.is_finite())
        && gr.opacity_logits.iter().all(|v| v.is_finite())
        && gr.sh.iter().all(|v| v.is_finite())
        && gr.means2d_abs.iter().flatten().all(|v| v.is_finite());
    assert!(all_finite, "NaN/Inf in gradients");
    assert_eq!(gr.means.len(), g.len());
    let st = out.stats;
    assert_eq!(st.visible + st.culled + st.invalid, g.len());
    st
}

#[test]
fn degenerate_and_non_finite_gaussians_are_counted_and_never_poison_the_image() {
    let cam = camera(48, 40);
    let mut g = random_scene(3, 40, 3, &cam, (-2.0, 5.0));
    let mut rng = Rng::new(8);
    let base = g.len();
    // Valid extremes (must render cleanly, counted visible or culled).
    push(&mut g, &mut rng, &cam, [0.0, 0.0, 2.0], -30.0, 1.0); // tiny scale
    push(&mut g, &mut rng, &cam, [0.1, 0.0, 2.0], -100.0, 1.0); // denormal scale
    push(&mut g, &mut rng, &cam, [0.0, 0.1, 2.0], 60.0, 1.0); // huge (finite) scale
    push(&mut g, &mut rng, &cam, [0.0, 0.0, -1.0], -2.0, 1.0); // behind the camera
    push(&mut g, &mut rng, &cam, [0.0, 0.0, 0.0], -2.0, 1.0); // at the camera
    push(&mut g, &mut rng, &cam, [0.0, 0.0, 0.01], -2.0, 1.0); // on the near plane
    push(&mut g, &mut rng, &cam, [0.0, 0.0, 0.011], -4.0, 1.0); // just in front of it
    push(&mut g, &mut rng, &cam, [0.1, 0.1, 3.0], -2.0, -100.0); // opacity 0
    push(&mut g, &mut rng, &cam, [0.1, -0.1, 3.0], -2.0, 100.0); // opacity 1
    let valid_extra = g.len() - base;
    // Invalid ones.
    let mut invalid = 0;
    let mut add_bad = |g: &mut Gaussians, f: &dyn Fn(&mut Gaussians, usize)| {
        push(g, &mut rng, &cam, [0.0, 0.0, 2.5], -2.0, 1.0);
        let i = g.len() - 1;
        f(g, i);
        invalid += 1;
    };
    add_bad(&mut g, &|g, i| g.quats[i] = [0.0; 4]);
    add_bad(&mut g, &|g, i| g.log_scales[i][1] = 1000.0); // exp overflows
    add_bad(&mut g, &|g, i| g.means[i][0] = f32::NAN);
    add_bad(&mut g, &|g, i| g.means[i][2] = f32::INFINITY);
    add_bad(&mut g, &|g, i| g.log_scales[i][0] = f32::NAN);
    add_bad(&mut g, &|g, i| g.quats[i][2] = f32::NEG_INFINITY);
    add_bad(&mut g, &|g, i| g.opacity_logits[i] = f32::NAN);
    add_bad(&mut g, &|g, i| {
        let k = g.coeffs() * 3;
        g.sh[i * k + 5] = f32::NAN;
    });
    add_bad(&mut g, &|g, i| {
        let k = g.coeffs() * 3;
        g.sh[i * k] = f32::INFINITY;
    });
    for s in [
        RenderSettings::default(),
        RenderSettings {
            antialiased: true,
            background: [1.0, 0.0, 0.5],
            ..Default::default()
        },
    ] {
        let st = assert_clean(&g, &cam, &s);
        assert_eq!(st.invalid, invalid, "{st:?}");
        assert!(st.visible >= 30 && valid_extra > 0);
    }
}

#[test]
fn tiny_wide_and_empty_images_and_scenes() {
    let s = RenderSettings::default();
    for (w, h) in [(1, 1), (4097, 3), (3, 4097 / 64), (17, 1)] {
        let cam = camera(w, h);
        let g = random_scene(w as u64 + h as u64, 300, 2, &cam, (-2.0, 6.0));
        let st = assert_clean(&g, &cam, &s);
        assert_eq!(st.invalid, 0);
        let st0 = assert_clean(&Gaussians::empty(3), &cam, &s);
        assert_eq!(st0, augsplat_render::RenderStats::default());
    }
    // A 1×1 image still shows Gaussians covering it.
    let cam = camera(1, 1);
    let mut g = Gaussians::empty(0);
    let mut rng = Rng::new(1);
    push(&mut g, &mut rng, &cam, [0.0, 0.0, 2.0], -1.0, 2.0);
    let out = render(&g, &cam, &s);
    assert!(out.alpha[0] > 0.5, "{}", out.alpha[0]);
}

#[test]
fn inconsistent_inputs_do_not_panic() {
    let cam = camera(20, 10);
    let mut g = random_scene(4, 10, 1, &cam, (0.0, 2.0));
    let s = RenderSettings::default();
    let out = render(&g, &cam, &s);
    // Upstream gradients of the wrong length are treated as zero.
    let gr = backward(&g, &cam, &s, &out, &[1.0; 3], Some(&[1.0; 2]), None);
    assert!(gr.means.iter().flatten().all(|v| *v == 0.0));
    // Non-finite upstream values are ignored.
    let bad = vec![f32::NAN; 20 * 10 * 3];
    let gr = backward(&g, &cam, &s, &out, &bad, None, None);
    assert!(gr.means.iter().flatten().all(|v| v.is_finite()));
    // A mask of the wrong size is ignored; a broken camera renders the background.
    let m = augsplat_render::render_masked(&g, &cam, &s, Some(&[0u8; 3]));
    assert_eq!(m.rgb, out.rgb);
    let mut bad_cam = cam.clone();
    bad_cam.fx = f64::NAN;
    let b = render(&g, &bad_cam, &s);
    assert!(b.alpha.iter().all(|a| *a == 0.0));
    // Mismatched array lengths: everything invalid, nothing rendered.
    g.opacity_logits.pop();
    let st = render(&g, &cam, &s).stats;
    assert_eq!(st.invalid, g.len());
}
