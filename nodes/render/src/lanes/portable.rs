//! The portable lanes: an array of eight f64, one plain IEEE operation per lane. The
//! statement of what every vector implementation of [`Lanes`] computes.

use super::{Lanes, Mask, LANES, MANTISSA, ONE_BITS};
use std::ops::{Add, Div, Mul, Neg, Sub};

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
