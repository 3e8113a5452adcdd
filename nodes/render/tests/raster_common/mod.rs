//! Scene and camera generators shared by the rasteriser tests.
#![allow(dead_code)]

use augsplat_core::linalg::{axis_angle, mat3_vec, mat4_from_rt, transpose3};
use augsplat_core::{Camera, Rng};
use augsplat_render::Gaussians;

/// A camera looking roughly along +z from near the origin, with an off-centre principal
/// point and unequal focal lengths.
pub fn camera(width: u32, height: u32) -> Camera {
    let r = axis_angle([0.3, 1.0, -0.2], 0.25);
    Camera {
        width,
        height,
        fx: 0.95 * width as f64,
        fy: 1.05 * width as f64,
        cx: 0.43 * width as f64,
        cy: 0.56 * height as f64,
        world_to_camera: mat4_from_rt(&r, [0.2, -0.1, 0.3]),
    }
}

/// World point whose camera coordinates are `pc`.
pub fn world_of(cam: &Camera, pc: [f64; 3]) -> [f32; 3] {
    let r = cam.rotation();
    let t = cam.translation();
    let d = [pc[0] - t[0], pc[1] - t[1], pc[2] - t[2]];
    let w = mat3_vec(&transpose3(&r), d);
    [w[0] as f32, w[1] as f32, w[2] as f32]
}

/// Appends one Gaussian with camera-frame centre `pc` (normalised image coords u = x/z,
/// v = y/z are what matter), isotropic-ish log scale `ls` and opacity logit `logit`.
pub fn push(g: &mut Gaussians, rng: &mut Rng, cam: &Camera, pc: [f64; 3], ls: f64, logit: f32) {
    g.means.push(world_of(cam, pc));
    g.log_scales.push([
        (ls + rng.uniform(-0.6, 0.6)) as f32,
        (ls + rng.uniform(-0.6, 0.6)) as f32,
        (ls + rng.uniform(-0.6, 0.6)) as f32,
    ]);
    g.quats.push([
        rng.normal() as f32,
        rng.normal() as f32,
        rng.normal() as f32,
        rng.normal() as f32,
    ]);
    g.opacity_logits.push(logit);
    let k = g.coeffs() * 3;
    for j in 0..k {
        let sd = if j < 3 { 0.8 } else { 0.25 };
        g.sh.push((rng.normal() * sd) as f32);
    }
}

/// A random scene of `n` Gaussians mostly inside the view of `cam` at depths 1.5–6, with
/// opacities spread over `logit_range` (include values above MAX_ALPHA with e.g. up to 7).
pub fn random_scene(
    seed: u64,
    n: usize,
    degree: u32,
    cam: &Camera,
    logit_range: (f64, f64),
) -> Gaussians {
    let mut rng = Rng::new(seed);
    let mut g = Gaussians::empty(degree);
    let (hw, hh) = (
        0.5 * cam.width as f64 / cam.fx,
        0.5 * cam.height as f64 / cam.fy,
    );
    for _ in 0..n {
        let z = rng.uniform(1.5, 6.0);
        let u = rng.uniform(-1.3 * hw, 1.3 * hw);
        let v = rng.uniform(-1.3 * hh, 1.3 * hh);
        let ls = rng.uniform(-3.2, -1.0) + (z / 3.0).ln() + (24.0 / cam.width as f64).ln() * 0.0;
        let logit = rng.uniform(logit_range.0, logit_range.1) as f32;
        push(&mut g, &mut rng, cam, [u * z, v * z, z], ls, logit);
    }
    g
}

/// Maximum absolute difference.
pub fn max_abs_diff(a: &[f32], b: &[f64]) -> f64 {
    assert_eq!(a.len(), b.len());
    a.iter()
        .zip(b)
        .map(|(x, y)| (*x as f64 - y).abs())
        .fold(0.0, f64::max)
}
