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
//! pairwise. The register-blocked AVX-512 (`gemm512.rs`) and AVX2 + FMA (`gemm256.rs`)
//! kernels use fused multiply-adds in exactly that order (the AVX2 ones are tested bit for bit
//! against the portable kernels run with fused multiply-adds); the portable path on CPUs
//! without them does not fuse. Results are therefore bit-identical for any thread count on one
//! machine, and across AVX-512 and AVX2 machines. An f64 reference lives in
//! [`crate::reference`].

/// Batch padding granularity (one AVX-512 register of f32).
pub const LANES: usize = 16;

/// Columns per block in [`Mlp::forward`] / [`Mlp::backward`] (a multiple of [`LANES`]).
pub const COLUMN_BLOCK: usize = 512;

/// `n` rounded up to a multiple of [`LANES`].
pub fn padded(n: usize) -> usize {
    n.div_ceil(LANES) * LANES
}

/// `a·b + c`, fused when `FMA` (the AVX paths) so every path of one build gives the same
/// bits on one machine.
#[inline(always)]
fn fmadd<const FMA: bool>(a: f32, b: f32, c: f32) -> f32 {
    if FMA {
        a.mul_add(b, c)
    } else {
        a * b + c
    }
}

#[inline(always)]
fn lanes(s: &[f32], at: usize) -> &[f32; LANES] {
    s[at..at + LANES].try_into().expect("lane slice")
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

#[inline(always)]
#[allow(clippy::too_many_arguments)]
fn fwd_block<const OB: usize, const T: usize, const FMA: bool>(
    w: &[f32],
    b: Option<&[f32]>,
    x: &[f32],
    ldx: usize,
    y: &mut [f32],
    ldy: usize,
    inp: usize,
    o0: usize,
    base: usize,
    store: Store<'_>,
) {
    let mut acc = [[[0f32; LANES]; T]; OB];
    if let Some(b) = b {
        for k in 0..OB {
            acc[k] = [[b[o0 + k]; LANES]; T];
        }
    }
    for i in 0..inp {
        let mut xv = [[0f32; LANES]; T];
        for t in 0..T {
            xv[t] = *lanes(x, i * ldx + base + t * LANES);
        }
        for k in 0..OB {
            let wk = w[(o0 + k) * inp + i];
            for t in 0..T {
                for l in 0..LANES {
                    acc[k][t][l] = fmadd::<FMA>(wk, xv[t][l], acc[k][t][l]);
                }
            }
        }
    }
    for k in 0..OB {
        for t in 0..T {
            let c = base + t * LANES;
            let at = (o0 + k) * ldy + c;
            let row = &mut y[at..at + LANES];
            match store {
                Store::Linear => row.copy_from_slice(&acc[k][t]),
                Store::Relu => {
                    for l in 0..LANES {
                        row[l] = acc[k][t][l].max(0.0);
                    }
                }
                Store::MaskPositive(m, ldm) => {
                    let mr = lanes(m, (o0 + k) * ldm + c);
                    for l in 0..LANES {
                        row[l] = if mr[l] > 0.0 { acc[k][t][l] } else { 0.0 };
                    }
                }
            }
        }
    }
}

#[inline(always)]
#[allow(clippy::too_many_arguments)]
fn fwd_body<const OB: usize, const FMA: bool>(
    w: &[f32],
    b: Option<&[f32]>,
    x: &[f32],
    ldx: usize,
    y: &mut [f32],
    ldy: usize,
    inp: usize,
    out: usize,
    ncols: usize,
    store: Store<'_>,
) {
    let mut base = 0;
    while base < ncols {
        let two = base + 2 * LANES <= ncols;
        let mut o0 = 0;
        while o0 + OB <= out {
            if two {
                fwd_block::<OB, 2, FMA>(w, b, x, ldx, y, ldy, inp, o0, base, store);
            } else {
                fwd_block::<OB, 1, FMA>(w, b, x, ldx, y, ldy, inp, o0, base, store);
            }
            o0 += OB;
        }
        while o0 < out {
            if two {
                fwd_block::<1, 2, FMA>(w, b, x, ldx, y, ldy, inp, o0, base, store);
            } else {
                fwd_block::<1, 1, FMA>(w, b, x, ldx, y, ldy, inp, o0, base, store);
            }
            o0 += 1;
        }
        base += if two { 2 * LANES } else { LANES };
    }
}

/// Portable weight-gradient accumulation (same contract as
/// [`crate::gemm512::backward_weights`]): columns are transposed in blocks, then every
/// `dwp` row is updated column after column (the inner loop over inputs vectorises).
#[inline(always)]
#[allow(clippy::too_many_arguments)]
fn dw_body<const FMA: bool>(
    dy: &[f32],
    lddy: usize,
    x: &[f32],
    ldx: usize,
    dwp: &mut [f32],
    lane_sums: &mut [f32],
    inp: usize,
    out: usize,
    ncols: usize,
    xt: &mut Vec<f32>,
) {
    let inp_pad = inp.div_ceil(LANES) * LANES;
    const KC: usize = 64;
    xt.resize(KC * inp_pad, 0.0);
    let mut kb = 0;
    while kb < ncols {
        let kc = KC.min(ncols - kb);
        for i in 0..inp_pad {
            for n in 0..kc {
                xt[n * inp_pad + i] = if i < inp { x[i * ldx + kb + n] } else { 0.0 };
            }
        }
        for o in 0..out {
            let row = &mut dwp[o * inp_pad..(o + 1) * inp_pad];
            for n in 0..kc {
                let d = dy[o * lddy + kb + n];
                let xr = &xt[n * inp_pad..(n + 1) * inp_pad];
                for i in 0..inp_pad {
                    row[i] = fmadd::<FMA>(d, xr[i], row[i]);
                }
            }
        }
        kb += kc;
    }
    for o in 0..out {
        let acc: &mut [f32; LANES] = (&mut lane_sums[o * LANES..(o + 1) * LANES])
            .try_into()
            .expect("lane sums");
        for base in (0..ncols).step_by(LANES) {
            let d = lanes(dy, o * lddy + base);
            for l in 0..LANES {
                acc[l] += d[l];
            }
        }
    }
}

/// Horizontal sum in a fixed pairwise order.
#[inline(always)]
pub(crate) fn hsum(a: &[f32; LANES]) -> f32 {
    let mut h = [0f32; 8];
    for l in 0..8 {
        h[l] = a[l] + a[l + 8];
    }
    let q = [h[0] + h[4], h[1] + h[5], h[2] + h[6], h[3] + h[7]];
    (q[0] + q[2]) + (q[1] + q[3])
}

fn has_avx512() -> bool {
    #[cfg(target_arch = "x86_64")]
    {
        std::arch::is_x86_feature_detected!("avx512f") && std::arch::is_x86_feature_detected!("fma")
    }
    #[cfg(not(target_arch = "x86_64"))]
    {
        false
    }
}

fn has_avx2() -> bool {
    #[cfg(target_arch = "x86_64")]
    {
        std::arch::is_x86_feature_detected!("avx2") && std::arch::is_x86_feature_detected!("fma")
    }
    #[cfg(not(target_arch = "x86_64"))]
    {
        false
    }
}

/// Panics with a message naming the buffer when a kernel argument is too short (a caller bug,
/// never data-dependent: shapes come from the layer definitions).
#[inline]
fn check_rows(len: usize, rows: usize, ld: usize, ncols: usize, what: &str) {
    let need = if rows == 0 {
        0
    } else {
        (rows - 1) * ld + ncols
    };
    assert!(
        len >= need && ncols.is_multiple_of(LANES),
        "dense-layer kernel: {what} has {len} floats, needs {rows} rows of stride {ld} with {ncols} columns"
    );
}

/// Forward-style product over columns `< ncols` with separate row strides (dispatch).
#[allow(clippy::too_many_arguments)]
fn product(
    w: &[f32],
    b: Option<&[f32]>,
    x: &[f32],
    ldx: usize,
    y: &mut [f32],
    ldy: usize,
    inp: usize,
    out: usize,
    ncols: usize,
    store: Store<'_>,
) {
    assert!(
        w.len() >= inp * out,
        "dense-layer kernel: weights too short"
    );
    if let Some(b) = b {
        assert!(b.len() >= out, "dense-layer kernel: biases too short");
    }
    check_rows(x.len(), inp, ldx, ncols, "input batch");
    check_rows(y.len(), out, ldy, ncols, "output batch");
    if let Store::MaskPositive(m, ldm) = store {
        check_rows(m.len(), out, ldm, ncols, "ReLU mask");
    }
    #[cfg(target_arch = "x86_64")]
    {
        if has_avx512() {
            // SAFETY: the CPU supports AVX-512F (checked); shapes checked above.
            return unsafe {
                crate::gemm512::forward(w, b, x, ldx, y, ldy, inp, out, ncols, store)
            };
        }
        if has_avx2() {
            // SAFETY: the CPU supports AVX2 and FMA (checked); shapes checked above.
            return unsafe {
                crate::gemm256::forward(w, b, x, ldx, y, ldy, inp, out, ncols, store)
            };
        }
    }
    fwd_body::<4, false>(w, b, x, ldx, y, ldy, inp, out, ncols, store)
}

/// Weight-gradient accumulation over columns `< ncols` into a padded `dwp` (`out × inp_pad`)
/// and per-lane bias sums (dispatch).
#[allow(clippy::too_many_arguments)]
fn weight_grad(
    dy: &[f32],
    lddy: usize,
    x: &[f32],
    ldx: usize,
    dwp: &mut [f32],
    lane_sums: &mut [f32],
    inp: usize,
    out: usize,
    ncols: usize,
    xt: &mut Vec<f32>,
) {
    check_rows(dy.len(), out, lddy, ncols, "output gradient");
    check_rows(x.len(), inp, ldx, ncols, "input batch");
    assert!(
        dwp.len() >= out * inp.div_ceil(LANES) * LANES && lane_sums.len() >= out * LANES,
        "dense-layer kernel: gradient accumulators too short"
    );
    #[cfg(target_arch = "x86_64")]
    {
        if has_avx512() {
            // SAFETY: the CPU supports AVX-512F (checked); shapes checked above.
            return unsafe {
                crate::gemm512::backward_weights(
                    dy, lddy, x, ldx, dwp, lane_sums, inp, out, ncols, xt,
                )
            };
        }
        if has_avx2() {
            // SAFETY: the CPU supports AVX2 and FMA (checked); shapes checked above.
            return unsafe {
                crate::gemm256::backward_weights(
                    dy, lddy, x, ldx, dwp, lane_sums, inp, out, ncols, xt,
                )
            };
        }
    }
    dw_body::<false>(dy, lddy, x, ldx, dwp, lane_sums, inp, out, ncols, xt)
}

/// Copies `dw` (`out × inp`) into a padded `dwp` (`out × inp_pad`, zero padding).
fn pad_weights(dw: &[f32], dwp: &mut [f32], inp: usize, out: usize) {
    let inp_pad = inp.div_ceil(LANES) * LANES;
    for o in 0..out {
        dwp[o * inp_pad..o * inp_pad + inp].copy_from_slice(&dw[o * inp..(o + 1) * inp]);
        dwp[o * inp_pad + inp..(o + 1) * inp_pad].fill(0.0);
    }
}

/// Writes the padded accumulators back: `dw` from `dwp`, `db[o] += hsum(lane_sums[o])`.
fn unpad_weights(dwp: &[f32], lane_sums: &[f32], dw: &mut [f32], db: &mut [f32], inp: usize) {
    let inp_pad = inp.div_ceil(LANES) * LANES;
    for o in 0..db.len() {
        dw[o * inp..(o + 1) * inp].copy_from_slice(&dwp[o * inp_pad..o * inp_pad + inp]);
        db[o] += hsum(
            lane_sums[o * LANES..(o + 1) * LANES]
                .try_into()
                .expect("lane sums"),
        );
    }
}

/// `y[o] = act(b[o] + Σ_i w[o·inp + i] · x[i])` for every column of a channel-major batch
/// (`x`: `inp × ld`, `y`: `out × ld`, `w`: `out × inp` row-major). `act` is ReLU when
/// `relu`, else identity. `ld` must be a multiple of [`LANES`]. Each output sums over `i` in
/// order, so block sizes do not change the result.
#[allow(clippy::too_many_arguments)]
pub fn linear_forward(
    w: &[f32],
    b: Option<&[f32]>,
    x: &[f32],
    y: &mut [f32],
    inp: usize,
    out: usize,
    ld: usize,
    relu: bool,
) {
    let store = if relu { Store::Relu } else { Store::Linear };
    product(w, b, x, ld, y, ld, inp, out, ld, store)
}

/// Weight gradients of a layer: `dw[o·inp + i] += Σ_n dy[o][n] · x[i][n]` (the sequential sum
/// over the columns, after the existing value) and `db[o] += Σ_n dy[o][n]` (16 lane sums
/// combined pairwise).
#[allow(clippy::too_many_arguments)]
pub fn linear_backward_weights(
    dy: &[f32],
    x: &[f32],
    dw: &mut [f32],
    db: &mut [f32],
    inp: usize,
    out: usize,
    ld: usize,
) {
    assert!(
        dw.len() >= inp * out && db.len() >= out,
        "dense-layer kernel: gradient buffers too short"
    );
    let inp_pad = inp.div_ceil(LANES) * LANES;
    let mut dwp = vec![0f32; out * inp_pad];
    let mut lane_sums = vec![0f32; out * LANES];
    pad_weights(dw, &mut dwp, inp, out);
    let mut xt = Vec::new();
    weight_grad(
        dy,
        ld,
        x,
        ld,
        &mut dwp,
        &mut lane_sums,
        inp,
        out,
        ld,
        &mut xt,
    );
    unpad_weights(&dwp, &lane_sums, dw, &mut db[..out], inp);
}

/// Transposed weights (`inp × out`) into `wt`.
fn transpose_weights(w: &[f32], wt: &mut [f32], inp: usize, out: usize) {
    for o in 0..out {
        for i in 0..inp {
            wt[i * out + o] = w[o * inp + i];
        }
    }
}

/// Input gradient of a layer: `dx[i] = Σ_o w[o·inp + i] · dy[o]` per column. `wt` is scratch
/// that receives the transposed weights.
#[allow(clippy::too_many_arguments)]
pub fn linear_backward_input(
    w: &[f32],
    dy: &[f32],
    dx: &mut [f32],
    inp: usize,
    out: usize,
    ld: usize,
    wt: &mut Vec<f32>,
) {
    linear_backward_input_masked(w, dy, dx, inp, out, ld, wt, None)
}

/// [`linear_backward_input`] followed by [`relu_backward`] with `mask` (the post-activation
/// output of the layer below, laid out like `dx`), fused into the kernel's store.
#[allow(clippy::too_many_arguments)]
pub fn linear_backward_input_masked(
    w: &[f32],
    dy: &[f32],
    dx: &mut [f32],
    inp: usize,
    out: usize,
    ld: usize,
    wt: &mut Vec<f32>,
    mask: Option<&[f32]>,
) {
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
    product(wt, None, dy, ld, dx, ld, out, inp, ld, store)
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
                product(
                    w,
                    Some(b),
                    &input[c0..],
                    ld,
                    &mut rest[0][c0..],
                    ld,
                    s.inp,
                    s.out,
                    nb,
                    store,
                );
            }
            c0 += nb;
        }
    }

    /// Backward pass. `d_out` is the gradient of the network output (`out × ld`, zero in the
    /// padding columns). Gradients are *added* to `grad` (same layout as
    /// `params`). When `d_x` is given it receives the gradient of the leading `d_x_rows`
    /// input rows (`min(d_x_rows, inp) × ld`; pass `usize::MAX` for all of them — each row is
    /// computed on its own, so asking for fewer leaves the others' bits unchanged). `scratch`
    /// and `wt` are reusable scratch. The batch runs through all layers one block of
    /// [`COLUMN_BLOCK`] columns at a time; every gradient sum runs over the columns in order,
    /// so the blocking does not change the result.
    #[allow(clippy::too_many_arguments)]
    pub fn backward(
        &self,
        params: &[f32],
        x: &[f32],
        acts: &[Vec<f32>],
        ld: usize,
        d_out: &[f32],
        grad: &mut [f32],
        d_x: Option<&mut Vec<f32>>,
        d_x_rows: usize,
        scratch: &mut Vec<f32>,
        wt: &mut Vec<f32>,
    ) {
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
        let mut d_x = d_x;
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
                weight_grad(
                    dy,
                    lddy,
                    &input[c0..],
                    ld,
                    &mut accs[ao..ao + s.out * pad(s.inp)],
                    &mut lane_sums[lo..lo + s.out * LANES],
                    s.inp,
                    s.out,
                    nb,
                    &mut xt,
                );
                let wtl = &wt[wo..wo + s.inp * s.out];
                if l > 0 {
                    product(
                        wtl,
                        None,
                        dy,
                        lddy,
                        next,
                        ldb,
                        s.out,
                        s.inp,
                        nb,
                        Store::MaskPositive(&acts[l - 1][c0..], ld),
                    );
                    std::mem::swap(&mut cur, &mut next);
                    from_top = false;
                } else if let Some(dx) = d_x.as_deref_mut() {
                    product(
                        wtl,
                        None,
                        dy,
                        lddy,
                        &mut dx[c0..],
                        ld,
                        s.out,
                        dx_rows,
                        nb,
                        Store::Linear,
                    );
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

#[cfg(test)]
mod tests {
    use super::*;
    use augsplat_core::Rng;

    fn batch(rng: &mut Rng, rows: usize, n: usize, ld: usize) -> Vec<f32> {
        let mut v = vec![0f32; rows * ld];
        for r in 0..rows {
            for i in 0..n {
                v[r * ld + i] = rng.uniform(-1.0, 1.0) as f32;
            }
        }
        v
    }

    /// Every kernel (whichever instruction set this machine selects) against f64 sums, for
    /// shapes that exercise all tile remainders (odd widths, 1–4 column vectors, long batches
    /// that span several transposed blocks).
    #[test]
    fn kernels_match_f64_sums() {
        let mut rng = Rng::new(11);
        for &(inp, out, n) in &[
            (5usize, 12usize, 21usize),
            (31, 64, 300),
            (64, 3, 47),
            (64, 16, 700),
            (17, 9, 16),
            (100, 70, 129),
        ] {
            let ld = padded(n);
            let w: Vec<f32> = (0..inp * out)
                .map(|_| rng.uniform(-0.5, 0.5) as f32)
                .collect();
            let b: Vec<f32> = (0..out).map(|_| rng.uniform(-0.5, 0.5) as f32).collect();
            let x = batch(&mut rng, inp, n, ld);
            let dy = batch(&mut rng, out, n, ld);
            let mask = batch(&mut rng, inp, n, ld);
            let mut y = vec![f32::NAN; out * ld];
            linear_forward(&w, Some(&b), &x, &mut y, inp, out, ld, true);
            for o in 0..out {
                for c in 0..n {
                    let r: f64 = b[o] as f64
                        + (0..inp)
                            .map(|i| w[o * inp + i] as f64 * x[i * ld + c] as f64)
                            .sum::<f64>();
                    let got = y[o * ld + c] as f64;
                    assert!(
                        (got - r.max(0.0)).abs() < 1e-5 * (1.0 + r.abs()),
                        "fwd {inp}x{out} ({o},{c})"
                    );
                }
            }
            let mut dx = vec![f32::NAN; inp * ld];
            let mut wt = Vec::new();
            linear_backward_input_masked(&w, &dy, &mut dx, inp, out, ld, &mut wt, Some(&mask));
            for i in 0..inp {
                for c in 0..ld {
                    let r: f64 = (0..out)
                        .map(|o| w[o * inp + i] as f64 * dy[o * ld + c] as f64)
                        .sum();
                    let r = if mask[i * ld + c] > 0.0 { r } else { 0.0 };
                    let got = dx[i * ld + c] as f64;
                    assert!(
                        (got - r).abs() < 1e-5 * (1.0 + r.abs()),
                        "dx {inp}x{out} ({i},{c})"
                    );
                }
            }
            let mut dw = vec![0.25f32; inp * out];
            let mut db = vec![-0.5f32; out];
            linear_backward_weights(&dy, &x, &mut dw, &mut db, inp, out, ld);
            for o in 0..out {
                for i in 0..inp {
                    let r: f64 = 0.25
                        + (0..n)
                            .map(|c| dy[o * ld + c] as f64 * x[i * ld + c] as f64)
                            .sum::<f64>();
                    let got = dw[o * inp + i] as f64;
                    assert!(
                        (got - r).abs() < 1e-4 * (1.0 + r.abs()),
                        "dw {inp}x{out} ({o},{i}): {got} vs {r}"
                    );
                }
                let r: f64 = -0.5 + (0..n).map(|c| dy[o * ld + c] as f64).sum::<f64>();
                assert!((db[o] as f64 - r).abs() < 1e-4 * (1.0 + r.abs()), "db {o}");
            }
        }
    }

    /// The portable kernels (used where AVX-512 and AVX2 are missing, hence not reached
    /// through the dispatch on this machine) against f64 sums, with separate row strides.
    #[test]
    fn portable_kernels_match_f64_sums() {
        let mut rng = Rng::new(12);
        for &(inp, out, n) in &[
            (5usize, 12usize, 21usize),
            (31, 64, 130),
            (64, 3, 47),
            (17, 9, 16),
        ] {
            let ld = padded(n);
            let ldy = ld + 16; // a different output stride
            let w: Vec<f32> = (0..inp * out)
                .map(|_| rng.uniform(-0.5, 0.5) as f32)
                .collect();
            let b: Vec<f32> = (0..out).map(|_| rng.uniform(-0.5, 0.5) as f32).collect();
            let x = batch(&mut rng, inp, n, ld);
            let dy = batch(&mut rng, out, n, ld);
            let mask = batch(&mut rng, out, n, ld);
            for mode in 0..3 {
                let store = match mode {
                    0 => Store::Linear,
                    1 => Store::Relu,
                    _ => Store::MaskPositive(&mask, ld),
                };
                let mut y = vec![f32::NAN; out * ldy];
                fwd_body::<4, false>(&w, Some(&b), &x, ld, &mut y, ldy, inp, out, ld, store);
                for o in 0..out {
                    for c in 0..n {
                        let r: f64 = b[o] as f64
                            + (0..inp)
                                .map(|i| w[o * inp + i] as f64 * x[i * ld + c] as f64)
                                .sum::<f64>();
                        let r = match mode {
                            0 => r,
                            1 => r.max(0.0),
                            _ => {
                                if mask[o * ld + c] > 0.0 {
                                    r
                                } else {
                                    0.0
                                }
                            }
                        };
                        let got = y[o * ldy + c] as f64;
                        assert!(
                            (got - r).abs() < 1e-5 * (1.0 + r.abs()),
                            "fwd mode {mode} ({o},{c})"
                        );
                    }
                }
            }
            let inp_pad = inp.div_ceil(LANES) * LANES;
            let mut dwp = vec![0.25f32; out * inp_pad];
            let mut lane_sums = vec![0f32; out * LANES];
            let mut xt = Vec::new();
            dw_body::<false>(
                &dy,
                ld,
                &x,
                ld,
                &mut dwp,
                &mut lane_sums,
                inp,
                out,
                ld,
                &mut xt,
            );
            for o in 0..out {
                for i in 0..inp {
                    let r: f64 = 0.25
                        + (0..n)
                            .map(|c| dy[o * ld + c] as f64 * x[i * ld + c] as f64)
                            .sum::<f64>();
                    let got = dwp[o * inp_pad + i] as f64;
                    assert!((got - r).abs() < 1e-4 * (1.0 + r.abs()), "dw ({o},{i})");
                }
                let r: f64 = (0..n).map(|c| dy[o * ld + c] as f64).sum();
                let got = hsum(lane_sums[o * LANES..(o + 1) * LANES].try_into().unwrap()) as f64;
                assert!((got - r).abs() < 1e-4 * (1.0 + r.abs()), "db {o}");
            }
        }
    }

    /// The column-blocked MLP passes give exactly the bits of whole-batch layer-by-layer
    /// kernel calls (the blocking is not part of the result).
    #[test]
    fn blocked_mlp_matches_whole_batch_layers_bitwise() {
        let mlp = Mlp::new(31, 24, 2, 3);
        let mut rng = Rng::new(4);
        let mut params = vec![0f32; mlp.n_params()];
        mlp.init(&mut params, &mut rng);
        for p in params.iter_mut() {
            *p += rng.uniform(-0.1, 0.1) as f32;
        }
        let n = 2 * COLUMN_BLOCK + 37;
        let ld = padded(n);
        let x = batch(&mut rng, 31, n, ld);
        let mut acts = Vec::new();
        mlp.forward(&params, &x, ld, &mut acts);
        let d_top = batch(&mut rng, 3, n, ld);
        let mut grad: Vec<f32> = (0..mlp.n_params()).map(|k| k as f32 * 1e-3).collect();
        let mut want_grad = grad.clone();
        let mut dx = Vec::new();
        let (mut s1, mut s2) = (Vec::new(), Vec::new());
        let d_out = d_top.clone();
        mlp.backward(
            &params,
            &x,
            &acts,
            ld,
            &d_out,
            &mut grad,
            Some(&mut dx),
            usize::MAX,
            &mut s1,
            &mut s2,
        );
        // Whole-batch reference with the public per-layer kernels.
        let mut want_acts: Vec<Vec<f32>> = Vec::new();
        for (l, s) in mlp.layers.iter().enumerate() {
            let (w, b) = mlp.split(&params, l);
            let mut y = vec![0f32; s.out * ld];
            let input = if l == 0 { &x } else { &want_acts[l - 1] };
            linear_forward(
                w,
                Some(b),
                input,
                &mut y,
                s.inp,
                s.out,
                ld,
                l + 1 < mlp.layers.len(),
            );
            want_acts.push(y);
        }
        assert_eq!(acts, want_acts);
        let mut d = d_top.clone();
        let mut wt = Vec::new();
        let mut want_dx = Vec::new();
        for l in (0..mlp.layers.len()).rev() {
            let s = mlp.layers[l];
            let (w, _) = mlp.split(&params, l);
            let off: usize = mlp.layers[..l].iter().map(LayerShape::params).sum();
            let (gw, gb) = want_grad[off..off + s.params()].split_at_mut(s.inp * s.out);
            let input = if l == 0 { &x } else { &want_acts[l - 1] };
            linear_backward_weights(&d, input, gw, gb, s.inp, s.out, ld);
            let mut nd = vec![0f32; s.inp * ld];
            let mask = if l > 0 {
                Some(&want_acts[l - 1][..])
            } else {
                None
            };
            linear_backward_input_masked(w, &d, &mut nd, s.inp, s.out, ld, &mut wt, mask);
            if l == 0 {
                want_dx = nd;
            } else {
                d = nd;
            }
        }
        assert_eq!(grad, want_grad);
        assert_eq!(dx, want_dx);
        // Asking for the leading 15 input rows gives exactly those rows, and the same
        // parameter gradients.
        let mut grad15: Vec<f32> = (0..mlp.n_params()).map(|k| k as f32 * 1e-3).collect();
        let mut dx15 = vec![f32::NAN; 3];
        mlp.backward(
            &params,
            &x,
            &acts,
            ld,
            &d_out,
            &mut grad15,
            Some(&mut dx15),
            15,
            &mut s1,
            &mut s2,
        );
        assert_eq!(grad15, want_grad);
        assert_eq!(dx15, want_dx[..15 * ld]);
    }

    /// `f64` value of `b[o] + Σ_i w[o·inp + i] · x[i][c]` after `store`.
    #[allow(clippy::too_many_arguments)]
    fn fwd_ref(
        w: &[f32],
        b: Option<&[f32]>,
        x: &[f32],
        ldx: usize,
        inp: usize,
        o: usize,
        c: usize,
        store: Store<'_>,
    ) -> f64 {
        let r = b.map_or(0.0, |b| b[o] as f64)
            + (0..inp)
                .map(|i| w[o * inp + i] as f64 * x[i * ldx + c] as f64)
                .sum::<f64>();
        match store {
            Store::Linear => r,
            Store::Relu => r.max(0.0),
            Store::MaskPositive(m, ldm) => {
                if m[o * ldm + c] > 0.0 {
                    r
                } else {
                    0.0
                }
            }
        }
    }

    /// The AVX2 register-blocked kernels ([`crate::gemm256`]) give exactly the bits of the
    /// portable kernels with fused multiply-adds (the contract every path keeps), for the real
    /// layer shapes (forward and the transposed input-gradient products), tile remainders of
    /// every size, column counts that are odd multiples of [`LANES`], separate row strides,
    /// all store modes, with and without bias; and they agree with `f64` sums.
    #[cfg(target_arch = "x86_64")]
    #[test]
    fn avx2_kernels_match_portable_bitwise() {
        if !has_avx2() {
            eprintln!("skipping avx2_kernels_match_portable_bitwise: the CPU lacks AVX2/FMA");
            return;
        }
        let mut rng = Rng::new(21);
        let mut xt_a = Vec::new();
        let mut xt_b = Vec::new();
        // (inp, out, ncols, ld padding of x, of y): the field's layers 32→64, 64→16, 31→64,
        // 64→64, 64→3 and their transposes, then odd shapes.
        for &(inp, out, ncols, px, py) in &[
            (32usize, 64usize, 512usize, 0usize, 16usize),
            (64, 64, 512, 16, 0),
            (64, 16, 208, 0, 32),
            (31, 64, 144, 16, 16),
            (64, 3, 176, 0, 0),
            (64, 3, 48, 32, 16),
            (64, 32, 80, 0, 16),
            (16, 64, 112, 16, 0),
            (3, 64, 16, 0, 16),
            (15, 64, 336, 0, 0),
            (1, 1, 16, 0, 0),
            (2, 5, 32, 16, 0),
            (7, 2, 48, 0, 16),
            (17, 9, 80, 16, 16),
            (40, 7, 1040, 0, 0),
            (100, 70, 272, 0, 16),
            (5, 13, 16, 16, 32),
        ] {
            let (ldx, ldy) = (ncols + px, ncols + py);
            let w: Vec<f32> = (0..inp * out)
                .map(|_| rng.uniform(-0.5, 0.5) as f32)
                .collect();
            let b: Vec<f32> = (0..out).map(|_| rng.uniform(-0.5, 0.5) as f32).collect();
            let x = batch(&mut rng, inp, ldx, ldx);
            let dy = batch(&mut rng, out, ldy, ldy);
            let mask = batch(&mut rng, out, ldy, ldy);
            for mode in 0..3 {
                for bias in [Some(&b[..]), None] {
                    let store = match mode {
                        0 => Store::Linear,
                        1 => Store::Relu,
                        _ => Store::MaskPositive(&mask, ldy),
                    };
                    // Padding columns past `ncols` must stay untouched.
                    let mut got = vec![f32::NAN; out * ldy];
                    let mut want = got.clone();
                    // SAFETY: AVX2 and FMA checked above; every row holds `ncols` columns.
                    unsafe {
                        crate::gemm256::forward(
                            &w, bias, &x, ldx, &mut got, ldy, inp, out, ncols, store,
                        )
                    };
                    fwd_body::<4, true>(&w, bias, &x, ldx, &mut want, ldy, inp, out, ncols, store);
                    let bits = |v: &[f32]| v.iter().map(|f| f.to_bits()).collect::<Vec<_>>();
                    assert_eq!(
                        bits(&got),
                        bits(&want),
                        "fwd {inp}->{out} x{ncols} mode {mode}"
                    );
                    for o in 0..out {
                        for c in 0..ncols {
                            let r = fwd_ref(&w, bias, &x, ldx, inp, o, c, store);
                            let g = got[o * ldy + c] as f64;
                            assert!(
                                (g - r).abs() < 1e-5 * (1.0 + r.abs()),
                                "fwd {inp}->{out} mode {mode} ({o},{c}): {g} vs {r}"
                            );
                        }
                    }
                }
            }
            // Weight gradient over the same shapes, accumulating onto non-zero values.
            let inp_pad = inp.div_ceil(LANES) * LANES;
            let dwp0: Vec<f32> = (0..out * inp_pad)
                .map(|_| rng.uniform(-0.5, 0.5) as f32)
                .collect();
            let ls0: Vec<f32> = (0..out * LANES)
                .map(|_| rng.uniform(-0.5, 0.5) as f32)
                .collect();
            let (mut dwp, mut ls) = (dwp0.clone(), ls0.clone());
            let (mut want_dwp, mut want_ls) = (dwp0.clone(), ls0.clone());
            // SAFETY: AVX2 and FMA checked above; buffers sized for the shapes.
            unsafe {
                crate::gemm256::backward_weights(
                    &dy, ldy, &x, ldx, &mut dwp, &mut ls, inp, out, ncols, &mut xt_a,
                )
            };
            dw_body::<true>(
                &dy,
                ldy,
                &x,
                ldx,
                &mut want_dwp,
                &mut want_ls,
                inp,
                out,
                ncols,
                &mut xt_b,
            );
            let bits = |v: &[f32]| v.iter().map(|f| f.to_bits()).collect::<Vec<_>>();
            assert_eq!(bits(&dwp), bits(&want_dwp), "dW {inp}->{out} x{ncols}");
            assert_eq!(bits(&ls), bits(&want_ls), "lane sums {inp}->{out} x{ncols}");
            for o in 0..out {
                for i in 0..inp {
                    let r: f64 = dwp0[o * inp_pad + i] as f64
                        + (0..ncols)
                            .map(|c| dy[o * ldy + c] as f64 * x[i * ldx + c] as f64)
                            .sum::<f64>();
                    let g = dwp[o * inp_pad + i] as f64;
                    assert!(
                        (g - r).abs() < 1e-4 * (1.0 + r.abs()),
                        "dW {inp}->{out} ({o},{i}): {g} vs {r}"
                    );
                }
                let r: f64 = (0..LANES).map(|l| ls0[o * LANES + l] as f64).sum::<f64>()
                    + (0..ncols).map(|c| dy[o * ldy + c] as f64).sum::<f64>();
                let g = hsum(ls[o * LANES..(o + 1) * LANES].try_into().unwrap()) as f64;
                assert!((g - r).abs() < 1e-4 * (1.0 + r.abs()), "db {o}: {g} vs {r}");
            }
        }
    }

    /// Non-finite values flow through the AVX2 forward kernel as through the portable one:
    /// ReLU maps NaN to 0, the mask keeps or zeroes NaN and infinities alike.
    #[cfg(target_arch = "x86_64")]
    #[test]
    fn avx2_forward_handles_non_finite_like_portable() {
        if !has_avx2() {
            eprintln!("skipping avx2_forward_handles_non_finite_like_portable: no AVX2/FMA");
            return;
        }
        let mut rng = Rng::new(22);
        let (inp, out, ld) = (9usize, 7usize, 64usize);
        let w: Vec<f32> = (0..inp * out)
            .map(|_| rng.uniform(-0.5, 0.5) as f32)
            .collect();
        let mut x = batch(&mut rng, inp, ld, ld);
        x[3 * ld + 5] = f32::NAN;
        x[ld + 17] = f32::INFINITY;
        x[40] = f32::NEG_INFINITY;
        let mut mask = batch(&mut rng, out, ld, ld);
        mask[2 * ld + 5] = f32::NAN;
        for mode in 0..3 {
            let store = match mode {
                0 => Store::Linear,
                1 => Store::Relu,
                _ => Store::MaskPositive(&mask, ld),
            };
            let mut got = vec![0f32; out * ld];
            let mut want = vec![0f32; out * ld];
            // SAFETY: AVX2 and FMA checked above; every row holds `ld` columns.
            unsafe { crate::gemm256::forward(&w, None, &x, ld, &mut got, ld, inp, out, ld, store) };
            fwd_body::<4, true>(&w, None, &x, ld, &mut want, ld, inp, out, ld, store);
            for (k, (g, e)) in got.iter().zip(&want).enumerate() {
                assert!(
                    g.to_bits() == e.to_bits() || (g.is_nan() && e.is_nan()),
                    "mode {mode} at {k}: {g} vs {e}"
                );
            }
        }
    }

    /// The AVX2 forward kernel's column walk on the 32-byte grid (masked first and last
    /// windows when rows start 16 bytes past a 32-byte boundary) gives the bits of the
    /// portable kernel for every start offset of the operands, short and long column counts,
    /// every store mode, and non-finite inputs; the columns around the written range (before
    /// the first and past the last) are never touched.
    #[cfg(target_arch = "x86_64")]
    #[test]
    fn avx2_forward_any_row_alignment_matches_portable() {
        if !has_avx2() {
            eprintln!("skipping avx2_forward_any_row_alignment_matches_portable: no AVX2/FMA");
            return;
        }
        let mut rng = Rng::new(23);
        let bits = |v: &[f32]| v.iter().map(|f| f.to_bits()).collect::<Vec<_>>();
        for &(inp, out, ncols, pad) in &[
            (64usize, 64usize, 528usize, 16usize),
            (64, 16, 48, 0),
            (31, 64, 16, 16),
            (64, 3, 32, 0),
            (3, 64, 16, 32),
            (16, 7, 80, 16),
            (64, 15, 144, 0),
        ] {
            let ld = ncols + pad;
            let w: Vec<f32> = (0..inp * out)
                .map(|_| rng.uniform(-0.5, 0.5) as f32)
                .collect();
            let b: Vec<f32> = (0..out).map(|_| rng.uniform(-0.5, 0.5) as f32).collect();
            // Storage with 8 spare floats in front, so every offset mod 32 bytes occurs.
            let mut xs = batch(&mut rng, inp, ld + 8, ld + 8)[..inp * ld + 8].to_vec();
            xs[8 + 3] = f32::NAN;
            xs[8 + ld + 1] = f32::INFINITY;
            xs[8 + (inp - 1) * ld + ncols - 1] = f32::NEG_INFINITY;
            let ms = batch(&mut rng, out, ld + 8, ld + 8)[..out * ld + 8].to_vec();
            for xo in 0..8 {
                for yo in [0usize, 4, 8 - xo.min(8)] {
                    let x = &xs[xo..xo + inp * ld];
                    let mo = (xo + yo) % 8;
                    let m = &ms[mo..mo + out * ld];
                    for mode in 0..3 {
                        for bias in [Some(&b[..]), None] {
                            let store = match mode {
                                0 => Store::Linear,
                                1 => Store::Relu,
                                _ => Store::MaskPositive(m, ld),
                            };
                            // Sentinels around the output rows: the floats before, the row
                            // padding and the floats after must keep their bits.
                            let mut got = vec![f32::from_bits(0x7fc0_1234); out * ld + 16];
                            let mut want = got.clone();
                            let span = 8 + yo % 8;
                            {
                                let y = &mut got[span..span + out * ld];
                                // SAFETY: AVX2 and FMA checked above; every row read or
                                // written holds `ncols` columns inside its slice.
                                unsafe {
                                    crate::gemm256::forward(
                                        &w, bias, x, ld, y, ld, inp, out, ncols, store,
                                    )
                                };
                            }
                            {
                                let y = &mut want[span..span + out * ld];
                                fwd_body::<4, true>(&w, bias, x, ld, y, ld, inp, out, ncols, store);
                            }
                            assert_eq!(
                                bits(&got),
                                bits(&want),
                                "{inp}->{out} x{ncols} offsets x {xo} y {yo} mode {mode}"
                            );
                        }
                    }
                }
            }
        }
    }

    #[cfg(target_arch = "x86_64")]
    #[test]
    fn transpose8_is_a_transpose() {
        if !has_avx2() {
            eprintln!("skipping transpose8_is_a_transpose: the CPU lacks AVX2/FMA");
            return;
        }
        let src: [f32; 64] = std::array::from_fn(|i| i as f32);
        let mut dst = [0f32; 64];
        // SAFETY: AVX2 checked above.
        unsafe { crate::gemm256::transpose8_slice(&src, &mut dst) };
        for r in 0..8 {
            for c in 0..8 {
                assert_eq!(dst[c * 8 + r], src[r * 8 + c], "({r},{c})");
            }
        }
    }

    #[cfg(target_arch = "x86_64")]
    #[test]
    fn transpose16_is_a_transpose() {
        if !has_avx512() {
            return;
        }
        let src: [f32; 256] = std::array::from_fn(|i| i as f32);
        let mut dst = [0f32; 256];
        // SAFETY: AVX-512F checked above.
        unsafe { crate::gemm512::transpose16_slice(&src, &mut dst) };
        for r in 0..16 {
            for c in 0..16 {
                assert_eq!(dst[c * 16 + r], src[r * 16 + c], "({r},{c})");
            }
        }
    }
}
