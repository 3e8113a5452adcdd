//! SSIM in the torchmetrics convention.
//!
//! Per channel: the five maps x, y, x², y², xy are reflect-padded by 5 px (mirror without
//! repeating the edge, as torch's `reflect`), filtered with a separable normalised Gaussian
//! (11 taps, σ 1.5), and combined as
//! `((2 μx μy + C1)(2 σxy + C2)) / ((μx² + μy² + C1)(σx² + σy² + C2))` with C1 = (0.01)²,
//! C2 = (0.03)² (data range 1). [`ssim`] averages the map over every pixel and channel;
//! [`ssim_valid`] over the map cropped by 5 px per side.
//!
//! Filtering runs in f32 over fixed 48-row chunks in parallel; each chunk's sum is an f64 and
//! chunks are added in order, so the result does not depend on the thread count.

use crate::{check_pair, MetricsError};
use augsplat_core::ImageF32;
use rayon::prelude::*;

/// Gaussian window size.
pub const WINDOW: usize = 11;
/// Gaussian standard deviation in pixels.
pub const SIGMA: f64 = 1.5;
/// K1 constant (C1 = (K1 · data range)²).
pub const K1: f64 = 0.01;
/// K2 constant (C2 = (K2 · data range)²).
pub const K2: f64 = 0.03;
/// Half window: the padding and the crop of [`ssim_valid`].
pub const PAD: usize = WINDOW / 2;
const ROWS_PER_CHUNK: usize = 48;

/// The normalised 1-D Gaussian window (torchmetrics `_gaussian`): offsets −5..=5.
pub fn gaussian_window() -> [f64; WINDOW] {
    let mut g = [0.0; WINDOW];
    let half = (WINDOW as f64 - 1.0) / 2.0;
    for (i, v) in g.iter_mut().enumerate() {
        let d = i as f64 - half;
        *v = (-(d / SIGMA).powi(2) / 2.0).exp();
    }
    let s: f64 = g.iter().sum();
    g.iter_mut().for_each(|v| *v /= s);
    g
}

/// Mirror index for torch `reflect` padding: −1 → 1, n → n − 2.
#[inline]
pub(crate) fn reflect(i: isize, n: usize) -> usize {
    let n = n as isize;
    let mut i = i;
    if i < 0 {
        i = -i;
    }
    if i >= n {
        i = 2 * (n - 1) - i;
    }
    i as usize
}

/// SSIM (torchmetrics convention, full-map mean) of two images with values in [0, 1].
///
/// Errors on mismatched sizes, non-finite values, or images smaller than 6 px on a side
/// (reflect padding by 5 needs at least 6).
pub fn ssim(a: &ImageF32, b: &ImageF32) -> Result<f64, MetricsError> {
    ssim_mean(a, b, 0)
}

/// SSIM with the map cropped by 5 px per side before averaging (scikit-image
/// `structural_similarity(gaussian_weights=True, sigma=1.5, use_sample_covariance=False)`).
///
/// Errors as [`ssim`], and on images smaller than 11 px on a side.
pub fn ssim_valid(a: &ImageF32, b: &ImageF32) -> Result<f64, MetricsError> {
    ssim_mean(a, b, PAD)
}

/// The image's channels one after another (CHW).
fn planar(img: &ImageF32) -> Vec<f32> {
    let nc = img.channels as usize;
    let n = img.pixels();
    let mut out = vec![0f32; n * nc];
    for c in 0..nc {
        for (d, px) in out[c * n..(c + 1) * n]
            .iter_mut()
            .zip(img.data.chunks_exact(nc))
        {
            *d = px[c];
        }
    }
    out
}

fn ssim_mean(a: &ImageF32, b: &ImageF32, crop: usize) -> Result<f64, MetricsError> {
    check_pair(a, b)?;
    let (w, h, nc) = (a.width as usize, a.height as usize, a.channels as usize);
    let min = (PAD + 1).max(2 * crop + 1);
    if w < min || h < min {
        return Err(MetricsError::BadImage(format!(
            "SSIM needs images of at least {min}×{min} pixels, got {w}×{h}"
        )));
    }
    let g64 = gaussian_window();
    let mut g = [0f32; WINDOW];
    for (d, s) in g.iter_mut().zip(g64) {
        *d = s as f32;
    }
    let (pa, pb) = (planar(a), planar(b));
    let planes: Vec<(&[f32], &[f32])> = (0..nc)
        .map(|c| {
            (
                &pa[c * w * h..(c + 1) * w * h],
                &pb[c * w * h..(c + 1) * w * h],
            )
        })
        .collect();
    let (y0, y1) = (crop, h - crop);
    let chunks_per_channel = (y1 - y0).div_ceil(ROWS_PER_CHUNK);
    let sums: Vec<f64> = (0..nc * chunks_per_channel)
        .into_par_iter()
        .map_init(Buffers::default, |buf, job| {
            let (c, k) = (job / chunks_per_channel, job % chunks_per_channel);
            let r0 = y0 + k * ROWS_PER_CHUNK;
            let r1 = (r0 + ROWS_PER_CHUNK).min(y1);
            let chunk = Chunk {
                x: planes[c].0,
                y: planes[c].1,
                w,
                h,
                r0,
                r1,
                crop,
            };
            chunk_sum(&chunk, &g, buf)
        })
        .collect();
    let count = nc * (y1 - y0) * (w - 2 * crop);
    Ok(sums.iter().sum::<f64>() / count as f64)
}

/// Scratch space reused between chunks (its content never matters: every value is written
/// before it is read).
#[derive(Default)]
struct Buffers {
    hmaps: Vec<f32>,
    padded: Vec<f32>,
    v: Vec<f32>,
    smap: Vec<f32>,
}

/// One job of `chunk_sum`: output rows `r0..r1` and columns `crop..w - crop` of one channel,
/// from the channel's `w × h` planes of the two images.
#[derive(Clone, Copy)]
struct Chunk<'a> {
    x: &'a [f32],
    y: &'a [f32],
    w: usize,
    h: usize,
    r0: usize,
    r1: usize,
    crop: usize,
}

// `chunk_sum`: the sum of the SSIM map over one `Chunk`, compiled for every instruction-set
// tier and dispatched by `augsplat_core::simd::active` (the arithmetic is the same, so the bits
// are too: Rust never fuses multiply-adds on its own).
augsplat_core::multiversion!(fn chunk_sum(
    chunk: &Chunk<'_>,
    g: &[f32; WINDOW],
    buf: &mut Buffers,
) -> f64 => chunk_sum_generic);

/// `out[i] = Σ_k g[k] p[i + k]` over an 11-tap symmetric window (`p.len() == out.len() + 10`),
/// taps paired as `g[k] (p[i+k] + p[i+10−k])`.
#[inline(always)]
fn filter_row(p: &[f32], out: &mut [f32], g: &[f32; WINDOW]) {
    let w = out.len();
    for (o, &c) in out.iter_mut().zip(&p[PAD..PAD + w]) {
        *o = g[PAD] * c;
    }
    for (k, &gk) in g.iter().enumerate().take(PAD) {
        let (l, r) = (&p[k..k + w], &p[WINDOW - 1 - k..WINDOW - 1 - k + w]);
        for ((o, &a), &b) in out.iter_mut().zip(l).zip(r) {
            *o += gk * (a + b);
        }
    }
}

#[inline(always)]
fn chunk_sum_generic(chunk: &Chunk<'_>, g: &[f32; WINDOW], buf: &mut Buffers) -> f64 {
    let Chunk {
        x,
        y,
        w,
        h,
        r0,
        r1,
        crop,
    } = *chunk;
    let c1 = (K1 * K1) as f32;
    let c2 = (K2 * K2) as f32;
    let rows = r1 - r0 + 2 * PAD;
    let wp = w + 2 * PAD;
    // Horizontally filtered maps (x, y, x², y², xy) of the source rows r0-5 .. r1+5:
    // map m, row r at hmaps[(m * rows + r) * w ..].
    buf.hmaps.resize(5 * rows * w, 0.0);
    buf.padded.resize(5 * wp, 0.0);
    buf.v.resize(5 * w, 0.0);
    buf.smap.resize(w, 0.0);
    let Buffers {
        hmaps,
        padded,
        v,
        smap,
    } = buf;
    for r in 0..rows {
        let src = reflect(r0 as isize + r as isize - PAD as isize, h);
        let (xr, yr) = (&x[src * w..(src + 1) * w], &y[src * w..(src + 1) * w]);
        let (px, rest) = padded.split_at_mut(wp);
        let (py, rest) = rest.split_at_mut(wp);
        let (pxx, rest) = rest.split_at_mut(wp);
        let (pyy, pxy) = rest.split_at_mut(wp);
        for i in 0..wp {
            let s = reflect(i as isize - PAD as isize, w);
            px[i] = xr[s];
            py[i] = yr[s];
        }
        for i in 0..wp {
            let (a, b) = (px[i], py[i]);
            pxx[i] = a * a;
            pyy[i] = b * b;
            pxy[i] = a * b;
        }
        for m in 0..5 {
            let out = &mut hmaps[(m * rows + r) * w..(m * rows + r + 1) * w];
            filter_row(&padded[m * wp..(m + 1) * wp], out, g);
        }
    }
    let mut total = 0f64;
    for out_row in 0..(r1 - r0) {
        for m in 0..5 {
            let map = &hmaps[m * rows * w..(m + 1) * rows * w];
            let row = |k: usize| &map[(out_row + k) * w..(out_row + k + 1) * w];
            let dst = &mut v[m * w..(m + 1) * w];
            for (d, &c) in dst.iter_mut().zip(row(PAD)) {
                *d = g[PAD] * c;
            }
            for (k, &gk) in g.iter().enumerate().take(PAD) {
                for ((d, &a), &b) in dst.iter_mut().zip(row(k)).zip(row(WINDOW - 1 - k)) {
                    *d += gk * (a + b);
                }
            }
        }
        let (mx, rest) = v.split_at(w);
        let (my, rest) = rest.split_at(w);
        let (exx, rest) = rest.split_at(w);
        let (eyy, exy) = rest.split_at(w);
        for i in crop..w - crop {
            let (ux, uy) = (mx[i], my[i]);
            let (uxx, uyy, uxy) = (ux * ux, uy * uy, ux * uy);
            let sxx = exx[i] - uxx;
            let syy = eyy[i] - uyy;
            let sxy = exy[i] - uxy;
            let num = (2.0 * uxy + c1) * (2.0 * sxy + c2);
            let den = (uxx + uyy + c1) * (sxx + syy + c2);
            smap[i] = num / den;
        }
        // Eight f64 lanes in a fixed order: vectorisable and thread-count independent.
        let mut lanes = [0f64; 8];
        let row = &smap[crop..w - crop];
        let mut chunks = row.chunks_exact(8);
        for c in &mut chunks {
            for (l, &v) in lanes.iter_mut().zip(c) {
                *l += v as f64;
            }
        }
        let row_sum =
            lanes.iter().sum::<f64>() + chunks.remainder().iter().map(|&v| v as f64).sum::<f64>();
        total += row_sum;
    }
    total
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Independent f64 reference: direct 2-D window sums over an explicitly padded image.
    fn ssim_reference(a: &ImageF32, b: &ImageF32, crop: usize) -> f64 {
        let g = gaussian_window();
        let (w, h, nc) = (a.width as usize, a.height as usize, a.channels as usize);
        let (c1, c2) = (K1 * K1, K2 * K2);
        let mut total = 0.0;
        let mut n = 0usize;
        for c in 0..nc {
            let at = |img: &ImageF32, yy: isize, xx: isize| {
                let (ry, rx) = (reflect(yy, h), reflect(xx, w));
                img.data[(ry * w + rx) * nc + c] as f64
            };
            for yy in crop..h - crop {
                for xx in crop..w - crop {
                    let (mut mx, mut my, mut sxx, mut syy, mut sxy) = (0.0, 0.0, 0.0, 0.0, 0.0);
                    for dy in 0..WINDOW {
                        for dx in 0..WINDOW {
                            let wt = g[dy] * g[dx];
                            let sy = yy as isize + dy as isize - PAD as isize;
                            let sx = xx as isize + dx as isize - PAD as isize;
                            let (p, q) = (at(a, sy, sx), at(b, sy, sx));
                            mx += wt * p;
                            my += wt * q;
                            sxx += wt * p * p;
                            syy += wt * q * q;
                            sxy += wt * p * q;
                        }
                    }
                    let (vx, vy, cxy) = (sxx - mx * mx, syy - my * my, sxy - mx * my);
                    total += ((2.0 * mx * my + c1) * (2.0 * cxy + c2))
                        / ((mx * mx + my * my + c1) * (vx + vy + c2));
                    n += 1;
                }
            }
        }
        total / n as f64
    }

    fn noise_image(w: u32, h: u32, seed: u64) -> ImageF32 {
        let mut rng = augsplat_core::Rng::new(seed);
        let mut im = ImageF32::new(w, h, 3);
        for (i, v) in im.data.iter_mut().enumerate() {
            let x = (i / 3) as u32 % w;
            *v = (0.3 + 0.4 * ((x as f32) * 0.37).sin() * 0.5 + 0.3 * rng.next_f32()).clamp(0., 1.);
        }
        im
    }

    #[test]
    fn matches_f64_reference() {
        for (w, h) in [(6, 6), (37, 29), (70, 41)] {
            let a = noise_image(w, h, 1);
            let b = noise_image(w, h, 2);
            let full = ssim(&a, &b).unwrap();
            let reference = ssim_reference(&a, &b, 0);
            assert!(
                (full - reference).abs() < 2e-6,
                "{w}×{h}: {full} vs {reference}"
            );
            if w >= 11 && h >= 11 {
                let valid = ssim_valid(&a, &b).unwrap();
                let reference = ssim_reference(&a, &b, PAD);
                assert!((valid - reference).abs() < 2e-6, "{valid} vs {reference}");
            }
        }
    }

    #[test]
    fn identity_and_errors() {
        let a = noise_image(40, 33, 3);
        assert!((ssim(&a, &a).unwrap() - 1.0).abs() < 1e-6);
        assert!((ssim_valid(&a, &a).unwrap() - 1.0).abs() < 1e-6);
        let small = noise_image(5, 40, 3);
        assert!(ssim(&small, &small)
            .unwrap_err()
            .to_string()
            .contains("at least 6×6"));
        let s10 = noise_image(10, 40, 3);
        assert!(ssim(&s10, &s10).is_ok());
        assert!(ssim_valid(&s10, &s10).is_err());
    }

    /// Every tier (the filters compiled for AVX2 and the portable build) gives the same bits.
    #[test]
    fn every_tier_gives_the_same_bits() {
        let a = noise_image(70, 53, 6);
        let b = noise_image(70, 53, 7);
        let runs = augsplat_core::simd::for_each_isa("ssim filters", |_| {
            (
                ssim(&a, &b).unwrap().to_bits(),
                ssim_valid(&a, &b).unwrap().to_bits(),
            )
        });
        for (isa, bits) in &runs {
            assert_eq!(*bits, runs[0].1, "{isa} vs {}", runs[0].0);
        }
    }

    #[test]
    fn thread_count_does_not_change_bits() {
        let a = noise_image(90, 100, 4);
        let b = noise_image(90, 100, 5);
        let run = |n| {
            rayon::ThreadPoolBuilder::new()
                .num_threads(n)
                .build()
                .unwrap()
                .install(|| (ssim(&a, &b).unwrap(), ssim_valid(&a, &b).unwrap()))
        };
        let (s1, s2) = (run(1), run(2));
        assert_eq!(s1.0.to_bits(), s2.0.to_bits());
        assert_eq!(s1.1.to_bits(), s2.1.to_bits());
    }
}
