//! Step 2 of the backward pass: per Gaussian (in parallel chunks of [`PROJECT_CHUNK`]), its
//! pair slots summed in f64 in a fixed order (tiles in row-major order, so the result is the
//! same for any thread count), then the projection and SH backward eight Gaussians at a time
//! in f64 lanes: the portable lanes or the AVX2 lanes, with the same IEEE operations.

use super::PairGrad;
use crate::forward::PROJECT_CHUNK;
use crate::gaussians::Gaussians;
use crate::lanes::{c, Lanes, Mask, LANES, P8};
use crate::project::{project_vjp_lanes, CameraModel, ParamGrad, ParamLanes, ProjectedGradLanes};
use crate::render::RenderOutput;
use crate::sh;
use augsplat_core::simd::{self, Isa};
use augsplat_core::Camera;
use rayon::prelude::*;

/// Where [`gaussian_gradients`] puts each visible Gaussian's gradients.
#[derive(Clone, Copy, PartialEq, Eq)]
pub(super) enum Mode {
    /// Store them (the buffers hold zeros on entry).
    Store,
    /// Add them to the values already there (a step's running sum).
    Add,
}

/// The per-Gaussian destination slices of [`gaussian_gradients`].
pub(super) struct GradSinks<'a> {
    pub(super) means: &'a mut [[f32; 3]],
    pub(super) log_scales: &'a mut [[f32; 3]],
    pub(super) quats: &'a mut [[f32; 4]],
    pub(super) opacity_logits: &'a mut [f32],
    pub(super) sh: &'a mut [f32],
    /// The densification statistic (stored in either mode), when wanted.
    pub(super) means2d_abs: Option<&'a mut [[f32; 2]]>,
    pub(super) visible: &'a mut [bool],
}

/// One [`PROJECT_CHUNK`] of [`GradSinks`], starting at Gaussian `first`.
pub(super) struct SinkChunk<'a> {
    pub(super) first: usize,
    pub(super) sinks: GradSinks<'a>,
}

/// Step 2 of the backward pass: per Gaussian (in parallel chunks), its pair slots summed in
/// f64 in a fixed order, then the projection and SH backward; results stored or added
/// (`mode`) into `sinks`.
pub(super) fn gaussian_gradients(
    g: &Gaussians,
    cam: &Camera,
    out: &RenderOutput,
    pair_grads: &[PairGrad],
    sinks: GradSinks<'_>,
    mode: Mode,
) {
    let st = &out.state;
    let s = &st.settings;
    let bins = &st.bins;
    let kcoef = g.coeffs() * 3;
    let cm = CameraModel::new(cam);
    let degree = st.sh_degree;
    let active = sh::basis_len(degree) * 3;
    let (hw, hh) = (out.width as f64 * 0.5, out.height as f64 * 0.5);
    let isa = simd::active();
    let c = PROJECT_CHUNK;
    let mut m2d = sinks.means2d_abs.map(|v| v.chunks_mut(c));
    let chunks: Vec<SinkChunk<'_>> = sinks
        .means
        .chunks_mut(c)
        .zip(sinks.log_scales.chunks_mut(c))
        .zip(sinks.quats.chunks_mut(c))
        .zip(sinks.opacity_logits.chunks_mut(c))
        .zip(sinks.sh.chunks_mut(c * kcoef.max(1)))
        .zip(sinks.visible.chunks_mut(c))
        .enumerate()
        .map(
            |(ci, (((((means, log_scales), quats), opacity_logits), sh), visible))| SinkChunk {
                first: ci * c,
                sinks: GradSinks {
                    means,
                    log_scales,
                    quats,
                    opacity_logits,
                    sh,
                    means2d_abs: m2d.as_mut().and_then(|it| it.next()),
                    visible,
                },
            },
        )
        .collect();
    chunks.into_par_iter().for_each(|ch| {
        let SinkChunk {
            first,
            sinks:
                GradSinks {
                    means: gm,
                    log_scales: gl,
                    quats: gq,
                    opacity_logits: go,
                    sh: gsh,
                    mut means2d_abs,
                    visible: gv,
                },
        } = ch;
        // The chunk's Gaussians with a non-zero screen-space gradient, with their sums.
        let mut todo: Vec<(usize, [f64; 10])> = Vec::new();
        for j in 0..gm.len() {
            let i = first + j;
            let (lo, hi) = (bins.gauss_start[i], bins.gauss_start[i + 1]);
            if lo == hi {
                continue;
            }
            let mut rg = [0.0f64; 10];
            for pg in &pair_grads[lo..hi] {
                for q in 0..10 {
                    rg[q] += pg[q] as f64;
                }
            }
            gv[j] = true;
            if let Some(g2) = means2d_abs.as_deref_mut() {
                g2[j] = [(rg[0] * hw) as f32, (rg[1] * hh) as f32];
            }
            if rg.iter().all(|v| *v == 0.0) {
                // Visible but never composited (occluded or behind saturated pixels):
                // every parameter gradient is exactly zero.
                continue;
            }
            todo.push((j, rg));
        }
        for batch in todo.chunks(LANES) {
            // A short last batch repeats its last Gaussian in the spare lanes.
            let pick = |l: usize| &batch[l.min(batch.len() - 1)];
            let mut idx = [0usize; LANES];
            let mut screen = [[0.0f64; LANES]; 10];
            for l in 0..LANES {
                let (j, rg) = pick(l);
                idx[l] = first + j;
                for q in 0..10 {
                    screen[q][l] = rg[q];
                }
            }
            let job = LaneJob {
                cm: &cm,
                g,
                idx: &idx,
                opacity_scale: s.opacity_scale.as_deref(),
                antialiased: s.antialiased,
                near: s.near as f64,
                degree,
                kcoef,
                screen: &screen,
            };
            let lg = vjp_lanes(isa, &job);
            for (l, &(j, _)) in batch.iter().enumerate() {
                let p = lg.params[l];
                let gmean = p.mean;
                let with_sh = (lg.with_sh >> l) & 1 == 1;
                let sh_grad = &lg.sh[l];
                let dst_sh = &mut gsh[j * kcoef..j * kcoef + active];
                let vals = (
                    gmean.map(|x| x as f32),
                    p.log_scale.map(|x| x as f32),
                    p.quat.map(|x| x as f32),
                    p.logit as f32,
                );
                match mode {
                    Mode::Store => {
                        gm[j] = vals.0;
                        gl[j] = vals.1;
                        gq[j] = vals.2;
                        go[j] = vals.3;
                        if with_sh {
                            dst_sh.copy_from_slice(&sh_grad[..active]);
                        }
                    }
                    Mode::Add => {
                        for (d, s) in gm[j].iter_mut().zip(vals.0) {
                            *d += s;
                        }
                        for (d, s) in gl[j].iter_mut().zip(vals.1) {
                            *d += s;
                        }
                        for (d, s) in gq[j].iter_mut().zip(vals.2) {
                            *d += s;
                        }
                        go[j] += vals.3;
                        if with_sh {
                            for (d, s) in dst_sh.iter_mut().zip(&sh_grad[..active]) {
                                *d += s;
                            }
                        }
                    }
                }
            }
        }
    });
}

/// One batch of [`vjp_lanes`]: Gaussians `idx` with their screen-space gradient sums
/// (`screen[q][lane]` in [`PairGrad`] order).
pub(super) struct LaneJob<'a> {
    pub(super) cm: &'a CameraModel,
    pub(super) g: &'a Gaussians,
    pub(super) idx: &'a [usize; LANES],
    /// The render's opacity factors ([`crate::RenderSettings::opacity_scale`]).
    pub(super) opacity_scale: Option<&'a [f32]>,
    pub(super) antialiased: bool,
    pub(super) near: f64,
    pub(super) degree: u32,
    pub(super) kcoef: usize,
    pub(super) screen: &'a [[f64; LANES]; 10],
}

/// The per-Gaussian gradients of one [`LaneJob`].
pub(super) struct LaneGrads {
    /// Geometry and opacity gradients (the mean's includes the SH view-direction path).
    pub(super) params: [ParamGrad; LANES],
    /// dL/d(active SH coefficients), per lane.
    pub(super) sh: [[f32; 48]; LANES],
    /// Lanes whose Gaussian is not at the camera centre (their SH gradients are valid).
    pub(super) with_sh: Mask,
}

/// The projection and colour backward of one batch, in the lanes of `isa`: the same IEEE
/// operations on every instruction set (and as the scalar `sh` functions).
pub(super) fn vjp_lanes(isa: Isa, job: &LaneJob<'_>) -> LaneGrads {
    #[inline(always)]
    fn run<L: Lanes>(job: &LaneJob<'_>) -> LaneGrads {
        let LaneJob {
            cm,
            g,
            idx,
            opacity_scale,
            antialiased,
            near,
            degree,
            kcoef,
            screen,
        } = *job;
        let gl = ParamLanes::<L>::gather(
            &g.means,
            &g.log_scales,
            &g.quats,
            &g.opacity_logits,
            opacity_scale,
            idx,
        );
        let pg = ProjectedGradLanes::<L>::from_rows([
            screen[0], screen[1], screen[2], screen[3], screen[4], screen[5], screen[9],
        ]);
        let geo = project_vjp_lanes(cm, &gl, antialiased, near, &pg);
        // SH: the colour depends on the view direction normalize(mean − centre).
        let v = [
            gl.mean[0] - cm.center[0],
            gl.mean[1] - cm.center[1],
            gl.mean[2] - cm.center[2],
        ];
        let len = (v[0] * v[0] + v[1] * v[1] + v[2] * v[2]).sqrt();
        let with_sh = len.gt(c(0.0));
        let dir = [v[0] / len, v[1] / len, v[2] / len];
        let na = sh::basis_len(degree) * 3;
        let rows = sh::coef_rows(&g.sh, idx, kcoef, na);
        let cols = L::columns(&rows, na);
        let coef = |q: usize| cols[q];
        let g_color = [
            L::from_array(screen[6]),
            L::from_array(screen[7]),
            L::from_array(screen[8]),
        ];
        let mut grad_cols = [c::<L>(0.0); crate::lanes::COLUMNS];
        let gd = sh::eval_color_vjp_lanes(degree, coef, dir, g_color, |q, val| {
            grad_cols[q] = val;
        });
        let sh_grads = L::rows(&grad_cols, na);
        let dd = gd[0] * dir[0] + gd[1] * dir[1] + gd[2] * dir[2];
        let mut mean = geo.mean;
        for a in 0..3 {
            let with = mean[a] + (gd[a] - dir[a] * dd) / len;
            mean[a] = L::select(with_sh, with, mean[a]);
        }
        let geo = ParamLanes { mean, ..geo };
        LaneGrads {
            params: geo.unpack(),
            sh: sh_grads,
            with_sh,
        }
    }
    #[cfg(target_arch = "x86_64")]
    {
        #[target_feature(enable = "avx2,fma")]
        fn avx2(job: &LaneJob<'_>) -> LaneGrads {
            run::<crate::lanes::avx2::Y8>(job)
        }
        if isa == Isa::Avx2 {
            // SAFETY: `Isa::Avx2` is only active on CPUs with AVX2 and FMA.
            return unsafe { avx2(job) };
        }
    }
    run::<P8>(job)
}
