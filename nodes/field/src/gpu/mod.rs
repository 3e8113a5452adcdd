//! The radiance field on the GPU, through the splatting's wgpu context ([`GpuContext`]: the
//! same device, limits, buffer pool and error scopes): marching through the occupancy grid,
//! the hash encoding ([`crate::hashgrid::gpu`]), both MLPs ([`crate::mlp::gpu`]), volume
//! rendering with its losses and backward, the occupancy refresh and Adam — the CPU's maths
//! ([`crate::field`], [`crate::volume`], [`crate::train`]) in `field.wgsl` and `step.wgsl`.
//!
//! Determinism: every sum that reaches the weights runs in a fixed order (along a ray in
//! sample order; a weight gradient in fixed column chunks; the hash table in 64-bit fixed
//! point with integer atomics), so one adapter gives the same bytes run to run. Against the
//! CPU the last bits differ (fused multiply-adds, the order of the weight-gradient sums).
//!
//! - [`train`]: a training run ([`train::train_gpu`]), the CPU loop's twin;
//! - [`render`]: rendering cameras ([`render::render_cameras_gpu`]).

pub mod render;
pub mod train;

use crate::constants::*;
use crate::field::{Field, RayInput};
use crate::hashgrid::gpu::{record_encode, GpuPoints};
use crate::mlp::gpu::{record_mlp_forward, GpuBatch, GpuMlp};
use augsplat_render::gpu::prelude::{constant_f32, constant_u32};
use augsplat_render::gpu::{f32_words, GpuBuffer, GpuContext, GpuError, ModuleSetup, ReadTicket};

/// Floats per ray record (see `field.wgsl`).
pub const RAY_FLOATS: usize = 16;

/// Floats per ray of the per-ray outputs (see `field.wgsl`).
pub const RAY_OUT_FLOATS: usize = 12;

/// Image number of a ray that uses the mean appearance embedding.
pub const NO_IMAGE: u32 = u32::MAX;

/// Samples a pass may hold at once (about 1.1 KiB of activations each at the default widths):
/// a render batch whose rays march more is split. Lowered further where the adapter binds
/// less than a batch row of that many samples ([`sample_budget`]).
pub const SAMPLE_BUDGET: u32 = 1 << 20;

/// The most samples one pass of `field` may hold on `ctx`: [`SAMPLE_BUDGET`], or fewer where
/// the widest per-sample batch (`rows × samples` floats) would not fit one binding.
pub fn sample_budget(ctx: &GpuContext, field: &Field) -> u32 {
    let rows = [
        field.grid.output_dim(),
        field.config.hidden_width as usize,
        field.color.input_dim(),
        1 + GEO_FEAT_DIM,
        4,
    ]
    .into_iter()
    .max()
    .unwrap_or(1) as u64;
    let fit = ctx.binding_limit() / (4 * rows);
    // Rounded down to the batch stride's granularity (the rows are padded to it).
    let fit = (fit / 4096 * 4096).min(u64::from(SAMPLE_BUDGET));
    fit.max(4096) as u32
}

/// The field's own WGSL constants, from the Rust ones.
fn constants() -> String {
    let mut s = String::new();
    for (name, v) in [
        ("F_EXP_MIN", TRUNC_EXP_MIN),
        ("F_EXP_MAX", TRUNC_EXP_MAX),
        ("F_CONTRACTED_RADIUS", CONTRACTED_RADIUS),
        ("F_TRANSMITTANCE", TRANSMITTANCE_THRESHOLD),
        ("F_DEPTH_LOG_EPS", DEPTH_LOG_EPS),
        ("F_OCC_DECAY", OCCUPANCY_DECAY),
        ("F_OCC_THRESHOLD", OCCUPANCY_THRESHOLD),
    ] {
        s.push_str(&constant_f32(name, v));
    }
    for (name, v) in [
        ("F_MAX_MARCH", MAX_MARCH_ITERATIONS as u64),
        ("F_GEO", GEO_FEAT_DIM as u64),
        ("F_SH", SH_COMPONENTS as u64),
        ("F_NO_IMAGE", NO_IMAGE as u64),
    ] {
        s.push_str(&constant_u32(name, v));
    }
    s
}

/// The compiled kernels of `field.wgsl` and `step.wgsl`.
pub(crate) struct FieldKernels {
    pub(crate) march_count: wgpu::ComputePipeline,
    pub(crate) march_write: wgpu::ComputePipeline,
    pub(crate) color_input: wgpu::ComputePipeline,
    pub(crate) ray_train: wgpu::ComputePipeline,
    pub(crate) ray_render: wgpu::ComputePipeline,
    pub(crate) compact: wgpu::ComputePipeline,
    pub(crate) ray_composite: wgpu::ComputePipeline,
    pub(crate) occ_values: wgpu::ComputePipeline,
    pub(crate) occ_flags: wgpu::ComputePipeline,
    pub(crate) seg_count: wgpu::ComputePipeline,
    pub(crate) seg_gather: wgpu::ComputePipeline,
    pub(crate) seg_scatter: wgpu::ComputePipeline,
    pub(crate) seg_advance: wgpu::ComputePipeline,
    pub(crate) emb_ray: wgpu::ComputePipeline,
    pub(crate) emb_reduce: wgpu::ComputePipeline,
    pub(crate) count_nonfinite: wgpu::ComputePipeline,
    pub(crate) finish_step: wgpu::ComputePipeline,
    pub(crate) adam: wgpu::ComputePipeline,
}

impl FieldKernels {
    fn new(m: ModuleSetup<'_>) -> FieldKernels {
        let extra = constants();
        let [march_count, march_write, color_input, ray_train, ray_render, compact, ray_composite, occ_values, occ_flags, seg_count, seg_gather, seg_scatter, seg_advance] =
            augsplat_render::gpu::pipelines_with(
                m,
                "field.wgsl",
                &extra,
                include_str!("field.wgsl"),
                [
                    "march_count",
                    "march_write",
                    "color_input",
                    "ray_train",
                    "ray_render",
                    "compact",
                    "ray_composite",
                    "occ_values",
                    "occ_flags",
                    "seg_count",
                    "seg_gather",
                    "seg_scatter",
                    "seg_advance",
                ],
            );
        let [emb_ray, emb_reduce, count_nonfinite, finish_step, adam] =
            augsplat_render::gpu::pipelines_with(
                m,
                "step.wgsl",
                &extra,
                include_str!("step.wgsl"),
                [
                    "emb_ray",
                    "emb_reduce",
                    "count_nonfinite",
                    "finish_step",
                    "adam",
                ],
            );
        FieldKernels {
            march_count,
            march_write,
            color_input,
            ray_train,
            ray_render,
            compact,
            ray_composite,
            occ_values,
            occ_flags,
            seg_count,
            seg_gather,
            seg_scatter,
            seg_advance,
            emb_ray,
            emb_reduce,
            count_nonfinite,
            finish_step,
            adam,
        }
    }
}

/// The kernels on `ctx` (compiled at the first use).
pub(crate) fn kernels(ctx: &GpuContext) -> Result<std::sync::Arc<FieldKernels>, GpuError> {
    ctx.kernels_of(FieldKernels::new)
}

/// The record of one ray (`field.wgsl`): the ray, its target colour, target distance and
/// weight, and stratification jitter.
pub fn ray_record(ray: &RayInput, target: [f32; 3], depth: (f32, f32), jitter: f32) -> [f32; 16] {
    [
        ray.origin[0],
        ray.origin[1],
        ray.origin[2],
        ray.dir[0],
        ray.dir[1],
        ray.dir[2],
        ray.background[0],
        ray.background[1],
        ray.background[2],
        target[0],
        target[1],
        target[2],
        depth.0,
        depth.1,
        jitter,
        f32::from_bits(ray.image),
    ]
}

/// Per-pass settings of `field.wgsl`'s parameter block beyond the field's configuration.
#[derive(Clone, Copy, Debug, Default)]
pub(crate) struct PassSettings {
    pub(crate) n_rays: u32,
    pub(crate) ld: u32,
    pub(crate) n: u32,
    pub(crate) inv_rays: f32,
    pub(crate) depth_w: f32,
    pub(crate) depth_sigma: f32,
    pub(crate) dist_w: f32,
    pub(crate) min_color_w: f32,
    pub(crate) mode: u32,
    pub(crate) first: u32,
}

/// The words of `field.wgsl`'s `FieldParams`.
pub(crate) fn field_words(field: &Field, s: PassSettings) -> Vec<u32> {
    let c = field.config.center;
    let inv_radius = 1.0 / field.config.radius as f32;
    let e = field.config.appearance_dim;
    vec![
        (c[0] as f32).to_bits(),
        (c[1] as f32).to_bits(),
        (c[2] as f32).to_bits(),
        inv_radius.to_bits(),
        (field.config.radius as f32).to_bits(),
        (field.config.near as f32).to_bits(),
        (field.config.far as f32).to_bits(),
        field.config.contracted_step().to_bits(),
        s.n_rays,
        field.config.occupancy_resolution,
        s.ld,
        s.n,
        e,
        field.config.n_images,
        s.inv_rays.to_bits(),
        s.depth_w.to_bits(),
        s.depth_sigma.to_bits(),
        s.dist_w.to_bits(),
        s.min_color_w.to_bits(),
        field.embedding_offset as u32,
        s.mode,
        s.first,
        0,
        0,
    ]
}

/// Row stride of a batch of `n` samples: rounded up to 4,096 columns, so that batches of
/// similar sizes reuse the context's pooled buffers.
pub(crate) fn batch_stride(n: u32) -> u32 {
    n.max(1).div_ceil(4096) * 4096
}

/// A batch of rays on the GPU and the occupancy grid they march through.
#[derive(Clone, Copy)]
pub(crate) struct RayBatch<'a> {
    /// Ray records.
    pub(crate) rays: &'a wgpu::Buffer,
    /// Occupancy flags.
    pub(crate) occupied: &'a wgpu::Buffer,
    /// Rays.
    pub(crate) n_rays: u32,
}

/// The samples of a batch of rays on the GPU, after marching.
pub(crate) struct Marched {
    /// Samples.
    pub(crate) n: u32,
    /// Row stride of every per-sample batch.
    pub(crate) ld: u32,
    /// Each ray's first sample (`n_rays + 1` words; the last is `n`).
    pub(crate) starts: GpuBuffer,
    /// Marching steps per ray.
    pub(crate) steps: GpuBuffer,
    /// Positions for the hash encoding.
    pub(crate) points: GpuPoints,
    /// t, dt, m, ray per sample.
    pub(crate) samp: GpuBuffer,
}

/// Rays uploaded and counted: their buffer, each ray's first sample and steps (see
/// [`record_count`]), the samples in all, and the words of the extra parts read in the same
/// wait.
pub(crate) struct Counted {
    pub(crate) rays: GpuBuffer,
    pub(crate) starts: (GpuBuffer, GpuBuffer),
    pub(crate) n: u32,
    pub(crate) earlier: Vec<Vec<u32>>,
}

/// Uploads ray records and counts their samples through `occupied` (one wait, which also reads
/// `before`).
pub(crate) fn count_samples(
    ctx: &GpuContext,
    field: &Field,
    rays: &[[f32; RAY_FLOATS]],
    occupied: &wgpu::Buffer,
    before: &[(&wgpu::Buffer, u64, usize)],
) -> Result<Counted, GpuError> {
    count_later(ctx, field, rays, occupied, before)?.wait(ctx)
}

/// A count submitted by [`count_later`], not waited for yet.
pub(crate) struct Counting {
    rays: GpuBuffer,
    starts: (GpuBuffer, GpuBuffer),
    ticket: ReadTicket,
}

impl Counting {
    /// Waits for the count's submission alone (not for work submitted after it).
    pub(crate) fn wait(self, ctx: &GpuContext) -> Result<Counted, GpuError> {
        let mut read = self.ticket.wait(ctx)?;
        let earlier = read.split_off(1);
        Ok(Counted {
            rays: self.rays,
            starts: self.starts,
            n: read[0][0],
            earlier,
        })
    }
}

/// [`count_samples`] submitted without waiting: what is kept for the next submission goes
/// with it, and work submitted after it does not delay [`Counting::wait`].
pub(crate) fn count_later(
    ctx: &GpuContext,
    field: &Field,
    rays: &[[f32; RAY_FLOATS]],
    occupied: &wgpu::Buffer,
    before: &[(&wgpu::Buffer, u64, usize)],
) -> Result<Counting, GpuError> {
    let n_rays = rays.len() as u32;
    let buf = ctx.storage_init(
        "field rays",
        &f32_words(rays.iter().flat_map(|r| r.iter().copied())),
    )?;
    let mut enc = ctx.encoder();
    let batch = RayBatch {
        rays: &buf,
        occupied,
        n_rays,
    };
    let starts = record_count(ctx, &mut enc, field, batch)?;
    let mut parts = vec![(&*starts.0, u64::from(n_rays), 1)];
    parts.extend_from_slice(before);
    let ticket = ctx.read_later(enc, &parts)?;
    Ok(Counting {
        rays: buf,
        starts,
        ticket,
    })
}

/// Records the sample count of every ray (`march_count` and the prefix sum): `starts` then
/// holds each ray's first sample and, at `n_rays`, the total.
pub(crate) fn record_count(
    ctx: &GpuContext,
    enc: &mut augsplat_render::gpu::Encoder,
    field: &Field,
    batch: RayBatch<'_>,
) -> Result<(GpuBuffer, GpuBuffer), GpuError> {
    let RayBatch {
        rays,
        occupied: occ,
        n_rays,
    } = batch;
    let k = kernels(ctx)?;
    let starts = ctx.storage("field ray starts", 4 * (u64::from(n_rays) + 1))?;
    let steps = ctx.storage("field ray steps", 4 * u64::from(n_rays.max(1)))?;
    let words = field_words(
        field,
        PassSettings {
            n_rays,
            ..Default::default()
        },
    );
    let u = ctx.uniform("field params", &words);
    ctx.dispatch(
        enc,
        &k.march_count,
        &[(0, &u), (1, rays), (2, occ), (3, &starts), (8, &steps)],
        ctx.groups(n_rays.div_ceil(256)),
    );
    ctx.record_scan(enc, &starts, n_rays + 1)?;
    Ok((starts, steps))
}

/// Records the samples' positions and records once their count `n` is known.
pub(crate) fn record_write(
    ctx: &GpuContext,
    enc: &mut augsplat_render::gpu::Encoder,
    field: &Field,
    batch: RayBatch<'_>,
    (starts, steps): (GpuBuffer, GpuBuffer),
    n: u32,
) -> Result<Marched, GpuError> {
    let RayBatch {
        rays,
        occupied: occ,
        n_rays,
    } = batch;
    let k = kernels(ctx)?;
    let ld = batch_stride(n);
    let bytes = 4 * u64::from(ld);
    let px = ctx.storage("sample x", bytes)?;
    let py = ctx.storage("sample y", bytes)?;
    let pz = ctx.storage("sample z", bytes)?;
    let samp = ctx.storage("sample records", 4 * bytes)?;
    let words = field_words(
        field,
        PassSettings {
            n_rays,
            ld,
            n,
            ..Default::default()
        },
    );
    let u = ctx.uniform("field params", &words);
    ctx.dispatch(
        enc,
        &k.march_write,
        &[
            (0, &u),
            (1, rays),
            (2, occ),
            (3, &starts),
            (4, &px),
            (5, &py),
            (6, &pz),
            (7, &samp),
        ],
        ctx.groups(n_rays.div_ceil(256)),
    );
    let points = GpuPoints::from_buffers(px, py, pz, n as usize, ld as usize)?;
    Ok(Marched {
        n,
        ld,
        starts,
        steps,
        points,
        samp,
    })
}

/// The density network's activations over a batch of points: the encoding and each layer's
/// output (the last holds the density pre-activation in row 0, the geometry features after).
pub(crate) struct DensityPass {
    pub(crate) enc: GpuBuffer,
    pub(crate) acts: Vec<GpuBuffer>,
}

impl DensityPass {
    /// The network's output (`1 + GEO_FEAT_DIM` rows).
    pub(crate) fn out(&self) -> &GpuBuffer {
        &self.acts[self.acts.len() - 1]
    }
}

/// Records the encoding and the density network over `points` (`n` live columns of `ld`).
pub(crate) fn record_density(
    ctx: &GpuContext,
    enc: &mut augsplat_render::gpu::Encoder,
    field: &Field,
    params: &wgpu::Buffer,
    points: &GpuPoints,
    ld: u32,
    n: u32,
) -> Result<DensityPass, GpuError> {
    let lf = field.grid.output_dim() as u64;
    let code = ctx.storage("encoding", 4 * lf * u64::from(ld))?;
    record_encode(ctx, enc, &field.grid, params, points, &code)?;
    let acts = layer_buffers(ctx, &field.density, ld)?;
    let batch = GpuBatch {
        ld,
        cols: n,
        count: None,
    };
    let net = GpuMlp {
        mlp: &field.density,
        params,
        base: field.density_offset,
    };
    record_mlp_forward(ctx, enc, net, &code, &acts, batch)?;
    Ok(DensityPass { enc: code, acts })
}

/// One buffer per layer of `mlp`, `out × ld` floats.
pub(crate) fn layer_buffers(
    ctx: &GpuContext,
    mlp: &crate::mlp::Mlp,
    ld: u32,
) -> Result<Vec<GpuBuffer>, GpuError> {
    mlp.layers
        .iter()
        .map(|s| ctx.storage("mlp activations", 4 * s.out as u64 * u64::from(ld)))
        .collect()
}

/// The colour network's input and activations.
pub(crate) struct ColorPass {
    pub(crate) input: GpuBuffer,
    pub(crate) acts: Vec<GpuBuffer>,
}

/// Records the colour network's input (geometry features from the density network's output
/// `dout`, SH of the direction, embedding) and its forward pass. With `live` (compacted sample indices and their count on the
/// device) the columns are the live samples; otherwise every sample.
#[allow(clippy::too_many_arguments)]
pub(crate) fn record_color(
    ctx: &GpuContext,
    enc: &mut augsplat_render::gpu::Encoder,
    field: &Field,
    params: &wgpu::Buffer,
    rays: &wgpu::Buffer,
    marched: &Marched,
    dout: &wgpu::Buffer,
    mean_emb: &wgpu::Buffer,
    live: Option<(&wgpu::Buffer, &wgpu::Buffer)>,
) -> Result<ColorPass, GpuError> {
    let k = kernels(ctx)?;
    let ld = marched.ld;
    let rows = field.color.input_dim() as u64;
    let input = ctx.storage("colour input", 4 * rows * u64::from(ld))?;
    let words = field_words(
        field,
        PassSettings {
            ld,
            n: marched.n,
            mode: u32::from(live.is_some()),
            ..Default::default()
        },
    );
    let u = ctx.uniform("field params", &words);
    let dummy;
    let (alive, count) = match live {
        Some(l) => l,
        None => {
            dummy = ctx.storage("no compaction", 16)?;
            (&*dummy, &*dummy)
        }
    };
    ctx.dispatch(
        enc,
        &k.color_input,
        &[
            (0, &u),
            (1, rays),
            (7, &marched.samp),
            (9, dout),
            (10, params),
            (11, &input),
            (12, alive),
            (13, count),
            (14, mean_emb),
        ],
        ctx.groups(marched.n.div_ceil(256)),
    );
    let acts = layer_buffers(ctx, &field.color, ld)?;
    let batch = GpuBatch {
        ld,
        cols: marched.n,
        count: live.map(|l| l.1),
    };
    let net = GpuMlp {
        mlp: &field.color,
        params,
        base: field.color_offset,
    };
    record_mlp_forward(ctx, enc, net, &input, &acts, batch)?;
    Ok(ColorPass { input, acts })
}

/// The mean embedding as a buffer (at least one float, so it can be bound).
pub fn mean_embedding_buffer(
    ctx: &GpuContext,
    field: &Field,
    params: &[f32],
) -> Result<GpuBuffer, GpuError> {
    mean_buffer(ctx, field.mean_embedding(params))
}

/// A mean embedding (see [`Field::mean_of_embeddings`]) as a buffer of at least one float.
pub(crate) fn mean_buffer(ctx: &GpuContext, mean: Vec<f32>) -> Result<GpuBuffer, GpuError> {
    let mut m = mean;
    m.resize(m.len().max(4), 0.0);
    ctx.storage_init("mean embedding", &f32_words(m))
}

/// Occupancy flags as u32 words.
pub fn occupancy_words(occ: &crate::occupancy::OccupancyGrid) -> Vec<u32> {
    occ.occupied.iter().map(|&o| u32::from(o)).collect()
}
