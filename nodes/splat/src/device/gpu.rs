//! The GPU device: the WGSL kernels through one shared [`GpuContext`], with the training state
//! kept in GPU buffers between steps ([`crate::gpu::GpuTrainer`]).

use super::{DeviceModel, Frame, SplatDevice, TrainState, TrainingDevice, ViewTask};
use crate::adam::LearningRates;
use crate::densify::{gpu::Refinement, RefineReport};
use crate::gpu::{
    backward_gpu, render_scene, AdapterSummary, GpuContext, GpuError, GpuScene, GpuTarget,
    GpuTrainer, ViewLoss,
};
use crate::{Gaussians, Gradients, RenderSettings};
use augsplat_core::Camera;
use std::collections::{hash_map::Entry, HashMap};
use std::sync::Arc;

/// A GPU behind its context.
pub(super) struct GpuDevice(pub(super) Arc<GpuContext>);

impl SplatDevice for GpuDevice {
    fn adapter(&self) -> Option<&AdapterSummary> {
        Some(self.0.adapter())
    }
    fn upload<'a>(&'a self, g: &'a Gaussians) -> Result<Box<dyn DeviceModel + 'a>, GpuError> {
        Ok(Box::new(GpuModel {
            ctx: &self.0,
            scene: GpuScene::upload(&self.0, g)?,
        }))
    }
    fn gpu_context(&self) -> Option<&Arc<GpuContext>> {
        Some(&self.0)
    }
    fn training(&self) -> Box<dyn TrainingDevice> {
        Box::new(GpuTraining {
            ctx: self.0.clone(),
            state: None,
            ahead: false,
            targets: HashMap::new(),
            sh_active: 0,
            count_bound: 0,
            tile_pairs: HashMap::new(),
            overflows: 0,
        })
    }
}

/// Gaussians uploaded once for many views.
struct GpuModel<'a> {
    ctx: &'a GpuContext,
    scene: GpuScene,
}

impl DeviceModel for GpuModel<'_> {
    fn render(&self, cam: &Camera, s: &RenderSettings) -> Result<Frame, GpuError> {
        let f = render_scene(self.ctx, &self.scene, cam, s)?;
        Ok(Frame {
            width: f.width,
            height: f.height,
            rgb: f.rgb,
            alpha: f.alpha,
            depth: f.depth,
            stats: f.stats,
        })
    }
    fn backward(
        &self,
        cam: &Camera,
        s: &RenderSettings,
        d_rgb: &[f32],
    ) -> Result<Gradients, GpuError> {
        Ok(backward_gpu(self.ctx, &self.scene, cam, s, d_rgb)?.into_gradients())
    }
}

/// The pair slots of a view's next forward pass from its last pair count: 1/8 more plus 1024,
/// rounded up to one of eight sizes per octave (so that the context's pool, which reuses
/// buffers of equal size, serves most passes).
pub(crate) fn pair_slots(last: u32) -> u32 {
    let need = u64::from(last) + u64::from(last / 8) + 1024;
    let step = 1u64 << (63 - need.leading_zeros()).saturating_sub(3);
    need.next_multiple_of(step).min(u64::from(u32::MAX)) as u32
}

/// A training run's GPU half.
struct GpuTraining {
    ctx: Arc<GpuContext>,
    /// The state on the GPU, once uploaded.
    state: Option<GpuTrainer>,
    /// Whether the GPU's state is newer than the host's (whose values, and after a
    /// refinement on the GPU whose sizes, are then stale).
    ahead: bool,
    /// The views' targets, uploaded at their first use, by (synthetic?, view index).
    targets: HashMap<(bool, usize), GpuTarget>,
    /// The step's active SH width.
    sh_active: usize,
    /// Each view's (tile, Gaussian) pairs at its last pass, by (synthetic?, view index): the
    /// next pass is sized from them ([`pair_slots`]).
    tile_pairs: HashMap<(bool, usize), u32>,
    /// Passes that outgrew their slots and ran again.
    overflows: u64,
    /// A bound on every Gaussian's view count in the GPU's statistics: the largest count
    /// uploaded, plus the views added with the statistic since.
    count_bound: u64,
}

impl GpuTraining {
    /// The state on the GPU, uploaded from the host's when there is none.
    fn state(&mut self, st: &TrainState) -> Result<&GpuTrainer, GpuError> {
        if self.state.is_none() {
            self.count_bound = st
                .densifier
                .count
                .iter()
                .copied()
                .max()
                .map_or(0, u64::from);
            self.state = Some(GpuTrainer::upload(
                &self.ctx,
                &st.g,
                &st.adam,
                &st.densifier,
            )?);
        }
        Ok(self.state.as_ref().expect("uploaded above"))
    }
}

impl TrainingDevice for GpuTraining {
    fn begin_step(&mut self, st: &mut TrainState, sh_active: usize) -> Result<(), GpuError> {
        self.sh_active = sh_active;
        // The previous step's encoders were all submitted: its buffers are free.
        self.ctx.reclaim();
        self.ctx.count_training_step();
        let ctx = self.ctx.clone();
        self.state(st)?.begin_step(&ctx)
    }

    fn add_view(
        &mut self,
        st: &mut TrainState,
        view: ViewTask<'_>,
        s: &RenderSettings,
    ) -> Result<(f64, u64), GpuError> {
        let ctx = self.ctx.clone();
        self.state(st)?;
        let (src, i) = (view.source, view.index);
        let key = (view.synthetic, i);
        let sh_active = self.sh_active;
        let mut host = |rgb: &[f32], grad: &mut [f32]| src.loss(i, rgb, view.scale as f32, grad);
        let gpu_loss = src.gpu_loss(i);
        let host_mask = match &gpu_loss {
            Some(v) => {
                if let Entry::Vacant(e) = self.targets.entry(key) {
                    e.insert(GpuTarget::upload(&ctx, v.target, v.weights, src.mask(i))?);
                }
                None
            }
            None => {
                let cam = src.camera(i);
                let pixels = cam.width as usize * cam.height as usize;
                crate::gpu::upload_mask(&ctx, pixels, src.mask(i))?
            }
        };
        if view.stats.is_some() {
            self.count_bound += 1;
        }
        let state = self.state.as_ref().expect("uploaded above");
        // Sized from the view's last pass: no wait for its pair count. A pass that outgrew
        // them added nothing; it runs again, counted first.
        let ahead = self.tile_pairs.get(&key).map(|&c| pair_slots(c));
        for slots in [ahead, None].into_iter().skip(usize::from(ahead.is_none())) {
            let loss = match &gpu_loss {
                Some(v) => ViewLoss::Gpu {
                    target: &self.targets[&key],
                    loss: v.loss,
                    scale: view.scale as f32,
                },
                None => ViewLoss::Host {
                    loss: &mut host,
                    mask: host_mask.as_deref(),
                },
            };
            let out = state.add_view(&ctx, src.camera(i), s, loss, view.stats, sh_active, slots);
            // The view's encoders were all submitted (it ends with a read-back): the next
            // view reuses its buffers.
            ctx.reclaim();
            let out = out?;
            self.tile_pairs.insert(key, out.tile_pairs);
            if !out.overflowed {
                return Ok((out.loss, out.pairs));
            }
            self.overflows += 1;
        }
        Err(GpuError::Invalid(
            "a forward pass sized by its own count overflowed".into(),
        ))
    }

    fn adam_step(
        &mut self,
        st: &mut TrainState,
        lr: &LearningRates,
        means_lr: f64,
        dense: bool,
    ) -> Result<(), GpuError> {
        let ctx = self.ctx.clone();
        let consts = st.adam.next_gpu_consts(self.sh_active, lr, means_lr);
        self.state(st)?.adam_step(&ctx, &consts, dense)?;
        self.ahead = true;
        Ok(())
    }

    fn sync(&mut self, st: &mut TrainState) -> Result<(), GpuError> {
        if self.ahead {
            if let Some(gs) = &self.state {
                gs.download(&self.ctx, &mut st.g, &mut st.adam, &mut st.densifier)?;
            }
            self.ahead = false;
        }
        Ok(())
    }

    fn release(&mut self, st: &mut TrainState) -> Result<(), GpuError> {
        self.sync(st)?;
        self.state = None;
        Ok(())
    }

    fn discard(&mut self) {
        self.state = None;
        self.ahead = false;
    }

    fn post_update(
        &mut self,
        st: &mut TrainState,
        r: &Refinement<'_>,
        visibility: &mut dyn FnMut(&Gaussians) -> Vec<f64>,
    ) -> Result<RefineReport, GpuError> {
        let ctx = self.ctx.clone();
        self.state(st)?;
        let bound = self.count_bound;
        let state = self.state.as_mut().expect("uploaded above");
        match state.refine(&ctx, r, bound)? {
            Some(rep) => {
                if r.grows() {
                    self.count_bound = 0;
                }
                self.ahead = true;
                Ok(rep)
            }
            // A `KeepVisible` reset, or a set wider than one binding: on the host.
            None => {
                self.release(st)?;
                Ok(super::refine_on_host(st, r, visibility))
            }
        }
    }

    fn gaussians(&self, st: &TrainState) -> usize {
        self.state.as_ref().map_or(st.g.len(), GpuTrainer::len)
    }
}
