//! Eight f64 values processed in lock step: the per-Gaussian projection and its backward pass
//! run on eight Gaussians at once through the [`Lanes`] trait, with two implementations: one
//! AVX-512 register ([`avx512::Z8`]) and a portable array ([`P8`]).
//!
//! Every operation is the same IEEE operation on each lane (no fused multiply-adds; exact
//! `sqrt` and division; `min`/`max` follow one stated rule), so both implementations give
//! bit-identical lanes, and a lane's value does not depend on its neighbours. Branches
//! become masks (bit `l` = lane `l`) and selects. [`exp`] and [`ln`] are written here
//! (polynomials within 2 and 4 ulps of libm, tested below) because libm's are scalar calls.

// Lane loops index several arrays in step.
#![allow(clippy::needless_range_loop)]

use std::ops::{Add, Div, Mul, Neg, Sub};

/// Lanes per batch.
pub(crate) const LANES: usize = 8;

/// A lane mask: bit `l` is lane `l`.
pub(crate) type Mask = u8;

/// All eight lanes.
pub(crate) const ALL: Mask = 0xff;

/// Eight f64 lanes.
pub(crate) trait Lanes:
    Copy
    + Add<Output = Self>
    + Sub<Output = Self>
    + Mul<Output = Self>
    + Div<Output = Self>
    + Neg<Output = Self>
    + Add<f64, Output = Self>
    + Sub<f64, Output = Self>
    + Mul<f64, Output = Self>
    + Div<f64, Output = Self>
{
    /// Every lane `v`.
    fn splat(v: f64) -> Self;
    /// Lane `l` is `v[l]`.
    fn from_array(v: [f64; LANES]) -> Self;
    /// The lanes.
    fn to_array(self) -> [f64; LANES];
    /// Square root.
    fn sqrt(self) -> Self;
    /// Rounding up.
    fn ceil(self) -> Self;
    /// Rounding down.
    fn floor(self) -> Self;
    /// Rounding toward zero.
    fn trunc(self) -> Self;
    /// `if self < o { self } else { o }` (so a NaN in either gives `o`).
    fn min(self, o: Self) -> Self;
    /// `if self > o { self } else { o }` (so a NaN in either gives `o`).
    fn max(self, o: Self) -> Self;
    /// `self < o` (false for NaN).
    fn lt(self, o: Self) -> Mask;
    /// `self <= o`.
    fn le(self, o: Self) -> Mask;
    /// `self > o`.
    fn gt(self, o: Self) -> Mask;
    /// `self >= o`.
    fn ge(self, o: Self) -> Mask;
    /// `self == o`.
    fn eq(self, o: Self) -> Mask;
    /// Finite lanes.
    fn is_finite(self) -> Mask;
    /// Lane-wise `if m { a } else { b }`.
    fn select(m: Mask, a: Self, b: Self) -> Self;
    /// 2^k for integral lanes k in [−1022, 1023].
    fn pow2(self) -> Self;
    /// `(e, m)` with `self = m·2^e` and `m ∈ [1, 2)` for positive normal lanes.
    fn split_exponent(self) -> (Self, Self);
    /// The columns of eight rows of f32 values: element `q` has `rows[l][q]` (exactly, as
    /// f64) in lane `l`. Elements from `n` on are unspecified (callers read only `q < n`).
    #[inline(always)]
    fn columns(rows: &[[f32; COLUMNS]; LANES], n: usize) -> [Self; COLUMNS] {
        let mut out = [Self::splat(0.0); COLUMNS];
        for (q, o) in out.iter_mut().enumerate().take(n) {
            let mut a = [0.0; LANES];
            for (v, row) in a.iter_mut().zip(rows) {
                *v = row[q] as f64;
            }
            *o = Self::from_array(a);
        }
        out
    }
    /// The inverse of [`Lanes::columns`], rounding to f32: row `l` has lane `l` of the
    /// elements `q < n` (the rest zero).
    #[inline(always)]
    fn rows(cols: &[Self; COLUMNS], n: usize) -> [[f32; COLUMNS]; LANES] {
        let mut out = [[0.0f32; COLUMNS]; LANES];
        for (q, col) in cols.iter().enumerate().take(n) {
            let a = col.to_array();
            for (row, v) in out.iter_mut().zip(a) {
                row[q] = v as f32;
            }
        }
        out
    }
}

/// Values per row of [`Lanes::columns`] and [`Lanes::rows`] (the SH coefficients of one
/// Gaussian, degree 3).
pub(crate) const COLUMNS: usize = 48;

/// Whether this CPU runs the AVX-512 lanes (always false off x86-64).
pub(crate) fn wide_available() -> bool {
    #[cfg(target_arch = "x86_64")]
    {
        avx512::available()
    }
    #[cfg(not(target_arch = "x86_64"))]
    {
        false
    }
}

/// The constant `v` in every lane.
#[inline(always)]
pub(crate) fn c<L: Lanes>(v: f64) -> L {
    L::splat(v)
}

/// The lanes of each of `v`'s members. A loop rather than `array::map`: a closure is a
/// function of its own, compiled without the caller's target features, so the vector
/// instructions in it would not be inlined.
#[inline(always)]
pub(crate) fn to_arrays<L: Lanes, const N: usize>(v: [L; N]) -> [[f64; LANES]; N] {
    let mut out = [[0.0; LANES]; N];
    for (o, x) in out.iter_mut().zip(v) {
        *o = x.to_array();
    }
    out
}

/// `[c(v[0]), c(v[1]), …]` (a loop, for the reason given at [`to_arrays`]).
#[inline(always)]
pub(crate) fn splats<L: Lanes, const N: usize>(v: [f64; N]) -> [L; N] {
    let mut out = [L::splat(0.0); N];
    for (o, x) in out.iter_mut().zip(v) {
        *o = L::splat(x);
    }
    out
}

/// The portable lanes.
#[derive(Clone, Copy, Debug, PartialEq)]
pub(crate) struct P8(pub [f64; LANES]);

impl P8 {
    #[inline(always)]
    fn map(self, f: impl Fn(f64) -> f64) -> Self {
        let mut o = self.0;
        for v in o.iter_mut() {
            *v = f(*v);
        }
        P8(o)
    }
    #[inline(always)]
    fn zip(self, b: Self, f: impl Fn(f64, f64) -> f64) -> Self {
        let mut o = self.0;
        for l in 0..LANES {
            o[l] = f(o[l], b.0[l]);
        }
        P8(o)
    }
    #[inline(always)]
    fn test(self, b: Self, f: impl Fn(f64, f64) -> bool) -> Mask {
        let mut m = 0;
        for l in 0..LANES {
            m |= (f(self.0[l], b.0[l]) as u8) << l;
        }
        m
    }
}

macro_rules! p8_op {
    ($tr:ident, $f:ident, $op:tt) => {
        impl $tr for P8 {
            type Output = Self;
            #[inline(always)]
            fn $f(self, o: Self) -> Self {
                self.zip(o, |a, b| a $op b)
            }
        }
        impl $tr<f64> for P8 {
            type Output = Self;
            #[inline(always)]
            fn $f(self, o: f64) -> Self {
                self.map(|a| a $op o)
            }
        }
    };
}
p8_op!(Add, add, +);
p8_op!(Sub, sub, -);
p8_op!(Mul, mul, *);
p8_op!(Div, div, /);

impl Neg for P8 {
    type Output = Self;
    #[inline(always)]
    fn neg(self) -> Self {
        self.map(|a| -a)
    }
}

impl Lanes for P8 {
    #[inline(always)]
    fn splat(v: f64) -> Self {
        P8([v; LANES])
    }
    #[inline(always)]
    fn from_array(v: [f64; LANES]) -> Self {
        P8(v)
    }
    #[inline(always)]
    fn to_array(self) -> [f64; LANES] {
        self.0
    }
    #[inline(always)]
    fn sqrt(self) -> Self {
        self.map(f64::sqrt)
    }
    #[inline(always)]
    fn ceil(self) -> Self {
        self.map(f64::ceil)
    }
    #[inline(always)]
    fn floor(self) -> Self {
        self.map(f64::floor)
    }
    #[inline(always)]
    fn trunc(self) -> Self {
        self.map(f64::trunc)
    }
    #[inline(always)]
    fn min(self, o: Self) -> Self {
        self.zip(o, |a, b| if a < b { a } else { b })
    }
    #[inline(always)]
    fn max(self, o: Self) -> Self {
        self.zip(o, |a, b| if a > b { a } else { b })
    }
    #[inline(always)]
    fn lt(self, o: Self) -> Mask {
        self.test(o, |a, b| a < b)
    }
    #[inline(always)]
    fn le(self, o: Self) -> Mask {
        self.test(o, |a, b| a <= b)
    }
    #[inline(always)]
    fn gt(self, o: Self) -> Mask {
        self.test(o, |a, b| a > b)
    }
    #[inline(always)]
    fn ge(self, o: Self) -> Mask {
        self.test(o, |a, b| a >= b)
    }
    #[inline(always)]
    fn eq(self, o: Self) -> Mask {
        self.test(o, |a, b| a == b)
    }
    #[inline(always)]
    fn is_finite(self) -> Mask {
        self.test(self, |a, _| a.is_finite())
    }
    #[inline(always)]
    fn select(m: Mask, a: Self, b: Self) -> Self {
        let mut o = b.0;
        for l in 0..LANES {
            if (m >> l) & 1 == 1 {
                o[l] = a.0[l];
            }
        }
        P8(o)
    }
    #[inline(always)]
    fn pow2(self) -> Self {
        self.map(|k| f64::from_bits(((k as i64 + 1023) as u64) << 52))
    }
    #[inline(always)]
    fn split_exponent(self) -> (Self, Self) {
        let e = self.map(|x| ((x.to_bits() >> 52) & 0x7ff) as f64 - 1023.0);
        let m = self.map(|x| f64::from_bits((x.to_bits() & MANTISSA) | ONE_BITS));
        (e, m)
    }
}

const MANTISSA: u64 = 0x000f_ffff_ffff_ffff;
const ONE_BITS: u64 = 0x3ff0_0000_0000_0000;

/// AVX-512 lanes.
#[cfg(target_arch = "x86_64")]
pub(crate) mod avx512 {
    use super::*;
    use std::arch::x86_64::*;

    /// Eight f64 lanes in one AVX-512 register.
    ///
    /// Values of this type exist only inside code that runs after AVX-512F/DQ were detected
    /// (the `target_feature` wrappers of the projection): every method uses those
    /// instructions.
    #[derive(Clone, Copy, Debug)]
    pub(crate) struct Z8(__m512d);

    /// Whether the CPU runs [`Z8`].
    pub(crate) fn available() -> bool {
        std::arch::is_x86_feature_detected!("avx512f")
            && std::arch::is_x86_feature_detected!("avx512dq")
    }

    macro_rules! z8_op {
        ($tr:ident, $f:ident, $intr:ident) => {
            impl $tr for Z8 {
                type Output = Self;
                #[inline(always)]
                fn $f(self, o: Self) -> Self {
                    // SAFETY: see the type's invariant.
                    Z8(unsafe { $intr(self.0, o.0) })
                }
            }
            impl $tr<f64> for Z8 {
                type Output = Self;
                #[inline(always)]
                fn $f(self, o: f64) -> Self {
                    // SAFETY: see the type's invariant.
                    Z8(unsafe { $intr(self.0, _mm512_set1_pd(o)) })
                }
            }
        };
    }
    z8_op!(Add, add, _mm512_add_pd);
    z8_op!(Sub, sub, _mm512_sub_pd);
    z8_op!(Mul, mul, _mm512_mul_pd);
    z8_op!(Div, div, _mm512_div_pd);

    impl Neg for Z8 {
        type Output = Self;
        #[inline(always)]
        fn neg(self) -> Self {
            // SAFETY: see the type's invariant. Flips the sign bit, as `-x` does.
            Z8(unsafe { _mm512_xor_pd(self.0, _mm512_set1_pd(-0.0)) })
        }
    }

    impl Lanes for Z8 {
        #[inline(always)]
        fn splat(v: f64) -> Self {
            // SAFETY: see the type's invariant.
            Z8(unsafe { _mm512_set1_pd(v) })
        }
        #[inline(always)]
        fn from_array(v: [f64; LANES]) -> Self {
            // SAFETY: see the type's invariant; reads 8 f64.
            Z8(unsafe { _mm512_loadu_pd(v.as_ptr()) })
        }
        #[inline(always)]
        fn to_array(self) -> [f64; LANES] {
            let mut o = [0.0; LANES];
            // SAFETY: see the type's invariant; writes 8 f64.
            unsafe { _mm512_storeu_pd(o.as_mut_ptr(), self.0) };
            o
        }
        #[inline(always)]
        fn sqrt(self) -> Self {
            // SAFETY: see the type's invariant.
            Z8(unsafe { _mm512_sqrt_pd(self.0) })
        }
        #[inline(always)]
        fn ceil(self) -> Self {
            // SAFETY: see the type's invariant.
            Z8(unsafe {
                _mm512_roundscale_pd::<{ _MM_FROUND_TO_POS_INF | _MM_FROUND_NO_EXC }>(self.0)
            })
        }
        #[inline(always)]
        fn floor(self) -> Self {
            // SAFETY: see the type's invariant.
            Z8(unsafe {
                _mm512_roundscale_pd::<{ _MM_FROUND_TO_NEG_INF | _MM_FROUND_NO_EXC }>(self.0)
            })
        }
        #[inline(always)]
        fn trunc(self) -> Self {
            // SAFETY: see the type's invariant.
            Z8(unsafe {
                _mm512_roundscale_pd::<{ _MM_FROUND_TO_ZERO | _MM_FROUND_NO_EXC }>(self.0)
            })
        }
        #[inline(always)]
        fn min(self, o: Self) -> Self {
            // SAFETY: see the type's invariant. MINPD: `a < b ? a : b`.
            Z8(unsafe { _mm512_min_pd(self.0, o.0) })
        }
        #[inline(always)]
        fn max(self, o: Self) -> Self {
            // SAFETY: see the type's invariant. MAXPD: `a > b ? a : b`.
            Z8(unsafe { _mm512_max_pd(self.0, o.0) })
        }
        #[inline(always)]
        fn lt(self, o: Self) -> Mask {
            // SAFETY: see the type's invariant.
            unsafe { _mm512_cmp_pd_mask::<_CMP_LT_OQ>(self.0, o.0) }
        }
        #[inline(always)]
        fn le(self, o: Self) -> Mask {
            // SAFETY: see the type's invariant.
            unsafe { _mm512_cmp_pd_mask::<_CMP_LE_OQ>(self.0, o.0) }
        }
        #[inline(always)]
        fn gt(self, o: Self) -> Mask {
            // SAFETY: see the type's invariant.
            unsafe { _mm512_cmp_pd_mask::<_CMP_GT_OQ>(self.0, o.0) }
        }
        #[inline(always)]
        fn ge(self, o: Self) -> Mask {
            // SAFETY: see the type's invariant.
            unsafe { _mm512_cmp_pd_mask::<_CMP_GE_OQ>(self.0, o.0) }
        }
        #[inline(always)]
        fn eq(self, o: Self) -> Mask {
            // SAFETY: see the type's invariant.
            unsafe { _mm512_cmp_pd_mask::<_CMP_EQ_OQ>(self.0, o.0) }
        }
        #[inline(always)]
        fn is_finite(self) -> Mask {
            // SAFETY: see the type's invariant. |x| < ∞ (false for NaN).
            unsafe {
                let abs = _mm512_abs_pd(self.0);
                _mm512_cmp_pd_mask::<_CMP_LT_OQ>(abs, _mm512_set1_pd(f64::INFINITY))
            }
        }
        #[inline(always)]
        fn select(m: Mask, a: Self, b: Self) -> Self {
            // SAFETY: see the type's invariant.
            Z8(unsafe { _mm512_mask_blend_pd(m, b.0, a.0) })
        }
        #[inline(always)]
        fn pow2(self) -> Self {
            // SAFETY: see the type's invariant (AVX-512DQ converts to i64 exactly for these
            // integral lanes).
            unsafe {
                let k = _mm512_cvttpd_epi64(self.0);
                let bits = _mm512_slli_epi64::<52>(_mm512_add_epi64(k, _mm512_set1_epi64(1023)));
                Z8(_mm512_castsi512_pd(bits))
            }
        }
        #[inline(always)]
        fn split_exponent(self) -> (Self, Self) {
            // SAFETY: see the type's invariant.
            unsafe {
                let bits = _mm512_castpd_si512(self.0);
                let biased =
                    _mm512_and_si512(_mm512_srli_epi64::<52>(bits), _mm512_set1_epi64(0x7ff));
                let e = _mm512_sub_pd(_mm512_cvtepi64_pd(biased), _mm512_set1_pd(1023.0));
                let m = _mm512_or_si512(
                    _mm512_and_si512(bits, _mm512_set1_epi64(MANTISSA as i64)),
                    _mm512_set1_epi64(ONE_BITS as i64),
                );
                (Z8(e), Z8(_mm512_castsi512_pd(m)))
            }
        }
    }
}

/// AVX2 lanes.
#[cfg(target_arch = "x86_64")]
pub(crate) mod avx2 {
    use super::*;
    use std::arch::x86_64::*;

    /// Eight f64 lanes in two AVX registers (lanes 0–3, 4–7).
    ///
    /// Values of this type exist only inside code that runs after AVX2 and FMA were detected
    /// (the `target_feature` wrappers of the projection): every method uses AVX2
    /// instructions. No method fuses a multiply-add.
    #[derive(Clone, Copy, Debug)]
    pub(crate) struct Y8(__m256d, __m256d);

    /// Whether the CPU runs [`Y8`] (the kernels choose by [`crate::forward::Isa`]; the tests
    /// ask here).
    #[cfg(test)]
    pub(crate) fn available() -> bool {
        std::arch::is_x86_feature_detected!("avx2") && std::arch::is_x86_feature_detected!("fma")
    }

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
}

/// ln 2 split so that n·LN2_HI is exact for |n| < 2¹¹ (fdlibm's constants, by their bits).
const LN2_HI: f64 = f64::from_bits(0x3fe6_2e42_fee0_0000);
const LN2_LO: f64 = f64::from_bits(0x3dea_39ef_3579_3c76);
/// 1.5·2⁵²: adding it rounds |x| < 2⁵¹ to an integer (ties to even).
const ROUND_MAGIC: f64 = 6_755_399_441_055_744.0;
/// ln(f64::MAX): larger arguments overflow.
const EXP_MAX_ARG: f64 = 709.782_712_893_384;
/// Below this, exp underflows to 0.
const EXP_MIN_ARG: f64 = -745.133_219_101_941_1;

/// 1/k! for k = 0..=13.
const INV_FACTORIAL: [f64; 14] = [
    1.0,
    1.0,
    1.0 / 2.0,
    1.0 / 6.0,
    1.0 / 24.0,
    1.0 / 120.0,
    1.0 / 720.0,
    1.0 / 5_040.0,
    1.0 / 40_320.0,
    1.0 / 362_880.0,
    1.0 / 3_628_800.0,
    1.0 / 39_916_800.0,
    1.0 / 479_001_600.0,
    1.0 / 6_227_020_800.0,
];

/// e^x lane-wise, within 2 ulps of libm for normal results; +∞ above ln(f64::MAX), 0 below
/// the underflow bound, NaN for NaN.
#[inline(always)]
pub(crate) fn exp<L: Lanes>(x: L) -> L {
    // Clamped so that every intermediate stays finite (a NaN lane becomes 710 here and is
    // restored at the end).
    let xc = x.max(c(-746.0)).min(c(710.0));
    let n = (xc * std::f64::consts::LOG2_E + ROUND_MAGIC) - ROUND_MAGIC;
    let r = (xc - n * LN2_HI) - n * LN2_LO;
    // Taylor series of e^r, |r| ≤ ln2/2 + ε, to r¹³: the next term is below 4·10⁻¹⁸.
    let mut p = c::<L>(INV_FACTORIAL[13]);
    for k in (0..13).rev() {
        p = p * r + INV_FACTORIAL[k];
    }
    // 2ⁿ as two factors so that n ∈ [−1077, 1024] never leaves the normal range.
    let half = (n * 0.5).trunc();
    let y = p * half.pow2() * (n - half).pow2();
    let y = L::select(x.gt(c(EXP_MAX_ARG)), c(f64::INFINITY), y);
    let y = L::select(x.lt(c(EXP_MIN_ARG)), c(0.0), y);
    // NaN lanes (x ≠ x) keep their NaN.
    L::select(!x.eq(x), x, y)
}

/// Natural logarithm lane-wise, within 4 ulps of libm: −∞ at ±0, NaN below 0 or for NaN,
/// +∞ at +∞.
#[inline(always)]
pub(crate) fn ln<L: Lanes>(x: L) -> L {
    // Subnormals are scaled into the normal range first.
    let tiny = x.lt(c(f64::MIN_POSITIVE));
    let xs = L::select(tiny, x * 18_014_398_509_481_984.0, x); // 2⁵⁴
    let (e, m) = xs.split_exponent();
    let e = L::select(tiny, e - 54.0, e);
    // m ∈ [√½, √2).
    let big = m.gt(c(std::f64::consts::SQRT_2));
    let m = L::select(big, m * 0.5, m);
    let e = L::select(big, e + 1.0, e);
    // ln m = 2·atanh(s), s = (m − 1)/(m + 1), |s| ≤ 0.1716: the series to s²⁵ is exact to
    // below 10⁻¹⁷ relative.
    let s = (m - 1.0) / (m + 1.0);
    let s2 = s * s;
    let mut p = c::<L>(1.0 / 25.0);
    for k in (0..12).rev() {
        p = p * s2 + 1.0 / (2 * k + 1) as f64;
    }
    let y = e * LN2_HI + (s * p * 2.0 + e * LN2_LO);
    let y = L::select(x.eq(c(0.0)), c(f64::NEG_INFINITY), y);
    let y = L::select(x.eq(c(f64::INFINITY)), x, y);
    // Negative and NaN lanes.
    L::select(!x.ge(c(0.0)), c(f64::NAN), y)
}

/// Logistic sigmoid lane-wise, 1/(1 + e^−x).
#[inline(always)]
pub(crate) fn sigmoid<L: Lanes>(x: L) -> L {
    c::<L>(1.0) / (exp(-x) + 1.0)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[cfg(target_arch = "x86_64")]
    #[test]
    fn avx2_columns_equal_the_portable_ones_bit_for_bit() {
        if !avx2::available() {
            eprintln!("no AVX2 + FMA on this CPU: skipped");
            return;
        }
        let mut rng = augsplat_core::Rng::new(77);
        let mut rows = [[0.0f32; COLUMNS]; LANES];
        for row in rows.iter_mut() {
            for v in row.iter_mut() {
                *v = rng.normal() as f32;
            }
        }
        rows[3][5] = f32::NAN;
        rows[6][40] = f32::INFINITY;
        rows[1][47] = -0.0;
        rows[7][0] = 1e-40;
        for n in [0, 1, 3, 8, 12, 27, 47, 48] {
            #[target_feature(enable = "avx2,fma")]
            fn go(rows: &[[f32; COLUMNS]; LANES], n: usize) -> Vec<[f64; LANES]> {
                avx2::Y8::columns(rows, n)
                    .iter()
                    .map(|c| c.to_array())
                    .collect()
            }
            // SAFETY: AVX2 + FMA were detected.
            let wide = unsafe { go(&rows, n) };
            let portable = P8::columns(&rows, n);
            #[target_feature(enable = "avx2,fma")]
            fn back(rows: &[[f32; COLUMNS]; LANES], n: usize) -> [[f32; COLUMNS]; LANES] {
                avx2::Y8::rows(&avx2::Y8::columns(rows, n), n)
            }
            // SAFETY: AVX2 + FMA were detected.
            let again = unsafe { back(&rows, n) };
            assert_eq!(
                again.map(|r| r.map(f32::to_bits)),
                P8::rows(&portable, n).map(|r| r.map(f32::to_bits)),
                "n {n}"
            );
            for l in 0..LANES {
                for q in 0..COLUMNS {
                    let want = if q < n { rows[l][q].to_bits() } else { 0 };
                    assert_eq!(again[l][q].to_bits(), want, "n {n}, row {l}, value {q}");
                }
            }
            for q in 0..n {
                for l in 0..LANES {
                    assert_eq!(
                        wide[q][l].to_bits(),
                        portable[q].0[l].to_bits(),
                        "n {n}, column {q}, lane {l}"
                    );
                    assert_eq!(wide[q][l].to_bits(), (rows[l][q] as f64).to_bits());
                }
            }
        }
    }

    fn ulps(a: f64, b: f64) -> u64 {
        if a == b {
            return 0;
        }
        (a.to_bits() as i64 - b.to_bits() as i64).unsigned_abs()
    }

    fn exp1(x: f64) -> f64 {
        exp(P8::splat(x)).0[0]
    }

    fn ln1(x: f64) -> f64 {
        ln(P8::splat(x)).0[0]
    }

    #[test]
    fn exp_is_within_two_ulps_of_libm_over_its_whole_range() {
        let mut rng = augsplat_core::Rng::new(3);
        let mut worst = 0;
        for i in 0..100_000 {
            let x = match i % 4 {
                0 => rng.uniform(-745.0, 709.7),
                1 => rng.uniform(-30.0, 30.0),
                2 => rng.uniform(-1.0, 1.0),
                _ => rng.uniform(-1e-6, 1e-6),
            };
            let (y, want) = (exp1(x), x.exp());
            if want > 1e-300 {
                worst = worst.max(ulps(y, want));
            } else {
                // Relative accuracy is lost towards the subnormal range (as in libm).
                assert!((y - want).abs() <= 1e-312, "{x}: {y} vs {want}");
            }
        }
        assert!(worst <= 2, "worst {worst} ulps");
    }

    #[test]
    fn exp_special_values() {
        for x in [
            0.0,
            -0.0,
            EXP_MAX_ARG,
            EXP_MAX_ARG + 1e-12,
            710.0,
            1e300,
            f64::INFINITY,
            -746.0,
            -1e300,
            f64::NEG_INFINITY,
            -745.0,
            -708.0,
            f64::NAN,
        ] {
            let (y, want) = (exp1(x), x.exp());
            if want.is_nan() {
                assert!(y.is_nan(), "{x}");
            } else if want.is_infinite() || want == 0.0 {
                assert_eq!(y, want, "{x}");
            } else if want < f64::MIN_POSITIVE {
                assert!(
                    (y - want).abs() <= 2.0 * f64::from_bits(1),
                    "{x}: {y} vs {want}"
                );
            } else {
                assert!(ulps(y, want) <= 2, "{x}: {y} vs {want}");
            }
        }
        assert!(exp1(EXP_MAX_ARG).is_finite());
    }

    #[test]
    fn ln_is_within_four_ulps_of_libm_and_handles_special_values() {
        let mut rng = augsplat_core::Rng::new(4);
        let mut worst = 0;
        for i in 0..100_000 {
            let x = match i % 4 {
                0 => 10f64.powf(rng.uniform(-307.0, 308.0)),
                1 => rng.uniform(0.5, 2.0),
                2 => rng.uniform(1.0, 300.0),
                _ => f64::from_bits(rng.below(1 << 52).max(1)),
            };
            let (y, want) = (ln1(x), x.ln());
            if (x - 1.0).abs() < 1e-3 {
                // Near ln = 0, measured against the scale of the terms.
                assert!(
                    (y - want).abs() <= 1e-19 + 4.0 * f64::EPSILON * want.abs(),
                    "{x}"
                );
            } else {
                worst = worst.max(ulps(y, want));
            }
        }
        assert!(worst <= 4, "worst {worst} ulps");
        assert_eq!(ln1(0.0), f64::NEG_INFINITY);
        assert_eq!(ln1(-0.0), f64::NEG_INFINITY);
        assert_eq!(ln1(f64::INFINITY), f64::INFINITY);
        assert_eq!(ln1(1.0), 0.0);
        for x in [-1.0, -1e-300, f64::NEG_INFINITY, f64::NAN] {
            assert!(ln1(x).is_nan(), "{x}");
        }
    }

    /// Inputs that exercise every branch of the lane functions.
    fn awkward(rng: &mut augsplat_core::Rng) -> [f64; LANES] {
        let pick = [
            0.0,
            -0.0,
            f64::NAN,
            f64::INFINITY,
            f64::NEG_INFINITY,
            1e-310,
            -1e-310,
            800.0,
            -800.0,
            1.0,
        ];
        std::array::from_fn(|_| match rng.below(4) {
            0 => pick[rng.below(pick.len() as u64) as usize],
            1 => rng.uniform(-1e3, 1e3),
            2 => rng.uniform(-3.0, 3.0),
            _ => 10f64.powf(rng.uniform(-300.0, 300.0)),
        })
    }

    #[test]
    fn every_lane_is_computed_independently_and_vector_lanes_match_portable_bit_for_bit() {
        let mut rng = augsplat_core::Rng::new(5);
        for _ in 0..2_000 {
            let a = awkward(&mut rng);
            let b = awkward(&mut rng);
            let (pa, pb) = (P8(a), P8(b));
            let portable = [
                exp(pa).0,
                ln(pa).0,
                sigmoid(pa).0,
                pa.min(pb).0,
                pa.max(pb).0,
                pa.ceil().0,
                pa.trunc().0,
                pa.floor().0,
                (pa / pb).0,
                pa.sqrt().0,
            ];
            // Lane independence: each lane equals the computation on a splat of its input.
            for l in 0..LANES {
                assert_eq!(
                    exp(P8::splat(a[l])).0[0].to_bits(),
                    portable[0][l].to_bits()
                );
                assert_eq!(ln(P8::splat(a[l])).0[0].to_bits(), portable[1][l].to_bits());
            }
            for (p, q) in [pa.lt(pb), pa.le(pb), pa.gt(pb), pa.ge(pb), pa.eq(pb)]
                .into_iter()
                .zip([
                    |x: f64, y: f64| x < y,
                    |x: f64, y: f64| x <= y,
                    |x: f64, y: f64| x > y,
                    |x: f64, y: f64| x >= y,
                    |x: f64, y: f64| x == y,
                ])
            {
                for l in 0..LANES {
                    assert_eq!((p >> l) & 1 == 1, q(a[l], b[l]));
                }
            }
            #[cfg(target_arch = "x86_64")]
            if avx2::available() {
                // SAFETY: AVX2 + FMA were detected.
                let (results, masks) = unsafe { avx2_results(a, b) };
                for (w, p) in results.iter().zip(&portable) {
                    for l in 0..LANES {
                        let same =
                            w[l].to_bits() == p[l].to_bits() || (w[l].is_nan() && p[l].is_nan());
                        assert!(same, "{:?} vs {:?} for {:?}, {:?}", w, p, a, b);
                    }
                }
                assert_eq!(
                    masks,
                    [
                        pa.lt(pb),
                        pa.le(pb),
                        pa.gt(pb),
                        pa.ge(pb),
                        pa.eq(pb),
                        pa.is_finite()
                    ]
                );
            }
            #[cfg(target_arch = "x86_64")]
            if avx512::available() {
                // SAFETY: AVX-512F/DQ were detected.
                let wide = unsafe { wide_results(a, b) };
                for (w, p) in wide.iter().zip(&portable) {
                    for l in 0..LANES {
                        let same =
                            w[l].to_bits() == p[l].to_bits() || (w[l].is_nan() && p[l].is_nan());
                        assert!(same, "{:?} vs {:?} for {:?}, {:?}", w, p, a, b);
                    }
                }
                // SAFETY: as above.
                assert_eq!(
                    unsafe { wide_masks(a, b) },
                    [pa.lt(pb), pa.ge(pb), pa.is_finite()]
                );
            }
        }
    }

    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx512f,avx512dq")]
    fn wide_results(a: [f64; LANES], b: [f64; LANES]) -> [[f64; LANES]; 10] {
        use avx512::Z8;
        let (za, zb) = (Z8::from_array(a), Z8::from_array(b));
        [
            exp(za).to_array(),
            ln(za).to_array(),
            sigmoid(za).to_array(),
            za.min(zb).to_array(),
            za.max(zb).to_array(),
            za.ceil().to_array(),
            za.trunc().to_array(),
            za.floor().to_array(),
            (za / zb).to_array(),
            za.sqrt().to_array(),
        ]
    }

    /// The AVX2 lanes' results of the portable comparison list, their masks, and selects,
    /// powers of two and exponent splits checked against the portable lanes.
    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx2,fma")]
    fn avx2_results(a: [f64; LANES], b: [f64; LANES]) -> ([[f64; LANES]; 10], [Mask; 6]) {
        use avx2::Y8;
        let (ya, yb) = (Y8::from_array(a), Y8::from_array(b));
        let (pa, pb) = (P8(a), P8(b));
        for m in [0u8, 0x5a, 0xa5, 0x0f, 0xf0, 0xff, 0x81] {
            let (s, t) = (Y8::select(m, ya, yb).to_array(), P8::select(m, pa, pb).0);
            assert!(s.iter().zip(&t).all(|(x, y)| x.to_bits() == y.to_bits()));
        }
        let ks: [f64; LANES] =
            std::array::from_fn(|l| [-1022.0, 1016.0, 0.0, -1.0][l % 4] + l as f64);
        assert_eq!(
            Y8::from_array(ks).pow2().to_array().map(f64::to_bits),
            P8(ks).pow2().0.map(f64::to_bits)
        );
        let (ye, ym) = ya.split_exponent();
        let (pe, pm) = pa.split_exponent();
        assert_eq!(ye.to_array().map(f64::to_bits), pe.0.map(f64::to_bits));
        assert_eq!(ym.to_array().map(f64::to_bits), pm.0.map(f64::to_bits));
        assert_eq!(
            (-ya).to_array().map(f64::to_bits),
            (-pa).0.map(f64::to_bits)
        );
        (
            [
                exp(ya).to_array(),
                ln(ya).to_array(),
                sigmoid(ya).to_array(),
                ya.min(yb).to_array(),
                ya.max(yb).to_array(),
                ya.ceil().to_array(),
                ya.trunc().to_array(),
                ya.floor().to_array(),
                (ya / yb).to_array(),
                ya.sqrt().to_array(),
            ],
            [
                ya.lt(yb),
                ya.le(yb),
                ya.gt(yb),
                ya.ge(yb),
                ya.eq(yb),
                ya.is_finite(),
            ],
        )
    }

    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx512f,avx512dq")]
    fn wide_masks(a: [f64; LANES], b: [f64; LANES]) -> [Mask; 3] {
        use avx512::Z8;
        let (za, zb) = (Z8::from_array(a), Z8::from_array(b));
        [za.lt(zb), za.ge(zb), za.is_finite()]
    }
}
