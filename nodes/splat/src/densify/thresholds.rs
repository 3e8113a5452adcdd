//! Densification's comparisons as exact integer tests, so that the GPU (`densify.wgsl`)
//! decides every Gaussian as the CPU's [`super::Densifier`] does without f64 or `exp` on the
//! device.
//!
//! Each CPU test is a monotone predicate of one f32 value: `exp(max log-scale) ≤ X` holds
//! for every log-scale up to some largest f32, `grad2d / count > threshold` for every sum from
//! some smallest one (one boundary per count). The host finds each boundary by bisection over
//! the ordered f32 values, evaluating the CPU's own expression, and the device compares
//! [`ord_key`]s, integers that order the floats as `<` does: no float arithmetic or
//! comparison runs on the device, so flushed denormals and NaN handling cannot differ.

/// The integer that orders f32 values as `<` does (−∞ lowest, +∞ highest; −0 and +0 share
/// one key). NaNs get keys outside [`ord_key`]`(−∞)..=`[`ord_key`]`(+∞)`: callers test
/// for NaN first. The WGSL twin is `ord_key` in `densify.wgsl`.
pub fn ord_key(x: f32) -> u32 {
    let b = if x == 0.0 { 0 } else { x.to_bits() };
    if b >> 31 == 1 {
        !b
    } else {
        b | 0x8000_0000
    }
}

/// The f32 value whose [`ord_key`] is `k` (−0 for the key between −0 and the smallest
/// negative denormal's, which no value maps to).
pub fn from_key(k: u32) -> f32 {
    if k >> 31 == 1 {
        f32::from_bits(k & 0x7fff_ffff)
    } else {
        f32::from_bits(!k)
    }
}

/// The largest key in `lo..=hi` whose value satisfies `pred`, which must hold up to some
/// point and fail after it (`None` when it fails at `lo`).
fn largest_key_where(lo: u32, hi: u32, pred: impl Fn(f32) -> bool) -> Option<u32> {
    if !pred(from_key(lo)) {
        return None;
    }
    let (mut good, mut bad) = (lo, hi);
    if pred(from_key(hi)) {
        return Some(hi);
    }
    while bad - good > 1 {
        let mid = good + (bad - good) / 2;
        if pred(from_key(mid)) {
            good = mid;
        } else {
            bad = mid;
        }
    }
    Some(good)
}

/// The key of the largest log-scale `l` (over −∞..=+∞) with `exp(l) as f64 ≤ bound`, with
/// `f32::exp` as the CPU evaluates it; for `bound ≥ 0` it exists (`exp(−∞) = 0`).
pub fn log_scale_key_at_most(bound: f64) -> Option<u32> {
    largest_key_where(ord_key(f32::NEG_INFINITY), ord_key(f32::INFINITY), |l| {
        (l.exp() as f64) <= bound
    })
}

/// Per count `c` in `0..=max_count`: the key of the smallest non-negative sum `g` with
/// `g as f64 / max(c, 1) as f64 > threshold` (the CPU's grow test, which grows whatever is
/// not `≤ threshold`: a NaN sum too, which the device tests apart), or `u32::MAX` when no
/// f32 passes (a sum's key is then never at least it).
pub fn grow_keys(threshold: f64, max_count: u32) -> Vec<u32> {
    let (zero, inf) = (ord_key(0.0), ord_key(f32::INFINITY));
    (0..=max_count)
        .map(|c| {
            let d = f64::from(c.max(1));
            // The largest sum that does not grow, plus one key.
            match largest_key_where(zero, inf, |g| g as f64 / d <= threshold) {
                None => zero,
                Some(k) if k == inf => u32::MAX,
                Some(k) => k + 1,
            }
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;
    use augsplat_core::Rng;

    fn values(rng: &mut Rng, count: usize) -> Vec<f32> {
        let mut v: Vec<f32> = (0..count)
            .map(|_| f32::from_bits(rng.next_u64() as u32))
            .filter(|x| !x.is_nan())
            .collect();
        v.extend([
            0.0,
            -0.0,
            f32::MIN_POSITIVE,
            -f32::MIN_POSITIVE,
            f32::from_bits(1),
            f32::from_bits(0x8000_0001),
            f32::INFINITY,
            f32::NEG_INFINITY,
            f32::MAX,
            f32::MIN,
            1.0,
            -1.0,
        ]);
        v
    }

    #[test]
    fn keys_order_floats_as_less_than_does() {
        let mut rng = Rng::new(7);
        let v = values(&mut rng, 2000);
        for a in &v {
            assert!(from_key(ord_key(*a)) == *a, "{a:e} round trip");
            for b in v.iter().take(200) {
                assert_eq!(ord_key(*a) < ord_key(*b), a < b, "{a:e} < {b:e}");
                assert_eq!(ord_key(*a) == ord_key(*b), a == b, "{a:e} == {b:e}");
            }
        }
        for nan in [f32::NAN, -f32::NAN, f32::from_bits(0x7f80_0001)] {
            let k = ord_key(nan);
            assert!(k < ord_key(f32::NEG_INFINITY) || k > ord_key(f32::INFINITY));
        }
    }

    #[test]
    fn the_log_scale_boundary_decides_as_exp_does() {
        let mut rng = Rng::new(11);
        for bound in [0.0, 1e-30, 0.003, 0.0123, 1.0, 2.5, 1e30, f64::MAX] {
            let key = log_scale_key_at_most(bound).expect("exp(-inf) = 0 is within");
            let edge = from_key(key);
            // The boundary and its neighbours, and random log-scales.
            let mut ls = vec![edge, from_key(key.saturating_sub(1)), from_key(key + 1)];
            ls.extend(values(&mut rng, 3000));
            ls.extend((0..2000).map(|_| (rng.next_f64() * 200.0 - 100.0) as f32));
            for l in ls {
                assert_eq!(
                    ord_key(l) <= key,
                    (l.exp() as f64) <= bound,
                    "log-scale {l:e} against {bound:e}"
                );
            }
        }
    }

    #[test]
    fn the_grow_boundaries_decide_as_the_division_does() {
        let mut rng = Rng::new(13);
        for thr in [0.0, 2e-4, 0.0002000001, 1.0, 3e38] {
            let keys = grow_keys(thr, 40);
            for (c, &key) in keys.iter().enumerate() {
                let d = (c as u32).max(1) as f64;
                let mut gs: Vec<f32> = values(&mut rng, 500)
                    .into_iter()
                    .filter(|g| *g >= 0.0)
                    .collect();
                if key != u32::MAX {
                    gs.extend([from_key(key), from_key(key - 1), from_key(key + 1)]);
                }
                gs.extend((0..500).map(|_| (rng.next_f64() * 4e-4 * d) as f32));
                for g in gs.into_iter().filter(|g| !g.is_nan()) {
                    assert_eq!(
                        ord_key(g) >= key,
                        g as f64 / d > thr,
                        "sum {g:e} over {c} views against {thr:e}"
                    );
                }
            }
        }
    }
}
