//! Projection of every Gaussian into its compositing record ([`Splat2D`]), in fixed chunks
//! of [`PROJECT_CHUNK`] Gaussians (parallel), eight at a time in f64 lanes: the portable lanes
//! or the AVX2 lanes, with the same IEEE operations.

use super::{Splat2D, PROJECT_CHUNK};
use crate::buffers::uninit_vec;
use crate::gaussians::Gaussians;
use crate::lanes::{c, Lanes, Mask, LANES, P8};
use crate::project::{project_lanes, CameraModel, ParamLanes, Projected};
use crate::render::RenderSettings;
use crate::sh;
use crate::tiles::TileGrid;
use augsplat_core::simd::Isa;
use rayon::prelude::*;
use std::mem::MaybeUninit;

/// Builds the compositing record of a projected Gaussian, or `None` when it cannot be
/// represented in f32 (it is then culled).
pub(super) fn make_splat(
    p: &crate::project::Projected,
    rgb: [f64; 3],
    log_alpha_ratio: f64,
) -> Option<Splat2D> {
    let [a, b, c] = p.conic;
    // Σ2d = conic⁻¹; Σ_yy = a / det(conic), Σ_xy = −b / det(conic).
    let det = a * c - b * b;
    let syy = a / det;
    let row_q = 0.5 / syy;
    let row_w = 2.0 / a;
    let row_shift = b / a;
    // log_alpha_ratio = ln(opacity / ALPHA_THRESHOLD), from the projection.
    let sigma_max = log_alpha_ratio.max(0.0) * (1.0 + 1e-3) + 1e-3;
    let lim = f32::MAX as f64;
    let sp = Splat2D {
        x: p.mean2d[0] as f32,
        y: p.mean2d[1] as f32,
        a: a as f32,
        b: b as f32,
        c: c as f32,
        opacity: p.opacity as f32,
        rgb: [rgb[0] as f32, rgb[1] as f32, rgb[2] as f32],
        depth: p.depth as f32,
        ymin: (p.mean2d[1] - p.radius[1] as f64) as f32,
        ymax: (p.mean2d[1] + p.radius[1] as f64) as f32,
        sigma_max: sigma_max as f32,
        // Clamped to finite values: the row test must never see ∞·0.
        row_q: row_q.clamp(0.0, lim) as f32,
        row_w: row_w.clamp(0.0, lim) as f32,
        row_shift: row_shift.clamp(-lim, lim) as f32,
    };
    let core = [
        sp.x, sp.y, sp.a, sp.b, sp.c, sp.opacity, sp.rgb[0], sp.rgb[1], sp.rgb[2], sp.depth,
    ];
    let ok = core.iter().all(|v| v.is_finite())
        && det > 0.0
        && !row_q.is_nan()
        && !row_w.is_nan()
        && !row_shift.is_nan()
        && sp.sigma_max.is_finite();
    ok.then_some(sp)
}

/// One chunk of [`project_all`]'s work.
pub(super) struct ProjectJob<'a> {
    pub(super) g: &'a Gaussians,
    pub(super) cm: &'a CameraModel,
    pub(super) s: &'a RenderSettings,
    pub(super) degree: u32,
    pub(super) grid: &'a TileGrid,
    /// Index of the chunk's first Gaussian.
    pub(super) first: usize,
}

/// Projects one chunk of Gaussians (see [`project_all`]), eight at a time in lanes `L`.
#[inline(always)]
pub(super) fn project_chunk<L: Lanes>(
    job: &ProjectJob<'_>,
    sp_out: &mut [MaybeUninit<Splat2D>],
    rect_out: &mut [MaybeUninit<[u32; 4]>],
    st_out: &mut [u8],
) {
    let ProjectJob {
        g,
        cm,
        s,
        degree,
        grid,
        ..
    } = *job;
    let k = g.coeffs() * 3;
    let nb = sh::basis_len(degree);
    let len = sp_out.len();
    let centre = crate::lanes::splats::<L, 3>(cm.center);
    for j0 in (0..len).step_by(LANES) {
        let n = (len - j0).min(LANES);
        let live: Mask = if n == LANES { 0xff } else { (1u8 << n) - 1 };
        // A short last block repeats its last Gaussian in the spare lanes.
        let mut idx = [0usize; LANES];
        for (l, v) in idx.iter_mut().enumerate() {
            *v = job.first + (j0 + l).min(len - 1);
        }
        let gl = ParamLanes::<L>::gather(
            &g.means,
            &g.log_scales,
            &g.quats,
            &g.opacity_logits,
            s.opacity_scale.as_deref(),
            &idx,
        );
        let pl = project_lanes(cm, &gl, s.antialiased, s.near as f64);
        // Tile rectangles (the radius saturates as `Projected`'s i32 does).
        let r_max = c::<L>(i32::MAX as f64);
        let rect = grid.rect_lanes(
            pl.mean2d,
            [pl.radius[0].min(r_max), pl.radius[1].min(r_max)],
        );
        let nonempty = rect[0].lt(rect[1]) & rect[2].lt(rect[3]);
        // The lanes' active SH coefficients, each Gaussian's read once and contiguously.
        // Non-finite ones make a Gaussian invalid (checked first).
        let na = nb * 3;
        let rows = sh::coef_rows(&g.sh, &idx, k, na);
        let mut sh_ok: Mask = 0;
        for (l, row) in rows.iter().enumerate().take(n) {
            let finite = row[..na].iter().fold(true, |ok, v| ok & v.is_finite());
            sh_ok |= (finite as u8) << l;
        }
        let invalid = (!sh_ok | pl.status.invalid) & live;
        let mut visible = sh_ok & pl.status.visible() & nonempty & live;
        for l in 0..n {
            st_out[j0 + l] = if (invalid >> l) & 1 == 1 {
                INVALID
            } else {
                CULLED
            };
        }
        if visible == 0 {
            continue;
        }
        // Colours of the eight lanes from the view directions normalize(mean − centre).
        let v = [
            gl.mean[0] - centre[0],
            gl.mean[1] - centre[1],
            gl.mean[2] - centre[2],
        ];
        let vlen = (v[0] * v[0] + v[1] * v[1] + v[2] * v[2]).sqrt();
        let away = vlen.gt(c(0.0));
        let dir = [
            L::select(away, v[0] / vlen, c(0.0)),
            L::select(away, v[1] / vlen, c(0.0)),
            L::select(away, v[2] / vlen, c(1.0)),
        ];
        let cols = L::columns(&rows, na);
        let col = crate::lanes::to_arrays(sh::eval_color_lanes(degree, |q| cols[q], dir));
        let m = [pl.mean2d[0].to_array(), pl.mean2d[1].to_array()];
        let kc = crate::lanes::to_arrays(pl.conic);
        let (op, dp) = (pl.opacity.to_array(), pl.depth.to_array());
        let rad = [pl.radius[0].to_array(), pl.radius[1].to_array()];
        let lr = pl.log_alpha_ratio.to_array();
        let rect = crate::lanes::to_arrays(rect);
        while visible != 0 {
            let l = visible.trailing_zeros() as usize;
            visible &= visible - 1;
            let p = Projected {
                mean2d: [m[0][l], m[1][l]],
                conic: [kc[0][l], kc[1][l], kc[2][l]],
                opacity: op[l],
                depth: dp[l],
                radius: [rad[0][l] as i32, rad[1][l] as i32],
            };
            let rgb = [col[0][l], col[1][l], col[2][l]];
            if let Some(sp) = make_splat(&p, rgb, lr[l]) {
                let j = j0 + l;
                sp_out[j].write(sp);
                rect_out[j].write([
                    rect[0][l] as u32,
                    rect[1][l] as u32,
                    rect[2][l] as u32,
                    rect[3][l] as u32,
                ]);
                st_out[j] = VISIBLE;
            }
        }
    }
}

/// [`project_chunk`] with AVX2 lanes: the same IEEE operations as the portable lanes.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2,fma")]
pub(super) fn project_chunk_avx2(
    job: &ProjectJob<'_>,
    sp_out: &mut [MaybeUninit<Splat2D>],
    rect_out: &mut [MaybeUninit<[u32; 4]>],
    st_out: &mut [u8],
) {
    project_chunk::<crate::lanes::avx2::Y8>(job, sp_out, rect_out, st_out)
}

/// Runs [`project_chunk`] in the lanes of tier `isa` (every tier gives the same bits).
pub(super) fn project_chunk_dispatch(
    isa: Isa,
    job: &ProjectJob<'_>,
    sp_out: &mut [MaybeUninit<Splat2D>],
    rect_out: &mut [MaybeUninit<[u32; 4]>],
    st_out: &mut [u8],
) {
    match isa {
        #[cfg(target_arch = "x86_64")]
        Isa::Avx2 => {
            // SAFETY: `Isa::Avx2` is only active on CPUs with AVX2 and FMA.
            unsafe { project_chunk_avx2(job, sp_out, rect_out, st_out) }
        }
        _ => project_chunk::<P8>(job, sp_out, rect_out, st_out),
    }
}

/// Projection status of one Gaussian: visible (its record and rectangle were written).
pub(super) const VISIBLE: u8 = 0;
/// Projection status: outside the view or behind the near plane.
pub(super) const CULLED: u8 = 1;
/// Projection status: a non-finite parameter or a degenerate covariance.
pub(super) const INVALID: u8 = 2;

/// Projects every Gaussian and evaluates the colour of the visible ones: fills `splats`,
/// `rects` and `status` (indexed by Gaussian).
pub(super) fn project_all(
    g: &Gaussians,
    cm: &CameraModel,
    s: &RenderSettings,
    degree: u32,
    grid: &TileGrid,
) -> ProjectedAll {
    let n = g.len();
    let k = g.coeffs() * 3;
    let sh_ok = g.sh.len() == n * k
        && g.log_scales.len() == n
        && g.quats.len() == n
        && g.opacity_logits.len() == n;
    let mut splats = uninit_vec::<Splat2D>(n);
    let mut rects = uninit_vec::<[u32; 4]>(n);
    let mut status = vec![INVALID; n];
    if !sh_ok {
        return ProjectedAll {
            splats,
            rects,
            status,
        };
    }
    let isa = augsplat_core::simd::active();
    splats
        .par_chunks_mut(PROJECT_CHUNK)
        .zip(rects.par_chunks_mut(PROJECT_CHUNK))
        .zip(status.par_chunks_mut(PROJECT_CHUNK))
        .enumerate()
        .for_each(|(ci, ((sp_out, rect_out), st_out))| {
            let job = ProjectJob {
                g,
                cm,
                s,
                degree,
                grid,
                first: ci * PROJECT_CHUNK,
            };
            project_chunk_dispatch(isa, &job, sp_out, rect_out, st_out);
        });
    ProjectedAll {
        splats,
        rects,
        status,
    }
}

/// The per-Gaussian results of [`project_all`]: `splats[i]` and `rects[i]` are initialised
/// exactly where `status[i] == VISIBLE`.
pub(super) struct ProjectedAll {
    pub(super) splats: Vec<MaybeUninit<Splat2D>>,
    pub(super) rects: Vec<MaybeUninit<[u32; 4]>>,
    pub(super) status: Vec<u8>,
}
