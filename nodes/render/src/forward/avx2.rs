//! AVX2 forward tile kernels (8 lanes: one tile row is two vectors, its left and right
//! halves), written with intrinsics; the same IEEE operations in the same order per pixel as
//! the portable twin in [`super::tile`], so bit-identical to it.

// Negated comparisons are deliberate: they also reject NaN. Index loops read best in
// small fixed-size numeric code.
#![allow(clippy::neg_cmp_op_on_partial_ord, clippy::needless_range_loop)]

use super::exp2::{RowGeom, EXP2_POLY, EXP_BIAS_FROM_ROUND, ROUND};
use super::tile::{raster_tile_impl, ForwardKernel, RowState, TileCoords, TileState};
use super::{Splat2D, BATCH, CHORD_PAD, SIGMA_CLAMP};
use crate::constants::{ALPHA_THRESHOLD, TRANSMITTANCE_THRESHOLD};
use std::arch::x86_64::*;

/// [`exp2_core`] lane-wise: exactly its operations (2ⁿ built in the exponent bits).
#[inline(always)]
pub(crate) unsafe fn exp2_core_v(x: __m256) -> __m256 {
    let round = _mm256_set1_ps(ROUND);
    let shifted = _mm256_add_ps(x, round);
    let n = _mm256_sub_ps(shifted, round);
    let f = _mm256_sub_ps(x, n);
    // A macro, not a closure: a closure would be compiled without the target features.
    macro_rules! c {
        ($i:expr) => {
            _mm256_set1_ps(EXP2_POLY[$i])
        };
    }
    let f2 = _mm256_mul_ps(f, f);
    let lo = _mm256_fmadd_ps(c!(1), f, c!(0));
    let mid = _mm256_fmadd_ps(c!(3), f, c!(2));
    let hi = _mm256_fmadd_ps(c!(5), f, c!(4));
    let p = _mm256_fmadd_ps(_mm256_fmadd_ps(hi, f2, mid), f2, lo);
    let biased = _mm256_add_epi32(
        _mm256_castps_si256(shifted),
        _mm256_set1_epi32(EXP_BIAS_FROM_ROUND as i32),
    );
    let scale = _mm256_slli_epi32::<23>(biased);
    _mm256_mul_ps(p, _mm256_castsi256_ps(scale))
}

/// [`gauss_of_exponent`] lane-wise (`max` returns its second operand for a NaN, as the
/// scalar `max(−SIGMA_CLAMP)` does).
#[inline(always)]
pub(crate) unsafe fn gauss_v(ex: __m256) -> __m256 {
    let lo = _mm256_max_ps(ex, _mm256_set1_ps(-SIGMA_CLAMP));
    exp2_core_v(_mm256_min_ps(lo, _mm256_setzero_ps()))
}

/// [`row_mask_portable`] for the eight rows whose centres are `py`, with the chord tested
/// against the pixel centres `left ..= right`.
#[inline(always)]
unsafe fn row_mask8(sp: &Splat2D, py: __m256, left: f32, right: f32) -> u32 {
    let zero = _mm256_setzero_ps();
    let dy = _mm256_sub_ps(_mm256_set1_ps(sp.y), py);
    let dy2 = _mm256_mul_ps(dy, dy);
    let rem = _mm256_fnmadd_ps(_mm256_set1_ps(sp.row_q), dy2, _mm256_set1_ps(sp.sigma_max));
    let w2 = _mm256_mul_ps(_mm256_set1_ps(sp.row_w), rem);
    let half = _mm256_add_ps(
        _mm256_sqrt_ps(_mm256_max_ps(w2, zero)),
        _mm256_set1_ps(CHORD_PAD),
    );
    let centre = _mm256_fmadd_ps(_mm256_set1_ps(sp.row_shift), dy, _mm256_set1_ps(sp.x));
    let m = _mm256_and_ps(
        _mm256_cmp_ps::<_CMP_GE_OQ>(py, _mm256_set1_ps(sp.ymin)),
        _mm256_cmp_ps::<_CMP_LE_OQ>(py, _mm256_set1_ps(sp.ymax)),
    );
    let m = _mm256_and_ps(m, _mm256_cmp_ps::<_CMP_GE_OQ>(w2, zero));
    let m = _mm256_and_ps(
        m,
        _mm256_cmp_ps::<_CMP_GE_OQ>(_mm256_add_ps(centre, half), _mm256_set1_ps(left)),
    );
    let m = _mm256_and_ps(
        m,
        _mm256_cmp_ps::<_CMP_LE_OQ>(_mm256_sub_ps(centre, half), _mm256_set1_ps(right)),
    );
    _mm256_movemask_ps(m) as u32
}

/// The 16 row bits of `row_mask8` over both groups of eight rows.
#[inline(always)]
unsafe fn row_mask16(sp: &Splat2D, tc: &TileCoords, left: f32, right: f32) -> u32 {
    let top = row_mask8(sp, _mm256_load_ps(tc.py.as_ptr()), left, right);
    let bottom = row_mask8(sp, _mm256_load_ps(tc.py.as_ptr().add(8)), left, right);
    top | (bottom << 8)
}

/// [`row_mask_portable`] with the 16 rows as two vectors of lanes.
#[inline(always)]
pub(crate) unsafe fn row_mask(sp: &Splat2D, tc: &TileCoords) -> u16 {
    row_mask16(sp, tc, tc.left, tc.right) as u16
}

/// [`ForwardKernel::half_row_masks`]: the row test against the left eight and the right
/// eight pixel centres.
#[inline(always)]
pub(crate) unsafe fn half_row_masks(sp: &Splat2D, tc: &TileCoords) -> u32 {
    row_mask16(sp, tc, tc.left, tc.px[7]) | (row_mask16(sp, tc, tc.px[8], tc.right) << 16)
}

/// [`ForwardKernel::transpose`]: per row, the row bit of 16 masks at a time is moved to
/// the sign of its 16-bit lane, the words are packed to bytes (saturation keeps the
/// sign) and their signs collected with one byte move-mask.
#[inline(always)]
pub(crate) unsafe fn transpose(masks: &[u16; BATCH]) -> [u64; 16] {
    let p = masks.as_ptr() as *const __m256i;
    let v = [
        _mm256_loadu_si256(p),
        _mm256_loadu_si256(p.add(1)),
        _mm256_loadu_si256(p.add(2)),
        _mm256_loadu_si256(p.add(3)),
    ];
    let mut rows = [0u64; 16];
    let mut shift = 15;
    for r in rows.iter_mut() {
        let count = _mm_cvtsi32_si128(shift);
        // Masks 0–15 and 16–31 as bytes; the pack interleaves the 128-bit halves, which
        // the 64-bit permutation puts back in entry order.
        let lo = _mm256_packs_epi16(_mm256_sll_epi16(v[0], count), _mm256_sll_epi16(v[1], count));
        let hi = _mm256_packs_epi16(_mm256_sll_epi16(v[2], count), _mm256_sll_epi16(v[3], count));
        let lo = _mm256_permute4x64_epi64::<0xD8>(lo);
        let hi = _mm256_permute4x64_epi64::<0xD8>(hi);
        *r = (_mm256_movemask_epi8(lo) as u32 as u64)
            | ((_mm256_movemask_epi8(hi) as u32 as u64) << 32);
        shift -= 1;
    }
    rows
}

/// Lane `l` all ones where bit `l` of `bits` is set.
#[inline(always)]
pub(crate) unsafe fn lane_mask(bits: u32) -> __m256 {
    let sel = _mm256_setr_epi32(1, 2, 4, 8, 16, 32, 64, 128);
    let v = _mm256_and_si256(_mm256_set1_epi32(bits as i32), sel);
    _mm256_castsi256_ps(_mm256_cmpeq_epi32(v, sel))
}

/// [`composite_row_portable`] (hard cutoff) over the pixels `8·h .. 8·h + 8` of a row,
/// whose state stays in registers; returns the composited pairs.
#[allow(clippy::too_many_arguments)]
#[inline(always)]
unsafe fn composite_half(
    h: usize,
    splats: &[Splat2D],
    batch: &[u32],
    k_base: u32,
    mut bits: u64,
    row: &mut RowState,
    active: &mut u16,
    tc: &TileCoords,
    py: f32,
    max_alpha: f32,
) -> u32 {
    let act_bits = ((*active >> (8 * h)) & 0xff) as u32;
    if act_bits == 0 {
        return 0;
    }
    let o = 8 * h;
    let px = _mm256_load_ps(tc.px.as_ptr().add(o));
    let zero = _mm256_setzero_ps();
    let one = _mm256_set1_ps(1.0);
    let maxa = _mm256_set1_ps(max_alpha);
    let thr = _mm256_set1_ps(ALPHA_THRESHOLD);
    let tthr = _mm256_set1_ps(TRANSMITTANCE_THRESHOLD);
    let mut t = _mm256_load_ps(row.t.as_ptr().add(o));
    let mut cr = _mm256_load_ps(row.c[0].as_ptr().add(o));
    let mut cg = _mm256_load_ps(row.c[1].as_ptr().add(o));
    let mut cb = _mm256_load_ps(row.c[2].as_ptr().add(o));
    let mut d = _mm256_load_ps(row.d.as_ptr().add(o));
    let mut last = _mm256_load_ps(row.last.as_ptr().add(o) as *const f32);
    let mut act = lane_mask(act_bits);
    let mut pairs = 0u32;
    // α of entry j and the lanes where it passes the cutoff (σ ≥ 0, α ≥ 1/255).
    macro_rules! alpha {
        ($j:expr) => {{
            let sp = splats.get_unchecked(*batch.get_unchecked($j as usize) as usize);
            let g = RowGeom::new(sp, py);
            let dx = _mm256_sub_ps(_mm256_set1_ps(sp.x), px);
            let u = _mm256_fmadd_ps(_mm256_set1_ps(g.ea), dx, _mm256_set1_ps(g.eb));
            let ex = _mm256_fmadd_ps(u, dx, _mm256_set1_ps(g.ec));
            let e = gauss_v(ex);
            let a1 = _mm256_min_ps(_mm256_mul_ps(_mm256_set1_ps(sp.opacity), e), maxa);
            let pass = _mm256_and_ps(
                _mm256_cmp_ps::<_CMP_LE_OQ>(ex, zero),
                _mm256_cmp_ps::<_CMP_GE_OQ>(a1, thr),
            );
            (sp, a1, pass)
        }};
    }
    // Composites entry j (α and pass lanes from `alpha!`). Branch-free: where no lane
    // passes, every update is a no-op.
    macro_rules! composite {
        ($j:expr, $sp:expr, $a1:expr, $pass:expr) => {{
            let (j, sp, a1): (u32, &Splat2D, __m256) = ($j, $sp, $a1);
            let ok = _mm256_and_ps(act, $pass);
            let next_t = _mm256_mul_ps(t, _mm256_sub_ps(one, a1));
            let stop = _mm256_and_ps(ok, _mm256_cmp_ps::<_CMP_LE_OQ>(next_t, tthr));
            let comp = _mm256_andnot_ps(stop, ok);
            act = _mm256_andnot_ps(stop, act);
            // w is zeroed outside `comp`: there the sums gain w·c = ±0, which leaves
            // them unchanged (colour and depth are finite, and a sum that starts at +0
            // and gains only products ≥ 0 or ±0 is never −0).
            let w = _mm256_and_ps(_mm256_mul_ps(a1, t), comp);
            cr = _mm256_fmadd_ps(w, _mm256_set1_ps(sp.rgb[0]), cr);
            cg = _mm256_fmadd_ps(w, _mm256_set1_ps(sp.rgb[1]), cg);
            cb = _mm256_fmadd_ps(w, _mm256_set1_ps(sp.rgb[2]), cb);
            d = _mm256_fmadd_ps(w, _mm256_set1_ps(sp.depth), d);
            t = _mm256_blendv_ps(t, next_t, comp);
            let kk = _mm256_castsi256_ps(_mm256_set1_epi32((k_base + j + 1) as i32));
            last = _mm256_blendv_ps(last, kk, comp);
            pairs += (_mm256_movemask_ps(comp) as u32).count_ones();
        }};
    }
    // Two entries per step: both α (independent exponentials the CPU overlaps) before
    // the two compositing steps, which run in list order. Once no lane is active every
    // step is a no-op, so the walk may stop after either.
    while bits != 0 {
        let j0 = bits.trailing_zeros();
        bits &= bits - 1;
        if bits != 0 {
            let j1 = bits.trailing_zeros();
            bits &= bits - 1;
            let (sp0, a0, p0) = alpha!(j0);
            let (sp1, a1, p1) = alpha!(j1);
            composite!(j0, sp0, a0, p0);
            composite!(j1, sp1, a1, p1);
        } else {
            let (sp0, a0, p0) = alpha!(j0);
            composite!(j0, sp0, a0, p0);
        }
        if _mm256_movemask_ps(act) == 0 {
            break;
        }
    }
    _mm256_store_ps(row.t.as_mut_ptr().add(o), t);
    _mm256_store_ps(row.c[0].as_mut_ptr().add(o), cr);
    _mm256_store_ps(row.c[1].as_mut_ptr().add(o), cg);
    _mm256_store_ps(row.c[2].as_mut_ptr().add(o), cb);
    _mm256_store_ps(row.d.as_mut_ptr().add(o), d);
    _mm256_store_ps(row.last.as_mut_ptr().add(o) as *mut f32, last);
    let kept = _mm256_movemask_ps(act) as u16;
    *active = (*active & !(0xff << (8 * h))) | (kept << (8 * h));
    pairs
}

/// Marker type of the AVX2 forward kernels. A row's two halves are composited one after
/// the other: pixels are independent, so the results are those of the whole-row kernels.
pub(crate) struct Avx2;

impl ForwardKernel for Avx2 {
    const HALF_ROWS: bool = true;
    #[inline(always)]
    unsafe fn prefetch(p: *const Splat2D) {
        _mm_prefetch::<_MM_HINT_T0>(p as *const i8);
    }
    #[inline(always)]
    unsafe fn transpose(masks: &[u16; BATCH]) -> [u64; 16] {
        transpose(masks)
    }
    #[inline(always)]
    unsafe fn row_mask(sp: &Splat2D, tc: &TileCoords) -> u16 {
        row_mask(sp, tc)
    }
    #[inline(always)]
    unsafe fn half_row_masks(sp: &Splat2D, tc: &TileCoords) -> u32 {
        half_row_masks(sp, tc)
    }
    #[inline(always)]
    unsafe fn composite_half(
        h: usize,
        splats: &[Splat2D],
        batch: &[u32],
        k_base: u32,
        bits: u64,
        row: &mut RowState,
        active: &mut u16,
        tc: &TileCoords,
        py: f32,
        max_alpha: f32,
    ) -> u32 {
        composite_half(
            h, splats, batch, k_base, bits, row, active, tc, py, max_alpha,
        )
    }
    #[inline(always)]
    unsafe fn composite_row(
        splats: &[Splat2D],
        batch: &[u32],
        k_base: u32,
        bits: u64,
        row: &mut RowState,
        active: &mut u16,
        tc: &TileCoords,
        py: f32,
        max_alpha: f32,
    ) -> u32 {
        let mut pairs = 0;
        for h in 0..2 {
            pairs += composite_half(
                h, splats, batch, k_base, bits, row, active, tc, py, max_alpha,
            );
        }
        pairs
    }
}
/// The AVX2 tile kernel (the smooth cutoff runs the portable twin inside it).
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2,fma,bmi1,popcnt")]
pub(super) fn raster_tile_avx2<const SMOOTH: bool>(
    splats: &[Splat2D],
    list: &[u32],
    x0: u32,
    y0: u32,
    active_init: &[u16; 16],
    max_alpha: f32,
    st: &mut TileState,
) -> u64 {
    // SAFETY: this function is only compiled for, and called on, CPUs with AVX2 + FMA.
    unsafe { raster_tile_impl::<Avx2, SMOOTH>(splats, list, x0, y0, active_init, max_alpha, st) }
}
