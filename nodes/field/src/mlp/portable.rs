//! The portable twin of the dense-layer kernels: plain Rust over [`LANES`]-wide column
//! vectors (the inner loops auto-vectorise), the readable statement of the operation order
//! every variant keeps.
//!
//! `FMA` selects fused multiply-adds (`mul_add`). The dispatch runs these kernels *without*
//! them in the portable tier; with them they give exactly the bits of the AVX2 kernels
//! ([`super::avx2`]), which is what the tests compare.

use super::{Gemm, Store, WeightGrad, LANES};

/// `a·b + c`, fused when `FMA` (the twin of the AVX2 kernels, which fuse every step).
#[inline(always)]
fn fmadd<const FMA: bool>(a: f32, b: f32, c: f32) -> f32 {
    if FMA {
        a.mul_add(b, c)
    } else {
        a * b + c
    }
}

#[inline(always)]
fn lanes(s: &[f32], at: usize) -> &[f32; LANES] {
    s[at..at + LANES].try_into().expect("lane slice")
}

/// One forward tile of `g`: outputs `o0..o0 + OB` × columns `base..base + T·LANES`, each
/// output summing `b + Σ_i w_i x_i` in `i` order, then stored into `y` (rows `ldy` apart) as
/// `g.store` says.
#[inline(always)]
fn fwd_block<const OB: usize, const T: usize, const FMA: bool>(
    g: Gemm<'_>,
    y: &mut [f32],
    ldy: usize,
    o0: usize,
    base: usize,
) {
    let Gemm {
        w,
        b,
        x,
        ldx,
        inp,
        store,
        ..
    } = g;
    let mut acc = [[[0f32; LANES]; T]; OB];
    if let Some(b) = b {
        for k in 0..OB {
            acc[k] = [[b[o0 + k]; LANES]; T];
        }
    }
    for i in 0..inp {
        let mut xv = [[0f32; LANES]; T];
        for t in 0..T {
            xv[t] = *lanes(x, i * ldx + base + t * LANES);
        }
        for k in 0..OB {
            let wk = w[(o0 + k) * inp + i];
            for t in 0..T {
                for l in 0..LANES {
                    acc[k][t][l] = fmadd::<FMA>(wk, xv[t][l], acc[k][t][l]);
                }
            }
        }
    }
    for k in 0..OB {
        for t in 0..T {
            let c = base + t * LANES;
            let at = (o0 + k) * ldy + c;
            let row = &mut y[at..at + LANES];
            match store {
                Store::Linear => row.copy_from_slice(&acc[k][t]),
                Store::Relu => {
                    for l in 0..LANES {
                        row[l] = acc[k][t][l].max(0.0);
                    }
                }
                Store::MaskPositive(m, ldm) => {
                    let mr = lanes(m, (o0 + k) * ldm + c);
                    for l in 0..LANES {
                        row[l] = if mr[l] > 0.0 { acc[k][t][l] } else { 0.0 };
                    }
                }
            }
        }
    }
}

/// Forward-style product `g` into `y` (rows `ldy` apart) over the columns `< g.ncols`:
/// tiles of `OB` outputs × two (or, at the end, one) column vectors.
#[inline(always)]
pub(super) fn fwd_body<const OB: usize, const FMA: bool>(g: Gemm<'_>, y: &mut [f32], ldy: usize) {
    let (out, ncols) = (g.out, g.ncols);
    let mut base = 0;
    while base < ncols {
        let two = base + 2 * LANES <= ncols;
        let mut o0 = 0;
        while o0 + OB <= out {
            if two {
                fwd_block::<OB, 2, FMA>(g, y, ldy, o0, base);
            } else {
                fwd_block::<OB, 1, FMA>(g, y, ldy, o0, base);
            }
            o0 += OB;
        }
        while o0 < out {
            if two {
                fwd_block::<1, 2, FMA>(g, y, ldy, o0, base);
            } else {
                fwd_block::<1, 1, FMA>(g, y, ldy, o0, base);
            }
            o0 += 1;
        }
        base += if two { 2 * LANES } else { LANES };
    }
}

/// Portable weight-gradient accumulation (same contract as
/// [`super::avx2::backward_weights`]): columns are transposed in blocks, then every
/// `dwp` row is updated column after column (the inner loop over inputs vectorises).
#[inline(always)]
pub(super) fn dw_body<const FMA: bool>(
    g: WeightGrad<'_>,
    dwp: &mut [f32],
    lane_sums: &mut [f32],
    xt: &mut Vec<f32>,
) {
    let WeightGrad {
        dy,
        lddy,
        x,
        ldx,
        inp,
        out,
        ncols,
    } = g;
    let inp_pad = inp.div_ceil(LANES) * LANES;
    const KC: usize = 64;
    xt.resize(KC * inp_pad, 0.0);
    let mut kb = 0;
    while kb < ncols {
        let kc = KC.min(ncols - kb);
        for i in 0..inp_pad {
            for n in 0..kc {
                xt[n * inp_pad + i] = if i < inp { x[i * ldx + kb + n] } else { 0.0 };
            }
        }
        for o in 0..out {
            let row = &mut dwp[o * inp_pad..(o + 1) * inp_pad];
            for n in 0..kc {
                let d = dy[o * lddy + kb + n];
                let xr = &xt[n * inp_pad..(n + 1) * inp_pad];
                for i in 0..inp_pad {
                    row[i] = fmadd::<FMA>(d, xr[i], row[i]);
                }
            }
        }
        kb += kc;
    }
    for o in 0..out {
        let acc: &mut [f32; LANES] = (&mut lane_sums[o * LANES..(o + 1) * LANES])
            .try_into()
            .expect("lane sums");
        for base in (0..ncols).step_by(LANES) {
            let d = lanes(dy, o * lddy + base);
            for l in 0..LANES {
                acc[l] += d[l];
            }
        }
    }
}

/// Horizontal sum in a fixed pairwise order.
#[inline(always)]
pub(super) fn hsum(a: &[f32; LANES]) -> f32 {
    let mut h = [0f32; 8];
    for l in 0..8 {
        h[l] = a[l] + a[l + 8];
    }
    let q = [h[0] + h[4], h[1] + h[5], h[2] + h[6], h[3] + h[7]];
    (q[0] + q[2]) + (q[1] + q[3])
}
