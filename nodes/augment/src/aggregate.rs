//! Ensemble aggregation kernels (AugSplat §3.2; docs/design.md, *The method*): per-pixel
//! median target and variance-based confidence weights.
//!
//! For one view seen by M members (planar RGB, `n = width × height` pixels):
//! 1. **target** `T_c(p) = median_m I_m,c(p)` per channel; for an even M the mean of the two
//!    middle values;
//! 2. **variance** `V(p) = (1/3) Σ_c (1/M) Σ_m (I_m,c(p) − mean_c(p))²` — the population variance
//!    (ddof 0). The unbiased M/(M−1) factor would change nothing below: blur is linear and the
//!    percentile normalisation is scale invariant;
//! 3. optional **blur** of V with a k×k Gaussian, σ = 0.3·((k−1)/2 − 1) + 0.8 (OpenCV's rule for
//!    `GaussianBlur(ksize=k, sigma=0)`, what the reference code calls), borders reflected
//!    without repeating the edge pixel (OpenCV's default `BORDER_REFLECT_101`);
//! 4. **normalise** per image: `V_n = clip((V − P_lo) / (P_hi − P_lo), 0, 1)` with the
//!    percentiles taken by linear interpolation between closest ranks (numpy's default:
//!    rank `r = p/100 · (n−1)`, value `s[⌊r⌋] + (r − ⌊r⌋)(s[⌈r⌉] − s[⌊r⌋])` over the sorted map);
//! 5. **weight** `w = (1 − V_n)^γ`, then optionally floored: `w ← f + (1 − f)·w`.
//!
//! Degenerate cases (all give finite weights in [0, 1]):
//! - `P_hi = P_lo` (e.g. a constant variance map): `V_n` is the limit of the clipped ramp as its
//!   width goes to 0: `V_n = 0` where `V ≤ P_lo`, `1` where `V > P_lo`. A constant map (and
//!   M = 1, whose variance is 0 everywhere) therefore gets weight 1 (floor or not) everywhere:
//!   with no relative information, every pixel is trusted equally;
//! - `γ = 0`: `w = 1` everywhere (`0^0 = 1`);
//! - non-finite render values are rejected by the node with an error naming the file.

use serde::{Deserialize, Serialize};

/// Aggregation settings.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct AggregateParams {
    /// Exponent γ of the weight `(1 − V_n)^γ`; ≥ 0.
    pub gamma: f64,
    /// Side of the Gaussian blur applied to the variance before normalising (odd); `None`
    /// for no blur. The reference code uses `Some(9)`.
    pub blur: Option<u32>,
    /// Lower and upper percentiles (0–100) of the per-image normalisation.
    pub percentiles: (f64, f64),
    /// Floor `f` in [0, 1]: `w ← f + (1 − f)·w`. The reference code uses `Some(0.1)`.
    pub floor: Option<f64>,
}

impl Default for AggregateParams {
    fn default() -> Self {
        AggregateParams {
            gamma: 1.5,
            blur: None,
            percentiles: (5.0, 95.0),
            floor: None,
        }
    }
}

impl AggregateParams {
    /// Checks ranges.
    pub fn validate(&self) -> Result<(), String> {
        if !self.gamma.is_finite() || self.gamma < 0.0 {
            return Err(format!("gamma = {} must be finite and ≥ 0", self.gamma));
        }
        if let Some(k) = self.blur {
            if k == 0 || k % 2 == 0 {
                return Err(format!("blur = {k} must be an odd kernel side (e.g. 9)"));
            }
        }
        let (lo, hi) = self.percentiles;
        if !(lo.is_finite() && hi.is_finite() && 0.0 <= lo && lo < hi && hi <= 100.0) {
            return Err(format!(
                "percentiles = ({lo}, {hi}) must satisfy 0 ≤ lo < hi ≤ 100"
            ));
        }
        if let Some(f) = self.floor {
            if !f.is_finite() || !(0.0..=1.0).contains(&f) {
                return Err(format!("floor = {f} must lie in [0, 1]"));
            }
        }
        Ok(())
    }
}

/// Median of a small slice, sorted in place; the mean of the two middle values for an even
/// length (computed in f64). The slice must not be empty.
pub fn median_in_place(values: &mut [f32]) -> f32 {
    // Insertion sort: M is small (an ensemble), and it allocates nothing.
    for i in 1..values.len() {
        let mut j = i;
        while j > 0 && values[j - 1].total_cmp(&values[j]).is_gt() {
            values.swap(j - 1, j);
            j -= 1;
        }
    }
    let n = values.len();
    if n % 2 == 1 {
        values[n / 2]
    } else {
        ((values[n / 2 - 1] as f64 + values[n / 2] as f64) * 0.5) as f32
    }
}

/// Per-pixel median target and RGB-averaged variance over `members`.
///
/// Each member is planar RGB of `3n` values (R plane, G plane, B plane). Writes the planar
/// target (`3n`) and the variance map (`n`). `scratch` must hold `members.len()` values.
pub fn median_and_variance(
    members: &[&[f32]],
    n: usize,
    target: &mut [f32],
    variance: &mut [f64],
    scratch: &mut [f32],
) {
    let m = members.len();
    debug_assert!(m > 0 && scratch.len() >= m);
    debug_assert!(members.iter().all(|x| x.len() == 3 * n));
    debug_assert!(target.len() == 3 * n && variance.len() == n);
    let inv_m = 1.0 / m as f64;
    for (p, var_out) in variance[..n].iter_mut().enumerate() {
        let mut v = 0.0;
        for c in 0..3 {
            let idx = c * n + p;
            let mut sum = 0.0;
            for (k, mem) in members.iter().enumerate() {
                let x = mem[idx];
                scratch[k] = x;
                sum += x as f64;
            }
            let mean = sum * inv_m;
            let mut ss = 0.0;
            for &x in &scratch[..m] {
                let d = x as f64 - mean;
                ss += d * d;
            }
            v += ss * inv_m;
            target[idx] = median_in_place(&mut scratch[..m]);
        }
        *var_out = v / 3.0;
    }
}

/// The normalised 1-D Gaussian of side `k` with OpenCV's σ for `sigma = 0`:
/// σ = 0.3·((k−1)/2 − 1) + 0.8.
pub fn gaussian_kernel(k: u32) -> Vec<f64> {
    let sigma = 0.3 * ((k as f64 - 1.0) * 0.5 - 1.0) + 0.8;
    let half = (k / 2) as f64;
    let mut w: Vec<f64> = (0..k)
        .map(|i| {
            let x = i as f64 - half;
            (-x * x / (2.0 * sigma * sigma)).exp()
        })
        .collect();
    let s: f64 = w.iter().sum();
    w.iter_mut().for_each(|v| *v /= s);
    w
}

/// Index `i` (possibly outside `0..n`) reflected into range without repeating the edge
/// (OpenCV `BORDER_REFLECT_101`: `…, 2, 1 | 0, 1, 2, … n−1 | n−2, …`).
pub fn reflect101(i: i64, n: usize) -> usize {
    if n == 1 {
        return 0;
    }
    let period = 2 * (n as i64 - 1);
    let mut j = i.rem_euclid(period);
    if j >= n as i64 {
        j = period - j;
    }
    j as usize
}

/// Separable k×k Gaussian blur of a `width × height` map (see [`gaussian_kernel`],
/// [`reflect101`]). `tmp` and `out` must hold `width × height` values.
pub fn gaussian_blur(
    src: &[f64],
    width: usize,
    height: usize,
    k: u32,
    tmp: &mut [f64],
    out: &mut [f64],
) {
    let w = gaussian_kernel(k);
    let half = (k / 2) as i64;
    // Border handling by index tables (no division in the loops): padded position `x + t`
    // reads source column `cols[x + t]`.
    let table = |n: usize| -> Vec<usize> {
        (0..n + k as usize - 1)
            .map(|i| reflect101(i as i64 - half, n))
            .collect()
    };
    let cols = table(width);
    let rows = table(height);
    for y in 0..height {
        let row = &src[y * width..(y + 1) * width];
        let dst = &mut tmp[y * width..(y + 1) * width];
        for (x, d) in dst.iter_mut().enumerate() {
            let idx = &cols[x..x + w.len()];
            let mut acc = 0.0;
            for (wt, &i) in w.iter().zip(idx) {
                acc += wt * row[i];
            }
            *d = acc;
        }
    }
    for y in 0..height {
        let dst = &mut out[y * width..(y + 1) * width];
        dst.iter_mut().for_each(|v| *v = 0.0);
        for (wt, &r) in w.iter().zip(&rows[y..y + w.len()]) {
            let srow = &tmp[r * width..(r + 1) * width];
            for (d, s) in dst.iter_mut().zip(srow) {
                *d += wt * s;
            }
        }
    }
}

/// The `p`-th percentile (0–100) of ascending `sorted` values, linear between closest ranks
/// (numpy's default). NaN for an empty slice.
pub fn percentile_sorted(sorted: &[f64], p: f64) -> f64 {
    if sorted.is_empty() {
        return f64::NAN;
    }
    let r = (p / 100.0).clamp(0.0, 1.0) * (sorted.len() - 1) as f64;
    let lo = r.floor() as usize;
    let hi = (lo + 1).min(sorted.len() - 1);
    let f = r - lo as f64;
    sorted[lo] + f * (sorted[hi] - sorted[lo])
}

/// Fills `out` with the confidence weights of a variance map given its normalisation
/// percentiles `(p_lo, p_hi)`, γ and an optional floor (see the module docs for the degenerate
/// cases). Returns whether the normalisation was degenerate (`p_hi ≤ p_lo`).
pub fn confidence_weights(
    variance: &[f64],
    p_lo: f64,
    p_hi: f64,
    gamma: f64,
    floor: Option<f64>,
    out: &mut [f32],
) -> bool {
    let range = p_hi - p_lo;
    let degenerate = range <= 0.0 || !range.is_finite();
    let f = floor.unwrap_or(0.0);
    for (o, &v) in out.iter_mut().zip(variance) {
        let vn = if degenerate {
            if v > p_lo {
                1.0
            } else {
                0.0
            }
        } else {
            ((v - p_lo) / range).clamp(0.0, 1.0)
        };
        let w = if gamma == 0.0 {
            1.0
        } else {
            (1.0 - vn).powf(gamma)
        };
        *o = (f + (1.0 - f) * w) as f32;
    }
    degenerate
}

/// Reusable buffers for [`aggregate_view`] (one set per worker, none per pixel).
#[derive(Default)]
pub struct Workspace {
    scratch: Vec<f32>,
    variance: Vec<f64>,
    blurred: Vec<f64>,
    tmp: Vec<f64>,
    sorted: Vec<f64>,
}

/// The aggregate of one view.
#[derive(Clone, Debug, PartialEq)]
pub struct ViewAggregate {
    /// Planar RGB median target, `3n` values.
    pub target: Vec<f32>,
    /// Confidence weights, `n` values in [0, 1].
    pub weight: Vec<f32>,
    /// The lower normalisation percentile of the (blurred) variance.
    pub p_lo: f64,
    /// The upper normalisation percentile.
    pub p_hi: f64,
    /// Mean (blurred) variance.
    pub mean_variance: f64,
    /// Whether `p_hi ≤ p_lo` (see the module docs).
    pub degenerate: bool,
}

/// Aggregates one view: median target, variance, optional blur, percentiles, weights.
/// `members` are planar RGB (`3 · width · height` values each); there must be at least one.
pub fn aggregate_view(
    members: &[&[f32]],
    width: usize,
    height: usize,
    params: &AggregateParams,
    ws: &mut Workspace,
) -> ViewAggregate {
    let n = width * height;
    ws.scratch.resize(members.len(), 0.0);
    ws.variance.resize(n, 0.0);
    let mut target = vec![0.0f32; 3 * n];
    median_and_variance(members, n, &mut target, &mut ws.variance, &mut ws.scratch);
    let var: &[f64] = match params.blur {
        Some(k) if k > 1 => {
            ws.tmp.resize(n, 0.0);
            ws.blurred.resize(n, 0.0);
            gaussian_blur(&ws.variance, width, height, k, &mut ws.tmp, &mut ws.blurred);
            &ws.blurred
        }
        _ => &ws.variance,
    };
    ws.sorted.clear();
    ws.sorted.extend_from_slice(var);
    ws.sorted.sort_unstable_by(|a, b| a.total_cmp(b));
    let p_lo = percentile_sorted(&ws.sorted, params.percentiles.0);
    let p_hi = percentile_sorted(&ws.sorted, params.percentiles.1);
    let mut weight = vec![0.0f32; n];
    let degenerate = confidence_weights(var, p_lo, p_hi, params.gamma, params.floor, &mut weight);
    let mean_variance = if n > 0 {
        var.iter().sum::<f64>() / n as f64
    } else {
        0.0
    };
    ViewAggregate {
        target,
        weight,
        p_lo,
        p_hi,
        mean_variance,
        degenerate,
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use augsplat_core::Rng;

    // ---- An independent f64 reference, written from the definitions. ----

    fn ref_median(mut v: Vec<f64>) -> f64 {
        v.sort_by(|a, b| a.partial_cmp(b).unwrap());
        let n = v.len();
        if n % 2 == 1 {
            v[n / 2]
        } else {
            (v[n / 2 - 1] + v[n / 2]) / 2.0
        }
    }

    /// numpy.percentile(method="linear"), written as the documented formula.
    fn ref_percentile(v: &[f64], p: f64) -> f64 {
        let mut s = v.to_vec();
        s.sort_by(|a, b| a.partial_cmp(b).unwrap());
        let h = (s.len() as f64 - 1.0) * p / 100.0;
        let lo = h.floor();
        let hi = h.ceil();
        s[lo as usize] + (h - lo) * (s[hi as usize] - s[lo as usize])
    }

    fn ref_blur(v: &[f64], w: usize, h: usize, k: usize) -> Vec<f64> {
        // Direct 2-D convolution with the outer product kernel, reflect-101 by explicit mirror.
        let sigma = 0.3 * ((k as f64 - 1.0) / 2.0 - 1.0) + 0.8;
        let r = (k / 2) as i64;
        let g: Vec<f64> = (-r..=r)
            .map(|x| (-(x * x) as f64 / (2.0 * sigma * sigma)).exp())
            .collect();
        let gs: f64 = g.iter().sum();
        let mirror = |i: i64, n: i64| -> usize {
            let mut i = i;
            while i < 0 || i >= n {
                if n == 1 {
                    return 0;
                }
                if i < 0 {
                    i = -i;
                }
                if i >= n {
                    i = 2 * (n - 1) - i;
                }
            }
            i as usize
        };
        let mut out = vec![0.0; w * h];
        for y in 0..h as i64 {
            for x in 0..w as i64 {
                let mut acc = 0.0;
                for dy in -r..=r {
                    for dx in -r..=r {
                        let wt = g[(dy + r) as usize] * g[(dx + r) as usize] / (gs * gs);
                        acc += wt * v[mirror(y + dy, h as i64) * w + mirror(x + dx, w as i64)];
                    }
                }
                out[y as usize * w + x as usize] = acc;
            }
        }
        out
    }

    /// The whole aggregation in f64, from the definitions.
    fn ref_aggregate(
        members: &[Vec<f32>],
        w: usize,
        h: usize,
        p: &AggregateParams,
    ) -> (Vec<f64>, Vec<f64>) {
        let n = w * h;
        let m = members.len() as f64;
        let mut target = vec![0.0; 3 * n];
        let mut var = vec![0.0; n];
        for px in 0..n {
            for c in 0..3 {
                let vals: Vec<f64> = members.iter().map(|x| x[c * n + px] as f64).collect();
                target[c * n + px] = ref_median(vals.clone());
                let mean = vals.iter().sum::<f64>() / m;
                var[px] += vals.iter().map(|v| (v - mean).powi(2)).sum::<f64>() / m / 3.0;
            }
        }
        if let Some(k) = p.blur {
            var = ref_blur(&var, w, h, k as usize);
        }
        let lo = ref_percentile(&var, p.percentiles.0);
        let hi = ref_percentile(&var, p.percentiles.1);
        let f = p.floor.unwrap_or(0.0);
        let weight = var
            .iter()
            .map(|&v| {
                let vn = if hi > lo {
                    ((v - lo) / (hi - lo)).clamp(0.0, 1.0)
                } else if v > lo {
                    1.0
                } else {
                    0.0
                };
                f + (1.0 - f) * (1.0 - vn).powf(p.gamma)
            })
            .collect();
        (target, weight)
    }

    fn random_members(m: usize, n: usize, seed: u64) -> Vec<Vec<f32>> {
        let mut rng = Rng::new(seed);
        (0..m)
            .map(|_| (0..3 * n).map(|_| rng.next_f32()).collect())
            .collect()
    }

    #[test]
    fn median_even_odd_and_reference() {
        assert_eq!(median_in_place(&mut [0.3, 0.1, 0.2]), 0.2);
        assert_eq!(median_in_place(&mut [0.4, 0.1, 0.3, 0.2]), 0.25);
        assert_eq!(median_in_place(&mut [0.7]), 0.7);
        let mut rng = Rng::new(5);
        for m in 1..10 {
            let v: Vec<f32> = (0..m).map(|_| rng.next_f32()).collect();
            let r = ref_median(v.iter().map(|&x| x as f64).collect());
            let got = median_in_place(&mut v.clone());
            assert!((got as f64 - r).abs() < 1e-7, "m={m}");
        }
    }

    #[test]
    fn percentile_matches_numpy_linear() {
        // numpy.percentile([1, 2, 3, 4], [5, 50, 95]) = [1.15, 2.5, 3.85]
        let s = [1.0, 2.0, 3.0, 4.0];
        assert!((percentile_sorted(&s, 5.0) - 1.15).abs() < 1e-12);
        assert!((percentile_sorted(&s, 50.0) - 2.5).abs() < 1e-12);
        assert!((percentile_sorted(&s, 95.0) - 3.85).abs() < 1e-12);
        assert_eq!(percentile_sorted(&s, 0.0), 1.0);
        assert_eq!(percentile_sorted(&s, 100.0), 4.0);
        assert_eq!(percentile_sorted(&[7.0], 95.0), 7.0);
        let mut rng = Rng::new(2);
        let mut v: Vec<f64> = (0..101).map(|_| rng.next_f64()).collect();
        let r = ref_percentile(&v, 37.3);
        v.sort_by(|a, b| a.total_cmp(b));
        assert!((percentile_sorted(&v, 37.3) - r).abs() < 1e-15);
    }

    #[test]
    fn reflect101_matches_opencv_layout() {
        // n = 4: … 2 1 | 0 1 2 3 | 2 1 0 1 …
        let got: Vec<usize> = (-3..8).map(|i| reflect101(i, 4)).collect();
        assert_eq!(got, vec![3, 2, 1, 0, 1, 2, 3, 2, 1, 0, 1]);
        assert_eq!(reflect101(-5, 1), 0);
        assert_eq!(reflect101(9, 2), 1);
    }

    #[test]
    fn gaussian_kernel_sigma_rule() {
        let k = gaussian_kernel(9);
        assert_eq!(k.len(), 9);
        assert!((k.iter().sum::<f64>() - 1.0).abs() < 1e-15);
        // σ = 1.7 for k = 9: ratio of neighbours e^(−1/(2σ²)).
        let s = 1.7f64;
        assert!((k[5] / k[4] - (-1.0 / (2.0 * s * s)).exp()).abs() < 1e-12);
    }

    #[test]
    fn whole_aggregation_matches_f64_reference() {
        let (w, h) = (13, 9);
        for (m, params) in [
            (5, AggregateParams::default()),
            (
                4,
                AggregateParams {
                    gamma: 0.5,
                    blur: Some(9),
                    percentiles: (5.0, 95.0),
                    floor: Some(0.1),
                },
            ),
            (
                3,
                AggregateParams {
                    gamma: 3.0,
                    blur: Some(3),
                    percentiles: (10.0, 80.0),
                    floor: None,
                },
            ),
            (
                2,
                AggregateParams {
                    gamma: 1.0,
                    blur: Some(5),
                    percentiles: (0.0, 100.0),
                    floor: Some(0.5),
                },
            ),
        ] {
            let mem = random_members(m, w * h, m as u64);
            let refs: Vec<&[f32]> = mem.iter().map(|v| v.as_slice()).collect();
            let got = aggregate_view(&refs, w, h, &params, &mut Workspace::default());
            let (t, wt) = ref_aggregate(&mem, w, h, &params);
            for (a, b) in got.target.iter().zip(&t) {
                assert!((*a as f64 - b).abs() < 1e-6, "target {a} vs {b}");
            }
            for (a, b) in got.weight.iter().zip(&wt) {
                assert!(
                    (*a as f64 - b).abs() < 1e-5,
                    "weight {a} vs {b} ({params:?})"
                );
            }
            assert!(!got.degenerate);
            // Clipping happened: some pixels at the top and bottom of the range.
            let f = params.floor.unwrap_or(0.0) as f32;
            if params.percentiles != (0.0, 100.0) {
                assert!(got.weight.iter().any(|&x| (x - 1.0).abs() < 1e-6));
                assert!(got.weight.iter().any(|&x| (x - f).abs() < 1e-6));
            }
        }
    }

    #[test]
    fn gamma_and_floor_closed_form() {
        // Variance ramp 0..1 with percentiles (0, 100): V_n = V exactly.
        let var: Vec<f64> = (0..=10).map(|i| i as f64 / 10.0).collect();
        let mut out = vec![0.0f32; 11];
        for gamma in [0.0, 0.5, 1.0, 1.5, 2.0, 3.0] {
            for floor in [None, Some(0.1), Some(1.0)] {
                confidence_weights(&var, 0.0, 1.0, gamma, floor, &mut out);
                let f = floor.unwrap_or(0.0);
                for (i, &w) in out.iter().enumerate() {
                    let e = f + (1.0 - f) * (1.0 - var[i]).powf(gamma);
                    assert!((w as f64 - e).abs() < 1e-7, "γ={gamma} f={floor:?} i={i}");
                }
            }
        }
        // γ = 0: exactly 1 everywhere, even at V_n = 1.
        confidence_weights(&var, 0.0, 1.0, 0.0, None, &mut out);
        assert!(out.iter().all(|&w| w == 1.0));
    }

    #[test]
    fn degenerate_cases_are_finite_and_documented() {
        let (w, h) = (6, 5);
        let n = w * h;
        // M = 1: variance 0 → weight 1 everywhere, target = the member.
        let one = random_members(1, n, 1);
        for params in [
            AggregateParams::default(),
            AggregateParams {
                blur: Some(9),
                floor: Some(0.1),
                ..AggregateParams::default()
            },
        ] {
            let a = aggregate_view(&[&one[0]], w, h, &params, &mut Workspace::default());
            assert!(a.degenerate);
            assert!(a.weight.iter().all(|&x| x == 1.0));
            assert_eq!(a.target, one[0]);
        }
        // Constant (non-zero) variance: members differ by the same offset everywhere.
        let base: Vec<f32> = vec![0.5; 3 * n];
        let plus: Vec<f32> = vec![0.7; 3 * n];
        let a = aggregate_view(
            &[&base, &plus],
            w,
            h,
            &AggregateParams::default(),
            &mut Workspace::default(),
        );
        assert!(a.degenerate && a.p_lo == a.p_hi && a.p_lo > 0.0);
        assert!(a.weight.iter().all(|&x| x == 1.0));
        assert!(a.target.iter().all(|&x| (x - 0.6).abs() < 1e-6));
        // P95 = P5 = 0 but a few pixels vary: those get V_n = 1 (the limit of the clipped
        // ramp), the rest weight 1.
        let mut odd = base.clone();
        odd[0] = 0.9; // pixel 0, red
        let a = aggregate_view(
            &[&base, &odd],
            w,
            h,
            &AggregateParams::default(),
            &mut Workspace::default(),
        );
        assert!(a.degenerate);
        assert_eq!(a.weight[0], 0.0);
        assert!(a.weight[1..].iter().all(|&x| x == 1.0));
        // 1×1 image with blur.
        let tiny = random_members(3, 1, 4);
        let refs: Vec<&[f32]> = tiny.iter().map(|v| v.as_slice()).collect();
        let a = aggregate_view(
            &refs,
            1,
            1,
            &AggregateParams {
                blur: Some(9),
                ..AggregateParams::default()
            },
            &mut Workspace::default(),
        );
        assert!(a.weight[0].is_finite() && a.weight[0] == 1.0);
    }

    #[test]
    fn validation_rejects_bad_args() {
        let bad = [
            AggregateParams {
                gamma: -1.0,
                ..Default::default()
            },
            AggregateParams {
                gamma: f64::NAN,
                ..Default::default()
            },
            AggregateParams {
                blur: Some(4),
                ..Default::default()
            },
            AggregateParams {
                percentiles: (95.0, 5.0),
                ..Default::default()
            },
            AggregateParams {
                percentiles: (5.0, 101.0),
                ..Default::default()
            },
            AggregateParams {
                floor: Some(1.5),
                ..Default::default()
            },
        ];
        for b in bad {
            assert!(b.validate().is_err(), "{b:?}");
        }
        assert!(AggregateParams::default().validate().is_ok());
    }
}
