//! Real spherical harmonics, degrees 0–3 (the gsplat/Inria basis and sign convention), with
//! their derivative with respect to the (unit) direction.
//!
//! Colour of one channel = max(Σ_k coef_k · Y_k(d) + 0.5, 0) with d = normalize(mean − camera
//! centre).

// Negated comparisons are deliberate: they also reject NaN. Index loops read best in
// small fixed-size numeric code.
#![allow(clippy::neg_cmp_op_on_partial_ord, clippy::needless_range_loop)]

use crate::constants::{C0, C1, C2, C3};
use crate::lanes::{c, Lanes, LANES};

/// Number of basis functions up to `degree` (at most 16).
pub const fn basis_len(degree: u32) -> usize {
    ((degree + 1) * (degree + 1)) as usize
}

/// Evaluates the basis up to `degree` (≤ 3) at unit direction `d` into `out[..basis_len]`.
#[inline]
pub fn basis(degree: u32, d: [f64; 3], out: &mut [f64; 16]) {
    let [x, y, z] = d;
    out[0] = C0;
    if degree < 1 {
        return;
    }
    out[1] = -C1 * y;
    out[2] = C1 * z;
    out[3] = -C1 * x;
    if degree < 2 {
        return;
    }
    let (xx, yy, zz) = (x * x, y * y, z * z);
    out[4] = C2[0] * x * y;
    out[5] = C2[1] * y * z;
    out[6] = C2[2] * (2.0 * zz - xx - yy);
    out[7] = C2[3] * x * z;
    out[8] = C2[4] * (xx - yy);
    if degree < 3 {
        return;
    }
    out[9] = C3[0] * y * (3.0 * xx - yy);
    out[10] = C3[1] * x * y * z;
    out[11] = C3[2] * y * (4.0 * zz - xx - yy);
    out[12] = C3[3] * z * (2.0 * zz - 3.0 * xx - 3.0 * yy);
    out[13] = C3[4] * x * (4.0 * zz - xx - yy);
    out[14] = C3[5] * z * (xx - yy);
    out[15] = C3[6] * x * (xx - 3.0 * yy);
}

/// Given dL/dY_k (`g[..basis_len]`), returns dL/dd treating the three components of `d` as
/// independent (the caller projects through the normalisation).
#[inline]
pub fn basis_vjp(degree: u32, d: [f64; 3], g: &[f64; 16]) -> [f64; 3] {
    let [x, y, z] = d;
    let mut gd = [0.0f64; 3];
    if degree < 1 {
        return gd;
    }
    gd[1] -= C1 * g[1];
    gd[2] += C1 * g[2];
    gd[0] -= C1 * g[3];
    if degree < 2 {
        return gd;
    }
    let (xx, yy, zz) = (x * x, y * y, z * z);
    // Y4 = C2[0]·xy
    gd[0] += C2[0] * y * g[4];
    gd[1] += C2[0] * x * g[4];
    // Y5 = C2[1]·yz
    gd[1] += C2[1] * z * g[5];
    gd[2] += C2[1] * y * g[5];
    // Y6 = C2[2]·(2z² − x² − y²)
    gd[0] -= 2.0 * C2[2] * x * g[6];
    gd[1] -= 2.0 * C2[2] * y * g[6];
    gd[2] += 4.0 * C2[2] * z * g[6];
    // Y7 = C2[3]·xz
    gd[0] += C2[3] * z * g[7];
    gd[2] += C2[3] * x * g[7];
    // Y8 = C2[4]·(x² − y²)
    gd[0] += 2.0 * C2[4] * x * g[8];
    gd[1] -= 2.0 * C2[4] * y * g[8];
    if degree < 3 {
        return gd;
    }
    // Y9 = C3[0]·y(3x² − y²)
    gd[0] += 6.0 * C3[0] * x * y * g[9];
    gd[1] += 3.0 * C3[0] * (xx - yy) * g[9];
    // Y10 = C3[1]·xyz
    gd[0] += C3[1] * y * z * g[10];
    gd[1] += C3[1] * x * z * g[10];
    gd[2] += C3[1] * x * y * g[10];
    // Y11 = C3[2]·y(4z² − x² − y²)
    gd[0] -= 2.0 * C3[2] * x * y * g[11];
    gd[1] += C3[2] * (4.0 * zz - xx - 3.0 * yy) * g[11];
    gd[2] += 8.0 * C3[2] * y * z * g[11];
    // Y12 = C3[3]·z(2z² − 3x² − 3y²)
    gd[0] -= 6.0 * C3[3] * x * z * g[12];
    gd[1] -= 6.0 * C3[3] * y * z * g[12];
    gd[2] += C3[3] * (6.0 * zz - 3.0 * xx - 3.0 * yy) * g[12];
    // Y13 = C3[4]·x(4z² − x² − y²)
    gd[0] += C3[4] * (4.0 * zz - 3.0 * xx - yy) * g[13];
    gd[1] -= 2.0 * C3[4] * x * y * g[13];
    gd[2] += 8.0 * C3[4] * x * z * g[13];
    // Y14 = C3[5]·z(x² − y²)
    gd[0] += 2.0 * C3[5] * x * z * g[14];
    gd[1] -= 2.0 * C3[5] * y * z * g[14];
    gd[2] += C3[5] * (xx - yy) * g[14];
    // Y15 = C3[6]·x(x² − 3y²)
    gd[0] += 3.0 * C3[6] * (xx - yy) * g[15];
    gd[1] -= 6.0 * C3[6] * x * y * g[15];
    gd
}

/// Colour of one Gaussian: `coefs` holds `K·3` values (`[k·3 + c]`, K the stored count),
/// `degree` the active degree. Returns the clamped colour; `basis_out` receives the basis.
#[inline]
pub fn eval_color(
    degree: u32,
    coefs: &[f32],
    dir: [f64; 3],
    basis_out: &mut [f64; 16],
) -> [f64; 3] {
    basis(degree, dir, basis_out);
    let n = basis_len(degree);
    let mut c = [0.5f64; 3];
    for k in 0..n {
        for ch in 0..3 {
            c[ch] += coefs[k * 3 + ch] as f64 * basis_out[k];
        }
    }
    [c[0].max(0.0), c[1].max(0.0), c[2].max(0.0)]
}

/// Backward of [`eval_color`]: given dL/d(colour), adds dL/d(coefs) into `g_coefs`
/// (`K·3` values) and returns dL/d(dir) (direction components independent).
pub fn eval_color_vjp(
    degree: u32,
    coefs: &[f32],
    dir: [f64; 3],
    g_color: [f64; 3],
    g_coefs: &mut [f64],
) -> [f64; 3] {
    let mut y = [0.0f64; 16];
    basis(degree, dir, &mut y);
    let n = basis_len(degree);
    // Clamped channels pass no gradient.
    let mut raw = [0.5f64; 3];
    for k in 0..n {
        for ch in 0..3 {
            raw[ch] += coefs[k * 3 + ch] as f64 * y[k];
        }
    }
    let gc = [
        if raw[0] > 0.0 { g_color[0] } else { 0.0 },
        if raw[1] > 0.0 { g_color[1] } else { 0.0 },
        if raw[2] > 0.0 { g_color[2] } else { 0.0 },
    ];
    let mut gy = [0.0f64; 16];
    for k in 0..n {
        let mut s = 0.0;
        for ch in 0..3 {
            g_coefs[k * 3 + ch] += gc[ch] * y[k];
            s += gc[ch] * coefs[k * 3 + ch] as f64;
        }
        gy[k] = s;
    }
    basis_vjp(degree, dir, &gy)
}

/// Backward of [`eval_color`] writing rather than adding: `out[..basis_len·3]` receives
/// dL/d(coefs) as f32 (the values [`eval_color_vjp`] would add to a zeroed f64 buffer, rounded
/// once); returns dL/d(dir) (direction components independent).
#[inline]
pub fn eval_color_vjp_into(
    degree: u32,
    coefs: &[f32],
    dir: [f64; 3],
    g_color: [f64; 3],
    out: &mut [f32],
) -> [f64; 3] {
    let n = basis_len(degree);
    let mut y = [0.0f64; 16];
    basis(degree, dir, &mut y);
    let c = &coefs[..n * 3];
    let out = &mut out[..n * 3];
    let mut raw = [0.5f64; 3];
    for k in 0..n {
        for ch in 0..3 {
            raw[ch] += c[k * 3 + ch] as f64 * y[k];
        }
    }
    let gc = [
        if raw[0] > 0.0 { g_color[0] } else { 0.0 },
        if raw[1] > 0.0 { g_color[1] } else { 0.0 },
        if raw[2] > 0.0 { g_color[2] } else { 0.0 },
    ];
    let mut gy = [0.0f64; 16];
    for k in 0..n {
        for ch in 0..3 {
            out[k * 3 + ch] = (gc[ch] * y[k]) as f32;
        }
        gy[k] = gc[0] * c[k * 3] as f64 + gc[1] * c[k * 3 + 1] as f64 + gc[2] * c[k * 3 + 2] as f64;
    }
    basis_vjp(degree, dir, &gy)
}

/// The first `n` (≤ 48) SH values of Gaussians `idx` (rows of `k` values in `sh`), one row
/// per lane, zero-padded; a full row is a fixed-size copy (no libc call per row).
#[inline(always)]
pub(crate) fn coef_rows(
    sh: &[f32],
    idx: &[usize; LANES],
    k: usize,
    n: usize,
) -> [[f32; 48]; LANES] {
    let mut rows = [[0.0f32; 48]; LANES];
    for (row, &i) in rows.iter_mut().zip(idx) {
        let src = &sh[i * k..i * k + n];
        match <&[f32; 48]>::try_from(src) {
            Ok(full) => *row = *full,
            Err(_) => row[..n].copy_from_slice(src),
        }
    }
    rows
}

/// [`basis`] of eight directions at once (the same operations per lane, so the same bits).
#[inline(always)]
pub(crate) fn basis_lanes<L: Lanes>(degree: u32, d: [L; 3]) -> [L; 16] {
    let [x, y, z] = d;
    let mut out = [c::<L>(0.0); 16];
    out[0] = c(C0);
    if degree < 1 {
        return out;
    }
    out[1] = y * -C1;
    out[2] = z * C1;
    out[3] = x * -C1;
    if degree < 2 {
        return out;
    }
    let (xx, yy, zz) = (x * x, y * y, z * z);
    out[4] = x * C2[0] * y;
    out[5] = y * C2[1] * z;
    out[6] = (zz * 2.0 - xx - yy) * C2[2];
    out[7] = x * C2[3] * z;
    out[8] = (xx - yy) * C2[4];
    if degree < 3 {
        return out;
    }
    out[9] = y * C3[0] * (xx * 3.0 - yy);
    out[10] = x * C3[1] * y * z;
    out[11] = y * C3[2] * (zz * 4.0 - xx - yy);
    out[12] = z * C3[3] * (zz * 2.0 - xx * 3.0 - yy * 3.0);
    out[13] = x * C3[4] * (zz * 4.0 - xx - yy);
    out[14] = z * C3[5] * (xx - yy);
    out[15] = x * C3[6] * (xx - yy * 3.0);
    out
}

/// [`eval_color`] of eight Gaussians (coefficients `coefs(k)` = lane values of coefficient
/// `k`, in the `sh` layout order), the same operations per lane.
#[inline(always)]
pub(crate) fn eval_color_lanes<L: Lanes>(
    degree: u32,
    coefs: impl Fn(usize) -> L,
    dir: [L; 3],
) -> [L; 3] {
    let y = basis_lanes(degree, dir);
    let n = basis_len(degree);
    let mut col = [c::<L>(0.5); 3];
    for k in 0..n {
        for ch in 0..3 {
            col[ch] = col[ch] + coefs(k * 3 + ch) * y[k];
        }
    }
    let zero = c::<L>(0.0);
    [col[0].max(zero), col[1].max(zero), col[2].max(zero)]
}

/// [`basis_vjp`] of eight directions at once (the same operations per lane).
#[inline(always)]
pub(crate) fn basis_vjp_lanes<L: Lanes>(degree: u32, d: [L; 3], g: &[L; 16]) -> [L; 3] {
    let [x, y, z] = d;
    let mut gd = [c::<L>(0.0); 3];
    if degree < 1 {
        return gd;
    }
    gd[1] = gd[1] - g[1] * C1;
    gd[2] = gd[2] + g[2] * C1;
    gd[0] = gd[0] - g[3] * C1;
    if degree < 2 {
        return gd;
    }
    let (xx, yy, zz) = (x * x, y * y, z * z);
    gd[0] = gd[0] + y * C2[0] * g[4];
    gd[1] = gd[1] + x * C2[0] * g[4];
    gd[1] = gd[1] + z * C2[1] * g[5];
    gd[2] = gd[2] + y * C2[1] * g[5];
    gd[0] = gd[0] - x * (2.0 * C2[2]) * g[6];
    gd[1] = gd[1] - y * (2.0 * C2[2]) * g[6];
    gd[2] = gd[2] + z * (4.0 * C2[2]) * g[6];
    gd[0] = gd[0] + z * C2[3] * g[7];
    gd[2] = gd[2] + x * C2[3] * g[7];
    gd[0] = gd[0] + x * (2.0 * C2[4]) * g[8];
    gd[1] = gd[1] - y * (2.0 * C2[4]) * g[8];
    if degree < 3 {
        return gd;
    }
    gd[0] = gd[0] + x * (6.0 * C3[0]) * y * g[9];
    gd[1] = gd[1] + (xx - yy) * (3.0 * C3[0]) * g[9];
    gd[0] = gd[0] + y * C3[1] * z * g[10];
    gd[1] = gd[1] + x * C3[1] * z * g[10];
    gd[2] = gd[2] + x * C3[1] * y * g[10];
    gd[0] = gd[0] - x * (2.0 * C3[2]) * y * g[11];
    gd[1] = gd[1] + (zz * 4.0 - xx - yy * 3.0) * C3[2] * g[11];
    gd[2] = gd[2] + y * (8.0 * C3[2]) * z * g[11];
    gd[0] = gd[0] - x * (6.0 * C3[3]) * z * g[12];
    gd[1] = gd[1] - y * (6.0 * C3[3]) * z * g[12];
    gd[2] = gd[2] + (zz * 6.0 - xx * 3.0 - yy * 3.0) * C3[3] * g[12];
    gd[0] = gd[0] + (zz * 4.0 - xx * 3.0 - yy) * C3[4] * g[13];
    gd[1] = gd[1] - x * (2.0 * C3[4]) * y * g[13];
    gd[2] = gd[2] + x * (8.0 * C3[4]) * z * g[13];
    gd[0] = gd[0] + x * (2.0 * C3[5]) * z * g[14];
    gd[1] = gd[1] - y * (2.0 * C3[5]) * z * g[14];
    gd[2] = gd[2] + (xx - yy) * C3[5] * g[14];
    gd[0] = gd[0] + (xx - yy) * (3.0 * C3[6]) * g[15];
    gd[1] = gd[1] - x * (6.0 * C3[6]) * y * g[15];
    gd
}

/// [`eval_color_vjp_into`] of eight Gaussians: coefficient lanes `coefs(q)` (the `sh` layout
/// order), colour gradients `g_color`; `out(q, lanes)` receives the coefficient gradients
/// `q < basis_len·3` (rounded to f32 per lane by the caller); returns dL/d(direction).
#[inline(always)]
pub(crate) fn eval_color_vjp_lanes<L: Lanes>(
    degree: u32,
    coefs: impl Fn(usize) -> L,
    dir: [L; 3],
    g_color: [L; 3],
    mut out: impl FnMut(usize, L),
) -> [L; 3] {
    let n = basis_len(degree);
    let y = basis_lanes(degree, dir);
    let mut raw = [c::<L>(0.5); 3];
    for k in 0..n {
        for ch in 0..3 {
            raw[ch] = raw[ch] + coefs(k * 3 + ch) * y[k];
        }
    }
    let zero = c::<L>(0.0);
    let gc = [
        L::select(raw[0].gt(zero), g_color[0], zero),
        L::select(raw[1].gt(zero), g_color[1], zero),
        L::select(raw[2].gt(zero), g_color[2], zero),
    ];
    let mut gy = [zero; 16];
    for k in 0..n {
        for ch in 0..3 {
            out(k * 3 + ch, gc[ch] * y[k]);
        }
        gy[k] = gc[0] * coefs(k * 3) + gc[1] * coefs(k * 3 + 1) + gc[2] * coefs(k * 3 + 2);
    }
    basis_vjp_lanes(degree, dir, &gy)
}

#[cfg(test)]
mod tests {
    use super::*;
    use augsplat_core::linalg::normalize;

    fn random3(rng: &mut augsplat_core::Rng) -> [f64; 3] {
        [
            rng.uniform(-1.0, 1.0),
            rng.uniform(-1.0, 1.0),
            rng.uniform(-1.0, 1.0),
        ]
    }

    /// Eight 3-vectors as three lane vectors.
    fn lanes3(v: &[[f64; 3]]) -> [crate::lanes::P8; 3] {
        [0, 1, 2].map(|a| crate::lanes::P8(std::array::from_fn(|l| v[l][a])))
    }

    #[test]
    fn lane_colour_backward_equals_the_scalar_one_bit_for_bit() {
        use crate::lanes::P8;
        let mut rng = augsplat_core::Rng::new(10);
        for degree in 0..=3 {
            let dirs: Vec<[f64; 3]> = (0..8).map(|_| normalize(random3(&mut rng))).collect();
            // Some colours clamp at 0 (their gradient is cut).
            let coefs: Vec<f32> = (0..8 * 48).map(|_| rng.uniform(-1.5, 1.0) as f32).collect();
            let gcol: Vec<[f64; 3]> = (0..8).map(|_| random3(&mut rng)).collect();
            let (d, g) = (lanes3(&dirs), lanes3(&gcol));
            let mut outl = [[0.0f32; 48]; 8];
            let gdl = eval_color_vjp_lanes(
                degree,
                |q| P8(std::array::from_fn(|l| coefs[l * 48 + q] as f64)),
                d,
                g,
                |q, v| {
                    for l in 0..8 {
                        outl[l][q] = v.0[l] as f32;
                    }
                },
            );
            for l in 0..8 {
                let mut out = [0.0f32; 48];
                let gd = eval_color_vjp_into(
                    degree,
                    &coefs[l * 48..(l + 1) * 48],
                    dirs[l],
                    gcol[l],
                    &mut out,
                );
                let nb = basis_len(degree) * 3;
                assert_eq!(out[..nb], outl[l][..nb], "degree {degree}");
                for a in 0..3 {
                    assert_eq!(gd[a].to_bits(), gdl[a].0[l].to_bits(), "degree {degree}");
                }
            }
        }
    }

    #[test]
    fn lane_basis_and_colour_equal_the_scalar_ones_bit_for_bit() {
        use crate::lanes::P8;
        let mut rng = augsplat_core::Rng::new(9);
        for degree in 0..=3 {
            let dirs: Vec<[f64; 3]> = (0..8).map(|_| normalize(random3(&mut rng))).collect();
            let coefs: Vec<f32> = (0..8 * 48).map(|_| rng.uniform(-1.0, 1.0) as f32).collect();
            let d = lanes3(&dirs);
            let yl = basis_lanes(degree, d);
            let cl = eval_color_lanes(
                degree,
                |q| P8(std::array::from_fn(|l| coefs[l * 48 + q] as f64)),
                d,
            );
            for l in 0..8 {
                let mut y = [0.0; 16];
                basis(degree, dirs[l], &mut y);
                for k in 0..basis_len(degree) {
                    assert_eq!(y[k].to_bits(), yl[k].0[l].to_bits(), "degree {degree} Y{k}");
                }
                let col = eval_color(degree, &coefs[l * 48..(l + 1) * 48], dirs[l], &mut y);
                for ch in 0..3 {
                    // Equal values (a zero's sign may differ: `max` rules).
                    assert_eq!(col[ch], cl[ch].0[l], "degree {degree}");
                }
            }
        }
    }

    #[test]
    fn basis_vjp_matches_finite_differences() {
        let d = [0.3f64, -0.5, 0.81];
        for k in 0..16 {
            let mut g = [0.0; 16];
            g[k] = 1.0;
            let an = basis_vjp(3, d, &g);
            for a in 0..3 {
                let h = 1e-6;
                let mut dp = d;
                let mut dm = d;
                dp[a] += h;
                dm[a] -= h;
                let (mut yp, mut ym) = ([0.0; 16], [0.0; 16]);
                basis(3, dp, &mut yp);
                basis(3, dm, &mut ym);
                let fd = (yp[k] - ym[k]) / (2.0 * h);
                assert!(
                    (fd - an[a]).abs() < 1e-7,
                    "Y{k} d{a}: fd {fd} analytic {}",
                    an[a]
                );
            }
        }
    }

    #[test]
    fn vjp_into_matches_the_accumulating_vjp() {
        let mut rng = augsplat_core::Rng::new(3);
        for degree in 0..=3 {
            let coefs: Vec<f32> = (0..48).map(|_| rng.uniform(-0.6, 0.6) as f32).collect();
            let d = [0.3f64, -0.5, 0.81];
            let n = (d[0] * d[0] + d[1] * d[1] + d[2] * d[2]).sqrt();
            let d = [d[0] / n, d[1] / n, d[2] / n];
            let g = [0.7, -0.2, 0.4];
            let mut acc = [0.0f64; 48];
            let ga = eval_color_vjp(degree, &coefs, d, g, &mut acc);
            let mut out = [f32::NAN; 48];
            let gb = eval_color_vjp_into(degree, &coefs, d, g, &mut out);
            let nb = basis_len(degree) * 3;
            for q in 0..nb {
                assert_eq!(out[q], acc[q] as f32);
            }
            for a in 0..3 {
                assert!((ga[a] - gb[a]).abs() <= 1e-12 * ga[a].abs().max(1.0));
            }
        }
    }
}
