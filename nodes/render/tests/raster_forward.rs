//! The tiled f32 forward pass against the independent untiled f64 reference.
#![allow(clippy::needless_range_loop)]

mod raster_common;

use augsplat_render::reference::{render_reference, RefGaussians};
use augsplat_render::{render, RenderSettings};
use raster_common::*;

fn check(seed: u64, n: usize, w: u32, h: u32, s: &RenderSettings) {
    let cam = camera(w, h);
    // Logits up to 7 ⇒ opacities up to 0.999 > MAX_ALPHA.
    let g = random_scene(seed, n, 3, &cam, (-3.0, 7.0));
    let out = render(&g, &cam, s);
    let r = render_reference(&RefGaussians::from(&g), &cam, s, false);
    assert_eq!(out.stats.visible, r.visible, "visible count");
    assert!(out.stats.pairs > 0);
    let e_rgb = max_abs_diff(&out.rgb, &r.rgb);
    let e_a = max_abs_diff(&out.alpha, &r.alpha);
    assert!(e_rgb < 1e-5, "seed {seed}: rgb error {e_rgb}");
    assert!(e_a < 1e-5, "seed {seed}: alpha error {e_a}");
    // Depth is normalised by alpha: compare where alpha is not tiny, relative to depth.
    let mut e_d = 0.0f64;
    for i in 0..out.depth.len() {
        if r.alpha[i] > 1e-2 {
            e_d = e_d.max((out.depth[i] as f64 - r.depth[i]).abs() / r.depth[i].abs().max(1.0));
        }
    }
    assert!(e_d < 1e-5, "seed {seed}: depth error {e_d}");
    eprintln!("seed {seed}: max |Δ| rgb {e_rgb:.2e}, alpha {e_a:.2e}, depth (rel) {e_d:.2e}");
}

#[test]
fn forward_matches_reference_on_random_scenes() {
    let s = RenderSettings::default();
    for seed in 0..4 {
        check(seed, 150, 61, 47, &s);
    }
}

#[test]
fn forward_matches_reference_with_background_aa_and_low_degree() {
    let s = RenderSettings {
        sh_degree: 1,
        background: [0.2, 0.5, 0.9],
        antialiased: true,
        max_alpha: 0.999,
        ..Default::default()
    };
    for seed in 10..13 {
        check(seed, 120, 40, 70, &s);
    }
}

#[test]
fn dense_scene_hits_transmittance_stop_and_matches() {
    // Many opaque Gaussians: most pixels stop early on the 1e-4 transmittance rule.
    let s = RenderSettings::default();
    let cam = camera(33, 29);
    let g = random_scene(99, 400, 2, &cam, (3.0, 8.0));
    let out = render(&g, &cam, &s);
    let r = render_reference(&RefGaussians::from(&g), &cam, &s, false);
    assert!(max_abs_diff(&out.rgb, &r.rgb) < 1e-5);
    assert!(max_abs_diff(&out.alpha, &r.alpha) < 1e-5);
    assert!(out.alpha.iter().filter(|a| **a > 0.999).count() > 100);
}

#[test]
fn masked_pixels_show_background_and_empty_tiles_are_skipped() {
    let s = RenderSettings {
        background: [0.1, 0.2, 0.3],
        ..Default::default()
    };
    let cam = camera(40, 36);
    let g = random_scene(5, 100, 3, &cam, (0.0, 4.0));
    let full = render(&g, &cam, &s);
    let mut mask = vec![1u8; 40 * 36];
    for y in 0..36 {
        for x in 0..40 {
            if x < 16 || (x + y) % 3 == 0 {
                mask[y * 40 + x] = 0;
            }
        }
    }
    let m = augsplat_render::render_masked(&g, &cam, &s, Some(&mask));
    for i in 0..40 * 36 {
        if mask[i] == 0 {
            assert_eq!(m.alpha[i], 0.0);
            assert_eq!(&m.rgb[i * 3..i * 3 + 3], &[0.1, 0.2, 0.3]);
        } else {
            assert_eq!(m.rgb[i * 3..i * 3 + 3], full.rgb[i * 3..i * 3 + 3]);
            assert_eq!(m.alpha[i], full.alpha[i]);
        }
    }
    assert!(m.stats.pairs < full.stats.pairs);
}
