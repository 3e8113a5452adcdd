//! The fused SSIM forward and backward (see the module documentation of [`super`]): bands of
//! rows, a ring of horizontal moments, a ring of per-pixel partials, and the adjoint passes
//! adding the gradient straight into the caller's buffer.

// Index loops over fixed-size moment blocks read best in small numeric code.
#![allow(clippy::needless_range_loop)]

use super::{LANES, SSIM_C1, SSIM_C2, SSIM_WINDOW};
use augsplat_core::multiversion;
use augsplat_core::simd::{self, Isa};
use rayon::prelude::*;

/// Rows (and interleaved values / 3) a window reaches past its first one.
pub(super) const HALO: usize = SSIM_WINDOW - 1;
/// The halo in interleaved values (3 channels).
pub(super) const HALO3: usize = 3 * HALO;
/// Rows in the rings of horizontal moments and of partials: one window plus one, so that
/// two consecutive map rows can be filtered together ([`vertical_pair`]).
pub(super) const RING: usize = SSIM_WINDOW + 1;
/// Rows per band of the fused SSIM for an image of `height` rows: an even number of bands
/// (two per started 256 rows; one below 48 rows) of equal height, the last one possibly
/// shorter. A function of the height only, so results do not depend on the thread count;
/// each band recomputes a 10-row halo, so fewer, taller bands waste less.
pub(super) fn band_rows(height: usize) -> usize {
    if height < 48 {
        return height.max(1);
    }
    let bands = 2 * height.div_ceil(256);
    height.div_ceil(bands)
}

/// The geometry of one SSIM evaluation, in interleaved values.
#[derive(Clone, Copy, Debug)]
pub(super) struct Geo {
    /// Image height.
    pub(super) h: usize,
    /// Interleaved row length, `3·W`.
    pub(super) l: usize,
    /// Interleaved map row length, `3·(W − 10)`.
    pub(super) m: usize,
    /// `m` rounded up to a multiple of [`LANES`].
    pub(super) mp: usize,
    /// `l` rounded up to a multiple of [`LANES`].
    pub(super) lp: usize,
    /// Map height, `H − 10`.
    pub(super) oh: usize,
}

impl Geo {
    pub(super) fn new(width: usize, height: usize) -> Self {
        let l = 3 * width;
        let m = 3 * (width - HALO);
        Geo {
            h: height,
            l,
            m,
            mp: m.div_ceil(LANES) * LANES,
            lp: l.div_ceil(LANES) * LANES,
            oh: height - HALO,
        }
    }
    /// Length of a zero-padded input row (the horizontal pass reads `mp + 30` values).
    fn rl(&self) -> usize {
        self.mp + HALO3
    }
    /// Length of a padded adjoint row: `30` zeros, `mp` values, zeros up to `lp + 30`.
    fn vl(&self) -> usize {
        self.lp + HALO3
    }
}

/// The per-task buffers of the fused SSIM (reused across calls through a thread-local).
#[derive(Default)]
pub(super) struct Scratch {
    /// Input rows x, y, x², y², xy (each `rl` long, zero tail).
    pub(super) rows: Vec<f32>,
    /// Ring of [`RING`] horizontal-moment rows: `[slot][moment][mp]`.
    pub(super) hm: Vec<f32>,
    /// Ring of [`RING`] partial rows: `[slot][partial][mp]` (tail beyond `m` kept zero).
    pub(super) part: Vec<f32>,
    /// The SSIM values of the second map row of a [`vertical_pair`] (`mp` values).
    pub(super) pair_ssim: Vec<f32>,
    /// Vertical adjoint rows, `[partial][vl]`, data at `30..30 + mp`, zeros around it.
    pub(super) vb: Vec<f32>,
    /// Horizontal adjoint rows, `[partial][lp]`.
    pub(super) hb: Vec<f32>,
}

impl Scratch {
    fn prepare(&mut self, g: &Geo) {
        let fit = |v: &mut Vec<f32>, n: usize| {
            v.clear();
            v.resize(n, 0.0);
        };
        fit(&mut self.rows, 5 * g.rl());
        fit(&mut self.hm, RING * 5 * g.mp);
        fit(&mut self.part, RING * 3 * g.mp);
        fit(&mut self.pair_ssim, g.mp);
        fit(&mut self.vb, 3 * g.vl());
        fit(&mut self.hb, 3 * g.lp);
    }
}

thread_local! {
    static SCRATCH: std::cell::RefCell<Scratch> = std::cell::RefCell::new(Scratch::default());
}

/// The pixel term fused into the SSIM pass.
#[derive(Clone, Copy, Debug, PartialEq)]
pub(super) enum Pix {
    /// None (plain SSIM).
    None,
    /// L2 with gradient factor `2·scale/n`.
    L2(f32),
    /// L1 with gradient factor `scale/n`.
    L1(f32),
}

/// What one fused call computes.
#[derive(Clone, Copy, Debug)]
pub(super) struct Fused {
    pub(super) geo: Geo,
    pub(super) win: [f32; SSIM_WINDOW],
    pub(super) pix: Pix,
    /// `scale / count`, the factor of dSSIM/dpred.
    pub(super) gs: f32,
    /// Whether gradients are written at all.
    pub(super) backward: bool,
}

/// Horizontal 11-tap filter of an interleaved row: `dst[j] = Σ_k w_k src[j + 3k]`,
/// `j < dst.len()` (a multiple of [`LANES`]; `src` is at least `dst.len() + 30` long).
#[inline(always)]
pub(super) fn hfilter(src: &[f32], dst: &mut [f32], win: &[f32; SSIM_WINDOW]) {
    for (jb, out) in dst.chunks_exact_mut(LANES).enumerate() {
        let j = jb * LANES;
        let mut acc = [0f32; LANES];
        for (k, &wk) in win.iter().enumerate() {
            let s = &src[j + 3 * k..j + 3 * k + LANES];
            for l in 0..LANES {
                acc[l] = wk.mul_add(s[l], acc[l]);
            }
        }
        out.copy_from_slice(&acc);
    }
}

/// Horizontal pass of input row `r`: the five moment rows into ring slot `r % RING`.
#[inline(always)]
pub(super) fn horizontal_row(f: &Fused, pred: &[f32], target: &[f32], r: usize, sc: &mut Scratch) {
    let g = &f.geo;
    let rl = g.rl();
    let (xr, rest) = sc.rows.split_at_mut(rl);
    let (yr, rest) = rest.split_at_mut(rl);
    let (xx, rest) = rest.split_at_mut(rl);
    let (yy, xy) = rest.split_at_mut(rl);
    xr[..g.l].copy_from_slice(&pred[r * g.l..(r + 1) * g.l]);
    yr[..g.l].copy_from_slice(&target[r * g.l..(r + 1) * g.l]);
    for i in 0..g.l {
        let (a, b) = (xr[i], yr[i]);
        xx[i] = a * a;
        yy[i] = b * b;
        xy[i] = a * b;
    }
    let slot = &mut sc.hm[(r % RING) * 5 * g.mp..(r % RING + 1) * 5 * g.mp];
    for (q, src) in [&*xr, &*yr, &*xx, &*yy, &*xy].into_iter().enumerate() {
        hfilter(src, &mut slot[q * g.mp..(q + 1) * g.mp], &f.win);
    }
}

/// SSIM of one window from its five moments, and the partials dS/dμx, dS/dE[x²], dS/dE[xy].
/// One division: with `inv = 1/(d1·d2)`, `S = n1·n2·inv`,
/// `dS/dμx = 2·inv·(μy·(n2 − n1) + μx·S·(d1 − d2))`, `dS/dE[x²] = −S·d1·inv`,
/// `dS/dE[xy] = 2·n1·inv`.
#[inline(always)]
pub(super) fn ssim_window(mx: f32, my: f32, exx: f32, eyy: f32, exy: f32) -> [f32; 4] {
    const C1: f32 = SSIM_C1 as f32;
    const C2: f32 = SSIM_C2 as f32;
    let mx2 = mx * mx;
    let my2 = my * my;
    let mxy = mx * my;
    let n1 = 2.0 * mxy + C1;
    let n2 = 2.0 * (exy - mxy) + C2;
    let d1 = mx2 + my2 + C1;
    let d2 = (exx - mx2) + (eyy - my2) + C2;
    let inv = 1.0 / (d1 * d2);
    let s = n1 * n2 * inv;
    let a = 2.0 * inv * (my * (n2 - n1) + mx * s * (d1 - d2));
    let b = -s * d1 * inv;
    let c = 2.0 * n1 * inv;
    [s, a, b, c]
}

/// SSIM and its three partials ([`ssim_window`]) of a block of windows from their five
/// moment sums, `[moment][lane]`.
#[inline(always)]
pub(super) fn ssim_block(mo: &[[f32; LANES]; 5]) -> [[f32; LANES]; 4] {
    let mut out = [[0f32; LANES]; 4];
    for l in 0..LANES {
        let r = ssim_window(mo[0][l], mo[1][l], mo[2][l], mo[3][l], mo[4][l]);
        for p in 0..4 {
            out[p][l] = r[p];
        }
    }
    out
}

/// Adds the SSIM values of the block at `j` that lie in the map (`j + l < m`) to `lanes`.
#[inline(always)]
pub(super) fn count_block(vals: &[f32; LANES], j: usize, m: usize, lanes: &mut [f64; LANES]) {
    for l in 0..LANES {
        if j + l < m {
            lanes[l] += vals[l] as f64;
        }
    }
}

/// Vertical pass of map row `oy` from ring rows `oy..oy + 11`: the partials into ring slot
/// `oy % RING` (zero beyond `m`); when `count`, the SSIM values are added to `lanes`.
#[inline(always)]
pub(super) fn vertical_row(
    f: &Fused,
    oy: usize,
    sc: &mut Scratch,
    count: bool,
    lanes: &mut [f64; LANES],
) {
    let g = &f.geo;
    let mp = g.mp;
    let hm = &sc.hm;
    let slot = oy % RING;
    let part = &mut sc.part[slot * 3 * mp..(slot + 1) * 3 * mp];
    let base: [usize; SSIM_WINDOW] = std::array::from_fn(|k| ((oy + k) % RING) * 5 * mp);
    for jb in 0..mp / LANES {
        let j = jb * LANES;
        let mut mo = [[0f32; LANES]; 5];
        for (k, &wk) in f.win.iter().enumerate() {
            for (q, mq) in mo.iter_mut().enumerate() {
                let s = &hm[base[k] + q * mp + j..base[k] + q * mp + j + LANES];
                for l in 0..LANES {
                    mq[l] = wk.mul_add(s[l], mq[l]);
                }
            }
        }
        let out = ssim_block(&mo);
        if count {
            count_block(&out[0], j, g.m, lanes);
        }
        for p in 0..3 {
            part[p * mp + j..p * mp + j + LANES].copy_from_slice(&out[p + 1]);
        }
    }
    for p in 0..3 {
        part[p * mp + g.m..(p + 1) * mp].fill(0.0);
    }
}

/// Whether [`vertical_pair`] runs on this CPU (it needs AVX2 + FMA; elsewhere map rows are
/// filtered one at a time, with the same results).
#[inline(always)]
pub(super) fn pairs_available() -> bool {
    cfg!(target_arch = "x86_64") && simd::active() == Isa::Avx2
}

/// [`vertical_row`] of map rows `oy` and `oy + 1` in one pass over the 12 moment rows they
/// read (they share 10, so the ring is read about half as often): each value's sums in the
/// same order as two single calls, so the results are bit-identical. `count` says per row
/// whether its SSIM values are added to `lanes`, row `oy`'s first (as two calls would).
/// Only called where [`pairs_available`].
#[cfg(target_arch = "x86_64")]
#[inline(always)]
pub(super) fn vertical_pair(
    f: &Fused,
    oy: usize,
    sc: &mut Scratch,
    count: [bool; 2],
    lanes: &mut [f64; LANES],
) {
    let g = &f.geo;
    let mp = g.mp;
    let (slot0, slot1) = (oy % RING, (oy + 1) % RING);
    let base: [usize; RING] = std::array::from_fn(|k| ((oy + k) % RING) * 5 * mp);
    assert!(sc.hm.len() >= RING * 5 * mp && mp.is_multiple_of(LANES));
    for jb in 0..mp / LANES {
        let j = jb * LANES;
        let mut m0 = [[0f32; LANES]; 5];
        let mut m1 = [[0f32; LANES]; 5];
        // SAFETY: `pairs_available` (checked by the caller) means AVX2 and FMA; every read
        // lies inside the ring (asserted above: base[k] + 4·mp + j + LANES ≤ RING·5·mp).
        unsafe { super::pair_avx2::moments(&sc.hm, &base, mp, j, &f.win, &mut m0, &mut m1) };
        let out = ssim_block(&m0);
        if count[0] {
            count_block(&out[0], j, g.m, lanes);
        }
        for p in 0..3 {
            let o = (slot0 * 3 + p) * mp + j;
            sc.part[o..o + LANES].copy_from_slice(&out[p + 1]);
        }
        let out = ssim_block(&m1);
        sc.pair_ssim[j..j + LANES].copy_from_slice(&out[0]);
        for p in 0..3 {
            let o = (slot1 * 3 + p) * mp + j;
            sc.part[o..o + LANES].copy_from_slice(&out[p + 1]);
        }
    }
    for slot in [slot0, slot1] {
        for p in 0..3 {
            let o = (slot * 3 + p) * mp;
            sc.part[o + g.m..o + mp].fill(0.0);
        }
    }
    // Row oy + 1's SSIM values after all of row oy's, as two single calls add them.
    if count[1] {
        for (i, &v) in sc.pair_ssim[..g.m].iter().enumerate() {
            lanes[i % LANES] += v as f64;
        }
    }
}

/// The backward of input row `y` (`y − a` in the band's gradient rows `grow`): vertical
/// gather of the partial rows, horizontal gather, chain rule, plus the pixel term.
#[inline(always)]
pub(super) fn gradient_row<const P: u8>(
    f: &Fused,
    pred: &[f32],
    target: &[f32],
    y: usize,
    grow: &mut [f32],
    sc: &mut Scratch,
    pix_lanes: &mut [f64; LANES],
) {
    let g = &f.geo;
    let (mp, vl, lp) = (g.mp, g.vl(), g.lp);
    // Vertical adjoint: map rows y − k, k ∈ [klo, khi], each in the partial ring.
    let klo = (y + 1).saturating_sub(g.oh);
    let khi = y.min(HALO);
    {
        let part = &sc.part;
        let vb = &mut sc.vb;
        for jb in 0..mp / LANES {
            let j = jb * LANES;
            let mut acc = [[0f32; LANES]; 3];
            for k in klo..=khi {
                let wk = f.win[k];
                let slot = (y - k) % RING;
                for (p, ap) in acc.iter_mut().enumerate() {
                    let o = (slot * 3 + p) * mp + j;
                    let s = &part[o..o + LANES];
                    for l in 0..LANES {
                        ap[l] = wk.mul_add(s[l], ap[l]);
                    }
                }
            }
            for (p, ap) in acc.iter().enumerate() {
                vb[p * vl + HALO3 + j..p * vl + HALO3 + j + LANES].copy_from_slice(ap);
            }
        }
    }
    // Horizontal adjoint: hb[i] = Σ_k w_k vb[30 + i − 3k].
    for p in 0..3 {
        let src = &sc.vb[p * vl..(p + 1) * vl];
        let dst = &mut sc.hb[p * lp..(p + 1) * lp];
        for (ib, out) in dst.chunks_exact_mut(LANES).enumerate() {
            let i = ib * LANES + HALO3;
            let mut acc = [0f32; LANES];
            for (k, &wk) in f.win.iter().enumerate() {
                let s = &src[i - 3 * k..i - 3 * k + LANES];
                for l in 0..LANES {
                    acc[l] = wk.mul_add(s[l], acc[l]);
                }
            }
            out.copy_from_slice(&acc);
        }
    }
    // Chain rule through the moments, plus the pixel term.
    let xr = &pred[y * g.l..(y + 1) * g.l];
    let tr = &target[y * g.l..(y + 1) * g.l];
    let (ha, rest) = sc.hb.split_at(lp);
    let (hbb, hc) = rest.split_at(lp);
    let k = match f.pix {
        Pix::None => 0.0,
        Pix::L2(k) | Pix::L1(k) => k,
    };
    let gs = f.gs;
    let full = g.l / LANES * LANES;
    let mut acc = *pix_lanes;
    for (ib, gc) in grow[..full].chunks_exact_mut(LANES).enumerate() {
        let i = ib * LANES;
        let (x, t) = (&xr[i..i + LANES], &tr[i..i + LANES]);
        let (a, b, c) = (&ha[i..i + LANES], &hbb[i..i + LANES], &hc[i..i + LANES]);
        for l in 0..LANES {
            gc[l] = combine::<P>(gs, k, x[l], t[l], a[l], b[l], c[l], gc[l], &mut acc[l]);
        }
    }
    for (l, gv) in grow[full..g.l].iter_mut().enumerate() {
        let i = full + l;
        *gv = combine::<P>(gs, k, xr[i], tr[i], ha[i], hbb[i], hc[i], *gv, &mut acc[l]);
    }
    *pix_lanes = acc;
}

/// [`Pix`] as a const parameter: no pixel term.
pub(super) const PIX_NONE: u8 = 0;
/// L2 pixel term.
pub(super) const PIX_L2: u8 = 1;
/// L1 pixel term.
pub(super) const PIX_L1: u8 = 2;

/// The chain rule through the moments for one value (`dS/dx = A + 2x·B + y·C`, scaled),
/// plus the pixel term; returns the new gradient value and adds the pixel loss into `acc`.
#[inline(always)]
#[allow(clippy::too_many_arguments)]
pub(super) fn combine<const P: u8>(
    gs: f32,
    k: f32,
    x: f32,
    t: f32,
    a: f32,
    b: f32,
    c: f32,
    gv: f32,
    acc: &mut f64,
) -> f32 {
    let d = t.mul_add(c, (2.0 * x).mul_add(b, a));
    let diff = x - t;
    let base = match P {
        PIX_L2 => {
            *acc += (diff as f64) * (diff as f64);
            k.mul_add(diff, gv)
        }
        PIX_L1 => {
            *acc += diff.abs() as f64;
            l1_step(diff, k, gv)
        }
        _ => gv,
    };
    gs.mul_add(d, base)
}

/// `gv ± k` by the sign of `diff` (unchanged at 0): the L1 subgradient step.
#[inline(always)]
pub(super) fn l1_step(diff: f32, k: f32, gv: f32) -> f32 {
    if diff > 0.0 {
        gv + k
    } else if diff < 0.0 {
        gv - k
    } else {
        gv
    }
}

/// The pixel-term sum of row `y` without gradients (forward-only calls).
#[inline(always)]
pub(super) fn pixel_sum_row(
    f: &Fused,
    pred: &[f32],
    target: &[f32],
    y: usize,
    acc: &mut [f64; LANES],
) {
    let l = f.geo.l;
    let xr = &pred[y * l..(y + 1) * l];
    let tr = &target[y * l..(y + 1) * l];
    for i in 0..l {
        let diff = xr[i] - tr[i];
        acc[i % LANES] += match f.pix {
            Pix::None => 0.0,
            Pix::L2(_) => (diff as f64) * (diff as f64),
            Pix::L1(_) => diff.abs() as f64,
        };
    }
}

/// One band: gradient rows `a..b` (`grad` holds exactly those rows). Returns the lane sums
/// of (pixel term over rows `a..b`, SSIM over map rows `a..min(b, oh)`).
#[inline(always)]
pub(super) fn band_body(
    f: &Fused,
    pred: &[f32],
    target: &[f32],
    a: usize,
    b: usize,
    grad: &mut [f32],
    sc: &mut Scratch,
) -> ([f64; LANES], [f64; LANES]) {
    match f.pix {
        Pix::None => band_impl::<PIX_NONE>(f, pred, target, a, b, grad, sc),
        Pix::L2(_) => band_impl::<PIX_L2>(f, pred, target, a, b, grad, sc),
        Pix::L1(_) => band_impl::<PIX_L1>(f, pred, target, a, b, grad, sc),
    }
}

/// [`band_body`] for one pixel term.
#[inline(always)]
pub(super) fn band_impl<const P: u8>(
    f: &Fused,
    pred: &[f32],
    target: &[f32],
    a: usize,
    b: usize,
    grad: &mut [f32],
    sc: &mut Scratch,
) -> ([f64; LANES], [f64; LANES]) {
    let g = &f.geo;
    let mut pix = [0f64; LANES];
    let mut ssim = [0f64; LANES];
    // Map rows this band evaluates: its own, plus (for the backward) the 10 above.
    let oy0 = if f.backward {
        a.saturating_sub(HALO)
    } else {
        a
    };
    let oy1 = g.oh.min(b);
    for r in oy0..(oy0 + HALO).min(g.h) {
        horizontal_row(f, pred, target, r, sc);
    }
    let pairs = pairs_available();
    let mut oy = oy0;
    while oy < oy1 {
        // Two map rows at a time where there are two left (and the paired kernel runs).
        let rows = if pairs && oy + 1 < oy1 { 2 } else { 1 };
        for r in 0..rows {
            horizontal_row(f, pred, target, oy + r + HALO, sc);
        }
        if rows == 2 {
            #[cfg(target_arch = "x86_64")]
            vertical_pair(f, oy, sc, [oy >= a, oy + 1 >= a], &mut ssim);
        } else {
            vertical_row(f, oy, sc, oy >= a, &mut ssim);
        }
        for y in oy..oy + rows {
            if f.backward && y >= a {
                let o = (y - a) * g.l;
                gradient_row::<P>(f, pred, target, y, &mut grad[o..o + g.l], sc, &mut pix);
            }
        }
        oy += rows;
    }
    for y in a.max(g.oh)..b {
        if f.backward {
            let o = (y - a) * g.l;
            gradient_row::<P>(f, pred, target, y, &mut grad[o..o + g.l], sc, &mut pix);
        }
    }
    if !f.backward && f.pix != Pix::None {
        for y in a..b {
            pixel_sum_row(f, pred, target, y, &mut pix);
        }
    }
    (pix, ssim)
}

multiversion!(fn band(
    f: &Fused,
    pred: &[f32],
    target: &[f32],
    a: usize,
    b: usize,
    grad: &mut [f32],
    sc: &mut Scratch,
) -> ([f64; LANES], [f64; LANES]) => band_body);

/// Sums lane accumulators in a fixed order.
pub(super) fn lane_sum(l: &[f64; LANES]) -> f64 {
    l.iter().sum()
}

/// The fused pass: returns (pixel-term sum, SSIM sum) and adds the scaled gradients.
pub(super) fn fused(f: &Fused, pred: &[f32], target: &[f32], grad: &mut [f32]) -> (f64, f64) {
    let g = f.geo;
    let rows = band_rows(g.h);
    let parts: Vec<([f64; LANES], [f64; LANES])> = grad
        .par_chunks_mut(rows * g.l)
        .enumerate()
        .map(|(bi, gb)| {
            let a = bi * rows;
            let b = (a + rows).min(g.h);
            SCRATCH.with(|s| {
                let mut sc = s.borrow_mut();
                sc.prepare(&g);
                band(f, pred, target, a, b, gb, &mut sc)
            })
        })
        .collect();
    let mut pix = 0.0;
    let mut ssim = 0.0;
    for (p, s) in &parts {
        pix += lane_sum(p);
        ssim += lane_sum(s);
    }
    (pix, ssim)
}
