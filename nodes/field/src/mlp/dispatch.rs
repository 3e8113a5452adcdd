//! Dispatch of the dense-layer kernels by [`augsplat_core::simd::active`], and the padding of
//! the weight-gradient accumulators that every tier shares.
//!
//! | tier | forward / input gradient | weight gradient |
//! |---|---|---|
//! | `Avx2` | [`super::avx2::forward`] (fused) | [`super::avx2::backward_weights`] (fused) |
//! | `Portable` | [`fwd_body`] without fused multiply-adds | [`dw_body`] without them |
//!
//! The portable tier does not fuse, so its bits differ from the AVX2 tier's in the last place;
//! the portable kernels *with* fused multiply-adds give exactly the AVX2 bits (the tests
//! compare them).

use super::portable::{dw_body, fwd_body, hsum};
use super::{Gemm, Store, WeightGrad, LANES};
#[cfg(target_arch = "x86_64")]
use augsplat_core::simd::{self, Isa};

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

/// Forward-style product `g` into `y` (rows `ldy` apart) over the columns `< g.ncols`
/// (dispatch).
pub(super) fn product(g: Gemm<'_>, y: &mut [f32], ldy: usize) {
    let Gemm {
        w,
        b,
        x,
        ldx,
        inp,
        out,
        ncols,
        store,
    } = g;
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
    if simd::active() == Isa::Avx2 {
        // SAFETY: `active` returns `Avx2` only on CPUs with its features; shapes checked above.
        return unsafe { super::avx2::forward(g, y, ldy) };
    }
    fwd_body::<4, false>(g, y, ldy)
}

/// Weight-gradient accumulation `g` over the columns `< g.ncols` into a padded `dwp`
/// (`out × inp_pad`) and per-lane bias sums; `xt` is transpose scratch (dispatch).
pub(super) fn weight_grad(
    g: WeightGrad<'_>,
    dwp: &mut [f32],
    lane_sums: &mut [f32],
    xt: &mut Vec<f32>,
) {
    let (inp, out) = (g.inp, g.out);
    check_rows(g.dy.len(), out, g.lddy, g.ncols, "output gradient");
    check_rows(g.x.len(), inp, g.ldx, g.ncols, "input batch");
    assert!(
        dwp.len() >= out * inp.div_ceil(LANES) * LANES && lane_sums.len() >= out * LANES,
        "dense-layer kernel: gradient accumulators too short"
    );
    #[cfg(target_arch = "x86_64")]
    if simd::active() == Isa::Avx2 {
        // SAFETY: `active` returns `Avx2` only on CPUs with its features; shapes checked above.
        return unsafe { super::avx2::backward_weights(g, dwp, lane_sums, xt) };
    }
    dw_body::<false>(g, dwp, lane_sums, xt)
}

/// Copies `dw` (`out × inp`) into a padded `dwp` (`out × inp_pad`, zero padding).
pub(super) fn pad_weights(dw: &[f32], dwp: &mut [f32], inp: usize, out: usize) {
    let inp_pad = inp.div_ceil(LANES) * LANES;
    for o in 0..out {
        dwp[o * inp_pad..o * inp_pad + inp].copy_from_slice(&dw[o * inp..(o + 1) * inp]);
        dwp[o * inp_pad + inp..(o + 1) * inp_pad].fill(0.0);
    }
}

/// Writes the padded accumulators back: `dw` from `dwp`, `db[o] += hsum(lane_sums[o])`.
pub(super) fn unpad_weights(
    dwp: &[f32],
    lane_sums: &[f32],
    dw: &mut [f32],
    db: &mut [f32],
    inp: usize,
) {
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

/// Transposed weights (`inp × out`) into `wt`.
pub(super) fn transpose_weights(w: &[f32], wt: &mut [f32], inp: usize, out: usize) {
    for o in 0..out {
        for i in 0..inp {
            wt[i * out + o] = w[o * inp + i];
        }
    }
}
