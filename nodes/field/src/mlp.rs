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
pub(crate) fn hsum(a: &[f32; LANES]) -> f32 {
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
    check_lengths(w.len(), inp * out, "weights");
    check_lengths(x.len(), inp * ld, "input batch");
    check_lengths(y.len(), out * ld, "output batch");
    if let Some(b) = b {
        check_lengths(b.len(), out, "biases");
    }
    #[cfg(target_arch = "x86_64")]
    {
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
            let store = if relu {
                crate::gemm512::Store::Relu
            } else {
                crate::gemm512::Store::Linear
            };
            // SAFETY: the CPU supports AVX-512F (checked); lengths checked above.
            return unsafe { crate::gemm512::forward(w, b, x, y, inp, out, ld, store) };
        }
        if has_avx2() {
            // SAFETY: the CPU supports the enabled features (checked).
            return unsafe { v256(w, b, x, y, inp, out, ld, relu) };
        }
    }
    fwd_body::<4, false>(w, b, x, y, inp, out, ld, relu)
}

/// Weight gradients of a layer: `dw[o·inp + i] += Σ_n dy[o][n] · x[i][n]` and
/// `db[o] += Σ_n dy[o][n]`. Each sum runs in a fixed order that does not depend on block
/// sizes: with AVX-512, `dw` is the sequential fused sum over the batch columns; the other
/// paths sum 16 lane-strided partial sums and combine them pairwise (as `db` does everywhere).
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
    check_lengths(dy.len(), out * ld, "output gradient");
    check_lengths(x.len(), inp * ld, "input batch");
    check_lengths(dw.len(), inp * out, "weight gradient");
    check_lengths(db.len(), out, "bias gradient");
    #[cfg(target_arch = "x86_64")]
    {
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
            // SAFETY: the CPU supports AVX-512F (checked); lengths checked above.
            return unsafe { crate::gemm512::backward_weights(dy, x, dw, db, inp, out, ld) };
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
    linear_backward_input_masked(w, dy, dx, inp, out, ld, wt, None)
}

/// [`linear_backward_input`] followed by [`relu_backward`] with `mask` (the post-activation
/// output of the layer below, laid out like `dx`), fused into the kernel's store where the
/// CPU allows.
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
    check_lengths(w.len(), inp * out, "weights");
    check_lengths(dy.len(), out * ld, "output gradient");
    check_lengths(dx.len(), inp * ld, "input gradient");
    wt.clear();
    wt.resize(inp * out, 0.0);
    for o in 0..out {
        for i in 0..inp {
            wt[i * out + o] = w[o * inp + i];
        }
    }
    #[cfg(target_arch = "x86_64")]
    if has_avx512() {
        let store = match mask {
            Some(m) => {
                check_lengths(m.len(), inp * ld, "ReLU mask");
                crate::gemm512::Store::MaskPositive(m)
            }
            None => crate::gemm512::Store::Linear,
        };
        // SAFETY: the CPU supports AVX-512F (checked); lengths checked above.
        unsafe { crate::gemm512::forward(wt, None, dy, dx, out, inp, ld, store) };
        return;
    }
    linear_forward(wt, None, dy, dx, out, inp, ld, false);
    if let Some(m) = mask {
        relu_backward(&mut dx[..inp * ld], &m[..inp * ld]);
    }
}

/// Panics with a message naming the buffer when a kernel argument is too short (a caller bug,
/// never data-dependent: shapes come from the layer definitions).
#[inline]
fn check_lengths(have: usize, need: usize, what: &str) {
    assert!(
        have >= need,
        "dense-layer kernel: {what} has {have} floats, needs {need}"
    );
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
            // Every element of `y[..out·ld]` is overwritten: no need to clear it first.
            y.resize(s.out * ld, 0.0);
            let relu = l + 1 < self.layers.len();
            linear_forward(
                w,
                Some(b),
                input,
                &mut y[..s.out * ld],
                s.inp,
                s.out,
                ld,
                relu,
            );
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
            // The input-gradient kernels overwrite all of `[..inp·ld]`: no clearing needed.
            if l > 0 {
                scratch.resize(s.inp * ld, 0.0);
                scratch.truncate(s.inp * ld);
                linear_backward_input_masked(
                    w,
                    d_out,
                    scratch,
                    s.inp,
                    s.out,
                    ld,
                    wt,
                    Some(&acts[l - 1][..s.inp * ld]),
                );
                std::mem::swap(d_out, scratch);
            } else if let Some(dx) = d_x.take() {
                dx.resize(s.inp * ld, 0.0);
                dx.truncate(s.inp * ld);
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
