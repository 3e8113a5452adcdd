//! The moment sums of the paired vertical pass (`fused::vertical_pair`) with explicit AVX2
//! fused multiply-adds (the auto-vectorised form of the paired loop compiles to scalar code).
//! Each sum is `fma(w_k, value, sum)` from +0 over k in ascending order, exactly as
//! `fused::vertical_row`'s `mul_add`s, so the bits are the same.

use super::fused::{HALO, RING};
use super::{LANES, SSIM_WINDOW};
use std::arch::x86_64::*;

/// Moments of map rows oy (`m0`) and oy + 1 (`m1`) for the `LANES` values from `j`:
/// moment row k (ring offset `base[k]`) feeds `m0` with weight `win[k]` and `m1` with
/// weight `win[k − 1]`.
///
/// # Safety
/// The CPU must have AVX2 and FMA, and `base[k] + 4·mp + j + LANES ≤ hm.len()` for all k.
// Index loops over the five moments: each is one register.
#[allow(clippy::needless_range_loop)]
#[target_feature(enable = "avx2,fma")]
#[inline]
pub(super) unsafe fn moments(
    hm: &[f32],
    base: &[usize; RING],
    mp: usize,
    j: usize,
    win: &[f32; SSIM_WINDOW],
    m0: &mut [[f32; LANES]; 5],
    m1: &mut [[f32; LANES]; 5],
) {
    let p = hm.as_ptr();
    for h in (0..LANES).step_by(8) {
        let mut a0 = [_mm256_setzero_ps(); 5];
        let mut a1 = [_mm256_setzero_ps(); 5];
        let w = _mm256_set1_ps(win[0]);
        for q in 0..5 {
            let s = _mm256_loadu_ps(p.add(base[0] + q * mp + j + h));
            a0[q] = _mm256_fmadd_ps(w, s, a0[q]);
        }
        for k in 1..SSIM_WINDOW {
            let (wa, wb) = (_mm256_set1_ps(win[k]), _mm256_set1_ps(win[k - 1]));
            for q in 0..5 {
                let s = _mm256_loadu_ps(p.add(base[k] + q * mp + j + h));
                a0[q] = _mm256_fmadd_ps(wa, s, a0[q]);
                a1[q] = _mm256_fmadd_ps(wb, s, a1[q]);
            }
        }
        let w = _mm256_set1_ps(win[HALO]);
        for q in 0..5 {
            let s = _mm256_loadu_ps(p.add(base[SSIM_WINDOW] + q * mp + j + h));
            a1[q] = _mm256_fmadd_ps(w, s, a1[q]);
        }
        for q in 0..5 {
            _mm256_storeu_ps(m0[q].as_mut_ptr().add(h), a0[q]);
            _mm256_storeu_ps(m1[q].as_mut_ptr().add(h), a1[q]);
        }
    }
}
