//! Tests of the lanes: every lane independent, AVX2 equal to the portable lanes bit for
//! bit on awkward inputs, and the accuracy of exp and ln.

use super::math::EXP_MAX_ARG;
use super::*;
use augsplat_core::simd::{for_each_isa, Isa};

#[cfg(target_arch = "x86_64")]
#[test]
fn avx2_columns_equal_the_portable_ones_bit_for_bit() {
    if !for_each_isa("AVX2 SH transposes", |isa| isa)
        .iter()
        .any(|(isa, _)| *isa == Isa::Avx2)
    {
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
    // The AVX2 lanes run where the CPU has them (`for_each_isa` reports a tier it cannot run).
    let avx2_tier = for_each_isa("f64 lanes", |isa| isa)
        .iter()
        .any(|(isa, _)| *isa == Isa::Avx2);
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
        if avx2_tier {
            // SAFETY: AVX2 + FMA were detected.
            let (results, masks) = unsafe { avx2_results(a, b) };
            for (w, p) in results.iter().zip(&portable) {
                for l in 0..LANES {
                    let same = w[l].to_bits() == p[l].to_bits() || (w[l].is_nan() && p[l].is_nan());
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
    }
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
    let ks: [f64; LANES] = std::array::from_fn(|l| [-1022.0, 1016.0, 0.0, -1.0][l % 4] + l as f64);
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
