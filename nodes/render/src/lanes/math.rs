//! Lane-wise e^x, ln x and the logistic function, written here (polynomials within 2 and 4
//! ulps of libm, tested) because libm's are scalar calls.

use super::{c, Lanes};

/// ln 2 split so that n·LN2_HI is exact for |n| < 2¹¹ (fdlibm's constants, by their bits).
pub(super) const LN2_HI: f64 = f64::from_bits(0x3fe6_2e42_fee0_0000);
pub(super) const LN2_LO: f64 = f64::from_bits(0x3dea_39ef_3579_3c76);
/// 1.5·2⁵²: adding it rounds |x| < 2⁵¹ to an integer (ties to even).
pub(super) const ROUND_MAGIC: f64 = 6_755_399_441_055_744.0;
/// ln(f64::MAX): larger arguments overflow.
pub(super) const EXP_MAX_ARG: f64 = 709.782_712_893_384;
/// Below this, exp underflows to 0.
pub(super) const EXP_MIN_ARG: f64 = -745.133_219_101_941_1;

/// 1/k! for k = 0..=13.
pub(super) const INV_FACTORIAL: [f64; 14] = [
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
