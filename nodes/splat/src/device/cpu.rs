//! The CPU device: the kernels of this crate, with the training state kept in the host's
//! [`TrainState`] itself.

use super::{DeviceModel, Frame, SplatDevice, TrainState, TrainingDevice, ViewTask};
use crate::adam::{LearningRates, ParamGrads};
use crate::gpu::{AdapterSummary, GpuError};
use crate::{Gaussians, Gradients, RenderOutput, RenderSettings};
use augsplat_core::Camera;
use rayon::prelude::*;

/// The CPU (all cores; the same bytes for any thread count).
pub(super) struct CpuDevice;

impl SplatDevice for CpuDevice {
    fn adapter(&self) -> Option<&AdapterSummary> {
        None
    }
    fn upload<'a>(&'a self, g: &'a Gaussians) -> Result<Box<dyn DeviceModel + 'a>, GpuError> {
        Ok(Box::new(CpuModel(g)))
    }
    fn training(&self) -> Box<dyn TrainingDevice> {
        Box::new(CpuTraining::default())
    }
    fn gpu_context(&self) -> Option<&std::sync::Arc<crate::gpu::GpuContext>> {
        None
    }
}

/// Gaussians rendered on the CPU (nothing to upload: the host's set is read in place).
struct CpuModel<'a>(&'a Gaussians);

impl DeviceModel for CpuModel<'_> {
    fn render(&self, cam: &Camera, s: &RenderSettings) -> Result<Frame, GpuError> {
        Ok(Frame::from(crate::render(self.0, cam, s)))
    }
    fn backward(
        &self,
        cam: &Camera,
        s: &RenderSettings,
        d_rgb: &[f32],
    ) -> Result<Gradients, GpuError> {
        let out = crate::render(self.0, cam, s);
        Ok(crate::backward(self.0, cam, s, &out, d_rgb, None, None))
    }
}

/// A training run's CPU half: the step's gradient sum and a colour-gradient buffer.
#[derive(Default)]
struct CpuTraining {
    /// The step's sum (the first view's own buffers once it is there).
    acc: Option<ParamGrads>,
    /// The step's active SH width.
    sh_active: usize,
    /// `scale · dL/d(rgb)` of the current view.
    d_rgb: Vec<f32>,
    /// The step's views' (loss, pairs) so far.
    results: Vec<(f64, u64)>,
}

impl TrainingDevice for CpuTraining {
    fn begin_step(&mut self, _st: &mut TrainState, sh_active: usize) -> Result<(), GpuError> {
        self.acc = None;
        self.sh_active = sh_active;
        self.results.clear();
        Ok(())
    }

    fn add_view(
        &mut self,
        st: &mut TrainState,
        view: ViewTask<'_>,
        s: &RenderSettings,
    ) -> Result<(), GpuError> {
        let (src, i) = (view.source, view.index);
        let cam = src.camera(i);
        let out: RenderOutput = crate::render_masked(&st.g, cam, s, src.mask(i));
        self.d_rgb.clear();
        self.d_rgb.resize(out.rgb.len(), 0.0);
        let loss = src.loss(i, &out.rgb, view.scale as f32, &mut self.d_rgb);
        let n = st.g.len();
        if view.synthetic && view.stats.is_none() {
            // No statistic wanted: add straight into the step's sum (the same values as
            // merging a fresh buffer, without N-sized buffers per view).
            let sh_active = self.sh_active;
            let acc = self.acc.get_or_insert_with(|| ParamGrads {
                sh_active,
                ..ParamGrads::zeros(n, st.g.coeffs())
            });
            crate::backward_add(&st.g, cam, &out, &self.d_rgb, acc);
        } else {
            let gr = crate::backward(&st.g, cam, s, &out, &self.d_rgb, None, None);
            if let Some(f) = view.stats {
                if gr.means2d_abs.len() == n && gr.visible.len() == n {
                    st.densifier
                        .accumulate_scaled(&gr.means2d_abs, &gr.visible, f);
                }
            }
            merge_grads(&mut self.acc, gr, n, st.g.coeffs() * 3, self.sh_active);
        }
        self.results.push((loss, out.stats.pairs));
        Ok(())
    }

    fn end_views(
        &mut self,
        _st: &mut TrainState,
        _views: &[ViewTask<'_>],
        _s: &RenderSettings,
    ) -> Result<Option<Vec<(f64, u64)>>, GpuError> {
        Ok(Some(std::mem::take(&mut self.results)))
    }

    fn adam_step(
        &mut self,
        st: &mut TrainState,
        lr: &LearningRates,
        means_lr: f64,
        dense: bool,
    ) -> Result<(), GpuError> {
        let sh_active = self.sh_active;
        let mut acc = self.acc.take().unwrap_or_else(|| ParamGrads {
            sh_active,
            ..ParamGrads::zeros(st.g.len(), st.g.coeffs())
        });
        if dense {
            // The densification statistics were gathered already; Adam now sees every
            // Gaussian.
            acc.visible.fill(true);
        }
        st.adam.step(&mut st.g, &acc, lr, means_lr);
        Ok(())
    }

    fn sync(&mut self, _st: &mut TrainState) -> Result<(), GpuError> {
        Ok(())
    }
    fn release(&mut self, _st: &mut TrainState) -> Result<(), GpuError> {
        Ok(())
    }
    fn discard(&mut self) {}
}

/// Gaussians per parallel chunk of the gradient sum.
const ADD_CHUNK: usize = 1024;

/// Adds one render's gradients into the step's sum: only the Gaussians visible in that
/// render (the others have zero gradients) and only the first `sh_active` SH values of each
/// (the rest are zero above the active degree). Element-wise, so the order of renders is the
/// only order that matters, and it is fixed. (What [`crate::backward_add`] does without the
/// render's own buffers.)
pub fn add_grads(acc: &mut ParamGrads, g: &Gradients, sh_active: usize) {
    let n = acc.len();
    let k3 = acc.sh.len().checked_div(n).unwrap_or(0);
    let sh_cols = sh_active.min(k3);
    let with_sh = g.sh.len() == acc.sh.len();
    let c = ADD_CHUNK;
    acc.means
        .par_chunks_mut(c)
        .zip(acc.log_scales.par_chunks_mut(c))
        .zip(acc.quats.par_chunks_mut(c))
        .zip(acc.opacity_logits.par_chunks_mut(c))
        .zip(acc.sh.par_chunks_mut(c * k3.max(1)))
        .zip(acc.visible.par_chunks_mut(c))
        .enumerate()
        .for_each(|(ci, (((((me, ls), qu), op), sh), vi))| {
            let first = ci * c;
            for j in 0..me.len() {
                let i = first + j;
                if !g.visible[i] {
                    continue;
                }
                vi[j] = true;
                for (d, s) in me[j].iter_mut().zip(&g.means[i]) {
                    *d += s;
                }
                for (d, s) in ls[j].iter_mut().zip(&g.log_scales[i]) {
                    *d += s;
                }
                for (d, s) in qu[j].iter_mut().zip(&g.quats[i]) {
                    *d += s;
                }
                op[j] += g.opacity_logits[i];
                if with_sh {
                    let dst = &mut sh[j * k3..j * k3 + sh_cols];
                    let src = &g.sh[i * k3..i * k3 + sh_cols];
                    for (d, s) in dst.iter_mut().zip(src) {
                        *d += s;
                    }
                }
            }
        });
}

/// Folds one render's gradients into the step's sum: the first render's buffers become the
/// sum (no copy, no zeroing), later ones are added with [`add_grads`]. A gradient of the
/// wrong size (e.g. from an empty set) contributes nothing.
fn merge_grads(acc: &mut Option<ParamGrads>, gr: Gradients, n: usize, k3: usize, sh_active: usize) {
    let sized = gr.means.len() == n
        && gr.log_scales.len() == n
        && gr.quats.len() == n
        && gr.opacity_logits.len() == n
        && gr.visible.len() == n;
    if !sized {
        return;
    }
    match acc {
        Some(a) => add_grads(a, &gr, sh_active),
        None => {
            let sh = if gr.sh.len() == n * k3 {
                gr.sh
            } else {
                vec![0.0; n * k3]
            };
            *acc = Some(ParamGrads {
                means: gr.means,
                log_scales: gr.log_scales,
                quats: gr.quats,
                opacity_logits: gr.opacity_logits,
                sh,
                visible: gr.visible,
                sh_active,
            });
        }
    }
}
