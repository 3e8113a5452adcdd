//! AVX2 + FMA register-blocked kernels for the dense layers of [`crate::mlp`] (x86-64 only;
//! the [`augsplat_core::simd::Isa::Avx2`] tier), with 8-lane ymm registers:
//!
//! - Forward / input gradient: a tile of up to 6 outputs × 16 batch columns (2 ymm each), or of
//!   up to 3 outputs × 32 columns when the layer has at most 3 outputs, lives in 12 ymm
//!   accumulators; every step of the reduction loads the tile's column vectors and broadcasts
//!   one weight per output. Bias, ReLU or the ReLU mask of the layer below are applied in the
//!   store. Each output sums `b + Σ_i w_i x_i` in `i` order with fused multiply-adds — the same
//!   operations, hence the same bits, as the portable twin with fused multiply-adds.
//! - Weight gradient `dW = δ·Xᵀ`: the batch is cut into blocks of `kc` columns; each block of
//!   `X` is transposed (8×8 in-register transposes) to sample-major rows, then a tile of up to
//!   6 outputs × 16 inputs (or 3 outputs × 32 inputs) accumulates in registers, one sample
//!   after the other. Every weight gradient is therefore the sequential fused sum over the
//!   batch in column order, independent of block sizes. The bias lane sums keep the 16 lanes of
//!   [`crate::mlp::LANES`] (two ymm halves), so they add exactly the same numbers. The next
//!   block of `X` is prefetched during each block's transpose (its rows are too far apart for
//!   the hardware prefetcher).
//! - Alignment: large `Vec`s from the C allocator start 16 bytes past a 64-byte boundary, so
//!   every other 8-float vector of a row would straddle two cache lines. When `x`'s rows start
//!   16 bytes past a 32-byte boundary, the forward kernel walks the columns on the 32-byte grid
//!   (masked 4-column windows at both ends); the columns each tile computes change, the
//!   operations per output do not.
//!
//! The callers check slice lengths; these functions are `unsafe` because they require AVX2
//! and FMA and read through raw pointers within those checked bounds.

use std::arch::x86_64::*;

use super::{Gemm, Store, WeightGrad};

/// Store modes of the forward tile (const generic so the store loop is fully unrolled).
const LINEAR: u8 = 0;
const RELU: u8 = 1;
const MASK: u8 = 2;

/// Floats per ymm register.
const V: usize = 8;

/// Row strides of the forward kernel's operands.
#[derive(Clone, Copy)]
struct Strides {
    x: usize,
    y: usize,
    m: usize,
}

/// The operands of the forward tiles: [`Gemm`] and its output as raw pointers (the bounds are
/// checked by the callers of [`forward`]).
#[derive(Clone, Copy)]
struct Fwd {
    /// Weights, `out × inp` row-major.
    w: *const f32,
    /// Biases, if any.
    b: Option<*const f32>,
    /// Input rows.
    x: *const f32,
    /// Output rows.
    y: *mut f32,
    /// ReLU-mask rows (read only in the `MASK` store mode).
    mask: *const f32,
    /// Input width.
    inp: usize,
    /// Output width.
    out: usize,
    /// Row strides of `x`, `y` and `mask`.
    ld: Strides,
}

/// One forward tile: outputs `o0..o0 + OB` × columns `base..base + 8·T`.
#[inline(always)]
unsafe fn fwd_tile<const OB: usize, const T: usize, const MODE: u8>(
    op: Fwd,
    o0: usize,
    base: usize,
    prefetch_next: bool,
) {
    let Fwd {
        w,
        b,
        x,
        y,
        mask,
        inp,
        ld,
        ..
    } = op;
    // Bring the tile's output (and mask) lines in while the reduction runs.
    for k in 0..OB {
        for t in (0..T).step_by(2) {
            let c = base + V * t;
            _mm_prefetch::<_MM_HINT_T0>(y.add((o0 + k) * ld.y + c) as *const i8);
            if MODE == MASK {
                _mm_prefetch::<_MM_HINT_T0>(mask.add((o0 + k) * ld.m + c) as *const i8);
            }
        }
    }
    let mut acc = [[_mm256_setzero_ps(); T]; OB];
    if let Some(b) = b {
        for k in 0..OB {
            let bv = _mm256_set1_ps(*b.add(o0 + k));
            for t in 0..T {
                acc[k][t] = bv;
            }
        }
    }
    let wp = w.add(o0 * inp);
    let xp = x.add(base);
    for i in 0..inp {
        let mut xv = [_mm256_setzero_ps(); T];
        for t in 0..T {
            xv[t] = _mm256_loadu_ps(xp.add(i * ld.x + V * t));
        }
        if prefetch_next {
            // The next column panel (the row stride defeats the hardware prefetcher).
            for t in (0..T).step_by(2) {
                _mm_prefetch::<_MM_HINT_T0>(xp.add(i * ld.x + V * (T + t)) as *const i8);
            }
        }
        for k in 0..OB {
            let wk = _mm256_broadcast_ss(&*wp.add(k * inp + i));
            for t in 0..T {
                acc[k][t] = _mm256_fmadd_ps(wk, xv[t], acc[k][t]);
            }
        }
    }
    let zero = _mm256_setzero_ps();
    for k in 0..OB {
        for t in 0..T {
            let c = base + V * t;
            let v = if MODE == RELU {
                // max(acc, 0) returns the second operand (0) when acc is NaN.
                _mm256_max_ps(acc[k][t], zero)
            } else if MODE == MASK {
                let mv = _mm256_loadu_ps(mask.add((o0 + k) * ld.m + c));
                let keep = _mm256_cmp_ps::<_CMP_GT_OQ>(mv, zero);
                _mm256_and_ps(keep, acc[k][t])
            } else {
                acc[k][t]
            };
            _mm256_storeu_ps(y.add((o0 + k) * ld.y + c), v);
        }
    }
}

/// All outputs of one column panel of `8·T` columns: tiles of `OB` outputs, then one tile of
/// the remaining `< OB` outputs (`OB ≤ 6`).
#[inline(always)]
unsafe fn fwd_columns<const T: usize, const OB: usize, const MODE: u8>(
    op: Fwd,
    ncols: usize,
    base: usize,
) {
    let out = op.out;
    // Prefetch the next panel during the first tile (if there is a next panel).
    let pf = base + V * T < ncols;
    let mut o0 = 0;
    while o0 + OB <= out {
        fwd_tile::<OB, T, MODE>(op, o0, base, pf && o0 == 0);
        o0 += OB;
    }
    let pf = pf && o0 == 0;
    match out - o0 {
        0 => {}
        1 => fwd_tile::<1, T, MODE>(op, o0, base, pf),
        2 => fwd_tile::<2, T, MODE>(op, o0, base, pf),
        3 => fwd_tile::<3, T, MODE>(op, o0, base, pf),
        4 => fwd_tile::<4, T, MODE>(op, o0, base, pf),
        _ => fwd_tile::<5, T, MODE>(op, o0, base, pf),
    }
}

/// One tile of up to 6 outputs over the 8-column window starting at column `col` (which may
/// be negative or reach past the last column), on the lanes set in `lm` only: masked loads
/// and stores, so the lanes outside the operands are never accessed (their addresses are
/// formed with wrapping arithmetic and never dereferenced). The active lanes compute exactly
/// what [`fwd_tile`] computes for their columns.
#[inline(always)]
unsafe fn fwd_tile_part<const OB: usize, const MODE: u8>(
    op: Fwd,
    o0: usize,
    col: isize,
    lm: __m256i,
) {
    let Fwd {
        w,
        b,
        x,
        y,
        mask,
        inp,
        ld,
        ..
    } = op;
    let at =
        |p: *const f32, row: usize, stride: usize| p.wrapping_offset((row * stride) as isize + col);
    let mut acc = [_mm256_setzero_ps(); OB];
    if let Some(b) = b {
        for k in 0..OB {
            acc[k] = _mm256_set1_ps(*b.add(o0 + k));
        }
    }
    let wp = w.add(o0 * inp);
    for i in 0..inp {
        let xv = _mm256_maskload_ps(at(x, i, ld.x), lm);
        for k in 0..OB {
            let wk = _mm256_broadcast_ss(&*wp.add(k * inp + i));
            acc[k] = _mm256_fmadd_ps(wk, xv, acc[k]);
        }
    }
    let zero = _mm256_setzero_ps();
    for k in 0..OB {
        let v = if MODE == RELU {
            _mm256_max_ps(acc[k], zero)
        } else if MODE == MASK {
            let mv = _mm256_maskload_ps(at(mask, o0 + k, ld.m), lm);
            let keep = _mm256_cmp_ps::<_CMP_GT_OQ>(mv, zero);
            _mm256_and_ps(keep, acc[k])
        } else {
            acc[k]
        };
        _mm256_maskstore_ps(at(y, o0 + k, ld.y) as *mut f32, lm, v);
    }
}

/// All outputs of one masked 8-column window ([`fwd_tile_part`]): tiles of 6 outputs, then
/// one of the rest.
#[inline(always)]
unsafe fn fwd_part_columns<const MODE: u8>(op: Fwd, col: isize, lm: __m256i) {
    let out = op.out;
    let mut o0 = 0;
    while o0 + 6 <= out {
        fwd_tile_part::<6, MODE>(op, o0, col, lm);
        o0 += 6;
    }
    match out - o0 {
        0 => {}
        1 => fwd_tile_part::<1, MODE>(op, o0, col, lm),
        2 => fwd_tile_part::<2, MODE>(op, o0, col, lm),
        3 => fwd_tile_part::<3, MODE>(op, o0, col, lm),
        4 => fwd_tile_part::<4, MODE>(op, o0, col, lm),
        _ => fwd_tile_part::<5, MODE>(op, o0, col, lm),
    }
}

/// Every column panel: panels of `8·T` columns, then one of 16 or 8 columns for the rest.
///
/// When the rows of `x` start 16 bytes past a 32-byte boundary (large `Vec`s from the C
/// allocator start 16 bytes into a page), every other 8-column vector of a row would straddle
/// two cache lines and a 16-column panel would occupy two lines per row. The columns are then
/// walked on the 32-byte grid instead: a masked window for the first 4 columns, aligned
/// panels, and a masked window for the last 4. Every output column is still computed by one
/// tile with the same operations, so the bits do not depend on the walk.
#[inline(always)]
unsafe fn fwd_all<const T: usize, const OB: usize, const MODE: u8>(op: Fwd, ncols: usize) {
    let Fwd { x, y, mask, ld, .. } = op;
    let shift = (x as usize) % 32 == 16 && ld.x.is_multiple_of(V) && ncols >= V;
    if shift {
        // Lanes 4..8 of the window at column -4, and lanes 0..4 of the one at `ncols - 4`.
        let head = _mm256_setr_epi32(0, 0, 0, 0, -1, -1, -1, -1);
        let tail = _mm256_setr_epi32(-1, -1, -1, -1, 0, 0, 0, 0);
        fwd_part_columns::<MODE>(op, -4, head);
        // Columns 4..ncols - 4 (a multiple of 8) from aligned rows.
        let h = V / 2;
        let mask_h = if MODE == MASK { mask.add(h) } else { mask };
        let aligned = Fwd {
            x: x.add(h),
            y: y.add(h),
            mask: mask_h,
            ..op
        };
        fwd_body::<T, OB, MODE>(aligned, ncols - V);
        fwd_part_columns::<MODE>(op, (ncols - h) as isize, tail);
    } else {
        fwd_body::<T, OB, MODE>(op, ncols);
    }
}

/// The column walk of [`fwd_all`] over `ncols` (a multiple of 8) columns from `op`'s rows.
#[inline(always)]
unsafe fn fwd_body<const T: usize, const OB: usize, const MODE: u8>(op: Fwd, ncols: usize) {
    let mut base = 0;
    while base + V * T <= ncols {
        fwd_columns::<T, OB, MODE>(op, ncols, base);
        base += V * T;
    }
    if base + 2 * V <= ncols {
        fwd_columns::<2, 6, MODE>(op, ncols, base);
        base += 2 * V;
    }
    if base < ncols {
        fwd_columns::<1, 6, MODE>(op, ncols, base);
    }
}

/// Picks the tile shape: 6 outputs × 2 vectors, or `out` (≤ 3) outputs × 4 vectors.
#[inline(always)]
unsafe fn fwd_mode<const MODE: u8>(op: Fwd, ncols: usize) {
    if op.out <= 3 {
        fwd_all::<4, 3, MODE>(op, ncols)
    } else {
        fwd_all::<2, 6, MODE>(op, ncols)
    }
}

/// `y[o][c] = store(b[o] + Σ_i w[o·inp + i] · x[i][c])` for columns `c < ncols` of the
/// channel-major operands of `g` (`x` rows `ldx` apart, a mask's rows its own stride apart),
/// into `y` (rows `ldy` apart).
///
/// # Safety
/// AVX2 and FMA must be available; `ncols` is a multiple of 8; `w.len() ≥ out·inp`,
/// `b.len() ≥ out`, and every row `r` read or written lies inside its slice
/// (`r·ld + ncols ≤ len`).
#[target_feature(enable = "avx2,fma,bmi1,popcnt")]
pub(crate) unsafe fn forward(g: Gemm<'_>, y: &mut [f32], ldy: usize) {
    let mut op = Fwd {
        w: g.w.as_ptr(),
        b: g.b.map(|b| b.as_ptr()),
        x: g.x.as_ptr(),
        y: y.as_mut_ptr(),
        mask: std::ptr::null(),
        inp: g.inp,
        out: g.out,
        ld: Strides {
            x: g.ldx,
            y: ldy,
            m: 0,
        },
    };
    match g.store {
        Store::Linear => fwd_mode::<LINEAR>(op, g.ncols),
        Store::Relu => fwd_mode::<RELU>(op, g.ncols),
        Store::MaskPositive(m, ldm) => {
            op.mask = m.as_ptr();
            op.ld.m = ldm;
            fwd_mode::<MASK>(op, g.ncols)
        }
    }
}

/// Transposes an 8×8 block: `rows[r][c]` → `out[c][r]`.
#[inline(always)]
unsafe fn transpose8(r: [__m256; 8]) -> [__m256; 8] {
    // 32-bit interleave of row pairs: t[2p] holds, in 128-bit half h, columns 4h, 4h + 1 of
    // rows 2p, 2p + 1; t[2p + 1] columns 4h + 2, 4h + 3.
    let mut t = [_mm256_setzero_ps(); 8];
    for p in 0..4 {
        t[2 * p] = _mm256_unpacklo_ps(r[2 * p], r[2 * p + 1]);
        t[2 * p + 1] = _mm256_unpackhi_ps(r[2 * p], r[2 * p + 1]);
    }
    // 64-bit selection of pair pairs: u[4g + c] holds, in half h, column 4h + c of rows
    // 4g..4g + 3.
    let mut u = [_mm256_setzero_ps(); 8];
    for g in 0..2 {
        let (a0, a1, b0, b1) = (t[4 * g], t[4 * g + 1], t[4 * g + 2], t[4 * g + 3]);
        u[4 * g] = _mm256_shuffle_ps::<0x44>(a0, b0);
        u[4 * g + 1] = _mm256_shuffle_ps::<0xEE>(a0, b0);
        u[4 * g + 2] = _mm256_shuffle_ps::<0x44>(a1, b1);
        u[4 * g + 3] = _mm256_shuffle_ps::<0xEE>(a1, b1);
    }
    // Column c: low halves of u[c], u[4 + c]; column 4 + c: their high halves.
    let mut o = [_mm256_setzero_ps(); 8];
    for c in 0..4 {
        o[c] = _mm256_permute2f128_ps::<0x20>(u[c], u[4 + c]);
        o[4 + c] = _mm256_permute2f128_ps::<0x31>(u[c], u[4 + c]);
    }
    o
}

/// Test hook: transposes an 8×8 row-major block.
///
/// # Safety
/// AVX2 must be available.
#[cfg(test)]
#[target_feature(enable = "avx2,fma,bmi1,popcnt")]
pub(crate) unsafe fn transpose8_slice(src: &[f32; 64], dst: &mut [f32; 64]) {
    let mut r = [_mm256_setzero_ps(); 8];
    for i in 0..8 {
        r[i] = _mm256_loadu_ps(src.as_ptr().add(8 * i));
    }
    let o = transpose8(r);
    for i in 0..8 {
        _mm256_storeu_ps(dst.as_mut_ptr().add(8 * i), o[i]);
    }
}

/// The operands of the weight-gradient tiles as raw pointers (the bounds are checked by the
/// callers of [`backward_weights`]).
#[derive(Clone, Copy)]
struct Dw {
    /// Output-gradient rows.
    dy: *const f32,
    /// The transposed block of the input: sample-major rows of `inp_pad` floats.
    xt: *const f32,
    /// Padded weight-gradient accumulators, `out × inp_pad`.
    dwp: *mut f32,
    /// Input width rounded up to 16.
    inp_pad: usize,
    /// Output width.
    out: usize,
    /// Row stride of `dy`.
    lddy: usize,
}

/// One weight-gradient tile: outputs `o0..o0 + OB` × inputs `i0..i0 + 8·IV`, over the
/// samples `kb..kb + kc` (rows of the transposed block `xt`) in order.
#[inline(always)]
unsafe fn dw_tile<const OB: usize, const IV: usize>(
    op: Dw,
    o0: usize,
    i0: usize,
    kb: usize,
    kc: usize,
) {
    let Dw {
        dy,
        xt,
        dwp,
        inp_pad,
        lddy,
        ..
    } = op;
    let mut acc = [[_mm256_setzero_ps(); IV]; OB];
    for k in 0..OB {
        for v in 0..IV {
            acc[k][v] = _mm256_loadu_ps(dwp.add((o0 + k) * inp_pad + i0 + V * v));
        }
    }
    let dyp = dy.add(o0 * lddy + kb);
    for n in 0..kc {
        let xr = xt.add(n * inp_pad + i0);
        let mut xv = [_mm256_setzero_ps(); IV];
        for v in 0..IV {
            xv[v] = _mm256_loadu_ps(xr.add(V * v));
        }
        for k in 0..OB {
            let d = _mm256_broadcast_ss(&*dyp.add(k * lddy + n));
            for v in 0..IV {
                acc[k][v] = _mm256_fmadd_ps(d, xv[v], acc[k][v]);
            }
        }
    }
    for k in 0..OB {
        for v in 0..IV {
            _mm256_storeu_ps(dwp.add((o0 + k) * inp_pad + i0 + V * v), acc[k][v]);
        }
    }
}

/// All outputs of one strip of `8·IV` inputs: tiles of `OB` outputs, then one tile of the
/// remaining `< OB` outputs (`OB ≤ 6`).
#[inline(always)]
unsafe fn dw_rows<const OB: usize, const IV: usize>(op: Dw, i0: usize, kb: usize, kc: usize) {
    let out = op.out;
    let mut o0 = 0;
    while o0 + OB <= out {
        dw_tile::<OB, IV>(op, o0, i0, kb, kc);
        o0 += OB;
    }
    match out - o0 {
        0 => {}
        1 => dw_tile::<1, IV>(op, o0, i0, kb, kc),
        2 => dw_tile::<2, IV>(op, o0, i0, kb, kc),
        3 => dw_tile::<3, IV>(op, o0, i0, kb, kc),
        4 => dw_tile::<4, IV>(op, o0, i0, kb, kc),
        _ => dw_tile::<5, IV>(op, o0, i0, kb, kc),
    }
}

/// Weight-gradient accumulation `g` over columns `c < ncols`: `dwp[o·inp_pad + i] +=
/// Σ_c dy[o][c] · x[i][c]` as one sequential fused sum per entry (`inp_pad` = `inp` rounded up
/// to 16; padding entries accumulate products with zero), and `lanes[o·16 + l] += Σ dy[o][c]`
/// over the columns `c ≡ l (mod 16)`. `xt` is scratch.
///
/// # Safety
/// AVX2 and FMA must be available; `ncols` is a multiple of 16; `dwp.len() ≥ out·inp_pad`,
/// `lanes.len() ≥ 16·out`, and the rows of `dy` (stride `lddy`) and `x` (stride `ldx`) hold
/// `ncols` columns inside their slices.
#[target_feature(enable = "avx2,fma,bmi1,popcnt")]
pub(crate) unsafe fn backward_weights(
    g: WeightGrad<'_>,
    dwp: &mut [f32],
    lanes: &mut [f32],
    xt: &mut Vec<f32>,
) {
    let (inp, out, ncols, ldx) = (g.inp, g.out, g.ncols, g.ldx);
    let inp_pad = inp.div_ceil(16) * 16;
    // Keep the transposed block (kc × inp_pad floats) within ~16 KiB of L1.
    let kc_max = (4096 / inp_pad).max(1).div_ceil(16) * 16;
    if xt.len() < kc_max * inp_pad {
        xt.resize(kc_max * inp_pad, 0.0);
    }
    let (dyp, xp, xtp) = (g.dy.as_ptr(), g.x.as_ptr(), xt.as_mut_ptr());
    let op = Dw {
        dy: dyp,
        xt: xtp,
        dwp: dwp.as_mut_ptr(),
        inp_pad,
        out,
        lddy: g.lddy,
    };
    let zero = _mm256_setzero_ps();
    let mut kb = 0;
    while kb < ncols {
        let kc = kc_max.min(ncols - kb);
        // The next block's columns of x (the layer input, usually written long before and
        // out of L1/L2; its rows are far apart, too many streams for the hardware
        // prefetcher): one line of every row per 16 columns, requested during this block's
        // transpose so it arrives while this block's tiles run.
        let next = kb + kc;
        let next_kc = kc_max.min(ncols.saturating_sub(next));
        // Transpose x[.., kb..kb + kc] into xt (sample-major, zero-padded channels).
        for i0 in (0..inp_pad).step_by(V) {
            for n0 in (0..kc).step_by(V) {
                if n0 % 16 == 0 && n0 < next_kc {
                    for q in 0..V.min(inp.saturating_sub(i0)) {
                        let p = xp.wrapping_add((i0 + q) * ldx + next + n0);
                        _mm_prefetch::<_MM_HINT_T0>(p as *const i8);
                    }
                }
                let mut r = [zero; V];
                for q in 0..V {
                    if i0 + q < inp {
                        r[q] = _mm256_loadu_ps(xp.add((i0 + q) * ldx + kb + n0));
                    }
                }
                let o = transpose8(r);
                for j in 0..V {
                    _mm256_storeu_ps(xtp.add((n0 + j) * inp_pad + i0), o[j]);
                }
            }
        }
        if out <= 3 {
            // Few outputs: wider input strips (32 inputs, then 16) for enough accumulators.
            let mut i0 = 0;
            while i0 + 4 * V <= inp_pad {
                dw_rows::<3, 4>(op, i0, kb, kc);
                i0 += 4 * V;
            }
            if i0 < inp_pad {
                dw_rows::<6, 2>(op, i0, kb, kc);
            }
        } else {
            for i0 in (0..inp_pad).step_by(2 * V) {
                dw_rows::<6, 2>(op, i0, kb, kc);
            }
        }
        kb += kc;
    }
    // Bias lane sums: the 16 lanes as two ymm halves, one add per column as in the portable
    // loop.
    for o in 0..out {
        let lp = lanes.as_mut_ptr().add(16 * o);
        let mut lo = _mm256_loadu_ps(lp);
        let mut hi = _mm256_loadu_ps(lp.add(V));
        for base in (0..ncols).step_by(16) {
            lo = _mm256_add_ps(lo, _mm256_loadu_ps(dyp.add(o * op.lddy + base)));
            hi = _mm256_add_ps(hi, _mm256_loadu_ps(dyp.add(o * op.lddy + base + V)));
        }
        _mm256_storeu_ps(lp, lo);
        _mm256_storeu_ps(lp.add(V), hi);
    }
}
