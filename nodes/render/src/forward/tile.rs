//! The portable twin of the forward tile kernel and the [`ForwardKernel`] trait that the
//! instruction-set variants implement.
//!
//! A tile is processed in batches of [`BATCH`] list entries: for each entry a 16-bit *row
//! mask* (the tile rows whose pixel centres the Gaussian's α ≥ 1/255 ellipse can reach) is
//! scattered into one 64-bit set per row; each live row then walks its set front to back
//! with its 16 pixels as lanes and its state (T, colour, depth, last, active) held in
//! registers. Rows whose pixels have all stopped are dropped, and the tile ends when no row is
//! live. [`composite_row_portable`] is the compositing rule in plain Rust: the maths every
//! variant reproduces bit for bit.

// Negated comparisons are deliberate: they also reject NaN. Index loops read best in
// small fixed-size numeric code.
#![allow(clippy::neg_cmp_op_on_partial_ord, clippy::needless_range_loop)]

use super::exp2::{gauss_of_exponent, RowGeom};
use super::{smooth_cut, Splat2D, BATCH, CHORD_PAD, PREFETCH_AHEAD};
use crate::constants::{ALPHA_THRESHOLD, TRANSMITTANCE_THRESHOLD};

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
    pub(super) t: [f32; 16],
    pub(super) c: [[f32; 16]; 3],
    pub(super) d: [f32; 16],
    pub(super) last: [u32; 16],
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
pub(super) fn composite_row_portable<const SMOOTH: bool>(
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
pub(super) struct Portable;

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

/// The compositing state of one tile.
#[derive(Default)]
pub(crate) struct TileState {
    pub(super) rows: [RowState; 16],
}

/// Composites one tile front to back; returns the number of composited pairs. `active`
/// holds per row the pixels to composite (bit = column).
///
/// # Safety
/// The CPU must support `K`'s instruction set.
#[inline(always)]
pub(super) unsafe fn raster_tile_impl<K: ForwardKernel, const SMOOTH: bool>(
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
pub(super) unsafe fn raster_tile_halves_impl<K: ForwardKernel, const SMOOTH: bool>(
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
pub(super) fn raster_tile_portable<const SMOOTH: bool>(
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
