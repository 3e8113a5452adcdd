//! AVX-512 register-blocked kernels for the dense layers of [`crate::mlp`] (x86-64 only).
//!
//! - Forward / input gradient: a tile of up to 8 outputs × 48 batch columns lives in 24 zmm
//!   accumulators; every step of the reduction loads three column vectors and broadcasts one
//!   weight per output (an embedded-broadcast FMA operand). Bias, ReLU or the ReLU mask of the
//!   layer below are applied in the store. Each output sums `b + Σ_i w_i x_i` in `i` order
//!   with fused multiply-adds — the same operations, hence the same bits, as the previous
//!   auto-vectorised AVX-512 path.
//! - Weight gradient `dW = δ·Xᵀ`: the batch is cut into blocks of `kc` columns; each block of
//!   `X` is transposed (16×16 in-register transposes) to sample-major rows, then a tile of up
//!   to 6 outputs × 64 inputs accumulates in registers, one sample after the other. Every
//!   weight gradient is therefore the sequential fused sum over the batch in column order,
//!   independent of block sizes.
//!
//! The callers check slice lengths; these functions are `unsafe` because they require
//! AVX-512F and read through raw pointers within those checked bounds.

use std::arch::x86_64::*;

use crate::mlp::Store;

/// Store modes of the forward tile (const generic so the store loop is fully unrolled).
const LINEAR: u8 = 0;
const RELU: u8 = 1;
const MASK: u8 = 2;

#[inline(always)]
#[allow(clippy::too_many_arguments)]
unsafe fn fwd_tile<const OB: usize, const T: usize, const MODE: u8>(
    w: *const f32,
    b: Option<*const f32>,
    x: *const f32,
    y: *mut f32,
    mask: *const f32,
    inp: usize,
    o0: usize,
    ld: Strides,
    base: usize,
    prefetch_next: bool,
) {
    // Bring the tile's output (and mask) lines in while the reduction runs.
    for k in 0..OB {
        for t in 0..T {
            let c = base + 16 * t;
            _mm_prefetch::<_MM_HINT_T0>(y.add((o0 + k) * ld.y + c) as *const i8);
            if MODE == MASK {
                _mm_prefetch::<_MM_HINT_T0>(mask.add((o0 + k) * ld.m + c) as *const i8);
            }
        }
    }
    let mut acc = [[_mm512_setzero_ps(); T]; OB];
    if let Some(b) = b {
        for k in 0..OB {
            let bv = _mm512_set1_ps(*b.add(o0 + k));
            for t in 0..T {
                acc[k][t] = bv;
            }
        }
    }
    let wp = w.add(o0 * inp);
    let xp = x.add(base);
    for i in 0..inp {
        let mut xv = [_mm512_setzero_ps(); T];
        for t in 0..T {
            xv[t] = _mm512_loadu_ps(xp.add(i * ld.x + 16 * t));
        }
        if prefetch_next {
            // The next column panel (the row stride defeats the hardware prefetcher).
            for t in 0..3 {
                _mm_prefetch::<_MM_HINT_T0>(xp.add(i * ld.x + 16 * (T + t)) as *const i8);
            }
        }
        for k in 0..OB {
            let wk = _mm512_set1_ps(*wp.add(k * inp + i));
            for t in 0..T {
                acc[k][t] = _mm512_fmadd_ps(wk, xv[t], acc[k][t]);
            }
        }
    }
    let zero = _mm512_setzero_ps();
    for k in 0..OB {
        for t in 0..T {
            let c = base + 16 * t;
            let v = if MODE == RELU {
                // max(acc, 0) returns the second operand (0) when acc is NaN.
                _mm512_max_ps(acc[k][t], zero)
            } else if MODE == MASK {
                let mv = _mm512_loadu_ps(mask.add((o0 + k) * ld.m + c));
                let keep = _mm512_cmp_ps_mask::<_CMP_GT_OQ>(mv, zero);
                _mm512_maskz_mov_ps(keep, acc[k][t])
            } else {
                acc[k][t]
            };
            _mm512_storeu_ps(y.add((o0 + k) * ld.y + c), v);
        }
    }
}

#[inline(always)]
#[allow(clippy::too_many_arguments)]
unsafe fn fwd_columns<const T: usize, const MODE: u8>(
    w: *const f32,
    b: Option<*const f32>,
    x: *const f32,
    y: *mut f32,
    mask: *const f32,
    inp: usize,
    out: usize,
    ld: Strides,
    ncols: usize,
    base: usize,
) {
    // Prefetch the next panel during the first tile (if there is a next panel).
    let pf = base + 16 * T < ncols;
    let mut o0 = 0;
    while o0 + 8 <= out {
        fwd_tile::<8, T, MODE>(w, b, x, y, mask, inp, o0, ld, base, pf && o0 == 0);
        o0 += 8;
    }
    if o0 + 4 <= out {
        fwd_tile::<4, T, MODE>(w, b, x, y, mask, inp, o0, ld, base, pf && o0 == 0);
        o0 += 4;
    }
    if o0 + 2 <= out {
        fwd_tile::<2, T, MODE>(w, b, x, y, mask, inp, o0, ld, base, pf && o0 == 0);
        o0 += 2;
    }
    if o0 < out {
        fwd_tile::<1, T, MODE>(w, b, x, y, mask, inp, o0, ld, base, pf && o0 == 0);
    }
}

#[inline(always)]
#[allow(clippy::too_many_arguments)]
unsafe fn fwd_all<const MODE: u8>(
    w: *const f32,
    b: Option<*const f32>,
    x: *const f32,
    y: *mut f32,
    mask: *const f32,
    inp: usize,
    out: usize,
    ld: Strides,
    ncols: usize,
) {
    let mut base = 0;
    while base < ncols {
        match (ncols - base) / 16 {
            1 => {
                fwd_columns::<1, MODE>(w, b, x, y, mask, inp, out, ld, ncols, base);
                base += 16;
            }
            2 => {
                fwd_columns::<2, MODE>(w, b, x, y, mask, inp, out, ld, ncols, base);
                base += 32;
            }
            _ => {
                fwd_columns::<3, MODE>(w, b, x, y, mask, inp, out, ld, ncols, base);
                base += 48;
            }
        }
    }
}

/// Row strides of the forward kernel's operands.
#[derive(Clone, Copy)]
struct Strides {
    x: usize,
    y: usize,
    m: usize,
}

/// `y[o][c] = store(b[o] + Σ_i w[o·inp + i] · x[i][c])` for columns `c < ncols` of
/// channel-major operands (`x` rows `ldx` apart, `y` rows `ldy` apart, a mask's rows its own
/// stride apart).
///
/// # Safety
/// AVX-512F must be available; `ncols` is a multiple of 16; `w.len() ≥ out·inp`,
/// `b.len() ≥ out`, and every row `r` read or written lies inside its slice
/// (`r·ld + ncols ≤ len`).
#[target_feature(enable = "avx512f")]
#[allow(clippy::too_many_arguments)]
pub(crate) unsafe fn forward(
    w: &[f32],
    b: Option<&[f32]>,
    x: &[f32],
    ldx: usize,
    y: &mut [f32],
    ldy: usize,
    inp: usize,
    out: usize,
    ncols: usize,
    store: Store<'_>,
) {
    let (wp, bp, xp, yp) = (
        w.as_ptr(),
        b.map(|b| b.as_ptr()),
        x.as_ptr(),
        y.as_mut_ptr(),
    );
    let mut ld = Strides {
        x: ldx,
        y: ldy,
        m: 0,
    };
    match store {
        Store::Linear => fwd_all::<LINEAR>(wp, bp, xp, yp, std::ptr::null(), inp, out, ld, ncols),
        Store::Relu => fwd_all::<RELU>(wp, bp, xp, yp, std::ptr::null(), inp, out, ld, ncols),
        Store::MaskPositive(m, ldm) => {
            ld.m = ldm;
            fwd_all::<MASK>(wp, bp, xp, yp, m.as_ptr(), inp, out, ld, ncols)
        }
    }
}

/// Transposes a 16×16 block: `rows[r][c]` → `out[c][r]`.
#[inline(always)]
unsafe fn transpose16(r: [__m512; 16]) -> [__m512; 16] {
    // 32-bit interleave of row pairs, then 64-bit interleave of pair pairs: u[4g + c] holds,
    // in 128-bit lane q, column 4q + c of rows 4g..4g + 3.
    let mut t = [_mm512_setzero_ps(); 16];
    for p in 0..8 {
        t[2 * p] = _mm512_unpacklo_ps(r[2 * p], r[2 * p + 1]);
        t[2 * p + 1] = _mm512_unpackhi_ps(r[2 * p], r[2 * p + 1]);
    }
    let mut u = [_mm512_setzero_ps(); 16];
    for g in 0..4 {
        let (a0, a1, b0, b1) = (
            _mm512_castps_pd(t[4 * g]),
            _mm512_castps_pd(t[4 * g + 1]),
            _mm512_castps_pd(t[4 * g + 2]),
            _mm512_castps_pd(t[4 * g + 3]),
        );
        u[4 * g] = _mm512_castpd_ps(_mm512_unpacklo_pd(a0, b0));
        u[4 * g + 1] = _mm512_castpd_ps(_mm512_unpackhi_pd(a0, b0));
        u[4 * g + 2] = _mm512_castpd_ps(_mm512_unpacklo_pd(a1, b1));
        u[4 * g + 3] = _mm512_castpd_ps(_mm512_unpackhi_pd(a1, b1));
    }
    // Gather lane q of u[c], u[4 + c], u[8 + c], u[12 + c] into column 4q + c.
    let mut o = [_mm512_setzero_ps(); 16];
    for c in 0..4 {
        let w_lo = _mm512_shuffle_f32x4::<0x44>(u[c], u[4 + c]);
        let w_hi = _mm512_shuffle_f32x4::<0xEE>(u[c], u[4 + c]);
        let z_lo = _mm512_shuffle_f32x4::<0x44>(u[8 + c], u[12 + c]);
        let z_hi = _mm512_shuffle_f32x4::<0xEE>(u[8 + c], u[12 + c]);
        o[c] = _mm512_shuffle_f32x4::<0x88>(w_lo, z_lo);
        o[4 + c] = _mm512_shuffle_f32x4::<0xDD>(w_lo, z_lo);
        o[8 + c] = _mm512_shuffle_f32x4::<0x88>(w_hi, z_hi);
        o[12 + c] = _mm512_shuffle_f32x4::<0xDD>(w_hi, z_hi);
    }
    o
}

/// Test hook: transposes a 16×16 row-major block.
#[cfg(test)]
///
/// # Safety
/// AVX-512F must be available.
#[target_feature(enable = "avx512f")]
pub(crate) unsafe fn transpose16_slice(src: &[f32; 256], dst: &mut [f32; 256]) {
    let mut r = [_mm512_setzero_ps(); 16];
    for i in 0..16 {
        r[i] = _mm512_loadu_ps(src.as_ptr().add(16 * i));
    }
    let o = transpose16(r);
    for i in 0..16 {
        _mm512_storeu_ps(dst.as_mut_ptr().add(16 * i), o[i]);
    }
}

#[inline(always)]
#[allow(clippy::too_many_arguments)]
unsafe fn dw_tile<const OB: usize, const IV: usize>(
    dy: *const f32,
    xt: *const f32,
    dwp: *mut f32,
    inp_pad: usize,
    o0: usize,
    i0: usize,
    lddy: usize,
    kb: usize,
    kc: usize,
) {
    let mut acc = [[_mm512_setzero_ps(); IV]; OB];
    for k in 0..OB {
        for v in 0..IV {
            acc[k][v] = _mm512_loadu_ps(dwp.add((o0 + k) * inp_pad + i0 + 16 * v));
        }
    }
    let dyp = dy.add(o0 * lddy + kb);
    for n in 0..kc {
        let xr = xt.add(n * inp_pad + i0);
        let mut xv = [_mm512_setzero_ps(); IV];
        for v in 0..IV {
            xv[v] = _mm512_loadu_ps(xr.add(16 * v));
        }
        for k in 0..OB {
            let d = _mm512_set1_ps(*dyp.add(k * lddy + n));
            for v in 0..IV {
                acc[k][v] = _mm512_fmadd_ps(d, xv[v], acc[k][v]);
            }
        }
    }
    for k in 0..OB {
        for v in 0..IV {
            _mm512_storeu_ps(dwp.add((o0 + k) * inp_pad + i0 + 16 * v), acc[k][v]);
        }
    }
}

#[inline(always)]
#[allow(clippy::too_many_arguments)]
unsafe fn dw_rows<const OB: usize, const IV: usize>(
    dy: *const f32,
    xt: *const f32,
    dwp: *mut f32,
    inp_pad: usize,
    out: usize,
    i0: usize,
    ld: usize,
    kb: usize,
    kc: usize,
) {
    let mut o0 = 0;
    while o0 + OB <= out {
        dw_tile::<OB, IV>(dy, xt, dwp, inp_pad, o0, i0, ld, kb, kc);
        o0 += OB;
    }
    while o0 + 4 <= out {
        dw_tile::<4, IV>(dy, xt, dwp, inp_pad, o0, i0, ld, kb, kc);
        o0 += 4;
    }
    while o0 < out {
        dw_tile::<1, IV>(dy, xt, dwp, inp_pad, o0, i0, ld, kb, kc);
        o0 += 1;
    }
}

/// Weight-gradient accumulation over columns `c < ncols`: `dwp[o·inp_pad + i] +=
/// Σ_c dy[o][c] · x[i][c]` as one sequential fused sum per entry (`inp_pad` = `inp` rounded up
/// to 16; padding entries stay as they are), and `lanes[o·16 + l] += Σ dy[o][c]` over the
/// columns `c ≡ l (mod 16)`. `xt` is scratch.
///
/// # Safety
/// AVX-512F must be available; `ncols` is a multiple of 16; `dwp.len() ≥ out·inp_pad`,
/// `lanes.len() ≥ 16·out`, and the rows of `dy` (stride `lddy`) and `x` (stride `ldx`) hold
/// `ncols` columns inside their slices.
#[target_feature(enable = "avx512f")]
#[allow(clippy::too_many_arguments)]
pub(crate) unsafe fn backward_weights(
    dy: &[f32],
    lddy: usize,
    x: &[f32],
    ldx: usize,
    dwp: &mut [f32],
    lanes: &mut [f32],
    inp: usize,
    out: usize,
    ncols: usize,
    xt: &mut Vec<f32>,
) {
    let inp_pad = inp.div_ceil(16) * 16;
    // Keep the transposed block (kc × inp_pad floats) within ~16 KiB of L1.
    let kc_max = (4096 / inp_pad).max(1).div_ceil(16) * 16;
    xt.resize(kc_max * inp_pad, 0.0);
    let (dyp, xp, dwpp, xtp) = (dy.as_ptr(), x.as_ptr(), dwp.as_mut_ptr(), xt.as_mut_ptr());
    let zero = _mm512_setzero_ps();
    let mut kb = 0;
    while kb < ncols {
        let kc = kc_max.min(ncols - kb);
        // Transpose x[.., kb..kb + kc] into xt (sample-major, zero-padded channels).
        for i0 in (0..inp_pad).step_by(16) {
            for n0 in (0..kc).step_by(16) {
                let mut r = [zero; 16];
                for q in 0..16 {
                    if i0 + q < inp {
                        r[q] = _mm512_loadu_ps(xp.add((i0 + q) * ldx + kb + n0));
                    }
                }
                let o = transpose16(r);
                for j in 0..16 {
                    _mm512_storeu_ps(xtp.add((n0 + j) * inp_pad + i0), o[j]);
                }
            }
        }
        let mut i0 = 0;
        while i0 < inp_pad {
            match (inp_pad - i0) / 16 {
                1 => {
                    dw_rows::<16, 1>(dyp, xtp, dwpp, inp_pad, out, i0, lddy, kb, kc);
                    i0 += 16;
                }
                2 => {
                    dw_rows::<12, 2>(dyp, xtp, dwpp, inp_pad, out, i0, lddy, kb, kc);
                    i0 += 32;
                }
                3 => {
                    dw_rows::<8, 3>(dyp, xtp, dwpp, inp_pad, out, i0, lddy, kb, kc);
                    i0 += 48;
                }
                _ => {
                    dw_rows::<6, 4>(dyp, xtp, dwpp, inp_pad, out, i0, lddy, kb, kc);
                    i0 += 64;
                }
            }
        }
        kb += kc;
    }
    for o in 0..out {
        let lp = lanes.as_mut_ptr().add(16 * o);
        let mut acc = _mm512_loadu_ps(lp);
        for base in (0..ncols).step_by(16) {
            acc = _mm512_add_ps(acc, _mm512_loadu_ps(dyp.add(o * lddy + base)));
        }
        _mm512_storeu_ps(lp, acc);
    }
}
