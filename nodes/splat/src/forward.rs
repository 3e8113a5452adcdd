//! The forward pass: projection of every Gaussian (parallel, fixed chunks), tile binning, and
//! per-tile front-to-back compositing (tiles in parallel).
//!
//! Compositing (DESIGN.md §4): σ = ½(a·dx² + c·dy²) + b·dx·dy; α = min(max_alpha, o·e^−σ);
//! skip if σ < 0 or α < 1/255; stop *before* a Gaussian when T·(1 − α) ≤ 1e-4;
//! C += c·α·T; output C + T·background, alpha 1 − T, depth Σ z·α·T / (1 − T).
//!
//! Each tile keeps, per pixel, the number of list entries up to and including its last
//! contributor and its final transmittance; the backward pass walks back from there.
//!
//! The projected records ([`Splat2D`]) are stored in depth-rank order, one 48-byte record per
//! Gaussian so a tile's gather touches one cache line per Gaussian; inside a tile the kernel
//! works on structure-of-arrays pixel lanes (rows of 16 pixels).

// Negated comparisons are deliberate: they also reject NaN. Index loops read best in
// small fixed-size numeric code.
#![allow(clippy::neg_cmp_op_on_partial_ord, clippy::needless_range_loop)]

use crate::constants::{
    ALPHA_THRESHOLD, DEPTH_ALPHA_EPS, TILE, TILE_PIXELS, TRANSMITTANCE_THRESHOLD,
};
use crate::gaussians::Gaussians;
use crate::project::{project, CameraModel, Outcome};
use crate::render::{Cutoff, RenderOutput, RenderSettings, RenderStats};
use crate::sh;
use crate::tiles::{bin, depth_order, Bins, TileGrid};
use augsplat_core::Camera;
use rayon::prelude::*;

/// Gaussians per parallel projection chunk (fixed, so results never depend on the pool).
pub(crate) const PROJECT_CHUNK: usize = 4096;

/// One projected Gaussian, as the compositing kernels read it.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
#[repr(C)]
pub struct Splat2D {
    /// Centre x, pixels.
    pub x: f32,
    /// Centre y, pixels.
    pub y: f32,
    /// Conic a (xx).
    pub a: f32,
    /// Conic b (xy).
    pub b: f32,
    /// Conic c (yy).
    pub c: f32,
    /// Opacity (after compensation).
    pub opacity: f32,
    /// Colour.
    pub rgb: [f32; 3],
    /// Camera-space depth.
    pub depth: f32,
    /// Top of the bounding box (y − radius_y), pixels.
    pub ymin: f32,
    /// Bottom of the bounding box (y + radius_y), pixels.
    pub ymax: f32,
    /// σ beyond which α < 1/255: ln(255·opacity), padded by a relative 1e-4 so that rounding
    /// never skips a pixel the compositing rule would keep.
    pub sigma_max: f32,
}

/// State kept from the forward pass for the backward pass.
#[derive(Clone, Debug, Default)]
pub(crate) struct RasterState {
    pub grid: TileGrid,
    /// Projected records in rank (front-to-back) order.
    pub splats: Vec<Splat2D>,
    /// Gaussian index of each rank.
    pub rank_id: Vec<u32>,
    pub bins: Bins,
    /// Per pixel, tile-major (`tile·256 + row·16 + col`): list entries up to and including
    /// the last contributor.
    pub last: Vec<u32>,
    /// Per pixel, tile-major: final transmittance.
    pub final_t: Vec<f32>,
    pub settings: RenderSettings,
    pub cutoff: Cutoff,
    /// Active SH degree actually used.
    pub sh_degree: u32,
}

/// Per-Gaussian result of the projection stage.
#[derive(Clone, Copy)]
enum Proj {
    Visible(Splat2D, [u32; 4]),
    Culled,
    Invalid,
}

/// e^x for x ≤ 0 (inputs below −87 are clamped), branch-free and free of float→int
/// conversions so it vectorises; relative error below 3e-7.
#[inline(always)]
pub fn exp_neg(x: f32) -> f32 {
    const LOG2E: f32 = std::f32::consts::LOG2_E;
    const LN2_HI: f32 = 0.693_145_75;
    const LN2_LO: f32 = 1.428_606_8e-6;
    // 1.5·2²³: adding it rounds to an integer held in the low mantissa bits.
    const ROUND: f32 = 12_582_912.0;
    let x = x.clamp(-87.0, 0.0);
    let shifted = x * LOG2E + ROUND;
    let n = shifted - ROUND;
    let f = x - n * LN2_HI - n * LN2_LO;
    let p = 1.0
        + f * (1.0
            + f * (0.5
                + f * (1.0 / 6.0
                    + f * (1.0 / 24.0
                        + f * (1.0 / 120.0 + f * (1.0 / 720.0 + f * (1.0 / 5040.0)))))));
    let k = shifted.to_bits().wrapping_sub(ROUND.to_bits());
    let scale = f32::from_bits(k.wrapping_add(127) << 23);
    p * scale
}

/// The smooth cutoff factor s(α) (C¹ smoothstep from 1/255 to 2/255) and its derivative.
#[inline(always)]
pub(crate) fn smooth_cut(alpha: f32) -> (f32, f32) {
    let x = ((alpha - ALPHA_THRESHOLD) * (1.0 / ALPHA_THRESHOLD)).clamp(0.0, 1.0);
    (
        x * x * (3.0 - 2.0 * x),
        6.0 * x * (1.0 - x) / ALPHA_THRESHOLD,
    )
}

/// The alpha clamp actually used: `max_alpha` limited to [0, 1 − 1e-6] (so 1/(1 − α) stays
/// finite in the backward pass); a non-finite value falls back to the default 0.99.
pub(crate) fn effective_max_alpha(s: &RenderSettings) -> f32 {
    if s.max_alpha.is_finite() {
        s.max_alpha.clamp(0.0, 1.0 - 1e-6)
    } else {
        crate::constants::MAX_ALPHA
    }
}

/// Per-tile pixel results.
struct TilePixels {
    t: [f32; TILE_PIXELS],
    last: [u32; TILE_PIXELS],
    c: [[f32; TILE_PIXELS]; 3],
    d: [f32; TILE_PIXELS],
}

impl Default for TilePixels {
    fn default() -> Self {
        TilePixels {
            t: [1.0; TILE_PIXELS],
            last: [0; TILE_PIXELS],
            c: [[0.0; TILE_PIXELS]; 3],
            d: [0.0; TILE_PIXELS],
        }
    }
}

/// Projects every Gaussian and evaluates the colour of the visible ones.
fn project_all(
    g: &Gaussians,
    cm: &CameraModel,
    s: &RenderSettings,
    degree: u32,
    grid: &TileGrid,
) -> Vec<Proj> {
    let n = g.len();
    let k = g.coeffs() * 3;
    let sh_ok = g.sh.len() == n * k
        && g.log_scales.len() == n
        && g.quats.len() == n
        && g.opacity_logits.len() == n;
    let mut out = vec![Proj::Invalid; n];
    out.par_chunks_mut(PROJECT_CHUNK)
        .enumerate()
        .for_each(|(ci, chunk)| {
            let mut basis = [0.0f64; 16];
            for (j, slot) in chunk.iter_mut().enumerate() {
                let i = ci * PROJECT_CHUNK + j;
                if !sh_ok {
                    *slot = Proj::Invalid;
                    continue;
                }
                let coefs = &g.sh[i * k..(i + 1) * k];
                let nb = sh::basis_len(degree);
                if !coefs[..nb * 3].iter().all(|v| v.is_finite()) {
                    *slot = Proj::Invalid;
                    continue;
                }
                *slot = match project(
                    cm,
                    g.means[i],
                    g.log_scales[i],
                    g.quats[i],
                    g.opacity_logits[i],
                    s.antialiased,
                    s.near as f64,
                ) {
                    Outcome::Invalid => Proj::Invalid,
                    Outcome::Culled => Proj::Culled,
                    Outcome::Visible(p) => {
                        let m = g.means[i];
                        let v = [
                            m[0] as f64 - cm.center[0],
                            m[1] as f64 - cm.center[1],
                            m[2] as f64 - cm.center[2],
                        ];
                        let len = (v[0] * v[0] + v[1] * v[1] + v[2] * v[2]).sqrt();
                        let dir = if len > 0.0 {
                            [v[0] / len, v[1] / len, v[2] / len]
                        } else {
                            [0.0, 0.0, 1.0]
                        };
                        let col = sh::eval_color(degree, coefs, dir, &mut basis);
                        let rect = grid.rect(p.mean2d, p.radius);
                        if rect[0] >= rect[1] || rect[2] >= rect[3] {
                            Proj::Culled
                        } else {
                            Proj::Visible(
                                Splat2D {
                                    x: p.mean2d[0] as f32,
                                    y: p.mean2d[1] as f32,
                                    a: p.conic[0] as f32,
                                    b: p.conic[1] as f32,
                                    c: p.conic[2] as f32,
                                    opacity: p.opacity as f32,
                                    rgb: [col[0] as f32, col[1] as f32, col[2] as f32],
                                    depth: p.depth as f32,
                                    ymin: (p.mean2d[1] - p.radius[1] as f64) as f32,
                                    ymax: (p.mean2d[1] + p.radius[1] as f64) as f32,
                                    sigma_max: ((p.opacity / ALPHA_THRESHOLD as f64).ln().max(0.0)
                                        * (1.0 + 1e-4)
                                        + 1e-4)
                                        as f32,
                                },
                                rect,
                            )
                        }
                    }
                };
            }
        });
    out
}

/// Row range `[lo, hi)` of a tile (top pixel row `y0`) whose pixel centres lie inside both
/// the Gaussian's bounding box and its α ≥ 1/255 ellipse.
#[inline(always)]
pub(crate) fn row_range(sp: &Splat2D, y0: u32) -> (usize, usize) {
    // σ restricted to a row is minimal at dx = −b·dy/a where it equals ½·dy²·(c − b²/a).
    let q = (sp.c - sp.b * sp.b / sp.a).max(1e-30);
    let ext = (2.0 * sp.sigma_max / q).sqrt();
    let base = y0 as f32 + 0.5;
    let top = sp.ymin.max(sp.y - ext);
    let bottom = sp.ymax.min(sp.y + ext);
    let lo = (top - base).ceil().max(0.0);
    let hi = ((bottom - base).floor() + 1.0).min(TILE as f32);
    if !(hi > lo) {
        (0, 0)
    } else {
        (lo as usize, hi as usize)
    }
}

/// Whether the α ≥ 1/255 chord of the Gaussian's ellipse on the row at offset `dy`
/// (= mean_y − pixel_y) reaches the 16 pixel centres starting at `x0 + 0.5`.
#[inline(always)]
pub(crate) fn row_hits(sp: &Splat2D, dy: f32, x0: u32) -> bool {
    let q = sp.c - sp.b * sp.b / sp.a;
    let w2 = 2.0 * (sp.sigma_max - 0.5 * dy * dy * q) / sp.a;
    if !(w2 >= 0.0) {
        return false;
    }
    let w = w2.sqrt() + 1e-3;
    let centre = sp.x + sp.b * dy / sp.a;
    let left = x0 as f32 + 0.5;
    centre + w >= left && centre - w <= left + 15.0
}

/// Alpha of one Gaussian for a row of 16 pixels (0 where it is skipped: σ < 0 or below the
/// 1/255 cutoff). Pure arithmetic over lanes, so it vectorises.
#[inline(always)]
pub(crate) fn row_alpha<const SMOOTH: bool>(
    sp: &Splat2D,
    px: &[f32; 16],
    dy: f32,
    max_alpha: f32,
    out: &mut [f32; 16],
) {
    for lx in 0..16 {
        let dx = sp.x - px[lx];
        let sigma = 0.5 * (sp.a * dx * dx + sp.c * dy * dy) + sp.b * dx * dy;
        let a1 = (sp.opacity * exp_neg(-sigma)).min(max_alpha);
        let (alpha, ok) = if SMOOTH {
            let x = ((a1 - ALPHA_THRESHOLD) * (1.0 / ALPHA_THRESHOLD)).clamp(0.0, 1.0);
            (a1 * (x * x * (3.0 - 2.0 * x)), a1 > ALPHA_THRESHOLD)
        } else {
            (a1, a1 >= ALPHA_THRESHOLD)
        };
        out[lx] = if ok && sigma >= 0.0 { alpha } else { 0.0 };
    }
}

/// Composites one tile front to back; returns the number of composited pairs.
#[allow(clippy::too_many_arguments)]
#[inline(always)]
fn raster_tile<const SMOOTH: bool>(
    splats: &[Splat2D],
    list: &[u32],
    x0: u32,
    y0: u32,
    active_init: &[u32; TILE_PIXELS],
    max_alpha: f32,
    out: &mut TilePixels,
) -> u64 {
    // 1 = still compositing, 0 = done (outside the image, masked, or saturated).
    let mut active = *active_init;
    let mut remaining: u32 = active.iter().sum();
    if remaining == 0 {
        return 0;
    }
    let mut px = [0.0f32; 16];
    for (lx, v) in px.iter_mut().enumerate() {
        *v = (x0 + lx as u32) as f32 + 0.5;
    }
    let mut pairs = 0u64;
    let mut alpha = [0.0f32; 16];
    // Pixels still compositing, per row: rows that are all done are skipped.
    let mut row_live = [0u32; 16];
    for (ly, live) in row_live.iter_mut().enumerate() {
        *live = active[ly * 16..ly * 16 + 16].iter().sum();
    }
    for (k, &rank) in list.iter().enumerate() {
        let sp = &splats[rank as usize];
        let (lo, hi) = row_range(sp, y0);
        let kk = k as u32 + 1;
        for ly in lo..hi {
            if row_live[ly] == 0 {
                continue;
            }
            let dy = sp.y - ((y0 + ly as u32) as f32 + 0.5);
            if !row_hits(sp, dy, x0) {
                continue;
            }
            row_alpha::<SMOOTH>(sp, &px, dy, max_alpha, &mut alpha);
            let base = ly * TILE as usize;
            let t_row: &mut [f32; 16] = (&mut out.t[base..base + 16]).try_into().unwrap();
            let act: &mut [u32; 16] = (&mut active[base..base + 16]).try_into().unwrap();
            let last: &mut [u32; 16] = (&mut out.last[base..base + 16]).try_into().unwrap();
            let [c0, c1, c2] = &mut out.c;
            let cr: &mut [f32; 16] = (&mut c0[base..base + 16]).try_into().unwrap();
            let cg: &mut [f32; 16] = (&mut c1[base..base + 16]).try_into().unwrap();
            let cb: &mut [f32; 16] = (&mut c2[base..base + 16]).try_into().unwrap();
            let dd: &mut [f32; 16] = (&mut out.d[base..base + 16]).try_into().unwrap();
            let mut stops = 0u32;
            let mut comps = 0u32;
            for lx in 0..16 {
                let a = alpha[lx];
                let t = t_row[lx];
                let next_t = t * (1.0 - a);
                let ok = a > 0.0 && act[lx] != 0;
                let stop = ok && next_t <= TRANSMITTANCE_THRESHOLD;
                let comp = ok && !stop;
                act[lx] = if stop { 0 } else { act[lx] };
                stops += stop as u32;
                comps += comp as u32;
                let w = if comp { a * t } else { 0.0 };
                cr[lx] += w * sp.rgb[0];
                cg[lx] += w * sp.rgb[1];
                cb[lx] += w * sp.rgb[2];
                dd[lx] += w * sp.depth;
                t_row[lx] = if comp { next_t } else { t };
                last[lx] = if comp { kk } else { last[lx] };
            }
            pairs += comps as u64;
            remaining -= stops;
            row_live[ly] -= stops;
        }
        if remaining == 0 {
            break;
        }
    }
    pairs
}

/// [`raster_tile`] compiled for AVX-512F (16 lanes: one tile row per vector).
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx512f")]
#[allow(clippy::too_many_arguments)]
fn raster_tile_avx512<const SMOOTH: bool>(
    splats: &[Splat2D],
    list: &[u32],
    x0: u32,
    y0: u32,
    active_init: &[u32; TILE_PIXELS],
    max_alpha: f32,
    out: &mut TilePixels,
) -> u64 {
    raster_tile::<SMOOTH>(splats, list, x0, y0, active_init, max_alpha, out)
}

/// [`raster_tile`] compiled for AVX2.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
#[allow(clippy::too_many_arguments)]
fn raster_tile_avx2<const SMOOTH: bool>(
    splats: &[Splat2D],
    list: &[u32],
    x0: u32,
    y0: u32,
    active_init: &[u32; TILE_PIXELS],
    max_alpha: f32,
    out: &mut TilePixels,
) -> u64 {
    raster_tile::<SMOOTH>(splats, list, x0, y0, active_init, max_alpha, out)
}

/// Runs [`raster_tile`] with the widest vector unit the CPU has. Every variant performs the same
/// IEEE operations in the same order (no FMA contraction, sequential lane sums), so results
/// are bit-identical whichever one runs.
#[allow(clippy::too_many_arguments)]
fn raster_tile_dispatch<const SMOOTH: bool>(
    splats: &[Splat2D],
    list: &[u32],
    x0: u32,
    y0: u32,
    active_init: &[u32; TILE_PIXELS],
    max_alpha: f32,
    out: &mut TilePixels,
) -> u64 {
    #[cfg(target_arch = "x86_64")]
    {
        if std::arch::is_x86_feature_detected!("avx512f") {
            // SAFETY: the CPU supports AVX-512F (checked just above).
            return unsafe {
                raster_tile_avx512::<SMOOTH>(splats, list, x0, y0, active_init, max_alpha, out)
            };
        }
        if std::arch::is_x86_feature_detected!("avx2") {
            // SAFETY: the CPU supports AVX2 (checked just above).
            return unsafe {
                raster_tile_avx2::<SMOOTH>(splats, list, x0, y0, active_init, max_alpha, out)
            };
        }
    }
    raster_tile::<SMOOTH>(splats, list, x0, y0, active_init, max_alpha, out)
}

pub(crate) fn render_impl(
    g: &Gaussians,
    cam: &Camera,
    s: &RenderSettings,
    mask: Option<&[u8]>,
    cutoff: Cutoff,
) -> RenderOutput {
    let (width, height) = (cam.width, cam.height);
    let npix = width as usize * height as usize;
    let degree = s.sh_degree.min(g.sh_degree).min(3);
    let grid = TileGrid::new(width, height);
    let mask = mask.filter(|m| m.len() == npix);
    let mut stats = RenderStats::default();
    let cam_ok = cam.validate().is_ok();
    let projs = if cam_ok {
        let cm = CameraModel::new(cam);
        project_all(g, &cm, s, degree, &grid)
    } else {
        vec![Proj::Culled; g.len()]
    };
    let mut visible = Vec::new();
    let mut depth = vec![0.0f32; g.len()];
    for (i, p) in projs.iter().enumerate() {
        match p {
            Proj::Visible(sp, _) => {
                visible.push(i as u32);
                depth[i] = sp.depth;
            }
            Proj::Culled => stats.culled += 1,
            Proj::Invalid => stats.invalid += 1,
        }
    }
    stats.visible = visible.len();
    let rank_id = depth_order(&visible, &depth);
    let mut splats = Vec::with_capacity(rank_id.len());
    let mut rects = Vec::with_capacity(rank_id.len());
    for &i in &rank_id {
        if let Proj::Visible(sp, r) = projs[i as usize] {
            splats.push(sp);
            rects.push(r);
        }
    }
    drop(projs);
    let bins = bin(&grid, &rects);
    drop(rects);

    let max_alpha = effective_max_alpha(s);
    let mut tiles: Vec<TilePixels> = Vec::new();
    tiles.resize_with(grid.len(), TilePixels::default);
    let pairs: u64 = tiles
        .par_iter_mut()
        .enumerate()
        .map(|(t, out)| {
            let tx = (t % grid.tiles_x as usize) as u32;
            let ty = (t / grid.tiles_x as usize) as u32;
            let (x0, y0) = (tx * TILE, ty * TILE);
            let mut active = [0u32; TILE_PIXELS];
            for ly in 0..TILE {
                for lx in 0..TILE {
                    let (x, y) = (x0 + lx, y0 + ly);
                    if x < width && y < height {
                        let on = mask.is_none_or(|m| m[(y * width + x) as usize] != 0);
                        active[(ly * TILE + lx) as usize] = on as u32;
                    }
                }
            }
            let list = &bins.ranks[bins.ranges[t]..bins.ranges[t + 1]];
            match cutoff {
                Cutoff::Hard => {
                    raster_tile_dispatch::<false>(&splats, list, x0, y0, &active, max_alpha, out)
                }
                Cutoff::Smooth => {
                    raster_tile_dispatch::<true>(&splats, list, x0, y0, &active, max_alpha, out)
                }
            }
        })
        .sum();
    stats.pairs = pairs;

    let mut rgb = vec![0.0f32; npix * 3];
    let mut alpha = vec![0.0f32; npix];
    let mut depth_img = vec![0.0f32; npix];
    let bg = s.background;
    let w = width as usize;
    rgb.par_chunks_mut(w * 3)
        .zip(alpha.par_chunks_mut(w))
        .zip(depth_img.par_chunks_mut(w))
        .enumerate()
        .for_each(|(y, ((rgb_row, a_row), d_row))| {
            let ty = y / TILE as usize;
            let ly = y % TILE as usize;
            for x in 0..w {
                let tile = &tiles[ty * grid.tiles_x as usize + x / TILE as usize];
                let p = ly * TILE as usize + x % TILE as usize;
                let t = tile.t[p];
                for ch in 0..3 {
                    rgb_row[x * 3 + ch] = tile.c[ch][p] + t * bg[ch];
                }
                let a = 1.0 - t;
                a_row[x] = a;
                d_row[x] = if a >= DEPTH_ALPHA_EPS {
                    tile.d[p] / a
                } else {
                    0.0
                };
            }
        });
    let mut last = vec![0u32; grid.len() * TILE_PIXELS];
    let mut final_t = vec![1.0f32; grid.len() * TILE_PIXELS];
    last.par_chunks_mut(TILE_PIXELS)
        .zip(final_t.par_chunks_mut(TILE_PIXELS))
        .zip(tiles.par_iter())
        .for_each(|((l, ft), tile)| {
            l.copy_from_slice(&tile.last);
            ft.copy_from_slice(&tile.t);
        });
    RenderOutput {
        width,
        height,
        rgb,
        alpha,
        depth: depth_img,
        stats,
        state: RasterState {
            grid,
            splats,
            rank_id,
            bins,
            last,
            final_t,
            settings: s.clone(),
            cutoff,
            sh_degree: degree,
        },
    }
}

#[cfg(test)]
pub(crate) mod tests {
    use super::*;

    /// Random projected Gaussians around one tile.
    pub(crate) fn random_tile_splats(seed: u64, n: usize) -> Vec<Splat2D> {
        let mut rng = augsplat_core::Rng::new(seed);
        (0..n)
            .map(|i| {
                let (sx, sy) = (rng.uniform(0.7, 6.0), rng.uniform(0.7, 6.0));
                let rho = rng.uniform(-0.8, 0.8);
                let cov = [sx * sx, rho * sx * sy, sy * sy];
                let det = cov[0] * cov[2] - cov[1] * cov[1];
                let o = rng.uniform(0.02, 0.999);
                let y = rng.uniform(-6.0, 22.0);
                let ry = 3.33 * cov[2].sqrt();
                Splat2D {
                    x: rng.uniform(-6.0, 22.0) as f32,
                    y: y as f32,
                    a: (cov[2] / det) as f32,
                    b: (-cov[1] / det) as f32,
                    c: (cov[0] / det) as f32,
                    opacity: o as f32,
                    rgb: [rng.next_f32(), rng.next_f32(), rng.next_f32()],
                    depth: 1.0 + i as f32 * 0.01,
                    ymin: (y - ry) as f32,
                    ymax: (y + ry) as f32,
                    sigma_max: ((o * 255.0).ln().max(0.0) * 1.0001 + 1e-4) as f32,
                }
            })
            .collect()
    }

    #[test]
    fn vector_variants_are_bit_identical_to_the_portable_kernel() {
        let splats = random_tile_splats(3, 300);
        let list: Vec<u32> = (0..300).collect();
        let mut active = [1u32; TILE_PIXELS];
        active[17] = 0;
        for smooth in [false, true] {
            let mut a = TilePixels::default();
            let mut b = TilePixels::default();
            let (pa, pb) = if smooth {
                (
                    raster_tile::<true>(&splats, &list, 0, 0, &active, 0.99, &mut a),
                    raster_tile_dispatch::<true>(&splats, &list, 0, 0, &active, 0.99, &mut b),
                )
            } else {
                (
                    raster_tile::<false>(&splats, &list, 0, 0, &active, 0.99, &mut a),
                    raster_tile_dispatch::<false>(&splats, &list, 0, 0, &active, 0.99, &mut b),
                )
            };
            assert_eq!(pa, pb);
            assert!(pa > 1000);
            assert_eq!(a.last, b.last);
            let bits = |v: &[f32]| v.iter().map(|x| x.to_bits()).collect::<Vec<_>>();
            assert_eq!(bits(&a.t), bits(&b.t));
            for ch in 0..3 {
                assert_eq!(bits(&a.c[ch]), bits(&b.c[ch]));
            }
            assert_eq!(bits(&a.d), bits(&b.d));
        }
    }

    #[test]
    fn exp_neg_is_accurate() {
        let mut x = 0.0f32;
        while x > -80.0 {
            let e = exp_neg(x) as f64;
            let r = (x as f64).exp();
            assert!(((e - r) / r).abs() < 3e-7, "x {x}: {e} vs {r}");
            x -= 0.0137;
        }
        assert_eq!(exp_neg(0.0), 1.0);
        assert!(exp_neg(-1e30) >= 0.0 && exp_neg(-1e30) < 1e-37);
    }
}
