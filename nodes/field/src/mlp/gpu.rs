//! The field's MLPs on the GPU (`mlp/mlp.wgsl`): the forward products, the input gradients
//! through the transposed weights and the weight gradients, over the same channel-major
//! batches and parameter layout as the CPU ([`Mlp`]).
//!
//! Sums run in a fixed order: a layer output adds its inputs in order (with fused
//! multiply-adds); a weight gradient sums each chunk of [`WGRAD_CHUNK`] columns in order, then
//! the chunks in order. The forward and input-gradient products load their weights, and the
//! weight gradients their rows of the batches, tile by tile into workgroup memory. The same
//! inputs give the same bytes on one adapter; against the CPU,
//! which sums a weight gradient along the whole batch, the last bits differ.

use super::{LayerShape, Mlp};
use augsplat_render::gpu::{GpuBuffer, GpuContext, GpuError, ModuleSetup};

/// Columns per chunk of a weight-gradient sum (part of the GPU result's definition).
pub const WGRAD_CHUNK: u32 = 1024;

/// `mlp.wgsl`'s `NO_BIAS`.
const NO_BIAS: u32 = u32::MAX;

/// The compiled kernels of `mlp.wgsl`.
pub(crate) struct MlpKernels {
    dense: wgpu::ComputePipeline,
    wgrad_partial: wgpu::ComputePipeline,
    wgrad_partial_tiled: wgpu::ComputePipeline,
    wgrad_reduce: wgpu::ComputePipeline,
}

impl MlpKernels {
    fn new(m: ModuleSetup<'_>) -> MlpKernels {
        let extra = augsplat_render::gpu::prelude::constant_u32("WGRAD_CHUNK", WGRAD_CHUNK as u64);
        let [dense, wgrad_partial, wgrad_partial_tiled, wgrad_reduce] =
            augsplat_render::gpu::pipelines_with(
                m,
                "mlp.wgsl",
                &extra,
                include_str!("mlp.wgsl"),
                [
                    "dense",
                    "wgrad_partial",
                    "wgrad_partial_tiled",
                    "wgrad_reduce",
                ],
            );
        MlpKernels {
            dense,
            wgrad_partial,
            wgrad_partial_tiled,
            wgrad_reduce,
        }
    }
}

/// What a dense product stores.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum DenseStore {
    /// The sum.
    Linear,
    /// `max(sum, 0)` (NaN → 0).
    Relu,
    /// The sum where the mask is positive, else 0 (the ReLU backward of the layer below).
    Masked,
}

/// A batch on the GPU: `rows × ld` floats, the first `cols` columns live; `count`, when set,
/// holds a device-side column count that further bounds the live columns.
#[derive(Clone, Copy)]
pub struct GpuBatch<'a> {
    /// Row stride.
    pub ld: u32,
    /// Columns to compute.
    pub cols: u32,
    /// A one-word buffer with the live column count (set on the device).
    pub count: Option<&'a wgpu::Buffer>,
}

/// Records `y[o − o_begin + y_row0] = store(b[o] + Σ_i W(o, i) x[i])` for `o` in `outs`.
#[allow(clippy::too_many_arguments)]
fn record_dense(
    ctx: &GpuContext,
    enc: &mut augsplat_render::gpu::Encoder,
    words: [u32; 12],
    params: &wgpu::Buffer,
    x: &wgpu::Buffer,
    y: &wgpu::Buffer,
    mask: Option<&wgpu::Buffer>,
    batch: GpuBatch<'_>,
) -> Result<(), GpuError> {
    let k = ctx.kernels_of(MlpKernels::new)?;
    let u = ctx.uniform("dense layer", &words);
    // Without a device-side count the binding is never read: the input stands in for it.
    let count = batch.count.unwrap_or(x);
    ctx.dispatch(
        enc,
        &k.dense,
        &[
            (0, &u),
            (1, params),
            (2, x),
            (3, y),
            (4, mask.unwrap_or(x)),
            (5, count),
        ],
        ctx.groups(batch.cols.div_ceil(256)),
    );
    Ok(())
}

fn dense_words(
    batch: GpuBatch<'_>,
    inp: u32,
    w: (u32, u32, u32),
    b_off: u32,
    store: DenseStore,
    outs: (u32, u32),
    y_row0: u32,
) -> [u32; 12] {
    let store = match store {
        DenseStore::Linear => 0,
        DenseStore::Relu => 1,
        DenseStore::Masked => 2,
    };
    [
        inp,
        batch.cols,
        batch.ld,
        w.0,
        w.1,
        w.2,
        b_off,
        store,
        outs.0,
        outs.1,
        y_row0,
        u32::from(batch.count.is_some()),
    ]
}

/// The offsets of each layer's weights in a parameter buffer whose MLP starts at `base`.
fn layer_offsets(mlp: &Mlp, base: usize) -> Vec<usize> {
    let mut off = base;
    mlp.layers
        .iter()
        .map(|s| {
            let o = off;
            off += s.params();
            o
        })
        .collect()
}

/// An MLP whose parameters start at float `base` of the buffer `params`.
#[derive(Clone, Copy)]
pub struct GpuMlp<'a> {
    /// The layers.
    pub mlp: &'a Mlp,
    /// The parameter buffer.
    pub params: &'a wgpu::Buffer,
    /// First float of the MLP's parameters.
    pub base: usize,
}

/// Records the forward pass of an MLP on `x` (`input_dim × ld`) into `acts` (one buffer per
/// layer, `out × ld`; hidden layers ReLU, the last linear), as [`Mlp::forward`].
pub fn record_mlp_forward(
    ctx: &GpuContext,
    enc: &mut augsplat_render::gpu::Encoder,
    net: GpuMlp<'_>,
    x: &wgpu::Buffer,
    acts: &[GpuBuffer],
    batch: GpuBatch<'_>,
) -> Result<(), GpuError> {
    let GpuMlp { mlp, params, base } = net;
    let offs = layer_offsets(mlp, base);
    let nl = mlp.layers.len();
    for (l, s) in mlp.layers.iter().enumerate() {
        let input: &wgpu::Buffer = if l == 0 { x } else { &acts[l - 1] };
        let store = if l + 1 < nl {
            DenseStore::Relu
        } else {
            DenseStore::Linear
        };
        let words = dense_words(
            batch,
            s.inp as u32,
            (offs[l] as u32, s.inp as u32, 1),
            (offs[l] + s.inp * s.out) as u32,
            store,
            (0, s.out as u32),
            0,
        );
        record_dense(ctx, enc, words, params, input, &acts[l], None, batch)?;
    }
    Ok(())
}

/// Where the input gradient of an MLP goes: rows `rows` of the first layer's input gradient
/// are written to `dst` from row `row0` on.
pub struct InputGradOut<'a> {
    /// The destination batch (same row stride).
    pub dst: &'a wgpu::Buffer,
    /// Input rows to compute.
    pub rows: std::ops::Range<u32>,
    /// First destination row.
    pub row0: u32,
}

/// Records the backward pass of an MLP after [`record_mlp_forward`]: adds the weight and bias
/// gradients of the output gradient `d_out` (`output_dim × ld`, zero past the live columns)
/// to `grad` (the parameter layout of `params`) and writes each requested slice of the input
/// gradient.
#[allow(clippy::too_many_arguments)]
pub fn record_mlp_backward(
    ctx: &GpuContext,
    enc: &mut augsplat_render::gpu::Encoder,
    net: GpuMlp<'_>,
    x: &wgpu::Buffer,
    acts: &[GpuBuffer],
    d_out: &wgpu::Buffer,
    grad: &wgpu::Buffer,
    input_grads: &[InputGradOut<'_>],
    batch: GpuBatch<'_>,
) -> Result<(), GpuError> {
    let GpuMlp { mlp, params, base } = net;
    let offs = layer_offsets(mlp, base);
    let nl = mlp.layers.len();
    let widest = mlp.layers.iter().map(|s| s.out).max().unwrap_or(1) as u64;
    let bytes = 4 * widest * u64::from(batch.ld);
    let bufs = [
        ctx.storage("mlp gradient", bytes)?,
        ctx.storage("mlp gradient", bytes)?,
    ];
    let mut dy: &wgpu::Buffer = d_out;
    for l in (0..nl).rev() {
        let s = mlp.layers[l];
        let input: &wgpu::Buffer = if l == 0 { x } else { &acts[l - 1] };
        let tiles = WeightGradKernel::for_adapter(ctx);
        record_weight_grad(ctx, enc, s, (dy, input), grad, offs[l], batch, tiles)?;
        // Input gradient through the transposed weights: W(o', i') = w[i'·inp + o'].
        let w = (offs[l] as u32, 1, s.inp as u32);
        if l > 0 {
            let next = &bufs[l % 2];
            let words = dense_words(
                batch,
                s.out as u32,
                w,
                NO_BIAS,
                DenseStore::Masked,
                (0, s.inp as u32),
                0,
            );
            record_dense(ctx, enc, words, params, dy, next, Some(&acts[l - 1]), batch)?;
            dy = next;
        } else {
            for out in input_grads {
                let words = dense_words(
                    batch,
                    s.out as u32,
                    w,
                    NO_BIAS,
                    DenseStore::Linear,
                    (out.rows.start, out.rows.end.min(s.inp as u32)),
                    out.row0,
                );
                record_dense(ctx, enc, words, params, dy, out.dst, None, batch)?;
            }
        }
    }
    Ok(())
}

/// How the weight gradient's chunk sums are computed (the same bits either way).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum WeightGradKernel {
    /// One invocation per (chunk, weight), reading the batches straight from memory.
    PerWeight,
    /// 16 × 16 weights a workgroup, their rows of the batches tiled through workgroup memory.
    Tiled,
}

impl WeightGradKernel {
    /// Tiles on a GPU; one invocation per weight on a software adapter (lavapipe), where each
    /// workgroup barrier costs more than the tiles save (1,024-ray field steps: 3.6 s per
    /// weight, 4.95 s tiled; `docs/notes/benchmarks.md`).
    pub fn for_adapter(ctx: &GpuContext) -> WeightGradKernel {
        if ctx.adapter().device_type == "Cpu" {
            WeightGradKernel::PerWeight
        } else {
            WeightGradKernel::Tiled
        }
    }
}

/// Adds `Σ_c dy[o][c] x[i][c]` to the gradient of W and `Σ_c dy[o][c]` to that of b, for a
/// layer of shape `s` whose weights start at `w_off` in `grad`; `(dy, x)` are the output
/// gradient and the input batch.
#[allow(clippy::too_many_arguments)]
pub fn record_weight_grad(
    ctx: &GpuContext,
    enc: &mut augsplat_render::gpu::Encoder,
    s: LayerShape,
    (dy, x): (&wgpu::Buffer, &wgpu::Buffer),
    grad: &wgpu::Buffer,
    w_off: usize,
    batch: GpuBatch<'_>,
    kernel: WeightGradKernel,
) -> Result<(), GpuError> {
    let k = ctx.kernels_of(MlpKernels::new)?;
    let cols = batch.cols;
    if cols == 0 {
        return Ok(());
    }
    let chunks = cols.div_ceil(WGRAD_CHUNK);
    let q = (s.out * (s.inp + 1)) as u32;
    let u = ctx.uniform(
        "weight gradient",
        &[
            s.inp as u32,
            s.out as u32,
            batch.ld,
            cols,
            chunks,
            w_off as u32,
            (w_off + s.inp * s.out) as u32,
            0,
        ],
    );
    let partial = ctx.storage(
        "weight gradient chunks",
        4 * u64::from(q) * u64::from(chunks),
    )?;
    let bindings = [(2, x), (6, &*u), (7, dy), (8, &*partial)];
    match kernel {
        WeightGradKernel::PerWeight => ctx.dispatch(
            enc,
            &k.wgrad_partial,
            &bindings,
            ctx.groups((q * chunks).div_ceil(256)),
        ),
        // One workgroup per (chunk, block of 16 outputs × 16 inputs including the bias).
        WeightGradKernel::Tiled => {
            let blocks = (s.out as u32).div_ceil(16) * (s.inp as u32 + 1).div_ceil(16);
            ctx.dispatch(
                enc,
                &k.wgrad_partial_tiled,
                &bindings,
                ctx.groups(chunks * blocks),
            )
        }
    }
    ctx.dispatch(
        enc,
        &k.wgrad_reduce,
        &[(6, &u), (8, &partial), (9, grad)],
        ctx.groups(q.div_ceil(256)),
    );
    Ok(())
}
