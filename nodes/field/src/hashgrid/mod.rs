//! Multiresolution hash encoding (instant-ngp): `L` levels with geometrically growing
//! resolution, `F` features per table entry, a table of at most `2^T` entries per level
//! (levels whose dense grid fits are indexed densely), trilinear interpolation.
//!
//! Inputs are points in `[0, 1]³` in structure-of-arrays form; the output is channel-major
//! (`(level·F + f) × ld`), i.e. directly the first MLP layer's input batch. The backward pass
//! runs one level at a time (levels own disjoint parts of the table), so levels can be
//! processed in parallel while each level accumulates its samples in a fixed order.
//!
//! The level kernels work on blocks of 16 points: corner indices and weights of the next block
//! are computed (and, on hashed levels, prefetched) while the current block is gathered or
//! scattered. The level kernels are compiled for the portable tier and for AVX2 and chosen by
//! [`augsplat_core::simd::active`]; in the AVX2 tier the corners of every level are computed,
//! and two-feature levels blended, by the 8-lane twins in `hashgrid/avx2.rs`, with the same
//! operations in the same order as the scalar loops (the bits do not change; the tests compare
//! them). `hashgrid/gpu.rs` and `hashgrid.wgsl` are the GPU twin, on the splatting's wgpu
//! context.

#[cfg(target_arch = "x86_64")]
mod avx2;
pub mod gpu;

use crate::error::FieldError;
use serde::{Deserialize, Serialize};

/// Hyper-parameters of the encoding.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct HashGridConfig {
    /// Number of levels `L`.
    pub levels: u32,
    /// Features per entry `F` (1, 2, 4 or 8).
    pub features_per_level: u32,
    /// log2 of the maximum table size per level `T`.
    pub log2_table_size: u32,
    /// Resolution of the coarsest level.
    pub base_resolution: u32,
    /// Resolution of the finest level.
    pub max_resolution: u32,
}

impl Default for HashGridConfig {
    fn default() -> Self {
        HashGridConfig {
            levels: 16,
            features_per_level: 2,
            log2_table_size: 17,
            base_resolution: 16,
            max_resolution: 2048,
        }
    }
}

/// Per-level layout of the encoding's parameters.
#[derive(Clone, Debug, PartialEq)]
pub struct HashGrid {
    /// The configuration.
    pub config: HashGridConfig,
    /// Grid resolution per level (cells per axis).
    pub resolutions: Vec<u32>,
    /// Table entries per level.
    pub sizes: Vec<usize>,
    /// Offset (in floats) of each level's table in the parameter vector.
    pub offsets: Vec<usize>,
    /// Whether each level is indexed densely (no hashing).
    pub dense: Vec<bool>,
}

/// A batch of points for [`HashGrid::encode`] and [`HashGrid::backward_level`]: coordinates in
/// structure-of-arrays form, and the row stride of the channel-major encoding (and of its
/// gradient).
#[derive(Clone, Copy, Debug)]
pub struct PointBatch<'a> {
    /// x coordinates in `[0, 1]` (values outside are clamped, NaN counts as 0).
    pub px: &'a [f32],
    /// y coordinates in `[0, 1]`.
    pub py: &'a [f32],
    /// z coordinates in `[0, 1]`.
    pub pz: &'a [f32],
    /// Number of points (each coordinate slice holds at least this many).
    pub n: usize,
    /// Row stride of the encoding, `≥ n` (column `i` of row `r` is at `r·ld + i`).
    pub ld: usize,
}

/// The geometry of one level: what the level kernels need besides the points.
#[derive(Clone, Copy, Debug)]
struct Level {
    /// Cells per axis.
    res: u32,
    /// Table entries.
    size: usize,
}

/// Points per block in the level kernels: corner indices and weights of a block are computed
/// first (branch-free, vectorisable), then the table is gathered or scattered.
const BLOCK: usize = 16;

/// The coordinates of points `start..start + BLOCK` (zeros past `n`) and how many are real.
#[inline(always)]
fn block_positions(pts: PointBatch<'_>, start: usize) -> ([[f32; BLOCK]; 3], usize) {
    let PointBatch { px, py, pz, n, .. } = pts;
    let mut pos = [[0f32; BLOCK]; 3];
    let cnt = (n - start).min(BLOCK);
    if cnt == BLOCK {
        // Fixed-size copies compile to register moves (no libc memmove call per block).
        pos[0] = px[start..start + BLOCK].try_into().expect("block");
        pos[1] = py[start..start + BLOCK].try_into().expect("block");
        pos[2] = pz[start..start + BLOCK].try_into().expect("block");
    } else {
        // A plain loop: `copy_from_slice` of a variable length becomes a libc call.
        #[allow(clippy::manual_memcpy)]
        for l in 0..cnt {
            pos[0][l] = px[start + l];
            pos[1][l] = py[start + l];
            pos[2][l] = pz[start + l];
        }
    }
    (pos, cnt)
}

/// Corner indices (entry numbers, not floats) and trilinear weights of up to [`BLOCK`] points
/// `start..start + BLOCK` (points past `n` get index 0 and weight 0).
#[inline(always)]
fn corners_block<const DENSE: bool>(
    lv: Level,
    pts: PointBatch<'_>,
    start: usize,
    idx: &mut [[u32; BLOCK]; 8],
    w: &mut [[f32; BLOCK]; 8],
) {
    let Level { res, size } = lv;
    let r = res as f32;
    let stride = res + 1;
    let mask = size as u32 - 1;
    let (pos, cnt) = block_positions(pts, start);
    let valid: [f32; BLOCK] = std::array::from_fn(|l| if l < cnt { 1.0 } else { 0.0 });
    let mut lo = [[0u32; BLOCK]; 3];
    let mut hi = [[0u32; BLOCK]; 3];
    let mut fr = [[0f32; BLOCK]; 3];
    for a in 0..3 {
        let (m, s) = if DENSE {
            (1u32, [1u32, stride, stride * stride][a])
        } else {
            (crate::constants::HASH_PRIMES[a], 0)
        };
        for l in 0..BLOCK {
            // Clamped to [0, r]; NaN, negatives and −0 become +0 (as the AVX2 twin).
            let x = pos[a][l] * r;
            let x = if x > 0.0 { x.min(r) } else { 0.0 };
            // x ∈ [0, r] is finite and non-negative: truncation is floor; keep one cell below r.
            let i0 = x as u32;
            let i0 = if i0 >= res { res - 1 } else { i0 };
            fr[a][l] = x - i0 as f32;
            if DENSE {
                lo[a][l] = i0 * s;
                hi[a][l] = (i0 + 1) * s;
            } else {
                lo[a][l] = i0.wrapping_mul(m);
                hi[a][l] = (i0 + 1).wrapping_mul(m);
            }
        }
    }
    for c in 0..8 {
        let (bx, by, bz) = (c & 1 == 1, (c >> 1) & 1 == 1, (c >> 2) & 1 == 1);
        for l in 0..BLOCK {
            let ix = if bx { hi[0][l] } else { lo[0][l] };
            let iy = if by { hi[1][l] } else { lo[1][l] };
            let iz = if bz { hi[2][l] } else { lo[2][l] };
            let e = if DENSE {
                ix + iy + iz
            } else {
                (ix ^ iy ^ iz) & mask
            };
            idx[c][l] = if l < cnt { e } else { 0 };
            let wx = if bx { fr[0][l] } else { 1.0 - fr[0][l] };
            let wy = if by { fr[1][l] } else { 1.0 - fr[1][l] };
            let wz = if bz { fr[2][l] } else { 1.0 - fr[2][l] };
            w[c][l] = wx * wy * wz * valid[l];
        }
    }
}

/// Hints the cache about the table entries of one block (x86-64; no-op elsewhere). Only the
/// hashed levels need it: their tables are far larger than the caches and every fine-level
/// sample lands on new cache lines.
#[inline(always)]
fn prefetch_block<const F: usize>(t: &[f32], idx: &[[u32; BLOCK]; 8], cnt: usize) {
    #[cfg(target_arch = "x86_64")]
    for c in 0..8 {
        for l in 0..cnt {
            // A prefetch never faults; `wrapping_add` keeps the address computation defined.
            let p = t.as_ptr().wrapping_add(idx[c][l] as usize * F);
            // SAFETY: prefetching has no architectural effect beyond the cache.
            unsafe {
                std::arch::x86_64::_mm_prefetch::<{ std::arch::x86_64::_MM_HINT_T0 }>(
                    p as *const i8,
                )
            };
        }
    }
    #[cfg(not(target_arch = "x86_64"))]
    let _ = (t, idx, cnt);
}

/// Whether a level may use the AVX2 block kernels of `hashgrid/avx2.rs`: `allowed` (false in the
/// portable twins the tests compare with), the AVX2 tier, and a resolution whose cell
/// indices convert through `i32` exactly.
#[inline(always)]
fn simd_blocks(allowed: bool, res: u32) -> bool {
    #[cfg(target_arch = "x86_64")]
    {
        allowed
            && res < (1 << 24)
            && augsplat_core::simd::active() == augsplat_core::simd::Isa::Avx2
    }
    #[cfg(not(target_arch = "x86_64"))]
    {
        let _ = (allowed, res);
        false
    }
}

/// [`corners_block`], through its AVX2 twin when `simd` (from [`simd_blocks`]).
#[inline(always)]
fn corners<const DENSE: bool>(
    simd: bool,
    lv: Level,
    pts: PointBatch<'_>,
    start: usize,
    idx: &mut [[u32; BLOCK]; 8],
    w: &mut [[f32; BLOCK]; 8],
) {
    #[cfg(target_arch = "x86_64")]
    if simd {
        // SAFETY: `simd_blocks` allows it only in the AVX2 tier and for `res < 2²⁴`; the
        // callers pass `start < n` and `n` points.
        unsafe { avx2::corners_block::<DENSE>(lv, pts, start, idx, w) };
        return;
    }
    let _ = simd;
    corners_block::<DENSE>(lv, pts, start, idx, w)
}

/// The encode kernel with the AVX2 block kernels in the AVX2 tier.
#[inline(always)]
fn encode_level_body<const F: usize, const DENSE: bool>(
    t: &[f32],
    lv: Level,
    pts: PointBatch<'_>,
    out: &mut [f32],
) {
    encode_level_impl::<F, DENSE, true>(t, lv, pts, out)
}

/// Encodes one level of the points `pts` from its table `t` into `out` (`F` rows of `pts.ld`);
/// `GATHER` allows the AVX2 block kernels (`false`: the scalar loops only, the portable twin
/// the tests compare them with).
#[inline(always)]
fn encode_level_impl<const F: usize, const DENSE: bool, const GATHER: bool>(
    t: &[f32],
    lv: Level,
    pts: PointBatch<'_>,
    out: &mut [f32],
) {
    let (Level { res, size }, PointBatch { n, ld, .. }) = (lv, pts);
    let t = &t[..size * F];
    let simd = simd_blocks(GATHER, res);
    #[cfg(target_arch = "x86_64")]
    let gather2 = simd && F == 2 && BLOCK == 16;
    // Double-buffered corners: block b + 1 is computed and prefetched while block b is
    // gathered.
    let mut idx = [[[0u32; BLOCK]; 8]; 2];
    let mut w = [[[0f32; BLOCK]; 8]; 2];
    if n == 0 {
        return;
    }
    corners::<DENSE>(simd, lv, pts, 0, &mut idx[0], &mut w[0]);
    let mut cur = 0;
    for start in (0..n).step_by(BLOCK) {
        let next = start + BLOCK;
        if next < n {
            let (ni, nw) = (&mut idx[cur ^ 1], &mut w[cur ^ 1]);
            corners::<DENSE>(simd, lv, pts, next, ni, nw);
            if !DENSE {
                prefetch_block::<F>(t, ni, (n - next).min(BLOCK));
            }
        }
        let (idx, w) = (&idx[cur], &w[cur]);
        let cnt = (n - start).min(BLOCK);
        #[cfg(target_arch = "x86_64")]
        if gather2 && start + BLOCK <= ld {
            // SAFETY: `simd` is set only in the AVX2 tier; every index is a
            // valid entry (< size) and the output rows hold `start + BLOCK ≤ ld` columns
            // (checked: a last block that ends past the row, where `ld` is not a multiple of
            // BLOCK, takes the scalar loop).
            unsafe { avx2::gather2_block(t, idx, w, out, ld, start) };
            cur ^= 1;
            continue;
        }
        for l in 0..cnt {
            let mut acc = [0f32; F];
            for c in 0..8 {
                let e = idx[c][l] as usize * F;
                let v: &[f32; F] = t[e..e + F].try_into().expect("entry");
                for k in 0..F {
                    acc[k] += w[c][l] * v[k];
                }
            }
            for k in 0..F {
                out[k * ld + start + l] = acc[k];
            }
        }
        cur ^= 1;
    }
}

/// Adds the table gradient of one level for the points `pts` and the encoding gradient `d_out`
/// (`F` rows of `pts.ld`) to `grad`, point after point; `SIMD` allows the AVX2 corner kernel
/// (`false`: the portable twin the tests compare with).
#[inline(always)]
fn backward_level_body<const F: usize, const DENSE: bool, const SIMD: bool>(
    grad: &mut [f32],
    lv: Level,
    pts: PointBatch<'_>,
    d_out: &[f32],
) {
    let (Level { res, size }, PointBatch { n, ld, .. }) = (lv, pts);
    let grad = &mut grad[..size * F];
    let simd = simd_blocks(SIMD, res);
    let mut idx = [[[0u32; BLOCK]; 8]; 2];
    let mut w = [[[0f32; BLOCK]; 8]; 2];
    let live = |start: usize| {
        let cnt = (n - start).min(BLOCK);
        (0..F).any(|k| {
            d_out[k * ld + start..k * ld + start + cnt]
                .iter()
                .any(|&v| v != 0.0)
        })
    };
    // The next block with a non-zero gradient, from `start` on.
    let next_live = |mut start: usize| {
        while start < n && !live(start) {
            start += BLOCK;
        }
        start
    };
    let mut start = next_live(0);
    if start >= n {
        return;
    }
    corners::<DENSE>(simd, lv, pts, start, &mut idx[0], &mut w[0]);
    let mut cur = 0;
    while start < n {
        let next = next_live(start + BLOCK);
        if next < n {
            let (ni, nw) = (&mut idx[cur ^ 1], &mut w[cur ^ 1]);
            corners::<DENSE>(simd, lv, pts, next, ni, nw);
            if !DENSE {
                prefetch_block::<F>(grad, ni, (n - next).min(BLOCK));
            }
        }
        let (idx, w) = (&idx[cur], &w[cur]);
        let cnt = (n - start).min(BLOCK);
        for l in 0..cnt {
            let mut d = [0f32; F];
            for k in 0..F {
                d[k] = d_out[k * ld + start + l];
            }
            for c in 0..8 {
                let e = idx[c][l] as usize * F;
                let g: &mut [f32; F] = (&mut grad[e..e + F]).try_into().expect("entry");
                for k in 0..F {
                    g[k] += w[c][l] * d[k];
                }
            }
        }
        cur ^= 1;
        start = next;
    }
}

/// Defines a level kernel once per tier and dispatches by [`augsplat_core::simd::active`]: what
/// [`augsplat_core::multiversion!`] does, for bodies generic over `F` and `DENSE` (which that
/// macro does not take), with the same tiers and the same AVX2 feature set.
macro_rules! level_kernel {
    ($name:ident, $body:ident, $first:ident) => {
        fn $name<const F: usize, const DENSE: bool>(
            $first: &[f32],
            lv: Level,
            pts: PointBatch<'_>,
            other: &mut [f32],
        ) {
            #[cfg(target_arch = "x86_64")]
            {
                // The body compiled for AVX2 (8-lane corner computation; Rust never
                // contracts a separate multiply and add, so the bits are unchanged).
                #[target_feature(enable = "avx2,fma,bmi1,popcnt")]
                unsafe fn avx2<const F: usize, const DENSE: bool>(
                    a: &[f32],
                    lv: Level,
                    pts: PointBatch<'_>,
                    b: &mut [f32],
                ) {
                    level_kernel!(@call $body, a, lv, pts, b)
                }
                if augsplat_core::simd::active() == augsplat_core::simd::Isa::Avx2 {
                    // SAFETY: `active` returns `Avx2` only on CPUs with its features.
                    return unsafe { avx2::<F, DENSE>($first, lv, pts, other) };
                }
            }
            level_kernel!(@call $body, $first, lv, pts, other)
        }
    };
    (@call encode_level_body, $a:expr, $lv:expr, $pts:expr, $b:expr) => {
        encode_level_body::<F, DENSE>($a, $lv, $pts, $b)
    };
    (@call backward_level_body, $a:expr, $lv:expr, $pts:expr, $b:expr) => {
        backward_level_body::<F, DENSE, true>($b, $lv, $pts, $a)
    };
}

level_kernel!(encode_level, encode_level_body, table);
level_kernel!(backward_level_ro, backward_level_body, d_out);

/// Backward of one level: `grad` (mutable) first, then the level, the points and `d_out`.
#[inline]
fn backward_level<const F: usize, const DENSE: bool>(
    grad: &mut [f32],
    lv: Level,
    pts: PointBatch<'_>,
    d_out: &[f32],
) {
    backward_level_ro::<F, DENSE>(d_out, lv, pts, grad)
}

impl HashGrid {
    /// Builds the layout, checking the configuration.
    pub fn new(config: HashGridConfig) -> Result<HashGrid, FieldError> {
        let c = &config;
        if c.levels == 0 || c.levels > 32 {
            return Err(FieldError::Config(format!(
                "levels = {} must be in 1..=32",
                c.levels
            )));
        }
        if ![1, 2, 4, 8].contains(&c.features_per_level) {
            return Err(FieldError::Config(format!(
                "features_per_level = {} must be 1, 2, 4 or 8",
                c.features_per_level
            )));
        }
        if !(4..=24).contains(&c.log2_table_size) {
            return Err(FieldError::Config(format!(
                "log2_table_size = {} must be in 4..=24",
                c.log2_table_size
            )));
        }
        if c.base_resolution < 2
            || c.max_resolution < c.base_resolution
            || c.max_resolution > 1 << 20
        {
            return Err(FieldError::Config(format!(
                "resolutions {}..{} must satisfy 2 ≤ base ≤ max ≤ 2^20",
                c.base_resolution, c.max_resolution
            )));
        }
        let l = c.levels as usize;
        let growth = if l > 1 {
            ((c.max_resolution as f64).ln() - (c.base_resolution as f64).ln()) / (l - 1) as f64
        } else {
            0.0
        };
        let max_size = 1usize << c.log2_table_size;
        let f = c.features_per_level as usize;
        let mut grid = HashGrid {
            config: config.clone(),
            resolutions: Vec::with_capacity(l),
            sizes: Vec::with_capacity(l),
            offsets: Vec::with_capacity(l),
            dense: Vec::with_capacity(l),
        };
        let mut off = 0;
        for lvl in 0..l {
            let res = ((c.base_resolution as f64) * (growth * lvl as f64).exp()).floor() as u32;
            let res = res.max(2);
            let dense_size = (res as usize + 1).pow(3);
            let dense = dense_size <= max_size;
            let size = if dense { dense_size } else { max_size };
            grid.resolutions.push(res);
            grid.sizes.push(size);
            grid.dense.push(dense);
            grid.offsets.push(off);
            off += size * f;
        }
        Ok(grid)
    }

    /// Number of levels.
    pub fn levels(&self) -> usize {
        self.resolutions.len()
    }
    /// Features per level.
    pub fn features(&self) -> usize {
        self.config.features_per_level as usize
    }
    /// Width of the encoding (`L·F`).
    pub fn output_dim(&self) -> usize {
        self.levels() * self.features()
    }
    /// Total table parameters.
    pub fn n_params(&self) -> usize {
        self.offsets.last().copied().unwrap_or(0)
            + self.sizes.last().copied().unwrap_or(0) * self.features()
    }
    /// Parameter range of one level.
    pub fn level_range(&self, level: usize) -> std::ops::Range<usize> {
        self.offsets[level]..self.offsets[level] + self.sizes[level] * self.features()
    }
    /// The geometry of one level for the level kernels.
    fn level(&self, level: usize) -> Level {
        Level {
            res: self.resolutions[level],
            size: self.sizes[level],
        }
    }

    /// Encodes the points of `pts` (coordinates in `[0, 1]`, clamped) into `out`
    /// (`(level·F + f) · pts.ld + i`).
    pub fn encode(&self, table: &[f32], pts: PointBatch<'_>, out: &mut [f32]) {
        let (f, n, ld) = (self.features(), pts.n, pts.ld);
        for lvl in 0..self.levels() {
            let t = &table[self.level_range(lvl)];
            let (lv, dense) = (self.level(lvl), self.dense[lvl]);
            let o = &mut out[lvl * f * ld..(lvl + 1) * f * ld];
            match (f, dense) {
                (1, true) => encode_level::<1, true>(t, lv, pts, o),
                (1, false) => encode_level::<1, false>(t, lv, pts, o),
                (2, true) => encode_level::<2, true>(t, lv, pts, o),
                (2, false) => encode_level::<2, false>(t, lv, pts, o),
                (4, true) => encode_level::<4, true>(t, lv, pts, o),
                (4, false) => encode_level::<4, false>(t, lv, pts, o),
                (_, true) => encode_level::<8, true>(t, lv, pts, o),
                (_, false) => encode_level::<8, false>(t, lv, pts, o),
            }
            for v in o.iter_mut() {
                if !v.is_finite() {
                    *v = 0.0;
                }
            }
            for k in 0..f {
                for v in &mut o[k * ld + n..(k + 1) * ld] {
                    *v = 0.0;
                }
            }
        }
    }

    /// Adds the table gradient of one level: for each point `i` of `pts` (in order), each
    /// corner `c` and feature `k`, `grad[idx·F + k] += w_c · d_out[(level·F + k)·pts.ld + i]`.
    /// `grad` is the level's slice ([`HashGrid::level_range`]).
    pub fn backward_level(
        &self,
        level: usize,
        pts: PointBatch<'_>,
        d_out: &[f32],
        grad: &mut [f32],
    ) {
        let (f, ld) = (self.features(), pts.ld);
        let (lv, dense) = (self.level(level), self.dense[level]);
        let d = &d_out[level * f * ld..(level + 1) * f * ld];
        match (f, dense) {
            (1, true) => backward_level::<1, true>(grad, lv, pts, d),
            (1, false) => backward_level::<1, false>(grad, lv, pts, d),
            (2, true) => backward_level::<2, true>(grad, lv, pts, d),
            (2, false) => backward_level::<2, false>(grad, lv, pts, d),
            (4, true) => backward_level::<4, true>(grad, lv, pts, d),
            (4, false) => backward_level::<4, false>(grad, lv, pts, d),
            (_, true) => backward_level::<8, true>(grad, lv, pts, d),
            (_, false) => backward_level::<8, false>(grad, lv, pts, d),
        }
    }

    /// Uniform initialisation in ±[`crate::constants::GRID_INIT_RANGE`].
    pub fn init(&self, table: &mut [f32], rng: &mut augsplat_core::Rng) {
        let r = crate::constants::GRID_INIT_RANGE as f64;
        for v in table.iter_mut() {
            *v = rng.uniform(-r, r) as f32;
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use augsplat_core::Rng;

    /// Points in the unit cube with a few on the faces, corners and outside (clamped), and
    /// one NaN (mapped to 0).
    fn points(rng: &mut Rng, n: usize) -> [Vec<f32>; 3] {
        let mut p: [Vec<f32>; 3] =
            std::array::from_fn(|_| (0..n).map(|_| rng.next_f32()).collect());
        let special = [
            0.0f32,
            1.0,
            -0.25,
            1.5,
            f32::NAN,
            0.999_999_9,
            -0.0,
            f32::INFINITY,
        ];
        for (k, &v) in special.iter().enumerate() {
            if 3 * k + 2 < n {
                p[k % 3][3 * k + 2] = v;
            }
        }
        p
    }

    /// A row stride that is not a multiple of the block (here `ld = n = 1000`, whose last
    /// block ends 8 columns past the row) never writes past the output: the values just
    /// after it keep their sentinel, and the encoding is that of padded rows.
    #[test]
    fn an_unpadded_row_stride_writes_nothing_past_the_output() {
        augsplat_core::simd::for_each_isa("hash-grid encoding with ld = n = 1000", |_| {
            let mut rng = Rng::new(3);
            let grid = HashGrid::new(HashGridConfig {
                levels: 3,
                features_per_level: 2,
                log2_table_size: 10,
                base_resolution: 4,
                max_resolution: 64,
            })
            .unwrap();
            let mut table = vec![0f32; grid.n_params()];
            grid.init(&mut table, &mut rng);
            let n = 1000;
            let p = points(&mut rng, n);
            let pts = PointBatch {
                px: &p[0],
                py: &p[1],
                pz: &p[2],
                n,
                ld: n,
            };
            let rows = grid.output_dim() * n;
            let mut out = vec![-7.0f32; rows + 32];
            grid.encode(&table, pts, &mut out[..rows]);
            assert!(
                out[rows..].iter().all(|v| *v == -7.0),
                "written past the rows"
            );
            // The same values as with padded rows.
            let ld = n.div_ceil(BLOCK) * BLOCK;
            let mut padded = vec![0f32; grid.output_dim() * ld];
            grid.encode(&table, PointBatch { ld, ..pts }, &mut padded);
            for r in 0..grid.output_dim() {
                for i in 0..n {
                    assert_eq!(out[r * n + i].to_bits(), padded[r * ld + i].to_bits());
                }
            }
        });
    }

    /// The dispatched level kernels of every tier (in the AVX2 tier: the AVX2 corner and blend
    /// kernels and AVX2-compiled bodies) give exactly the bits of the portable scalar kernels,
    /// on dense and hashed levels with 1, 2, 4 and 8 features, batches that end inside a
    /// block, padded rows, and points on the faces, outside, infinite, NaN and −0.
    #[test]
    fn simd_level_kernels_match_portable_bitwise() {
        augsplat_core::simd::for_each_isa(
            "hash-grid level kernels against the scalar loop",
            |_| level_kernels_match_portable_once(),
        );
    }

    fn level_kernels_match_portable_once() {
        let mut rng = Rng::new(31);
        for f in [2u32, 1, 4, 8] {
            let grid = HashGrid::new(HashGridConfig {
                levels: 6,
                features_per_level: f,
                log2_table_size: 10,
                base_resolution: 4,
                max_resolution: 200,
            })
            .unwrap();
            assert!(grid.dense[0] && !grid.dense[5], "dense and hashed levels");
            let table: Vec<f32> = (0..grid.n_params())
                .map(|_| rng.uniform(-1.0, 1.0) as f32)
                .collect();
            for n in [1usize, 16, 37, 300] {
                let ld = n.div_ceil(16) * 16 + 16;
                let [px, py, pz] = points(&mut rng, n);
                let fd = f as usize;
                let pts = PointBatch {
                    px: &px,
                    py: &py,
                    pz: &pz,
                    n,
                    ld,
                };
                let mut got = vec![f32::NAN; grid.output_dim() * ld];
                grid.encode(&table, pts, &mut got);
                let d_out: Vec<f32> = (0..grid.output_dim() * ld)
                    .map(|k| {
                        if k % ld < n && k % 7 != 3 {
                            rng.uniform(-1.0, 1.0) as f32
                        } else {
                            0.0
                        }
                    })
                    .collect();
                for lvl in 0..grid.levels() {
                    let t = &table[grid.level_range(lvl)];
                    let (lv, size, dense) = (grid.level(lvl), grid.sizes[lvl], grid.dense[lvl]);
                    let mut want = vec![0f32; fd * ld];
                    macro_rules! enc {
                        ($f:literal) => {
                            if dense {
                                encode_level_impl::<$f, true, false>(t, lv, pts, &mut want)
                            } else {
                                encode_level_impl::<$f, false, false>(t, lv, pts, &mut want)
                            }
                        };
                    }
                    match fd {
                        1 => enc!(1),
                        2 => enc!(2),
                        4 => enc!(4),
                        _ => enc!(8),
                    }
                    for v in want.iter_mut() {
                        if !v.is_finite() {
                            *v = 0.0;
                        }
                    }
                    for k in 0..fd {
                        for c in 0..n {
                            let (g, e) = (got[(lvl * fd + k) * ld + c], want[k * ld + c]);
                            assert_eq!(
                                g.to_bits(),
                                e.to_bits(),
                                "encode F={f} n={n} level {lvl} channel {k} point {c}: {g} vs {e}"
                            );
                        }
                    }
                    // Backward: dispatched against the portable body.
                    let mut g1 = vec![0.5f32; size * fd];
                    let mut g2 = g1.clone();
                    let d = &d_out[lvl * fd * ld..(lvl + 1) * fd * ld];
                    grid.backward_level(lvl, pts, &d_out, &mut g1);
                    macro_rules! bwd {
                        ($f:literal) => {
                            if dense {
                                backward_level_body::<$f, true, false>(&mut g2, lv, pts, d)
                            } else {
                                backward_level_body::<$f, false, false>(&mut g2, lv, pts, d)
                            }
                        };
                    }
                    match fd {
                        1 => bwd!(1),
                        2 => bwd!(2),
                        4 => bwd!(4),
                        _ => bwd!(8),
                    }
                    let bits = |v: &[f32]| v.iter().map(|x| x.to_bits()).collect::<Vec<_>>();
                    assert_eq!(bits(&g1), bits(&g2), "backward F={f} n={n} level {lvl}");
                }
            }
        }
    }
}
