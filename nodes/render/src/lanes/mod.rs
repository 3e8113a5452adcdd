//! Eight f64 values processed in lock step: the per-Gaussian projection and its backward pass
//! run on eight Gaussians at once through the [`Lanes`] trait, with two implementations: a
//! portable array ([`P8`], in `portable.rs`) and two AVX2 registers (`avx2::Y8`, in
//! `avx2.rs`); `math.rs` holds the lane-wise [`exp`], [`ln`] and [`sigmoid`].
//!
//! Every operation is the same IEEE operation on each lane (no fused multiply-adds; exact
//! `sqrt` and division; `min`/`max` follow one stated rule), so both implementations give
//! bit-identical lanes, and a lane's value does not depend on its neighbours. Branches
//! become masks (bit `l` = lane `l`) and selects. [`exp`] and [`ln`] are written here
//! (polynomials within 2 and 4 ulps of libm, tested below) because libm's are scalar calls.

// Lane loops index several arrays in step.
#![allow(clippy::needless_range_loop)]

#[cfg(target_arch = "x86_64")]
pub(crate) mod avx2;
mod math;
mod portable;
#[cfg(test)]
mod tests;

pub(crate) use math::{exp, ln, sigmoid};
pub(crate) use portable::P8;

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

/// The mantissa bits of an f64.
const MANTISSA: u64 = 0x000f_ffff_ffff_ffff;
/// The bits of 1.0 (a zero mantissa with the exponent bias).
const ONE_BITS: u64 = 0x3ff0_0000_0000_0000;
