//! The hash encoding on the GPU (`hashgrid/hashgrid.wgsl`), on the renderer's context
//! ([`GpuContext`], the same device, limits, buffer pool and error scopes as splatting): the
//! encoding and its table gradient, the CPU's maths ([`HashGrid::encode`],
//! [`HashGrid::backward_level`]).
//!
//! Two deterministic gradient sums, neither with float atomics:
//!
//! - [`record_backward`]: the (point, corner) pairs of a level are sorted by table entry with
//!   the context's stable radix sort, and each entry adds its run in (point, corner) order —
//!   the order of the CPU's point-after-point loop, so the sums round as the CPU's do;
//! - [`record_backward_fixed`] (`hashgrid_fixed.wgsl`): each term is scaled by a power of two
//!   chosen per level, rounded to an integer and added to a 64-bit accumulator with integer
//!   atomics, whose sum does not depend on the order; its range is bounded by construction.
//!   Far cheaper than the sort (`docs/notes/benchmarks.md`), one rounding per term.
//!
//! Either way the same inputs give the same bytes on one adapter, however many samples share
//! an entry.

use super::{HashGrid, PointBatch};
use crate::constants::HASH_PRIMES;
use augsplat_render::gpu::{f32_words, GpuBuffer, GpuContext, GpuError};

/// The float-atomic variant of the table gradient (`hashgrid_atomic.wgsl`), which exists only
/// to measure what the deterministic sum costs (`examples/gpu_hashgrid_cost.rs`).
#[cfg(feature = "determinism-cost")]
struct AtomicKernels {
    scatter: wgpu::ComputePipeline,
}

#[cfg(feature = "determinism-cost")]
impl AtomicKernels {
    fn new(m: augsplat_render::gpu::ModuleSetup<'_>) -> AtomicKernels {
        let src = concat!(
            include_str!("hashgrid.wgsl"),
            include_str!("hashgrid_atomic.wgsl")
        );
        let [scatter] =
            augsplat_render::gpu::pipelines(m, "hashgrid_atomic.wgsl", src, ["scatter_atomic"]);
        AtomicKernels { scatter }
    }
}

/// [`record_backward`] with float atomics instead of the sorted sum: each term is added
/// straight into its entry with a compare-exchange loop, so the sum's order (and its last
/// bits) depends on how the invocations ran. For measuring only.
#[cfg(feature = "determinism-cost")]
pub fn record_backward_atomic(
    ctx: &GpuContext,
    enc: &mut augsplat_render::gpu::Encoder,
    grid: &HashGrid,
    pts: &GpuPoints,
    d_out: &wgpu::Buffer,
    grad: &wgpu::Buffer,
) -> Result<(), GpuError> {
    check_backward_buffers(grid, pts, d_out, grad)?;
    if pts.n == 0 {
        return Ok(());
    }
    let k = ctx.kernels_of(AtomicKernels::new)?;
    for level in 0..grid.levels() {
        let params = ctx.uniform("hash grid params", &level_params(grid, level, pts));
        ctx.dispatch(
            enc,
            &k.scatter,
            &[
                (0, &params),
                (1, &pts.px),
                (2, &pts.py),
                (3, &pts.pz),
                (9, d_out),
                (12, grad),
            ],
            ctx.groups(pts.n.div_ceil(256)),
        );
    }
    Ok(())
}

/// The fixed-point table gradient (`hashgrid_fixed.wgsl` after `hashgrid.wgsl`).
struct FixedKernels {
    level_max: wgpu::ComputePipeline,
    scatter: wgpu::ComputePipeline,
    to_float: wgpu::ComputePipeline,
}

impl FixedKernels {
    fn new(m: augsplat_render::gpu::ModuleSetup<'_>) -> FixedKernels {
        let src = concat!(
            include_str!("hashgrid.wgsl"),
            include_str!("hashgrid_fixed.wgsl")
        );
        let [level_max, scatter, to_float] = augsplat_render::gpu::pipelines(
            m,
            "hashgrid_fixed.wgsl",
            src,
            ["level_max_abs", "scatter_fixed", "fixed_to_float"],
        );
        FixedKernels {
            level_max,
            scatter,
            to_float,
        }
    }
}

/// Records the table gradient of [`record_backward`] summed in 64-bit fixed point
/// (`hashgrid_fixed.wgsl`): every term is scaled by a power of two chosen per level from the
/// level's largest `|d_out|`, so that no entry's sum can overflow, rounded to an integer and
/// added with integer atomics, whose sum does not depend on the order. Deterministic, with
/// one rounding per term (about 2^-40 of the level's largest term at a million points) where
/// the sorted sum rounds as the CPU does; each entry's sum is then added to `grad`.
///
/// Returns two words per level: the bits of its largest finite `|d_out|`, and 1 where the
/// level held a value that is not finite (such terms are left out, where the CPU's sum would
/// turn NaN).
pub fn record_backward_fixed(
    ctx: &GpuContext,
    enc: &mut augsplat_render::gpu::Encoder,
    grid: &HashGrid,
    pts: &GpuPoints,
    d_out: &wgpu::Buffer,
    grad: &wgpu::Buffer,
) -> Result<GpuBuffer, GpuError> {
    check_backward_buffers(grid, pts, d_out, grad)?;
    let levels = ctx.storage("hash grid level maxima", 8 * grid.levels() as u64)?;
    if pts.n == 0 {
        return Ok(levels);
    }
    let k = ctx.kernels_of(FixedKernels::new)?;
    let fixed = ctx.storage("hash grid fixed-point sums", 8 * grid.n_params() as u64)?;
    let point_groups = ctx.groups(pts.n.div_ceil(256));
    for level in 0..grid.levels() {
        let params = ctx.uniform("hash grid params", &level_params(grid, level, pts));
        ctx.dispatch(
            enc,
            &k.level_max,
            &[(0, &params), (9, d_out), (13, &levels)],
            point_groups,
        );
        ctx.dispatch(
            enc,
            &k.scatter,
            &[
                (0, &params),
                (1, &pts.px),
                (2, &pts.py),
                (3, &pts.pz),
                (9, d_out),
                (12, &fixed),
                (13, &levels),
            ],
            point_groups,
        );
        let floats = grid.sizes[level] as u32 * grid.features() as u32;
        ctx.dispatch(
            enc,
            &k.to_float,
            &[(0, &params), (10, grad), (12, &fixed), (13, &levels)],
            ctx.groups(floats.div_ceil(256)),
        );
    }
    Ok(levels)
}

/// The compiled kernels of `hashgrid.wgsl`.
struct HashGridKernels {
    encode: wgpu::ComputePipeline,
    emit: wgpu::ComputePipeline,
    find_ranges: wgpu::ComputePipeline,
    reduce: wgpu::ComputePipeline,
}

impl HashGridKernels {
    fn new(m: augsplat_render::gpu::ModuleSetup<'_>) -> HashGridKernels {
        let [encode, emit, find_ranges, reduce] = augsplat_render::gpu::pipelines(
            m,
            "hashgrid.wgsl",
            include_str!("hashgrid.wgsl"),
            ["encode", "emit", "find_ranges", "reduce"],
        );
        HashGridKernels {
            encode,
            emit,
            find_ranges,
            reduce,
        }
    }
}

/// Points on the GPU: the coordinates of a [`PointBatch`] (`n` points) and the row stride
/// `ld` of the encoding and its gradient.
pub struct GpuPoints {
    px: GpuBuffer,
    py: GpuBuffer,
    pz: GpuBuffer,
    n: u32,
    ld: u32,
}

impl GpuPoints {
    /// Uploads the first `pts.n` coordinates of each axis.
    pub fn upload(ctx: &GpuContext, pts: PointBatch<'_>) -> Result<GpuPoints, GpuError> {
        // Pair numbers 8·i + c must fit a u32.
        if pts.n >= 1 << 29 || pts.ld > u32::MAX as usize || pts.ld < pts.n {
            return Err(GpuError::Invalid(format!(
                "{} points with row stride {}: at most 2^29 points, stride ≥ points",
                pts.n, pts.ld
            )));
        }
        let up =
            |what: &str, v: &[f32]| ctx.storage_init(what, &f32_words(v[..pts.n].iter().copied()));
        Ok(GpuPoints {
            px: up("point x", pts.px)?,
            py: up("point y", pts.py)?,
            pz: up("point z", pts.pz)?,
            n: pts.n as u32,
            ld: pts.ld as u32,
        })
    }

    /// Points already on the GPU (`n` coordinates per axis; the encoding's row stride `ld`).
    pub fn from_buffers(
        px: GpuBuffer,
        py: GpuBuffer,
        pz: GpuBuffer,
        n: usize,
        ld: usize,
    ) -> Result<GpuPoints, GpuError> {
        if n >= 1 << 29 || ld > u32::MAX as usize || ld < n || px.size() < 4 * n as u64 {
            return Err(GpuError::Invalid(format!(
                "{n} points with row stride {ld}: at most 2^29 points, stride ≥ points"
            )));
        }
        Ok(GpuPoints {
            px,
            py,
            pz,
            n: n as u32,
            ld: ld as u32,
        })
    }

    /// The x, y and z coordinate buffers.
    pub fn buffers(&self) -> [&GpuBuffer; 3] {
        [&self.px, &self.py, &self.pz]
    }

    /// Number of points.
    pub fn len(&self) -> usize {
        self.n as usize
    }

    /// Whether there are no points.
    pub fn is_empty(&self) -> bool {
        self.n == 0
    }
}

/// The words of `hashgrid.wgsl`'s `Params` for `level`.
fn level_params(grid: &HashGrid, level: usize, pts: &GpuPoints) -> Vec<u32> {
    let f = grid.features() as u32;
    vec![
        pts.n,
        pts.ld,
        grid.resolutions[level],
        grid.sizes[level] as u32,
        u32::from(grid.dense[level]),
        level as u32 * f,
        grid.offsets[level] as u32,
        f,
        8 * pts.n,
        level as u32,
        0,
        0,
        HASH_PRIMES[0],
        HASH_PRIMES[1],
        HASH_PRIMES[2],
        0,
    ]
}

/// Checks that `buf` holds at least `floats` f32 values.
fn check_len(buf: &wgpu::Buffer, floats: usize, what: &str) -> Result<(), GpuError> {
    if buf.size() < 4 * floats as u64 {
        return Err(GpuError::Invalid(format!(
            "the {what} buffer holds {} floats, {floats} needed",
            buf.size() / 4
        )));
    }
    Ok(())
}

/// Checks the buffers of a table gradient: `grad` holds the table, `d_out` the encoding.
fn check_backward_buffers(
    grid: &HashGrid,
    pts: &GpuPoints,
    d_out: &wgpu::Buffer,
    grad: &wgpu::Buffer,
) -> Result<(), GpuError> {
    check_len(grad, grid.n_params(), "table gradient")?;
    check_len(
        d_out,
        grid.output_dim() * pts.ld as usize,
        "encoding gradient",
    )
}

/// Records the encoding of `pts` from `table` ([`HashGrid::n_params`] floats) into `out`
/// (`L·F` rows of `ld`; columns past the points and values that are not finite are 0).
pub fn record_encode(
    ctx: &GpuContext,
    enc: &mut augsplat_render::gpu::Encoder,
    grid: &HashGrid,
    table: &wgpu::Buffer,
    pts: &GpuPoints,
    out: &wgpu::Buffer,
) -> Result<(), GpuError> {
    check_len(table, grid.n_params(), "table")?;
    check_len(out, grid.output_dim() * pts.ld as usize, "encoding")?;
    let k = ctx.kernels_of(HashGridKernels::new)?;
    for level in 0..grid.levels() {
        let params = ctx.uniform("hash grid params", &level_params(grid, level, pts));
        ctx.dispatch(
            enc,
            &k.encode,
            &[
                (0, &params),
                (1, &pts.px),
                (2, &pts.py),
                (3, &pts.pz),
                (4, table),
                (5, out),
            ],
            ctx.groups(pts.ld.div_ceil(256)),
        );
    }
    Ok(())
}

/// Records the table gradient of every level: for each point (in order), corner and feature,
/// `grad[entry·F + k] += w · d_out[(level·F + k)·ld + i]`, added in the CPU's order
/// ([`HashGrid::backward_level`]) by sorting the pairs by entry (see the module notes).
pub fn record_backward(
    ctx: &GpuContext,
    enc: &mut augsplat_render::gpu::Encoder,
    grid: &HashGrid,
    pts: &GpuPoints,
    d_out: &wgpu::Buffer,
    grad: &wgpu::Buffer,
) -> Result<(), GpuError> {
    check_backward_buffers(grid, pts, d_out, grad)?;
    if pts.n == 0 {
        return Ok(());
    }
    let k = ctx.kernels_of(HashGridKernels::new)?;
    let pairs = 8 * pts.n;
    let np = 4 * u64::from(pairs);
    let keys = ctx.storage("hash grid pair entries", np)?;
    let vals = ctx.storage("hash grid pair numbers", np)?;
    let keys2 = ctx.storage("hash grid pair entries (scratch)", np)?;
    let vals2 = ctx.storage("hash grid pair numbers (scratch)", np)?;
    let weights = ctx.storage("hash grid pair weights", np)?;
    let largest = grid.sizes.iter().copied().max().unwrap_or(1) as u64;
    let ranges = ctx.storage("hash grid entry runs", 8 * largest)?;
    let point_groups = ctx.groups(pts.n.div_ceil(256));
    for level in 0..grid.levels() {
        let size = grid.sizes[level] as u32;
        let params = ctx.uniform("hash grid params", &level_params(grid, level, pts));
        ctx.dispatch(
            enc,
            &k.emit,
            &[
                (0, &params),
                (1, &pts.px),
                (2, &pts.py),
                (3, &pts.pz),
                (6, &keys),
                (7, &vals),
                (8, &weights),
            ],
            point_groups,
        );
        let bits = u32::BITS - (size - 1).leading_zeros();
        let (sorted_keys, sorted_vals) =
            ctx.record_sort(enc, &keys, &vals, (&keys2, &vals2), pairs, bits)?;
        enc.clear_buffer(&ranges, 0, Some(8 * u64::from(size)));
        ctx.dispatch(
            enc,
            &k.find_ranges,
            &[(0, &params), (6, sorted_keys), (11, &ranges)],
            ctx.groups(pairs.div_ceil(256)),
        );
        ctx.dispatch(
            enc,
            &k.reduce,
            &[
                (0, &params),
                (7, sorted_vals),
                (8, &weights),
                (9, d_out),
                (10, grad),
                (11, &ranges),
            ],
            ctx.groups(size.div_ceil(256)),
        );
    }
    Ok(())
}

/// [`HashGrid::encode`] on the GPU: uploads `table` and the points, encodes, reads back `out`
/// (`L·F` rows of `pts.ld`).
pub fn encode_gpu(
    ctx: &GpuContext,
    grid: &HashGrid,
    table: &[f32],
    pts: PointBatch<'_>,
) -> Result<Vec<f32>, GpuError> {
    ctx.scoped(|| {
        let table = ctx.storage_init("hash table", &f32_words(table.iter().copied()))?;
        let points = GpuPoints::upload(ctx, pts)?;
        let len = grid.output_dim() * pts.ld;
        let out = ctx.storage("encoding", 4 * len as u64)?;
        let mut enc = ctx.encoder();
        record_encode(ctx, &mut enc, grid, &table, &points, &out)?;
        let words = ctx.read_after(enc, &[(&out, 0, len)])?;
        ctx.reclaim();
        Ok(words[0].iter().map(|w| f32::from_bits(*w)).collect())
    })
}

/// Every level's [`HashGrid::backward_level`] on the GPU: adds the table gradient of the
/// points `pts` and the encoding gradient `d_out` (`L·F` rows of `pts.ld`) to `grad`
/// ([`HashGrid::n_params`] floats), summed as [`record_backward`] sums.
pub fn backward_gpu(
    ctx: &GpuContext,
    grid: &HashGrid,
    pts: PointBatch<'_>,
    d_out: &[f32],
    grad: &mut [f32],
) -> Result<(), GpuError> {
    backward_on_gpu(ctx, grid, pts, d_out, grad, false)
}

/// [`backward_gpu`] through [`record_backward_fixed`]: a [`GpuError::Invalid`] naming the level
/// when `d_out` holds a value that is not finite.
pub fn backward_gpu_fixed(
    ctx: &GpuContext,
    grid: &HashGrid,
    pts: PointBatch<'_>,
    d_out: &[f32],
    grad: &mut [f32],
) -> Result<(), GpuError> {
    backward_on_gpu(ctx, grid, pts, d_out, grad, true)
}

/// Uploads, records the sorted (`fixed` false) or fixed-point sum, and reads `grad` back.
fn backward_on_gpu(
    ctx: &GpuContext,
    grid: &HashGrid,
    pts: PointBatch<'_>,
    d_out: &[f32],
    grad: &mut [f32],
    fixed: bool,
) -> Result<(), GpuError> {
    ctx.scoped(|| {
        let points = GpuPoints::upload(ctx, pts)?;
        let d = ctx.storage_init("encoding gradient", &f32_words(d_out.iter().copied()))?;
        let g = ctx.storage_init("table gradient", &f32_words(grad.iter().copied()))?;
        let mut enc = ctx.encoder();
        let levels = if fixed {
            Some(record_backward_fixed(ctx, &mut enc, grid, &points, &d, &g)?)
        } else {
            record_backward(ctx, &mut enc, grid, &points, &d, &g)?;
            None
        };
        let mut parts = vec![(&*g, 0, grad.len())];
        if let Some(levels) = &levels {
            parts.push((levels, 0, 2 * grid.levels()));
        }
        let words = ctx.read_after(enc, &parts)?;
        ctx.reclaim();
        if let Some(flags) = words.get(1) {
            if let Some(level) = (0..grid.levels()).find(|l| flags[2 * l + 1] != 0) {
                return Err(GpuError::Invalid(format!(
                    "the encoding gradient of level {level} holds a value that is not finite"
                )));
            }
        }
        for (v, w) in grad.iter_mut().zip(&words[0]) {
            *v = f32::from_bits(*w);
        }
        Ok(())
    })
}
