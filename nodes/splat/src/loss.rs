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
//! The loops work on blocks of 16 values with `f32::mul_add` taps; they are compiled three
//! times (AVX-512, AVX2+FMA, baseline) and chosen at run time. `mul_add` is a fused
//! multiply-add in every version (hardware FMA, or the exact libm `fmaf` on CPUs without
//! it), and every sum has a fixed lane structure written in the code, so the result is
//! bit-identical on every CPU and for any rayon thread count.
//!
//! [`mod@reference`] holds plain f64 versions (direct per-window sums) for the tests.

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

/// Values per SIMD block of the fused kernel (one AVX-512 vector, two AVX2 vectors).
const LANES: usize = 16;
/// Rows (and interleaved values / 3) a window reaches past its first one.
const HALO: usize = SSIM_WINDOW - 1;
/// The halo in interleaved values (3 channels).
const HALO3: usize = 3 * HALO;
/// Rows in the rings of horizontal moments and of partials: one window plus one, so that
/// two consecutive map rows can be filtered together ([`vertical_pair`]).
const RING: usize = SSIM_WINDOW + 1;
/// Rows per band of the fused SSIM for an image of `height` rows: an even number of bands
/// (two per started 256 rows; one below 48 rows) of equal height, the last one possibly
/// shorter. A function of the height only, so results do not depend on the thread count;
/// each band recomputes a 10-row halo, so fewer, taller bands waste less.
fn band_rows(height: usize) -> usize {
    if height < 48 {
        return height.max(1);
    }
    let bands = 2 * height.div_ceil(256);
    height.div_ceil(bands)
}

/// The geometry of one SSIM evaluation, in interleaved values.
#[derive(Clone, Copy, Debug)]
struct Geo {
    /// Image height.
    h: usize,
    /// Interleaved row length, `3·W`.
    l: usize,
    /// Interleaved map row length, `3·(W − 10)`.
    m: usize,
    /// `m` rounded up to a multiple of [`LANES`].
    mp: usize,
    /// `l` rounded up to a multiple of [`LANES`].
    lp: usize,
    /// Map height, `H − 10`.
    oh: usize,
}

impl Geo {
    fn new(width: usize, height: usize) -> Self {
        let l = 3 * width;
        let m = 3 * (width - HALO);
        Geo {
            h: height,
            l,
            m,
            mp: m.div_ceil(LANES) * LANES,
            lp: l.div_ceil(LANES) * LANES,
            oh: height - HALO,
        }
    }
    /// Length of a zero-padded input row (the horizontal pass reads `mp + 30` values).
    fn rl(&self) -> usize {
        self.mp + HALO3
    }
    /// Length of a padded adjoint row: `30` zeros, `mp` values, zeros up to `lp + 30`.
    fn vl(&self) -> usize {
        self.lp + HALO3
    }
}

/// The per-task buffers of the fused SSIM (reused across calls through a thread-local).
#[derive(Default)]
struct Scratch {
    /// Input rows x, y, x², y², xy (each `rl` long, zero tail).
    rows: Vec<f32>,
    /// Ring of [`RING`] horizontal-moment rows: `[slot][moment][mp]`.
    hm: Vec<f32>,
    /// Ring of [`RING`] partial rows: `[slot][partial][mp]` (tail beyond `m` kept zero).
    part: Vec<f32>,
    /// The SSIM values of the second map row of a [`vertical_pair`] (`mp` values).
    pair_ssim: Vec<f32>,
    /// Vertical adjoint rows, `[partial][vl]`, data at `30..30 + mp`, zeros around it.
    vb: Vec<f32>,
    /// Horizontal adjoint rows, `[partial][lp]`.
    hb: Vec<f32>,
}

impl Scratch {
    fn prepare(&mut self, g: &Geo) {
        let fit = |v: &mut Vec<f32>, n: usize| {
            v.clear();
            v.resize(n, 0.0);
        };
        fit(&mut self.rows, 5 * g.rl());
        fit(&mut self.hm, RING * 5 * g.mp);
        fit(&mut self.part, RING * 3 * g.mp);
        fit(&mut self.pair_ssim, g.mp);
        fit(&mut self.vb, 3 * g.vl());
        fit(&mut self.hb, 3 * g.lp);
    }
}

thread_local! {
    static SCRATCH: std::cell::RefCell<Scratch> = std::cell::RefCell::new(Scratch::default());
}

/// The pixel term fused into the SSIM pass.
#[derive(Clone, Copy, Debug, PartialEq)]
enum Pix {
    /// None (plain SSIM).
    None,
    /// L2 with gradient factor `2·scale/n`.
    L2(f32),
    /// L1 with gradient factor `scale/n`.
    L1(f32),
}

/// What one fused call computes.
#[derive(Clone, Copy, Debug)]
struct Fused {
    geo: Geo,
    win: [f32; SSIM_WINDOW],
    pix: Pix,
    /// `scale / count`, the factor of dSSIM/dpred.
    gs: f32,
    /// Whether gradients are written at all.
    backward: bool,
}

/// Horizontal 11-tap filter of an interleaved row: `dst[j] = Σ_k w_k src[j + 3k]`,
/// `j < dst.len()` (a multiple of [`LANES`]; `src` is at least `dst.len() + 30` long).
#[inline(always)]
fn hfilter(src: &[f32], dst: &mut [f32], win: &[f32; SSIM_WINDOW]) {
    for (jb, out) in dst.chunks_exact_mut(LANES).enumerate() {
        let j = jb * LANES;
        let mut acc = [0f32; LANES];
        for (k, &wk) in win.iter().enumerate() {
            let s = &src[j + 3 * k..j + 3 * k + LANES];
            for l in 0..LANES {
                acc[l] = wk.mul_add(s[l], acc[l]);
            }
        }
        out.copy_from_slice(&acc);
    }
}

/// Horizontal pass of input row `r`: the five moment rows into ring slot `r % RING`.
#[inline(always)]
fn horizontal_row(f: &Fused, pred: &[f32], target: &[f32], r: usize, sc: &mut Scratch) {
    let g = &f.geo;
    let rl = g.rl();
    let (xr, rest) = sc.rows.split_at_mut(rl);
    let (yr, rest) = rest.split_at_mut(rl);
    let (xx, rest) = rest.split_at_mut(rl);
    let (yy, xy) = rest.split_at_mut(rl);
    xr[..g.l].copy_from_slice(&pred[r * g.l..(r + 1) * g.l]);
    yr[..g.l].copy_from_slice(&target[r * g.l..(r + 1) * g.l]);
    for i in 0..g.l {
        let (a, b) = (xr[i], yr[i]);
        xx[i] = a * a;
        yy[i] = b * b;
        xy[i] = a * b;
    }
    let slot = &mut sc.hm[(r % RING) * 5 * g.mp..(r % RING + 1) * 5 * g.mp];
    for (q, src) in [&*xr, &*yr, &*xx, &*yy, &*xy].into_iter().enumerate() {
        hfilter(src, &mut slot[q * g.mp..(q + 1) * g.mp], &f.win);
    }
}

/// SSIM of one window from its five moments, and the partials dS/dμx, dS/dE[x²], dS/dE[xy].
/// One division: with `inv = 1/(d1·d2)`, `S = n1·n2·inv`,
/// `dS/dμx = 2·inv·(μy·(n2 − n1) + μx·S·(d1 − d2))`, `dS/dE[x²] = −S·d1·inv`,
/// `dS/dE[xy] = 2·n1·inv`.
#[inline(always)]
fn ssim_window(mx: f32, my: f32, exx: f32, eyy: f32, exy: f32) -> [f32; 4] {
    const C1: f32 = SSIM_C1 as f32;
    const C2: f32 = SSIM_C2 as f32;
    let mx2 = mx * mx;
    let my2 = my * my;
    let mxy = mx * my;
    let n1 = 2.0 * mxy + C1;
    let n2 = 2.0 * (exy - mxy) + C2;
    let d1 = mx2 + my2 + C1;
    let d2 = (exx - mx2) + (eyy - my2) + C2;
    let inv = 1.0 / (d1 * d2);
    let s = n1 * n2 * inv;
    let a = 2.0 * inv * (my * (n2 - n1) + mx * s * (d1 - d2));
    let b = -s * d1 * inv;
    let c = 2.0 * n1 * inv;
    [s, a, b, c]
}

/// SSIM and its three partials ([`ssim_window`]) of a block of windows from their five
/// moment sums, `[moment][lane]`.
#[inline(always)]
fn ssim_block(mo: &[[f32; LANES]; 5]) -> [[f32; LANES]; 4] {
    let mut out = [[0f32; LANES]; 4];
    for l in 0..LANES {
        let r = ssim_window(mo[0][l], mo[1][l], mo[2][l], mo[3][l], mo[4][l]);
        for p in 0..4 {
            out[p][l] = r[p];
        }
    }
    out
}

/// Adds the SSIM values of the block at `j` that lie in the map (`j + l < m`) to `lanes`.
#[inline(always)]
fn count_block(vals: &[f32; LANES], j: usize, m: usize, lanes: &mut [f64; LANES]) {
    for l in 0..LANES {
        if j + l < m {
            lanes[l] += vals[l] as f64;
        }
    }
}

/// Vertical pass of map row `oy` from ring rows `oy..oy + 11`: the partials into ring slot
/// `oy % RING` (zero beyond `m`); when `count`, the SSIM values are added to `lanes`.
#[inline(always)]
fn vertical_row(f: &Fused, oy: usize, sc: &mut Scratch, count: bool, lanes: &mut [f64; LANES]) {
    let g = &f.geo;
    let mp = g.mp;
    let hm = &sc.hm;
    let slot = oy % RING;
    let part = &mut sc.part[slot * 3 * mp..(slot + 1) * 3 * mp];
    let base: [usize; SSIM_WINDOW] = std::array::from_fn(|k| ((oy + k) % RING) * 5 * mp);
    for jb in 0..mp / LANES {
        let j = jb * LANES;
        let mut mo = [[0f32; LANES]; 5];
        for (k, &wk) in f.win.iter().enumerate() {
            for (q, mq) in mo.iter_mut().enumerate() {
                let s = &hm[base[k] + q * mp + j..base[k] + q * mp + j + LANES];
                for l in 0..LANES {
                    mq[l] = wk.mul_add(s[l], mq[l]);
                }
            }
        }
        let out = ssim_block(&mo);
        if count {
            count_block(&out[0], j, g.m, lanes);
        }
        for p in 0..3 {
            part[p * mp + j..p * mp + j + LANES].copy_from_slice(&out[p + 1]);
        }
    }
    for p in 0..3 {
        part[p * mp + g.m..(p + 1) * mp].fill(0.0);
    }
}

/// Whether [`vertical_pair`] runs on this CPU (it needs AVX2 + FMA; elsewhere map rows are
/// filtered one at a time, with the same results).
#[inline(always)]
fn pairs_available() -> bool {
    cfg!(target_arch = "x86_64") && simd_level() >= 1
}

/// [`vertical_row`] of map rows `oy` and `oy + 1` in one pass over the 12 moment rows they
/// read (they share 10, so the ring is read about half as often): each value's sums in the
/// same order as two single calls, so the results are bit-identical. `count` says per row
/// whether its SSIM values are added to `lanes`, row `oy`'s first (as two calls would).
/// Only called where [`pairs_available`].
#[cfg(target_arch = "x86_64")]
#[inline(always)]
fn vertical_pair(
    f: &Fused,
    oy: usize,
    sc: &mut Scratch,
    count: [bool; 2],
    lanes: &mut [f64; LANES],
) {
    let g = &f.geo;
    let mp = g.mp;
    let (slot0, slot1) = (oy % RING, (oy + 1) % RING);
    let base: [usize; RING] = std::array::from_fn(|k| ((oy + k) % RING) * 5 * mp);
    assert!(sc.hm.len() >= RING * 5 * mp && mp.is_multiple_of(LANES));
    for jb in 0..mp / LANES {
        let j = jb * LANES;
        let mut m0 = [[0f32; LANES]; 5];
        let mut m1 = [[0f32; LANES]; 5];
        // SAFETY: `pairs_available` (checked by the caller) means AVX2 and FMA; every read
        // lies inside the ring (asserted above: base[k] + 4·mp + j + LANES ≤ RING·5·mp).
        unsafe { pair_avx2::moments(&sc.hm, &base, mp, j, &f.win, &mut m0, &mut m1) };
        let out = ssim_block(&m0);
        if count[0] {
            count_block(&out[0], j, g.m, lanes);
        }
        for p in 0..3 {
            let o = (slot0 * 3 + p) * mp + j;
            sc.part[o..o + LANES].copy_from_slice(&out[p + 1]);
        }
        let out = ssim_block(&m1);
        sc.pair_ssim[j..j + LANES].copy_from_slice(&out[0]);
        for p in 0..3 {
            let o = (slot1 * 3 + p) * mp + j;
            sc.part[o..o + LANES].copy_from_slice(&out[p + 1]);
        }
    }
    for slot in [slot0, slot1] {
        for p in 0..3 {
            let o = (slot * 3 + p) * mp;
            sc.part[o + g.m..o + mp].fill(0.0);
        }
    }
    // Row oy + 1's SSIM values after all of row oy's, as two single calls add them.
    if count[1] {
        for (i, &v) in sc.pair_ssim[..g.m].iter().enumerate() {
            lanes[i % LANES] += v as f64;
        }
    }
}

/// The moment sums of [`vertical_pair`] with explicit AVX2 fused multiply-adds (the
/// auto-vectorised form of the paired loop compiles to scalar code). Each sum is
/// `fma(w_k, value, sum)` from +0 over k in ascending order, exactly as [`vertical_row`]'s
/// `mul_add`s, so the bits are the same.
#[cfg(target_arch = "x86_64")]
mod pair_avx2 {
    use super::{HALO, LANES, RING, SSIM_WINDOW};
    use std::arch::x86_64::*;

    /// Moments of map rows oy (`m0`) and oy + 1 (`m1`) for the `LANES` values from `j`:
    /// moment row k (ring offset `base[k]`) feeds `m0` with weight `win[k]` and `m1` with
    /// weight `win[k − 1]`.
    ///
    /// # Safety
    /// The CPU must have AVX2 and FMA, and `base[k] + 4·mp + j + LANES ≤ hm.len()` for all k.
    // Index loops over the five moments: each is one register.
    #[allow(clippy::needless_range_loop)]
    #[target_feature(enable = "avx2,fma")]
    pub(super) unsafe fn moments(
        hm: &[f32],
        base: &[usize; RING],
        mp: usize,
        j: usize,
        win: &[f32; SSIM_WINDOW],
        m0: &mut [[f32; LANES]; 5],
        m1: &mut [[f32; LANES]; 5],
    ) {
        let p = hm.as_ptr();
        for h in (0..LANES).step_by(8) {
            let mut a0 = [_mm256_setzero_ps(); 5];
            let mut a1 = [_mm256_setzero_ps(); 5];
            let w = _mm256_set1_ps(win[0]);
            for q in 0..5 {
                let s = _mm256_loadu_ps(p.add(base[0] + q * mp + j + h));
                a0[q] = _mm256_fmadd_ps(w, s, a0[q]);
            }
            for k in 1..SSIM_WINDOW {
                let (wa, wb) = (_mm256_set1_ps(win[k]), _mm256_set1_ps(win[k - 1]));
                for q in 0..5 {
                    let s = _mm256_loadu_ps(p.add(base[k] + q * mp + j + h));
                    a0[q] = _mm256_fmadd_ps(wa, s, a0[q]);
                    a1[q] = _mm256_fmadd_ps(wb, s, a1[q]);
                }
            }
            let w = _mm256_set1_ps(win[HALO]);
            for q in 0..5 {
                let s = _mm256_loadu_ps(p.add(base[SSIM_WINDOW] + q * mp + j + h));
                a1[q] = _mm256_fmadd_ps(w, s, a1[q]);
            }
            for q in 0..5 {
                _mm256_storeu_ps(m0[q].as_mut_ptr().add(h), a0[q]);
                _mm256_storeu_ps(m1[q].as_mut_ptr().add(h), a1[q]);
            }
        }
    }
}

/// The backward of input row `y` (`y − a` in the band's gradient rows `grow`): vertical
/// gather of the partial rows, horizontal gather, chain rule, plus the pixel term.
#[inline(always)]
fn gradient_row<const P: u8>(
    f: &Fused,
    pred: &[f32],
    target: &[f32],
    y: usize,
    grow: &mut [f32],
    sc: &mut Scratch,
    pix_lanes: &mut [f64; LANES],
) {
    let g = &f.geo;
    let (mp, vl, lp) = (g.mp, g.vl(), g.lp);
    // Vertical adjoint: map rows y − k, k ∈ [klo, khi], each in the partial ring.
    let klo = (y + 1).saturating_sub(g.oh);
    let khi = y.min(HALO);
    {
        let part = &sc.part;
        let vb = &mut sc.vb;
        for jb in 0..mp / LANES {
            let j = jb * LANES;
            let mut acc = [[0f32; LANES]; 3];
            for k in klo..=khi {
                let wk = f.win[k];
                let slot = (y - k) % RING;
                for (p, ap) in acc.iter_mut().enumerate() {
                    let o = (slot * 3 + p) * mp + j;
                    let s = &part[o..o + LANES];
                    for l in 0..LANES {
                        ap[l] = wk.mul_add(s[l], ap[l]);
                    }
                }
            }
            for (p, ap) in acc.iter().enumerate() {
                vb[p * vl + HALO3 + j..p * vl + HALO3 + j + LANES].copy_from_slice(ap);
            }
        }
    }
    // Horizontal adjoint: hb[i] = Σ_k w_k vb[30 + i − 3k].
    for p in 0..3 {
        let src = &sc.vb[p * vl..(p + 1) * vl];
        let dst = &mut sc.hb[p * lp..(p + 1) * lp];
        for (ib, out) in dst.chunks_exact_mut(LANES).enumerate() {
            let i = ib * LANES + HALO3;
            let mut acc = [0f32; LANES];
            for (k, &wk) in f.win.iter().enumerate() {
                let s = &src[i - 3 * k..i - 3 * k + LANES];
                for l in 0..LANES {
                    acc[l] = wk.mul_add(s[l], acc[l]);
                }
            }
            out.copy_from_slice(&acc);
        }
    }
    // Chain rule through the moments, plus the pixel term.
    let xr = &pred[y * g.l..(y + 1) * g.l];
    let tr = &target[y * g.l..(y + 1) * g.l];
    let (ha, rest) = sc.hb.split_at(lp);
    let (hbb, hc) = rest.split_at(lp);
    let k = match f.pix {
        Pix::None => 0.0,
        Pix::L2(k) | Pix::L1(k) => k,
    };
    let gs = f.gs;
    let full = g.l / LANES * LANES;
    let mut acc = *pix_lanes;
    for (ib, gc) in grow[..full].chunks_exact_mut(LANES).enumerate() {
        let i = ib * LANES;
        let (x, t) = (&xr[i..i + LANES], &tr[i..i + LANES]);
        let (a, b, c) = (&ha[i..i + LANES], &hbb[i..i + LANES], &hc[i..i + LANES]);
        for l in 0..LANES {
            gc[l] = combine::<P>(gs, k, x[l], t[l], a[l], b[l], c[l], gc[l], &mut acc[l]);
        }
    }
    for (l, gv) in grow[full..g.l].iter_mut().enumerate() {
        let i = full + l;
        *gv = combine::<P>(gs, k, xr[i], tr[i], ha[i], hbb[i], hc[i], *gv, &mut acc[l]);
    }
    *pix_lanes = acc;
}

/// [`Pix`] as a const parameter: no pixel term.
const PIX_NONE: u8 = 0;
/// L2 pixel term.
const PIX_L2: u8 = 1;
/// L1 pixel term.
const PIX_L1: u8 = 2;

/// The chain rule through the moments for one value (`dS/dx = A + 2x·B + y·C`, scaled),
/// plus the pixel term; returns the new gradient value and adds the pixel loss into `acc`.
#[inline(always)]
#[allow(clippy::too_many_arguments)]
fn combine<const P: u8>(
    gs: f32,
    k: f32,
    x: f32,
    t: f32,
    a: f32,
    b: f32,
    c: f32,
    gv: f32,
    acc: &mut f64,
) -> f32 {
    let d = t.mul_add(c, (2.0 * x).mul_add(b, a));
    let diff = x - t;
    let base = match P {
        PIX_L2 => {
            *acc += (diff as f64) * (diff as f64);
            k.mul_add(diff, gv)
        }
        PIX_L1 => {
            *acc += diff.abs() as f64;
            l1_step(diff, k, gv)
        }
        _ => gv,
    };
    gs.mul_add(d, base)
}

/// `gv ± k` by the sign of `diff` (unchanged at 0): the L1 subgradient step.
#[inline(always)]
fn l1_step(diff: f32, k: f32, gv: f32) -> f32 {
    if diff > 0.0 {
        gv + k
    } else if diff < 0.0 {
        gv - k
    } else {
        gv
    }
}

/// The pixel-term sum of row `y` without gradients (forward-only calls).
#[inline(always)]
fn pixel_sum_row(f: &Fused, pred: &[f32], target: &[f32], y: usize, acc: &mut [f64; LANES]) {
    let l = f.geo.l;
    let xr = &pred[y * l..(y + 1) * l];
    let tr = &target[y * l..(y + 1) * l];
    for i in 0..l {
        let diff = xr[i] - tr[i];
        acc[i % LANES] += match f.pix {
            Pix::None => 0.0,
            Pix::L2(_) => (diff as f64) * (diff as f64),
            Pix::L1(_) => diff.abs() as f64,
        };
    }
}

/// One band: gradient rows `a..b` (`grad` holds exactly those rows). Returns the lane sums
/// of (pixel term over rows `a..b`, SSIM over map rows `a..min(b, oh)`).
#[inline(always)]
fn band_body(
    f: &Fused,
    pred: &[f32],
    target: &[f32],
    a: usize,
    b: usize,
    grad: &mut [f32],
    sc: &mut Scratch,
) -> ([f64; LANES], [f64; LANES]) {
    match f.pix {
        Pix::None => band_impl::<PIX_NONE>(f, pred, target, a, b, grad, sc),
        Pix::L2(_) => band_impl::<PIX_L2>(f, pred, target, a, b, grad, sc),
        Pix::L1(_) => band_impl::<PIX_L1>(f, pred, target, a, b, grad, sc),
    }
}

/// [`band_body`] for one pixel term.
#[inline(always)]
fn band_impl<const P: u8>(
    f: &Fused,
    pred: &[f32],
    target: &[f32],
    a: usize,
    b: usize,
    grad: &mut [f32],
    sc: &mut Scratch,
) -> ([f64; LANES], [f64; LANES]) {
    let g = &f.geo;
    let mut pix = [0f64; LANES];
    let mut ssim = [0f64; LANES];
    // Map rows this band evaluates: its own, plus (for the backward) the 10 above.
    let oy0 = if f.backward {
        a.saturating_sub(HALO)
    } else {
        a
    };
    let oy1 = g.oh.min(b);
    for r in oy0..(oy0 + HALO).min(g.h) {
        horizontal_row(f, pred, target, r, sc);
    }
    let pairs = pairs_available();
    let mut oy = oy0;
    while oy < oy1 {
        // Two map rows at a time where there are two left (and the paired kernel runs).
        let rows = if pairs && oy + 1 < oy1 { 2 } else { 1 };
        for r in 0..rows {
            horizontal_row(f, pred, target, oy + r + HALO, sc);
        }
        if rows == 2 {
            #[cfg(target_arch = "x86_64")]
            vertical_pair(f, oy, sc, [oy >= a, oy + 1 >= a], &mut ssim);
        } else {
            vertical_row(f, oy, sc, oy >= a, &mut ssim);
        }
        for y in oy..oy + rows {
            if f.backward && y >= a {
                let o = (y - a) * g.l;
                gradient_row::<P>(f, pred, target, y, &mut grad[o..o + g.l], sc, &mut pix);
            }
        }
        oy += rows;
    }
    for y in a.max(g.oh)..b {
        if f.backward {
            let o = (y - a) * g.l;
            gradient_row::<P>(f, pred, target, y, &mut grad[o..o + g.l], sc, &mut pix);
        }
    }
    if !f.backward && f.pix != Pix::None {
        for y in a..b {
            pixel_sum_row(f, pred, target, y, &mut pix);
        }
    }
    (pix, ssim)
}

/// Which vector extension the fused kernels use on this CPU (0 = baseline, 1 = AVX2+FMA,
/// 2 = AVX-512).
pub(crate) fn simd_level() -> u8 {
    use std::sync::atomic::{AtomicU8, Ordering};
    static LEVEL: AtomicU8 = AtomicU8::new(u8::MAX);
    let mut v = LEVEL.load(Ordering::Relaxed);
    if v == u8::MAX {
        #[allow(unused_mut)]
        let mut level = 0u8;
        #[cfg(target_arch = "x86_64")]
        {
            use std::arch::is_x86_feature_detected as has;
            if has!("avx2") && has!("fma") {
                level = 1;
                if has!("avx512f") && has!("avx512vl") {
                    level = 2;
                }
            }
        }
        LEVEL.store(level, Ordering::Relaxed);
        v = level;
    }
    #[cfg(test)]
    {
        let f = test_simd::FORCED.load(Ordering::Relaxed);
        if f != u8::MAX {
            return f.min(v);
        }
    }
    v
}

/// Test-only control of the dispatched instruction set.
#[cfg(test)]
pub(crate) mod test_simd {
    use std::sync::atomic::{AtomicU8, Ordering};
    use std::sync::Mutex;

    /// The forced level (`u8::MAX` = none).
    pub(crate) static FORCED: AtomicU8 = AtomicU8::new(u8::MAX);
    static LOCK: Mutex<()> = Mutex::new(());

    /// Runs `f` once per available level (baseline, AVX2, AVX-512 as far as the CPU has
    /// them), holding a lock so no other forcing test interleaves; returns the results.
    pub(crate) fn each_level<R>(mut f: impl FnMut() -> R) -> Vec<(u8, R)> {
        let _g = LOCK.lock().unwrap_or_else(|e| e.into_inner());
        FORCED.store(u8::MAX, Ordering::SeqCst);
        let top = super::simd_level();
        let mut out = Vec::new();
        for level in 0..=top {
            FORCED.store(level, Ordering::SeqCst);
            out.push((level, f()));
        }
        FORCED.store(u8::MAX, Ordering::SeqCst);
        out
    }
}

/// Defines `$name` with the signature of the `#[inline(always)]` function `$body`, compiled
/// for AVX-512, AVX2+FMA and the baseline target, dispatched by [`simd_level`]. Results are
/// identical in every version as long as `$body` uses `mul_add` (never a separate multiply
/// and add that the compiler could not fuse anyway) and fixed reduction orders.
macro_rules! multiversion {
    ($vis:vis fn $name:ident($($a:ident : $t:ty),* $(,)?) $(-> $r:ty)? => $body:path) => {
        #[allow(clippy::too_many_arguments)]
        $vis fn $name($($a: $t),*) $(-> $r)? {
            #[cfg(target_arch = "x86_64")]
            {
                #[target_feature(enable = "avx512f,avx512vl,avx2,fma")]
                #[allow(clippy::too_many_arguments)]
                unsafe fn v512($($a: $t),*) $(-> $r)? {
                    $body($($a),*)
                }
                #[target_feature(enable = "avx2,fma")]
                #[allow(clippy::too_many_arguments)]
                unsafe fn v256($($a: $t),*) $(-> $r)? {
                    $body($($a),*)
                }
                match $crate::loss::simd_level() {
                    // SAFETY: the CPU supports the enabled features (checked at run time).
                    2 => return unsafe { v512($($a),*) },
                    // SAFETY: as above.
                    1 => return unsafe { v256($($a),*) },
                    _ => {}
                }
            }
            $body($($a),*)
        }
    };
}
pub(crate) use multiversion;

multiversion!(fn band(
    f: &Fused,
    pred: &[f32],
    target: &[f32],
    a: usize,
    b: usize,
    grad: &mut [f32],
    sc: &mut Scratch,
) -> ([f64; LANES], [f64; LANES]) => band_body);

/// Sums lane accumulators in a fixed order.
fn lane_sum(l: &[f64; LANES]) -> f64 {
    l.iter().sum()
}

/// The fused pass: returns (pixel-term sum, SSIM sum) and adds the scaled gradients.
fn fused(f: &Fused, pred: &[f32], target: &[f32], grad: &mut [f32]) -> (f64, f64) {
    let g = f.geo;
    let rows = band_rows(g.h);
    let parts: Vec<([f64; LANES], [f64; LANES])> = grad
        .par_chunks_mut(rows * g.l)
        .enumerate()
        .map(|(bi, gb)| {
            let a = bi * rows;
            let b = (a + rows).min(g.h);
            SCRATCH.with(|s| {
                let mut sc = s.borrow_mut();
                sc.prepare(&g);
                band(f, pred, target, a, b, gb, &mut sc)
            })
        })
        .collect();
    let mut pix = 0.0;
    let mut ssim = 0.0;
    for (p, s) in &parts {
        pix += lane_sum(p);
        ssim += lane_sum(s);
    }
    (pix, ssim)
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

#[cfg(test)]
mod tests {
    use super::*;
    use augsplat_core::Rng;

    fn image(rng: &mut Rng, w: usize, h: usize) -> Vec<f32> {
        (0..w * h * 3).map(|_| rng.next_f32()).collect()
    }

    /// A target correlated with `p` (so SSIM is far from 0 and the partials are varied).
    fn correlated(rng: &mut Rng, p: &[f32], mix: f32) -> Vec<f32> {
        p.iter()
            .map(|&v| (mix * v + (1.0 - mix) * rng.next_f32()).min(1.0))
            .collect()
    }

    fn to64(v: &[f32]) -> Vec<f64> {
        v.iter().map(|&x| x as f64).collect()
    }

    /// Mean SSIM and its gradient in f64, window by window (no separability, no bands),
    /// with the partials in their textbook form (four divisions).
    fn reference_with_grad(p: &[f64], t: &[f64], w: usize, h: usize) -> (f64, Vec<f64>) {
        let w1 = gaussian_window();
        let (ow, oh) = (w - HALO, h - HALO);
        let count = (ow * oh * 3) as f64;
        let mut total = 0.0;
        let mut grad = vec![0.0; p.len()];
        for ch in 0..3 {
            for oy in 0..oh {
                for ox in 0..ow {
                    let idx = |ky: usize, kx: usize| ((oy + ky) * w + ox + kx) * 3 + ch;
                    let (mut mx, mut my, mut exx, mut eyy, mut exy) = (0.0, 0.0, 0.0, 0.0, 0.0);
                    for ky in 0..SSIM_WINDOW {
                        for kx in 0..SSIM_WINDOW {
                            let wt = w1[ky] * w1[kx];
                            let (x, y) = (p[idx(ky, kx)], t[idx(ky, kx)]);
                            mx += wt * x;
                            my += wt * y;
                            exx += wt * x * x;
                            eyy += wt * y * y;
                            exy += wt * x * y;
                        }
                    }
                    let n1 = 2.0 * mx * my + SSIM_C1;
                    let n2 = 2.0 * (exy - mx * my) + SSIM_C2;
                    let d1 = mx * mx + my * my + SSIM_C1;
                    let d2 = exx - mx * mx + eyy - my * my + SSIM_C2;
                    let s = n1 * n2 / (d1 * d2);
                    total += s;
                    let a = s * (2.0 * my / n1 - 2.0 * my / n2 - 2.0 * mx / d1 + 2.0 * mx / d2);
                    let b = -s / d2;
                    let c = 2.0 * s / n2;
                    for ky in 0..SSIM_WINDOW {
                        for kx in 0..SSIM_WINDOW {
                            let i = idx(ky, kx);
                            grad[i] += w1[ky] * w1[kx] * (a + 2.0 * p[i] * b + t[i] * c) / count;
                        }
                    }
                }
            }
        }
        (total / count, grad)
    }

    #[test]
    fn fused_ssim_and_gradient_match_the_f64_window_reference_across_bands() {
        let mut rng = Rng::new(21);
        // Widths with map rows that are and are not multiples of 16; one band (11 rows), two
        // bands, and six bands (530 rows).
        for &(w, h, mix) in &[
            (11usize, 11usize, 0.6f32),
            (16, 75, 0.8),
            (27, 138, 0.5),
            (12, 530, 0.9),
            (43, 66, 0.3),
        ] {
            let p = image(&mut rng, w, h);
            let t = correlated(&mut rng, &p, mix);
            let mut g = vec![0f32; p.len()];
            let s = ssim(&p, &t, w, h, 1.0, &mut g);
            let (r, rg) = reference_with_grad(&to64(&p), &to64(&t), w, h);
            assert!((s - r).abs() < 2e-6, "{w}x{h}: fused {s} vs reference {r}");
            let gmax = rg.iter().fold(0f64, |m, v| m.max(v.abs()));
            let worst = g
                .iter()
                .zip(&rg)
                .map(|(&a, &b)| (a as f64 - b).abs())
                .fold(0f64, f64::max);
            assert!(
                worst <= 2e-5 * gmax,
                "{w}x{h}: worst gradient error {worst:e} vs max {gmax:e}"
            );
            // The reference gradient itself against central differences of the reference SSIM
            // at a few values (band edges included).
            let x = to64(&p);
            let t64 = to64(&t);
            for &i in &[
                0,
                3 * w * (h / 2) + 1,
                3 * (w * 64 + 5) % p.len(),
                p.len() - 1,
            ] {
                let hstep = 1e-5;
                let mut a = x.clone();
                a[i] += hstep;
                let fp = reference::ssim(&a, &t64, w, h);
                a[i] -= 2.0 * hstep;
                let fm = reference::ssim(&a, &t64, w, h);
                let num = (fp - fm) / (2.0 * hstep);
                assert!(
                    (num - rg[i]).abs() <= 1e-6 * gmax + 1e-10,
                    "{w}x{h} value {i}: reference gradient {} vs fd {num}",
                    rg[i]
                );
            }
        }
    }

    #[test]
    fn photometric_fused_equals_its_separate_terms_bit_for_bit() {
        let mut rng = Rng::new(8);
        let (w, h) = (37usize, 141usize);
        let p = image(&mut rng, w, h);
        let t = correlated(&mut rng, &p, 0.7);
        let g0: Vec<f32> = (0..p.len()).map(|_| rng.next_f32() - 0.5).collect();
        for kind in [PixelLoss::L2, PixelLoss::L1] {
            let mut fused_g = g0.clone();
            let (lv, pix, s) = photometric(&p, &t, w, h, kind, 0.2, 1.5, &mut fused_g);
            let mut sep_g = g0.clone();
            let pix2 = match kind {
                PixelLoss::L2 => l2(&p, &t, 1.5 * 0.8, &mut sep_g),
                PixelLoss::L1 => l1(&p, &t, 1.5 * 0.8, &mut sep_g),
            };
            let s2 = ssim(&p, &t, w, h, -1.5 * 0.2, &mut sep_g);
            assert!(
                (pix - pix2).abs() <= 1e-12 * pix2.abs(),
                "{kind:?}: {pix} vs {pix2}"
            );
            assert!((s - s2).abs() <= 1e-12, "{kind:?}: {s} vs {s2}");
            let lam = 0.2f32 as f64;
            assert!((lv - ((1.0 - lam) * pix + lam * (1.0 - s))).abs() < 1e-12);
            for (i, (a, b)) in fused_g.iter().zip(&sep_g).enumerate() {
                assert_eq!(a.to_bits(), b.to_bits(), "{kind:?} value {i}: {a} vs {b}");
            }
        }
        // Scale 0: values only, the buffer untouched.
        let mut g = g0.clone();
        let (_, pix, s) = photometric(&p, &t, w, h, PixelLoss::L2, 0.2, 0.0, &mut g);
        assert_eq!(g, g0);
        let mut scratch = vec![0f32; p.len()];
        assert!((pix - l2(&p, &t, 0.0, &mut scratch)).abs() < 1e-12);
        assert!((s - ssim(&p, &t, w, h, 0.0, &mut scratch)).abs() < 1e-12);
    }

    #[test]
    fn losses_are_bit_identical_for_every_instruction_set_and_thread_count() {
        let mut rng = Rng::new(4);
        let (w, h) = (45usize, 130usize);
        let p = image(&mut rng, w, h);
        let t = correlated(&mut rng, &p, 0.6);
        let run = |threads: usize| {
            rayon::ThreadPoolBuilder::new()
                .num_threads(threads)
                .build()
                .unwrap()
                .install(|| {
                    let mut g = vec![0f32; p.len()];
                    let a = photometric(&p, &t, w, h, PixelLoss::L2, 0.2, 1.0, &mut g);
                    let b = photometric(&p, &t, w, h, PixelLoss::L1, 0.3, 0.5, &mut g);
                    let c = l2(&p, &t, 0.7, &mut g);
                    let d = l1(&p, &t, 0.7, &mut g);
                    let bits = |v: (f64, f64, f64)| [v.0.to_bits(), v.1.to_bits(), v.2.to_bits()];
                    let vals = [bits(a), bits(b), [c.to_bits(), d.to_bits(), 0]];
                    (vals, g.iter().map(|v| v.to_bits()).collect::<Vec<_>>())
                })
        };
        let results = test_simd::each_level(|| [run(1), run(2), run(3)]);
        let first = &results[0].1[0];
        for (level, per_threads) in &results {
            for (k, r) in per_threads.iter().enumerate() {
                assert!(
                    r == first,
                    "level {level}, run {k} differs from baseline 1-thread"
                );
            }
        }
    }

    #[test]
    fn non_finite_inputs_do_not_panic_and_stay_local() {
        let mut rng = Rng::new(2);
        let (w, h) = (30usize, 90usize);
        let mut p = image(&mut rng, w, h);
        let t = image(&mut rng, w, h);
        p[3 * (w * 5 + 5)] = f32::NAN;
        let mut g = vec![0f32; p.len()];
        let (lv, _, _) = photometric(&p, &t, w, h, PixelLoss::L2, 0.2, 1.0, &mut g);
        assert!(lv.is_nan());
        // Far from the bad value (more than a window away) the gradient is clean.
        let far = 3 * (w * 60 + 20);
        assert!(g[far].is_finite() && g[far] != 0.0);
    }
}
