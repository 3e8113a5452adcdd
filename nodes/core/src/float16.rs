//! IEEE 754 binary16 (half precision) conversions: the LPIPS weights stored in float16 and the
//! report viewer's packed splats.
//!
//! [`to_f32`] is exact (every float16 value is a float32 value); [`from_f32`] rounds to the
//! nearest float16, ties to even, as numpy's `astype(float16)` and torch's `.half()` do:
//! magnitudes from 65520 up become infinity, those up to 2⁻²⁵ become zero, float16
//! subnormals are produced below 2⁻¹⁴, and NaN stays NaN.

/// The float32 value of the float16 with bits `h`.
pub fn to_f32(h: u16) -> f32 {
    let sign = u32::from(h & 0x8000) << 16;
    let exp = u32::from((h >> 10) & 0x1f);
    let man = u32::from(h & 0x3ff);
    let bits = match exp {
        0 => {
            // Zero or subnormal: man · 2⁻²⁴, exact in float32.
            let v = man as f32 * (1.0 / 16_777_216.0);
            return if sign != 0 { -v } else { v };
        }
        0x1f => sign | 0x7f80_0000 | (man << 13),
        _ => sign | ((exp + 112) << 23) | (man << 13),
    };
    f32::from_bits(bits)
}

/// The bits of the float16 nearest to `x` (ties to even).
pub fn from_f32(x: f32) -> u16 {
    let b = x.to_bits();
    let sign = ((b >> 16) & 0x8000) as u16;
    let exp = ((b >> 23) & 0xff) as i32;
    let man = b & 0x7f_ffff;
    if exp == 0xff {
        // Infinity, or NaN (kept quiet, with the top payload bits).
        return sign
            | 0x7c00
            | if man != 0 {
                0x200 | (man >> 13) as u16
            } else {
                0
            };
    }
    let e = exp - 127 + 15;
    if e >= 0x1f {
        return sign | 0x7c00;
    }
    let round = |kept: u32, rem: u32, half: u32| -> u32 {
        if rem > half || (rem == half && kept & 1 == 1) {
            kept + 1
        } else {
            kept
        }
    };
    if e <= 0 {
        // A float16 subnormal (or zero): the count of 2⁻²⁴ units is m · 2^(e − 14).
        if e < -10 {
            return sign;
        }
        let m = man | 0x80_0000;
        let shift = (14 - e) as u32;
        let kept = round(m >> shift, m & ((1 << shift) - 1), 1 << (shift - 1));
        // A carry out of the subnormals lands on the smallest normal, as it should.
        return sign | kept as u16;
    }
    // A carry out of the significand bumps the exponent (up to infinity), as it should.
    let kept = round(((e as u32) << 10) | (man >> 13), man & 0x1fff, 0x1000);
    sign | kept as u16
}

#[cfg(test)]
mod tests {
    use super::{from_f32, to_f32};

    #[test]
    fn every_float16_round_trips() {
        for h in 0..=u16::MAX {
            let v = to_f32(h);
            if v.is_nan() {
                assert!(to_f32(from_f32(v)).is_nan(), "{h:#06x}");
            } else {
                assert_eq!(from_f32(v), h, "{h:#06x} = {v:e}");
            }
        }
    }

    #[test]
    fn known_values() {
        assert_eq!(to_f32(0x3c00), 1.0);
        assert_eq!(to_f32(0xc000), -2.0);
        assert_eq!(to_f32(0x7bff), 65504.0);
        assert_eq!(to_f32(0x0001), 2f32.powi(-24));
        assert_eq!(to_f32(0x0400), 2f32.powi(-14));
        assert_eq!(to_f32(0x7c00), f32::INFINITY);
        assert_eq!(from_f32(0.1), 0x2e66);
        assert_eq!(from_f32(-0.0), 0x8000);
        assert_eq!(from_f32(65519.0), 0x7bff);
        assert_eq!(from_f32(65520.0), 0x7c00);
        assert_eq!(from_f32(1e-8), 0);
        assert_eq!(from_f32(f32::from_bits(1)), 0);
    }

    /// Halfway between two neighbours goes to the even one; anything past halfway goes up.
    #[test]
    fn rounds_to_nearest_ties_to_even() {
        for h in [
            0x0000u16, 0x0001, 0x0002, 0x03ff, 0x0400, 0x3c00, 0x3c01, 0x7bfe,
        ] {
            let (lo, hi) = (to_f32(h), to_f32(h + 1));
            let mid = lo + (hi - lo) / 2.0;
            let even = if h & 1 == 0 { h } else { h + 1 };
            assert_eq!(from_f32(mid), even, "midpoint above {h:#06x}");
            let above = f32::from_bits(mid.to_bits() + 1);
            assert_eq!(
                from_f32(above),
                h + 1,
                "just above the midpoint of {h:#06x}"
            );
            let below = f32::from_bits(mid.to_bits() - 1);
            assert_eq!(from_f32(below), h, "just below the midpoint of {h:#06x}");
        }
    }
}
