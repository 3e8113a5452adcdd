//! The opacity reset modes: `Periodic` can starve small Gaussians (every pixel under the
//! 1/255 alpha cutoff, opacity gradient exactly zero), `KeepVisible` cannot; `Never` resets
//! nothing but still prunes oversized Gaussians after `reset_every` steps.

use augsplat_core::{linalg, Camera};
use augsplat_splat::adam::Adam;
use augsplat_splat::densify::{
    self, Densifier, DensifyArgs, Extents, OpacityReset, KEEP_VISIBLE_ALPHA,
};
use augsplat_splat::{backward, render, Gaussians, RenderSettings};

fn sigmoid(x: f64) -> f64 {
    1.0 / (1.0 + (-x).exp())
}

fn camera() -> Camera {
    let id = [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]];
    Camera {
        width: 32,
        height: 32,
        fx: 32.0,
        fy: 32.0,
        cx: 16.0,
        cy: 16.0,
        world_to_camera: linalg::mat4_from_rt(&id, [0.0; 3]),
    }
}

/// 12 sub-pixel Gaussians (σ ≈ 0.25 px) centred on pixel corners and centres, and one large
/// one (σ ≈ 4 px), all at depth 2 with opacity 0.9.
fn gaussians() -> Gaussians {
    let mut g = Gaussians::empty(0);
    let z = 2.0f32;
    let mut add = |u: f32, v: f32, sigma_px: f32| {
        g.means
            .push([(u - 16.0) * z / 32.0, (v - 16.0) * z / 32.0, z]);
        g.log_scales.push([(sigma_px * z / 32.0).ln(); 3]);
        g.quats.push([1.0, 0.0, 0.0, 0.0]);
        g.opacity_logits.push(2.197); // 0.9
        g.sh.extend_from_slice(&[0.5, 0.2, -0.3]);
    };
    for k in 0..12 {
        let (u, v) = (4.0 + 2.0 * (k % 6) as f32, 6.0 + 8.0 * (k / 6) as f32);
        // Even k on a pixel corner, odd k on a pixel centre.
        let off = if k % 2 == 0 { 0.0 } else { 0.5 };
        add(u + off, v + off, 0.25);
    }
    add(20.0, 24.0, 4.0);
    g
}

fn settings() -> RenderSettings {
    RenderSettings {
        sh_degree: 0,
        antialiased: true,
        ..Default::default()
    }
}

/// Opacity-logit gradients of a loss whose colour gradient is 1 everywhere.
fn opacity_grads(g: &Gaussians) -> Vec<f32> {
    let cam = camera();
    let s = settings();
    let out = render(g, &cam, &s);
    let d_rgb = vec![1.0f32; out.rgb.len()];
    backward(g, &cam, &s, &out, &d_rgb, None, None).opacity_logits
}

#[test]
fn keep_visible_reset_never_starves_a_gaussian() {
    let g0 = gaussians();
    let n = g0.len();
    assert!(
        opacity_grads(&g0).iter().all(|&d| d != 0.0),
        "before any reset"
    );
    // Periodic: every opacity clamped to 0.01; the sub-pixel Gaussians' compensated alpha
    // falls under 1/255 at every pixel and their gradient is exactly zero.
    let mut g = g0.clone();
    let mut adam = Adam::new(n, 1);
    densify::reset_opacities(&mut g, &mut adam, 0.01);
    let d = opacity_grads(&g);
    let starved = d[..12].iter().filter(|&&v| v == 0.0).count();
    assert!(starved >= 6, "only {starved} of 12 starved: {d:?}");
    assert!(d[12] != 0.0);
    // KeepVisible: the same clamp where it is harmless, a higher floor where it is not.
    let cam = camera();
    let ratios = densify::peak_alpha_ratios(&g0, &[&cam], true, 0.01);
    assert!(ratios.iter().all(|&r| r > 0.0 && r <= 1.0), "{ratios:?}");
    let mut g = g0.clone();
    densify::reset_opacities_keep_visible(&mut g, &mut adam, 0.01, &ratios);
    let d = opacity_grads(&g);
    assert!(d.iter().all(|&v| v != 0.0), "a Gaussian starved: {d:?}");
    for (i, (&logit, &ratio)) in g.opacity_logits.iter().zip(&ratios).enumerate() {
        let o = sigmoid(logit as f64);
        let want = (KEEP_VISIBLE_ALPHA / ratio).clamp(0.01, 0.9);
        assert!((o - want).abs() < 1e-5, "Gaussian {i}: {o} vs {want}");
    }
    // The large Gaussian is reset exactly as by `Periodic`.
    assert!((sigmoid(g.opacity_logits[12] as f64) - 0.01).abs() < 1e-6);
}

#[test]
fn keep_visible_keeps_no_floor_for_a_gaussian_no_opacity_keeps_visible() {
    use augsplat_splat::densify::{keep_visible_floor, KEEP_VISIBLE_MAX_OPACITY};
    let cutoff = 1.0 / 255.0f32;
    // A peak that the ceiling keeps at the cutoff or above gets the ceiling at most.
    let lowest = f64::from(cutoff) / KEEP_VISIBLE_MAX_OPACITY;
    assert_eq!(
        keep_visible_floor(lowest * 1.000001),
        KEEP_VISIBLE_MAX_OPACITY
    );
    assert!((keep_visible_floor(0.5) - KEEP_VISIBLE_ALPHA / 0.5).abs() < 1e-15);
    // Below it no opacity makes the Gaussian visible: no floor (reset as by `Periodic`).
    for r in [lowest * 0.999999, 1e-82, 0.0] {
        assert_eq!(keep_visible_floor(r), 0.0, "ratio {r:e}");
    }
    let mut g = gaussians();
    let mut adam = Adam::new(g.len(), 1);
    let mut ratios = vec![0.5; g.len()];
    ratios[0] = 1e-82;
    densify::reset_opacities_keep_visible(&mut g, &mut adam, 0.01, &ratios);
    assert!((sigmoid(f64::from(g.opacity_logits[0])) - 0.01).abs() < 1e-6);
    let kept = sigmoid(f64::from(g.opacity_logits[1]));
    assert!((kept - KEEP_VISIBLE_ALPHA / 0.5).abs() < 1e-6, "{kept}");
}

#[test]
fn reset_modes_through_the_strategy() {
    // One large Gaussian (scale 0.5 > prune_scale3d × scene scale 1 = 0.1), one small.
    let base = {
        let mut g = Gaussians::empty(0);
        for (m, s) in [([0.0, 0.0, 2.0], 0.5f32), ([0.1, 0.0, 2.0], 0.01)] {
            g.means.push(m);
            g.log_scales.push([s.ln(); 3]);
            g.quats.push([1.0, 0.0, 0.0, 0.0]);
            g.opacity_logits.push(2.0);
            g.sh.extend_from_slice(&[0.1, 0.1, 0.1]);
        }
        g
    };
    let run = |mode: OpacityReset| {
        let args = DensifyArgs {
            reset: mode,
            ..Default::default()
        };
        let sched = args.scaled(3000); // refine every 100 in (125, 1500), reset every 750
        let mut g = base.clone();
        let mut adam = Adam::new(2, 1);
        let mut d = Densifier::new(2);
        let cam = camera();
        let mut calls = 0;
        let mut vis = |g: &Gaussians| {
            calls += 1;
            densify::peak_alpha_ratios(g, &[&cam], true, 0.01)
        };
        // Refinement at 700: before `reset_every`, nothing is too large yet.
        let r = d.step_post_update(
            700,
            &sched,
            &args,
            &mut g,
            &mut adam,
            Extents::uniform(1.0),
            0,
            &mut vis,
        );
        assert_eq!((r.pruned, r.reset), (0, false));
        let r750 = d.step_post_update(
            750,
            &sched,
            &args,
            &mut g,
            &mut adam,
            Extents::uniform(1.0),
            0,
            &mut vis,
        );
        let after_reset = g.clone();
        let r800 = d.step_post_update(
            800,
            &sched,
            &args,
            &mut g,
            &mut adam,
            Extents::uniform(1.0),
            0,
            &mut vis,
        );
        (r750.reset, after_reset, r800.pruned, g.len(), calls)
    };
    let (reset, g, pruned, left, calls) = run(OpacityReset::Never);
    assert!(!reset && calls == 0);
    assert_eq!(
        g.opacity_logits, base.opacity_logits,
        "Never changed opacities"
    );
    assert_eq!(
        (pruned, left),
        (1, 1),
        "Never must still prune the large Gaussian"
    );
    let (reset, g, pruned, _, calls) = run(OpacityReset::Periodic);
    assert!(reset && calls == 0);
    assert!(g
        .opacity_logits
        .iter()
        .all(|&o| (sigmoid(o as f64) - 0.01).abs() < 1e-6));
    assert_eq!(pruned, 1);
    let (reset, _, pruned, _, calls) = run(OpacityReset::KeepVisible);
    assert!(reset && calls == 1);
    assert_eq!(pruned, 1);
}

/// The default mode stays out of the canonical args (old pipelines keep their keys); the
/// others are written.
#[test]
fn default_reset_mode_is_left_out_of_the_encoding() {
    let json = |a: &DensifyArgs| serde_json::to_string(a).unwrap();
    assert!(!json(&DensifyArgs::default()).contains("\"reset\""));
    for mode in [OpacityReset::Never, OpacityReset::KeepVisible] {
        let a = DensifyArgs {
            reset: mode,
            ..Default::default()
        };
        assert!(json(&a).contains(&format!("\"reset\":\"{mode:?}\"")));
    }
}
