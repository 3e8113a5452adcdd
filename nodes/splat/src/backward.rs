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
//! by multiplying by its dx once. As in the forward pass, every kernel has a portable
//! twin and AVX-512 and AVX2 versions performing the same IEEE operations, and the results are
//! bit-identical.

// Negated comparisons are deliberate: they also reject NaN. Index loops read best in
// small fixed-size numeric code.
#![allow(clippy::neg_cmp_op_on_partial_ord, clippy::needless_range_loop)]

use crate::adam::ParamGrads;
use crate::buffers::filled_par;
use crate::constants::{ALPHA_THRESHOLD, DEPTH_ALPHA_EPS, TILE, TILE_PIXELS};
use crate::forward::{
    detect_isa, gauss_of_exponent, row_mask_portable, smooth_cut, Isa, RowGeom, Splat2D,
    TileCoords, PREFETCH_AHEAD, PROJECT_CHUNK,
};
use crate::gaussians::Gaussians;
use crate::lanes::{c, Lanes, Mask, LANES, P8};
use crate::project::{project_vjp_lanes, CameraModel, ParamGrad, ParamLanes, ProjectedGradLanes};
use crate::render::{Cutoff, Gradients, RenderOutput, RenderSettings};
use crate::sh;
use augsplat_core::Camera;
use rayon::prelude::*;

/// Screen-space gradient of one (tile, Gaussian) pair: mean2d x, y; conic a, b, c; opacity;
/// colour r, g, b; depth.
type PairGrad = [f32; 10];

/// Per-pixel lane sums of one (tile, Gaussian) pair: P, S_x, S_y, S_xx, S_xy, S_yy,
/// colour r, g, b, depth (see the module documentation).
type LaneSums = [f32; 10];

/// The backward state of one tile row (16 pixels).
#[derive(Clone, Copy, Default)]
#[repr(C, align(64))]
struct BwdRow {
    /// Transmittance after the Gaussian being visited.
    t: [f32; 16],
    /// The running "behind" sum R.
    r: [f32; 16],
    /// Upstream dL/d(colour).
    gc: [[f32; 16]; 3],
    /// Upstream dL/d(unnormalised depth sum).
    gs: [f32; 16],
    /// List entries up to and including the last contributor.
    last: [u32; 16],
}

/// The backward state of one tile.
#[derive(Default)]
struct BwdTile {
    rows: [BwdRow; 16],
    /// Per row, the largest `last`.
    row_last: [u32; 16],
}

/// Tree sum of 16 lanes: (l, l+8), then (l, l+4), (l, l+2), (l, l+1) — the order the vector
/// reduction uses.
#[inline(always)]
fn tree_sum16(v: &[f32; 16]) -> f32 {
    let mut s8 = [0.0f32; 8];
    for i in 0..8 {
        s8[i] = v[i] + v[i + 8];
    }
    let mut s4 = [0.0f32; 4];
    for i in 0..4 {
        s4[i] = s8[i] + s8[i + 4];
    }
    let s2 = [s4[0] + s4[2], s4[1] + s4[3]];
    s2[0] + s2[1]
}

/// Portable backward of one Gaussian over the rows in `rows`: updates the rows' T and R and
/// returns the lane sums. `k` is the Gaussian's list index.
#[allow(clippy::too_many_arguments)]
#[inline(always)]
fn backward_gaussian_portable<const SMOOTH: bool>(
    sp: &Splat2D,
    k: u32,
    mut rows: u16,
    tile: &mut BwdTile,
    tc: &TileCoords,
    max_alpha: f32,
) -> LaneSums {
    let mut lanes = [[0.0f32; 16]; 10];
    while rows != 0 {
        let ly = rows.trailing_zeros() as usize;
        rows &= rows - 1;
        let g = RowGeom::new(sp, tc.py[ly]);
        let dy2 = g.dy * g.dy;
        let row = &mut tile.rows[ly];
        for l in 0..16 {
            let dx = sp.x - tc.px[l];
            let ex = g.exponent(dx);
            let gauss = gauss_of_exponent(ex);
            let raw = sp.opacity * gauss;
            let a1 = raw.min(max_alpha);
            let (alpha, pass, da_da1) = if SMOOTH {
                let (s, ds) = smooth_cut(a1);
                (a1 * s, a1 > ALPHA_THRESHOLD, s + a1 * ds)
            } else {
                (a1, a1 >= ALPHA_THRESHOLD, 1.0)
            };
            if !(k < row.last[l] && ex <= 0.0 && pass) {
                continue;
            }
            let ra = 1.0 / (1.0 - alpha);
            let ti = row.t[l] * ra;
            let w = alpha * ti;
            let mut gcol = row.gc[0][l] * sp.rgb[0];
            gcol = row.gc[1][l].mul_add(sp.rgb[1], gcol);
            gcol = row.gc[2][l].mul_add(sp.rgb[2], gcol);
            gcol = row.gs[l].mul_add(sp.depth, gcol);
            // G·T_i − R/(1 − α) = (G·T_{i+1} − R)/(1 − α): the fused multiply-add does not
            // wait for the division.
            let mut dl = gcol.mul_add(row.t[l], -row.r[l]) * ra;
            if SMOOTH {
                dl *= da_da1;
            }
            if raw < max_alpha {
                let q = dl * gauss;
                lanes[0][l] += q;
                lanes[2][l] = q.mul_add(g.dy, lanes[2][l]);
                lanes[5][l] = q.mul_add(dy2, lanes[5][l]);
            }
            for ch in 0..3 {
                lanes[6 + ch][l] = row.gc[ch][l].mul_add(w, lanes[6 + ch][l]);
            }
            lanes[9][l] = row.gs[l].mul_add(w, lanes[9][l]);
            row.r[l] = gcol.mul_add(w, row.r[l]);
            row.t[l] = ti;
        }
    }
    // dx is constant along a lane, so the sums weighted by dx are formed once per lane.
    for l in 0..16 {
        let dx = sp.x - tc.px[l];
        lanes[1][l] = lanes[0][l] * dx;
        lanes[3][l] = lanes[1][l] * dx;
        lanes[4][l] = lanes[2][l] * dx;
    }
    let mut out = [0.0f32; 10];
    for q in 0..10 {
        out[q] = tree_sum16(&lanes[q]);
    }
    out
}

/// The two vector primitives of the backward tile loop.
trait BackwardKernel {
    /// Hints the cache that `p` will be read soon (no effect on results).
    ///
    /// # Safety
    /// The CPU must support the kernel's instruction set.
    unsafe fn prefetch(_p: *const Splat2D) {}
    /// Row mask of one Gaussian (as in the forward pass).
    ///
    /// # Safety
    /// The CPU must support the kernel's instruction set.
    unsafe fn row_mask(sp: &Splat2D, tc: &TileCoords) -> u16;
    /// Row masks of one Gaussian per half of the tile: bits 0–15 for its left eight pixel
    /// columns, bits 16–31 for the right eight (the default, for kernels that take whole
    /// rows, repeats the whole-row mask).
    ///
    /// # Safety
    /// The CPU must support the kernel's instruction set.
    unsafe fn half_row_masks(sp: &Splat2D, tc: &TileCoords) -> u32 {
        let m = Self::row_mask(sp, tc) as u32;
        m | (m << 16)
    }
    /// Hard-cutoff backward of one Gaussian (see [`backward_gaussian_portable`]).
    ///
    /// # Safety
    /// The CPU must support the kernel's instruction set.
    unsafe fn backward_gaussian(
        sp: &Splat2D,
        k: u32,
        rows: u16,
        tile: &mut BwdTile,
        tc: &TileCoords,
        max_alpha: f32,
    ) -> LaneSums;
    /// [`BackwardKernel::backward_gaussian`] over the left halves of the rows `left` and the
    /// right halves of the rows `right` (the default takes whole rows: every pixel outside
    /// the Gaussian's chord is skipped by the compositing rule anyway).
    ///
    /// # Safety
    /// The CPU must support the kernel's instruction set.
    unsafe fn backward_halves(
        sp: &Splat2D,
        k: u32,
        left: u16,
        right: u16,
        tile: &mut BwdTile,
        tc: &TileCoords,
        max_alpha: f32,
    ) -> LaneSums {
        Self::backward_gaussian(sp, k, left | right, tile, tc, max_alpha)
    }
}

/// The portable kernels.
struct Portable;

impl BackwardKernel for Portable {
    #[inline(always)]
    unsafe fn row_mask(sp: &Splat2D, tc: &TileCoords) -> u16 {
        row_mask_portable(sp, tc)
    }
    #[inline(always)]
    unsafe fn backward_gaussian(
        sp: &Splat2D,
        k: u32,
        rows: u16,
        tile: &mut BwdTile,
        tc: &TileCoords,
        max_alpha: f32,
    ) -> LaneSums {
        backward_gaussian_portable::<false>(sp, k, rows, tile, tc, max_alpha)
    }
}

/// AVX-512 kernels (16 lanes: one tile row per vector).
#[cfg(target_arch = "x86_64")]
mod avx512 {
    use super::*;
    use crate::forward::avx512::{gauss_v, row_mask};
    use std::arch::x86_64::*;

    /// [`tree_sum16`] of ten vectors at once: each shuffle stage adds the same lane pairs
    /// as the scalar tree ((l, l+8), (l, l+4), (l, l+2), (l, l+1)), so every sum is
    /// bit-identical to it, but the stages serve several accumulators per instruction.
    #[inline(always)]
    unsafe fn reduce10(a: &[__m512; 10]) -> [f32; 10] {
        // (l, l+8): [s8 of A | s8 of B].
        let f = |x: __m512, y: __m512| {
            _mm512_add_ps(
                _mm512_shuffle_f32x4::<0x44>(x, y),
                _mm512_shuffle_f32x4::<0xEE>(x, y),
            )
        };
        // (l, l+4): [s4 of A | B | C | D] from [s8 A | s8 B], [s8 C | s8 D].
        let g = |x: __m512, y: __m512| {
            _mm512_add_ps(
                _mm512_shuffle_f32x4::<0x88>(x, y),
                _mm512_shuffle_f32x4::<0xDD>(x, y),
            )
        };
        // (l, l+2) within each 128-bit lane.
        let h = |x: __m512, y: __m512| {
            _mm512_add_ps(
                _mm512_shuffle_ps::<0x44>(x, y),
                _mm512_shuffle_ps::<0xEE>(x, y),
            )
        };
        // (l, l+1) within each 128-bit lane.
        let k = |x: __m512, y: __m512| {
            _mm512_add_ps(
                _mm512_shuffle_ps::<0x88>(x, y),
                _mm512_shuffle_ps::<0xDD>(x, y),
            )
        };
        let zero = _mm512_setzero_ps();
        let c0 = f(a[0], a[1]);
        let c1 = f(a[2], a[3]);
        let c2 = f(a[4], a[5]);
        let c3 = f(a[6], a[7]);
        let c4 = f(a[8], a[9]);
        let e0 = g(c0, c1);
        let e1 = g(c2, c3);
        let e2 = g(c4, zero);
        let r = k(h(e0, e1), h(e2, zero));
        // 128-bit lane l holds the sums of accumulators l, 4 + l and (l < 2) 8 + l.
        let mut buf = [0.0f32; 16];
        _mm512_storeu_ps(buf.as_mut_ptr(), r);
        let mut out = [0.0f32; 10];
        for q in 0..10 {
            out[q] = buf[4 * (q % 4) + q / 4];
        }
        out
    }

    /// [`backward_gaussian_portable`] (hard cutoff) with a row's pixels as lanes and the lane
    /// sums in registers across rows.
    #[inline(always)]
    pub(super) unsafe fn backward_gaussian(
        sp: &Splat2D,
        k: u32,
        mut rows: u16,
        tile: &mut BwdTile,
        tc: &TileCoords,
        max_alpha: f32,
    ) -> LaneSums {
        let px = _mm512_load_ps(tc.px.as_ptr());
        let zero = _mm512_setzero_ps();
        let one = _mm512_set1_ps(1.0);
        let maxa = _mm512_set1_ps(max_alpha);
        let thr = _mm512_set1_ps(ALPHA_THRESHOLD);
        let kv = _mm512_set1_epi32(k as i32);
        let xs = _mm512_set1_ps(sp.x);
        let ea = _mm512_set1_ps(RowGeom::exp_a(sp));
        let o = _mm512_set1_ps(sp.opacity);
        let (cr, cg, cb, cz) = (
            _mm512_set1_ps(sp.rgb[0]),
            _mm512_set1_ps(sp.rgb[1]),
            _mm512_set1_ps(sp.rgb[2]),
            _mm512_set1_ps(sp.depth),
        );
        let mut acc = [zero; 10];
        while rows != 0 {
            let ly = rows.trailing_zeros() as usize;
            rows &= rows - 1;
            let g = RowGeom::new(sp, *tc.py.get_unchecked(ly));
            let row = tile.rows.get_unchecked_mut(ly);
            let last = _mm512_load_si512(row.last.as_ptr() as *const __m512i);
            let dx = _mm512_sub_ps(xs, px);
            let u = _mm512_fmadd_ps(ea, dx, _mm512_set1_ps(g.eb));
            let ex = _mm512_fmadd_ps(u, dx, _mm512_set1_ps(g.ec));
            let gauss = gauss_v(ex);
            let raw = _mm512_mul_ps(o, gauss);
            let a1 = _mm512_min_ps(raw, maxa);
            let ok = _mm512_cmpgt_epu32_mask(last, kv);
            let ok = _mm512_mask_cmp_ps_mask::<_CMP_LE_OQ>(ok, ex, zero);
            let ok = _mm512_mask_cmp_ps_mask::<_CMP_GE_OQ>(ok, a1, thr);
            if ok == 0 {
                continue;
            }
            let t = _mm512_load_ps(row.t.as_ptr());
            let r = _mm512_load_ps(row.r.as_ptr());
            let gr = _mm512_load_ps(row.gc[0].as_ptr());
            let gg = _mm512_load_ps(row.gc[1].as_ptr());
            let gb = _mm512_load_ps(row.gc[2].as_ptr());
            let gs = _mm512_load_ps(row.gs.as_ptr());
            let ra = _mm512_div_ps(one, _mm512_sub_ps(one, a1));
            let ti = _mm512_mul_ps(t, ra);
            let w = _mm512_maskz_mul_ps(ok, a1, ti);
            let gcol = _mm512_mul_ps(gr, cr);
            let gcol = _mm512_fmadd_ps(gg, cg, gcol);
            let gcol = _mm512_fmadd_ps(gb, cb, gcol);
            let gcol = _mm512_fmadd_ps(gs, cz, gcol);
            let dl = _mm512_mul_ps(_mm512_fmsub_ps(gcol, t, r), ra);
            let qm = _mm512_mask_cmp_ps_mask::<_CMP_LT_OQ>(ok, raw, maxa);
            let q = _mm512_maskz_mul_ps(qm, dl, gauss);
            let dy = _mm512_set1_ps(g.dy);
            acc[0] = _mm512_add_ps(acc[0], q);
            acc[2] = _mm512_fmadd_ps(q, dy, acc[2]);
            acc[5] = _mm512_fmadd_ps(q, _mm512_set1_ps(g.dy * g.dy), acc[5]);
            acc[6] = _mm512_fmadd_ps(gr, w, acc[6]);
            acc[7] = _mm512_fmadd_ps(gg, w, acc[7]);
            acc[8] = _mm512_fmadd_ps(gb, w, acc[8]);
            acc[9] = _mm512_fmadd_ps(gs, w, acc[9]);
            _mm512_store_ps(row.r.as_mut_ptr(), _mm512_mask3_fmadd_ps(gcol, w, r, ok));
            _mm512_store_ps(row.t.as_mut_ptr(), _mm512_mask_mov_ps(t, ok, ti));
        }
        // The dx-weighted sums, once per lane (as the portable twin).
        let dx = _mm512_sub_ps(xs, px);
        acc[1] = _mm512_mul_ps(acc[0], dx);
        acc[3] = _mm512_mul_ps(acc[1], dx);
        acc[4] = _mm512_mul_ps(acc[2], dx);
        reduce10(&acc)
    }

    /// Marker type of the AVX-512 backward kernels.
    pub(super) struct Avx512;

    impl BackwardKernel for Avx512 {
        #[inline(always)]
        unsafe fn prefetch(p: *const Splat2D) {
            _mm_prefetch::<_MM_HINT_T0>(p as *const i8);
        }
        #[inline(always)]
        unsafe fn row_mask(sp: &Splat2D, tc: &TileCoords) -> u16 {
            row_mask(sp, tc)
        }
        #[inline(always)]
        unsafe fn backward_gaussian(
            sp: &Splat2D,
            k: u32,
            rows: u16,
            tile: &mut BwdTile,
            tc: &TileCoords,
            max_alpha: f32,
        ) -> LaneSums {
            backward_gaussian(sp, k, rows, tile, tc, max_alpha)
        }
    }
}

/// AVX2 kernels (8 lanes: a row's left and right halves are separate vectors).
#[cfg(target_arch = "x86_64")]
mod avx2 {
    use super::*;
    use crate::forward::avx2::{gauss_v, half_row_masks, row_mask};
    use std::arch::x86_64::*;

    /// [`tree_sum16`] of ten accumulators held as left and right halves: `lo + hi` gives the
    /// (l, l+8) sums; each later shuffle stage adds the same lane pairs as the scalar tree
    /// ((l, l+4), (l, l+2), (l, l+1)) for several accumulators per instruction, so every sum
    /// is bit-identical to it.
    #[inline(always)]
    unsafe fn reduce10(lo: &[__m256; 10], hi: &[__m256; 10]) -> [f32; 10] {
        // Plain loops and macros, not closures: a closure would be compiled without the
        // target features and call the intrinsics out of line.
        let mut s8 = [_mm256_setzero_ps(); 10];
        for q in 0..10 {
            s8[q] = _mm256_add_ps(lo[q], hi[q]);
        }
        // (l, l+4): [s4 of A | s4 of B].
        macro_rules! f {
            ($a:expr, $b:expr) => {
                _mm256_add_ps(
                    _mm256_permute2f128_ps::<0x20>($a, $b),
                    _mm256_permute2f128_ps::<0x31>($a, $b),
                )
            };
        }
        // (l, l+2) within each 128-bit lane: [s2 of A, s2 of C | s2 of B, s2 of D].
        macro_rules! g {
            ($x:expr, $y:expr) => {
                _mm256_add_ps(
                    _mm256_shuffle_ps::<0x44>($x, $y),
                    _mm256_shuffle_ps::<0xEE>($x, $y),
                )
            };
        }
        // (l, l+1) within each 128-bit lane.
        macro_rules! h {
            ($x:expr, $y:expr) => {
                _mm256_add_ps(
                    _mm256_shuffle_ps::<0x88>($x, $y),
                    _mm256_shuffle_ps::<0xDD>($x, $y),
                )
            };
        }
        let zero = _mm256_setzero_ps();
        // e0 = [0 | 1], e1 = [2 | 3], e2 = [4 | 5], e3 = [6 | 7], e4 = [8 | 9].
        let e = [
            f!(s8[0], s8[1]),
            f!(s8[2], s8[3]),
            f!(s8[4], s8[5]),
            f!(s8[6], s8[7]),
            f!(s8[8], s8[9]),
        ];
        // [0, 2 | 1, 3], [4, 6 | 5, 7], [8, – | 9, –] (two values each).
        let g0 = g!(e[0], e[1]);
        let g1 = g!(e[2], e[3]);
        let g2 = g!(e[4], zero);
        // [0, 2, 4, 6 | 1, 3, 5, 7], [8, –, –, – | 9, –, –, –].
        let r0 = h!(g0, g1);
        let r1 = h!(g2, zero);
        let mut a = [0.0f32; 8];
        let mut b = [0.0f32; 8];
        _mm256_storeu_ps(a.as_mut_ptr(), r0);
        _mm256_storeu_ps(b.as_mut_ptr(), r1);
        [a[0], a[4], a[1], a[5], a[2], a[6], a[3], a[7], b[0], b[4]]
    }

    /// [`backward_gaussian_portable`] (hard cutoff) over the pixels `8·h .. 8·h + 8` of the
    /// rows in `rows`, with the lane sums in registers across rows.
    #[inline(always)]
    unsafe fn backward_half(
        h: usize,
        sp: &Splat2D,
        k: u32,
        mut rows: u16,
        tile: &mut BwdTile,
        tc: &TileCoords,
        max_alpha: f32,
    ) -> [__m256; 10] {
        let o = 8 * h;
        let zero = _mm256_setzero_ps();
        let mut acc = [zero; 10];
        let px = _mm256_load_ps(tc.px.as_ptr().add(o));
        let one = _mm256_set1_ps(1.0);
        let maxa = _mm256_set1_ps(max_alpha);
        let thr = _mm256_set1_ps(ALPHA_THRESHOLD);
        // `k < last` as a signed comparison: both are below 2³¹ (see `backward_tile_impl`).
        let kv = _mm256_set1_epi32(k as i32);
        let dx = _mm256_sub_ps(_mm256_set1_ps(sp.x), px);
        let ea = _mm256_set1_ps(RowGeom::exp_a(sp));
        let o_v = _mm256_set1_ps(sp.opacity);
        let (cr, cg, cb, cz) = (
            _mm256_set1_ps(sp.rgb[0]),
            _mm256_set1_ps(sp.rgb[1]),
            _mm256_set1_ps(sp.rgb[2]),
            _mm256_set1_ps(sp.depth),
        );
        // One row: updates its T and R (where `ok`) and evaluates to the lane sums' terms,
        // zero outside `ok`. Adding those zeros changes no sum: a sum that starts at +0 is
        // never −0, and the upstream gradients are finite. Branch-free, so that two rows
        // form one block the compiler can interleave.
        macro_rules! row_terms {
            ($ly:expr) => {{
                let ly: usize = $ly;
                let g = RowGeom::new(sp, *tc.py.get_unchecked(ly));
                let row = tile.rows.as_mut_ptr().add(ly);
                let last = _mm256_load_si256((*row).last.as_ptr().add(o) as *const __m256i);
                let u = _mm256_fmadd_ps(ea, dx, _mm256_set1_ps(g.eb));
                let ex = _mm256_fmadd_ps(u, dx, _mm256_set1_ps(g.ec));
                let gauss = gauss_v(ex);
                let raw = _mm256_mul_ps(o_v, gauss);
                let a1 = _mm256_min_ps(raw, maxa);
                let ok = _mm256_castsi256_ps(_mm256_cmpgt_epi32(last, kv));
                let ok = _mm256_and_ps(ok, _mm256_cmp_ps::<_CMP_LE_OQ>(ex, zero));
                let ok = _mm256_and_ps(ok, _mm256_cmp_ps::<_CMP_GE_OQ>(a1, thr));
                // Volatile loads: otherwise LLVM turns the blend-and-store of T and R below
                // into masked stores, which are slow (microcoded) on some AVX2 CPUs.
                let t = std::ptr::read_volatile((*row).t.as_ptr().add(o) as *const __m256);
                let r = std::ptr::read_volatile((*row).r.as_ptr().add(o) as *const __m256);
                let gr = _mm256_load_ps((*row).gc[0].as_ptr().add(o));
                let gg = _mm256_load_ps((*row).gc[1].as_ptr().add(o));
                let gb = _mm256_load_ps((*row).gc[2].as_ptr().add(o));
                let gs = _mm256_load_ps((*row).gs.as_ptr().add(o));
                let ra = _mm256_div_ps(one, _mm256_sub_ps(one, a1));
                let ti = _mm256_mul_ps(t, ra);
                let w = _mm256_and_ps(_mm256_mul_ps(a1, ti), ok);
                let gcol = _mm256_mul_ps(gr, cr);
                let gcol = _mm256_fmadd_ps(gg, cg, gcol);
                let gcol = _mm256_fmadd_ps(gb, cb, gcol);
                let gcol = _mm256_fmadd_ps(gs, cz, gcol);
                let dl = _mm256_mul_ps(_mm256_fmsub_ps(gcol, t, r), ra);
                let qm = _mm256_and_ps(ok, _mm256_cmp_ps::<_CMP_LT_OQ>(raw, maxa));
                let q = _mm256_and_ps(_mm256_mul_ps(dl, gauss), qm);
                let r_new = _mm256_blendv_ps(r, _mm256_fmadd_ps(gcol, w, r), ok);
                _mm256_store_ps((*row).r.as_mut_ptr().add(o), r_new);
                _mm256_store_ps((*row).t.as_mut_ptr().add(o), _mm256_blendv_ps(t, ti, ok));
                (q, g.dy, [gr, gg, gb, gs], w)
            }};
        }
        // Adds one row's terms to the lane sums (rows in ascending order, as the twin).
        macro_rules! accumulate {
            ($terms:expr) => {{
                let (q, gdy, gc, w) = $terms;
                acc[0] = _mm256_add_ps(acc[0], q);
                acc[2] = _mm256_fmadd_ps(q, _mm256_set1_ps(gdy), acc[2]);
                acc[5] = _mm256_fmadd_ps(q, _mm256_set1_ps(gdy * gdy), acc[5]);
                acc[6] = _mm256_fmadd_ps(gc[0], w, acc[6]);
                acc[7] = _mm256_fmadd_ps(gc[1], w, acc[7]);
                acc[8] = _mm256_fmadd_ps(gc[2], w, acc[8]);
                acc[9] = _mm256_fmadd_ps(gc[3], w, acc[9]);
            }};
        }
        // Two rows at a time: their (independent) exponentials and divisions overlap.
        while rows != 0 {
            let first = rows.trailing_zeros() as usize;
            rows &= rows - 1;
            if rows != 0 {
                let second = rows.trailing_zeros() as usize;
                rows &= rows - 1;
                let a = row_terms!(first);
                let b = row_terms!(second);
                accumulate!(a);
                accumulate!(b);
            } else {
                let a = row_terms!(first);
                accumulate!(a);
            }
        }
        // The dx-weighted sums, once per lane (as the portable twin).
        acc[1] = _mm256_mul_ps(acc[0], dx);
        acc[3] = _mm256_mul_ps(acc[1], dx);
        acc[4] = _mm256_mul_ps(acc[2], dx);
        acc
    }

    /// Marker type of the AVX2 backward kernels. The two halves of the rows are walked one
    /// after the other; each pixel's state and each lane's sums see the same operations in
    /// the same order as in the whole-row kernels.
    pub(super) struct Avx2;

    impl BackwardKernel for Avx2 {
        #[inline(always)]
        unsafe fn prefetch(p: *const Splat2D) {
            _mm_prefetch::<_MM_HINT_T0>(p as *const i8);
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
        unsafe fn backward_gaussian(
            sp: &Splat2D,
            k: u32,
            rows: u16,
            tile: &mut BwdTile,
            tc: &TileCoords,
            max_alpha: f32,
        ) -> LaneSums {
            Self::backward_halves(sp, k, rows, rows, tile, tc, max_alpha)
        }
        #[inline(always)]
        unsafe fn backward_halves(
            sp: &Splat2D,
            k: u32,
            left: u16,
            right: u16,
            tile: &mut BwdTile,
            tc: &TileCoords,
            max_alpha: f32,
        ) -> LaneSums {
            let lo = backward_half(0, sp, k, left, tile, tc, max_alpha);
            let hi = backward_half(1, sp, k, right, tile, tc, max_alpha);
            reduce10(&lo, &hi)
        }
    }
}

/// The screen-space pair gradient from the lane sums (in f64, rounded once).
#[inline(always)]
fn finish(sp: &Splat2D, s: &LaneSums) -> PairGrad {
    let f = |v: f32| v as f64;
    let (a, b, c, mo) = (f(sp.a), f(sp.b), f(sp.c), -f(sp.opacity));
    let (sx, sy) = (f(s[1]), f(s[2]));
    [
        (mo * (a * sx + b * sy)) as f32,
        (mo * (b * sx + c * sy)) as f32,
        (mo * 0.5 * f(s[3])) as f32,
        (mo * f(s[4])) as f32,
        (mo * 0.5 * f(s[5])) as f32,
        s[0],
        s[6],
        s[7],
        s[8],
        s[9],
    ]
}

/// Walks one tile back to front and hands the pair gradient of every list entry (zero where
/// the Gaussian contributes to no pixel) to `emit(k, gradient)`.
///
/// # Safety
/// The CPU must support `K`'s instruction set.
#[inline(always)]
unsafe fn backward_tile_impl<K: BackwardKernel, const SMOOTH: bool>(
    splats: &[Splat2D],
    list: &[u32],
    x0: u32,
    y0: u32,
    tile: &mut BwdTile,
    max_alpha: f32,
    emit: &mut impl FnMut(usize, PairGrad),
) {
    // List positions (and so `last` values) stay below 2³¹: the vector kernels compare them
    // as signed integers. (A tile list that long would need over 8 GiB of ranks alone.)
    assert!(list.len() < i32::MAX as usize, "tile list too long");
    let max_last = (tile.row_last.iter().copied().max().unwrap_or(0) as usize).min(list.len());
    for k in max_last..list.len() {
        emit(k, [0.0; 10]);
    }
    let tc = TileCoords::new(x0, y0);
    for k in (0..max_last).rev() {
        if k >= PREFETCH_AHEAD {
            K::prefetch(
                splats
                    .as_ptr()
                    .wrapping_add(list[k - PREFETCH_AHEAD] as usize),
            );
        }
        let kk = k as u32;
        let mut live = 0u16;
        for (ly, &m) in tile.row_last.iter().enumerate() {
            live |= ((kk < m) as u16) << ly;
        }
        let sp = &splats[list[k] as usize];
        let halves = K::half_row_masks(sp, &tc);
        let (left, right) = (halves as u16 & live, (halves >> 16) as u16 & live);
        if left | right == 0 {
            emit(k, [0.0; 10]);
            continue;
        }
        let sums = if SMOOTH {
            backward_gaussian_portable::<true>(sp, kk, left | right, tile, &tc, max_alpha)
        } else {
            K::backward_halves(sp, kk, left, right, tile, &tc, max_alpha)
        };
        emit(k, finish(sp, &sums));
    }
}

/// The portable tile kernel.
fn backward_tile_portable<const SMOOTH: bool>(
    splats: &[Splat2D],
    list: &[u32],
    x0: u32,
    y0: u32,
    tile: &mut BwdTile,
    max_alpha: f32,
    out: &mut impl FnMut(usize, PairGrad),
) {
    // SAFETY: the portable kernel has no instruction-set requirement.
    unsafe { backward_tile_impl::<Portable, SMOOTH>(splats, list, x0, y0, tile, max_alpha, out) }
}

/// The AVX2 tile kernel (the smooth cutoff runs the portable twin inside it).
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2,fma,bmi1,popcnt")]
fn backward_tile_avx2<const SMOOTH: bool>(
    splats: &[Splat2D],
    list: &[u32],
    x0: u32,
    y0: u32,
    tile: &mut BwdTile,
    max_alpha: f32,
    out: &mut impl FnMut(usize, PairGrad),
) {
    // SAFETY: this function is only compiled for, and called on, CPUs with AVX2 + FMA.
    unsafe { backward_tile_impl::<avx2::Avx2, SMOOTH>(splats, list, x0, y0, tile, max_alpha, out) }
}

/// The AVX-512 tile kernel.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx512f,avx512dq,avx512bw,fma,bmi1,popcnt")]
fn backward_tile_avx512(
    splats: &[Splat2D],
    list: &[u32],
    x0: u32,
    y0: u32,
    tile: &mut BwdTile,
    max_alpha: f32,
    out: &mut impl FnMut(usize, PairGrad),
) {
    // SAFETY: this function is only compiled for, and called on, CPUs with AVX-512F/DQ + FMA.
    unsafe {
        backward_tile_impl::<avx512::Avx512, false>(splats, list, x0, y0, tile, max_alpha, out)
    }
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
        Isa::Avx512 if !SMOOTH => {
            // SAFETY: `Isa::Avx512` is only chosen when the CPU has AVX-512F/DQ and FMA.
            unsafe { backward_tile_avx512(splats, list, x0, y0, tile, max_alpha, out) }
        }
        #[cfg(target_arch = "x86_64")]
        Isa::Avx512 | Isa::Avx2 => {
            // SAFETY: both variants imply AVX2, FMA, BMI1 and POPCNT support (every AVX-512
            // CPU has the last two).
            unsafe { backward_tile_avx2::<SMOOTH>(splats, list, x0, y0, tile, max_alpha, out) }
        }
        Isa::Portable => {
            backward_tile_portable::<SMOOTH>(splats, list, x0, y0, tile, max_alpha, out)
        }
    }
}

/// Where [`gaussian_gradients`] puts each visible Gaussian's gradients.
#[derive(Clone, Copy, PartialEq, Eq)]
enum Mode {
    /// Store them (the buffers hold zeros on entry).
    Store,
    /// Add them to the values already there (a step's running sum).
    Add,
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
    let isa = detect_isa();
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

/// The per-Gaussian destination slices of [`gaussian_gradients`].
struct GradSinks<'a> {
    means: &'a mut [[f32; 3]],
    log_scales: &'a mut [[f32; 3]],
    quats: &'a mut [[f32; 4]],
    opacity_logits: &'a mut [f32],
    sh: &'a mut [f32],
    /// The densification statistic (stored in either mode), when wanted.
    means2d_abs: Option<&'a mut [[f32; 2]]>,
    visible: &'a mut [bool],
}

/// One [`PROJECT_CHUNK`] of [`GradSinks`], starting at Gaussian `first`.
struct SinkChunk<'a> {
    first: usize,
    sinks: GradSinks<'a>,
}

/// Step 2 of the backward pass: per Gaussian (in parallel chunks), its pair slots summed in
/// f64 in a fixed order, then the projection and SH backward; results stored or added
/// (`mode`) into `sinks`.
fn gaussian_gradients(
    g: &Gaussians,
    cam: &Camera,
    out: &RenderOutput,
    pair_grads: &[PairGrad],
    sinks: GradSinks,
    mode: Mode,
) {
    let st = &out.state;
    let s = &st.settings;
    let bins = &st.bins;
    let kcoef = g.coeffs() * 3;
    let cm = CameraModel::new(cam);
    let degree = st.sh_degree;
    let active = sh::basis_len(degree) * 3;
    let (hw, hh) = (out.width as f64 * 0.5, out.height as f64 * 0.5);
    let isa = detect_isa();
    let c = PROJECT_CHUNK;
    let mut m2d = sinks.means2d_abs.map(|v| v.chunks_mut(c));
    let chunks: Vec<SinkChunk> = sinks
        .means
        .chunks_mut(c)
        .zip(sinks.log_scales.chunks_mut(c))
        .zip(sinks.quats.chunks_mut(c))
        .zip(sinks.opacity_logits.chunks_mut(c))
        .zip(sinks.sh.chunks_mut(c * kcoef.max(1)))
        .zip(sinks.visible.chunks_mut(c))
        .enumerate()
        .map(
            |(ci, (((((means, log_scales), quats), opacity_logits), sh), visible))| SinkChunk {
                first: ci * c,
                sinks: GradSinks {
                    means,
                    log_scales,
                    quats,
                    opacity_logits,
                    sh,
                    means2d_abs: m2d.as_mut().and_then(|it| it.next()),
                    visible,
                },
            },
        )
        .collect();
    chunks.into_par_iter().for_each(|ch| {
        let SinkChunk {
            first,
            sinks:
                GradSinks {
                    means: gm,
                    log_scales: gl,
                    quats: gq,
                    opacity_logits: go,
                    sh: gsh,
                    mut means2d_abs,
                    visible: gv,
                },
        } = ch;
        // The chunk's Gaussians with a non-zero screen-space gradient, with their sums.
        let mut todo: Vec<(usize, [f64; 10])> = Vec::new();
        for j in 0..gm.len() {
            let i = first + j;
            let (lo, hi) = (bins.gauss_start[i], bins.gauss_start[i + 1]);
            if lo == hi {
                continue;
            }
            let mut rg = [0.0f64; 10];
            for pg in &pair_grads[lo..hi] {
                for q in 0..10 {
                    rg[q] += pg[q] as f64;
                }
            }
            gv[j] = true;
            if let Some(g2) = means2d_abs.as_deref_mut() {
                g2[j] = [(rg[0] * hw) as f32, (rg[1] * hh) as f32];
            }
            if rg.iter().all(|v| *v == 0.0) {
                // Visible but never composited (occluded or behind saturated pixels):
                // every parameter gradient is exactly zero.
                continue;
            }
            todo.push((j, rg));
        }
        for batch in todo.chunks(LANES) {
            // A short last batch repeats its last Gaussian in the spare lanes.
            let pick = |l: usize| &batch[l.min(batch.len() - 1)];
            let mut idx = [0usize; LANES];
            let mut screen = [[0.0f64; LANES]; 10];
            for l in 0..LANES {
                let (j, rg) = pick(l);
                idx[l] = first + j;
                for q in 0..10 {
                    screen[q][l] = rg[q];
                }
            }
            let job = LaneJob {
                cm: &cm,
                g,
                idx: &idx,
                antialiased: s.antialiased,
                near: s.near as f64,
                degree,
                kcoef,
                screen: &screen,
            };
            let lg = vjp_lanes(isa, &job);
            for (l, &(j, _)) in batch.iter().enumerate() {
                let p = lg.params[l];
                let gmean = p.mean;
                let with_sh = (lg.with_sh >> l) & 1 == 1;
                let sh_grad = &lg.sh[l];
                let dst_sh = &mut gsh[j * kcoef..j * kcoef + active];
                let vals = (
                    gmean.map(|x| x as f32),
                    p.log_scale.map(|x| x as f32),
                    p.quat.map(|x| x as f32),
                    p.logit as f32,
                );
                match mode {
                    Mode::Store => {
                        gm[j] = vals.0;
                        gl[j] = vals.1;
                        gq[j] = vals.2;
                        go[j] = vals.3;
                        if with_sh {
                            dst_sh.copy_from_slice(&sh_grad[..active]);
                        }
                    }
                    Mode::Add => {
                        for (d, s) in gm[j].iter_mut().zip(vals.0) {
                            *d += s;
                        }
                        for (d, s) in gl[j].iter_mut().zip(vals.1) {
                            *d += s;
                        }
                        for (d, s) in gq[j].iter_mut().zip(vals.2) {
                            *d += s;
                        }
                        go[j] += vals.3;
                        if with_sh {
                            for (d, s) in dst_sh.iter_mut().zip(&sh_grad[..active]) {
                                *d += s;
                            }
                        }
                    }
                }
            }
        }
    });
}

/// One batch of [`vjp_lanes`]: Gaussians `idx` with their screen-space gradient sums
/// (`screen[q][lane]` in [`PairGrad`] order).
struct LaneJob<'a> {
    cm: &'a CameraModel,
    g: &'a Gaussians,
    idx: &'a [usize; LANES],
    antialiased: bool,
    near: f64,
    degree: u32,
    kcoef: usize,
    screen: &'a [[f64; LANES]; 10],
}

/// The per-Gaussian gradients of one [`LaneJob`].
struct LaneGrads {
    /// Geometry and opacity gradients (the mean's includes the SH view-direction path).
    params: [ParamGrad; LANES],
    /// dL/d(active SH coefficients), per lane.
    sh: [[f32; 48]; LANES],
    /// Lanes whose Gaussian is not at the camera centre (their SH gradients are valid).
    with_sh: Mask,
}

/// The projection and colour backward of one batch, in the lanes of `isa` (AVX-512 lanes only
/// where they are available): the same IEEE operations on every instruction set (and as the
/// scalar `sh` functions).
fn vjp_lanes(isa: Isa, job: &LaneJob) -> LaneGrads {
    #[inline(always)]
    fn run<L: Lanes>(job: &LaneJob) -> LaneGrads {
        let LaneJob {
            cm,
            g,
            idx,
            antialiased,
            near,
            degree,
            kcoef,
            screen,
        } = *job;
        let gl = ParamLanes::<L>::gather(&g.means, &g.log_scales, &g.quats, &g.opacity_logits, idx);
        let pg = ProjectedGradLanes::<L>::from_rows([
            screen[0], screen[1], screen[2], screen[3], screen[4], screen[5], screen[9],
        ]);
        let geo = project_vjp_lanes(cm, &gl, antialiased, near, &pg);
        // SH: the colour depends on the view direction normalize(mean − centre).
        let v = [
            gl.mean[0] - cm.center[0],
            gl.mean[1] - cm.center[1],
            gl.mean[2] - cm.center[2],
        ];
        let len = (v[0] * v[0] + v[1] * v[1] + v[2] * v[2]).sqrt();
        let with_sh = len.gt(c(0.0));
        let dir = [v[0] / len, v[1] / len, v[2] / len];
        let na = sh::basis_len(degree) * 3;
        let rows = sh::coef_rows(&g.sh, idx, kcoef, na);
        let cols = L::columns(&rows, na);
        let coef = |q: usize| cols[q];
        let g_color = [
            L::from_array(screen[6]),
            L::from_array(screen[7]),
            L::from_array(screen[8]),
        ];
        let mut grad_cols = [c::<L>(0.0); crate::lanes::COLUMNS];
        let gd = sh::eval_color_vjp_lanes(degree, coef, dir, g_color, |q, val| {
            grad_cols[q] = val;
        });
        let sh_grads = L::rows(&grad_cols, na);
        let dd = gd[0] * dir[0] + gd[1] * dir[1] + gd[2] * dir[2];
        let mut mean = geo.mean;
        for a in 0..3 {
            let with = mean[a] + (gd[a] - dir[a] * dd) / len;
            mean[a] = L::select(with_sh, with, mean[a]);
        }
        let geo = ParamLanes { mean, ..geo };
        LaneGrads {
            params: geo.unpack(),
            sh: sh_grads,
            with_sh,
        }
    }
    #[cfg(target_arch = "x86_64")]
    {
        #[target_feature(enable = "avx512f,avx512dq,avx2,fma")]
        fn avx512(job: &LaneJob) -> LaneGrads {
            run::<crate::lanes::avx512::Z8>(job)
        }
        #[target_feature(enable = "avx2,fma")]
        fn avx2(job: &LaneJob) -> LaneGrads {
            run::<crate::lanes::avx2::Y8>(job)
        }
        match isa {
            Isa::Avx512 if crate::lanes::wide_available() => {
                // SAFETY: AVX-512F/DQ (checked here), AVX2 and FMA (implied by
                // `Isa::Avx512`) were detected.
                return unsafe { avx512(job) };
            }
            Isa::Avx512 | Isa::Avx2 => {
                // SAFETY: both variants imply AVX2 + FMA support.
                return unsafe { avx2(job) };
            }
            Isa::Portable => {}
        }
    }
    run::<P8>(job)
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

#[cfg(test)]
mod tests {
    use super::*;
    use crate::forward::tests::random_tile_splats;

    fn tile_state(seed: u64, n: u32) -> BwdTile {
        let mut rng = augsplat_core::Rng::new(seed);
        let mut tile = BwdTile::default();
        for ly in 0..16 {
            let row = &mut tile.rows[ly];
            for l in 0..16 {
                row.last[l] = rng.below(n as u64 + 1) as u32;
                row.t[l] = rng.uniform(1e-4, 1.0) as f32;
                for ch in 0..3 {
                    row.gc[ch][l] = rng.uniform(-1.0, 1.0) as f32;
                }
                row.gs[l] = rng.uniform(-0.1, 0.1) as f32;
                row.r[l] = rng.uniform(-1.0, 1.0) as f32;
            }
            tile.row_last[ly] = row.last.iter().copied().max().unwrap();
        }
        tile
    }

    fn run(isa: Isa, smooth: bool, splats: &[Splat2D], list: &[u32]) -> Vec<u32> {
        let mut tile = tile_state(9, list.len() as u32);
        let mut out = vec![[f32::NAN; 10]; list.len()];
        let mut emit = |k: usize, v: PairGrad| out[k] = v;
        if smooth {
            backward_tile_dispatch::<true>(isa, splats, list, 0, 0, &mut tile, 0.99, &mut emit);
        } else {
            backward_tile_dispatch::<false>(isa, splats, list, 0, 0, &mut tile, 0.99, &mut emit);
        }
        assert!(
            out.iter().flatten().all(|v| v.is_finite()),
            "every entry is emitted"
        );
        let mut v: Vec<u32> = out.iter().flatten().map(|x| x.to_bits()).collect();
        for row in &tile.rows {
            v.extend(row.t.iter().map(|x| x.to_bits()));
            v.extend(row.r.iter().map(|x| x.to_bits()));
        }
        v
    }

    #[test]
    fn vector_variants_are_bit_identical_to_the_portable_kernel() {
        let splats = random_tile_splats(5, 200);
        let list: Vec<u32> = (0..200).collect();
        let mut isas = vec![];
        #[cfg(target_arch = "x86_64")]
        {
            if std::arch::is_x86_feature_detected!("avx2")
                && std::arch::is_x86_feature_detected!("fma")
            {
                isas.push(Isa::Avx2);
            }
            if crate::forward::avx512::available() {
                isas.push(Isa::Avx512);
            } else {
                eprintln!("no AVX-512 on this CPU: only the portable variants are compared");
            }
        }
        for smooth in [false, true] {
            let a = run(Isa::Portable, smooth, &splats, &list);
            assert!(a.iter().filter(|v| **v != 0).count() > 500);
            for &isa in &isas {
                assert_eq!(
                    a,
                    run(isa, smooth, &splats, &list),
                    "{isa:?} smooth {smooth}"
                );
            }
        }
    }

    #[test]
    fn tree_sum_matches_plain_sum_closely() {
        let v: [f32; 16] = std::array::from_fn(|i| (i as f32 * 0.37).sin());
        let plain: f64 = v.iter().map(|x| *x as f64).sum();
        assert!((tree_sum16(&v) as f64 - plain).abs() < 1e-6);
    }
}
