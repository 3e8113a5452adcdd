//! Tests of the dense-layer kernels: every tier against `f64` sums, the AVX2 kernels against
//! the portable twin bit for bit, and the blocked MLP passes against whole-batch layers.

use super::portable::{dw_body, fwd_body, hsum};
use super::*;
use augsplat_core::simd::{for_each_isa, Isa};
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

/// The portable twin of the forward-style kernels with the fusing of `isa`'s kernels: the AVX2
/// tier fuses every multiply-add, the portable tier none.
fn twin_forward(isa: Isa, g: Gemm<'_>, y: &mut [f32], ldy: usize) {
    if isa == Isa::Portable {
        fwd_body::<4, false>(g, y, ldy)
    } else {
        fwd_body::<4, true>(g, y, ldy)
    }
}

/// The portable twin of the weight-gradient kernel with the fusing of `isa`'s kernels.
fn twin_weight_grad(
    isa: Isa,
    g: WeightGrad<'_>,
    dwp: &mut [f32],
    lane_sums: &mut [f32],
    xt: &mut Vec<f32>,
) {
    if isa == Isa::Portable {
        dw_body::<false>(g, dwp, lane_sums, xt)
    } else {
        dw_body::<true>(g, dwp, lane_sums, xt)
    }
}

/// Every kernel, dispatched in every tier this CPU supports, against f64 sums, for shapes
/// that exercise all tile remainders (odd widths, 1–4 column vectors, long batches that span
/// several transposed blocks).
#[test]
fn kernels_match_f64_sums() {
    for_each_isa("mlp kernels against f64 sums", |_| {
        kernels_match_f64_sums_once()
    });
}

fn kernels_match_f64_sums_once() {
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
        let shape = LayerShape { inp, out };
        linear_forward(&w, Some(&b), &x, &mut y, shape, ld, true);
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
        linear_backward_input_masked(&w, &dy, &mut dx, shape, ld, &mut wt, Some(&mask));
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
        linear_backward_weights(&dy, &x, &mut dw, &mut db, shape, ld);
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

/// The portable kernels without fused multiply-adds (the portable tier), called directly,
/// against f64 sums, with separate row strides.
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
            let g = Gemm {
                w: &w,
                b: Some(&b),
                x: &x,
                ldx: ld,
                inp,
                out,
                ncols: ld,
                store,
            };
            fwd_body::<4, false>(g, &mut y, ldy);
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
        let g = WeightGrad {
            dy: &dy,
            lddy: ld,
            x: &x,
            ldx: ld,
            inp,
            out,
            ncols: ld,
        };
        dw_body::<false>(g, &mut dwp, &mut lane_sums, &mut xt);
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
/// kernel calls (the blocking is not part of the result), in every tier.
#[test]
fn blocked_mlp_matches_whole_batch_layers_bitwise() {
    for_each_isa("blocked MLP against whole-batch layers", |_| {
        blocked_mlp_matches_whole_batch_layers_once()
    });
}

fn blocked_mlp_matches_whole_batch_layers_once() {
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
    let mut scratch = BackwardScratch::default();
    let d_out = d_top.clone();
    let pass = ForwardPass {
        params: &params,
        x: &x,
        acts: &acts,
        ld,
    };
    let all_rows = InputGrad {
        d_x: &mut dx,
        rows: usize::MAX,
    };
    mlp.backward(pass, &d_out, &mut grad, Some(all_rows), &mut scratch);
    // Whole-batch reference with the public per-layer kernels.
    let mut want_acts: Vec<Vec<f32>> = Vec::new();
    for (l, s) in mlp.layers.iter().enumerate() {
        let (w, b) = mlp.split(&params, l);
        let mut y = vec![0f32; s.out * ld];
        let input = if l == 0 { &x } else { &want_acts[l - 1] };
        linear_forward(w, Some(b), input, &mut y, *s, ld, l + 1 < mlp.layers.len());
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
        linear_backward_weights(&d, input, gw, gb, s, ld);
        let mut nd = vec![0f32; s.inp * ld];
        let mask = if l > 0 {
            Some(&want_acts[l - 1][..])
        } else {
            None
        };
        linear_backward_input_masked(w, &d, &mut nd, s, ld, &mut wt, mask);
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
    let rows15 = InputGrad {
        d_x: &mut dx15,
        rows: 15,
    };
    mlp.backward(pass, &d_out, &mut grad15, Some(rows15), &mut scratch);
    assert_eq!(grad15, want_grad);
    assert_eq!(dx15, want_dx[..15 * ld]);
}

/// `f64` value of `b[o] + Σ_i w[o·inp + i] · x[i][c]` after `store`, for the operands of `g`.
fn fwd_ref(g: Gemm<'_>, o: usize, c: usize) -> f64 {
    let Gemm {
        w,
        b,
        x,
        ldx,
        inp,
        store,
        ..
    } = g;
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

/// The dispatched kernels of every tier give exactly the bits of the portable twin with that
/// tier's fusing (the AVX2 register-blocked kernels: the portable kernels with fused
/// multiply-adds), for the real layer shapes (forward and the transposed input-gradient
/// products), tile remainders of every size, column counts that are odd multiples of
/// [`LANES`], separate row strides, all store modes, with and without bias; and they agree
/// with `f64` sums.
#[test]
fn tier_kernels_match_portable_bitwise() {
    for_each_isa(
        "mlp kernels against the portable twin",
        tier_kernels_match_portable_once,
    );
}

fn tier_kernels_match_portable_once(isa: Isa) {
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
                let g = Gemm {
                    w: &w,
                    b: bias,
                    x: &x,
                    ldx,
                    inp,
                    out,
                    ncols,
                    store,
                };
                // Padding columns past `ncols` must stay untouched.
                let mut got = vec![f32::NAN; out * ldy];
                let mut want = got.clone();
                product(g, &mut got, ldy);
                twin_forward(isa, g, &mut want, ldy);
                let bits = |v: &[f32]| v.iter().map(|f| f.to_bits()).collect::<Vec<_>>();
                assert_eq!(
                    bits(&got),
                    bits(&want),
                    "fwd {inp}->{out} x{ncols} mode {mode}"
                );
                for o in 0..out {
                    for c in 0..ncols {
                        let r = fwd_ref(g, o, c);
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
        let g = WeightGrad {
            dy: &dy,
            lddy: ldy,
            x: &x,
            ldx,
            inp,
            out,
            ncols,
        };
        weight_grad(g, &mut dwp, &mut ls, &mut xt_a);
        twin_weight_grad(isa, g, &mut want_dwp, &mut want_ls, &mut xt_b);
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

/// Non-finite values flow through the forward kernel of every tier as through the portable
/// twin: ReLU maps NaN to 0, the mask keeps or zeroes NaN and infinities alike.
#[test]
fn forward_handles_non_finite_like_portable() {
    for_each_isa(
        "mlp forward with non-finite values",
        forward_non_finite_once,
    );
}

fn forward_non_finite_once(isa: Isa) {
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
        let g = Gemm {
            w: &w,
            b: None,
            x: &x,
            ldx: ld,
            inp,
            out,
            ncols: ld,
            store,
        };
        let mut got = vec![0f32; out * ld];
        let mut want = vec![0f32; out * ld];
        product(g, &mut got, ld);
        twin_forward(isa, g, &mut want, ld);
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
/// the first and past the last) are never touched. Every tier runs (the portable one
/// against itself, through the dispatch).
#[test]
fn forward_any_row_alignment_matches_portable() {
    for_each_isa(
        "mlp forward at every row alignment",
        forward_any_alignment_once,
    );
}

fn forward_any_alignment_once(isa: Isa) {
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
                        let g = Gemm {
                            w: &w,
                            b: bias,
                            x,
                            ldx: ld,
                            inp,
                            out,
                            ncols,
                            store,
                        };
                        product(g, &mut got[span..span + out * ld], ld);
                        twin_forward(isa, g, &mut want[span..span + out * ld], ld);
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

/// The AVX2 8×8 in-register transpose (the weight gradient's building block) transposes.
#[test]
fn transpose8_is_a_transpose() {
    for_each_isa("avx2 8x8 transpose", |isa| {
        #[cfg(target_arch = "x86_64")]
        if isa == Isa::Avx2 {
            let src: [f32; 64] = std::array::from_fn(|i| i as f32);
            let mut dst = [0f32; 64];
            // SAFETY: `for_each_isa` runs the AVX2 tier only on CPUs that support it.
            unsafe { super::avx2::transpose8_slice(&src, &mut dst) };
            for r in 0..8 {
                for c in 0..8 {
                    assert_eq!(dst[c * 8 + r], src[r * 8 + c], "({r},{c})");
                }
            }
        }
        let _ = isa;
    });
}
