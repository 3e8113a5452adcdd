//! The forward pass: projection of every Gaussian (parallel, fixed chunks), tile binning, and
//! per-tile front-to-back compositing (tiles in parallel).
//!
//! Compositing (docs/design.md, *Compositing*): σ = ½(a·dx² + c·dy²) + b·dx·dy;
//! α = min(max_alpha, o·e^−σ); skip if σ < 0 or α < 1/255; stop *before* a Gaussian when
//! T·(1 − α) ≤ 1e-4; C += c·α·T; output C + T·background, alpha 1 − T, depth Σ z·α·T / (1 − T).
//!
//! Each tile keeps, per pixel, the number of list entries up to and including its last
//! contributor and its final transmittance; the backward pass walks back from there.
//!
//! # Where things are
//!
//! | file | what it owns |
//! |---|---|
//! | `mod.rs` | the compositing record [`Splat2D`], the state kept for the backward pass, the alpha rule, dispatch by instruction-set tier, `render_impl` (project → sort → bin → composite → write) |
//! | `exp2.rs` | the base-2 exponential and the per-row geometry that feeds it |
//! | `tile.rs` | the portable twin of the tile kernel (the maths) and the `ForwardKernel` trait the variants implement |
//! | `avx2.rs` | the AVX2 tile kernel (x86-64) |
//! | `project_chunk.rs` | projection of every Gaussian into compositing records, portable and AVX2 lanes |
//! | `tests.rs` | every tier against the portable twin bit for bit; the tile kernel against a direct loop |
//!
//! The projected records ([`Splat2D`]) are stored in depth-rank order, one 64-byte
//! (cache-line) record per Gaussian. Every kernel exists as a portable twin and an AVX2
//! variant (a row is two 8-lane vectors, composited one after the other) written with
//! intrinsics; both perform the same IEEE operations in the same order per pixel (fused
//! multiply-adds are `f32::mul_add` in the twin), so they give bit-identical results, which
//! the tests check for every tier the CPU supports ([`augsplat_core::simd::for_each_isa`]).
//! The tier is chosen by [`augsplat_core::simd::active`].

// Negated comparisons are deliberate: they also reject NaN. Index loops read best in
// small fixed-size numeric code.
#![allow(clippy::neg_cmp_op_on_partial_ord, clippy::needless_range_loop)]

#[cfg(target_arch = "x86_64")]
pub(crate) mod avx2;
mod exp2;
pub mod gpu;
mod project_chunk;
#[cfg(test)]
pub(crate) mod tests;
mod tile;

pub use exp2::exp2_neg;
pub(crate) use exp2::{gauss_of_exponent, RowGeom};
pub(crate) use tile::{row_mask_portable, TileCoords};

use crate::buffers::filled_par;
use crate::constants::{ALPHA_THRESHOLD, DEPTH_ALPHA_EPS, TILE, TILE_PIXELS};
use crate::gaussians::Gaussians;
use crate::project::CameraModel;
use crate::render::{Cutoff, RenderOutput, RenderSettings, RenderStats};
use crate::tiles::{bin_indexed, depth_order, Bins, TileGrid};
use augsplat_core::simd::{self, Isa};
use augsplat_core::Camera;
use project_chunk::{project_all, ProjectedAll, CULLED, VISIBLE};
use rayon::prelude::*;
use tile::{raster_tile_portable, TileState};

/// Gaussians per parallel projection chunk (fixed, so results never depend on the pool).
pub(crate) const PROJECT_CHUNK: usize = 1024;

/// List entries per compositing batch (one bit each in a row's 64-bit set).
pub(crate) const BATCH: usize = 64;

/// How many list entries ahead the tile loops prefetch projected records.
pub(crate) const PREFETCH_AHEAD: usize = 8;

/// The exponent in bits (−σ·log₂e) is clamped to ≥ −this before the exponential: below it
/// α < 2⁻⁴⁴ < 1/255 for any opacity ≤ 1, so the clamp never changes a composited value, and
/// the power of two stays a normal float.
pub(crate) const SIGMA_CLAMP: f32 = 44.0;

/// Padding (pixels) added to the half-chord of the row test, so that rounding never drops
/// a pixel the compositing rule would keep.
const CHORD_PAD: f32 = 1e-2;

/// One projected Gaussian, as the compositing kernels read it (64 bytes, one cache line).
#[derive(Clone, Copy, Debug, Default, PartialEq)]
#[repr(C, align(64))]
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
    /// σ beyond which α < 1/255: ln(255·opacity), padded by a relative 1e-3 (+1e-3) so that
    /// rounding never skips a pixel the compositing rule would keep.
    pub sigma_max: f32,
    /// ½·(c − b²/a) = ½/Σ2d_yy: the minimum of σ along a pixel row at offset dy from the
    /// centre is `row_q·dy²`.
    pub row_q: f32,
    /// 2/a: on a row at offset dy the α ≥ 1/255 chord has squared half-length
    /// `row_w·(sigma_max − row_q·dy²)`.
    pub row_w: f32,
    /// b/a: on a row at offset dy (= y − pixel y) the chord is centred at `x + row_shift·dy`.
    pub row_shift: f32,
}

/// State kept from the forward pass for the backward pass.
#[derive(Clone, Debug, Default)]
pub(crate) struct RasterState {
    pub grid: TileGrid,
    /// Projected records in rank (front-to-back) order.
    pub splats: Vec<Splat2D>,
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

/// Runs the tile kernel variant `isa` (the smooth cutoff, a test-only path, always runs the
/// portable twin). Every variant gives bit-identical results.
#[allow(clippy::too_many_arguments)]
fn raster_tile_dispatch<const SMOOTH: bool>(
    isa: Isa,
    splats: &[Splat2D],
    list: &[u32],
    x0: u32,
    y0: u32,
    active_init: &[u16; 16],
    max_alpha: f32,
    st: &mut TileState,
) -> u64 {
    match isa {
        #[cfg(target_arch = "x86_64")]
        Isa::Avx2 => {
            // SAFETY: `Isa::Avx2` is only active on CPUs with AVX2, FMA, BMI1 and POPCNT.
            unsafe {
                avx2::raster_tile_avx2::<SMOOTH>(splats, list, x0, y0, active_init, max_alpha, st)
            }
        }
        _ => raster_tile_portable::<SMOOTH>(splats, list, x0, y0, active_init, max_alpha, st),
    }
}

/// Raw pointers to the output images, written by the tiles in parallel.
#[derive(Clone, Copy)]
struct ImageOut {
    rgb: *mut f32,
    alpha: *mut f32,
    depth: *mut f32,
}

impl ImageOut {
    /// Writes pixel `p` (the closures capture the whole wrapper through this method).
    ///
    /// # Safety
    /// `p` must lie inside the image and be written by one thread only.
    #[inline(always)]
    unsafe fn write(&self, p: usize, rgb: [f32; 3], alpha: f32, depth: f32) {
        for (ch, v) in rgb.iter().enumerate() {
            *self.rgb.add(p * 3 + ch) = *v;
        }
        *self.alpha.add(p) = alpha;
        *self.depth.add(p) = depth;
    }
}

// SAFETY: the tiles write disjoint pixels (see `render_impl`).
unsafe impl Send for ImageOut {}
// SAFETY: as above.
unsafe impl Sync for ImageOut {}

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
    let ProjectedAll {
        splats: all_splats,
        rects: all_rects,
        status,
    } = if cam.validate().is_ok() {
        let cm = CameraModel::new(cam);
        project_all(g, &cm, s, degree, &grid)
    } else {
        ProjectedAll {
            splats: Vec::new(),
            rects: Vec::new(),
            status: vec![CULLED; g.len()],
        }
    };
    let mut visible = Vec::new();
    let mut depth = vec![0.0f32; g.len()];
    for (i, st) in status.iter().enumerate() {
        match *st {
            VISIBLE => {
                visible.push(i as u32);
                // SAFETY: the record of a visible Gaussian was written by `project_all`.
                depth[i] = unsafe { all_splats[i].assume_init_ref() }.depth;
            }
            CULLED => stats.culled += 1,
            _ => stats.invalid += 1,
        }
    }
    stats.visible = visible.len();
    let rank_id = depth_order(&visible, &depth);
    drop(depth);
    let splats: Vec<Splat2D> = rank_id
        .par_iter()
        .with_min_len(PROJECT_CHUNK)
        // SAFETY: `rank_id` lists visible Gaussians only, whose records `project_all` wrote.
        .map(|&i| unsafe { all_splats[i as usize].assume_init() })
        .collect();
    let rects: Vec<[u32; 4]> = rank_id
        .par_iter()
        .with_min_len(PROJECT_CHUNK)
        // SAFETY: as above, for the rectangles.
        .map(|&i| unsafe { all_rects[i as usize].assume_init() })
        .collect();
    drop(all_splats);
    drop(all_rects);
    let bins = bin_indexed(&grid, &rects, &rank_id, g.len());
    drop(rects);

    let max_alpha = effective_max_alpha(s);
    let isa = simd::active();
    let mut rgb = filled_par(npix * 3, 0.0f32);
    let mut alpha = filled_par(npix, 0.0f32);
    let mut depth_img = filled_par(npix, 0.0f32);
    let mut last = filled_par(grid.len() * TILE_PIXELS, 0u32);
    let mut final_t = filled_par(grid.len() * TILE_PIXELS, 1.0f32);
    let out = ImageOut {
        rgb: rgb.as_mut_ptr(),
        alpha: alpha.as_mut_ptr(),
        depth: depth_img.as_mut_ptr(),
    };
    let bg = s.background;
    let pairs: u64 = last
        .par_chunks_mut(TILE_PIXELS)
        .zip(final_t.par_chunks_mut(TILE_PIXELS))
        .enumerate()
        .map_init(TileState::default, |st, (t, (last_t, ft))| {
            let tx = (t % grid.tiles_x as usize) as u32;
            let ty = (t / grid.tiles_x as usize) as u32;
            let (x0, y0) = (tx * TILE, ty * TILE);
            let mut active = [0u16; 16];
            for ly in 0..TILE {
                for lx in 0..TILE {
                    let (x, y) = (x0 + lx, y0 + ly);
                    if x < width && y < height {
                        let on = mask.is_none_or(|m| m[(y * width + x) as usize] != 0);
                        active[ly as usize] |= (on as u16) << lx;
                    }
                }
            }
            *st = TileState::default();
            let list = &bins.ranks[bins.ranges[t]..bins.ranges[t + 1]];
            let pairs = match cutoff {
                Cutoff::Hard => raster_tile_dispatch::<false>(
                    isa, &splats, list, x0, y0, &active, max_alpha, st,
                ),
                Cutoff::Smooth => {
                    raster_tile_dispatch::<true>(isa, &splats, list, x0, y0, &active, max_alpha, st)
                }
            };
            for ly in 0..TILE as usize {
                let y = y0 as usize + ly;
                let row = &st.rows[ly];
                last_t[ly * 16..ly * 16 + 16].copy_from_slice(&row.last);
                ft[ly * 16..ly * 16 + 16].copy_from_slice(&row.t);
                if y >= height as usize {
                    continue;
                }
                for lx in 0..TILE as usize {
                    let x = x0 as usize + lx;
                    if x >= width as usize {
                        break;
                    }
                    let p = y * width as usize + x;
                    let tt = row.t[lx];
                    let a = 1.0 - tt;
                    let dv = if a >= DEPTH_ALPHA_EPS {
                        row.d[lx] / a
                    } else {
                        0.0
                    };
                    let rgb: [f32; 3] = std::array::from_fn(|ch| row.c[ch][lx] + tt * bg[ch]);
                    // SAFETY: pixel (x, y) lies inside the image (checked above) and inside
                    // this tile only, so no other tile writes it; the buffers outlive the
                    // parallel loop.
                    unsafe { out.write(p, rgb, a, dv) };
                }
            }
            pairs
        })
        .sum();
    stats.pairs = pairs;
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
            bins,
            last,
            final_t,
            settings: s.clone(),
            cutoff,
            sh_degree: degree,
        },
    }
}
