//! Photometric losses with their gradients: L1, L2, per-pixel weighted L2 and a fused
//! SSIM forward/backward (11×11 Gaussian window, σ = 1.5, K1 = 0.01, K2 = 0.03, data range 1).
//!
//! Images are interleaved `H·W·3` f32 slices (the layout of [`crate::RenderOutput::rgb`]).
//! Every loss returns its value in f64 and *adds* `scale · dL/d(pred)` into a gradient buffer,
//! so several terms (and several weighted supervision sources) accumulate into one buffer
//! without temporaries.
//!
//! SSIM uses **valid** padding, as gsplat's `fused_ssim(..., padding="valid")` in
//! `simple_trainer`: the map covers the `(H−10)×(W−10)` positions where the whole window fits,
//! so borders carry no padding artefacts. For an image smaller than the window in either
//! dimension the map is empty; [`ssim`] then returns `1.0` and adds no gradient (the SSIM term
//! of the loss vanishes), which is documented rather than an error because tiny synthetic views
//! are legitimate. Evaluation SSIM (torchmetrics, reflect padding) lives in `augsplat-metrics`.
//!
//! **How the fused kernel is laid out.** All three channels are filtered together on the
//! interleaved rows (a horizontal tap is an offset of 3 floats), so nothing is de-interleaved.
//! The image is cut into fixed bands of rows (the cut depends only on the image height); one
//! task streams through its band: the horizontal pass of the five moment rows (μx, μy, E\[x²\],
//! E\[y²\], E\[xy\]) goes into a 12-row ring, the vertical pass turns 11 ring rows into one SSIM
//! row and its three per-pixel partials (dS/dμx, dS/dE\[x²\], dS/dE\[xy\]) in a second ring (with
//! AVX2, two map rows per pass from the 12 ring rows they need, which halves the ring reads), and
//! as soon as an input row has all the partials it needs, the adjoint passes (vertical gather,
//! horizontal gather) and the chain rule through the moments (`A + 2x·B + y·C`) add its
//! gradient, together with the L2/L1 term, straight into the caller's buffer. A band
//! recomputes the 10-row halo its neighbours also compute, so the working set of a task is a
//! few hundred kB (cache resident) and nothing image-sized is written besides the gradient.
//! The loops work on blocks of 16 values with `f32::mul_add` taps; they are compiled for every
//! tier of [`augsplat_core::simd`] (AVX2+FMA and the baseline) and chosen at run time. `mul_add` is a fused
//! multiply-add in every version (hardware FMA, or the exact libm `fmaf` on CPUs without
//! it), and every sum has a fixed lane structure written in the code, so the result is
//! bit-identical on every CPU and for any rayon thread count.
//!
//! # Where things are
//!
//! | file | what it owns |
//! |---|---|
//! | `mod.rs` | the public losses: L1, L2, weighted L2, [`ssim`], [`photometric`] |
//! | `fused.rs` | the fused SSIM forward/backward in bands (the portable statement of the maths) |
//! | `pair_avx2.rs` | the AVX2 paired vertical pass (x86-64) |
//! | `reference.rs` | plain f64 versions (direct per-window sums) for the tests |
//! | `tests.rs` | the kernels against the references; every tier and thread count bit for bit |

mod fused;
pub(crate) mod gpu;
#[cfg(target_arch = "x86_64")]
mod pair_avx2;
pub mod reference;
#[cfg(test)]
mod tests;

use augsplat_core::multiversion;
use fused::{fused, l1_step, lane_sum, Fused, Geo, Pix};
use rayon::prelude::*;

/// Values per SIMD block of the fused kernel and lanes of the pixel-loss sums (two AVX2
/// vectors).
const LANES: usize = 16;

/// SSIM window side.
pub const SSIM_WINDOW: usize = 11;
/// SSIM Gaussian σ, pixels.
pub const SSIM_SIGMA: f64 = 1.5;
/// SSIM stabiliser C1 = (K1 · L)², K1 = 0.01, L = 1.
pub const SSIM_C1: f64 = 0.01 * 0.01;
/// SSIM stabiliser C2 = (K2 · L)², K2 = 0.03, L = 1.
pub const SSIM_C2: f64 = 0.03 * 0.03;

/// Which pixel-wise term a real-image loss uses.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
pub enum PixelLoss {
    /// Mean squared error (the AugSplat paper's real loss).
    #[default]
    L2,
    /// Mean absolute error (gsplat's and Inria's default).
    L1,
}

/// The normalised 1-D Gaussian window (separable factor of the 11×11 window), in f64.
pub fn gaussian_window() -> [f64; SSIM_WINDOW] {
    let mut w = [0.0; SSIM_WINDOW];
    let half = (SSIM_WINDOW / 2) as f64;
    let mut sum = 0.0;
    for (k, v) in w.iter_mut().enumerate() {
        let d = k as f64 - half;
        *v = (-d * d / (2.0 * SSIM_SIGMA * SSIM_SIGMA)).exp();
        sum += *v;
    }
    for v in &mut w {
        *v /= sum;
    }
    w
}

fn check_len(pred: &[f32], target: &[f32], grad: &[f32]) {
    assert_eq!(
        pred.len(),
        target.len(),
        "loss: prediction and target sizes differ"
    );
    assert_eq!(
        pred.len(),
        grad.len(),
        "loss: prediction and gradient sizes differ"
    );
}

/// Sums `f(i)` over `0..n` in fixed chunks of `chunk` items (parallel), then the chunk sums in
/// order: deterministic for any thread count.
fn det_sum(n: usize, chunk: usize, f: impl Fn(std::ops::Range<usize>) -> f64 + Sync) -> f64 {
    let chunks = n.div_ceil(chunk.max(1));
    let parts: Vec<f64> = (0..chunks)
        .into_par_iter()
        .map(|c| f(c * chunk..((c + 1) * chunk).min(n)))
        .collect();
    parts.iter().sum()
}

/// Values per parallel chunk of the element-wise losses (a multiple of the lane count).
const PIX_CHUNK: usize = 16 * 1024;

/// L2 (`L2 = true`) or L1 over one chunk: adds `k·(pred − target)` (L2) or `±k` (L1) into
/// `grad` and returns the lane sums of `(pred − target)²` or `|pred − target|`.
#[inline(always)]
fn pixel_chunk_body<const L2: bool>(
    pred: &[f32],
    target: &[f32],
    k: f32,
    grad: &mut [f32],
) -> [f64; LANES] {
    let mut acc = [0f64; LANES];
    let full = pred.len() / LANES * LANES;
    for ((p, t), gc) in pred[..full]
        .chunks_exact(LANES)
        .zip(target[..full].chunks_exact(LANES))
        .zip(grad[..full].chunks_exact_mut(LANES))
    {
        for l in 0..LANES {
            gc[l] = pixel_elem::<L2>(p[l], t[l], k, gc[l], &mut acc[l]);
        }
    }
    for (l, ((&p, &t), gv)) in pred[full..]
        .iter()
        .zip(&target[full..])
        .zip(&mut grad[full..])
        .enumerate()
    {
        *gv = pixel_elem::<L2>(p, t, k, *gv, &mut acc[l]);
    }
    acc
}

/// One value of the L2 (`L2 = true`) or L1 term: the new gradient, loss added into `acc`.
#[inline(always)]
fn pixel_elem<const L2: bool>(p: f32, t: f32, k: f32, gv: f32, acc: &mut f64) -> f32 {
    let d = p - t;
    if L2 {
        *acc += (d as f64) * (d as f64);
        k.mul_add(d, gv)
    } else {
        *acc += d.abs() as f64;
        l1_step(d, k, gv)
    }
}

#[inline(always)]
fn l2_chunk_body(pred: &[f32], target: &[f32], k: f32, grad: &mut [f32]) -> [f64; LANES] {
    pixel_chunk_body::<true>(pred, target, k, grad)
}

#[inline(always)]
fn l1_chunk_body(pred: &[f32], target: &[f32], k: f32, grad: &mut [f32]) -> [f64; LANES] {
    pixel_chunk_body::<false>(pred, target, k, grad)
}

multiversion!(fn l2_chunk(pred: &[f32], target: &[f32], k: f32, grad: &mut [f32]) -> [f64; LANES] => l2_chunk_body);
multiversion!(fn l1_chunk(pred: &[f32], target: &[f32], k: f32, grad: &mut [f32]) -> [f64; LANES] => l1_chunk_body);

/// A chunk kernel of an element-wise loss: (pred, target, gradient factor, gradient) → lane sums.
type PixelKernel = fn(&[f32], &[f32], f32, &mut [f32]) -> [f64; LANES];

/// Runs a pixel-loss chunk kernel over fixed chunks in parallel; chunk sums in order.
fn pixel_loss(pred: &[f32], target: &[f32], k: f32, grad: &mut [f32], kernel: PixelKernel) -> f64 {
    let parts: Vec<f64> = grad
        .par_chunks_mut(PIX_CHUNK)
        .enumerate()
        .map(|(c, gc)| {
            let r = c * PIX_CHUNK..c * PIX_CHUNK + gc.len();
            lane_sum(&kernel(&pred[r.clone()], &target[r], k, gc))
        })
        .collect();
    parts.iter().sum()
}

/// Mean squared error over all values; adds `scale · dL/dpred` into `grad`.
///
/// Panics if the slices differ in length (a programming error, not bad data).
pub fn l2(pred: &[f32], target: &[f32], scale: f32, grad: &mut [f32]) -> f64 {
    check_len(pred, target, grad);
    let n = pred.len();
    if n == 0 {
        return 0.0;
    }
    pixel_loss(pred, target, 2.0 * scale / n as f32, grad, l2_chunk) / n as f64
}

/// Mean absolute error over all values; adds `scale · dL/dpred` into `grad` (subgradient 0 at
/// equality).
pub fn l1(pred: &[f32], target: &[f32], scale: f32, grad: &mut [f32]) -> f64 {
    check_len(pred, target, grad);
    let n = pred.len();
    if n == 0 {
        return 0.0;
    }
    pixel_loss(pred, target, scale / n as f32, grad, l1_chunk) / n as f64
}

/// How a weighted L2 loss is normalised.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum WeightNorm {
    /// Divide by `3 · Σ w` (a weighted mean of the squared error; AugSplat code's default).
    WeightSum,
    /// Divide by `3 · H · W` (the mean of `w · d²`).
    PixelCount,
}

/// Confidence-weighted L2: `L = Σ_p w_p Σ_c (pred − target)² / N`, with `N = 3 Σ_p w_p`
/// ([`WeightNorm::WeightSum`]) or `N = 3 · pixels` ([`WeightNorm::PixelCount`]). Both equal the
/// plain MSE when every weight is 1. `weights` has one value per pixel (`pred.len() / 3`).
/// A zero (or non-positive) weight sum gives loss 0 and no gradient. Non-finite weights are
/// treated as 0. Adds `scale · dL/dpred` into `grad`.
pub fn weighted_l2(
    pred: &[f32],
    target: &[f32],
    weights: &[f32],
    norm: WeightNorm,
    scale: f32,
    grad: &mut [f32],
) -> f64 {
    check_len(pred, target, grad);
    assert_eq!(
        pred.len(),
        weights.len() * 3,
        "weighted_l2: weight map size differs"
    );
    let px = weights.len();
    if px == 0 {
        return 0.0;
    }
    let clean = |w: f32| if w.is_finite() && w > 0.0 { w } else { 0.0 };
    let denom = weighted_l2_denominator(weights, norm);
    if denom <= 0.0 || !denom.is_finite() {
        return 0.0;
    }
    let g = (2.0 * scale as f64 / denom) as f32;
    let chunk = 4096; // pixels
    let loss = grad
        .par_chunks_mut(chunk * 3)
        .enumerate()
        .map(|(c, gc)| {
            let base = c * chunk;
            let mut s = 0.0f64;
            for (k, gp) in gc.chunks_exact_mut(3).enumerate() {
                let p = base + k;
                let w = clean(weights[p]);
                if w == 0.0 {
                    continue;
                }
                for ch in 0..3 {
                    let d = pred[p * 3 + ch] - target[p * 3 + ch];
                    s += w as f64 * (d as f64) * (d as f64);
                    gp[ch] += g * w * d;
                }
            }
            s
        })
        .collect::<Vec<f64>>()
        .iter()
        .sum::<f64>();
    loss / denom
}

/// The denominator `N` of [`weighted_l2`] for a weight map: `3 · Σ w` over the finite
/// positive weights ([`WeightNorm::WeightSum`], summed in fixed chunks) or `3 · pixels`
/// ([`WeightNorm::PixelCount`]). The GPU's weighted L2 takes the same number.
pub fn weighted_l2_denominator(weights: &[f32], norm: WeightNorm) -> f64 {
    let clean = |w: f32| if w.is_finite() && w > 0.0 { w } else { 0.0 };
    match norm {
        WeightNorm::WeightSum => {
            3.0 * det_sum(weights.len(), 4096, |r| {
                r.map(|p| clean(weights[p]) as f64).sum()
            })
        }
        WeightNorm::PixelCount => 3.0 * weights.len() as f64,
    }
}

/// Fused SSIM forward and backward (valid padding, see the module docs). Returns the mean SSIM
/// over the `(H−10)·(W−10)·3` map values and adds `scale · dSSIM/dpred` into `grad` (pass a
/// negative scale for a `1 − SSIM` loss). `pred` and `target` are interleaved `H·W·3`.
///
/// Panics if the slices differ in length or do not hold `width·height·3` values (a
/// programming error, not bad data).
pub fn ssim(
    pred: &[f32],
    target: &[f32],
    width: usize,
    height: usize,
    scale: f32,
    grad: &mut [f32],
) -> f64 {
    check_len(pred, target, grad);
    assert_eq!(pred.len(), width * height * 3, "ssim: image size mismatch");
    if width < SSIM_WINDOW || height < SSIM_WINDOW {
        return 1.0;
    }
    let geo = Geo::new(width, height);
    let count = (geo.m * geo.oh) as f64;
    let f = Fused {
        geo,
        win: gaussian_window().map(|v| v as f32),
        pix: Pix::None,
        gs: (scale as f64 / count) as f32,
        backward: scale != 0.0,
    };
    fused(&f, pred, target, grad).1 / count
}

/// The real-image loss `(1 − λ)·P + λ·(1 − SSIM)` with P the L2 or L1 term. Adds
/// `scale · dL/dpred` into `grad` and returns `(loss, pixel term, ssim)`.
#[allow(clippy::too_many_arguments)]
pub fn photometric(
    pred: &[f32],
    target: &[f32],
    width: usize,
    height: usize,
    kind: PixelLoss,
    ssim_lambda: f32,
    scale: f32,
    grad: &mut [f32],
) -> (f64, f64, f64) {
    let lam = ssim_lambda as f64;
    let pix_scale = scale * (1.0 - ssim_lambda);
    if ssim_lambda == 0.0 || width < SSIM_WINDOW || height < SSIM_WINDOW {
        // No SSIM map: the pixel term alone (SSIM counts as 1).
        let p = match kind {
            PixelLoss::L2 => l2(pred, target, pix_scale, grad),
            PixelLoss::L1 => l1(pred, target, pix_scale, grad),
        };
        return ((1.0 - lam) * p, p, 1.0);
    }
    check_len(pred, target, grad);
    assert_eq!(
        pred.len(),
        width * height * 3,
        "photometric: image size mismatch"
    );
    let geo = Geo::new(width, height);
    let n = pred.len();
    let count = (geo.m * geo.oh) as f64;
    let ssim_scale = -scale * ssim_lambda;
    let f = Fused {
        geo,
        win: gaussian_window().map(|v| v as f32),
        pix: match kind {
            PixelLoss::L2 => Pix::L2(2.0 * pix_scale / n as f32),
            PixelLoss::L1 => Pix::L1(pix_scale / n as f32),
        },
        gs: (ssim_scale as f64 / count) as f32,
        backward: scale != 0.0,
    };
    let (ps, ss) = fused(&f, pred, target, grad);
    let p = ps / n as f64;
    let s = ss / count;
    ((1.0 - lam) * p + lam * (1.0 - s), p, s)
}
