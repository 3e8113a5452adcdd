//! The portable twin of the backward tile kernel and the [`BackwardKernel`] trait that the
//! instruction-set variants implement. [`backward_gaussian_portable`] states the maths of one
//! (tile, Gaussian) pair; every variant reproduces it bit for bit.

// Negated comparisons are deliberate: they also reject NaN. Index loops read best in
// small fixed-size numeric code.
#![allow(clippy::neg_cmp_op_on_partial_ord, clippy::needless_range_loop)]

use super::{sum, LaneSums, PairGrad};
use crate::constants::ALPHA_THRESHOLD;
use crate::forward::{
    gauss_of_exponent, row_mask_portable, smooth_cut, RowGeom, Splat2D, TileCoords, PREFETCH_AHEAD,
};

/// The backward state of one tile row (16 pixels).
#[derive(Clone, Copy, Default)]
#[repr(C, align(64))]
pub(super) struct BwdRow {
    /// Transmittance after the Gaussian being visited.
    pub(super) t: [f32; 16],
    /// The running "behind" sum R.
    pub(super) r: [f32; 16],
    /// Upstream dL/d(colour).
    pub(super) gc: [[f32; 16]; 3],
    /// Upstream dL/d(unnormalised depth sum).
    pub(super) gs: [f32; 16],
    /// List entries up to and including the last contributor.
    pub(super) last: [u32; 16],
}

/// The backward state of one tile.
#[derive(Default)]
pub(super) struct BwdTile {
    pub(super) rows: [BwdRow; 16],
    /// Per row, the largest `last`.
    pub(super) row_last: [u32; 16],
}

/// Tree sum of 16 lanes: (l, l+8), then (l, l+4), (l, l+2), (l, l+1) — the order the vector
/// reduction uses.
#[inline(always)]
pub(super) fn tree_sum16(v: &[f32; 16]) -> f32 {
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
pub(super) fn backward_gaussian_portable<const SMOOTH: bool>(
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
                lanes[sum::Q][l] += q;
                lanes[sum::Q_DY][l] = q.mul_add(g.dy, lanes[sum::Q_DY][l]);
                lanes[sum::Q_DY2][l] = q.mul_add(dy2, lanes[sum::Q_DY2][l]);
            }
            for ch in 0..3 {
                lanes[sum::COLOR + ch][l] = row.gc[ch][l].mul_add(w, lanes[sum::COLOR + ch][l]);
            }
            lanes[sum::DEPTH][l] = row.gs[l].mul_add(w, lanes[sum::DEPTH][l]);
            row.r[l] = gcol.mul_add(w, row.r[l]);
            row.t[l] = ti;
        }
    }
    // dx is constant along a lane, so the sums weighted by dx are formed once per lane.
    for l in 0..16 {
        let dx = sp.x - tc.px[l];
        lanes[sum::Q_DX][l] = lanes[sum::Q][l] * dx;
        lanes[sum::Q_DX2][l] = lanes[sum::Q_DX][l] * dx;
        lanes[sum::Q_DXDY][l] = lanes[sum::Q_DY][l] * dx;
    }
    let mut out = [0.0f32; 10];
    for q in 0..10 {
        out[q] = tree_sum16(&lanes[q]);
    }
    out
}

/// The two vector primitives of the backward tile loop.
pub(super) trait BackwardKernel {
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
pub(super) struct Portable;

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

/// The screen-space pair gradient from the lane sums (in f64, rounded once).
#[inline(always)]
pub(super) fn finish(sp: &Splat2D, s: &LaneSums) -> PairGrad {
    let f = |v: f32| v as f64;
    let (a, b, c, mo) = (f(sp.a), f(sp.b), f(sp.c), -f(sp.opacity));
    let (sx, sy) = (f(s[sum::Q_DX]), f(s[sum::Q_DY]));
    [
        (mo * (a * sx + b * sy)) as f32,
        (mo * (b * sx + c * sy)) as f32,
        (mo * 0.5 * f(s[sum::Q_DX2])) as f32,
        (mo * f(s[sum::Q_DXDY])) as f32,
        (mo * 0.5 * f(s[sum::Q_DY2])) as f32,
        s[sum::Q],
        s[sum::COLOR],
        s[sum::COLOR + 1],
        s[sum::COLOR + 2],
        s[sum::DEPTH],
    ]
}

/// Walks one tile back to front and hands the pair gradient of every list entry (zero where
/// the Gaussian contributes to no pixel) to `emit(k, gradient)`.
///
/// # Safety
/// The CPU must support `K`'s instruction set.
#[inline(always)]
pub(super) unsafe fn backward_tile_impl<K: BackwardKernel, const SMOOTH: bool>(
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
pub(super) fn backward_tile_portable<const SMOOTH: bool>(
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
