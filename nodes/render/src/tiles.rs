//! Tile binning: each visible Gaussian is listed in every 16×16 tile its bounding box
//! touches, each tile's list front to back.
//!
//! One sort: visible Gaussians are sorted once by (depth, index) — their *rank* — and the
//! per-tile lists are then filled by a counting pass in rank order, which yields exactly the
//! order of a sort of (tile, depth) keys. Tile lists hold ranks; the projected records are
//! stored in rank order so that a tile's records are read in increasing memory order.

// Negated comparisons are deliberate: they also reject NaN. Index loops read best in
// small fixed-size numeric code.
#![allow(clippy::neg_cmp_op_on_partial_ord, clippy::needless_range_loop)]

use crate::constants::TILE;
use crate::lanes::{c, Lanes, P8};
use rayon::prelude::*;

/// The tile grid of an image.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Default)]
pub struct TileGrid {
    /// Tiles per row.
    pub tiles_x: u32,
    /// Tile rows.
    pub tiles_y: u32,
}

impl TileGrid {
    /// The grid covering a `width × height` image.
    pub fn new(width: u32, height: u32) -> Self {
        TileGrid {
            tiles_x: width.div_ceil(TILE),
            tiles_y: height.div_ceil(TILE),
        }
    }
    /// Number of tiles.
    pub fn len(&self) -> usize {
        self.tiles_x as usize * self.tiles_y as usize
    }
    /// Whether the grid is empty.
    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }
    /// Tiles `[x0, x1) × [y0, y1)` touched by the box `mean2d ± radius` (gsplat's rule:
    /// floor/ceil of the box edges in tile units, clamped to the grid).
    pub fn rect(&self, mean2d: [f64; 2], radius: [i32; 2]) -> [u32; 4] {
        let r = self.rect_lanes(mean2d.map(P8::splat), radius.map(|v| P8::splat(v as f64)));
        r.map(|v| v.0[0] as u32)
    }

    /// [`TileGrid::rect`] of eight boxes (integral radii), as integral f64 lanes; a NaN edge
    /// clamps to 0.
    #[inline(always)]
    pub(crate) fn rect_lanes<L: Lanes>(&self, mean2d: [L; 2], radius: [L; 2]) -> [L; 4] {
        let ts = TILE as f64;
        let clamp = |v: L, hi: u32| v.max(c(0.0)).min(c(hi as f64));
        let (tx, ty) = (mean2d[0] / ts, mean2d[1] / ts);
        let (rx, ry) = (radius[0] / ts, radius[1] / ts);
        [
            clamp((tx - rx).floor(), self.tiles_x),
            clamp((tx + rx).ceil(), self.tiles_x),
            clamp((ty - ry).floor(), self.tiles_y),
            clamp((ty + ry).ceil(), self.tiles_y),
        ]
    }
}

/// The binned (tile, rank) pairs.
#[derive(Clone, Debug, Default)]
pub struct Bins {
    /// Tile t's list is `ranks[ranges[t]..ranges[t + 1]]`.
    pub ranges: Vec<usize>,
    /// Ranks (front-to-back index among visible Gaussians), per tile, ascending.
    pub ranks: Vec<u32>,
    /// Rank r's pairs are `pair_index[pair_start[r]..pair_start[r + 1]]`, tiles in row-major
    /// order: the positions in `ranks` where r is listed.
    pub pair_start: Vec<usize>,
    /// See `pair_start`.
    pub pair_index: Vec<u32>,
    /// List position (index into `ranks`) → *Gaussian-major* pair slot: per-pair results
    /// written at `pair_slot[pos]` lie contiguously per Gaussian, Gaussians in index order
    /// and each one's tiles in row-major order. With [`bin`] (no index map) Gaussian-major
    /// is rank-major and this is the inverse of `pair_index`.
    pub pair_slot: Vec<u32>,
    /// Gaussian i's pair slots are `gauss_start[i]..gauss_start[i + 1]` (empty when it is
    /// not visible).
    pub gauss_start: Vec<usize>,
}

/// Sorts visible Gaussians by (depth, index): returns their indices front to back.
pub fn depth_order(visible: &[u32], depth: &[f32]) -> Vec<u32> {
    let mut keys: Vec<u64> = visible
        .par_iter()
        .with_min_len(4096)
        .map(|&i| ((depth[i as usize].to_bits() as u64) << 32) | i as u64)
        .collect();
    // Depths are ≥ near > 0, so their bit patterns order like the values; keys are unique.
    keys.par_sort_unstable();
    keys.into_par_iter()
        .with_min_len(4096)
        .map(|k| k as u32)
        .collect()
}

/// Builds the per-tile lists from the tile rectangles of the ranked Gaussians (rank r is
/// Gaussian r: `pair_slot` and `gauss_start` are rank-major).
pub fn bin(grid: &TileGrid, rects: &[[u32; 4]]) -> Bins {
    let ids: Vec<u32> = (0..rects.len() as u32).collect();
    bin_indexed(grid, rects, &ids, rects.len())
}

/// Ranks per block of the parallel binning passes: about 8192, at most 64 blocks, and at
/// most 4M per-block tile counters in all (8 bytes each) for very large images. Derived from
/// the rank and tile counts only, never from the thread count (and the result does not
/// depend on it anyway: every list position is fixed by rank order).
fn rank_block(ranks: usize, tiles: usize) -> usize {
    let cap = (4 << 20) / tiles.max(1);
    let blocks = (ranks / 8192).min(64).min(cap).max(1);
    ranks.div_ceil(blocks).max(1)
}

/// Raw pointer for the disjoint writes of the binning blocks.
#[derive(Clone, Copy)]
struct SharedOut(*mut u32);

impl SharedOut {
    /// Writes `v` at `i`.
    ///
    /// # Safety
    /// `i` is in bounds and no other thread writes index `i`.
    #[inline(always)]
    unsafe fn write(self, i: usize, v: u32) {
        *self.0.add(i) = v;
    }
}

// SAFETY: the blocks write disjoint positions (see `bin_indexed`).
unsafe impl Send for SharedOut {}
// SAFETY: as above.
unsafe impl Sync for SharedOut {}

/// Builds the per-tile lists from the tile rectangles of the ranked Gaussians; `rank_id[r]`
/// is the index (below `n`) of the Gaussian of rank r, used for the Gaussian-major
/// `pair_slot` / `gauss_start`.
///
/// Blocks of consecutive ranks are counted and filled in parallel: block b's entries in
/// tile t start after the entries of blocks 0..b in that tile, which is where a serial pass
/// in rank order would put them, so the lists are exactly the serial ones.
pub fn bin_indexed(grid: &TileGrid, rects: &[[u32; 4]], rank_id: &[u32], n: usize) -> Bins {
    let ntiles = grid.len();
    let tx = grid.tiles_x as usize;
    let area = |r: &[u32; 4]| (r[1] - r[0]) as usize * (r[3] - r[2]) as usize;
    let block = rank_block(rects.len(), ntiles);
    // Per block, per tile: the block's pair count, then its first list position.
    let mut cursors: Vec<Vec<usize>> = rects
        .par_chunks(block)
        .map(|rs| {
            let mut c = vec![0usize; ntiles];
            for r in rs {
                for y in r[2]..r[3] {
                    let row = y as usize * tx;
                    for x in r[0]..r[1] {
                        c[row + x as usize] += 1;
                    }
                }
            }
            c
        })
        .collect();
    let mut ranges = vec![0usize; ntiles + 1];
    for t in 0..ntiles {
        let mut at = ranges[t];
        for c in cursors.iter_mut() {
            let count = c[t];
            c[t] = at;
            at += count;
        }
        ranges[t + 1] = at;
    }
    let total = ranges[ntiles];
    let mut pair_start = Vec::with_capacity(rects.len() + 1);
    let mut gauss_start = vec![0usize; n + 1];
    let mut acc = 0usize;
    for (rank, r) in rects.iter().enumerate() {
        pair_start.push(acc);
        acc += area(r);
        gauss_start[rank_id[rank] as usize] = area(r);
    }
    pair_start.push(acc);
    let mut acc = 0usize;
    for v in gauss_start.iter_mut() {
        let c = *v;
        *v = acc;
        acc += c;
    }
    let mut ranks = vec![0u32; total];
    let mut pair_index = vec![0u32; total];
    let mut pair_slot = vec![0u32; total];
    // pair_index is rank-major: each block owns one contiguous piece of it.
    let mut pieces: Vec<&mut [u32]> = Vec::with_capacity(cursors.len());
    let mut rest: &mut [u32] = &mut pair_index;
    for b in 0..cursors.len() {
        let lo = pair_start[b * block];
        let hi = pair_start[((b + 1) * block).min(rects.len())];
        let (piece, tail) = rest.split_at_mut(hi - lo);
        pieces.push(piece);
        rest = tail;
    }
    let (ranks_out, slot_out) = (
        SharedOut(ranks.as_mut_ptr()),
        SharedOut(pair_slot.as_mut_ptr()),
    );
    let gauss_start_ref = &gauss_start;
    cursors
        .par_iter_mut()
        .zip(pieces.into_par_iter())
        .enumerate()
        .for_each(|(b, (cursor, index_piece))| {
            let first = b * block;
            let mut k = 0usize;
            for (j, r) in rects[first..(first + block).min(rects.len())]
                .iter()
                .enumerate()
            {
                let rank = first + j;
                let mut slot = gauss_start_ref[rank_id[rank] as usize];
                for y in r[2]..r[3] {
                    let row = y as usize * tx;
                    for x in r[0]..r[1] {
                        let t = row + x as usize;
                        let pos = cursor[t];
                        cursor[t] += 1;
                        assert!(pos < total);
                        // SAFETY: `pos` < total (checked) and lies in this block's share of
                        // tile t's list, which no other block writes.
                        unsafe {
                            ranks_out.write(pos, rank as u32);
                            slot_out.write(pos, slot as u32);
                        }
                        index_piece[k] = pos as u32;
                        slot += 1;
                        k += 1;
                    }
                }
            }
        });
    Bins {
        ranges,
        ranks,
        pair_start,
        pair_index,
        pair_slot,
        gauss_start,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn gaussian_major_slots_are_a_permutation_grouped_by_gaussian_in_tile_order() {
        let grid = TileGrid::new(70, 50);
        let mut rng = augsplat_core::Rng::new(4);
        let n = 40;
        // Ranks 0..30 map to a shuffled subset of the 40 Gaussians.
        let mut ids: Vec<u32> = (0..n as u32).collect();
        for i in (1..ids.len()).rev() {
            ids.swap(i, rng.below(i as u64 + 1) as usize);
        }
        let rank_id = &ids[..30];
        let rects: Vec<[u32; 4]> = (0..30)
            .map(|_| {
                let x0 = rng.below(5) as u32;
                let y0 = rng.below(4) as u32;
                [
                    x0,
                    x0 + 1 + rng.below(5 - x0 as u64) as u32,
                    y0,
                    y0 + 1 + rng.below(4 - y0 as u64) as u32,
                ]
            })
            .collect();
        let b = bin_indexed(&grid, &rects, rank_id, n);
        let total = b.ranks.len();
        let mut seen = vec![false; total];
        for &s in &b.pair_slot {
            assert!(!seen[s as usize]);
            seen[s as usize] = true;
        }
        assert_eq!(b.gauss_start.len(), n + 1);
        assert_eq!(b.gauss_start[n], total);
        // Slot → (tile) must list each Gaussian's tiles in row-major order.
        let mut tile_of_slot = vec![usize::MAX; total];
        for t in 0..grid.len() {
            for pos in b.ranges[t]..b.ranges[t + 1] {
                tile_of_slot[b.pair_slot[pos] as usize] = t;
                let i = rank_id[b.ranks[pos] as usize] as usize;
                let s = b.pair_slot[pos] as usize;
                assert!(b.gauss_start[i] <= s && s < b.gauss_start[i + 1]);
            }
        }
        for i in 0..n {
            let tiles = &tile_of_slot[b.gauss_start[i]..b.gauss_start[i + 1]];
            assert!(tiles.windows(2).all(|w| w[0] < w[1]));
            let visible = rank_id.contains(&(i as u32));
            assert_eq!(!tiles.is_empty(), visible);
        }
    }

    /// The single-pass serial binning that the parallel blocks must reproduce.
    fn serial(grid: &TileGrid, rects: &[[u32; 4]], rank_id: &[u32], n: usize) -> Bins {
        let ntiles = grid.len();
        let tx = grid.tiles_x as usize;
        let area = |r: &[u32; 4]| (r[1] - r[0]) as usize * (r[3] - r[2]) as usize;
        let mut counts = vec![0usize; ntiles];
        let mut pair_start = vec![0usize];
        let mut gauss_start = vec![0usize; n + 1];
        for (rank, r) in rects.iter().enumerate() {
            for y in r[2]..r[3] {
                for x in r[0]..r[1] {
                    counts[y as usize * tx + x as usize] += 1;
                }
            }
            pair_start.push(pair_start[rank] + area(r));
            gauss_start[rank_id[rank] as usize] = area(r);
        }
        let mut acc = 0;
        for v in gauss_start.iter_mut() {
            let c = *v;
            *v = acc;
            acc += c;
        }
        let mut ranges = vec![0usize; ntiles + 1];
        for t in 0..ntiles {
            ranges[t + 1] = ranges[t] + counts[t];
        }
        let total = ranges[ntiles];
        let mut cursor = ranges[..ntiles].to_vec();
        let (mut ranks, mut pair_index, mut pair_slot) =
            (vec![0u32; total], vec![0u32; total], vec![0u32; total]);
        let mut k = 0;
        for (rank, r) in rects.iter().enumerate() {
            let mut slot = gauss_start[rank_id[rank] as usize];
            for y in r[2]..r[3] {
                for x in r[0]..r[1] {
                    let t = y as usize * tx + x as usize;
                    let pos = cursor[t];
                    cursor[t] += 1;
                    ranks[pos] = rank as u32;
                    pair_index[k] = pos as u32;
                    pair_slot[pos] = slot as u32;
                    slot += 1;
                    k += 1;
                }
            }
        }
        Bins {
            ranges,
            ranks,
            pair_start,
            pair_index,
            pair_slot,
            gauss_start,
        }
    }

    #[test]
    fn parallel_blocks_reproduce_the_serial_binning_for_any_thread_count() {
        let grid = TileGrid::new(200, 150);
        let mut rng = augsplat_core::Rng::new(8);
        // Enough ranks for several blocks; some Gaussians are not ranked (not visible).
        let n = 30_000;
        let mut ids: Vec<u32> = (0..n as u32).collect();
        for i in (1..ids.len()).rev() {
            ids.swap(i, rng.below(i as u64 + 1) as usize);
        }
        let rank_id = &ids[..26_000];
        assert!(rank_block(rank_id.len(), grid.len()) < rank_id.len());
        // A huge image gets fewer blocks (bounded counter memory).
        assert_eq!(rank_block(1 << 20, 1 << 20), 1 << 18);
        assert_eq!(rank_block(1 << 20, 8 << 20), 1 << 20);
        assert_eq!(rank_block(1 << 20, 1 << 17), (1 << 20) / 32);
        let rects: Vec<[u32; 4]> = (0..rank_id.len())
            .map(|_| {
                let x0 = rng.below(grid.tiles_x as u64) as u32;
                let y0 = rng.below(grid.tiles_y as u64) as u32;
                let x1 = (x0 + rng.below(3) as u32).min(grid.tiles_x);
                let y1 = (y0 + 1 + rng.below(3) as u32).min(grid.tiles_y);
                [x0, x1, y0, y1]
            })
            .collect();
        let want = serial(&grid, &rects, rank_id, n);
        for threads in [1, 2, 3] {
            let pool = rayon::ThreadPoolBuilder::new()
                .num_threads(threads)
                .build()
                .unwrap();
            let got = pool.install(|| bin_indexed(&grid, &rects, rank_id, n));
            assert_eq!(got.ranges, want.ranges);
            assert_eq!(got.ranks, want.ranks);
            assert_eq!(got.pair_start, want.pair_start);
            assert_eq!(got.pair_index, want.pair_index);
            assert_eq!(got.pair_slot, want.pair_slot);
            assert_eq!(got.gauss_start, want.gauss_start);
        }
    }
}
