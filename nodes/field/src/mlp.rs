//! Small dense layers over channel-major (structure-of-arrays) batches.
//!
//! A batch of `n` activations with `c` channels is stored as `c` rows of `ld` floats
//! (`ld` = `n` rounded up to [`LANES`]; padding columns are kept at zero by the callers'
//! loss gradients, so they never leak into weight gradients). A layer is then a small matrix
//! product `Y = W X + b` whose inner loop runs along the batch and vectorises.
//!
//! Every kernel sums in a fixed order that does not depend on block sizes or the instruction
//! set chosen at run time (no fused multiply-add), so results are bit-identical everywhere on
//! one machine. An f64 reference lives in [`crate::reference`].

/// Batch padding granularity (one AVX-512 register of f32).
pub const LANES: usize = 16;

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

#[inline(always)]
#[allow(clippy::too_many_arguments)]
fn fwd_block<const OB: usize, const T: usize, const FMA: bool>(
    w: &[f32],
    b: Option<&[f32]>,
    x: &[f32],
    y: &mut [f32],
    inp: usize,
    o0: usize,
    ld: usize,
    base: usize,
    relu: bool,
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
            xv[t] = *lanes(x, i * ld + base + t * LANES);
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
            let at = (o0 + k) * ld + base + t * LANES;
            let row = &mut y[at..at + LANES];
            for l in 0..LANES {
                row[l] = if relu {
                    acc[k][t][l].max(0.0)
                } else {
                    acc[k][t][l]
                };
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
    y: &mut [f32],
    inp: usize,
    out: usize,
    ld: usize,
    relu: bool,
) {
    let mut base = 0;
    while base < ld {
        let two = base + 2 * LANES <= ld;
        let mut o0 = 0;
        while o0 + OB <= out {
            if two {
                fwd_block::<OB, 2, FMA>(w, b, x, y, inp, o0, ld, base, relu);
            } else {
                fwd_block::<OB, 1, FMA>(w, b, x, y, inp, o0, ld, base, relu);
            }
            o0 += OB;
        }
        while o0 < out {
            if two {
                fwd_block::<1, 2, FMA>(w, b, x, y, inp, o0, ld, base, relu);
            } else {
                fwd_block::<1, 1, FMA>(w, b, x, y, inp, o0, ld, base, relu);
            }
            o0 += 1;
        }
        base += if two { 2 * LANES } else { LANES };
    }
}

#[inline(always)]
fn dw_block<const OB: usize, const IB: usize, const FMA: bool>(
    dy: &[f32],
    x: &[f32],
    dw: &mut [f32],
    inp: usize,
    o0: usize,
    i0: usize,
    ld: usize,
) {
    let mut acc = [[[0f32; LANES]; IB]; OB];
    for base in (0..ld).step_by(LANES) {
        let mut xv = [[0f32; LANES]; IB];
        for j in 0..IB {
            xv[j] = *lanes(x, (i0 + j) * ld + base);
        }
        for k in 0..OB {
            let d = lanes(dy, (o0 + k) * ld + base);
            for j in 0..IB {
                for l in 0..LANES {
                    acc[k][j][l] = fmadd::<FMA>(d[l], xv[j][l], acc[k][j][l]);
                }
            }
        }
    }
    for k in 0..OB {
        for j in 0..IB {
            dw[(o0 + k) * inp + i0 + j] += hsum(&acc[k][j]);
        }
    }
}

/// Horizontal sum in a fixed pairwise order.
#[inline(always)]
fn hsum(a: &[f32; LANES]) -> f32 {
    let mut h = [0f32; 8];
    for l in 0..8 {
        h[l] = a[l] + a[l + 8];
    }
    let q = [h[0] + h[4], h[1] + h[5], h[2] + h[6], h[3] + h[7]];
    (q[0] + q[2]) + (q[1] + q[3])
}

#[inline(always)]
fn dw_body<const OB: usize, const IB: usize, const FMA: bool>(
    dy: &[f32],
    x: &[f32],
    dw: &mut [f32],
    db: &mut [f32],
    inp: usize,
    out: usize,
    ld: usize,
) {
    let mut o0 = 0;
    while o0 < out {
        let ob = (out - o0).min(OB);
        let mut i0 = 0;
        while i0 < inp {
            let ib = (inp - i0).min(IB);
            match (ob == OB, ib == IB) {
                (true, true) => dw_block::<OB, IB, FMA>(dy, x, dw, inp, o0, i0, ld),
                _ => {
                    for k in 0..ob {
                        for j in 0..ib {
                            dw_block::<1, 1, FMA>(dy, x, dw, inp, o0 + k, i0 + j, ld);
                        }
                    }
                }
            }
            i0 += ib;
        }
        o0 += ob;
    }
    for o in 0..out {
        let mut acc = [0f32; LANES];
        for base in (0..ld).step_by(LANES) {
            let d = lanes(dy, o * ld + base);
            for l in 0..LANES {
                acc[l] += d[l];
            }
        }
        db[o] += hsum(&acc);
    }
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
    #[cfg(target_arch = "x86_64")]
    {
        #[target_feature(enable = "avx512f,fma")]
        #[allow(clippy::too_many_arguments)]
        unsafe fn v512(
            w: &[f32],
            b: Option<&[f32]>,
            x: &[f32],
            y: &mut [f32],
            inp: usize,
            out: usize,
            ld: usize,
            relu: bool,
        ) {
            fwd_body::<8, true>(w, b, x, y, inp, out, ld, relu)
        }
        #[target_feature(enable = "avx2,fma")]
        #[allow(clippy::too_many_arguments)]
        unsafe fn v256(
            w: &[f32],
            b: Option<&[f32]>,
            x: &[f32],
            y: &mut [f32],
            inp: usize,
            out: usize,
            ld: usize,
            relu: bool,
        ) {
            fwd_body::<4, true>(w, b, x, y, inp, out, ld, relu)
        }
        if has_avx512() {
            // SAFETY: the CPU supports the enabled features (checked).
            return unsafe { v512(w, b, x, y, inp, out, ld, relu) };
        }
        if has_avx2() {
            // SAFETY: the CPU supports the enabled features (checked).
            return unsafe { v256(w, b, x, y, inp, out, ld, relu) };
        }
    }
    fwd_body::<4, false>(w, b, x, y, inp, out, ld, relu)
}

/// Weight gradients of a layer: `dw[o·inp + i] += Σ_n dy[o][n] · x[i][n]` and
/// `db[o] += Σ_n dy[o][n]` (each sum in lane-blocked fixed order, independent of block sizes).
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
    #[cfg(target_arch = "x86_64")]
    {
        #[target_feature(enable = "avx512f,fma")]
        #[allow(clippy::too_many_arguments)]
        unsafe fn v512(
            dy: &[f32],
            x: &[f32],
            dw: &mut [f32],
            db: &mut [f32],
            inp: usize,
            out: usize,
            ld: usize,
        ) {
            dw_body::<4, 4, true>(dy, x, dw, db, inp, out, ld)
        }
        #[target_feature(enable = "avx2,fma")]
        #[allow(clippy::too_many_arguments)]
        unsafe fn v256(
            dy: &[f32],
            x: &[f32],
            dw: &mut [f32],
            db: &mut [f32],
            inp: usize,
            out: usize,
            ld: usize,
        ) {
            dw_body::<4, 2, true>(dy, x, dw, db, inp, out, ld)
        }
        if has_avx512() {
            // SAFETY: the CPU supports the enabled features (checked).
            return unsafe { v512(dy, x, dw, db, inp, out, ld) };
        }
        if has_avx2() {
            // SAFETY: the CPU supports the enabled features (checked).
            return unsafe { v256(dy, x, dw, db, inp, out, ld) };
        }
    }
    dw_body::<4, 2, false>(dy, x, dw, db, inp, out, ld)
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
    wt.clear();
    wt.resize(inp * out, 0.0);
    for o in 0..out {
        for i in 0..inp {
            wt[i * out + o] = w[o * inp + i];
        }
    }
    linear_forward(wt, None, dy, dx, out, inp, ld, false);
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
    /// holds the (linear) network output.
    pub fn forward(&self, params: &[f32], x: &[f32], ld: usize, acts: &mut Vec<Vec<f32>>) {
        acts.resize_with(self.layers.len(), Vec::new);
        for (l, s) in self.layers.iter().enumerate() {
            let (w, b) = self.split(params, l);
            let (done, rest) = acts.split_at_mut(l);
            let input: &[f32] = if l == 0 { x } else { &done[l - 1] };
            let y = &mut rest[0];
            y.clear();
            y.resize(s.out * ld, 0.0);
            let relu = l + 1 < self.layers.len();
            linear_forward(w, Some(b), input, y, s.inp, s.out, ld, relu);
        }
    }

    /// Backward pass. `d_out` is the gradient of the network output (`out × ld`, zero in the
    /// padding columns); it is consumed as scratch. Gradients are *added* to `grad` (same
    /// layout as `params`). When `d_x` is given it receives the input gradient.
    #[allow(clippy::too_many_arguments)]
    pub fn backward(
        &self,
        params: &[f32],
        x: &[f32],
        acts: &[Vec<f32>],
        ld: usize,
        d_out: &mut Vec<f32>,
        grad: &mut [f32],
        d_x: Option<&mut Vec<f32>>,
        scratch: &mut Vec<f32>,
        wt: &mut Vec<f32>,
    ) {
        let nl = self.layers.len();
        let mut d_x = d_x;
        for l in (0..nl).rev() {
            let s = self.layers[l];
            let (w, _) = self.split(params, l);
            let off: usize = self.layers[..l].iter().map(LayerShape::params).sum();
            let (gw, gb) = grad[off..off + s.params()].split_at_mut(s.inp * s.out);
            let input: &[f32] = if l == 0 { x } else { &acts[l - 1] };
            linear_backward_weights(d_out, input, gw, gb, s.inp, s.out, ld);
            if l > 0 {
                scratch.clear();
                scratch.resize(s.inp * ld, 0.0);
                linear_backward_input(w, d_out, scratch, s.inp, s.out, ld, wt);
                relu_backward(scratch, &acts[l - 1]);
                std::mem::swap(d_out, scratch);
            } else if let Some(dx) = d_x.take() {
                dx.clear();
                dx.resize(s.inp * ld, 0.0);
                linear_backward_input(w, d_out, dx, s.inp, s.out, ld, wt);
            }
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
