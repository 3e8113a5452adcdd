//! Convolution as im2col + a blocked f32 GEMM, with ReLU fused.
//!
//! `out[M × N] = relu(W[M × K] · cols[K × N] + bias)` where M = output channels,
//! K = C_in · kh · kw and N = output pixels (CHW layout in and out).
//!
//! - Weights are packed once into MR-row panels ([`PackedWeights`]).
//! - Output pixels are cut into fixed tiles of [`TILE_N`] columns; rayon runs the tiles. Each
//!   tile writes its im2col columns straight into NR-column packed panels, then runs the
//!   micro-kernel over K in blocks of [`KC`] (A block in L2, B micro-panel in L1).
//! - Every output element is one accumulator that adds its K products in increasing k order,
//!   whatever the tiling or thread count: results are bit-identical for any number of threads.
//! - The micro-kernel is the one of the instruction-set tier ([`augsplat_core::simd::active`])
//!   when the weights are packed: AVX2 + FMA (6×16) or portable Rust (4×16). The tile shape
//!   does not change any sum, but the AVX2 kernel fuses its multiply-adds and the portable one
//!   does not, so the two tiers may differ in the last bits; one tier always gives the same
//!   bits.

use augsplat_core::simd::{self, Isa};
use rayon::prelude::*;

/// Output pixels per parallel tile.
pub const TILE_N: usize = 256;
/// K block length.
pub const KC: usize = 256;

/// Columns of the micro-tile (two ymm registers in the AVX2 tier).
pub const NR: usize = 16;

/// Rows of the micro-tile of a tier's kernel: 6 with AVX2 + FMA (12 ymm accumulators), 4 in
/// the portable kernel.
pub fn micro_rows(isa: Isa) -> usize {
    match isa {
        Isa::Avx2 => 6,
        Isa::Portable => 4,
    }
}

/// Convolution weights packed for the micro-kernel: panels of MR output channels, each panel
/// holding MR consecutive values per k (zero rows pad the last panel).
#[derive(Clone, Debug)]
pub struct PackedWeights {
    isa: Isa,
    /// Output channels.
    pub m: usize,
    /// Input channels.
    pub c_in: usize,
    /// Kernel height.
    pub kh: usize,
    /// Kernel width.
    pub kw: usize,
    data: Vec<f32>,
    bias: Vec<f32>,
}

impl PackedWeights {
    /// Packs OIHW weights `[m, c_in, kh, kw]` and a bias of length m for the micro-kernel of
    /// the active tier ([`augsplat_core::simd::active`]).
    ///
    /// Panics if the slice lengths do not match the shape (callers check shapes first).
    pub fn new(weights: &[f32], bias: &[f32], m: usize, c_in: usize, kh: usize, kw: usize) -> Self {
        Self::with_isa(simd::active(), weights, bias, m, c_in, kh, kw)
    }

    /// As [`PackedWeights::new`] for the micro-kernel of tier `isa`, capped by what the CPU
    /// supports.
    pub fn with_isa(
        isa: Isa,
        weights: &[f32],
        bias: &[f32],
        m: usize,
        c_in: usize,
        kh: usize,
        kw: usize,
    ) -> Self {
        let isa = isa.min(Isa::detect());
        let k = c_in * kh * kw;
        assert_eq!(weights.len(), m * k, "weight length");
        assert_eq!(bias.len(), m, "bias length");
        let mr = micro_rows(isa);
        let panels = m.div_ceil(mr);
        let mut data = vec![0f32; panels * k * mr];
        for row in 0..m {
            let (p, r) = (row / mr, row % mr);
            for kk in 0..k {
                data[p * k * mr + kk * mr + r] = weights[row * k + kk];
            }
        }
        PackedWeights {
            isa,
            m,
            c_in,
            kh,
            kw,
            data,
            bias: bias.to_vec(),
        }
    }

    /// The tier whose micro-kernel these weights are packed for.
    pub fn isa(&self) -> Isa {
        self.isa
    }

    fn k(&self) -> usize {
        self.c_in * self.kh * self.kw
    }
}

/// Output size of a convolution or pooling window along one axis (floor mode), or `None`
/// when the input is too small.
pub fn out_size(input: usize, kernel: usize, stride: usize, pad: usize) -> Option<usize> {
    (input + 2 * pad)
        .checked_sub(kernel)
        .map(|v| v / stride + 1)
}

/// `relu(conv2d(input, w) + b)` for a CHW input of size `c_in × h × w`; returns the CHW
/// output and its height and width. Zero padding `pad` on every side.
///
/// Panics if `input.len() != c_in·h·w` or the output would be empty (callers check sizes).
pub fn conv2d_relu(
    input: &[f32],
    h: usize,
    w: usize,
    weights: &PackedWeights,
    stride: usize,
    pad: usize,
) -> (Vec<f32>, usize, usize) {
    assert_eq!(input.len(), weights.c_in * h * w, "input length");
    let oh = out_size(h, weights.kh, stride, pad).expect("input smaller than kernel");
    let ow = out_size(w, weights.kw, stride, pad).expect("input smaller than kernel");
    let n = oh * ow;
    // Zero-pad once so that im2col needs no bounds checks.
    let (hp, wp) = (h + 2 * pad, w + 2 * pad);
    let padded: std::borrow::Cow<'_, [f32]> = if pad == 0 {
        std::borrow::Cow::Borrowed(input)
    } else {
        let mut p = vec![0f32; weights.c_in * hp * wp];
        p.par_chunks_mut(hp * wp)
            .zip(input.par_chunks(h * w))
            .for_each(|(dst, src)| {
                for y in 0..h {
                    dst[(y + pad) * wp + pad..(y + pad) * wp + pad + w]
                        .copy_from_slice(&src[y * w..(y + 1) * w]);
                }
            });
        std::borrow::Cow::Owned(p)
    };
    let geo = Geometry {
        hp,
        wp,
        ow,
        stride,
        kh: weights.kh,
        kw: weights.kw,
        c_in: weights.c_in,
    };
    let tiles: Vec<Vec<f32>> = (0..n.div_ceil(TILE_N))
        .into_par_iter()
        .map_init(Vec::new, |bbuf, t| {
            let n0 = t * TILE_N;
            let nt = TILE_N.min(n - n0);
            tile(&padded, &geo, weights, n0, nt, bbuf)
        })
        .collect();
    let (mr, nr) = (micro_rows(weights.isa), NR);
    let mut out = vec![0f32; weights.m * n];
    out.par_chunks_mut(n).enumerate().for_each(|(row, dst)| {
        let (p, r) = (row / mr, row % mr);
        let b = weights.bias[row];
        for (t, buf) in tiles.iter().enumerate() {
            let n0 = t * TILE_N;
            let nt = TILE_N.min(n - n0);
            let npan = nt.div_ceil(nr);
            for j in 0..npan {
                let src = &buf[((p * npan + j) * mr + r) * nr..][..nr];
                let cols = nr.min(nt - j * nr);
                let d = &mut dst[n0 + j * nr..n0 + j * nr + cols];
                for (o, &v) in d.iter_mut().zip(src) {
                    *o = (v + b).max(0.0);
                }
            }
        }
    });
    (out, oh, ow)
}

struct Geometry {
    hp: usize,
    wp: usize,
    ow: usize,
    stride: usize,
    kh: usize,
    kw: usize,
    c_in: usize,
}

/// One output tile: im2col (from the zero-padded input) into packed panels, then the blocked
/// GEMM; returns the tile's accumulators in panel order `[m panel][n panel][MR × NR]`.
/// `b` is a reusable buffer whose content does not matter.
fn tile(
    padded: &[f32],
    g: &Geometry,
    wts: &PackedWeights,
    n0: usize,
    nt: usize,
    b: &mut Vec<f32>,
) -> Vec<f32> {
    let isa = wts.isa;
    let (mr, nr) = (micro_rows(isa), NR);
    let k = wts.k();
    let npan = nt.div_ceil(nr);
    let mpan = wts.m.div_ceil(mr);
    b.resize(npan * k * nr, 0.0);
    let plane = g.hp * g.wp;
    let s = g.stride;
    let mut base = vec![0usize; nr];
    for j in 0..npan {
        let cols = nr.min(nt - j * nr);
        let panel = &mut b[j * k * nr..(j + 1) * k * nr];
        let col0 = n0 + j * nr;
        let (oy0, ox0) = (col0 / g.ow, col0 % g.ow);
        if cols < nr {
            // Partial panel: the unused columns must be zero.
            for kk in 0..k {
                panel[kk * nr + cols..(kk + 1) * nr].fill(0.0);
            }
        }
        if ox0 + cols <= g.ow {
            // All columns in one output row: contiguous (stride 1) or strided reads.
            let row0 = oy0 * s * g.wp + ox0 * s;
            let mut kk = 0;
            for ci in 0..g.c_in {
                for ky in 0..g.kh {
                    for kx in 0..g.kw {
                        let src = &padded[ci * plane + row0 + ky * g.wp + kx..];
                        let dst = &mut panel[kk * nr..kk * nr + cols];
                        if s == 1 {
                            dst.copy_from_slice(&src[..cols]);
                        } else {
                            for (d, v) in dst.iter_mut().zip(src.iter().step_by(s)) {
                                *d = *v;
                            }
                        }
                        kk += 1;
                    }
                }
            }
        } else {
            for (t, bs) in base.iter_mut().enumerate().take(cols) {
                let col = col0 + t;
                *bs = (col / g.ow) * s * g.wp + (col % g.ow) * s;
            }
            let mut kk = 0;
            for ci in 0..g.c_in {
                for ky in 0..g.kh {
                    for kx in 0..g.kw {
                        let off = ci * plane + ky * g.wp + kx;
                        let dst = &mut panel[kk * nr..kk * nr + cols];
                        for (d, &bs) in dst.iter_mut().zip(&base) {
                            *d = padded[bs + off];
                        }
                        kk += 1;
                    }
                }
            }
        }
    }
    let mut c = vec![0f32; mpan * npan * mr * nr];
    let mut k0 = 0;
    while k0 < k {
        let kc = KC.min(k - k0);
        for j in 0..npan {
            let bp = &b[j * k * nr + k0 * nr..j * k * nr + (k0 + kc) * nr];
            for i in 0..mpan {
                let ap = &wts.data[i * k * mr + k0 * mr..i * k * mr + (k0 + kc) * mr];
                let cp = &mut c[(i * npan + j) * mr * nr..(i * npan + j + 1) * mr * nr];
                micro_kernel(isa, kc, ap, bp, cp);
            }
        }
        k0 += kc;
    }
    c
}

/// `c[MR × NR] += a[kc × MR]ᵀ · b[kc × NR]`, k in increasing order, one accumulator per
/// element.
fn micro_kernel(isa: Isa, kc: usize, a: &[f32], b: &[f32], c: &mut [f32]) {
    let (mr, nr) = (micro_rows(isa), NR);
    assert!(a.len() >= kc * mr && b.len() >= kc * nr && c.len() >= mr * nr);
    match isa {
        #[cfg(target_arch = "x86_64")]
        // SAFETY: `PackedWeights` holds `Isa::Avx2` only on CPUs with its features (capped by
        // `Isa::detect`); slice lengths were checked above.
        Isa::Avx2 => unsafe { x86::kernel_6x16(kc, a.as_ptr(), b.as_ptr(), c.as_mut_ptr()) },
        _ => kernel_portable(kc, a, b, c),
    }
}

fn kernel_portable(kc: usize, a: &[f32], b: &[f32], c: &mut [f32]) {
    const MR: usize = 4;
    const NR: usize = 16;
    let mut acc = [[0f32; NR]; MR];
    for (r, row) in acc.iter_mut().enumerate() {
        row.copy_from_slice(&c[r * NR..(r + 1) * NR]);
    }
    for p in 0..kc {
        let bv: &[f32; NR] = b[p * NR..(p + 1) * NR].try_into().expect("panel width");
        for (r, row) in acc.iter_mut().enumerate() {
            let av = a[p * MR + r];
            for (o, &bb) in row.iter_mut().zip(bv) {
                *o += av * bb;
            }
        }
    }
    for (r, row) in acc.iter().enumerate() {
        c[r * NR..(r + 1) * NR].copy_from_slice(row);
    }
}

#[cfg(target_arch = "x86_64")]
mod x86 {
    use std::arch::x86_64::*;

    /// 6×16 AVX2+FMA micro-kernel. Caller guarantees AVX2 and FMA and `a: kc×6`, `b: kc×16`,
    /// `c: 6×16` valid.
    #[target_feature(enable = "avx2,fma,bmi1,popcnt")]
    pub unsafe fn kernel_6x16(kc: usize, a: *const f32, b: *const f32, c: *mut f32) {
        let mut acc = [[_mm256_setzero_ps(); 2]; 6];
        for (r, row) in acc.iter_mut().enumerate() {
            row[0] = _mm256_loadu_ps(c.add(r * 16));
            row[1] = _mm256_loadu_ps(c.add(r * 16 + 8));
        }
        for p in 0..kc {
            let b0 = _mm256_loadu_ps(b.add(p * 16));
            let b1 = _mm256_loadu_ps(b.add(p * 16 + 8));
            let ap = a.add(p * 6);
            for (r, row) in acc.iter_mut().enumerate() {
                let av = _mm256_set1_ps(*ap.add(r));
                row[0] = _mm256_fmadd_ps(av, b0, row[0]);
                row[1] = _mm256_fmadd_ps(av, b1, row[1]);
            }
        }
        for (r, row) in acc.iter().enumerate() {
            _mm256_storeu_ps(c.add(r * 16), row[0]);
            _mm256_storeu_ps(c.add(r * 16 + 8), row[1]);
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A test convolution: a `c_in × h × w` input, `m` output channels, a `kh × kw` kernel.
    #[derive(Clone, Copy)]
    struct Case {
        c_in: usize,
        h: usize,
        w: usize,
        m: usize,
        kh: usize,
        kw: usize,
        stride: usize,
        pad: usize,
    }

    /// f64 direct convolution + bias + ReLU.
    fn conv_reference(input: &[f32], wts: &[f32], bias: &[f32], case: Case) -> Vec<f64> {
        let Case {
            c_in,
            h,
            w,
            m,
            kh,
            kw,
            stride,
            pad,
        } = case;
        let oh = (h + 2 * pad - kh) / stride + 1;
        let ow = (w + 2 * pad - kw) / stride + 1;
        let mut out = vec![0f64; m * oh * ow];
        for o in 0..m {
            for oy in 0..oh {
                for ox in 0..ow {
                    let mut s = bias[o] as f64;
                    for ci in 0..c_in {
                        for ky in 0..kh {
                            for kx in 0..kw {
                                let iy = (oy * stride + ky) as isize - pad as isize;
                                let ix = (ox * stride + kx) as isize - pad as isize;
                                if iy < 0 || ix < 0 || iy >= h as isize || ix >= w as isize {
                                    continue;
                                }
                                s += wts[((o * c_in + ci) * kh + ky) * kw + kx] as f64
                                    * input[(ci * h + iy as usize) * w + ix as usize] as f64;
                            }
                        }
                    }
                    out[(o * oh + oy) * ow + ox] = s.max(0.0);
                }
            }
        }
        out
    }

    fn values(n: usize, seed: u64) -> Vec<f32> {
        let mut rng = augsplat_core::Rng::new(seed);
        (0..n).map(|_| rng.next_f32() * 2.0 - 1.0).collect()
    }

    /// Every tier's micro-kernel against the f64 convolution.
    #[test]
    fn conv_matches_f64_reference() {
        // Odd sizes: partial M panels, partial N panels and tiles, K longer than one KC block.
        let cases = [
            (3, 13, 11, 7, 11, 11, 4, 2), // AlexNet-like first layer
            (35, 23, 19, 13, 3, 3, 1, 1), // K = 315 > KC
            (9, 70, 9, 10, 5, 5, 1, 2),   // N = 630 > TILE_N
            (4, 5, 5, 3, 3, 3, 2, 0),
            (2, 9, 140, 5, 11, 11, 4, 2), // wide rows: one-row panels with stride 4
            (4, 6, 70, 7, 3, 3, 1, 1),    // one-row panels (stride 1) and row-crossing ones
            (3, 7, 97, 4, 2, 2, 2, 0),    // no padding, stride 2
        ];
        for &(c_in, h, w, m, kh, kw, stride, pad) in &cases {
            let input = values(c_in * h * w, 1);
            let wts = values(m * c_in * kh * kw, 2);
            let bias = values(m, 3);
            let case = Case {
                c_in,
                h,
                w,
                m,
                kh,
                kw,
                stride,
                pad,
            };
            let reference = conv_reference(&input, &wts, &bias, case);
            simd::for_each_isa("conv micro-kernel against f64", |isa| {
                let packed = PackedWeights::new(&wts, &bias, m, c_in, kh, kw);
                assert_eq!(packed.isa(), isa);
                let (out, _, _) = conv2d_relu(&input, h, w, &packed, stride, pad);
                assert_eq!(out.len(), reference.len());
                for (i, (&o, &r)) in out.iter().zip(&reference).enumerate() {
                    assert!(
                        (o as f64 - r).abs() < 1e-4 * (1.0 + r.abs()),
                        "{isa:?} case {c_in}x{h}x{w} k{kh} elem {i}: {o} vs {r}"
                    );
                }
            });
        }
    }

    #[test]
    fn conv_is_thread_count_independent() {
        let (c_in, h, w, m) = (16, 40, 37, 20);
        let input = values(c_in * h * w, 4);
        let wts = values(m * c_in * 9, 5);
        let bias = values(m, 6);
        let packed = PackedWeights::new(&wts, &bias, m, c_in, 3, 3);
        let run = |n| {
            rayon::ThreadPoolBuilder::new()
                .num_threads(n)
                .build()
                .unwrap()
                .install(|| conv2d_relu(&input, h, w, &packed, 1, 1).0)
        };
        let (a, b) = (run(1), run(2));
        assert!(a.iter().zip(&b).all(|(x, y)| x.to_bits() == y.to_bits()));
    }
}
