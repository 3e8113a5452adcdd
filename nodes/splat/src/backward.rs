//! The analytic backward pass.
//!
//! 1. Per tile (in parallel), Gaussians are revisited back to front starting from the
//!    tile's largest last-contributor index; each pixel recovers its transmittance before a
//!    Gaussian as T_i = T_{i+1} / (1 − α_i) from the final T kept by the forward pass, and the
//!    colour/depth "behind" sums are accumulated as the walk proceeds. Each (tile, Gaussian)
//!    pair writes its summed screen-space gradient (mean2d, conic, opacity, colour, depth)
//!    into its own slot of a pair buffer, so no two tiles ever write the same memory.
//! 2. Per Gaussian (in parallel), its pair slots are summed in f64 in a fixed order (tiles in
//!    row-major order) — results are bit-identical for any number of threads.
//! 3. Per Gaussian, the projection and SH backward ([`crate::project::project_vjp`],
//!    [`crate::sh::eval_color_vjp`]) turn these into gradients of the raw parameters, the
//!    SH view direction's dependence on the mean included.
//!
//! With α = α₁·s(α₁) (smooth cutoff, tests only) or α = α₁ (hard), α₁ = min(max_alpha, o·e^−σ):
//! dL/dα_i = Σ_c g_c (c_i T_i − B_c/(1 − α_i)) + g_A' T_N/(1 − α_i) + g_S (z_i T_i − B_z/(1 − α_i))
//! with B the sums over Gaussians behind i (B_c includes T_N·background), g_S = g_D/A and
//! g_A' = g_A − g_D·D/A from the alpha-normalised depth D = S/A.

// Negated comparisons are deliberate: they also reject NaN. Index loops read best in
// small fixed-size numeric code.
#![allow(clippy::neg_cmp_op_on_partial_ord, clippy::needless_range_loop)]

use crate::constants::{ALPHA_THRESHOLD, DEPTH_ALPHA_EPS, TILE, TILE_PIXELS};
use crate::forward::{exp_neg, row_hits, row_range, smooth_cut, Splat2D, PROJECT_CHUNK};
use crate::gaussians::Gaussians;
use crate::project::{project_vjp, CameraModel, ProjectedGrad};
use crate::render::{Cutoff, Gradients, RenderOutput, RenderSettings};
use crate::sh;
use augsplat_core::Camera;
use rayon::prelude::*;

/// Screen-space gradient of one (tile, Gaussian) pair: mean2d x, y; conic a, b, c; opacity;
/// colour r, g, b; depth.
type PairGrad = [f32; 10];

/// Per-pixel upstream gradients of one tile.
struct Upstream {
    gc: [[f32; TILE_PIXELS]; 3],
    ga: [f32; TILE_PIXELS],
    gs: [f32; TILE_PIXELS],
}

#[allow(clippy::too_many_arguments)]
#[inline(always)]
fn backward_tile<const SMOOTH: bool>(
    splats: &[Splat2D],
    list: &[u32],
    x0: u32,
    y0: u32,
    last: &[u32],
    final_t: &[f32],
    up: &Upstream,
    bg: [f32; 3],
    max_alpha: f32,
    out: &mut [PairGrad],
) {
    let max_last = last.iter().copied().max().unwrap_or(0) as usize;
    if max_last == 0 {
        return;
    }
    let mut t = [0.0f32; TILE_PIXELS];
    t.copy_from_slice(final_t);
    let mut acc = [[0.0f32; TILE_PIXELS]; 3];
    for ch in 0..3 {
        for p in 0..TILE_PIXELS {
            acc[ch][p] = final_t[p] * bg[ch];
        }
    }
    let mut acc_d = [0.0f32; TILE_PIXELS];
    let mut px = [0.0f32; 16];
    for (lx, v) in px.iter_mut().enumerate() {
        *v = (x0 + lx as u32) as f32 + 0.5;
    }
    // Largest last-contributor count per row: rows where every pixel finished before a
    // Gaussian are skipped.
    let mut row_last = [0u32; 16];
    for (ly, m) in row_last.iter_mut().enumerate() {
        *m = last[ly * 16..ly * 16 + 16]
            .iter()
            .copied()
            .max()
            .unwrap_or(0);
    }
    for k in (0..max_last).rev() {
        let sp = &splats[list[k] as usize];
        let (lo, hi) = row_range(sp, y0);
        let kk = k as u32;
        let mut lanes = [[0.0f32; 16]; 10];
        for ly in lo..hi {
            if kk >= row_last[ly] {
                continue;
            }
            let dy = sp.y - ((y0 + ly as u32) as f32 + 0.5);
            if !row_hits(sp, dy, x0) {
                continue;
            }
            let base = ly * TILE as usize;
            let r16 = |v: &[f32]| -> [f32; 16] { v[base..base + 16].try_into().unwrap() };
            let (gcr, gcg, gcb) = (r16(&up.gc[0]), r16(&up.gc[1]), r16(&up.gc[2]));
            let (ga, gsv, tf) = (r16(&up.ga), r16(&up.gs), r16(final_t));
            let last_row: [u32; 16] = last[base..base + 16].try_into().unwrap();
            let t_row: &mut [f32; 16] = (&mut t[base..base + 16]).try_into().unwrap();
            let [a0, a1r, a2] = &mut acc;
            let ar: &mut [f32; 16] = (&mut a0[base..base + 16]).try_into().unwrap();
            let ag: &mut [f32; 16] = (&mut a1r[base..base + 16]).try_into().unwrap();
            let ab: &mut [f32; 16] = (&mut a2[base..base + 16]).try_into().unwrap();
            let ad: &mut [f32; 16] = (&mut acc_d[base..base + 16]).try_into().unwrap();
            for lx in 0..16 {
                let dx = sp.x - px[lx];
                let sigma = 0.5 * (sp.a * dx * dx + sp.c * dy * dy) + sp.b * dx * dy;
                let gauss = exp_neg(-sigma);
                let raw = sp.opacity * gauss;
                let a1 = raw.min(max_alpha);
                let (alpha, ok, da_da1) = if SMOOTH {
                    let (s, ds) = smooth_cut(a1);
                    (a1 * s, a1 > ALPHA_THRESHOLD, s + a1 * ds)
                } else {
                    (a1, a1 >= ALPHA_THRESHOLD, 1.0)
                };
                let ok = ok && sigma >= 0.0 && kk < last_row[lx];
                let ra = 1.0 / (1.0 - alpha);
                let ti = t_row[lx] * ra;
                let w = alpha * ti;
                let dl_da = gcr[lx] * (sp.rgb[0] * ti - ar[lx] * ra)
                    + gcg[lx] * (sp.rgb[1] * ti - ag[lx] * ra)
                    + gcb[lx] * (sp.rgb[2] * ti - ab[lx] * ra)
                    + ga[lx] * tf[lx] * ra
                    + gsv[lx] * (sp.depth * ti - ad[lx] * ra);
                let unclamped = raw < max_alpha;
                let d_raw = if ok && unclamped { dl_da * da_da1 } else { 0.0 };
                let d_sigma = -d_raw * raw;
                // Selects (not multiplications by a 0/1 mask) keep far-away lanes, whose
                // dx² may overflow, from turning 0·∞ into NaN.
                let sel = |v: f32| if ok { v } else { 0.0 };
                let wm = sel(w);
                lanes[5][lx] += sel(d_raw * gauss);
                lanes[2][lx] += sel(d_sigma * 0.5 * dx * dx);
                lanes[3][lx] += sel(d_sigma * dx * dy);
                lanes[4][lx] += sel(d_sigma * 0.5 * dy * dy);
                lanes[0][lx] += sel(d_sigma * (sp.a * dx + sp.b * dy));
                lanes[1][lx] += sel(d_sigma * (sp.b * dx + sp.c * dy));
                lanes[6][lx] += gcr[lx] * wm;
                lanes[7][lx] += gcg[lx] * wm;
                lanes[8][lx] += gcb[lx] * wm;
                lanes[9][lx] += gsv[lx] * wm;
                ar[lx] += sp.rgb[0] * wm;
                ag[lx] += sp.rgb[1] * wm;
                ab[lx] += sp.rgb[2] * wm;
                ad[lx] += sp.depth * wm;
                t_row[lx] = if ok { ti } else { t_row[lx] };
            }
        }
        let slot = &mut out[k];
        for (q, lane) in lanes.iter().enumerate() {
            slot[q] = lane.iter().sum();
        }
    }
}

/// [`backward_tile`] compiled for AVX-512F (16 lanes: one tile row per vector).
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx512f")]
#[allow(clippy::too_many_arguments)]
fn backward_tile_avx512<const SMOOTH: bool>(
    splats: &[Splat2D],
    list: &[u32],
    x0: u32,
    y0: u32,
    last: &[u32],
    final_t: &[f32],
    up: &Upstream,
    bg: [f32; 3],
    max_alpha: f32,
    out: &mut [PairGrad],
) {
    backward_tile::<SMOOTH>(splats, list, x0, y0, last, final_t, up, bg, max_alpha, out)
}

/// [`backward_tile`] compiled for AVX2.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
#[allow(clippy::too_many_arguments)]
fn backward_tile_avx2<const SMOOTH: bool>(
    splats: &[Splat2D],
    list: &[u32],
    x0: u32,
    y0: u32,
    last: &[u32],
    final_t: &[f32],
    up: &Upstream,
    bg: [f32; 3],
    max_alpha: f32,
    out: &mut [PairGrad],
) {
    backward_tile::<SMOOTH>(splats, list, x0, y0, last, final_t, up, bg, max_alpha, out)
}

/// Runs [`backward_tile`] with the widest vector unit the CPU has. Every variant performs the same
/// IEEE operations in the same order (no FMA contraction, sequential lane sums), so results
/// are bit-identical whichever one runs.
#[allow(clippy::too_many_arguments)]
fn backward_tile_dispatch<const SMOOTH: bool>(
    splats: &[Splat2D],
    list: &[u32],
    x0: u32,
    y0: u32,
    last: &[u32],
    final_t: &[f32],
    up: &Upstream,
    bg: [f32; 3],
    max_alpha: f32,
    out: &mut [PairGrad],
) {
    #[cfg(target_arch = "x86_64")]
    {
        if std::arch::is_x86_feature_detected!("avx512f") {
            // SAFETY: the CPU supports AVX-512F (checked just above).
            return unsafe {
                backward_tile_avx512::<SMOOTH>(
                    splats, list, x0, y0, last, final_t, up, bg, max_alpha, out,
                )
            };
        }
        if std::arch::is_x86_feature_detected!("avx2") {
            // SAFETY: the CPU supports AVX2 (checked just above).
            return unsafe {
                backward_tile_avx2::<SMOOTH>(
                    splats, list, x0, y0, last, final_t, up, bg, max_alpha, out,
                )
            };
        }
    }
    backward_tile::<SMOOTH>(splats, list, x0, y0, last, final_t, up, bg, max_alpha, out)
}

pub(crate) fn backward_impl(
    g: &Gaussians,
    cam: &Camera,
    _s: &RenderSettings,
    out: &RenderOutput,
    d_rgb: &[f32],
    d_alpha: Option<&[f32]>,
    d_depth: Option<&[f32]>,
) -> Gradients {
    let st = &out.state;
    let s = &st.settings;
    let n = g.len();
    let kcoef = g.coeffs() * 3;
    let mut grads = Gradients {
        means: vec![[0.0; 3]; n],
        log_scales: vec![[0.0; 3]; n],
        quats: vec![[0.0; 4]; n],
        opacity_logits: vec![0.0; n],
        sh: vec![0.0; g.sh.len()],
        means2d_abs: vec![[0.0; 2]; n],
        visible: vec![false; n],
    };
    let (width, height) = (out.width, out.height);
    let npix = width as usize * height as usize;
    if st.splats.is_empty() || cam.width != width || cam.height != height {
        return grads;
    }
    let d_rgb = (d_rgb.len() == npix * 3).then_some(d_rgb);
    let d_alpha = d_alpha.filter(|v| v.len() == npix);
    let d_depth = d_depth.filter(|v| v.len() == npix);
    let grid = st.grid;
    let bins = &st.bins;
    let max_alpha = crate::forward::effective_max_alpha(s);

    // 1. per-tile pair gradients.
    let mut pair_grads: Vec<PairGrad> = vec![[0.0; 10]; bins.ranks.len()];
    let mut slices: Vec<&mut [PairGrad]> = Vec::with_capacity(grid.len());
    let mut rest: &mut [PairGrad] = &mut pair_grads;
    for t in 0..grid.len() {
        let (a, b) = rest.split_at_mut(bins.ranges[t + 1] - bins.ranges[t]);
        slices.push(a);
        rest = b;
    }
    slices.into_par_iter().enumerate().for_each(|(t, slot)| {
        let tx = (t % grid.tiles_x as usize) as u32;
        let ty = (t / grid.tiles_x as usize) as u32;
        let (x0, y0) = (tx * TILE, ty * TILE);
        let last = &st.last[t * TILE_PIXELS..(t + 1) * TILE_PIXELS];
        if slot.is_empty() || last.iter().all(|&l| l == 0) {
            return;
        }
        let mut up = Upstream {
            gc: [[0.0; TILE_PIXELS]; 3],
            ga: [0.0; TILE_PIXELS],
            gs: [0.0; TILE_PIXELS],
        };
        for ly in 0..TILE {
            for lx in 0..TILE {
                let (x, y) = (x0 + lx, y0 + ly);
                if x >= width || y >= height {
                    continue;
                }
                let i = (y * width + x) as usize;
                let p = (ly * TILE + lx) as usize;
                if let Some(d) = d_rgb {
                    for ch in 0..3 {
                        up.gc[ch][p] = finite_or_zero(d[i * 3 + ch]);
                    }
                }
                let mut ga = d_alpha.map_or(0.0, |v| finite_or_zero(v[i]));
                let mut gs = 0.0;
                if let Some(dd) = d_depth {
                    let a = out.alpha[i];
                    if a >= DEPTH_ALPHA_EPS {
                        let gd = finite_or_zero(dd[i]);
                        gs = gd / a;
                        ga -= gd * out.depth[i] / a;
                    }
                }
                up.ga[p] = ga;
                up.gs[p] = gs;
            }
        }
        let list = &bins.ranks[bins.ranges[t]..bins.ranges[t + 1]];
        let ft = &st.final_t[t * TILE_PIXELS..(t + 1) * TILE_PIXELS];
        match st.cutoff {
            Cutoff::Hard => backward_tile_dispatch::<false>(
                &st.splats,
                list,
                x0,
                y0,
                last,
                ft,
                &up,
                s.background,
                max_alpha,
                slot,
            ),
            Cutoff::Smooth => backward_tile_dispatch::<true>(
                &st.splats,
                list,
                x0,
                y0,
                last,
                ft,
                &up,
                s.background,
                max_alpha,
                slot,
            ),
        }
    });

    // 2. per-rank sums in a fixed order.
    let nranks = st.splats.len();
    let mut rank_grads: Vec<[f64; 10]> = vec![[0.0; 10]; nranks];
    rank_grads
        .par_chunks_mut(PROJECT_CHUNK)
        .enumerate()
        .for_each(|(ci, chunk)| {
            for (j, acc) in chunk.iter_mut().enumerate() {
                let r = ci * PROJECT_CHUNK + j;
                for &pos in &bins.pair_index[bins.pair_start[r]..bins.pair_start[r + 1]] {
                    let pg = &pair_grads[pos as usize];
                    for q in 0..10 {
                        acc[q] += pg[q] as f64;
                    }
                }
            }
        });
    drop(pair_grads);
    let mut id_rank = vec![u32::MAX; n];
    for (r, &i) in st.rank_id.iter().enumerate() {
        id_rank[i as usize] = r as u32;
    }

    // 3. per-Gaussian projection + SH backward.
    let cm = CameraModel::new(cam);
    let degree = st.sh_degree;
    let nb = sh::basis_len(degree);
    let (hw, hh) = (width as f64 * 0.5, height as f64 * 0.5);
    grads
        .means
        .par_chunks_mut(PROJECT_CHUNK)
        .zip(grads.log_scales.par_chunks_mut(PROJECT_CHUNK))
        .zip(grads.quats.par_chunks_mut(PROJECT_CHUNK))
        .zip(grads.opacity_logits.par_chunks_mut(PROJECT_CHUNK))
        .zip(grads.sh.par_chunks_mut(PROJECT_CHUNK * kcoef.max(1)))
        .zip(grads.means2d_abs.par_chunks_mut(PROJECT_CHUNK))
        .zip(grads.visible.par_chunks_mut(PROJECT_CHUNK))
        .enumerate()
        .for_each(|(ci, ((((((gm, gl), gq), go), gsh), g2), gv))| {
            let mut g_coefs = [0.0f64; 48];
            for j in 0..gm.len() {
                let i = ci * PROJECT_CHUNK + j;
                let r = id_rank[i];
                if r == u32::MAX {
                    continue;
                }
                let rg = &rank_grads[r as usize];
                gv[j] = true;
                g2[j] = [(rg[0] * hw) as f32, (rg[1] * hh) as f32];
                if rg.iter().all(|v| *v == 0.0) {
                    // Visible but never composited (occluded or behind saturated pixels):
                    // every parameter gradient is exactly zero.
                    continue;
                }
                let pg = ProjectedGrad {
                    mean2d: [rg[0], rg[1]],
                    conic: [rg[2], rg[3], rg[4]],
                    opacity: rg[5],
                    depth: rg[9],
                };
                let p = project_vjp(
                    &cm,
                    g.means[i],
                    g.log_scales[i],
                    g.quats[i],
                    g.opacity_logits[i],
                    s.antialiased,
                    s.near as f64,
                    &pg,
                );
                let mut gmean = p.mean;
                // SH: colour depends on the view direction normalize(mean − centre).
                let m = g.means[i];
                let v = [
                    m[0] as f64 - cm.center[0],
                    m[1] as f64 - cm.center[1],
                    m[2] as f64 - cm.center[2],
                ];
                let len = (v[0] * v[0] + v[1] * v[1] + v[2] * v[2]).sqrt();
                if len > 0.0 {
                    let dir = [v[0] / len, v[1] / len, v[2] / len];
                    let coefs = &g.sh[i * kcoef..(i + 1) * kcoef];
                    g_coefs[..kcoef].iter_mut().for_each(|x| *x = 0.0);
                    let gd =
                        sh::eval_color_vjp(degree, coefs, dir, [rg[6], rg[7], rg[8]], &mut g_coefs);
                    let dd = gd[0] * dir[0] + gd[1] * dir[1] + gd[2] * dir[2];
                    for a in 0..3 {
                        gmean[a] += (gd[a] - dir[a] * dd) / len;
                    }
                    let dst = &mut gsh[j * kcoef..(j + 1) * kcoef];
                    for q in 0..nb * 3 {
                        dst[q] = g_coefs[q] as f32;
                    }
                }
                gm[j] = gmean.map(|x| x as f32);
                gl[j] = p.log_scale.map(|x| x as f32);
                gq[j] = p.quat.map(|x| x as f32);
                go[j] = p.logit as f32;
            }
        });
    grads
}

#[inline]
fn finite_or_zero(v: f32) -> f32 {
    if v.is_finite() {
        v
    } else {
        0.0
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::forward::tests::random_tile_splats;

    #[test]
    fn vector_variants_are_bit_identical_to_the_portable_kernel() {
        let splats = random_tile_splats(5, 200);
        let list: Vec<u32> = (0..200).collect();
        let mut rng = augsplat_core::Rng::new(9);
        let last: Vec<u32> = (0..TILE_PIXELS).map(|_| rng.below(201) as u32).collect();
        let final_t: Vec<f32> = (0..TILE_PIXELS)
            .map(|_| rng.uniform(1e-4, 1.0) as f32)
            .collect();
        let mut up = Upstream {
            gc: [[0.0; TILE_PIXELS]; 3],
            ga: [0.0; TILE_PIXELS],
            gs: [0.0; TILE_PIXELS],
        };
        for p in 0..TILE_PIXELS {
            for ch in 0..3 {
                up.gc[ch][p] = rng.uniform(-1.0, 1.0) as f32;
            }
            up.ga[p] = rng.uniform(-1.0, 1.0) as f32;
            up.gs[p] = rng.uniform(-0.1, 0.1) as f32;
        }
        let bg = [0.2, 0.4, 0.6];
        let mut a = vec![[0.0f32; 10]; 200];
        let mut b = vec![[0.0f32; 10]; 200];
        backward_tile::<false>(&splats, &list, 0, 0, &last, &final_t, &up, bg, 0.99, &mut a);
        backward_tile_dispatch::<false>(
            &splats, &list, 0, 0, &last, &final_t, &up, bg, 0.99, &mut b,
        );
        let bits = |v: &[[f32; 10]]| v.iter().flatten().map(|x| x.to_bits()).collect::<Vec<_>>();
        assert_eq!(bits(&a), bits(&b));
        assert!(a.iter().flatten().filter(|v| **v != 0.0).count() > 500);
        let mut a = vec![[0.0f32; 10]; 200];
        let mut b = vec![[0.0f32; 10]; 200];
        backward_tile::<true>(&splats, &list, 0, 0, &last, &final_t, &up, bg, 0.99, &mut a);
        backward_tile_dispatch::<true>(
            &splats, &list, 0, 0, &last, &final_t, &up, bg, 0.99, &mut b,
        );
        assert_eq!(bits(&a), bits(&b));
    }
}
