//! The device seam: where splatting runs, behind one interface.
//!
//! [`Backend`] is what a node's args or the CLI ask for; [`Device::open`] turns it into a
//! [`Device`] — the one place that chooses between the CPU kernels and the GPU's — and every
//! caller after that speaks to the [`SplatDevice`] trait:
//!
//! - [`SplatDevice::upload`] puts a set of Gaussians on the device as a [`DeviceModel`] that
//!   renders ([`DeviceModel::render`]) and back-propagates ([`DeviceModel::backward`]) any
//!   number of views (the evaluation node and `augsplat render`);
//! - [`SplatDevice::training`] starts a [`TrainingDevice`]: the device's half of one training
//!   run. The [`crate::train::Trainer`] writes the step and every schedule once, in terms of
//!   [`TrainingDevice::begin_step`], [`TrainingDevice::add_view`] (render, loss, gradient and
//!   densification statistic of one view, summed into the step's gradients in a fixed order)
//!   and [`TrainingDevice::adam_step`], and densification and opacity resets where the state
//!   lives ([`TrainingDevice::post_update`], [`TrainingDevice::reset_for_switch`]); a step's
//!   losses and pair counts may come back later ([`TrainingDevice::end_views`] gives `None`
//!   and [`TrainingDevice::resolve`] collects them while the device runs the next step);
//!   [`TrainingDevice::sync`] and [`TrainingDevice::release`] bring the state back to the host
//!   where the host must see or change it (checkpoints, the end of a run, a refinement the
//!   device cannot do).
//!
//! The CPU device (`device/cpu.rs`) keeps the state in the host's [`TrainState`] itself; the
//! GPU device (`device/gpu.rs`) keeps a copy in GPU buffers between steps and holds one
//! shared [`crate::gpu::GpuContext`] (adapter, limits, error scopes, kernels), which any
//! other family's GPU path can share through [`SplatDevice::gpu_context`].

mod cpu;
mod gpu;

pub use cpu::add_grads;

use crate::adam::{Adam, LearningRates};
use crate::densify::gpu::Refinement;
use crate::densify::{Densifier, RefineReport};
use crate::gpu::{AdapterSummary, GpuContext, GpuError};
use crate::supervision::Supervision;
use crate::{Gaussians, Gradients, RenderSettings, RenderStats};
use augsplat_core::Camera;
use std::sync::Arc;

/// Where a node computes: defined beside the GPU context so the splatting and the radiance
/// field share it.
pub use augsplat_render::Backend;

/// One render: the image planes and the counters, on either device.
#[derive(Clone, Debug, PartialEq)]
pub struct Frame {
    /// Image width.
    pub width: u32,
    /// Image height.
    pub height: u32,
    /// Colour, `height·width·3` interleaved, background composited.
    pub rgb: Vec<f32>,
    /// Accumulated alpha `1 − T`, `height·width`.
    pub alpha: Vec<f32>,
    /// Expected depth normalised by alpha (0 where alpha < 1e-6), `height·width`.
    pub depth: Vec<f32>,
    /// Counters, counted as the CPU renderer counts them.
    pub stats: RenderStats,
}

/// A set of Gaussians on a device, rendered from any number of cameras.
pub trait DeviceModel {
    /// Renders the set from `cam`.
    fn render(&self, cam: &Camera, s: &RenderSettings) -> Result<Frame, GpuError>;
    /// The gradients of a loss whose gradient on the rendered colour is `d_rgb`
    /// (`height·width·3`).
    fn backward(
        &self,
        cam: &Camera,
        s: &RenderSettings,
        d_rgb: &[f32],
    ) -> Result<Gradients, GpuError>;
}

/// The host's training state: the Gaussians, Adam's moments and the densification
/// statistics. A [`TrainingDevice`] may hold a newer copy; [`TrainingDevice::sync`] brings it
/// back.
pub struct TrainState {
    /// The Gaussians.
    pub g: Gaussians,
    /// The optimiser's moments.
    pub adam: Adam,
    /// The densification statistics.
    pub densifier: Densifier,
}

/// One view of one training step, as [`TrainingDevice::add_view`] takes it.
#[derive(Clone, Copy)]
pub struct ViewTask<'a> {
    /// The supervision source (real photos or synthetic targets).
    pub source: &'a dyn Supervision,
    /// The view's index in `source`.
    pub index: usize,
    /// Whether `source` is the synthetic one (a device may keep targets per source).
    pub synthetic: bool,
    /// The factor on the loss's gradient (the source's weight, ÷ the batch for a batch).
    pub scale: f64,
    /// With `Some(factor)`, the view's densification statistic (the screen-space mean
    /// gradient × `factor`, as [`Densifier::accumulate_scaled`]) is added to the sums.
    pub stats: Option<f32>,
}

/// The views of one step in flight and the settings they were added with, for
/// [`TrainingDevice::resolve`].
#[derive(Clone, Copy)]
pub struct StepViews<'a> {
    /// The views, in the order they were added.
    pub views: &'a [ViewTask<'a>],
    /// The step's render settings.
    pub settings: &'a RenderSettings,
}

/// The device's half of one training run (see the module documentation). Every method
/// leaves the sums in the CPU trainer's order, so a step is the same maths on every device.
pub trait TrainingDevice {
    /// Starts a step: the step's gradient sums are cleared (`sh_active` is the number of
    /// leading SH values per Gaussian whose gradient may be non-zero this step).
    fn begin_step(&mut self, st: &mut TrainState, sh_active: usize) -> Result<(), GpuError>;
    /// Renders the view, computes its loss and `scale · dL/d(rgb)`, back-propagates and adds
    /// the gradients to the step's sums (and the densification statistic, when asked). Its
    /// loss and counts may stay on the device until [`TrainingDevice::end_views`].
    fn add_view(
        &mut self,
        st: &mut TrainState,
        view: ViewTask<'_>,
        s: &RenderSettings,
    ) -> Result<(), GpuError>;
    /// After the step's last view: (the loss without `scale`, composited pairs) of each view
    /// added since [`TrainingDevice::begin_step`], in order, when the device has them now
    /// (the CPU); `None` when they are still on their way (the GPU), for
    /// [`TrainingDevice::resolve`]. `views` are those views as they were added (with `s`,
    /// the step's settings): a device that must run some again (a forward pass that outgrew
    /// its sizing) runs them from the first such one, in order, so the sums keep their order.
    fn end_views(
        &mut self,
        st: &mut TrainState,
        views: &[ViewTask<'_>],
        s: &RenderSettings,
    ) -> Result<Option<Vec<(f64, u64)>>, GpuError>;
    /// The steps whose [`TrainingDevice::end_views`] gave `None` and are not resolved yet,
    /// oldest first.
    fn in_flight(&self) -> usize {
        0
    }
    /// Resolves the oldest of the [`TrainingDevice::in_flight`] steps until at most `keep`
    /// remain, and returns their views' results as `end_views` would have, oldest first
    /// (more steps than asked when a step must run again: then every later step runs again
    /// behind it). `steps` are the in-flight steps' views and settings, oldest first.
    fn resolve(
        &mut self,
        _st: &mut TrainState,
        _steps: &[StepViews<'_>],
        _keep: usize,
    ) -> Result<Vec<Vec<(f64, u64)>>, GpuError> {
        Ok(Vec::new())
    }
    /// One Adam step with the step's sums: over every Gaussian with `dense`, otherwise over
    /// those some view of the step saw; `means_lr` is the means' rate at this step.
    fn adam_step(
        &mut self,
        st: &mut TrainState,
        lr: &LearningRates,
        means_lr: f64,
        dense: bool,
    ) -> Result<(), GpuError>;
    /// Makes `st` current (copies a newer device state back).
    fn sync(&mut self, st: &mut TrainState) -> Result<(), GpuError>;
    /// [`TrainingDevice::sync`], then drops the device's copy: the host is about to change
    /// the state, and the next step uploads it again.
    fn release(&mut self, st: &mut TrainState) -> Result<(), GpuError>;
    /// Drops the device's copy without reading it (the host's state was replaced).
    fn discard(&mut self);
    /// Densification's schedule after the update of step `r.step`
    /// ([`Densifier::step_post_update`]: refinement and opacity resets when due), wherever the
    /// state lives. The result is the host's refinement to the bit on every device, but for
    /// a `KeepVisible` reset on a GPU (its caps in f32, within rounding of the host's).
    fn post_update(
        &mut self,
        st: &mut TrainState,
        r: &Refinement<'_>,
    ) -> Result<RefineReport, GpuError> {
        self.release(st)?;
        Ok(refine_on_host(st, r))
    }
    /// The opacity reset of a Staged switch or Dual's switch-off, wherever the state lives:
    /// every opacity clamped to at most `value` ([`crate::densify::reset_opacities`]), then
    /// every moment and step counter of Adam and the densification statistics cleared.
    fn reset_for_switch(&mut self, st: &mut TrainState, value: f64) -> Result<(), GpuError> {
        self.release(st)?;
        reset_for_switch_on_host(st, value);
        Ok(())
    }
    /// The number of Gaussians in training (a device's copy may have densified since the
    /// host's was made current).
    fn gaussians(&self, st: &TrainState) -> usize {
        st.g.len()
    }
    /// Renders the current Gaussians from `cam` where they live (the held-out evaluations
    /// during training: only the image comes back).
    fn render(
        &mut self,
        st: &mut TrainState,
        cam: &Camera,
        s: &RenderSettings,
    ) -> Result<Frame, GpuError> {
        self.sync(st)?;
        Ok(Frame::from(crate::render(&st.g, cam, s)))
    }
}

impl From<crate::RenderOutput> for Frame {
    fn from(r: crate::RenderOutput) -> Frame {
        Frame {
            width: r.width,
            height: r.height,
            rgb: r.rgb,
            alpha: r.alpha,
            depth: r.depth,
            stats: r.stats,
        }
    }
}

/// [`Densifier::step_post_update`] on the host's state.
pub fn refine_on_host(st: &mut TrainState, r: &Refinement<'_>) -> RefineReport {
    st.densifier.step_post_update(
        r.step,
        r.sched,
        r.args,
        &mut st.g,
        &mut st.adam,
        r.extents,
        r.seed,
        &mut |g| r.views.peak_alpha_ratios(g),
    )
}

/// [`TrainingDevice::reset_for_switch`] on the host's state.
pub fn reset_for_switch_on_host(st: &mut TrainState, value: f64) {
    crate::densify::reset_opacities(&mut st.g, &mut st.adam, value);
    st.adam.clear();
    st.densifier.clear();
}

/// What a device can do.
pub trait SplatDevice: Send + Sync {
    /// The GPU adapter that computes (`None` on the CPU), for the outputs' metadata.
    fn adapter(&self) -> Option<&AdapterSummary>;
    /// Puts `g` on the device for rendering.
    fn upload<'a>(&'a self, g: &'a Gaussians) -> Result<Box<dyn DeviceModel + 'a>, GpuError>;
    /// A training run's device half, starting with nothing on the device.
    fn training(&self) -> Box<dyn TrainingDevice>;
    /// The GPU context (`None` on the CPU), for other kernels that run on the same device.
    fn gpu_context(&self) -> Option<&Arc<GpuContext>>;
}

/// An opened device: the CPU, or a GPU context (see the module documentation).
#[derive(Clone)]
pub struct Device {
    inner: Arc<dyn SplatDevice>,
}

impl Device {
    /// Opens the device `backend` names: the CPU always, a GPU when the machine has an adapter
    /// (otherwise the [`GpuError`] that says what was found, never a fall-back).
    pub fn open(backend: Backend) -> Result<Device, GpuError> {
        match backend {
            Backend::Cpu => Ok(Device::cpu()),
            Backend::Gpu => Ok(Device::gpu(Arc::new(GpuContext::new()?))),
        }
    }

    /// The CPU.
    pub fn cpu() -> Device {
        Device {
            inner: Arc::new(cpu::CpuDevice),
        }
    }

    /// A GPU through an existing context (e.g. one with a lowered binding limit).
    pub fn gpu(ctx: Arc<GpuContext>) -> Device {
        Device {
            inner: Arc::new(gpu::GpuDevice(ctx)),
        }
    }
}

impl std::ops::Deref for Device {
    type Target = dyn SplatDevice;
    fn deref(&self) -> &(dyn SplatDevice + 'static) {
        &*self.inner
    }
}

impl std::fmt::Debug for Device {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self.adapter() {
            Some(a) => write!(f, "Device(GPU: {a})"),
            None => f.write_str("Device(CPU)"),
        }
    }
}
