//! The analytic backward pass.
//!
//! 1. Per tile (in parallel), Gaussians are revisited back to front starting from the
//!    tile's largest last-contributor index; each pixel recovers its transmittance before a
//!    Gaussian as T_i = T_{i+1} / (1 − α_i) from the final T kept by the forward pass, and the
//!    "behind" sum of the loss is accumulated as the walk proceeds. Each (tile, Gaussian)
//!    pair writes its summed screen-space gradient (mean2d, conic, opacity, colour, depth)
//!    into its own slot of a pair buffer, so no two tiles ever write the same memory.
//! 2. Per Gaussian (in parallel), its pair slots are summed in f64 in a fixed order (tiles in
//!    row-major order) — results are bit-identical for any number of threads — and the
//!    projection and SH backward ([`crate::project::project_vjp`],
//!    [`crate::sh::eval_color_vjp_into`]) turn these into gradients of the raw parameters, the
//!    SH view direction's dependence on the mean included.
//!
//! With α = α₁·s(α₁) (smooth cutoff, tests only) or α = α₁ (hard), α₁ = min(max_alpha, o·e^−σ):
//! dL/dα_i = Σ_c g_c (c_i T_i − B_c/(1 − α_i)) + g_A' T_N/(1 − α_i) + g_S (z_i T_i − B_z/(1 − α_i))
//! with B the sums over Gaussians behind i (B_c includes T_N·background), g_S = g_D/A and
//! g_A' = g_A − g_D·D/A from the alpha-normalised depth D = S/A. Per pixel the kernel keeps
//! G_i = Σ_c g_c c_i + g_S z_i and one running sum R = Σ_behind G_j α_j T_j + T_N (g·bg − g_A'),
//! so that dL/dα_i = G_i T_i − R/(1 − α_i) = (G_i T_{i+1} − R)/(1 − α_i).
//!
//! Per (tile, Gaussian) the pixel lanes accumulate, with Q = dL/dα₁ · e^−σ (zero where the
//! alpha clamp is active): P = ΣQ, S_x = ΣQ·dx, S_y = ΣQ·dy, S_xx, S_xy, S_yy, and the colour
//! and depth sums Σ g_c·α·T, Σ g_S·α·T; since dσ = ½dx²·da + dx·dy·db + ½dy²·dc + (a dx + b dy)
//! d(mean_x) + (b dx + c dy) d(mean_y) and dα₁/dσ = −o·e^−σ, the screen-space gradient
//! follows from these sums per pair. dx is constant along a pixel lane (a tile column), so a
//! lane accumulates only ΣQ, ΣQ·dy and ΣQ·dy² over the rows and forms its S_x, S_xx and S_xy
//! by multiplying by its dx once (the sums are named in the `sum` module).
//!
//! # Where things are
//!
//! | file | what it owns |
//! |---|---|
//! | `mod.rs` | the two steps: per-tile pair gradients and their dispatch by instruction-set tier |
//! | `tile.rs` | the portable twin of the backward tile kernel (the maths) and the `BackwardKernel` trait |
//! | `avx2.rs` | the AVX2 tile kernel (x86-64) |
//! | `gaussian.rs` | step 2: per-Gaussian fixed-order sums, projection and SH backward in f64 lanes |
//! | `tests.rs` | every tier against the portable twin bit for bit |
//!
//! As in the forward pass, every kernel has a portable twin and an AVX2 variant performing
//! the same IEEE operations, so the results are bit-identical on every CPU
//! ([`augsplat_core::simd`] chooses the tier).

// Negated comparisons are deliberate: they also reject NaN. Index loops read best in
// small fixed-size numeric code.

// Negated comparisons are deliberate: they also reject NaN. Index loops read best in
// small fixed-size numeric code.
#![allow(clippy::neg_cmp_op_on_partial_ord, clippy::needless_range_loop)]

#[cfg(target_arch = "x86_64")]
mod avx2;
mod gaussian;
pub mod gpu;
#[cfg(test)]
mod tests;
mod tile;

use crate::buffers::filled_par;
use crate::constants::{DEPTH_ALPHA_EPS, TILE, TILE_PIXELS};
use crate::forward::Splat2D;
use crate::gaussians::Gaussians;
use crate::render::{Cutoff, Gradients, RenderOutput, RenderSettings};
use augsplat_core::simd::{self, Isa};
use augsplat_core::Camera;
use gaussian::{gaussian_gradients, GradSinks, Mode};
use rayon::prelude::*;
use tile::{backward_tile_portable, BwdTile};

/// Screen-space gradient of one (tile, Gaussian) pair: mean2d x, y; conic a, b, c; opacity;
/// colour r, g, b; depth.
type PairGrad = [f32; 10];

/// Per-pixel lane sums of one (tile, Gaussian) pair, indexed by the constants of `sum`.
type LaneSums = [f32; 10];

/// The indices of [`LaneSums`] (see the module documentation for the sums themselves).
pub(crate) mod sum {
    /// P = ΣQ, with Q = dL/dα₁ · e^−σ (zero where the alpha clamp is active).
    pub const Q: usize = 0;
    /// S_x = ΣQ·dx.
    pub const Q_DX: usize = 1;
    /// S_y = ΣQ·dy.
    pub const Q_DY: usize = 2;
    /// S_xx = ΣQ·dx².
    pub const Q_DX2: usize = 3;
    /// S_xy = ΣQ·dx·dy.
    pub const Q_DXDY: usize = 4;
    /// S_yy = ΣQ·dy².
    pub const Q_DY2: usize = 5;
    /// Σ g_c·α·T for the colour channels r, g, b (`COLOR + c`).
    pub const COLOR: usize = 6;
    /// Σ g_S·α·T, the depth sum.
    pub const DEPTH: usize = 9;
}

/// Runs the backward tile kernel variant `isa` (the smooth cutoff always runs the portable
/// twin). Every variant gives bit-identical results.
#[allow(clippy::too_many_arguments)]
fn backward_tile_dispatch<const SMOOTH: bool>(
    isa: Isa,
    splats: &[Splat2D],
    list: &[u32],
    x0: u32,
    y0: u32,
    tile: &mut BwdTile,
    max_alpha: f32,
    out: &mut impl FnMut(usize, PairGrad),
) {
    match isa {
        #[cfg(target_arch = "x86_64")]
        Isa::Avx2 => {
            // SAFETY: `Isa::Avx2` is only active on CPUs with AVX2, FMA, BMI1 and POPCNT.
            unsafe {
                avx2::backward_tile_avx2::<SMOOTH>(splats, list, x0, y0, tile, max_alpha, out)
            }
        }
        _ => backward_tile_portable::<SMOOTH>(splats, list, x0, y0, tile, max_alpha, out),
    }
}

/// Gradients of a loss given the upstream image gradients, in fresh buffers (see
/// [`crate::backward`]).
pub(crate) fn backward_impl(
    g: &Gaussians,
    cam: &Camera,
    _s: &RenderSettings,
    out: &RenderOutput,
    d_rgb: &[f32],
    d_alpha: Option<&[f32]>,
    d_depth: Option<&[f32]>,
) -> Gradients {
    let n = g.len();
    let mut grads = Gradients {
        means: filled_par(n, [0.0; 3]),
        log_scales: filled_par(n, [0.0; 3]),
        quats: filled_par(n, [0.0; 4]),
        opacity_logits: filled_par(n, 0.0),
        sh: filled_par(g.sh.len(), 0.0),
        means2d_abs: filled_par(n, [0.0; 2]),
        visible: filled_par(n, false),
    };
    let Some(pairs) = pair_gradients(cam, out, d_rgb, d_alpha, d_depth) else {
        return grads;
    };
    let sinks = GradSinks {
        means: &mut grads.means,
        log_scales: &mut grads.log_scales,
        quats: &mut grads.quats,
        opacity_logits: &mut grads.opacity_logits,
        sh: &mut grads.sh,
        means2d_abs: Some(&mut grads.means2d_abs),
        visible: &mut grads.visible,
    };
    gaussian_gradients(g, cam, out, &pairs, sinks, Mode::Store);
    grads
}

/// Adds the gradients of a loss given dL/d(rgb) to `acc` (a training step's running sum):
/// for every Gaussian this render composites, each value is added as `acc += gradient` with
/// the gradient rounded to f32 exactly as [`backward_impl`] stores it, and `visible` is set.
/// The result therefore equals adding [`backward_impl`]'s output value by value (bit for bit,
/// except that a Gaussian whose gradient is all zero is skipped, which may leave a −0 where
/// adding +0 would give +0), without allocating or reading N-sized buffers per render. The SH values above the render's degree
/// are left untouched. Buffers of the wrong size leave `acc` unchanged.
pub(crate) fn backward_add_impl(
    g: &Gaussians,
    cam: &Camera,
    out: &RenderOutput,
    d_rgb: &[f32],
    acc: &mut ParamGrads,
) {
    let n = g.len();
    let sized = acc.means.len() == n
        && acc.log_scales.len() == n
        && acc.quats.len() == n
        && acc.opacity_logits.len() == n
        && acc.visible.len() == n
        && acc.sh.len() == g.sh.len();
    if !sized {
        return;
    }
    let Some(pairs) = pair_gradients(cam, out, d_rgb, None, None) else {
        return;
    };
    let sinks = GradSinks {
        means: &mut acc.means,
        log_scales: &mut acc.log_scales,
        quats: &mut acc.quats,
        opacity_logits: &mut acc.opacity_logits,
        sh: &mut acc.sh,
        means2d_abs: None,
        visible: &mut acc.visible,
    };
    gaussian_gradients(g, cam, out, &pairs, sinks, Mode::Add);
}

/// Step 1 of the backward pass: the screen-space gradient of every (tile, Gaussian) pair,
/// Gaussian-major (`bins.pair_slot`). `None` when nothing was composited or the camera does
/// not match the render.
fn pair_gradients(
    cam: &Camera,
    out: &RenderOutput,
    d_rgb: &[f32],
    d_alpha: Option<&[f32]>,
    d_depth: Option<&[f32]>,
) -> Option<Vec<PairGrad>> {
    let st = &out.state;
    let s = &st.settings;
    let (width, height) = (out.width, out.height);
    let npix = width as usize * height as usize;
    if st.splats.is_empty() || cam.width != width || cam.height != height {
        return None;
    }
    let d_rgb = (d_rgb.len() == npix * 3).then_some(d_rgb);
    let d_alpha = d_alpha.filter(|v| v.len() == npix);
    let d_depth = d_depth.filter(|v| v.len() == npix);
    let grid = st.grid;
    let bins = &st.bins;
    let max_alpha = crate::forward::effective_max_alpha(s);
    let isa = simd::active();
    let bg = s.background;

    // Per-tile pair gradients, written Gaussian-major (`bins.pair_slot`): each Gaussian's
    // pairs are contiguous, in row-major tile order. Every slot is written exactly once.
    let total = bins.ranks.len();
    let mut pair_grads: Vec<PairGrad> = Vec::with_capacity(total);
    let dst = PairOut(pair_grads.as_mut_ptr());
    (0..grid.len())
        .into_par_iter()
        .for_each_init(BwdTile::default, |tile, t| {
            let lo = bins.ranges[t];
            let slots = &bins.pair_slot[lo..bins.ranges[t + 1]];
            let mut emit = |k: usize, v: PairGrad| {
                let slot = slots[k] as usize;
                assert!(slot < total);
                // SAFETY: `pair_slot` is a permutation of 0..total (built by `bin`), and
                // list position lo + k belongs to this tile only, so every slot is written
                // exactly once and by one thread; the buffer has capacity `total`.
                unsafe { dst.slot(slot).write(v) };
            };
            let tx = (t % grid.tiles_x as usize) as u32;
            let ty = (t / grid.tiles_x as usize) as u32;
            let (x0, y0) = (tx * TILE, ty * TILE);
            let last = &st.last[t * TILE_PIXELS..(t + 1) * TILE_PIXELS];
            if slots.is_empty() {
                return;
            }
            if last.iter().all(|&l| l == 0) {
                (0..slots.len()).for_each(|k| emit(k, [0.0; 10]));
                return;
            }
            let ft = &st.final_t[t * TILE_PIXELS..(t + 1) * TILE_PIXELS];
            for ly in 0..TILE as usize {
                let row = &mut tile.rows[ly];
                let base = ly * TILE as usize;
                row.last.copy_from_slice(&last[base..base + 16]);
                row.t.copy_from_slice(&ft[base..base + 16]);
                tile.row_last[ly] = row.last.iter().copied().max().unwrap_or(0);
                for lx in 0..TILE as usize {
                    let (x, y) = (x0 as usize + lx, y0 as usize + ly);
                    let (mut gc, mut ga, mut gs) = ([0.0f32; 3], 0.0f32, 0.0f32);
                    if x < width as usize && y < height as usize {
                        let i = y * width as usize + x;
                        if let Some(d) = d_rgb {
                            for ch in 0..3 {
                                gc[ch] = finite_or_zero(d[i * 3 + ch]);
                            }
                        }
                        ga = d_alpha.map_or(0.0, |v| finite_or_zero(v[i]));
                        if let Some(dd) = d_depth {
                            let a = out.alpha[i];
                            if a >= DEPTH_ALPHA_EPS {
                                let gd = finite_or_zero(dd[i]);
                                gs = gd / a;
                                ga -= gd * out.depth[i] / a;
                            }
                        }
                    }
                    for ch in 0..3 {
                        row.gc[ch][lx] = gc[ch];
                    }
                    row.gs[lx] = gs;
                    let tn = row.t[lx];
                    row.r[lx] = tn * (gc[0] * bg[0] + gc[1] * bg[1] + gc[2] * bg[2] - ga);
                }
            }
            let list = &bins.ranks[bins.ranges[t]..bins.ranges[t + 1]];
            match st.cutoff {
                Cutoff::Hard => backward_tile_dispatch::<false>(
                    isa, &st.splats, list, x0, y0, tile, max_alpha, &mut emit,
                ),
                Cutoff::Smooth => backward_tile_dispatch::<true>(
                    isa, &st.splats, list, x0, y0, tile, max_alpha, &mut emit,
                ),
            }
        });
    // SAFETY: every one of the `total` slots was written above (each tile emits every list
    // entry), and `PairGrad` is plain data.
    unsafe { pair_grads.set_len(total) };
    Some(pair_grads)
}

/// Raw pointer to the Gaussian-major pair buffer, written by the tiles in parallel.
#[derive(Clone, Copy)]
struct PairOut(*mut PairGrad);

impl PairOut {
    /// Pointer to slot `i` (the closures capture the whole wrapper through this method).
    #[inline(always)]
    fn slot(&self, i: usize) -> *mut PairGrad {
        self.0.wrapping_add(i)
    }
}

// SAFETY: the tiles write disjoint slots (see `backward_impl`).
unsafe impl Send for PairOut {}
// SAFETY: as above.
unsafe impl Sync for PairOut {}

#[inline]
fn finite_or_zero(v: f32) -> f32 {
    if v.is_finite() {
        v
    } else {
        0.0
    }
}

/// Summed gradients of one optimisation step, in the [`crate::Gaussians`] layout, plus the union of
/// the per-view visibility masks.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct ParamGrads {
    /// dL/d(means).
    pub means: Vec<[f32; 3]>,
    /// dL/d(log-scales).
    pub log_scales: Vec<[f32; 3]>,
    /// dL/d(raw quaternions).
    pub quats: Vec<[f32; 4]>,
    /// dL/d(opacity logits).
    pub opacity_logits: Vec<f32>,
    /// dL/d(SH), same layout as [`crate::Gaussians::sh`].
    pub sh: Vec<f32>,
    /// Whether the Gaussian was visible (radius > 0) in any render of the step.
    pub visible: Vec<bool>,
    /// How many leading values of each Gaussian's SH gradient row may be non-zero; the rest
    /// are promised to be zero (the backward pass leaves the coefficients above the active
    /// SH degree at zero, so a trainer passes `3·(active + 1)²`). The trainer's Adam skips
    /// the promised-zero values whose moments are still zero, which is exact: their update
    /// is `m = v = 0` and no parameter change. Values ≥ the row width mean "all".
    pub sh_active: usize,
}

impl ParamGrads {
    /// Zero gradients for `n` Gaussians with `coeffs` SH coefficients per channel.
    pub fn zeros(n: usize, coeffs: usize) -> Self {
        ParamGrads {
            means: vec![[0.0; 3]; n],
            log_scales: vec![[0.0; 3]; n],
            quats: vec![[0.0; 4]; n],
            opacity_logits: vec![0.0; n],
            sh: vec![0.0; n * coeffs * 3],
            visible: vec![false; n],
            sh_active: coeffs * 3,
        }
    }
    /// Number of Gaussians.
    pub fn len(&self) -> usize {
        self.means.len()
    }
    /// Whether there are none.
    pub fn is_empty(&self) -> bool {
        self.means.is_empty()
    }
}
