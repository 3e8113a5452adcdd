//! The base-2 exponential of the tile kernels and the per-row geometry that feeds it.
//!
//! The kernels never form σ: each row's coefficients ([`RowGeom`]) are those of σ scaled by
//! −log₂e, so two fused multiply-adds per pixel give the exponent in bits ex = −σ·log₂e, and
//! e^−σ = 2^ex. ex is clamped to [−44, 0], split as n + f with n an integer and |f| ≤ ½ (the
//! 1.5·2²³ rounding trick; the subtraction is exact), and 2^f comes from a degree-5 minimax
//! polynomial in Estrin's form (relative error below 2.4e-7), 2ⁿ from the exponent bits. That
//! is a dependency chain of about nine operations per α. The AVX2 kernels (`super::avx2`)
//! perform exactly these operations lane-wise.

use super::{Splat2D, SIGMA_CLAMP};

/// log₂e: the kernels evaluate the exponent in bits, −σ·log₂e, so that e^−σ = 2^(−σ·log₂e).
pub(super) const LOG2E: f32 = std::f32::consts::LOG2_E;
/// ½·log₂e, the factor of the conic's diagonal terms in σ·log₂e.
pub(super) const HALF_LOG2E: f32 = 0.5 * std::f32::consts::LOG2_E;
/// 1.5·2²³: adding it rounds to an integer held in the low mantissa bits.
pub(super) const ROUND: f32 = 12_582_912.0;
/// Added (wrapping) to the bits of x + ROUND, gives n + 127 in the low bits (n = round(x)).
pub(super) const EXP_BIAS_FROM_ROUND: u32 = 127u32.wrapping_sub(ROUND.to_bits());
/// Minimax polynomial of 2^f on |f| ≤ ½ (relative error), lowest degree first. Evaluated in
/// f32 by Estrin's scheme ([`poly5`]) its relative error stays below 2.4e-7.
pub(super) const EXP2_POLY: [f32; 6] = [
    1.000_000_1,
    6.931_469_4e-1,
    2.402_212e-1,
    5.550_713e-2,
    9.675_541e-3,
    1.327_647_1e-3,
];

/// The degree-5 polynomial `EXP2_POLY` at f by Estrin's scheme:
/// `(c0 + c1·f) + f²·((c2 + c3·f) + f²·(c4 + c5·f))` — a dependency chain of three fused
/// multiply-adds instead of Horner's five.
#[inline(always)]
pub(super) fn poly5(f: f32) -> f32 {
    let c = &EXP2_POLY;
    let f2 = f * f;
    let lo = c[1].mul_add(f, c[0]);
    let mid = c[3].mul_add(f, c[2]);
    let hi = c[5].mul_add(f, c[4]);
    hi.mul_add(f2, mid).mul_add(f2, lo)
}

/// 2^x for x ≤ 0 (inputs below −126 are clamped), branch-free and free of float→int
/// conversions so it vectorises; relative error below 2.4e-7.
#[inline(always)]
pub fn exp2_neg(x: f32) -> f32 {
    exp2_core(x.clamp(-126.0, 0.0))
}

/// 2^x for x in [−126, 0] (unchecked): x = n + f with n the nearest integer, 2^x = 2ⁿ·p(f).
/// The subtraction x − n is exact, so the only rounding is in the polynomial; the AVX2
/// kernels perform exactly these operations.
#[inline(always)]
pub(crate) fn exp2_core(x: f32) -> f32 {
    let shifted = x + ROUND;
    let n = shifted - ROUND;
    let p = poly5(x - n);
    // n + 127 in the low bits: (bits(shifted) − bits(ROUND)) + 127 as one wrapping add.
    let scale = f32::from_bits(shifted.to_bits().wrapping_add(EXP_BIAS_FROM_ROUND) << 23);
    p * scale
}

/// e^−σ as the kernels evaluate it, from the exponent in bits `ex` = −σ·log₂e (as
/// [`RowGeom::exponent`] gives it): clamped to [−SIGMA_CLAMP, 0] first, then 2^ex.
#[inline(always)]
pub(crate) fn gauss_of_exponent(ex: f32) -> f32 {
    // Not `clamp`: a NaN must become −SIGMA_CLAMP here, as `_mm256_max_ps` makes it (`max`
    // returns the other operand for a NaN). The sign of a zero does not matter: 2^±0 is the
    // same value.
    #[allow(clippy::manual_clamp)]
    let x = ex.max(-SIGMA_CLAMP).min(0.0);
    exp2_core(x)
}

/// Per-row scalars of one Gaussian. The kernels' exponent in bits, ex = −σ·log₂e (the
/// argument of their base-2 exponential), on the row at offset dy = y − pixel y is
/// `(ea·dx + eb)·dx + ec` with dx = x − pixel x (two fused multiply-adds per pixel). The
/// coefficients are those of σ·log₂e negated, so `ex` is exactly −(σ·log₂e) as the same
/// multiply-adds would round it (rounding is symmetric), and σ ≥ 0 exactly when ex ≤ 0.
#[derive(Clone, Copy)]
pub(crate) struct RowGeom {
    pub dy: f32,
    pub ea: f32,
    pub eb: f32,
    pub ec: f32,
}

impl RowGeom {
    /// The row-independent coefficient `ea` of `sp` (−½·a·log₂e).
    #[inline(always)]
    pub(crate) fn exp_a(sp: &Splat2D) -> f32 {
        -(HALF_LOG2E * sp.a)
    }

    #[inline(always)]
    pub(crate) fn new(sp: &Splat2D, py: f32) -> Self {
        let dy = sp.y - py;
        RowGeom {
            dy,
            ea: Self::exp_a(sp),
            eb: -(LOG2E * sp.b * dy),
            ec: -(HALF_LOG2E * sp.c * dy * dy),
        }
    }

    /// The exponent in bits, −σ·log₂e, at horizontal offset `dx`.
    #[inline(always)]
    pub(crate) fn exponent(&self, dx: f32) -> f32 {
        self.ea.mul_add(dx, self.eb).mul_add(dx, self.ec)
    }
}
