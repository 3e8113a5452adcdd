//! AVX2 backward tile kernels (8 lanes: a row's left and right halves are separate
//! vectors), written with intrinsics; the same IEEE operations in the same order as the
//! portable twin in [`super::tile`], so bit-identical to it.

// Negated comparisons are deliberate: they also reject NaN. Index loops read best in
// small fixed-size numeric code.
#![allow(clippy::neg_cmp_op_on_partial_ord, clippy::needless_range_loop)]

use super::tile::{backward_tile_impl, BackwardKernel, BwdTile};
use super::{LaneSums, PairGrad};
use crate::constants::ALPHA_THRESHOLD;
use crate::forward::avx2::{gauss_v, half_row_masks, row_mask};
use crate::forward::{RowGeom, Splat2D, TileCoords};
use std::arch::x86_64::*;

/// [`tree_sum16`] of ten accumulators held as left and right halves: `lo + hi` gives the
/// (l, l+8) sums; each later shuffle stage adds the same lane pairs as the scalar tree
/// ((l, l+4), (l, l+2), (l, l+1)) for several accumulators per instruction, so every sum
/// is bit-identical to it.
#[inline(always)]
unsafe fn reduce10(lo: &[__m256; 10], hi: &[__m256; 10]) -> [f32; 10] {
    // Plain loops and macros, not closures: a closure would be compiled without the
    // target features and call the intrinsics out of line.
    let mut s8 = [_mm256_setzero_ps(); 10];
    for q in 0..10 {
        s8[q] = _mm256_add_ps(lo[q], hi[q]);
    }
    // (l, l+4): [s4 of A | s4 of B].
    macro_rules! f {
        ($a:expr, $b:expr) => {
            _mm256_add_ps(
                _mm256_permute2f128_ps::<0x20>($a, $b),
                _mm256_permute2f128_ps::<0x31>($a, $b),
            )
        };
    }
    // (l, l+2) within each 128-bit lane: [s2 of A, s2 of C | s2 of B, s2 of D].
    macro_rules! g {
        ($x:expr, $y:expr) => {
            _mm256_add_ps(
                _mm256_shuffle_ps::<0x44>($x, $y),
                _mm256_shuffle_ps::<0xEE>($x, $y),
            )
        };
    }
    // (l, l+1) within each 128-bit lane.
    macro_rules! h {
        ($x:expr, $y:expr) => {
            _mm256_add_ps(
                _mm256_shuffle_ps::<0x88>($x, $y),
                _mm256_shuffle_ps::<0xDD>($x, $y),
            )
        };
    }
    let zero = _mm256_setzero_ps();
    // e0 = [0 | 1], e1 = [2 | 3], e2 = [4 | 5], e3 = [6 | 7], e4 = [8 | 9].
    let e = [
        f!(s8[0], s8[1]),
        f!(s8[2], s8[3]),
        f!(s8[4], s8[5]),
        f!(s8[6], s8[7]),
        f!(s8[8], s8[9]),
    ];
    // [0, 2 | 1, 3], [4, 6 | 5, 7], [8, – | 9, –] (two values each).
    let g0 = g!(e[0], e[1]);
    let g1 = g!(e[2], e[3]);
    let g2 = g!(e[4], zero);
    // [0, 2, 4, 6 | 1, 3, 5, 7], [8, –, –, – | 9, –, –, –].
    let r0 = h!(g0, g1);
    let r1 = h!(g2, zero);
    let mut a = [0.0f32; 8];
    let mut b = [0.0f32; 8];
    _mm256_storeu_ps(a.as_mut_ptr(), r0);
    _mm256_storeu_ps(b.as_mut_ptr(), r1);
    [a[0], a[4], a[1], a[5], a[2], a[6], a[3], a[7], b[0], b[4]]
}

/// [`backward_gaussian_portable`] (hard cutoff) over the pixels `8·h .. 8·h + 8` of the
/// rows in `rows`, with the lane sums in registers across rows.
#[inline(always)]
unsafe fn backward_half(
    h: usize,
    sp: &Splat2D,
    k: u32,
    mut rows: u16,
    tile: &mut BwdTile,
    tc: &TileCoords,
    max_alpha: f32,
) -> [__m256; 10] {
    let o = 8 * h;
    let zero = _mm256_setzero_ps();
    let mut acc = [zero; 10];
    let px = _mm256_load_ps(tc.px.as_ptr().add(o));
    let one = _mm256_set1_ps(1.0);
    let maxa = _mm256_set1_ps(max_alpha);
    let thr = _mm256_set1_ps(ALPHA_THRESHOLD);
    // `k < last` as a signed comparison: both are below 2³¹ (see `backward_tile_impl`).
    let kv = _mm256_set1_epi32(k as i32);
    let dx = _mm256_sub_ps(_mm256_set1_ps(sp.x), px);
    let ea = _mm256_set1_ps(RowGeom::exp_a(sp));
    let o_v = _mm256_set1_ps(sp.opacity);
    let (cr, cg, cb, cz) = (
        _mm256_set1_ps(sp.rgb[0]),
        _mm256_set1_ps(sp.rgb[1]),
        _mm256_set1_ps(sp.rgb[2]),
        _mm256_set1_ps(sp.depth),
    );
    // One row: updates its T and R (where `ok`) and evaluates to the lane sums' terms,
    // zero outside `ok`. Adding those zeros changes no sum: a sum that starts at +0 is
    // never −0, and the upstream gradients are finite. Branch-free, so that two rows
    // form one block the compiler can interleave.
    macro_rules! row_terms {
        ($ly:expr) => {{
            let ly: usize = $ly;
            let g = RowGeom::new(sp, *tc.py.get_unchecked(ly));
            let row = tile.rows.as_mut_ptr().add(ly);
            let last = _mm256_load_si256((*row).last.as_ptr().add(o) as *const __m256i);
            let u = _mm256_fmadd_ps(ea, dx, _mm256_set1_ps(g.eb));
            let ex = _mm256_fmadd_ps(u, dx, _mm256_set1_ps(g.ec));
            let gauss = gauss_v(ex);
            let raw = _mm256_mul_ps(o_v, gauss);
            let a1 = _mm256_min_ps(raw, maxa);
            let ok = _mm256_castsi256_ps(_mm256_cmpgt_epi32(last, kv));
            let ok = _mm256_and_ps(ok, _mm256_cmp_ps::<_CMP_LE_OQ>(ex, zero));
            let ok = _mm256_and_ps(ok, _mm256_cmp_ps::<_CMP_GE_OQ>(a1, thr));
            // Volatile loads: otherwise LLVM turns the blend-and-store of T and R below
            // into masked stores, which are slow (microcoded) on some AVX2 CPUs.
            let t = std::ptr::read_volatile((*row).t.as_ptr().add(o) as *const __m256);
            let r = std::ptr::read_volatile((*row).r.as_ptr().add(o) as *const __m256);
            let gr = _mm256_load_ps((*row).gc[0].as_ptr().add(o));
            let gg = _mm256_load_ps((*row).gc[1].as_ptr().add(o));
            let gb = _mm256_load_ps((*row).gc[2].as_ptr().add(o));
            let gs = _mm256_load_ps((*row).gs.as_ptr().add(o));
            let ra = _mm256_div_ps(one, _mm256_sub_ps(one, a1));
            let ti = _mm256_mul_ps(t, ra);
            let w = _mm256_and_ps(_mm256_mul_ps(a1, ti), ok);
            let gcol = _mm256_mul_ps(gr, cr);
            let gcol = _mm256_fmadd_ps(gg, cg, gcol);
            let gcol = _mm256_fmadd_ps(gb, cb, gcol);
            let gcol = _mm256_fmadd_ps(gs, cz, gcol);
            let dl = _mm256_mul_ps(_mm256_fmsub_ps(gcol, t, r), ra);
            let qm = _mm256_and_ps(ok, _mm256_cmp_ps::<_CMP_LT_OQ>(raw, maxa));
            let q = _mm256_and_ps(_mm256_mul_ps(dl, gauss), qm);
            let r_new = _mm256_blendv_ps(r, _mm256_fmadd_ps(gcol, w, r), ok);
            _mm256_store_ps((*row).r.as_mut_ptr().add(o), r_new);
            _mm256_store_ps((*row).t.as_mut_ptr().add(o), _mm256_blendv_ps(t, ti, ok));
            (q, g.dy, [gr, gg, gb, gs], w)
        }};
    }
    // Adds one row's terms to the lane sums (rows in ascending order, as the twin).
    macro_rules! accumulate {
        ($terms:expr) => {{
            let (q, gdy, gc, w) = $terms;
            acc[0] = _mm256_add_ps(acc[0], q);
            acc[2] = _mm256_fmadd_ps(q, _mm256_set1_ps(gdy), acc[2]);
            acc[5] = _mm256_fmadd_ps(q, _mm256_set1_ps(gdy * gdy), acc[5]);
            acc[6] = _mm256_fmadd_ps(gc[0], w, acc[6]);
            acc[7] = _mm256_fmadd_ps(gc[1], w, acc[7]);
            acc[8] = _mm256_fmadd_ps(gc[2], w, acc[8]);
            acc[9] = _mm256_fmadd_ps(gc[3], w, acc[9]);
        }};
    }
    // Two rows at a time: their (independent) exponentials and divisions overlap.
    while rows != 0 {
        let first = rows.trailing_zeros() as usize;
        rows &= rows - 1;
        if rows != 0 {
            let second = rows.trailing_zeros() as usize;
            rows &= rows - 1;
            let a = row_terms!(first);
            let b = row_terms!(second);
            accumulate!(a);
            accumulate!(b);
        } else {
            let a = row_terms!(first);
            accumulate!(a);
        }
    }
    // The dx-weighted sums, once per lane (as the portable twin).
    acc[1] = _mm256_mul_ps(acc[0], dx);
    acc[3] = _mm256_mul_ps(acc[1], dx);
    acc[4] = _mm256_mul_ps(acc[2], dx);
    acc
}

/// Marker type of the AVX2 backward kernels. The two halves of the rows are walked one
/// after the other; each pixel's state and each lane's sums see the same operations in
/// the same order as in the whole-row kernels.
pub(super) struct Avx2;

impl BackwardKernel for Avx2 {
    #[inline(always)]
    unsafe fn prefetch(p: *const Splat2D) {
        _mm_prefetch::<_MM_HINT_T0>(p as *const i8);
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
    unsafe fn backward_gaussian(
        sp: &Splat2D,
        k: u32,
        rows: u16,
        tile: &mut BwdTile,
        tc: &TileCoords,
        max_alpha: f32,
    ) -> LaneSums {
        Self::backward_halves(sp, k, rows, rows, tile, tc, max_alpha)
    }
    #[inline(always)]
    unsafe fn backward_halves(
        sp: &Splat2D,
        k: u32,
        left: u16,
        right: u16,
        tile: &mut BwdTile,
        tc: &TileCoords,
        max_alpha: f32,
    ) -> LaneSums {
        let lo = backward_half(0, sp, k, left, tile, tc, max_alpha);
        let hi = backward_half(1, sp, k, right, tile, tc, max_alpha);
        reduce10(&lo, &hi)
    }
}

/// The AVX2 tile kernel (the smooth cutoff runs the portable twin inside it).
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2,fma,bmi1,popcnt")]
pub(super) fn backward_tile_avx2<const SMOOTH: bool>(
    splats: &[Splat2D],
    list: &[u32],
    x0: u32,
    y0: u32,
    tile: &mut BwdTile,
    max_alpha: f32,
    out: &mut impl FnMut(usize, PairGrad),
) {
    // SAFETY: this function is only compiled for, and called on, CPUs with AVX2 + FMA.
    unsafe { backward_tile_impl::<Avx2, SMOOTH>(splats, list, x0, y0, tile, max_alpha, out) }
}
