//! AVX2 lanes: eight f64 in two ymm registers, the same IEEE operation per lane as the
//! portable lanes ([`super::P8`]), so bit-identical to them.

use super::math::ROUND_MAGIC;
use super::{Lanes, Mask, COLUMNS, LANES, MANTISSA, ONE_BITS};
use std::arch::x86_64::*;
use std::ops::{Add, Div, Mul, Neg, Sub};

/// Eight f64 lanes in two AVX registers (lanes 0–3, 4–7).
///
/// Values of this type exist only inside code that runs after AVX2 and FMA were detected
/// (the `target_feature` wrappers of the projection): every method uses AVX2
/// instructions. No method fuses a multiply-add.
#[derive(Clone, Copy, Debug)]
pub(crate) struct Y8(__m256d, __m256d);

// The halves are written out by these macros rather than passed to closures: a closure
// is a function of its own without the target features, so the intrinsics in it would
// not always be inlined.

/// `Y8(f(a.0), f(a.1))` for the expression `f` of `$x`.
macro_rules! map {
    ($a:expr, |$x:ident| $f:expr) => {{
        let a = $a;
        // SAFETY: see the type's invariant.
        unsafe {
            let $x = a.0;
            let lo = $f;
            let $x = a.1;
            Y8(lo, $f)
        }
    }};
}

/// `Y8(f(a.0, b.0), f(a.1, b.1))` for the expression `f` of `$x`, `$y`.
macro_rules! zip {
    ($a:expr, $b:expr, |$x:ident, $y:ident| $f:expr) => {{
        let (a, b) = ($a, $b);
        // SAFETY: see the type's invariant.
        unsafe {
            let ($x, $y) = (a.0, b.0);
            let lo = $f;
            let ($x, $y) = (a.1, b.1);
            Y8(lo, $f)
        }
    }};
}

/// The sign bits of the lanes of `zip!(...)` as a mask.
macro_rules! test {
    ($a:expr, $b:expr, |$x:ident, $y:ident| $f:expr) => {{
        let v = zip!($a, $b, |$x, $y| $f);
        // SAFETY: see the type's invariant.
        unsafe { (_mm256_movemask_pd(v.0) as u8) | ((_mm256_movemask_pd(v.1) as u8) << 4) }
    }};
}

/// Lane `l` all ones where bit `l` of `m` is set (`m`: four bits).
#[inline(always)]
unsafe fn lane_select(m: u8) -> __m256d {
    let sel = _mm256_setr_epi64x(1, 2, 4, 8);
    let v = _mm256_and_si256(_mm256_set1_epi64x(m as i64), sel);
    _mm256_castsi256_pd(_mm256_cmpeq_epi64(v, sel))
}

macro_rules! y8_op {
    ($tr:ident, $f:ident, $intr:ident) => {
        impl $tr for Y8 {
            type Output = Self;
            #[inline(always)]
            fn $f(self, o: Self) -> Self {
                zip!(self, o, |a, b| $intr(a, b))
            }
        }
        impl $tr<f64> for Y8 {
            type Output = Self;
            #[inline(always)]
            fn $f(self, o: f64) -> Self {
                map!(self, |a| $intr(a, _mm256_set1_pd(o)))
            }
        }
    };
}
y8_op!(Add, add, _mm256_add_pd);
y8_op!(Sub, sub, _mm256_sub_pd);
y8_op!(Mul, mul, _mm256_mul_pd);
y8_op!(Div, div, _mm256_div_pd);

impl Neg for Y8 {
    type Output = Self;
    #[inline(always)]
    fn neg(self) -> Self {
        // Flips the sign bit, as `-x` does.
        map!(self, |a| _mm256_xor_pd(a, _mm256_set1_pd(-0.0)))
    }
}

/// The 8×8 transpose of eight vectors of eight f32 (pairs of rows interleaved, then
/// quads, then the 128-bit halves): lane l of output i is lane i of input l.
///
/// # Safety
/// The CPU must support AVX (see [`Y8`]'s invariant).
#[inline(always)]
unsafe fn transpose8(r: [__m256; 8]) -> [__m256; 8] {
    let t0 = _mm256_unpacklo_ps(r[0], r[1]);
    let t1 = _mm256_unpackhi_ps(r[0], r[1]);
    let t2 = _mm256_unpacklo_ps(r[2], r[3]);
    let t3 = _mm256_unpackhi_ps(r[2], r[3]);
    let t4 = _mm256_unpacklo_ps(r[4], r[5]);
    let t5 = _mm256_unpackhi_ps(r[4], r[5]);
    let t6 = _mm256_unpacklo_ps(r[6], r[7]);
    let t7 = _mm256_unpackhi_ps(r[6], r[7]);
    let u0 = _mm256_shuffle_ps::<0x44>(t0, t2);
    let u1 = _mm256_shuffle_ps::<0xEE>(t0, t2);
    let u2 = _mm256_shuffle_ps::<0x44>(t1, t3);
    let u3 = _mm256_shuffle_ps::<0xEE>(t1, t3);
    let u4 = _mm256_shuffle_ps::<0x44>(t4, t6);
    let u5 = _mm256_shuffle_ps::<0xEE>(t4, t6);
    let u6 = _mm256_shuffle_ps::<0x44>(t5, t7);
    let u7 = _mm256_shuffle_ps::<0xEE>(t5, t7);
    [
        _mm256_permute2f128_ps::<0x20>(u0, u4),
        _mm256_permute2f128_ps::<0x20>(u1, u5),
        _mm256_permute2f128_ps::<0x20>(u2, u6),
        _mm256_permute2f128_ps::<0x20>(u3, u7),
        _mm256_permute2f128_ps::<0x31>(u0, u4),
        _mm256_permute2f128_ps::<0x31>(u1, u5),
        _mm256_permute2f128_ps::<0x31>(u2, u6),
        _mm256_permute2f128_ps::<0x31>(u3, u7),
    ]
}

impl Lanes for Y8 {
    #[inline(always)]
    fn splat(v: f64) -> Self {
        // SAFETY: see the type's invariant.
        unsafe { Y8(_mm256_set1_pd(v), _mm256_set1_pd(v)) }
    }
    #[inline(always)]
    fn from_array(v: [f64; LANES]) -> Self {
        // SAFETY: see the type's invariant; reads 8 f64.
        unsafe {
            Y8(
                _mm256_loadu_pd(v.as_ptr()),
                _mm256_loadu_pd(v.as_ptr().add(4)),
            )
        }
    }
    #[inline(always)]
    fn to_array(self) -> [f64; LANES] {
        let mut o = [0.0; LANES];
        // SAFETY: see the type's invariant; writes 8 f64.
        unsafe {
            _mm256_storeu_pd(o.as_mut_ptr(), self.0);
            _mm256_storeu_pd(o.as_mut_ptr().add(4), self.1);
        }
        o
    }
    #[inline(always)]
    fn sqrt(self) -> Self {
        map!(self, |a| _mm256_sqrt_pd(a))
    }
    #[inline(always)]
    fn ceil(self) -> Self {
        map!(self, |a| {
            _mm256_round_pd::<{ _MM_FROUND_TO_POS_INF | _MM_FROUND_NO_EXC }>(a)
        })
    }
    #[inline(always)]
    fn floor(self) -> Self {
        map!(self, |a| {
            _mm256_round_pd::<{ _MM_FROUND_TO_NEG_INF | _MM_FROUND_NO_EXC }>(a)
        })
    }
    #[inline(always)]
    fn trunc(self) -> Self {
        map!(self, |a| {
            _mm256_round_pd::<{ _MM_FROUND_TO_ZERO | _MM_FROUND_NO_EXC }>(a)
        })
    }
    #[inline(always)]
    fn min(self, o: Self) -> Self {
        // MINPD: `a < b ? a : b`.
        zip!(self, o, |a, b| _mm256_min_pd(a, b))
    }
    #[inline(always)]
    fn max(self, o: Self) -> Self {
        // MAXPD: `a > b ? a : b`.
        zip!(self, o, |a, b| _mm256_max_pd(a, b))
    }
    #[inline(always)]
    fn lt(self, o: Self) -> Mask {
        test!(self, o, |a, b| _mm256_cmp_pd::<_CMP_LT_OQ>(a, b))
    }
    #[inline(always)]
    fn le(self, o: Self) -> Mask {
        test!(self, o, |a, b| _mm256_cmp_pd::<_CMP_LE_OQ>(a, b))
    }
    #[inline(always)]
    fn gt(self, o: Self) -> Mask {
        test!(self, o, |a, b| _mm256_cmp_pd::<_CMP_GT_OQ>(a, b))
    }
    #[inline(always)]
    fn ge(self, o: Self) -> Mask {
        test!(self, o, |a, b| _mm256_cmp_pd::<_CMP_GE_OQ>(a, b))
    }
    #[inline(always)]
    fn eq(self, o: Self) -> Mask {
        test!(self, o, |a, b| _mm256_cmp_pd::<_CMP_EQ_OQ>(a, b))
    }
    #[inline(always)]
    fn is_finite(self) -> Mask {
        // |x| < ∞ (false for NaN).
        test!(self, self, |a, _b| _mm256_cmp_pd::<_CMP_LT_OQ>(
            _mm256_andnot_pd(_mm256_set1_pd(-0.0), a),
            _mm256_set1_pd(f64::INFINITY)
        ))
    }
    #[inline(always)]
    fn select(m: Mask, a: Self, b: Self) -> Self {
        // SAFETY: see the type's invariant.
        unsafe {
            Y8(
                _mm256_blendv_pd(b.0, a.0, lane_select(m & 0xf)),
                _mm256_blendv_pd(b.1, a.1, lane_select(m >> 4)),
            )
        }
    }
    #[inline(always)]
    fn pow2(self) -> Self {
        // k + 1023 + 1.5·2⁵² is exact for integral k in [−1022, 1023] and holds k + 1023
        // in its low mantissa bits; the shift keeps exactly those 11 bits as the biased
        // exponent, as the portable lanes build it.
        map!(self, |k| _mm256_castsi256_pd(_mm256_slli_epi64::<52>(
            _mm256_castpd_si256(_mm256_add_pd(k, _mm256_set1_pd(1023.0 + ROUND_MAGIC)))
        )))
    }
    #[inline(always)]
    fn split_exponent(self) -> (Self, Self) {
        // The biased exponent b ∈ [0, 2047] becomes a double exactly as the bits of
        // 2⁵² + b minus 2⁵².
        let two52 = 4_503_599_627_370_496.0;
        let e = map!(self, |x| _mm256_sub_pd(
            _mm256_sub_pd(
                _mm256_castsi256_pd(_mm256_or_si256(
                    _mm256_and_si256(
                        _mm256_srli_epi64::<52>(_mm256_castpd_si256(x)),
                        _mm256_set1_epi64x(0x7ff)
                    ),
                    _mm256_castpd_si256(_mm256_set1_pd(two52))
                )),
                _mm256_set1_pd(two52)
            ),
            _mm256_set1_pd(1023.0)
        ));
        let m = map!(self, |x| _mm256_castsi256_pd(_mm256_or_si256(
            _mm256_and_si256(_mm256_castpd_si256(x), _mm256_set1_epi64x(MANTISSA as i64)),
            _mm256_set1_epi64x(ONE_BITS as i64)
        )));
        (e, m)
    }
    /// Eight values of all eight rows at a time: an 8×8 transpose in registers (unpack,
    /// shuffle, 128-bit permute), then each column widened to f64.
    #[inline(always)]
    fn columns(rows: &[[f32; COLUMNS]; LANES], n: usize) -> [Self; COLUMNS] {
        // Every element is written below (whole blocks of eight; zeros past the blocks
        // `n` needs), so the array is not filled first.
        let mut out = [const { std::mem::MaybeUninit::<Self>::uninit() }; COLUMNS];
        let blocks = n.min(COLUMNS).div_ceil(8);
        for q in 8 * blocks..COLUMNS {
            out[q].write(Self::splat(0.0));
        }
        for b in 0..blocks {
            let q0 = 8 * b;
            // SAFETY: see the type's invariant; q0 + 8 ≤ COLUMNS, so every load is in
            // bounds.
            unsafe {
                let r: [__m256; 8] = [
                    _mm256_loadu_ps(rows[0].as_ptr().add(q0)),
                    _mm256_loadu_ps(rows[1].as_ptr().add(q0)),
                    _mm256_loadu_ps(rows[2].as_ptr().add(q0)),
                    _mm256_loadu_ps(rows[3].as_ptr().add(q0)),
                    _mm256_loadu_ps(rows[4].as_ptr().add(q0)),
                    _mm256_loadu_ps(rows[5].as_ptr().add(q0)),
                    _mm256_loadu_ps(rows[6].as_ptr().add(q0)),
                    _mm256_loadu_ps(rows[7].as_ptr().add(q0)),
                ];
                let c = transpose8(r);
                for i in 0..8 {
                    out[q0 + i].write(Y8(
                        _mm256_cvtps_pd(_mm256_castps256_ps128(c[i])),
                        _mm256_cvtps_pd(_mm256_extractf128_ps::<1>(c[i])),
                    ));
                }
            }
        }
        // SAFETY: all COLUMNS elements were written above.
        unsafe { std::mem::transmute::<_, [Self; COLUMNS]>(out) }
    }
    /// Eight columns at a time: each narrowed to f32 (as `as f32` rounds), then the 8×8
    /// transpose of [`Lanes::columns`] (it is its own inverse).
    #[inline(always)]
    fn rows(cols: &[Self; COLUMNS], n: usize) -> [[f32; COLUMNS]; LANES] {
        let mut out = [[0.0f32; COLUMNS]; LANES];
        let n = n.min(COLUMNS);
        for b in 0..n / 8 {
            let q0 = 8 * b;
            // SAFETY: see the type's invariant; q0 + 8 ≤ COLUMNS, so every store is in
            // bounds.
            unsafe {
                let mut r = [_mm256_setzero_ps(); 8];
                for i in 0..8 {
                    let c = cols[q0 + i];
                    r[i] = _mm256_set_m128(_mm256_cvtpd_ps(c.1), _mm256_cvtpd_ps(c.0));
                }
                let rows = transpose8(r);
                for l in 0..8 {
                    _mm256_storeu_ps(out[l].as_mut_ptr().add(q0), rows[l]);
                }
            }
        }
        // The last partial block lane by lane.
        for q in n / 8 * 8..n {
            let a = cols[q].to_array();
            for (row, v) in out.iter_mut().zip(a) {
                row[q] = v as f32;
            }
        }
        out
    }
}
