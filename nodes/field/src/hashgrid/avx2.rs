//! AVX2 twins of the hash encoding's block kernels (x86-64; the
//! [`augsplat_core::simd::Isa::Avx2`] tier), eight points per register:
//!
//! - [`corners_block`]: the corner indices and trilinear weights of a block of [`BLOCK`]
//!   points. The portable loop vectorises poorly (the compiler keeps parts of the clamp and
//!   the float-to-integer conversion scalar); this one does every step in 8 lanes, with the same
//!   operations in the same order: the same bits.
//! - [`gather2_block`]: the two-feature blend. Each corner entry (both features, 8 bytes) is
//!   read with a plain 64-bit load (faster than `vgatherdpd` on the project's AMD Zen 4 host:
//!   docs/notes/benchmarks.md, entry of 2026-11-27 on the hash encoding) and blended with a separate multiply and add in corner
//!   order, as the scalar loop does.

use super::{block_positions, Level, PointBatch, BLOCK};
use crate::constants::HASH_PRIMES;
use std::arch::x86_64::*;

/// Corner indices (entry numbers) and trilinear weights of up to [`BLOCK`] points
/// `start..start + BLOCK` (points past `n` get index 0 and weight 0): the AVX2 twin of the
/// portable `corners_block`, bit for bit.
///
/// # Safety
/// AVX2 must be available; `start < pts.n`; `pts.px`, `pts.py`, `pts.pz` must hold `pts.n`
/// points; `lv.res` must be below 2²⁴ (cell indices convert through `i32`).
#[target_feature(enable = "avx2,fma,bmi1,popcnt")]
pub(super) unsafe fn corners_block<const DENSE: bool>(
    lv: Level,
    pts: PointBatch<'_>,
    start: usize,
    idx: &mut [[u32; BLOCK]; 8],
    w: &mut [[f32; BLOCK]; 8],
) {
    let Level { res, size } = lv;
    let (pos, cnt) = block_positions(pts, start);
    let r = _mm256_set1_ps(res as f32);
    let zero = _mm256_setzero_ps();
    let one = _mm256_set1_ps(1.0);
    let top = _mm256_set1_epi32((res - 1) as i32);
    let mask = _mm256_set1_epi32((size as u32).wrapping_sub(1) as i32);
    let stride = res + 1;
    let mult: [u32; 3] = if DENSE {
        [1, stride, stride.wrapping_mul(stride)]
    } else {
        HASH_PRIMES
    };
    for h in 0..BLOCK / 8 {
        let mut lo = [_mm256_setzero_si256(); 3];
        let mut hi = [_mm256_setzero_si256(); 3];
        let mut fr = [zero; 3];
        let mut om = [zero; 3];
        for a in 0..3 {
            let x = _mm256_mul_ps(_mm256_loadu_ps(pos[a].as_ptr().add(8 * h)), r);
            // x > 0 ? min(x, r) : +0 — NaN, negatives and −0 become +0, as the portable loop.
            let x = _mm256_and_ps(_mm256_cmp_ps::<_CMP_GT_OQ>(x, zero), _mm256_min_ps(x, r));
            // x ∈ [0, r] with r < 2²⁴: truncation is floor; keep one cell below r.
            let i0 = _mm256_min_epu32(_mm256_cvttps_epi32(x), top);
            fr[a] = _mm256_sub_ps(x, _mm256_cvtepi32_ps(i0));
            om[a] = _mm256_sub_ps(one, fr[a]);
            let m = _mm256_set1_epi32(mult[a] as i32);
            lo[a] = _mm256_mullo_epi32(i0, m);
            hi[a] = _mm256_mullo_epi32(_mm256_add_epi32(i0, _mm256_set1_epi32(1)), m);
        }
        let lane = _mm256_add_epi32(
            _mm256_set1_epi32(8 * h as i32),
            _mm256_setr_epi32(0, 1, 2, 3, 4, 5, 6, 7),
        );
        let live = _mm256_cmpgt_epi32(_mm256_set1_epi32(cnt as i32), lane);
        let valid = _mm256_and_ps(_mm256_castsi256_ps(live), one);
        for c in 0..8 {
            let (bx, by, bz) = (c & 1 == 1, (c >> 1) & 1 == 1, (c >> 2) & 1 == 1);
            let ix = if bx { hi[0] } else { lo[0] };
            let iy = if by { hi[1] } else { lo[1] };
            let iz = if bz { hi[2] } else { lo[2] };
            let e = if DENSE {
                _mm256_add_epi32(_mm256_add_epi32(ix, iy), iz)
            } else {
                _mm256_and_si256(_mm256_xor_si256(_mm256_xor_si256(ix, iy), iz), mask)
            };
            let e = _mm256_and_si256(e, live);
            _mm256_storeu_si256(idx[c].as_mut_ptr().add(8 * h) as *mut __m256i, e);
            let wx = if bx { fr[0] } else { om[0] };
            let wy = if by { fr[1] } else { om[1] };
            let wz = if bz { fr[2] } else { om[2] };
            let wc = _mm256_mul_ps(_mm256_mul_ps(_mm256_mul_ps(wx, wy), wz), valid);
            _mm256_storeu_ps(w[c].as_mut_ptr().add(8 * h), wc);
        }
    }
}

/// Two-feature levels: blends the 8 corner entries of 16 points into rows `0` and `1` of
/// `out`. The entries are loaded in the order `i0 i1 i4 i5` / `i2 i3 i6 i7` so that one in-lane
/// shuffle de-interleaves the two features in point order; blending is the same separate
/// multiply and add, in the same corner order, as the scalar loop (so the bits match it).
///
/// # Safety
/// AVX2 must be available; `idx` entries must be `< t.len() / 2`; `out` must hold rows `0`
/// and `1` (stride `ld`) up to column `start + 16`.
#[target_feature(enable = "avx2,fma,bmi1,popcnt")]
pub(super) unsafe fn gather2_block(
    t: &[f32],
    idx: &[[u32; BLOCK]; 8],
    w: &[[f32; BLOCK]; 8],
    out: &mut [f32],
    ld: usize,
    start: usize,
) {
    let base = t.as_ptr() as *const f64;
    for h in 0..BLOCK / 8 {
        let mut a0 = _mm256_setzero_ps();
        let mut a1 = _mm256_setzero_ps();
        for c in 0..8 {
            let e = idx[c].as_ptr().add(8 * h);
            let at = |k: usize| base.add(*e.add(k) as usize);
            // Entries of points 0, 1, 4, 5 and 2, 3, 6, 7 (two floats each).
            let g0 = _mm256_castpd_ps(_mm256_set_m128d(
                _mm_loadh_pd(_mm_load_sd(at(4)), at(5)),
                _mm_loadh_pd(_mm_load_sd(at(0)), at(1)),
            ));
            let g1 = _mm256_castpd_ps(_mm256_set_m128d(
                _mm_loadh_pd(_mm_load_sd(at(6)), at(7)),
                _mm_loadh_pd(_mm_load_sd(at(2)), at(3)),
            ));
            let f0 = _mm256_shuffle_ps::<0x88>(g0, g1);
            let f1 = _mm256_shuffle_ps::<0xDD>(g0, g1);
            let wc = _mm256_loadu_ps(w[c].as_ptr().add(8 * h));
            a0 = _mm256_add_ps(a0, _mm256_mul_ps(wc, f0));
            a1 = _mm256_add_ps(a1, _mm256_mul_ps(wc, f1));
        }
        _mm256_storeu_ps(out.as_mut_ptr().add(start + 8 * h), a0);
        _mm256_storeu_ps(out.as_mut_ptr().add(ld + start + 8 * h), a1);
    }
}
