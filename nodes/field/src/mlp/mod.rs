//! Small dense layers over channel-major (structure-of-arrays) batches.
//!
//! A batch of `n` activations with `c` channels is stored as `c` rows of `ld` floats
//! (`ld` = `n` rounded up to [`LANES`]; padding columns are kept at zero by the callers'
//! loss gradients, so they never leak into weight gradients). A layer is then a small matrix
//! product `Y = W X + b` whose inner loop runs along the batch and vectorises.
//!
//! [`Mlp::forward`] and [`Mlp::backward`] walk the batch in blocks of [`COLUMN_BLOCK`]
//! columns through all layers, so a block's activations stay in cache between layers.
//!
//! Every kernel sums in a fixed order that depends neither on block sizes nor on how the batch
//! is cut into column blocks: a layer output is `b + Σ_i w_i x_i` in `i` order; a weight
//! gradient is the sequential sum over the batch columns in order; a bias gradient sums 16
//! lane-strided partial sums (lane `l` takes columns `≡ l mod 16`, in order) and combines them
//! pairwise. Results are therefore bit-identical for any thread count on one machine.
//!
//! # Implementations
//!
//! - `portable.rs`: the portable twin, plain Rust over 16-lane column vectors, generic over
//!   fusing its multiply-adds;
//! - `avx2.rs` (x86-64): register-blocked AVX2 + FMA kernels that use fused multiply-adds in
//!   exactly the order above (tested bit for bit against the portable kernels run with fused
//!   multiply-adds);
//! - `dispatch.rs`: the choice by [`augsplat_core::simd::active`]. The portable tier runs the
//!   portable kernels *without* fused multiply-adds (so `AUGSPLAT_ISA=portable` or a CPU
//!   without AVX2 may differ from the AVX2 tier in the last bits).
//!
//! Every tier's kernels take the same arguments: a `Gemm` (weights, bias, input batch, shape,
//! store mode) with the output batch for the forward-style products, a `WeightGrad` (output
//! gradient, input batch, shape) with the accumulators for the weight gradients.
//!
//! An f64 reference lives in [`crate::reference`].

#[cfg(target_arch = "x86_64")]
mod avx2;
mod dispatch;
pub mod gpu;
mod portable;
#[cfg(test)]
mod tests;

use dispatch::{pad_weights, product, transpose_weights, unpad_weights, weight_grad};

/// Batch padding granularity: 16 floats (two AVX2 registers; the bias gradient keeps 16 lane
/// sums).
pub const LANES: usize = 16;

/// Columns per block in [`Mlp::forward`] / [`Mlp::backward`] (a multiple of [`LANES`]).
pub const COLUMN_BLOCK: usize = 512;

/// `n` rounded up to a multiple of [`LANES`].
pub fn padded(n: usize) -> usize {
    n.div_ceil(LANES) * LANES
}

/// What a forward-style kernel applies when it stores an output.
#[derive(Clone, Copy, Debug)]
pub(crate) enum Store<'a> {
    /// `y = acc`.
    Linear,
    /// `y = max(acc, 0)` (NaN → 0).
    Relu,
    /// `y = acc` where `mask > 0`, else 0: the ReLU backward through the layer below. The mask
    /// (that layer's post-activation output) has its rows the given stride apart.
    MaskPositive(&'a [f32], usize),
}

/// The operands of a forward-style dense-layer product over the columns `< ncols` of
/// channel-major batches: `y[o][c] = store(b[o] + Σ_i w[o·inp + i] · x[i][c])`. Every tier's
/// kernel takes one, with the output batch and its row stride beside it.
#[derive(Clone, Copy, Debug)]
pub(crate) struct Gemm<'a> {
    /// Weights, `out × inp` row-major.
    pub(crate) w: &'a [f32],
    /// Biases (`out` of them); none adds nothing.
    pub(crate) b: Option<&'a [f32]>,
    /// Input batch: `inp` rows of `ldx` floats.
    pub(crate) x: &'a [f32],
    /// Row stride of `x`.
    pub(crate) ldx: usize,
    /// Input width (rows of `x`).
    pub(crate) inp: usize,
    /// Output width (rows of `y`).
    pub(crate) out: usize,
    /// Columns to compute (a multiple of [`LANES`]).
    pub(crate) ncols: usize,
    /// What is applied when an output is stored.
    pub(crate) store: Store<'a>,
}

/// The operands of a weight-gradient accumulation over the columns `< ncols`: `dw[o][i] +=
/// Σ_c dy[o][c] · x[i][c]` (into accumulators padded to `inp` rounded up to [`LANES`]) and the
/// bias lane sums of `dy`. Every tier's kernel takes one, with the accumulators and the
/// transpose scratch beside it.
#[derive(Clone, Copy, Debug)]
pub(crate) struct WeightGrad<'a> {
    /// Output gradient: `out` rows of `lddy` floats.
    pub(crate) dy: &'a [f32],
    /// Row stride of `dy`.
    pub(crate) lddy: usize,
    /// Input batch: `inp` rows of `ldx` floats.
    pub(crate) x: &'a [f32],
    /// Row stride of `x`.
    pub(crate) ldx: usize,
    /// Input width (rows of `x`).
    pub(crate) inp: usize,
    /// Output width (rows of `dy`).
    pub(crate) out: usize,
    /// Columns to sum over (a multiple of [`LANES`]).
    pub(crate) ncols: usize,
}

/// `y[o] = act(b[o] + Σ_i w[o·inp + i] · x[i])` for every column of a channel-major batch
/// (`x`: `inp × ld`, `y`: `out × ld`, `w`: `out × inp` row-major, with `inp`, `out` from
/// `shape`). `act` is ReLU when `relu`, else identity. `ld` must be a multiple of [`LANES`].
/// Each output sums over `i` in order, so block sizes do not change the result.
pub fn linear_forward(
    w: &[f32],
    b: Option<&[f32]>,
    x: &[f32],
    y: &mut [f32],
    shape: LayerShape,
    ld: usize,
    relu: bool,
) {
    let store = if relu { Store::Relu } else { Store::Linear };
    let LayerShape { inp, out } = shape;
    let g = Gemm {
        w,
        b,
        x,
        ldx: ld,
        inp,
        out,
        ncols: ld,
        store,
    };
    product(g, y, ld)
}

/// Weight gradients of a layer: `dw[o·inp + i] += Σ_n dy[o][n] · x[i][n]` (the sequential sum
/// over the columns, after the existing value) and `db[o] += Σ_n dy[o][n]` (16 lane sums
/// combined pairwise), with `inp`, `out` from `shape`.
pub fn linear_backward_weights(
    dy: &[f32],
    x: &[f32],
    dw: &mut [f32],
    db: &mut [f32],
    shape: LayerShape,
    ld: usize,
) {
    let LayerShape { inp, out } = shape;
    assert!(
        dw.len() >= inp * out && db.len() >= out,
        "dense-layer kernel: gradient buffers too short"
    );
    let inp_pad = inp.div_ceil(LANES) * LANES;
    let mut dwp = vec![0f32; out * inp_pad];
    let mut lane_sums = vec![0f32; out * LANES];
    pad_weights(dw, &mut dwp, inp, out);
    let mut xt = Vec::new();
    let g = WeightGrad {
        dy,
        lddy: ld,
        x,
        ldx: ld,
        inp,
        out,
        ncols: ld,
    };
    weight_grad(g, &mut dwp, &mut lane_sums, &mut xt);
    unpad_weights(&dwp, &lane_sums, dw, &mut db[..out], inp);
}

/// Input gradient of a layer: `dx[i] = Σ_o w[o·inp + i] · dy[o]` per column (`inp`, `out`
/// from `shape`). `wt` is scratch that receives the transposed weights.
pub fn linear_backward_input(
    w: &[f32],
    dy: &[f32],
    dx: &mut [f32],
    shape: LayerShape,
    ld: usize,
    wt: &mut Vec<f32>,
) {
    linear_backward_input_masked(w, dy, dx, shape, ld, wt, None)
}

/// [`linear_backward_input`] followed by [`relu_backward`] with `mask` (the post-activation
/// output of the layer below, laid out like `dx`), fused into the kernel's store.
pub fn linear_backward_input_masked(
    w: &[f32],
    dy: &[f32],
    dx: &mut [f32],
    shape: LayerShape,
    ld: usize,
    wt: &mut Vec<f32>,
    mask: Option<&[f32]>,
) {
    let LayerShape { inp, out } = shape;
    assert!(
        w.len() >= inp * out,
        "dense-layer kernel: weights too short"
    );
    wt.clear();
    wt.resize(inp * out, 0.0);
    transpose_weights(w, wt, inp, out);
    let store = match mask {
        Some(m) => Store::MaskPositive(m, ld),
        None => Store::Linear,
    };
    // The transposed product: `out` gradient rows in, `inp` rows out.
    let g = Gemm {
        w: wt,
        b: None,
        x: dy,
        ldx: ld,
        inp: out,
        out: inp,
        ncols: ld,
        store,
    };
    product(g, dx, ld)
}

/// Multiplies `d` by the ReLU derivative read from the layer's post-activation output `y`
/// (`y > 0`).
pub fn relu_backward(d: &mut [f32], y: &[f32]) {
    for (d, &y) in d.iter_mut().zip(y) {
        *d = if y > 0.0 { *d } else { 0.0 };
    }
}

/// Shape of one dense layer.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct LayerShape {
    /// Input width.
    pub inp: usize,
    /// Output width.
    pub out: usize,
}

impl LayerShape {
    /// Parameters: weights then biases.
    pub fn params(&self) -> usize {
        self.inp * self.out + self.out
    }
}

/// A multilayer perceptron: ReLU after every layer but the last (linear output).
#[derive(Clone, Debug, PartialEq)]
pub struct Mlp {
    /// The layers, first to last.
    pub layers: Vec<LayerShape>,
}

/// A forward pass of an [`Mlp`] for [`Mlp::backward`] to differentiate: what
/// [`Mlp::forward`] read and what it left.
#[derive(Clone, Copy, Debug)]
pub struct ForwardPass<'a> {
    /// The parameters (weights then biases, layer after layer).
    pub params: &'a [f32],
    /// The input batch (`inp × ld`).
    pub x: &'a [f32],
    /// The layer outputs [`Mlp::forward`] wrote.
    pub acts: &'a [Vec<f32>],
    /// Row stride of the batches (a multiple of [`LANES`]).
    pub ld: usize,
}

/// Where [`Mlp::backward`] writes the gradient of the network input, and how much of it.
#[derive(Debug)]
pub struct InputGrad<'a> {
    /// Receives `min(rows, inp) × ld` floats: the gradient of the leading input rows.
    pub d_x: &'a mut Vec<f32>,
    /// How many leading input rows to compute (`usize::MAX` for all of them). Each row is
    /// computed on its own, so asking for fewer leaves the others' bits unchanged.
    pub rows: usize,
}

/// Reusable scratch of [`Mlp::backward`] (its content never matters between calls).
#[derive(Clone, Debug, Default)]
pub struct BackwardScratch {
    /// Block buffers and padded gradient accumulators.
    buf: Vec<f32>,
    /// Transposed weights of every layer.
    wt: Vec<f32>,
}

impl Mlp {
    /// An MLP `inp → hidden × n_hidden → out`.
    pub fn new(inp: usize, hidden: usize, n_hidden: usize, out: usize) -> Mlp {
        let mut layers = Vec::new();
        let mut prev = inp;
        for _ in 0..n_hidden {
            layers.push(LayerShape {
                inp: prev,
                out: hidden,
            });
            prev = hidden;
        }
        layers.push(LayerShape { inp: prev, out });
        Mlp { layers }
    }
    /// Total parameters.
    pub fn n_params(&self) -> usize {
        self.layers.iter().map(LayerShape::params).sum()
    }
    /// Input width.
    pub fn input_dim(&self) -> usize {
        self.layers[0].inp
    }
    /// Output width.
    pub fn output_dim(&self) -> usize {
        self.layers[self.layers.len() - 1].out
    }
    fn split<'a>(&self, params: &'a [f32], layer: usize) -> (&'a [f32], &'a [f32]) {
        let off: usize = self.layers[..layer].iter().map(LayerShape::params).sum();
        let s = self.layers[layer];
        (
            &params[off..off + s.inp * s.out],
            &params[off + s.inp * s.out..off + s.params()],
        )
    }

    /// Forward pass. `acts` receives one buffer per layer output (`out × ld`); the last one
    /// holds the (linear) network output. The batch runs through all layers one block of
    /// [`COLUMN_BLOCK`] columns at a time (results do not depend on the blocking).
    pub fn forward(&self, params: &[f32], x: &[f32], ld: usize, acts: &mut Vec<Vec<f32>>) {
        let nl = self.layers.len();
        acts.resize_with(nl, Vec::new);
        for (l, s) in self.layers.iter().enumerate() {
            // Every element of `acts[l][..out·ld]` is overwritten: no need to clear it.
            acts[l].resize(s.out * ld, 0.0);
        }
        let mut c0 = 0;
        while c0 < ld {
            let nb = COLUMN_BLOCK.min(ld - c0);
            for (l, s) in self.layers.iter().enumerate() {
                let (w, b) = self.split(params, l);
                let (done, rest) = acts.split_at_mut(l);
                let input: &[f32] = if l == 0 { x } else { &done[l - 1] };
                let store = if l + 1 < nl {
                    Store::Relu
                } else {
                    Store::Linear
                };
                let g = Gemm {
                    w,
                    b: Some(b),
                    x: &input[c0..],
                    ldx: ld,
                    inp: s.inp,
                    out: s.out,
                    ncols: nb,
                    store,
                };
                product(g, &mut rest[0][c0..], ld);
            }
            c0 += nb;
        }
    }

    /// Backward pass through `pass`. `d_out` is the gradient of the network output
    /// (`out × ld`, zero in the padding columns). Gradients are *added* to `grad` (same layout
    /// as the parameters). When `d_x` is given it receives the gradient of the network input
    /// (see [`InputGrad`]). The batch runs through all layers one block of [`COLUMN_BLOCK`]
    /// columns at a time; every gradient sum runs over the columns in order, so the blocking
    /// does not change the result.
    pub fn backward(
        &self,
        pass: ForwardPass<'_>,
        d_out: &[f32],
        grad: &mut [f32],
        d_x: Option<InputGrad<'_>>,
        scratch: &mut BackwardScratch,
    ) {
        let ForwardPass {
            params,
            x,
            acts,
            ld,
        } = pass;
        let (mut d_x, d_x_rows) = match d_x {
            Some(InputGrad { d_x, rows }) => (Some(d_x), rows),
            None => (None, 0),
        };
        let BackwardScratch { buf: scratch, wt } = scratch;
        let nl = self.layers.len();
        let dx_rows = d_x_rows.min(self.layers.first().map_or(0, |s| s.inp));
        let pad = |n: usize| n.div_ceil(LANES) * LANES;
        // Scratch layout: two block buffers, padded weight-gradient accumulators and lane
        // sums of every layer, transposed-input block.
        let widest = self
            .layers
            .iter()
            .map(|s| s.inp.max(s.out))
            .max()
            .unwrap_or(0);
        let blk = COLUMN_BLOCK.min(ld.max(LANES));
        // Row stride of the block buffers: one padding vector past the block, so that rows
        // are an odd number of cache lines apart (a 2 KiB stride would put a 16-column panel
        // of every row into the same two L1 sets). Layout only: the sums are unchanged.
        let ldb = blk + LANES;
        let acc_len: usize = self.layers.iter().map(|s| s.out * pad(s.inp)).sum();
        let lane_len: usize = self.layers.iter().map(|s| s.out * LANES).sum();
        // `LANES` spare floats so that the block buffers can start on a 64-byte boundary
        // (whole cache lines per 16-column panel; layout only).
        scratch.resize(LANES + 2 * widest * ldb + acc_len + lane_len, 0.0);
        let skip = (64 - scratch.as_ptr() as usize % 64) % 64 / std::mem::size_of::<f32>();
        let (bufs, rest) = scratch[skip..].split_at_mut(2 * widest * ldb);
        let (buf_a, buf_b) = bufs.split_at_mut(widest * ldb);
        let (accs, lane_sums) = rest.split_at_mut(acc_len);
        lane_sums.fill(0.0);
        // Transposed weights of every layer.
        let wt_len: usize = self.layers.iter().map(|s| s.inp * s.out).sum();
        wt.resize(wt_len, 0.0);
        let mut xt = Vec::new();
        {
            let (mut wo, mut ao) = (0, 0);
            for (l, s) in self.layers.iter().enumerate() {
                let (w, _) = self.split(params, l);
                transpose_weights(w, &mut wt[wo..wo + s.inp * s.out], s.inp, s.out);
                let off: usize = self.layers[..l].iter().map(LayerShape::params).sum();
                pad_weights(
                    &grad[off..off + s.inp * s.out],
                    &mut accs[ao..ao + s.out * pad(s.inp)],
                    s.inp,
                    s.out,
                );
                wo += s.inp * s.out;
                ao += s.out * pad(s.inp);
            }
        }
        if let Some(dx) = d_x.as_deref_mut() {
            dx.resize(dx_rows * ld, 0.0);
        }
        let mut c0 = 0;
        while c0 < ld {
            let nb = blk.min(ld - c0);
            // The gradient of layer l's output for this block: rows `ldd` apart.
            let mut cur: &mut [f32] = &mut buf_a[..];
            let mut next: &mut [f32] = &mut buf_b[..];
            let mut from_top = true;
            let (mut wo, mut ao, mut lo) = (wt_len, acc_len, lane_len);
            for l in (0..nl).rev() {
                let s = self.layers[l];
                wo -= s.inp * s.out;
                ao -= s.out * pad(s.inp);
                lo -= s.out * LANES;
                let (dy, lddy): (&[f32], usize) = if from_top {
                    (&d_out[c0..], ld)
                } else {
                    (&cur[..], ldb)
                };
                let input: &[f32] = if l == 0 { x } else { &acts[l - 1] };
                let g = WeightGrad {
                    dy,
                    lddy,
                    x: &input[c0..],
                    ldx: ld,
                    inp: s.inp,
                    out: s.out,
                    ncols: nb,
                };
                weight_grad(
                    g,
                    &mut accs[ao..ao + s.out * pad(s.inp)],
                    &mut lane_sums[lo..lo + s.out * LANES],
                    &mut xt,
                );
                // The input gradient: the transposed product, `out` gradient rows in.
                let g = Gemm {
                    w: &wt[wo..wo + s.inp * s.out],
                    b: None,
                    x: dy,
                    ldx: lddy,
                    inp: s.out,
                    out: s.inp,
                    ncols: nb,
                    store: Store::Linear,
                };
                if l > 0 {
                    let store = Store::MaskPositive(&acts[l - 1][c0..], ld);
                    product(Gemm { store, ..g }, next, ldb);
                    std::mem::swap(&mut cur, &mut next);
                    from_top = false;
                } else if let Some(dx) = d_x.as_deref_mut() {
                    product(Gemm { out: dx_rows, ..g }, &mut dx[c0..], ld);
                }
            }
            c0 += nb;
        }
        let (mut ao, mut lo) = (0, 0);
        for (l, s) in self.layers.iter().enumerate() {
            let off: usize = self.layers[..l].iter().map(LayerShape::params).sum();
            let (gw, gb) = grad[off..off + s.params()].split_at_mut(s.inp * s.out);
            unpad_weights(
                &accs[ao..ao + s.out * pad(s.inp)],
                &lane_sums[lo..lo + s.out * LANES],
                gw,
                gb,
                s.inp,
            );
            ao += s.out * pad(s.inp);
            lo += s.out * LANES;
        }
    }

    /// Kaiming-uniform weights (bound sqrt(6 / fan_in)) and zero biases, from `rng`.
    pub fn init(&self, params: &mut [f32], rng: &mut augsplat_core::Rng) {
        let mut off = 0;
        for s in &self.layers {
            let bound = (6.0 / s.inp as f64).sqrt();
            for v in &mut params[off..off + s.inp * s.out] {
                *v = rng.uniform(-bound, bound) as f32;
            }
            for v in &mut params[off + s.inp * s.out..off + s.params()] {
                *v = 0.0;
            }
            off += s.params();
        }
    }
}
