//! Multiresolution hash encoding (instant-ngp): `L` levels with geometrically growing
//! resolution, `F` features per table entry, a table of at most `2^T` entries per level
//! (levels whose dense grid fits are indexed densely), trilinear interpolation.
//!
//! Inputs are points in `[0, 1]³` in structure-of-arrays form; the output is channel-major
//! (`(level·F + f) × ld`), i.e. directly the first MLP layer's input batch. The backward pass
//! runs one level at a time (levels own disjoint parts of the table), so levels can be
//! processed in parallel while each level accumulates its samples in a fixed order.

use crate::constants::HASH_PRIMES;
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

/// Corner indices (entry numbers, not floats) and trilinear weights of one point at one level.
#[inline(always)]
fn corners(res: u32, size: usize, dense: bool, p: [f32; 3]) -> ([u32; 8], [f32; 8]) {
    let mut i0 = [0u32; 3];
    let mut fr = [0f32; 3];
    for a in 0..3 {
        let x = p[a].clamp(0.0, 1.0) * res as f32;
        let f = x.floor().min(res as f32 - 1.0).max(0.0);
        i0[a] = f as u32;
        fr[a] = x - f;
    }
    let mut idx = [0u32; 8];
    let mut w = [0f32; 8];
    let stride = res + 1;
    for c in 0..8u32 {
        let (bx, by, bz) = (c & 1, (c >> 1) & 1, (c >> 2) & 1);
        let (x, y, z) = (i0[0] + bx, i0[1] + by, i0[2] + bz);
        idx[c as usize] = if dense {
            x + y * stride + z * stride * stride
        } else {
            let h = x.wrapping_mul(HASH_PRIMES[0])
                ^ y.wrapping_mul(HASH_PRIMES[1])
                ^ z.wrapping_mul(HASH_PRIMES[2]);
            h & (size as u32 - 1)
        };
        let wx = if bx == 1 { fr[0] } else { 1.0 - fr[0] };
        let wy = if by == 1 { fr[1] } else { 1.0 - fr[1] };
        let wz = if bz == 1 { fr[2] } else { 1.0 - fr[2] };
        w[c as usize] = wx * wy * wz;
    }
    (idx, w)
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

    /// Encodes `n` points (`px, py, pz` in `[0, 1]`, clamped) into `out`
    /// (`(level·F + f) · ld + i`).
    #[allow(clippy::too_many_arguments)]
    pub fn encode(
        &self,
        table: &[f32],
        px: &[f32],
        py: &[f32],
        pz: &[f32],
        n: usize,
        ld: usize,
        out: &mut [f32],
    ) {
        let f = self.features();
        for lvl in 0..self.levels() {
            let t = &table[self.level_range(lvl)];
            let (res, size, dense) = (self.resolutions[lvl], self.sizes[lvl], self.dense[lvl]);
            for i in 0..n {
                let (idx, w) = corners(res, size, dense, [px[i], py[i], pz[i]]);
                let mut acc = [0f32; 8];
                for c in 0..8 {
                    let e = idx[c] as usize * f;
                    for k in 0..f {
                        acc[k] += w[c] * t[e + k];
                    }
                }
                for k in 0..f {
                    out[(lvl * f + k) * ld + i] = acc[k];
                }
            }
            for k in 0..f {
                for v in &mut out[(lvl * f + k) * ld + n..(lvl * f + k + 1) * ld] {
                    *v = 0.0;
                }
            }
        }
    }

    /// Adds the table gradient of one level: for each point `i` (in order), each corner `c`
    /// and feature `k`, `grad[idx·F + k] += w_c · d_out[(level·F + k)·ld + i]`. `grad` is the
    /// level's slice ([`HashGrid::level_range`]).
    #[allow(clippy::too_many_arguments)]
    pub fn backward_level(
        &self,
        level: usize,
        px: &[f32],
        py: &[f32],
        pz: &[f32],
        n: usize,
        ld: usize,
        d_out: &[f32],
        grad: &mut [f32],
    ) {
        let f = self.features();
        let (res, size, dense) = (
            self.resolutions[level],
            self.sizes[level],
            self.dense[level],
        );
        for i in 0..n {
            let mut d = [0f32; 8];
            let mut any = false;
            for k in 0..f {
                d[k] = d_out[(level * f + k) * ld + i];
                any |= d[k] != 0.0;
            }
            if !any {
                continue;
            }
            let (idx, w) = corners(res, size, dense, [px[i], py[i], pz[i]]);
            for c in 0..8 {
                let e = idx[c] as usize * f;
                for k in 0..f {
                    grad[e + k] += w[c] * d[k];
                }
            }
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
