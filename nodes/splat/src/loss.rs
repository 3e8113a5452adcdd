//! Photometric losses with their gradients: L1, L2, per-pixel weighted L2 and a fused
//! SSIM forward/backward (11×11 Gaussian window, σ = 1.5, K1 = 0.01, K2 = 0.03, data range 1).
//!
//! Images are interleaved `H·W·3` f32 slices (the layout of [`crate::RenderOutput::rgb`]).
//! Every loss returns its value in f64 and *adds* `scale · dL/d(pred)` into a gradient buffer,
//! so several terms (and several weighted supervision sources) accumulate into one buffer
//! without temporaries. Reductions run over fixed row chunks and are summed in row order, so
//! results are bit-identical for any rayon thread count.
//!
//! SSIM uses **valid** padding, as gsplat's `fused_ssim(..., padding="valid")` in
//! `simple_trainer`: the map covers the `(H−10)×(W−10)` positions where the whole window fits,
//! so borders carry no padding artefacts. For an image smaller than the window in either
//! dimension the map is empty; [`ssim`] then returns `1.0` and adds no gradient (the SSIM term
//! of the loss vanishes), which is documented rather than an error because tiny synthetic views
//! are legitimate. Evaluation SSIM (torchmetrics, reflect padding) lives in `augsplat-metrics`.
//!
//! [`reference`] holds plain f64 versions (direct per-window sums) for the tests.

use rayon::prelude::*;

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

/// Mean squared error over all values; adds `scale · dL/dpred` into `grad`.
///
/// Panics if the slices differ in length (a programming error, not bad data).
pub fn l2(pred: &[f32], target: &[f32], scale: f32, grad: &mut [f32]) -> f64 {
    check_len(pred, target, grad);
    let n = pred.len();
    if n == 0 {
        return 0.0;
    }
    let g = 2.0 * scale / n as f32;
    let chunk = 4096;
    let loss = grad
        .par_chunks_mut(chunk)
        .enumerate()
        .map(|(c, gc)| {
            let base = c * chunk;
            let mut s = 0.0f64;
            for (k, gv) in gc.iter_mut().enumerate() {
                let d = pred[base + k] - target[base + k];
                s += (d as f64) * (d as f64);
                *gv += g * d;
            }
            s
        })
        .collect::<Vec<f64>>()
        .iter()
        .sum::<f64>();
    loss / n as f64
}

/// Mean absolute error over all values; adds `scale · dL/dpred` into `grad` (subgradient 0 at
/// equality).
pub fn l1(pred: &[f32], target: &[f32], scale: f32, grad: &mut [f32]) -> f64 {
    check_len(pred, target, grad);
    let n = pred.len();
    if n == 0 {
        return 0.0;
    }
    let g = scale / n as f32;
    let chunk = 4096;
    let loss = grad
        .par_chunks_mut(chunk)
        .enumerate()
        .map(|(c, gc)| {
            let base = c * chunk;
            let mut s = 0.0f64;
            for (k, gv) in gc.iter_mut().enumerate() {
                let d = pred[base + k] - target[base + k];
                s += d.abs() as f64;
                if d > 0.0 {
                    *gv += g;
                } else if d < 0.0 {
                    *gv -= g;
                }
            }
            s
        })
        .collect::<Vec<f64>>()
        .iter()
        .sum::<f64>();
    loss / n as f64
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
    let denom = match norm {
        WeightNorm::WeightSum => {
            3.0 * det_sum(px, 4096, |r| r.map(|p| clean(weights[p]) as f64).sum())
        }
        WeightNorm::PixelCount => 3.0 * px as f64,
    };
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

/// Fused SSIM forward and backward (valid padding, see the module docs). Returns the mean SSIM
/// over the `(H−10)·(W−10)·3` map values and adds `scale · dSSIM/dpred` into `grad` (pass a
/// negative scale for a `1 − SSIM` loss). `pred` and `target` are interleaved `H·W·3`.
///
/// Layout for speed: the images are split into planar channels, both separable passes run
/// over contiguous rows (taps outermost, so the inner loops vectorise), and the backward is
/// the adjoint of the two passes (a row gather vertically, a row scatter horizontally). Work
/// is split by (channel, row); every output value is computed by one task and the loss is
/// summed per row then in row order, so the result does not depend on the thread count.
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
    let win = gaussian_window().map(|v| v as f32);
    let ow = width - (SSIM_WINDOW - 1);
    let oh = height - (SSIM_WINDOW - 1);
    let count = (ow * oh * 3) as f64;
    let plane = width * height;
    // Planar copies [c][y][x].
    let mut xp = vec![0f32; 3 * plane];
    let mut yp = vec![0f32; 3 * plane];
    xp.par_chunks_mut(plane)
        .zip(yp.par_chunks_mut(plane))
        .enumerate()
        .for_each(|(c, (xs, ys))| {
            for p in 0..plane {
                xs[p] = pred[p * 3 + c];
                ys[p] = target[p * 3 + c];
            }
        });
    // Horizontal pass: five moment rows per (channel, row), each `ow` long:
    // hmom[((c·H + y)·5 + q)·ow + x].
    let mut hmom = vec![0f32; 3 * height * 5 * ow];
    hmom.par_chunks_mut(5 * ow)
        .enumerate()
        .for_each(|(row, out)| {
            let c = row / height;
            let y = row % height;
            let xr = &xp[c * plane + y * width..c * plane + (y + 1) * width];
            let yr = &yp[c * plane + y * width..c * plane + (y + 1) * width];
            let (mx, rest) = out.split_at_mut(ow);
            let (my, rest) = rest.split_at_mut(ow);
            let (mxx, rest) = rest.split_at_mut(ow);
            let (myy, mxy) = rest.split_at_mut(ow);
            for (k, &wk) in win.iter().enumerate() {
                let xs = &xr[k..k + ow];
                let ys = &yr[k..k + ow];
                for x in 0..ow {
                    let (a, b) = (xs[x], ys[x]);
                    mx[x] += wk * a;
                    my[x] += wk * b;
                    mxx[x] += wk * a * a;
                    myy[x] += wk * b * b;
                    mxy[x] += wk * a * b;
                }
            }
        });
    // Vertical pass → SSIM values and the partials dS/dμx, dS/dE[x²], dS/dE[xy] per map
    // position: part[((c·oh + oy)·3 + p)·ow + ox].
    let mut part = vec![0f32; 3 * oh * 3 * ow];
    let rows: Vec<f64> = part
        .par_chunks_mut(3 * ow)
        .enumerate()
        .map_init(
            || vec![0f32; 5 * ow],
            |m, (row, out)| {
                let c = row / oh;
                let oy = row % oh;
                m.iter_mut().for_each(|v| *v = 0.0);
                for (k, &wk) in win.iter().enumerate() {
                    let src =
                        &hmom[(c * height + oy + k) * 5 * ow..(c * height + oy + k + 1) * 5 * ow];
                    for (d, s) in m.iter_mut().zip(src) {
                        *d += wk * s;
                    }
                }
                let (pa, rest) = out.split_at_mut(ow);
                let (pb, pc) = rest.split_at_mut(ow);
                let mut s = 0f64;
                for ox in 0..ow {
                    let mux = m[ox] as f64;
                    let muy = m[ow + ox] as f64;
                    let sxx = m[2 * ow + ox] as f64 - mux * mux;
                    let syy = m[3 * ow + ox] as f64 - muy * muy;
                    let sxy = m[4 * ow + ox] as f64 - mux * muy;
                    let n1 = 2.0 * mux * muy + SSIM_C1;
                    let n2 = 2.0 * sxy + SSIM_C2;
                    let d1 = mux * mux + muy * muy + SSIM_C1;
                    let d2 = sxx + syy + SSIM_C2;
                    let v = n1 * n2 / (d1 * d2);
                    s += v;
                    pa[ox] = (v
                        * (2.0 * muy / n1 - 2.0 * muy / n2 - 2.0 * mux / d1 + 2.0 * mux / d2))
                        as f32;
                    pb[ox] = (-v / d2) as f32;
                    pc[ox] = (2.0 * v / n2) as f32;
                }
                s
            },
        )
        .collect();
    let loss = rows.iter().sum::<f64>() / count;
    if scale == 0.0 {
        return loss;
    }
    let gscale = (scale as f64 / count) as f32;
    // Backward. Vertical adjoint (gather over the ≤ 11 map rows that used input row y), then
    // horizontal adjoint (scatter each map column over its 11 input columns), then the chain
    // rule through the moments: d/dx = A + 2x·B + y·C.
    grad.par_chunks_mut(width * 3).enumerate().for_each_init(
        || (vec![0f32; 3 * ow], vec![0f32; 3 * width]),
        |(vb, hb), (y, grow)| {
            let k_lo = (y + 1).saturating_sub(oh);
            let k_hi = y.min(SSIM_WINDOW - 1);
            for c in 0..3 {
                vb.iter_mut().for_each(|v| *v = 0.0);
                for (k, &wk) in win.iter().enumerate().take(k_hi + 1).skip(k_lo) {
                    let oy = y - k;
                    let src = &part[(c * oh + oy) * 3 * ow..(c * oh + oy + 1) * 3 * ow];
                    for (d, s) in vb.iter_mut().zip(src) {
                        *d += wk * s;
                    }
                }
                hb.iter_mut().for_each(|v| *v = 0.0);
                for p in 0..3 {
                    let v = &vb[p * ow..(p + 1) * ow];
                    let h = &mut hb[p * width..(p + 1) * width];
                    for (k, &wk) in win.iter().enumerate() {
                        let dst = &mut h[k..k + ow];
                        for (d, s) in dst.iter_mut().zip(v) {
                            *d += wk * s;
                        }
                    }
                }
                let xr = &xp[c * plane + y * width..c * plane + (y + 1) * width];
                let yr = &yp[c * plane + y * width..c * plane + (y + 1) * width];
                for x in 0..width {
                    let d = hb[x] + 2.0 * xr[x] * hb[width + x] + yr[x] * hb[2 * width + x];
                    grow[x * 3 + c] += gscale * d;
                }
            }
        },
    );
    loss
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
    let pix_scale = scale * (1.0 - ssim_lambda);
    let p = match kind {
        PixelLoss::L2 => l2(pred, target, pix_scale, grad),
        PixelLoss::L1 => l1(pred, target, pix_scale, grad),
    };
    let s = if ssim_lambda != 0.0 {
        ssim(pred, target, width, height, -scale * ssim_lambda, grad)
    } else {
        1.0
    };
    let lam = ssim_lambda as f64;
    ((1.0 - lam) * p + lam * (1.0 - s), p, s)
}

/// Plain f64 references (direct per-window sums, no separability) for the tests.
pub mod reference {
    use super::*;

    /// Mean SSIM over the valid map, computed per window in f64.
    pub fn ssim(pred: &[f64], target: &[f64], width: usize, height: usize) -> f64 {
        if width < SSIM_WINDOW || height < SSIM_WINDOW {
            return 1.0;
        }
        let w1 = gaussian_window();
        let (ow, oh) = (width - SSIM_WINDOW + 1, height - SSIM_WINDOW + 1);
        let mut total = 0.0;
        for ch in 0..3 {
            for oy in 0..oh {
                for ox in 0..ow {
                    let (mut mx, mut my, mut exx, mut eyy, mut exy) = (0.0, 0.0, 0.0, 0.0, 0.0);
                    for ky in 0..SSIM_WINDOW {
                        for kx in 0..SSIM_WINDOW {
                            let w = w1[ky] * w1[kx];
                            let i = ((oy + ky) * width + ox + kx) * 3 + ch;
                            let (x, y) = (pred[i], target[i]);
                            mx += w * x;
                            my += w * y;
                            exx += w * x * x;
                            eyy += w * y * y;
                            exy += w * x * y;
                        }
                    }
                    let vx = exx - mx * mx;
                    let vy = eyy - my * my;
                    let cxy = exy - mx * my;
                    total += (2.0 * mx * my + SSIM_C1) * (2.0 * cxy + SSIM_C2)
                        / ((mx * mx + my * my + SSIM_C1) * (vx + vy + SSIM_C2));
                }
            }
        }
        total / (ow * oh * 3) as f64
    }

    /// Weighted L2 in f64 with the same normalisation rules as [`super::weighted_l2`].
    pub fn weighted_l2(pred: &[f64], target: &[f64], weights: &[f64], norm: WeightNorm) -> f64 {
        let mut s = 0.0;
        let mut ws = 0.0;
        for (p, &w) in weights.iter().enumerate() {
            let w = if w.is_finite() && w > 0.0 { w } else { 0.0 };
            ws += w;
            for ch in 0..3 {
                let d = pred[p * 3 + ch] - target[p * 3 + ch];
                s += w * d * d;
            }
        }
        let denom = match norm {
            WeightNorm::WeightSum => 3.0 * ws,
            WeightNorm::PixelCount => 3.0 * weights.len() as f64,
        };
        if denom <= 0.0 {
            0.0
        } else {
            s / denom
        }
    }
}
