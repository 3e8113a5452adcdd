//! Naive f64 references of every kernel, written from the maths and independent of the fast
//! f32 code paths (no batching, no shared helpers beyond the layouts). Tests compare the fast
//! kernels' outputs to these and their analytic gradients to central finite differences of
//! these.

use crate::constants::{GEO_FEAT_DIM, HASH_PRIMES, SH_COMPONENTS, TRUNC_EXP_MAX, TRUNC_EXP_MIN};
use crate::field::Field;
use crate::hashgrid::HashGrid;
use crate::mlp::Mlp;

/// Hash encoding of one point in `[0, 1]³` (output `level·F + f`).
pub fn hash_encode(grid: &HashGrid, table: &[f64], p: [f64; 3]) -> Vec<f64> {
    let f = grid.features();
    let mut out = vec![0f64; grid.output_dim()];
    for l in 0..grid.levels() {
        let res = grid.resolutions[l] as u64;
        let size = grid.sizes[l] as u64;
        let mut base = [0u64; 3];
        let mut fr = [0f64; 3];
        for a in 0..3 {
            let x = p[a].clamp(0.0, 1.0) * res as f64;
            let fl = x.floor().min(res as f64 - 1.0).max(0.0);
            base[a] = fl as u64;
            fr[a] = x - fl;
        }
        for dz in 0..2u64 {
            for dy in 0..2u64 {
                for dx in 0..2u64 {
                    let (x, y, z) = (base[0] + dx, base[1] + dy, base[2] + dz);
                    let idx = if grid.dense[l] {
                        x + y * (res + 1) + z * (res + 1) * (res + 1)
                    } else {
                        let h = (x * HASH_PRIMES[0] as u64)
                            ^ (y * HASH_PRIMES[1] as u64)
                            ^ (z * HASH_PRIMES[2] as u64);
                        (h % (1u64 << 32)) % size
                    };
                    let w = (if dx == 1 { fr[0] } else { 1.0 - fr[0] })
                        * (if dy == 1 { fr[1] } else { 1.0 - fr[1] })
                        * (if dz == 1 { fr[2] } else { 1.0 - fr[2] });
                    for k in 0..f {
                        out[l * f + k] += w * table[grid.offsets[l] + idx as usize * f + k];
                    }
                }
            }
        }
    }
    out
}

/// MLP forward for one input vector (ReLU between layers, linear output).
pub fn mlp_forward(mlp: &Mlp, params: &[f64], x: &[f64]) -> Vec<f64> {
    let mut a = x.to_vec();
    let mut off = 0;
    for (l, s) in mlp.layers.iter().enumerate() {
        let mut y = vec![0f64; s.out];
        for o in 0..s.out {
            let mut acc = params[off + s.inp * s.out + o];
            for i in 0..s.inp {
                acc += params[off + o * s.inp + i] * a[i];
            }
            y[o] = if l + 1 < mlp.layers.len() {
                acc.max(0.0)
            } else {
                acc
            };
        }
        off += s.params();
        a = y;
    }
    a
}

/// SH basis (degree 0–3) in f64 from the closed forms.
pub fn sh(d: [f64; 3]) -> [f64; SH_COMPONENTS] {
    let [x, y, z] = d;
    let pi = std::f64::consts::PI;
    let c0 = 0.5 * (1.0 / pi).sqrt();
    let c1 = (3.0 / (4.0 * pi)).sqrt();
    let c2a = 0.5 * (15.0 / pi).sqrt();
    let c2b = 0.25 * (5.0 / pi).sqrt();
    let c2c = 0.25 * (15.0 / pi).sqrt();
    let c3a = 0.25 * (35.0 / (2.0 * pi)).sqrt();
    let c3b = 0.5 * (105.0 / pi).sqrt();
    let c3c = 0.25 * (21.0 / (2.0 * pi)).sqrt();
    let c3d = 0.25 * (7.0 / pi).sqrt();
    let c3e = 0.25 * (105.0 / pi).sqrt();
    [
        c0,
        c1 * y,
        c1 * z,
        c1 * x,
        c2a * x * y,
        c2a * y * z,
        c2b * (3.0 * z * z - 1.0),
        c2a * x * z,
        c2c * (x * x - y * y),
        c3a * y * (3.0 * x * x - y * y),
        c3b * x * y * z,
        c3c * y * (5.0 * z * z - 1.0),
        c3d * z * (5.0 * z * z - 3.0),
        c3c * x * (5.0 * z * z - 1.0),
        c3e * z * (x * x - y * y),
        c3a * x * (x * x - 3.0 * y * y),
    ]
}

/// Density and colour of one sample: `p` in `[0, 1]³` hash coordinates, unit direction `d`,
/// appearance embedding `emb` (length `appearance_dim`).
pub fn field_sample(
    field: &Field,
    params: &[f64],
    p: [f64; 3],
    d: [f64; 3],
    emb: &[f64],
) -> (f64, [f64; 3]) {
    let enc = hash_encode(&field.grid, &params[..field.density_offset], p);
    let h = mlp_forward(
        &field.density,
        &params[field.density_offset..field.color_offset],
        &enc,
    );
    let sigma = h[0].clamp(TRUNC_EXP_MIN as f64, TRUNC_EXP_MAX as f64).exp();
    let mut x = h[1..1 + GEO_FEAT_DIM].to_vec();
    x.extend_from_slice(&sh(d));
    x.extend_from_slice(emb);
    let c = mlp_forward(
        &field.color,
        &params[field.color_offset..field.embedding_offset],
        &x,
    );
    let s = |v: f64| 1.0 / (1.0 + (-v).exp());
    (sigma, [s(c[0]), s(c[1]), s(c[2])])
}

/// One ray's volume rendering: colour over the first `n_color` samples, opacity and
/// premultiplied depth over all; returns (pixel colour with background, A, Σ w t, weights).
pub fn render_ray(
    sigma: &[f64],
    dt: &[f64],
    t: &[f64],
    rgb: &[[f64; 3]],
    n_color: usize,
    bg: [f64; 3],
) -> ([f64; 3], f64, f64, Vec<f64>) {
    let n = sigma.len();
    let mut w = vec![0f64; n];
    for i in 0..n {
        let mut tr = 1.0;
        for j in 0..i {
            tr *= (-sigma[j] * dt[j]).exp();
        }
        w[i] = tr * (1.0 - (-sigma[i] * dt[i]).exp());
    }
    let a: f64 = w.iter().sum();
    let dd: f64 = w.iter().zip(t).map(|(w, t)| w * t).sum();
    let mut c = [0f64; 3];
    for i in 0..n_color {
        for k in 0..3 {
            c[k] += w[i] * rgb[i][k];
        }
    }
    for k in 0..3 {
        c[k] += (1.0 - a) * bg[k];
    }
    (c, a, dd, w)
}

/// DS-NeRF depth loss of one ray (see [`crate::volume::ds_nerf_depth`]).
pub fn ds_nerf_depth(w: &[f64], t: &[f64], dt: &[f64], z: f64, s: f64) -> f64 {
    let eps = crate::constants::DEPTH_LOG_EPS as f64;
    (0..w.len())
        .map(|i| -(w[i] + eps).ln() * (-(t[i] - z).powi(2) / (2.0 * s * s)).exp() * dt[i])
        .sum()
}

/// Distortion loss of one ray, the O(n²) double sum.
pub fn distortion(w: &[f64], m: &[f64], ds: &[f64]) -> f64 {
    let mut l = 0.0;
    for i in 0..w.len() {
        for j in 0..w.len() {
            l += w[i] * w[j] * (m[i] - m[j]).abs();
        }
        l += w[i] * w[i] * ds[i] / 3.0;
    }
    l
}
