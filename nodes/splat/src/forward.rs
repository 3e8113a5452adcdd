//! The forward pass: projection of every Gaussian (parallel, fixed chunks), tile binning, and
//! per-tile front-to-back compositing (tiles in parallel).
//!
//! Compositing (DESIGN.md §4): σ = ½(a·dx² + c·dy²) + b·dx·dy; α = min(max_alpha, o·e^−σ);
//! skip if σ < 0 or α < 1/255; stop *before* a Gaussian when T·(1 − α) ≤ 1e-4;
//! C += c·α·T; output C + T·background, alpha 1 − T, depth Σ z·α·T / (1 − T).
//!
//! Each tile keeps, per pixel, the number of list entries up to and including its last
//! contributor and its final transmittance; the backward pass walks back from there.
//!
//! Layout and kernels. The projected records ([`Splat2D`]) are stored in depth-rank order, one
//! 64-byte (cache-line) record per Gaussian. A tile is processed in batches of 64 list
//! entries: for each entry a 16-bit *row mask* (the tile rows whose pixel centres the
//! Gaussian's α ≥ 1/255 ellipse can reach, all 16 rows evaluated at once as vector lanes) is
//! scattered into one 64-bit set per row; each live row then walks its set front to back with
//! its 16 pixels as the lanes of one vector and its state (T, colour, depth, last, active)
//! held in registers. Rows whose pixels have all stopped are dropped, and the tile ends when
//! no row is live.
//!
//! The exponential. The kernels never form σ: each row's coefficients (`RowGeom`) are
//! those of σ scaled by −log₂e, so two fused multiply-adds per pixel give the exponent in bits
//! ex = −σ·log₂e, and e^−σ = 2^ex. ex is clamped to [−44, 0], split as n + f with n an
//! integer and |f| ≤ ½ (the 1.5·2²³ rounding trick; the subtraction is exact), and 2^f comes
//! from a degree-5 minimax polynomial in Estrin's form (relative error below 2.4e-7), 2ⁿ from
//! the exponent bits. That is a dependency chain of about nine operations per α.
//!
//! Every kernel exists three times: a portable scalar twin, an AVX-512 version (a row is one
//! vector) and an AVX2 version (a row is two vectors, composited one after the other), the
//! last two written with intrinsics. All perform the same IEEE operations in the same order
//! per pixel (fused multiply-adds are `f32::mul_add` in the twin), so they give
//! bit-identical results; the tests check it.

// Negated comparisons are deliberate: they also reject NaN. Index loops read best in
// small fixed-size numeric code.
#![allow(clippy::neg_cmp_op_on_partial_ord, clippy::needless_range_loop)]

use crate::buffers::{filled_par, uninit_vec};
use crate::constants::{
    ALPHA_THRESHOLD, DEPTH_ALPHA_EPS, TILE, TILE_PIXELS, TRANSMITTANCE_THRESHOLD,
};
use crate::gaussians::Gaussians;
use crate::lanes::{c, Lanes, Mask, LANES, P8};
use crate::project::{project_lanes, CameraModel, ParamLanes, Projected};
use crate::render::{Cutoff, RenderOutput, RenderSettings, RenderStats};
use crate::sh;
use crate::tiles::{bin_indexed, depth_order, Bins, TileGrid};
use augsplat_core::Camera;
use rayon::prelude::*;
use std::mem::MaybeUninit;

/// Gaussians per parallel projection chunk (fixed, so results never depend on the pool).
pub(crate) const PROJECT_CHUNK: usize = 1024;

/// List entries per compositing batch (one bit each in a row's 64-bit set).
pub(crate) const BATCH: usize = 64;

/// How many list entries ahead the tile loops prefetch projected records.
pub(crate) const PREFETCH_AHEAD: usize = 8;

/// The exponent in bits (−σ·log₂e) is clamped to ≥ −this before the exponential: below it
/// α < 2⁻⁴⁴ < 1/255 for any opacity ≤ 1, so the clamp never changes a composited value, and
/// the power of two stays a normal float.
pub(crate) const SIGMA_CLAMP: f32 = 44.0;

/// Padding (pixels) added to the half-chord of the row test, so that rounding never drops
/// a pixel the compositing rule would keep.
const CHORD_PAD: f32 = 1e-2;

/// One projected Gaussian, as the compositing kernels read it (64 bytes, one cache line).
#[derive(Clone, Copy, Debug, Default, PartialEq)]
#[repr(C, align(64))]
pub struct Splat2D {
    /// Centre x, pixels.
    pub x: f32,
    /// Centre y, pixels.
    pub y: f32,
    /// Conic a (xx).
    pub a: f32,
    /// Conic b (xy).
    pub b: f32,
    /// Conic c (yy).
    pub c: f32,
    /// Opacity (after compensation).
    pub opacity: f32,
    /// Colour.
    pub rgb: [f32; 3],
    /// Camera-space depth.
    pub depth: f32,
    /// Top of the bounding box (y − radius_y), pixels.
    pub ymin: f32,
    /// Bottom of the bounding box (y + radius_y), pixels.
    pub ymax: f32,
    /// σ beyond which α < 1/255: ln(255·opacity), padded by a relative 1e-3 (+1e-3) so that
    /// rounding never skips a pixel the compositing rule would keep.
    pub sigma_max: f32,
    /// ½·(c − b²/a) = ½/Σ2d_yy: the minimum of σ along a pixel row at offset dy from the
    /// centre is `row_q·dy²`.
    pub row_q: f32,
    /// 2/a: on a row at offset dy the α ≥ 1/255 chord has squared half-length
    /// `row_w·(sigma_max − row_q·dy²)`.
    pub row_w: f32,
    /// b/a: on a row at offset dy (= y − pixel y) the chord is centred at `x + row_shift·dy`.
    pub row_shift: f32,
}

/// State kept from the forward pass for the backward pass.
#[derive(Clone, Debug, Default)]
pub(crate) struct RasterState {
    pub grid: TileGrid,
    /// Projected records in rank (front-to-back) order.
    pub splats: Vec<Splat2D>,
    pub bins: Bins,
    /// Per pixel, tile-major (`tile·256 + row·16 + col`): list entries up to and including
    /// the last contributor.
    pub last: Vec<u32>,
    /// Per pixel, tile-major: final transmittance.
    pub final_t: Vec<f32>,
    pub settings: RenderSettings,
    pub cutoff: Cutoff,
    /// Active SH degree actually used.
    pub sh_degree: u32,
}

/// log₂e: the kernels evaluate the exponent in bits, −σ·log₂e, so that e^−σ = 2^(−σ·log₂e).
const LOG2E: f32 = std::f32::consts::LOG2_E;
/// ½·log₂e, the factor of the conic's diagonal terms in σ·log₂e.
const HALF_LOG2E: f32 = 0.5 * std::f32::consts::LOG2_E;
/// 1.5·2²³: adding it rounds to an integer held in the low mantissa bits.
const ROUND: f32 = 12_582_912.0;
/// Added (wrapping) to the bits of x + ROUND, gives n + 127 in the low bits (n = round(x)).
const EXP_BIAS_FROM_ROUND: u32 = 127u32.wrapping_sub(ROUND.to_bits());
/// Minimax polynomial of 2^f on |f| ≤ ½ (relative error), lowest degree first. Evaluated in
/// f32 by Estrin's scheme ([`poly5`]) its relative error stays below 2.4e-7.
const EXP2_POLY: [f32; 6] = [
    1.000_000_1,
    6.931_469_4e-1,
    2.402_212e-1,
    5.550_713e-2,
    9.675_541e-3,
    1.327_647_1e-3,
];

/// The degree-5 polynomial `EXP2_POLY` at f by Estrin's scheme:
/// `(c0 + c1·f) + f²·((c2 + c3·f) + f²·(c4 + c5·f))` — a dependency chain of three fused
/// multiply-adds instead of Horner's five.
#[inline(always)]
fn poly5(f: f32) -> f32 {
    let c = &EXP2_POLY;
    let f2 = f * f;
    let lo = c[1].mul_add(f, c[0]);
    let mid = c[3].mul_add(f, c[2]);
    let hi = c[5].mul_add(f, c[4]);
    hi.mul_add(f2, mid).mul_add(f2, lo)
}

/// 2^x for x ≤ 0 (inputs below −126 are clamped), branch-free and free of float→int
/// conversions so it vectorises; relative error below 2.4e-7.
#[inline(always)]
pub fn exp2_neg(x: f32) -> f32 {
    exp2_core(x.clamp(-126.0, 0.0))
}

/// 2^x for x in [−126, 0] (unchecked): x = n + f with n the nearest integer, 2^x = 2ⁿ·p(f).
/// The subtraction x − n is exact, so the only rounding is in the polynomial; the AVX-512 and
/// AVX2 kernels perform exactly these operations.
#[inline(always)]
pub(crate) fn exp2_core(x: f32) -> f32 {
    let shifted = x + ROUND;
    let n = shifted - ROUND;
    let p = poly5(x - n);
    // n + 127 in the low bits: (bits(shifted) − bits(ROUND)) + 127 as one wrapping add.
    let scale = f32::from_bits(shifted.to_bits().wrapping_add(EXP_BIAS_FROM_ROUND) << 23);
    p * scale
}

/// e^−σ as the kernels evaluate it, from the exponent in bits `ex` = −σ·log₂e (as
/// [`RowGeom::exponent`] gives it): clamped to [−SIGMA_CLAMP, 0] first, then 2^ex.
#[inline(always)]
pub(crate) fn gauss_of_exponent(ex: f32) -> f32 {
    // Not `clamp`: a NaN must become −SIGMA_CLAMP here, as `_mm256_max_ps` makes it (`max`
    // returns the other operand for a NaN). The sign of a zero does not matter: 2^±0 is the
    // same value.
    #[allow(clippy::manual_clamp)]
    let x = ex.max(-SIGMA_CLAMP).min(0.0);
    exp2_core(x)
}

/// The smooth cutoff factor s(α) (C¹ smoothstep from 1/255 to 2/255) and its derivative.
#[inline(always)]
pub(crate) fn smooth_cut(alpha: f32) -> (f32, f32) {
    let x = ((alpha - ALPHA_THRESHOLD) * (1.0 / ALPHA_THRESHOLD)).clamp(0.0, 1.0);
    (
        x * x * (3.0 - 2.0 * x),
        6.0 * x * (1.0 - x) / ALPHA_THRESHOLD,
    )
}

/// The alpha clamp actually used: `max_alpha` limited to [0, 1 − 1e-6] (so 1/(1 − α) stays
/// finite in the backward pass); a non-finite value falls back to the default 0.99.
pub(crate) fn effective_max_alpha(s: &RenderSettings) -> f32 {
    if s.max_alpha.is_finite() {
        s.max_alpha.clamp(0.0, 1.0 - 1e-6)
    } else {
        crate::constants::MAX_ALPHA
    }
}

/// Per-row scalars of one Gaussian. The kernels' exponent in bits, ex = −σ·log₂e (the
/// argument of their base-2 exponential), on the row at offset dy = y − pixel y is
/// `(ea·dx + eb)·dx + ec` with dx = x − pixel x (two fused multiply-adds per pixel). The
/// coefficients are those of σ·log₂e negated, so `ex` is exactly −(σ·log₂e) as the same
/// multiply-adds would round it (rounding is symmetric), and σ ≥ 0 exactly when ex ≤ 0.
#[derive(Clone, Copy)]
pub(crate) struct RowGeom {
    pub dy: f32,
    pub ea: f32,
    pub eb: f32,
    pub ec: f32,
}

impl RowGeom {
    /// The row-independent coefficient `ea` of `sp` (−½·a·log₂e).
    #[inline(always)]
    pub(crate) fn exp_a(sp: &Splat2D) -> f32 {
        -(HALF_LOG2E * sp.a)
    }

    #[inline(always)]
    pub(crate) fn new(sp: &Splat2D, py: f32) -> Self {
        let dy = sp.y - py;
        RowGeom {
            dy,
            ea: Self::exp_a(sp),
            eb: -(LOG2E * sp.b * dy),
            ec: -(HALF_LOG2E * sp.c * dy * dy),
        }
    }

    /// The exponent in bits, −σ·log₂e, at horizontal offset `dx`.
    #[inline(always)]
    pub(crate) fn exponent(&self, dx: f32) -> f32 {
        self.ea.mul_add(dx, self.eb).mul_add(dx, self.ec)
    }
}

/// Pixel-centre coordinates of a tile: lane l of `px` is column x0 + l, of `py` row y0 + l.
#[derive(Clone, Copy)]
#[repr(C, align(64))]
pub(crate) struct TileCoords {
    pub px: [f32; 16],
    pub py: [f32; 16],
    pub left: f32,
    pub right: f32,
}

impl TileCoords {
    pub(crate) fn new(x0: u32, y0: u32) -> Self {
        let mut px = [0.0f32; 16];
        let mut py = [0.0f32; 16];
        for l in 0..16 {
            px[l] = (x0 + l as u32) as f32 + 0.5;
            py[l] = (y0 + l as u32) as f32 + 0.5;
        }
        TileCoords {
            px,
            py,
            left: px[0],
            right: px[15],
        }
    }
}

/// Portable row test: bit ly set when row ly of the tile lies inside the Gaussian's bounding
/// box and the α ≥ 1/255 chord on that row reaches the tile's 16 pixel centres.
#[inline(always)]
pub(crate) fn row_mask_portable(sp: &Splat2D, tc: &TileCoords) -> u16 {
    let mut m = 0u16;
    for l in 0..16 {
        let py = tc.py[l];
        let dy = sp.y - py;
        let dy2 = dy * dy;
        let rem = (-sp.row_q).mul_add(dy2, sp.sigma_max);
        let w2 = sp.row_w * rem;
        let half = w2.max(0.0).sqrt() + CHORD_PAD;
        let centre = sp.row_shift.mul_add(dy, sp.x);
        let hit = py >= sp.ymin
            && py <= sp.ymax
            && w2 >= 0.0
            && centre + half >= tc.left
            && centre - half <= tc.right;
        m |= (hit as u16) << l;
    }
    m
}

/// The per-row compositing state of one tile row (16 pixels).
#[derive(Clone, Copy)]
#[repr(C, align(64))]
pub(crate) struct RowState {
    t: [f32; 16],
    c: [[f32; 16]; 3],
    d: [f32; 16],
    last: [u32; 16],
}

impl Default for RowState {
    fn default() -> Self {
        RowState {
            t: [1.0; 16],
            c: [[0.0; 16]; 3],
            d: [0.0; 16],
            last: [0; 16],
        }
    }
}

/// Portable compositing of the pixels `lanes` of one row over the set bits of `bits` (entries
/// of `batch`, front to back); returns the number of composited pairs.
#[allow(clippy::too_many_arguments)]
#[inline(always)]
fn composite_row_portable<const SMOOTH: bool>(
    splats: &[Splat2D],
    batch: &[u32],
    k_base: u32,
    mut bits: u64,
    row: &mut RowState,
    active: &mut u16,
    tc: &TileCoords,
    py: f32,
    max_alpha: f32,
    lanes: std::ops::Range<usize>,
) -> u32 {
    let mut pairs = 0u32;
    let mut act = *active;
    let lane_bits = lanes.clone().fold(0u16, |m, l| m | (1 << l));
    while bits != 0 {
        let j = bits.trailing_zeros();
        bits &= bits - 1;
        let sp = &splats[batch[j as usize] as usize];
        let g = RowGeom::new(sp, py);
        let kk = k_base + j + 1;
        for l in lanes.clone() {
            let dx = sp.x - tc.px[l];
            let ex = g.exponent(dx);
            let a1 = (sp.opacity * gauss_of_exponent(ex)).min(max_alpha);
            let (alpha, pass) = if SMOOTH {
                (a1 * smooth_cut(a1).0, a1 > ALPHA_THRESHOLD)
            } else {
                (a1, a1 >= ALPHA_THRESHOLD)
            };
            if !((act >> l) & 1 != 0 && ex <= 0.0 && pass) {
                continue;
            }
            let t = row.t[l];
            let next_t = t * (1.0 - alpha);
            if next_t <= TRANSMITTANCE_THRESHOLD {
                act &= !(1u16 << l);
                continue;
            }
            let w = alpha * t;
            for ch in 0..3 {
                row.c[ch][l] = w.mul_add(sp.rgb[ch], row.c[ch][l]);
            }
            row.d[l] = w.mul_add(sp.depth, row.d[l]);
            row.t[l] = next_t;
            row.last[l] = kk;
            pairs += 1;
        }
        if act & lane_bits == 0 {
            break;
        }
    }
    *active = act;
    pairs
}

/// The two vector primitives of the forward tile loop.
pub(crate) trait ForwardKernel {
    /// Hints the cache that `p` will be read soon (no effect on results).
    ///
    /// # Safety
    /// The CPU must support the kernel's instruction set.
    unsafe fn prefetch(_p: *const Splat2D) {}
    /// Transposes the row masks of up to 64 batch entries: bit j of row ly's set is bit ly
    /// of `masks[j]` (entries past the batch must be zero).
    ///
    /// # Safety
    /// The CPU must support the kernel's instruction set.
    unsafe fn transpose(masks: &[u16; BATCH]) -> [u64; 16] {
        transpose_portable(masks)
    }
    /// Row mask of one Gaussian (see [`row_mask_portable`]).
    ///
    /// # Safety
    /// The CPU must support the kernel's instruction set.
    unsafe fn row_mask(sp: &Splat2D, tc: &TileCoords) -> u16;
    /// Whether the kernel composites the two 8-pixel halves of a row separately: the tile
    /// loop then tests rows per half ([`ForwardKernel::half_row_masks`]) and skips the
    /// halves a Gaussian cannot reach ([`ForwardKernel::composite_half`]).
    const HALF_ROWS: bool = false;
    /// Row masks of one Gaussian per half: bits 0–15 for the tile's left eight pixel
    /// columns, bits 16–31 for the right eight (the default repeats the whole-row mask).
    ///
    /// # Safety
    /// The CPU must support the kernel's instruction set.
    unsafe fn half_row_masks(sp: &Splat2D, tc: &TileCoords) -> u32 {
        let m = Self::row_mask(sp, tc) as u32;
        m | (m << 16)
    }
    /// Hard-cutoff compositing of the pixels `8·h .. 8·h + 8` of one row (the default runs
    /// the portable twin on them).
    ///
    /// # Safety
    /// The CPU must support the kernel's instruction set.
    #[allow(clippy::too_many_arguments)]
    unsafe fn composite_half(
        h: usize,
        splats: &[Splat2D],
        batch: &[u32],
        k_base: u32,
        bits: u64,
        row: &mut RowState,
        active: &mut u16,
        tc: &TileCoords,
        py: f32,
        max_alpha: f32,
    ) -> u32 {
        composite_row_portable::<false>(
            splats,
            batch,
            k_base,
            bits,
            row,
            active,
            tc,
            py,
            max_alpha,
            8 * h..8 * h + 8,
        )
    }
    /// Hard-cutoff compositing of one row (see [`composite_row_portable`]).
    ///
    /// # Safety
    /// The CPU must support the kernel's instruction set.
    #[allow(clippy::too_many_arguments)]
    unsafe fn composite_row(
        splats: &[Splat2D],
        batch: &[u32],
        k_base: u32,
        bits: u64,
        row: &mut RowState,
        active: &mut u16,
        tc: &TileCoords,
        py: f32,
        max_alpha: f32,
    ) -> u32;
}

/// Portable [`ForwardKernel::transpose`].
#[inline(always)]
pub(crate) fn transpose_portable(masks: &[u16; BATCH]) -> [u64; 16] {
    let mut rows = [0u64; 16];
    for (j, &m) in masks.iter().enumerate() {
        for (ly, r) in rows.iter_mut().enumerate() {
            *r |= (((m >> ly) & 1) as u64) << j;
        }
    }
    rows
}

/// The portable kernels.
struct Portable;

impl ForwardKernel for Portable {
    #[inline(always)]
    unsafe fn row_mask(sp: &Splat2D, tc: &TileCoords) -> u16 {
        row_mask_portable(sp, tc)
    }
    #[inline(always)]
    unsafe fn composite_row(
        splats: &[Splat2D],
        batch: &[u32],
        k_base: u32,
        bits: u64,
        row: &mut RowState,
        active: &mut u16,
        tc: &TileCoords,
        py: f32,
        max_alpha: f32,
    ) -> u32 {
        composite_row_portable::<false>(
            splats,
            batch,
            k_base,
            bits,
            row,
            active,
            tc,
            py,
            max_alpha,
            0..16,
        )
    }
}

/// AVX-512 kernels (16 lanes: one tile row per vector).
#[cfg(target_arch = "x86_64")]
pub(crate) mod avx512 {
    use super::*;
    use std::arch::x86_64::*;

    /// The features the AVX-512 kernels are compiled for.
    pub(crate) fn available() -> bool {
        std::arch::is_x86_feature_detected!("avx512f")
            && std::arch::is_x86_feature_detected!("avx512dq")
            && std::arch::is_x86_feature_detected!("avx512bw")
            && std::arch::is_x86_feature_detected!("fma")
    }

    /// 2^x for x in [−SIGMA_CLAMP, 0] lane-wise: exactly the operations of [`exp2_core`].
    #[inline(always)]
    pub(crate) unsafe fn exp2_core_v(x: __m512) -> __m512 {
        let shifted = _mm512_add_ps(x, _mm512_set1_ps(ROUND));
        let n = _mm512_sub_ps(shifted, _mm512_set1_ps(ROUND));
        let f = _mm512_sub_ps(x, n);
        // A macro, not a closure: a closure would be compiled without the target features.
        macro_rules! c {
            ($i:expr) => {
                _mm512_set1_ps(EXP2_POLY[$i])
            };
        }
        let f2 = _mm512_mul_ps(f, f);
        let lo = _mm512_fmadd_ps(c!(1), f, c!(0));
        let mid = _mm512_fmadd_ps(c!(3), f, c!(2));
        let hi = _mm512_fmadd_ps(c!(5), f, c!(4));
        let p = _mm512_fmadd_ps(_mm512_fmadd_ps(hi, f2, mid), f2, lo);
        // p·2ⁿ with n integral and the result normal: exact, like the multiplication by the
        // constructed power of two in the portable twin.
        _mm512_scalef_ps(p, n)
    }

    /// [`gauss_of_exponent`] lane-wise.
    #[inline(always)]
    pub(crate) unsafe fn gauss_v(ex: __m512) -> __m512 {
        let lo = _mm512_max_ps(ex, _mm512_set1_ps(-SIGMA_CLAMP));
        exp2_core_v(_mm512_min_ps(lo, _mm512_setzero_ps()))
    }

    /// [`row_mask_portable`] with the 16 rows as lanes.
    #[inline(always)]
    pub(crate) unsafe fn row_mask(sp: &Splat2D, tc: &TileCoords) -> u16 {
        let py = _mm512_load_ps(tc.py.as_ptr());
        let zero = _mm512_setzero_ps();
        let dy = _mm512_sub_ps(_mm512_set1_ps(sp.y), py);
        let dy2 = _mm512_mul_ps(dy, dy);
        let rem = _mm512_fnmadd_ps(_mm512_set1_ps(sp.row_q), dy2, _mm512_set1_ps(sp.sigma_max));
        let w2 = _mm512_mul_ps(_mm512_set1_ps(sp.row_w), rem);
        let half = _mm512_add_ps(
            _mm512_sqrt_ps(_mm512_max_ps(w2, zero)),
            _mm512_set1_ps(CHORD_PAD),
        );
        let centre = _mm512_fmadd_ps(_mm512_set1_ps(sp.row_shift), dy, _mm512_set1_ps(sp.x));
        let m = _mm512_cmp_ps_mask::<_CMP_GE_OQ>(py, _mm512_set1_ps(sp.ymin));
        let m = _mm512_mask_cmp_ps_mask::<_CMP_LE_OQ>(m, py, _mm512_set1_ps(sp.ymax));
        let m = _mm512_mask_cmp_ps_mask::<_CMP_GE_OQ>(m, w2, zero);
        let m = _mm512_mask_cmp_ps_mask::<_CMP_GE_OQ>(
            m,
            _mm512_add_ps(centre, half),
            _mm512_set1_ps(tc.left),
        );
        _mm512_mask_cmp_ps_mask::<_CMP_LE_OQ>(
            m,
            _mm512_sub_ps(centre, half),
            _mm512_set1_ps(tc.right),
        )
    }

    /// [`composite_row_portable`] (hard cutoff) with the row's pixels as lanes and its state
    /// in registers.
    #[allow(clippy::too_many_arguments)]
    #[inline(always)]
    pub(crate) unsafe fn composite_row(
        splats: &[Splat2D],
        batch: &[u32],
        k_base: u32,
        mut bits: u64,
        row: &mut RowState,
        active: &mut u16,
        tc: &TileCoords,
        py: f32,
        max_alpha: f32,
    ) -> u32 {
        let px = _mm512_load_ps(tc.px.as_ptr());
        let zero = _mm512_setzero_ps();
        let one = _mm512_set1_ps(1.0);
        let maxa = _mm512_set1_ps(max_alpha);
        let thr = _mm512_set1_ps(ALPHA_THRESHOLD);
        let tthr = _mm512_set1_ps(TRANSMITTANCE_THRESHOLD);
        let mut t = _mm512_load_ps(row.t.as_ptr());
        let mut cr = _mm512_load_ps(row.c[0].as_ptr());
        let mut cg = _mm512_load_ps(row.c[1].as_ptr());
        let mut cb = _mm512_load_ps(row.c[2].as_ptr());
        let mut d = _mm512_load_ps(row.d.as_ptr());
        let mut last = _mm512_load_si512(row.last.as_ptr() as *const __m512i);
        let mut act: __mmask16 = *active;
        let mut pairs = 0u32;
        while bits != 0 {
            let j = bits.trailing_zeros();
            bits &= bits - 1;
            let sp = splats.get_unchecked(*batch.get_unchecked(j as usize) as usize);
            let g = RowGeom::new(sp, py);
            let dx = _mm512_sub_ps(_mm512_set1_ps(sp.x), px);
            let u = _mm512_fmadd_ps(_mm512_set1_ps(g.ea), dx, _mm512_set1_ps(g.eb));
            let ex = _mm512_fmadd_ps(u, dx, _mm512_set1_ps(g.ec));
            let e = gauss_v(ex);
            let a1 = _mm512_min_ps(_mm512_mul_ps(_mm512_set1_ps(sp.opacity), e), maxa);
            let ok = _mm512_mask_cmp_ps_mask::<_CMP_LE_OQ>(act, ex, zero);
            let ok = _mm512_mask_cmp_ps_mask::<_CMP_GE_OQ>(ok, a1, thr);
            if ok == 0 {
                continue;
            }
            let next_t = _mm512_mul_ps(t, _mm512_sub_ps(one, a1));
            let stop = _mm512_mask_cmp_ps_mask::<_CMP_LE_OQ>(ok, next_t, tthr);
            let comp = ok & !stop;
            act &= !stop;
            let w = _mm512_mul_ps(a1, t);
            cr = _mm512_mask3_fmadd_ps(w, _mm512_set1_ps(sp.rgb[0]), cr, comp);
            cg = _mm512_mask3_fmadd_ps(w, _mm512_set1_ps(sp.rgb[1]), cg, comp);
            cb = _mm512_mask3_fmadd_ps(w, _mm512_set1_ps(sp.rgb[2]), cb, comp);
            d = _mm512_mask3_fmadd_ps(w, _mm512_set1_ps(sp.depth), d, comp);
            t = _mm512_mask_mov_ps(t, comp, next_t);
            last = _mm512_mask_mov_epi32(last, comp, _mm512_set1_epi32((k_base + j + 1) as i32));
            pairs += comp.count_ones();
            if act == 0 {
                break;
            }
        }
        _mm512_store_ps(row.t.as_mut_ptr(), t);
        _mm512_store_ps(row.c[0].as_mut_ptr(), cr);
        _mm512_store_ps(row.c[1].as_mut_ptr(), cg);
        _mm512_store_ps(row.c[2].as_mut_ptr(), cb);
        _mm512_store_ps(row.d.as_mut_ptr(), d);
        _mm512_store_si512(row.last.as_mut_ptr() as *mut __m512i, last);
        *active = act;
        pairs
    }

    /// Marker type of the AVX-512 forward kernels.
    pub(crate) struct Avx512;

    impl ForwardKernel for Avx512 {
        #[inline(always)]
        unsafe fn prefetch(p: *const Splat2D) {
            _mm_prefetch::<_MM_HINT_T0>(p as *const i8);
        }
        #[inline(always)]
        unsafe fn transpose(masks: &[u16; BATCH]) -> [u64; 16] {
            let lo = _mm512_loadu_si512(masks.as_ptr() as *const __m512i);
            let hi = _mm512_loadu_si512(masks.as_ptr().add(32) as *const __m512i);
            let mut rows = [0u64; 16];
            for (ly, r) in rows.iter_mut().enumerate() {
                let bit = _mm512_set1_epi16(1i16 << ly);
                let a = _mm512_test_epi16_mask(lo, bit) as u64;
                let b = _mm512_test_epi16_mask(hi, bit) as u64;
                *r = a | (b << 32);
            }
            rows
        }
        #[inline(always)]
        unsafe fn row_mask(sp: &Splat2D, tc: &TileCoords) -> u16 {
            row_mask(sp, tc)
        }
        #[inline(always)]
        unsafe fn composite_row(
            splats: &[Splat2D],
            batch: &[u32],
            k_base: u32,
            bits: u64,
            row: &mut RowState,
            active: &mut u16,
            tc: &TileCoords,
            py: f32,
            max_alpha: f32,
        ) -> u32 {
            composite_row(splats, batch, k_base, bits, row, active, tc, py, max_alpha)
        }
    }
}

/// AVX2 kernels (8 lanes: one tile row is two vectors, its left and right halves).
#[cfg(target_arch = "x86_64")]
pub(crate) mod avx2 {
    use super::*;
    use std::arch::x86_64::*;

    /// [`exp2_core`] lane-wise: exactly its operations (2ⁿ built in the exponent bits).
    #[inline(always)]
    pub(crate) unsafe fn exp2_core_v(x: __m256) -> __m256 {
        let round = _mm256_set1_ps(ROUND);
        let shifted = _mm256_add_ps(x, round);
        let n = _mm256_sub_ps(shifted, round);
        let f = _mm256_sub_ps(x, n);
        // A macro, not a closure: a closure would be compiled without the target features.
        macro_rules! c {
            ($i:expr) => {
                _mm256_set1_ps(EXP2_POLY[$i])
            };
        }
        let f2 = _mm256_mul_ps(f, f);
        let lo = _mm256_fmadd_ps(c!(1), f, c!(0));
        let mid = _mm256_fmadd_ps(c!(3), f, c!(2));
        let hi = _mm256_fmadd_ps(c!(5), f, c!(4));
        let p = _mm256_fmadd_ps(_mm256_fmadd_ps(hi, f2, mid), f2, lo);
        let biased = _mm256_add_epi32(
            _mm256_castps_si256(shifted),
            _mm256_set1_epi32(EXP_BIAS_FROM_ROUND as i32),
        );
        let scale = _mm256_slli_epi32::<23>(biased);
        _mm256_mul_ps(p, _mm256_castsi256_ps(scale))
    }

    /// [`gauss_of_exponent`] lane-wise (`max` returns its second operand for a NaN, as the
    /// scalar `max(−SIGMA_CLAMP)` does).
    #[inline(always)]
    pub(crate) unsafe fn gauss_v(ex: __m256) -> __m256 {
        let lo = _mm256_max_ps(ex, _mm256_set1_ps(-SIGMA_CLAMP));
        exp2_core_v(_mm256_min_ps(lo, _mm256_setzero_ps()))
    }

    /// [`row_mask_portable`] for the eight rows whose centres are `py`, with the chord tested
    /// against the pixel centres `left ..= right`.
    #[inline(always)]
    unsafe fn row_mask8(sp: &Splat2D, py: __m256, left: f32, right: f32) -> u32 {
        let zero = _mm256_setzero_ps();
        let dy = _mm256_sub_ps(_mm256_set1_ps(sp.y), py);
        let dy2 = _mm256_mul_ps(dy, dy);
        let rem = _mm256_fnmadd_ps(_mm256_set1_ps(sp.row_q), dy2, _mm256_set1_ps(sp.sigma_max));
        let w2 = _mm256_mul_ps(_mm256_set1_ps(sp.row_w), rem);
        let half = _mm256_add_ps(
            _mm256_sqrt_ps(_mm256_max_ps(w2, zero)),
            _mm256_set1_ps(CHORD_PAD),
        );
        let centre = _mm256_fmadd_ps(_mm256_set1_ps(sp.row_shift), dy, _mm256_set1_ps(sp.x));
        let m = _mm256_and_ps(
            _mm256_cmp_ps::<_CMP_GE_OQ>(py, _mm256_set1_ps(sp.ymin)),
            _mm256_cmp_ps::<_CMP_LE_OQ>(py, _mm256_set1_ps(sp.ymax)),
        );
        let m = _mm256_and_ps(m, _mm256_cmp_ps::<_CMP_GE_OQ>(w2, zero));
        let m = _mm256_and_ps(
            m,
            _mm256_cmp_ps::<_CMP_GE_OQ>(_mm256_add_ps(centre, half), _mm256_set1_ps(left)),
        );
        let m = _mm256_and_ps(
            m,
            _mm256_cmp_ps::<_CMP_LE_OQ>(_mm256_sub_ps(centre, half), _mm256_set1_ps(right)),
        );
        _mm256_movemask_ps(m) as u32
    }

    /// The 16 row bits of `row_mask8` over both groups of eight rows.
    #[inline(always)]
    unsafe fn row_mask16(sp: &Splat2D, tc: &TileCoords, left: f32, right: f32) -> u32 {
        let top = row_mask8(sp, _mm256_load_ps(tc.py.as_ptr()), left, right);
        let bottom = row_mask8(sp, _mm256_load_ps(tc.py.as_ptr().add(8)), left, right);
        top | (bottom << 8)
    }

    /// [`row_mask_portable`] with the 16 rows as two vectors of lanes.
    #[inline(always)]
    pub(crate) unsafe fn row_mask(sp: &Splat2D, tc: &TileCoords) -> u16 {
        row_mask16(sp, tc, tc.left, tc.right) as u16
    }

    /// [`ForwardKernel::half_row_masks`]: the row test against the left eight and the right
    /// eight pixel centres.
    #[inline(always)]
    pub(crate) unsafe fn half_row_masks(sp: &Splat2D, tc: &TileCoords) -> u32 {
        row_mask16(sp, tc, tc.left, tc.px[7]) | (row_mask16(sp, tc, tc.px[8], tc.right) << 16)
    }

    /// [`ForwardKernel::transpose`]: per row, the row bit of 16 masks at a time is moved to
    /// the sign of its 16-bit lane, the words are packed to bytes (saturation keeps the
    /// sign) and their signs collected with one byte move-mask.
    #[inline(always)]
    pub(crate) unsafe fn transpose(masks: &[u16; BATCH]) -> [u64; 16] {
        let p = masks.as_ptr() as *const __m256i;
        let v = [
            _mm256_loadu_si256(p),
            _mm256_loadu_si256(p.add(1)),
            _mm256_loadu_si256(p.add(2)),
            _mm256_loadu_si256(p.add(3)),
        ];
        let mut rows = [0u64; 16];
        let mut shift = 15;
        for r in rows.iter_mut() {
            let count = _mm_cvtsi32_si128(shift);
            // Masks 0–15 and 16–31 as bytes; the pack interleaves the 128-bit halves, which
            // the 64-bit permutation puts back in entry order.
            let lo =
                _mm256_packs_epi16(_mm256_sll_epi16(v[0], count), _mm256_sll_epi16(v[1], count));
            let hi =
                _mm256_packs_epi16(_mm256_sll_epi16(v[2], count), _mm256_sll_epi16(v[3], count));
            let lo = _mm256_permute4x64_epi64::<0xD8>(lo);
            let hi = _mm256_permute4x64_epi64::<0xD8>(hi);
            *r = (_mm256_movemask_epi8(lo) as u32 as u64)
                | ((_mm256_movemask_epi8(hi) as u32 as u64) << 32);
            shift -= 1;
        }
        rows
    }

    /// Lane `l` all ones where bit `l` of `bits` is set.
    #[inline(always)]
    pub(crate) unsafe fn lane_mask(bits: u32) -> __m256 {
        let sel = _mm256_setr_epi32(1, 2, 4, 8, 16, 32, 64, 128);
        let v = _mm256_and_si256(_mm256_set1_epi32(bits as i32), sel);
        _mm256_castsi256_ps(_mm256_cmpeq_epi32(v, sel))
    }

    /// [`composite_row_portable`] (hard cutoff) over the pixels `8·h .. 8·h + 8` of a row,
    /// whose state stays in registers; returns the composited pairs.
    #[allow(clippy::too_many_arguments)]
    #[inline(always)]
    unsafe fn composite_half(
        h: usize,
        splats: &[Splat2D],
        batch: &[u32],
        k_base: u32,
        mut bits: u64,
        row: &mut RowState,
        active: &mut u16,
        tc: &TileCoords,
        py: f32,
        max_alpha: f32,
    ) -> u32 {
        let act_bits = ((*active >> (8 * h)) & 0xff) as u32;
        if act_bits == 0 {
            return 0;
        }
        let o = 8 * h;
        let px = _mm256_load_ps(tc.px.as_ptr().add(o));
        let zero = _mm256_setzero_ps();
        let one = _mm256_set1_ps(1.0);
        let maxa = _mm256_set1_ps(max_alpha);
        let thr = _mm256_set1_ps(ALPHA_THRESHOLD);
        let tthr = _mm256_set1_ps(TRANSMITTANCE_THRESHOLD);
        let mut t = _mm256_load_ps(row.t.as_ptr().add(o));
        let mut cr = _mm256_load_ps(row.c[0].as_ptr().add(o));
        let mut cg = _mm256_load_ps(row.c[1].as_ptr().add(o));
        let mut cb = _mm256_load_ps(row.c[2].as_ptr().add(o));
        let mut d = _mm256_load_ps(row.d.as_ptr().add(o));
        let mut last = _mm256_load_ps(row.last.as_ptr().add(o) as *const f32);
        let mut act = lane_mask(act_bits);
        let mut pairs = 0u32;
        // α of entry j and the lanes where it passes the cutoff (σ ≥ 0, α ≥ 1/255).
        macro_rules! alpha {
            ($j:expr) => {{
                let sp = splats.get_unchecked(*batch.get_unchecked($j as usize) as usize);
                let g = RowGeom::new(sp, py);
                let dx = _mm256_sub_ps(_mm256_set1_ps(sp.x), px);
                let u = _mm256_fmadd_ps(_mm256_set1_ps(g.ea), dx, _mm256_set1_ps(g.eb));
                let ex = _mm256_fmadd_ps(u, dx, _mm256_set1_ps(g.ec));
                let e = gauss_v(ex);
                let a1 = _mm256_min_ps(_mm256_mul_ps(_mm256_set1_ps(sp.opacity), e), maxa);
                let pass = _mm256_and_ps(
                    _mm256_cmp_ps::<_CMP_LE_OQ>(ex, zero),
                    _mm256_cmp_ps::<_CMP_GE_OQ>(a1, thr),
                );
                (sp, a1, pass)
            }};
        }
        // Composites entry j (α and pass lanes from `alpha!`). Branch-free: where no lane
        // passes, every update is a no-op.
        macro_rules! composite {
            ($j:expr, $sp:expr, $a1:expr, $pass:expr) => {{
                let (j, sp, a1): (u32, &Splat2D, __m256) = ($j, $sp, $a1);
                let ok = _mm256_and_ps(act, $pass);
                let next_t = _mm256_mul_ps(t, _mm256_sub_ps(one, a1));
                let stop = _mm256_and_ps(ok, _mm256_cmp_ps::<_CMP_LE_OQ>(next_t, tthr));
                let comp = _mm256_andnot_ps(stop, ok);
                act = _mm256_andnot_ps(stop, act);
                // w is zeroed outside `comp`: there the sums gain w·c = ±0, which leaves
                // them unchanged (colour and depth are finite, and a sum that starts at +0
                // and gains only products ≥ 0 or ±0 is never −0).
                let w = _mm256_and_ps(_mm256_mul_ps(a1, t), comp);
                cr = _mm256_fmadd_ps(w, _mm256_set1_ps(sp.rgb[0]), cr);
                cg = _mm256_fmadd_ps(w, _mm256_set1_ps(sp.rgb[1]), cg);
                cb = _mm256_fmadd_ps(w, _mm256_set1_ps(sp.rgb[2]), cb);
                d = _mm256_fmadd_ps(w, _mm256_set1_ps(sp.depth), d);
                t = _mm256_blendv_ps(t, next_t, comp);
                let kk = _mm256_castsi256_ps(_mm256_set1_epi32((k_base + j + 1) as i32));
                last = _mm256_blendv_ps(last, kk, comp);
                pairs += (_mm256_movemask_ps(comp) as u32).count_ones();
            }};
        }
        // Two entries per step: both α (independent exponentials the CPU overlaps) before
        // the two compositing steps, which run in list order. Once no lane is active every
        // step is a no-op, so the walk may stop after either.
        while bits != 0 {
            let j0 = bits.trailing_zeros();
            bits &= bits - 1;
            if bits != 0 {
                let j1 = bits.trailing_zeros();
                bits &= bits - 1;
                let (sp0, a0, p0) = alpha!(j0);
                let (sp1, a1, p1) = alpha!(j1);
                composite!(j0, sp0, a0, p0);
                composite!(j1, sp1, a1, p1);
            } else {
                let (sp0, a0, p0) = alpha!(j0);
                composite!(j0, sp0, a0, p0);
            }
            if _mm256_movemask_ps(act) == 0 {
                break;
            }
        }
        _mm256_store_ps(row.t.as_mut_ptr().add(o), t);
        _mm256_store_ps(row.c[0].as_mut_ptr().add(o), cr);
        _mm256_store_ps(row.c[1].as_mut_ptr().add(o), cg);
        _mm256_store_ps(row.c[2].as_mut_ptr().add(o), cb);
        _mm256_store_ps(row.d.as_mut_ptr().add(o), d);
        _mm256_store_ps(row.last.as_mut_ptr().add(o) as *mut f32, last);
        let kept = _mm256_movemask_ps(act) as u16;
        *active = (*active & !(0xff << (8 * h))) | (kept << (8 * h));
        pairs
    }

    /// Marker type of the AVX2 forward kernels. A row's two halves are composited one after
    /// the other: pixels are independent, so the results are those of the whole-row kernels.
    pub(crate) struct Avx2;

    impl ForwardKernel for Avx2 {
        const HALF_ROWS: bool = true;
        #[inline(always)]
        unsafe fn prefetch(p: *const Splat2D) {
            _mm_prefetch::<_MM_HINT_T0>(p as *const i8);
        }
        #[inline(always)]
        unsafe fn transpose(masks: &[u16; BATCH]) -> [u64; 16] {
            transpose(masks)
        }
        #[inline(always)]
        unsafe fn row_mask(sp: &Splat2D, tc: &TileCoords) -> u16 {
            row_mask(sp, tc)
        }
        #[inline(always)]
        unsafe fn half_row_masks(sp: &Splat2D, tc: &TileCoords) -> u32 {
            half_row_masks(sp, tc)
        }
        #[inline(always)]
        unsafe fn composite_half(
            h: usize,
            splats: &[Splat2D],
            batch: &[u32],
            k_base: u32,
            bits: u64,
            row: &mut RowState,
            active: &mut u16,
            tc: &TileCoords,
            py: f32,
            max_alpha: f32,
        ) -> u32 {
            composite_half(
                h, splats, batch, k_base, bits, row, active, tc, py, max_alpha,
            )
        }
        #[inline(always)]
        unsafe fn composite_row(
            splats: &[Splat2D],
            batch: &[u32],
            k_base: u32,
            bits: u64,
            row: &mut RowState,
            active: &mut u16,
            tc: &TileCoords,
            py: f32,
            max_alpha: f32,
        ) -> u32 {
            let mut pairs = 0;
            for h in 0..2 {
                pairs += composite_half(
                    h, splats, batch, k_base, bits, row, active, tc, py, max_alpha,
                );
            }
            pairs
        }
    }
}

/// The compositing state of one tile.
#[derive(Default)]
pub(crate) struct TileState {
    rows: [RowState; 16],
}

/// Composites one tile front to back; returns the number of composited pairs. `active`
/// holds per row the pixels to composite (bit = column).
///
/// # Safety
/// The CPU must support `K`'s instruction set.
#[inline(always)]
unsafe fn raster_tile_impl<K: ForwardKernel, const SMOOTH: bool>(
    splats: &[Splat2D],
    list: &[u32],
    x0: u32,
    y0: u32,
    active_init: &[u16; 16],
    max_alpha: f32,
    st: &mut TileState,
) -> u64 {
    if K::HALF_ROWS {
        return raster_tile_halves_impl::<K, SMOOTH>(
            splats,
            list,
            x0,
            y0,
            active_init,
            max_alpha,
            st,
        );
    }
    let tc = TileCoords::new(x0, y0);
    let mut active = *active_init;
    let mut live = 0u16;
    for (ly, a) in active.iter().enumerate() {
        live |= ((*a != 0) as u16) << ly;
    }
    let mut pairs = 0u64;
    for (bi, batch) in list.chunks(BATCH).enumerate() {
        if live == 0 {
            break;
        }
        let mut masks = [0u16; BATCH];
        for (j, &rank) in batch.iter().enumerate() {
            if let Some(&ahead) = batch.get(j + PREFETCH_AHEAD) {
                K::prefetch(splats.as_ptr().wrapping_add(ahead as usize));
            }
            masks[j] = K::row_mask(&splats[rank as usize], &tc) & live;
        }
        let rowbits = K::transpose(&masks);
        let k_base = (bi * BATCH) as u32;
        let mut rows = live;
        while rows != 0 {
            let ly = rows.trailing_zeros() as usize;
            rows &= rows - 1;
            if rowbits[ly] == 0 {
                continue;
            }
            let row = &mut st.rows[ly];
            let p = if SMOOTH {
                composite_row_portable::<true>(
                    splats,
                    batch,
                    k_base,
                    rowbits[ly],
                    row,
                    &mut active[ly],
                    &tc,
                    tc.py[ly],
                    max_alpha,
                    0..16,
                )
            } else {
                K::composite_row(
                    splats,
                    batch,
                    k_base,
                    rowbits[ly],
                    row,
                    &mut active[ly],
                    &tc,
                    tc.py[ly],
                    max_alpha,
                )
            };
            pairs += p as u64;
            if active[ly] == 0 {
                live &= !(1u16 << ly);
            }
        }
    }
    pairs
}

/// [`raster_tile_impl`] for kernels that composite half rows: a (Gaussian, half row) is
/// visited only when the Gaussian's α ≥ 1/255 chord on that row reaches the half's pixel
/// centres. The test is conservative, so every pixel sees the same Gaussians, in the same
/// order, as with whole rows.
///
/// # Safety
/// The CPU must support `K`'s instruction set.
#[inline(always)]
unsafe fn raster_tile_halves_impl<K: ForwardKernel, const SMOOTH: bool>(
    splats: &[Splat2D],
    list: &[u32],
    x0: u32,
    y0: u32,
    active_init: &[u16; 16],
    max_alpha: f32,
    st: &mut TileState,
) -> u64 {
    let tc = TileCoords::new(x0, y0);
    let mut active = *active_init;
    // Bit 16·h + ly: half h of row ly still has pixels to composite.
    let mut live = 0u32;
    for (ly, a) in active.iter().enumerate() {
        live |= (((*a & 0xff) != 0) as u32) << ly;
        live |= (((*a >> 8) != 0) as u32) << (16 + ly);
    }
    let mut pairs = 0u64;
    for (bi, batch) in list.chunks(BATCH).enumerate() {
        if live == 0 {
            break;
        }
        let mut masks = [[0u16; BATCH]; 2];
        for (j, &rank) in batch.iter().enumerate() {
            if let Some(&ahead) = batch.get(j + PREFETCH_AHEAD) {
                K::prefetch(splats.as_ptr().wrapping_add(ahead as usize));
            }
            let m = K::half_row_masks(&splats[rank as usize], &tc) & live;
            masks[0][j] = m as u16;
            masks[1][j] = (m >> 16) as u16;
        }
        let rowbits = [K::transpose(&masks[0]), K::transpose(&masks[1])];
        let k_base = (bi * BATCH) as u32;
        let mut rows = live;
        while rows != 0 {
            let b = rows.trailing_zeros() as usize;
            rows &= rows - 1;
            let (h, ly) = (b / 16, b % 16);
            let bits = rowbits[h][ly];
            if bits == 0 {
                continue;
            }
            let row = &mut st.rows[ly];
            let p = if SMOOTH {
                composite_row_portable::<true>(
                    splats,
                    batch,
                    k_base,
                    bits,
                    row,
                    &mut active[ly],
                    &tc,
                    tc.py[ly],
                    max_alpha,
                    8 * h..8 * h + 8,
                )
            } else {
                K::composite_half(
                    h,
                    splats,
                    batch,
                    k_base,
                    bits,
                    row,
                    &mut active[ly],
                    &tc,
                    tc.py[ly],
                    max_alpha,
                )
            };
            pairs += p as u64;
            if (active[ly] >> (8 * h)) & 0xff == 0 {
                live &= !(1u32 << b);
            }
        }
    }
    pairs
}

/// The portable tile kernel.
fn raster_tile_portable<const SMOOTH: bool>(
    splats: &[Splat2D],
    list: &[u32],
    x0: u32,
    y0: u32,
    active_init: &[u16; 16],
    max_alpha: f32,
    st: &mut TileState,
) -> u64 {
    // SAFETY: the portable kernel has no instruction-set requirement.
    unsafe {
        raster_tile_impl::<Portable, SMOOTH>(splats, list, x0, y0, active_init, max_alpha, st)
    }
}

/// The AVX2 tile kernel (the smooth cutoff runs the portable twin inside it).
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2,fma,bmi1,popcnt")]
fn raster_tile_avx2<const SMOOTH: bool>(
    splats: &[Splat2D],
    list: &[u32],
    x0: u32,
    y0: u32,
    active_init: &[u16; 16],
    max_alpha: f32,
    st: &mut TileState,
) -> u64 {
    // SAFETY: this function is only compiled for, and called on, CPUs with AVX2 + FMA.
    unsafe {
        raster_tile_impl::<avx2::Avx2, SMOOTH>(splats, list, x0, y0, active_init, max_alpha, st)
    }
}

/// The AVX-512 tile kernel.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx512f,avx512dq,avx512bw,fma,bmi1,popcnt")]
fn raster_tile_avx512(
    splats: &[Splat2D],
    list: &[u32],
    x0: u32,
    y0: u32,
    active_init: &[u16; 16],
    max_alpha: f32,
    st: &mut TileState,
) -> u64 {
    // SAFETY: this function is only compiled for, and called on, CPUs with AVX-512F/DQ + FMA.
    unsafe {
        raster_tile_impl::<avx512::Avx512, false>(splats, list, x0, y0, active_init, max_alpha, st)
    }
}

/// Which compiled variant of the kernels runs on this CPU.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(crate) enum Isa {
    Portable,
    #[cfg(target_arch = "x86_64")]
    Avx2,
    #[cfg(target_arch = "x86_64")]
    Avx512,
}

/// The widest kernel variant the CPU supports.
pub(crate) fn detect_isa() -> Isa {
    #[cfg(target_arch = "x86_64")]
    {
        if avx512::available() {
            return Isa::Avx512;
        }
        // BMI1 and POPCNT come with every AVX2 CPU; the tile kernels use them for their bit
        // sets (checked all the same).
        if std::arch::is_x86_feature_detected!("avx2")
            && std::arch::is_x86_feature_detected!("fma")
            && std::arch::is_x86_feature_detected!("bmi1")
            && std::arch::is_x86_feature_detected!("popcnt")
        {
            return Isa::Avx2;
        }
    }
    Isa::Portable
}

/// Runs the tile kernel variant `isa` (the smooth cutoff, a test-only path, always runs the
/// portable twin). Every variant gives bit-identical results.
#[allow(clippy::too_many_arguments)]
fn raster_tile_dispatch<const SMOOTH: bool>(
    isa: Isa,
    splats: &[Splat2D],
    list: &[u32],
    x0: u32,
    y0: u32,
    active_init: &[u16; 16],
    max_alpha: f32,
    st: &mut TileState,
) -> u64 {
    match isa {
        #[cfg(target_arch = "x86_64")]
        Isa::Avx512 if !SMOOTH => {
            // SAFETY: `Isa::Avx512` is only chosen when the CPU has AVX-512F/DQ and FMA.
            unsafe { raster_tile_avx512(splats, list, x0, y0, active_init, max_alpha, st) }
        }
        #[cfg(target_arch = "x86_64")]
        Isa::Avx512 | Isa::Avx2 => {
            // SAFETY: both variants imply AVX2, FMA, BMI1 and POPCNT support (every AVX-512
            // CPU has the last two).
            unsafe { raster_tile_avx2::<SMOOTH>(splats, list, x0, y0, active_init, max_alpha, st) }
        }
        Isa::Portable => {
            raster_tile_portable::<SMOOTH>(splats, list, x0, y0, active_init, max_alpha, st)
        }
    }
}

/// Builds the compositing record of a projected Gaussian, or `None` when it cannot be
/// represented in f32 (it is then culled).
fn make_splat(
    p: &crate::project::Projected,
    rgb: [f64; 3],
    log_alpha_ratio: f64,
) -> Option<Splat2D> {
    let [a, b, c] = p.conic;
    // Σ2d = conic⁻¹; Σ_yy = a / det(conic), Σ_xy = −b / det(conic).
    let det = a * c - b * b;
    let syy = a / det;
    let row_q = 0.5 / syy;
    let row_w = 2.0 / a;
    let row_shift = b / a;
    // log_alpha_ratio = ln(opacity / ALPHA_THRESHOLD), from the projection.
    let sigma_max = log_alpha_ratio.max(0.0) * (1.0 + 1e-3) + 1e-3;
    let lim = f32::MAX as f64;
    let sp = Splat2D {
        x: p.mean2d[0] as f32,
        y: p.mean2d[1] as f32,
        a: a as f32,
        b: b as f32,
        c: c as f32,
        opacity: p.opacity as f32,
        rgb: [rgb[0] as f32, rgb[1] as f32, rgb[2] as f32],
        depth: p.depth as f32,
        ymin: (p.mean2d[1] - p.radius[1] as f64) as f32,
        ymax: (p.mean2d[1] + p.radius[1] as f64) as f32,
        sigma_max: sigma_max as f32,
        // Clamped to finite values: the row test must never see ∞·0.
        row_q: row_q.clamp(0.0, lim) as f32,
        row_w: row_w.clamp(0.0, lim) as f32,
        row_shift: row_shift.clamp(-lim, lim) as f32,
    };
    let core = [
        sp.x, sp.y, sp.a, sp.b, sp.c, sp.opacity, sp.rgb[0], sp.rgb[1], sp.rgb[2], sp.depth,
    ];
    let ok = core.iter().all(|v| v.is_finite())
        && det > 0.0
        && !row_q.is_nan()
        && !row_w.is_nan()
        && !row_shift.is_nan()
        && sp.sigma_max.is_finite();
    ok.then_some(sp)
}

/// One chunk of [`project_all`]'s work.
struct ProjectJob<'a> {
    g: &'a Gaussians,
    cm: &'a CameraModel,
    s: &'a RenderSettings,
    degree: u32,
    grid: &'a TileGrid,
    /// Index of the chunk's first Gaussian.
    first: usize,
}

/// Projects one chunk of Gaussians (see [`project_all`]), eight at a time in lanes `L`.
#[inline(always)]
fn project_chunk<L: Lanes>(
    job: &ProjectJob,
    sp_out: &mut [MaybeUninit<Splat2D>],
    rect_out: &mut [MaybeUninit<[u32; 4]>],
    st_out: &mut [u8],
) {
    let ProjectJob {
        g,
        cm,
        s,
        degree,
        grid,
        ..
    } = *job;
    let k = g.coeffs() * 3;
    let nb = sh::basis_len(degree);
    let len = sp_out.len();
    let centre = crate::lanes::splats::<L, 3>(cm.center);
    for j0 in (0..len).step_by(LANES) {
        let n = (len - j0).min(LANES);
        let live: Mask = if n == LANES { 0xff } else { (1u8 << n) - 1 };
        // A short last block repeats its last Gaussian in the spare lanes.
        let mut idx = [0usize; LANES];
        for (l, v) in idx.iter_mut().enumerate() {
            *v = job.first + (j0 + l).min(len - 1);
        }
        let gl =
            ParamLanes::<L>::gather(&g.means, &g.log_scales, &g.quats, &g.opacity_logits, &idx);
        let pl = project_lanes(cm, &gl, s.antialiased, s.near as f64);
        // Tile rectangles (the radius saturates as `Projected`'s i32 does).
        let r_max = c::<L>(i32::MAX as f64);
        let rect = grid.rect_lanes(
            pl.mean2d,
            [pl.radius[0].min(r_max), pl.radius[1].min(r_max)],
        );
        let nonempty = rect[0].lt(rect[1]) & rect[2].lt(rect[3]);
        // The lanes' active SH coefficients, each Gaussian's read once and contiguously.
        // Non-finite ones make a Gaussian invalid (checked first).
        let na = nb * 3;
        let rows = sh::coef_rows(&g.sh, &idx, k, na);
        let mut sh_ok: Mask = 0;
        for (l, row) in rows.iter().enumerate().take(n) {
            let finite = row[..na].iter().fold(true, |ok, v| ok & v.is_finite());
            sh_ok |= (finite as u8) << l;
        }
        let invalid = (!sh_ok | pl.status.invalid) & live;
        let mut visible = sh_ok & pl.status.visible() & nonempty & live;
        for l in 0..n {
            st_out[j0 + l] = if (invalid >> l) & 1 == 1 {
                INVALID
            } else {
                CULLED
            };
        }
        if visible == 0 {
            continue;
        }
        // Colours of the eight lanes from the view directions normalize(mean − centre).
        let v = [
            gl.mean[0] - centre[0],
            gl.mean[1] - centre[1],
            gl.mean[2] - centre[2],
        ];
        let vlen = (v[0] * v[0] + v[1] * v[1] + v[2] * v[2]).sqrt();
        let away = vlen.gt(c(0.0));
        let dir = [
            L::select(away, v[0] / vlen, c(0.0)),
            L::select(away, v[1] / vlen, c(0.0)),
            L::select(away, v[2] / vlen, c(1.0)),
        ];
        let cols = L::columns(&rows, na);
        let col = crate::lanes::to_arrays(sh::eval_color_lanes(degree, |q| cols[q], dir));
        let m = [pl.mean2d[0].to_array(), pl.mean2d[1].to_array()];
        let kc = crate::lanes::to_arrays(pl.conic);
        let (op, dp) = (pl.opacity.to_array(), pl.depth.to_array());
        let rad = [pl.radius[0].to_array(), pl.radius[1].to_array()];
        let lr = pl.log_alpha_ratio.to_array();
        let rect = crate::lanes::to_arrays(rect);
        while visible != 0 {
            let l = visible.trailing_zeros() as usize;
            visible &= visible - 1;
            let p = Projected {
                mean2d: [m[0][l], m[1][l]],
                conic: [kc[0][l], kc[1][l], kc[2][l]],
                opacity: op[l],
                depth: dp[l],
                radius: [rad[0][l] as i32, rad[1][l] as i32],
            };
            let rgb = [col[0][l], col[1][l], col[2][l]];
            if let Some(sp) = make_splat(&p, rgb, lr[l]) {
                let j = j0 + l;
                sp_out[j].write(sp);
                rect_out[j].write([
                    rect[0][l] as u32,
                    rect[1][l] as u32,
                    rect[2][l] as u32,
                    rect[3][l] as u32,
                ]);
                st_out[j] = VISIBLE;
            }
        }
    }
}

/// [`project_chunk`] with AVX-512 lanes: the same IEEE operations as the portable lanes.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx512f,avx512dq,avx2,fma")]
fn project_chunk_avx512(
    job: &ProjectJob,
    sp_out: &mut [MaybeUninit<Splat2D>],
    rect_out: &mut [MaybeUninit<[u32; 4]>],
    st_out: &mut [u8],
) {
    project_chunk::<crate::lanes::avx512::Z8>(job, sp_out, rect_out, st_out)
}

/// [`project_chunk`] with AVX2 lanes: the same IEEE operations as the portable lanes.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2,fma")]
fn project_chunk_avx2(
    job: &ProjectJob,
    sp_out: &mut [MaybeUninit<Splat2D>],
    rect_out: &mut [MaybeUninit<[u32; 4]>],
    st_out: &mut [u8],
) {
    project_chunk::<crate::lanes::avx2::Y8>(job, sp_out, rect_out, st_out)
}

/// Projection status of one Gaussian.
const VISIBLE: u8 = 0;
const CULLED: u8 = 1;
const INVALID: u8 = 2;

/// Projects every Gaussian and evaluates the colour of the visible ones: fills `splats`,
/// `rects` and `status` (indexed by Gaussian).
fn project_all(
    g: &Gaussians,
    cm: &CameraModel,
    s: &RenderSettings,
    degree: u32,
    grid: &TileGrid,
) -> ProjectedAll {
    let n = g.len();
    let k = g.coeffs() * 3;
    let sh_ok = g.sh.len() == n * k
        && g.log_scales.len() == n
        && g.quats.len() == n
        && g.opacity_logits.len() == n;
    let mut splats = uninit_vec::<Splat2D>(n);
    let mut rects = uninit_vec::<[u32; 4]>(n);
    let mut status = vec![INVALID; n];
    if !sh_ok {
        return ProjectedAll {
            splats,
            rects,
            status,
        };
    }
    let isa = detect_isa();
    let wide_lanes = crate::lanes::wide_available();
    splats
        .par_chunks_mut(PROJECT_CHUNK)
        .zip(rects.par_chunks_mut(PROJECT_CHUNK))
        .zip(status.par_chunks_mut(PROJECT_CHUNK))
        .enumerate()
        .for_each(|(ci, ((sp_out, rect_out), st_out))| {
            let job = ProjectJob {
                g,
                cm,
                s,
                degree,
                grid,
                first: ci * PROJECT_CHUNK,
            };
            match isa {
                #[cfg(target_arch = "x86_64")]
                Isa::Avx512 if wide_lanes => {
                    // SAFETY: AVX-512F/DQ, AVX2 and FMA were detected.
                    unsafe { project_chunk_avx512(&job, sp_out, rect_out, st_out) }
                }
                #[cfg(target_arch = "x86_64")]
                Isa::Avx2 | Isa::Avx512 => {
                    // SAFETY: both variants imply AVX2 + FMA support.
                    unsafe { project_chunk_avx2(&job, sp_out, rect_out, st_out) }
                }
                _ => {
                    let _ = wide_lanes; // only x86-64 has the AVX-512 lanes
                    project_chunk::<P8>(&job, sp_out, rect_out, st_out)
                }
            }
        });
    ProjectedAll {
        splats,
        rects,
        status,
    }
}

/// The per-Gaussian results of [`project_all`]: `splats[i]` and `rects[i]` are initialised
/// exactly where `status[i] == VISIBLE`.
struct ProjectedAll {
    splats: Vec<MaybeUninit<Splat2D>>,
    rects: Vec<MaybeUninit<[u32; 4]>>,
    status: Vec<u8>,
}

/// Raw pointers to the output images, written by the tiles in parallel.
#[derive(Clone, Copy)]
struct ImageOut {
    rgb: *mut f32,
    alpha: *mut f32,
    depth: *mut f32,
}

impl ImageOut {
    /// Writes pixel `p` (the closures capture the whole wrapper through this method).
    ///
    /// # Safety
    /// `p` must lie inside the image and be written by one thread only.
    #[inline(always)]
    unsafe fn write(&self, p: usize, rgb: [f32; 3], alpha: f32, depth: f32) {
        for (ch, v) in rgb.iter().enumerate() {
            *self.rgb.add(p * 3 + ch) = *v;
        }
        *self.alpha.add(p) = alpha;
        *self.depth.add(p) = depth;
    }
}

// SAFETY: the tiles write disjoint pixels (see `render_impl`).
unsafe impl Send for ImageOut {}
// SAFETY: as above.
unsafe impl Sync for ImageOut {}

pub(crate) fn render_impl(
    g: &Gaussians,
    cam: &Camera,
    s: &RenderSettings,
    mask: Option<&[u8]>,
    cutoff: Cutoff,
) -> RenderOutput {
    let (width, height) = (cam.width, cam.height);
    let npix = width as usize * height as usize;
    let degree = s.sh_degree.min(g.sh_degree).min(3);
    let grid = TileGrid::new(width, height);
    let mask = mask.filter(|m| m.len() == npix);
    let mut stats = RenderStats::default();
    let ProjectedAll {
        splats: all_splats,
        rects: all_rects,
        status,
    } = if cam.validate().is_ok() {
        let cm = CameraModel::new(cam);
        project_all(g, &cm, s, degree, &grid)
    } else {
        ProjectedAll {
            splats: Vec::new(),
            rects: Vec::new(),
            status: vec![CULLED; g.len()],
        }
    };
    let mut visible = Vec::new();
    let mut depth = vec![0.0f32; g.len()];
    for (i, st) in status.iter().enumerate() {
        match *st {
            VISIBLE => {
                visible.push(i as u32);
                // SAFETY: the record of a visible Gaussian was written by `project_all`.
                depth[i] = unsafe { all_splats[i].assume_init_ref() }.depth;
            }
            CULLED => stats.culled += 1,
            _ => stats.invalid += 1,
        }
    }
    stats.visible = visible.len();
    let rank_id = depth_order(&visible, &depth);
    drop(depth);
    // SAFETY (both gathers): `rank_id` lists visible Gaussians only, whose records and
    // rectangles `project_all` wrote.
    let splats: Vec<Splat2D> = rank_id
        .par_iter()
        .with_min_len(PROJECT_CHUNK)
        .map(|&i| unsafe { all_splats[i as usize].assume_init() })
        .collect();
    let rects: Vec<[u32; 4]> = rank_id
        .par_iter()
        .with_min_len(PROJECT_CHUNK)
        .map(|&i| unsafe { all_rects[i as usize].assume_init() })
        .collect();
    drop(all_splats);
    drop(all_rects);
    let bins = bin_indexed(&grid, &rects, &rank_id, g.len());
    drop(rects);

    let max_alpha = effective_max_alpha(s);
    let isa = detect_isa();
    let mut rgb = filled_par(npix * 3, 0.0f32);
    let mut alpha = filled_par(npix, 0.0f32);
    let mut depth_img = filled_par(npix, 0.0f32);
    let mut last = filled_par(grid.len() * TILE_PIXELS, 0u32);
    let mut final_t = filled_par(grid.len() * TILE_PIXELS, 1.0f32);
    let out = ImageOut {
        rgb: rgb.as_mut_ptr(),
        alpha: alpha.as_mut_ptr(),
        depth: depth_img.as_mut_ptr(),
    };
    let bg = s.background;
    let pairs: u64 = last
        .par_chunks_mut(TILE_PIXELS)
        .zip(final_t.par_chunks_mut(TILE_PIXELS))
        .enumerate()
        .map_init(TileState::default, |st, (t, (last_t, ft))| {
            let tx = (t % grid.tiles_x as usize) as u32;
            let ty = (t / grid.tiles_x as usize) as u32;
            let (x0, y0) = (tx * TILE, ty * TILE);
            let mut active = [0u16; 16];
            for ly in 0..TILE {
                for lx in 0..TILE {
                    let (x, y) = (x0 + lx, y0 + ly);
                    if x < width && y < height {
                        let on = mask.is_none_or(|m| m[(y * width + x) as usize] != 0);
                        active[ly as usize] |= (on as u16) << lx;
                    }
                }
            }
            *st = TileState::default();
            let list = &bins.ranks[bins.ranges[t]..bins.ranges[t + 1]];
            let pairs = match cutoff {
                Cutoff::Hard => raster_tile_dispatch::<false>(
                    isa, &splats, list, x0, y0, &active, max_alpha, st,
                ),
                Cutoff::Smooth => {
                    raster_tile_dispatch::<true>(isa, &splats, list, x0, y0, &active, max_alpha, st)
                }
            };
            for ly in 0..TILE as usize {
                let y = y0 as usize + ly;
                let row = &st.rows[ly];
                last_t[ly * 16..ly * 16 + 16].copy_from_slice(&row.last);
                ft[ly * 16..ly * 16 + 16].copy_from_slice(&row.t);
                if y >= height as usize {
                    continue;
                }
                for lx in 0..TILE as usize {
                    let x = x0 as usize + lx;
                    if x >= width as usize {
                        break;
                    }
                    let p = y * width as usize + x;
                    let tt = row.t[lx];
                    let a = 1.0 - tt;
                    let dv = if a >= DEPTH_ALPHA_EPS {
                        row.d[lx] / a
                    } else {
                        0.0
                    };
                    // SAFETY: pixel (x, y) lies inside the image (checked above) and inside
                    // this tile only, so no other tile writes it; the buffers outlive the
                    // parallel loop.
                    let rgb: [f32; 3] = std::array::from_fn(|ch| row.c[ch][lx] + tt * bg[ch]);
                    unsafe { out.write(p, rgb, a, dv) };
                }
            }
            pairs
        })
        .sum();
    stats.pairs = pairs;
    RenderOutput {
        width,
        height,
        rgb,
        alpha,
        depth: depth_img,
        stats,
        state: RasterState {
            grid,
            splats,
            bins,
            last,
            final_t,
            settings: s.clone(),
            cutoff,
            sh_degree: degree,
        },
    }
}

#[cfg(test)]
pub(crate) mod tests {
    use super::*;

    #[cfg(target_arch = "x86_64")]
    #[test]
    fn vector_and_portable_projection_chunks_agree_bit_for_bit() {
        let mut isas = vec![];
        if crate::lanes::wide_available() && matches!(detect_isa(), Isa::Avx512) {
            isas.push(Isa::Avx512);
        }
        if crate::lanes::avx2::available() {
            isas.push(Isa::Avx2);
        }
        if isas.is_empty() {
            eprintln!("no vector lanes on this CPU: skipped");
            return;
        }
        let mut rng = augsplat_core::Rng::new(21);
        let mut g = Gaussians::empty(3);
        let n = 1000; // not a multiple of the lane count
        for i in 0..n {
            g.means.push([
                rng.uniform(-3.0, 3.0) as f32,
                rng.uniform(-2.0, 2.0) as f32,
                rng.uniform(-1.0, 5.0) as f32,
            ]);
            let s = rng.uniform(-5.0, 0.0) as f32;
            g.log_scales.push([s, s + 0.3, s - 0.4]);
            g.quats
                .push([1.0, rng.uniform(-1.0, 1.0) as f32, 0.2, -0.1]);
            g.opacity_logits.push(rng.uniform(-7.0, 5.0) as f32);
            for q in 0..48 {
                let v = rng.uniform(-0.5, 0.5) as f32;
                // A few Gaussians with a non-finite coefficient (active or not).
                g.sh.push(if i % 97 == 0 && q == (i / 97) % 48 {
                    f32::NAN
                } else {
                    v
                });
            }
        }
        let cam = augsplat_core::Camera {
            width: 83,
            height: 45,
            fx: 60.0,
            fy: 58.0,
            cx: 40.0,
            cy: 23.0,
            world_to_camera: augsplat_core::linalg::mat4_from_rt(
                &[[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]],
                [0.1, 0.0, 1.5],
            ),
        };
        let cm = CameraModel::new(&cam);
        let grid = TileGrid::new(cam.width, cam.height);
        for degree in [1, 3] {
            for antialiased in [false, true] {
                let s = RenderSettings {
                    antialiased,
                    ..RenderSettings::default()
                };
                let job = ProjectJob {
                    g: &g,
                    cm: &cm,
                    s: &s,
                    degree,
                    grid: &grid,
                    first: 0,
                };
                let run = |isa: Isa| {
                    let mut sp = uninit_vec::<Splat2D>(n);
                    let mut rc = uninit_vec::<[u32; 4]>(n);
                    let mut st = vec![9u8; n];
                    match isa {
                        // SAFETY: AVX-512 was detected above.
                        Isa::Avx512 => unsafe {
                            project_chunk_avx512(&job, &mut sp, &mut rc, &mut st)
                        },
                        // SAFETY: AVX2 + FMA were detected above.
                        Isa::Avx2 => unsafe { project_chunk_avx2(&job, &mut sp, &mut rc, &mut st) },
                        Isa::Portable => project_chunk::<P8>(&job, &mut sp, &mut rc, &mut st),
                    }
                    let out: Vec<Option<(Splat2D, [u32; 4])>> = (0..n)
                        .map(|i| {
                            // SAFETY: written where the status is VISIBLE.
                            (st[i] == VISIBLE)
                                .then(|| unsafe { (sp[i].assume_init(), rc[i].assume_init()) })
                        })
                        .collect();
                    (st, out)
                };
                let b = run(Isa::Portable);
                for &isa in &isas {
                    let a = run(isa);
                    assert_eq!(a.0, b.0, "{isa:?}");
                    let bits = |o: &Option<(Splat2D, [u32; 4])>| {
                        o.map(|(p, r)| {
                            let f = [
                                p.x,
                                p.y,
                                p.a,
                                p.b,
                                p.c,
                                p.opacity,
                                p.rgb[0],
                                p.rgb[1],
                                p.rgb[2],
                                p.depth,
                                p.ymin,
                                p.ymax,
                                p.sigma_max,
                                p.row_q,
                                p.row_w,
                                p.row_shift,
                            ];
                            (f.map(f32::to_bits), r)
                        })
                    };
                    assert!(
                        a.1.iter().zip(&b.1).all(|(x, y)| bits(x) == bits(y)),
                        "{isa:?}"
                    );
                }
                for code in [VISIBLE, CULLED, INVALID] {
                    assert!(b.0.contains(&code), "status {code} never occurs");
                }
            }
        }
    }

    /// Random projected Gaussians around one tile.
    pub(crate) fn random_tile_splats(seed: u64, n: usize) -> Vec<Splat2D> {
        let mut rng = augsplat_core::Rng::new(seed);
        (0..n)
            .map(|i| {
                let (sx, sy) = (rng.uniform(0.7, 6.0), rng.uniform(0.7, 6.0));
                let rho = rng.uniform(-0.8, 0.8);
                let cov = [sx * sx, rho * sx * sy, sy * sy];
                let det = cov[0] * cov[2] - cov[1] * cov[1];
                let o = rng.uniform(0.02, 0.999);
                let y = rng.uniform(-6.0, 22.0);
                let ry = (3.33 * cov[2].sqrt()).ceil();
                let p = crate::project::Projected {
                    mean2d: [rng.uniform(-6.0, 22.0), y],
                    conic: [cov[2] / det, -cov[1] / det, cov[0] / det],
                    opacity: o,
                    depth: 1.0 + i as f64 * 0.01,
                    radius: [(3.33 * cov[0].sqrt()).ceil() as i32, ry as i32],
                };
                let rgb = [
                    rng.uniform(0.0, 1.0),
                    rng.uniform(0.0, 1.0),
                    rng.uniform(0.0, 1.0),
                ];
                let lr = crate::project::log_alpha_ratio(p.opacity);
                make_splat(&p, rgb, lr).unwrap()
            })
            .collect()
    }

    /// The mask of a fully active tile with pixel 17 (row 1, column 1) switched off.
    fn active_mask() -> [u16; 16] {
        let mut active = [0xffffu16; 16];
        active[1] &= !(1 << 1);
        active
    }

    fn run(isa: Isa, smooth: bool, splats: &[Splat2D], list: &[u32]) -> (u64, TileState) {
        let mut st = TileState::default();
        let p = if smooth {
            raster_tile_dispatch::<true>(isa, splats, list, 0, 0, &active_mask(), 0.99, &mut st)
        } else {
            raster_tile_dispatch::<false>(isa, splats, list, 0, 0, &active_mask(), 0.99, &mut st)
        };
        (p, st)
    }

    fn bits(st: &TileState) -> Vec<u32> {
        let mut v = Vec::new();
        for r in &st.rows {
            v.extend(r.t.iter().map(|x| x.to_bits()));
            for ch in 0..3 {
                v.extend(r.c[ch].iter().map(|x| x.to_bits()));
            }
            v.extend(r.d.iter().map(|x| x.to_bits()));
            v.extend(r.last.iter().copied());
        }
        v
    }

    #[test]
    fn vector_variants_are_bit_identical_to_the_portable_kernel() {
        let splats = random_tile_splats(3, 300);
        let list: Vec<u32> = (0..300).collect();
        let mut isas = vec![Isa::Portable];
        #[cfg(target_arch = "x86_64")]
        {
            if std::arch::is_x86_feature_detected!("avx2")
                && std::arch::is_x86_feature_detected!("fma")
            {
                isas.push(Isa::Avx2);
            }
            if avx512::available() {
                isas.push(Isa::Avx512);
            } else {
                eprintln!("no AVX-512 on this CPU: only the portable variants are compared");
            }
        }
        for smooth in [false, true] {
            let (p0, s0) = run(Isa::Portable, smooth, &splats, &list);
            assert!(p0 > 1000);
            for &isa in &isas[1..] {
                let (p, s) = run(isa, smooth, &splats, &list);
                assert_eq!(p0, p, "{isa:?}");
                assert_eq!(bits(&s0), bits(&s), "{isa:?} smooth {smooth}");
            }
        }
    }

    /// The tile kernel against a direct per-pixel f32 evaluation of the same compositing rule
    /// over the whole list (no row test, no batching): the row test must never drop a pixel.
    #[test]
    fn tile_kernel_matches_a_direct_per_pixel_loop() {
        let splats = random_tile_splats(11, 400);
        let list: Vec<u32> = (0..400).collect();
        let (pairs, st) = run(detect_isa(), false, &splats, &list);
        let active = active_mask();
        let mut direct_pairs = 0u64;
        for ly in 0..16 {
            for lx in 0..16 {
                let (px, py) = (lx as f32 + 0.5, ly as f32 + 0.5);
                let (mut t, mut c, mut last) = (1.0f64, [0.0f64; 3], 0u32);
                if (active[ly] >> lx) & 1 != 0 {
                    for (k, sp) in splats.iter().enumerate() {
                        let (dx, dy) = ((sp.x - px) as f64, (sp.y - py) as f64);
                        let sigma = 0.5 * (sp.a as f64 * dx * dx + sp.c as f64 * dy * dy)
                            + sp.b as f64 * dx * dy;
                        let a = (sp.opacity as f64 * (-sigma).exp()).min(0.99);
                        if sigma < 0.0 || a < ALPHA_THRESHOLD as f64 {
                            continue;
                        }
                        if t * (1.0 - a) <= TRANSMITTANCE_THRESHOLD as f64 {
                            break;
                        }
                        for ch in 0..3 {
                            c[ch] += a * t * sp.rgb[ch] as f64;
                        }
                        t *= 1.0 - a;
                        last = k as u32 + 1;
                        direct_pairs += 1;
                    }
                }
                let row = &st.rows[ly];
                assert_eq!(row.last[lx], last, "pixel ({lx}, {ly})");
                assert!((row.t[lx] as f64 - t).abs() < 1e-5, "pixel ({lx}, {ly})");
                for ch in 0..3 {
                    assert!((row.c[ch][lx] as f64 - c[ch]).abs() < 1e-5);
                }
            }
        }
        assert_eq!(pairs, direct_pairs);
    }

    #[cfg(target_arch = "x86_64")]
    #[test]
    fn vector_transpose_matches_the_portable_one() {
        let mut rng = augsplat_core::Rng::new(21);
        for round in 0..20 {
            let masks: [u16; BATCH] = std::array::from_fn(|j| match round {
                0 => 0xffff,
                1 => 0x8001 << (j % 2),
                _ => rng.below(1 << 16) as u16,
            });
            let want = transpose_portable(&masks);
            for ly in 0..16 {
                for j in 0..BATCH {
                    assert_eq!((want[ly] >> j) & 1, ((masks[j] >> ly) & 1) as u64);
                }
            }
            if std::arch::is_x86_feature_detected!("avx2") {
                #[target_feature(enable = "avx2,fma")]
                fn go2(m: &[u16; BATCH]) -> [u64; 16] {
                    // SAFETY: the caller checked AVX2 support.
                    unsafe { <avx2::Avx2 as ForwardKernel>::transpose(m) }
                }
                // SAFETY: AVX2 availability was checked above.
                assert_eq!(unsafe { go2(&masks) }, want);
            }
            if avx512::available() {
                #[target_feature(enable = "avx512f,avx512bw")]
                fn go(m: &[u16; BATCH]) -> [u64; 16] {
                    // SAFETY: the caller checked AVX-512 support.
                    unsafe { <avx512::Avx512 as ForwardKernel>::transpose(m) }
                }
                // SAFETY: AVX-512 availability was checked above.
                assert_eq!(unsafe { go(&masks) }, want);
            }
        }
    }

    #[test]
    fn base_two_exponential_is_accurate() {
        // Coarse steps over the whole range, fine ones over one period of the polynomial.
        let coarse = (0..9190).map(|i| -(i as f32) * 0.0137);
        let fine = (0..=20_000).map(|i| -(i as f32) / 20_000.0);
        let mut worst = 0.0f64;
        for x in coarse.chain(fine) {
            let e = exp2_neg(x) as f64;
            let r = (x as f64).exp2();
            worst = worst.max(((e - r) / r).abs());
        }
        assert!(worst < 2.4e-7, "worst relative error {worst}");
        assert!((exp2_neg(0.0) - 1.0).abs() <= 2.0 * f32::EPSILON);
        assert!(exp2_neg(-1e30) >= 0.0 && exp2_neg(-1e30) < 1e-37);
        assert!(exp2_neg(f32::NEG_INFINITY) < 1e-37);
    }

    #[test]
    fn row_geometry_in_bits_gives_the_gaussian_falloff() {
        // e^−σ from the kernels' base-2 form, against f64 on a rotated anisotropic conic.
        let sp = Splat2D {
            x: 10.3,
            y: -4.7,
            a: 0.37,
            b: -0.11,
            c: 0.21,
            ..Splat2D::default()
        };
        for py in [-9.5f32, -4.5, 0.5, 3.5] {
            let g = RowGeom::new(&sp, py);
            for px in [2.5f32, 8.5, 10.5, 17.5] {
                let dx = sp.x - px;
                let dy = (sp.y - py) as f64;
                let sigma = 0.5 * sp.a as f64 * (dx as f64).powi(2)
                    + sp.b as f64 * dx as f64 * dy
                    + 0.5 * sp.c as f64 * dy * dy;
                let want = (-sigma).exp();
                let got = gauss_of_exponent(g.exponent(dx)) as f64;
                assert!(
                    (got - want).abs() <= 1e-6 * want + 1e-12,
                    "({px}, {py}): {got} vs {want}"
                );
            }
        }
    }

    #[cfg(target_arch = "x86_64")]
    #[test]
    fn avx2_gaussian_falloff_matches_the_scalar_one_bit_for_bit() {
        if !(std::arch::is_x86_feature_detected!("avx2")
            && std::arch::is_x86_feature_detected!("fma"))
        {
            eprintln!("no AVX2 + FMA on this CPU: skipped");
            return;
        }
        let mut exponents: Vec<f32> = (0..4096).map(|i| i as f32 * -0.0093).collect();
        exponents.extend([
            1.0,
            -0.0,
            0.0,
            f32::NAN,
            f32::INFINITY,
            f32::NEG_INFINITY,
            -SIGMA_CLAMP,
            SIGMA_CLAMP,
            1e-30,
            -1e-30,
            -0.5,
            -43.5,
        ]);
        for chunk in exponents.chunks(8) {
            let mut v = [0.0f32; 8];
            v[..chunk.len()].copy_from_slice(chunk);
            let mut out = [0.0f32; 8];
            // SAFETY: AVX2 + FMA availability was checked above.
            unsafe {
                use std::arch::x86_64::*;
                #[target_feature(enable = "avx2,fma")]
                unsafe fn go(v: &[f32; 8], out: &mut [f32; 8]) {
                    let s = _mm256_loadu_ps(v.as_ptr());
                    _mm256_storeu_ps(out.as_mut_ptr(), avx2::gauss_v(s));
                }
                go(&v, &mut out);
            }
            for l in 0..8 {
                assert_eq!(
                    out[l].to_bits(),
                    gauss_of_exponent(v[l]).to_bits(),
                    "exponent {}",
                    v[l]
                );
            }
        }
    }

    #[cfg(target_arch = "x86_64")]
    #[test]
    fn vector_exponential_matches_the_scalar_one() {
        if !avx512::available() {
            eprintln!("no AVX-512 on this CPU: skipped");
            return;
        }
        let xs: Vec<f32> = (0..4096)
            .map(|i| -(i as f32) * 0.0093 - 1e-3 * (i % 7) as f32)
            .collect();
        for chunk in xs.chunks(16) {
            let mut v = [0.0f32; 16];
            v[..chunk.len()].copy_from_slice(chunk);
            let mut out = [0.0f32; 16];
            // SAFETY: AVX-512 availability was checked above.
            unsafe {
                use std::arch::x86_64::*;
                #[target_feature(enable = "avx512f,avx512dq,avx512bw,fma")]
                unsafe fn go(v: &[f32; 16], out: &mut [f32; 16]) {
                    let s = _mm512_loadu_ps(v.as_ptr());
                    _mm512_storeu_ps(out.as_mut_ptr(), avx512::gauss_v(s));
                }
                go(&v, &mut out);
            }
            for l in 0..16 {
                assert_eq!(
                    out[l].to_bits(),
                    gauss_of_exponent(v[l]).to_bits(),
                    "x {}",
                    v[l]
                );
            }
        }
    }
}
