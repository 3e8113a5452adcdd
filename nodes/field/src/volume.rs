//! Volume rendering of one ray, forward and analytic backward, plus the per-ray losses that
//! act on the sample weights (DS-NeRF depth, mip-NeRF 360 distortion).
//!
//! Samples `i` carry density `σ_i`, length `δ_i` and distance `t_i`; `α_i = 1 − e^{−σ_i δ_i}`,
//! `T_i = Π_{j<i} (1 − α_j)`, `w_i = T_i α_i`. Weights are computed for every marched sample
//! (densities are cheap); colour is evaluated only for the first `n_color` samples, up to and
//! including the one after which `T` falls below [`TRANSMITTANCE_THRESHOLD`] (early
//! termination: the mass left out is below the threshold). Then
//! `C = Σ_{i<n_color} w_i c_i`, `A = Σ_i w_i`, `D = Σ_i w_i t_i` and the pixel is
//! `C + (1 − A)·background`.

use crate::constants::{DEPTH_LOG_EPS, TRANSMITTANCE_THRESHOLD};

/// Computes `w_i` for every sample into `w` and returns `n_color`.
pub fn weights_forward(sigma: &[f32], dt: &[f32], w: &mut [f32]) -> usize {
    let mut t = 1.0f32;
    let mut n_color = sigma.len();
    for i in 0..sigma.len() {
        let trans = (-sigma[i] * dt[i]).exp();
        w[i] = t * (1.0 - trans);
        t *= trans;
        if t < TRANSMITTANCE_THRESHOLD && n_color == sigma.len() {
            n_color = i + 1;
        }
    }
    n_color
}

/// Composite colour `Σ_{i<n} w_i c_i` from SoA colour slices of length `n`.
pub fn composite_color(w: &[f32], r: &[f32], g: &[f32], b: &[f32]) -> [f32; 3] {
    let mut c = [0f32; 3];
    for i in 0..r.len() {
        c[0] += w[i] * r[i];
        c[1] += w[i] * g[i];
        c[2] += w[i] * b[i];
    }
    c
}

/// Accumulated opacity `Σ w_i` and premultiplied depth `Σ w_i t_i`.
pub fn opacity_depth(w: &[f32], t: &[f32]) -> (f32, f32) {
    let (mut a, mut d) = (0f32, 0f32);
    for i in 0..w.len() {
        a += w[i];
        d += w[i] * t[i];
    }
    (a, d)
}

/// Backward through the weights: given `g_i = ∂L/∂w_i`, writes
/// `∂L/∂σ_i = δ_i (g_i T_{i+1} − Σ_{k>i} g_k w_k)` (no division by `1 − α`, stable at α → 1).
pub fn weights_backward(sigma: &[f32], dt: &[f32], w: &[f32], g: &[f32], d_sigma: &mut [f32]) {
    let n = sigma.len();
    let mut suffix: f32 = 0.0;
    for i in 0..n {
        suffix += g[i] * w[i];
    }
    let mut t = 1.0f32;
    for i in 0..n {
        let trans = (-sigma[i] * dt[i]).exp();
        t *= trans;
        suffix -= g[i] * w[i];
        d_sigma[i] = dt[i] * (g[i] * t - suffix);
    }
}

/// DS-NeRF depth loss of one ray with target distance `z` (along the ray) and spread `s`:
/// `Σ_i −log(w_i + ε) · exp(−(t_i − z)² / (2 s²)) · δ_i`. Adds `scale · ∂/∂w_i` to `g` and
/// returns the unscaled loss.
pub fn ds_nerf_depth(
    w: &[f32],
    t: &[f32],
    dt: &[f32],
    z: f32,
    s: f32,
    scale: f32,
    g: &mut [f32],
) -> f32 {
    let inv = 1.0 / (2.0 * s * s);
    let mut loss = 0.0f32;
    for i in 0..w.len() {
        let d = t[i] - z;
        let k = (-(d * d) * inv).exp() * dt[i];
        if k == 0.0 {
            continue;
        }
        loss += -(w[i] + DEPTH_LOG_EPS).ln() * k;
        g[i] += scale * (-k / (w[i] + DEPTH_LOG_EPS));
    }
    loss
}

/// mip-NeRF 360 distortion loss of one ray over sample midpoints `m` (sorted) and lengths
/// `ds` in a normalised coordinate: `Σ_{i,j} w_i w_j |m_i − m_j| + ⅓ Σ_i w_i² ds_i`, in O(n).
/// Adds `scale · ∂/∂w_i` to `g` and returns the unscaled loss.
pub fn distortion(w: &[f32], m: &[f32], ds: &[f32], scale: f32, g: &mut [f32]) -> f32 {
    let n = w.len();
    let (mut w_tot, mut wm_tot) = (0f32, 0f32);
    for i in 0..n {
        w_tot += w[i];
        wm_tot += w[i] * m[i];
    }
    let (mut w_before, mut wm_before) = (0f32, 0f32);
    let mut loss = 0f32;
    for i in 0..n {
        let w_after = w_tot - w_before - w[i];
        let wm_after = wm_tot - wm_before - w[i] * m[i];
        // Σ_j w_j |m_i − m_j|
        let s = m[i] * w_before - wm_before + wm_after - m[i] * w_after;
        loss += w[i] * s + w[i] * w[i] * ds[i] / 3.0;
        g[i] += scale * (2.0 * s + 2.0 * w[i] * ds[i] / 3.0);
        w_before += w[i];
        wm_before += w[i] * m[i];
    }
    loss
}
