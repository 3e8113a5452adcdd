//! The Gaussian-splatting training loop with pluggable supervision sources and the AugSplat
//! schedules.
//!
//! A [`Trainer`] owns the Gaussians, the [`Adam`] state and the [`Densifier`]. Each
//! [`Trainer::step`]:
//! 1. asks the [`Schedule`] for the step's [`StepPlan`] (weights of the real and the synthetic
//!    source, synthetic batch size, whether this is the Staged switch);
//! 2. renders one real view (epoch-shuffled order, as gsplat's data loader) and/or a batch of
//!    synthetic views (drawn without replacement per step), each at its own camera and
//!    resolution; synthetic views with a skip mask use [`crate::render_masked`];
//! 3. asks each [`Supervision`] source for its loss and `dL/d(rgb)` scaled by the source's
//!    weight (÷ batch size for the synthetic batch), back-propagates, and sums the gradients
//!    in a fixed order (the real render's gradient buffers become the sum; later renders add
//!    only their visible Gaussians and the SH coefficients of the active degree — synthetic
//!    views straight into the sum with [`crate::backward_add`] unless their densification
//!    statistic is wanted);
//! 4. takes one Adam step over every Gaussian (`adam: Dense`, the default) or only those
//!    visible in some render of the step (`adam: Selective`); the means rate follows
//!    [`crate::adam::LearningRates::means_at`];
//! 5. feeds the densification statistic of the *real* renders (and of the synthetic ones when
//!    `densify_from_synthetic`) to the [`Densifier`] and runs its refinement schedule.
//!
//! The statistic is the gradient of the weighted total loss, as in the authors' code (one
//! backward of `λ_real·L_real + λ_nerf·L_nerf`); synthetic statistics are multiplied back by
//! the batch size (gsplat's `× n_cameras`).
//!
//! Every random choice comes from [`Rng::stream`] keyed by the seed and the step, and every
//! reduction has a fixed order, so a run is bit-identical for any thread count.
//!
//! The step is written once over the [`crate::device`] seam: [`Trainer::on_device`] moves
//! the training to another [`Device`] (the GPU keeps the state there between steps and brings
//! it back for evaluations, checkpoints and the resets it cannot do). [`Trainer::advance`]
//! records a step and leaves it in flight: on the GPU its losses and pair counts come back
//! while the device runs the next step (a pass that outgrew its pair slots is found then, and
//! that step and the one behind it run again: the results never depend on the lag);
//! [`Trainer::step`] resolves each step before it returns. The arguments live in
//! `train/args.rs`.

use crate::adam::Adam;
use crate::densify::{self, Densifier, DensifySchedule, Extents, PruneExtent};
use crate::device::{Device, StepViews, TrainState, TrainingDevice, ViewTask};
pub use crate::schedule::{dual_lambda, dual_raw_weight, Schedule, StepPlan};
pub use crate::supervision::{RealImages, RealView, Supervision, SynthView, SyntheticImages};
use crate::{Gaussians, RenderSettings};
use augsplat_core::{Camera, Rng};
use std::collections::VecDeque;

mod args;
pub(crate) mod gpu;
#[cfg(test)]
mod gpu_tests;

pub use crate::device::add_grads;
pub use args::{RealLoss, SyntheticArgs, TrainArgs};

/// What one step did.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct StepReport {
    /// The 0-based step index.
    pub step: u64,
    /// Weighted total loss.
    pub loss: f64,
    /// Real loss (unweighted), when a real view was rendered.
    pub real_loss: Option<f64>,
    /// Mean synthetic loss (unweighted) over the batch, when rendered.
    pub synthetic_loss: Option<f64>,
    /// Gaussians after the step.
    pub gaussians: usize,
    /// Densification that happened after the step.
    pub refine: densify::RefineReport,
    /// Composited (Gaussian, pixel) pairs over the step's renders.
    pub pairs: u64,
}

/// Scene scale as gsplat: 1.1 × the largest distance of a camera centre from their mean
/// (1.0 when there are no cameras or they coincide).
pub fn scene_scale(cameras: &[&Camera]) -> f64 {
    if cameras.is_empty() {
        return 1.0;
    }
    let (cs, mean) = centres_and_centroid(cameras);
    let r = cs
        .iter()
        .map(|c| {
            ((c[0] - mean[0]).powi(2) + (c[1] - mean[1]).powi(2) + (c[2] - mean[2]).powi(2)).sqrt()
        })
        .fold(0.0, f64::max);
    let s = 1.1 * r;
    if s.is_finite() && s > 0.0 {
        s
    } else {
        1.0
    }
}

/// The cameras' centres and their mean (`cameras` must not be empty).
fn centres_and_centroid(cameras: &[&Camera]) -> (Vec<[f64; 3]>, [f64; 3]) {
    let cs: Vec<[f64; 3]> = cameras.iter().map(|c| c.center()).collect();
    let mean = std::array::from_fn(|a| cs.iter().map(|c| c[a]).sum::<f64>() / cs.len() as f64);
    (cs, mean)
}

/// The content's extent: 1.1 × the 90th percentile (the `⌊0.9·(n−1)⌋`-th smallest, from 0)
/// of the distances of `means` from the cameras' centroid; `None` without cameras or points,
/// or when it is not a positive finite length. The percentile keeps a few far outliers of an
/// SfM cloud from setting it.
///
/// [`PruneExtent::Content`] prunes against the larger of this and [`scene_scale`]: in a
/// forward-facing capture the content reaches many times farther than the cameras spread.
pub fn content_extent(cameras: &[&Camera], means: &[[f32; 3]]) -> Option<f64> {
    if cameras.is_empty() || means.is_empty() {
        return None;
    }
    let (_, centroid) = centres_and_centroid(cameras);
    let mut d: Vec<f64> = means
        .iter()
        .map(|m| {
            let v: [f64; 3] = std::array::from_fn(|a| m[a] as f64 - centroid[a]);
            (v[0] * v[0] + v[1] * v[1] + v[2] * v[2]).sqrt()
        })
        .filter(|x| x.is_finite())
        .collect();
    if d.is_empty() {
        return None;
    }
    let k = (0.9 * (d.len() - 1) as f64).floor() as usize;
    let (_, kth, _) = d.select_nth_unstable_by(k, f64::total_cmp);
    let e = 1.1 * *kth;
    (e.is_finite() && e > 0.0).then_some(e)
}

/// The training state.
pub struct Trainer<'a> {
    args: TrainArgs,
    /// The Gaussians, the moments and the statistics (the device may hold newer values).
    state: TrainState,
    /// The device's half of the run.
    device: Box<dyn TrainingDevice>,
    dsched: DensifySchedule,
    scene_scale: f64,
    /// The large-Gaussian prune's extent (`densify.prune_extent`), fixed from the start.
    prune_extent: f64,
    step: u64,
    real: &'a dyn Supervision,
    synthetic: Option<&'a dyn Supervision>,
    real_order: Vec<usize>,
    real_pos: usize,
    epoch: u64,
    usable_synth: Vec<usize>,
    /// Steps recorded whose results are still on the device, oldest first.
    in_flight: VecDeque<InFlight<'a>>,
    /// Steps resolved whose reports no caller has taken yet, oldest first.
    finished: VecDeque<StepReport>,
}

/// How many recorded steps [`Trainer::advance`] leaves in flight: on a GPU, step `k`'s losses
/// and pair counts are read while the device runs step `k + 1`.
pub const STEPS_IN_FLIGHT: usize = 1;

/// A recorded step whose views' results are still on the device.
struct InFlight<'a> {
    /// The report, but for the losses and pairs.
    report: StepReport,
    /// The step's views, in the order they were added.
    views: Vec<ViewTask<'a>>,
    /// The step's render settings.
    settings: RenderSettings,
    /// How many of `views` are real (they come first).
    real_views: usize,
    /// The plan's weights.
    real_weight: f64,
    synthetic_weight: f64,
}

impl InFlight<'_> {
    /// The report with the views' (loss, pairs).
    fn complete(self, results: &[(f64, u64)]) -> StepReport {
        let mut rep = self.report;
        let (real_results, synth_results) = results.split_at(self.real_views.min(results.len()));
        if let Some(&(l, pairs)) = real_results.first() {
            rep.real_loss = Some(l);
            rep.loss += self.real_weight * l;
            rep.pairs += pairs;
        }
        let batch = self.views.len() - self.real_views;
        if batch > 0 {
            let mut sum = 0.0;
            for &(l, pairs) in synth_results {
                sum += l;
                rep.pairs += pairs;
            }
            rep.synthetic_loss = Some(sum / batch as f64);
            rep.loss += self.synthetic_weight * sum / batch as f64;
        }
        rep
    }
}

/// A device failure in the middle of a step: the training cannot go on, and the engine
/// reports the panic as the node's failure with the device's message.
fn device_failed(e: crate::gpu::GpuError) -> ! {
    panic!("backend: Gpu: {e}")
}

impl<'a> Trainer<'a> {
    /// A trainer on the CPU starting from `g`. The SH storage of `g` must be
    /// `args.sh_degree`. With `densify.prune_extent: Content`, the prune's extent is measured
    /// here from `g` and the real views' cameras (see [`content_extent`]).
    pub fn new(
        args: TrainArgs,
        g: Gaussians,
        scene_scale: f64,
        real: &'a dyn Supervision,
        synthetic: Option<&'a dyn Supervision>,
    ) -> Self {
        let n = g.len();
        let adam = Adam::new(n, g.coeffs());
        let dsched = args.densify.scaled(args.steps);
        let usable_synth = synthetic
            .map(|s| (0..s.len()).filter(|&i| s.usable(i)).collect())
            .unwrap_or_default();
        let prune_extent = match args.densify.prune_extent {
            PruneExtent::Cameras => scene_scale,
            PruneExtent::Content => {
                let cams: Vec<&Camera> = (0..real.len()).map(|i| real.camera(i)).collect();
                content_extent(&cams, &g.means).map_or(scene_scale, |e| e.max(scene_scale))
            }
        };
        Trainer {
            state: TrainState {
                g,
                adam,
                densifier: Densifier::new(n),
            },
            device: Device::cpu().training(),
            dsched,
            scene_scale,
            prune_extent,
            step: 0,
            real,
            synthetic,
            real_order: Vec::new(),
            real_pos: 0,
            epoch: 0,
            usable_synth,
            args,
            in_flight: VecDeque::new(),
            finished: VecDeque::new(),
        }
    }

    /// Trains on `device` from now on (the state moves there at the next step). A device
    /// failure in a later step ends the training with the device's message (a panic the
    /// engine reports as the node's failure).
    pub fn on_device(&mut self, device: &Device) {
        self.sync();
        self.device.discard();
        self.device = device.training();
    }

    /// Makes the host's state current (every step in flight resolved first).
    fn sync(&mut self) {
        self.resolve(0);
        self.device
            .sync(&mut self.state)
            .unwrap_or_else(|e| device_failed(e));
    }

    /// Resolves the oldest steps in flight until at most `keep` remain; their reports wait
    /// in `finished`.
    fn resolve(&mut self, keep: usize) {
        if self.in_flight.len() <= keep {
            return;
        }
        let steps: Vec<StepViews<'_>> = self
            .in_flight
            .iter()
            .map(|f| StepViews {
                views: &f.views,
                settings: &f.settings,
            })
            .collect();
        let results = self
            .device
            .resolve(&mut self.state, &steps, keep)
            .unwrap_or_else(|e| device_failed(e));
        for r in results {
            let f = self
                .in_flight
                .pop_front()
                .expect("the device resolves only steps in flight");
            self.finished.push_back(f.complete(&r));
        }
    }

    /// The number of Gaussians now (without bringing them back from the device).
    pub fn primitives(&self) -> usize {
        self.device.gaussians(&self.state)
    }

    /// [`evaluate`] of the current Gaussians, rendered where they live: on a GPU only the
    /// images come back (the GPU's renders agree with the CPU's to about 5e-7).
    pub fn evaluate(
        &mut self,
        views: &[RealView],
        settings: &RenderSettings,
        lpips: Option<&augsplat_metrics::lpips::Lpips>,
    ) -> Result<Evaluation, EvalError> {
        self.resolve(0);
        let (device, state) = (&mut self.device, &mut self.state);
        evaluate_with(views, lpips, &mut |cam| {
            device
                .render(state, cam, settings)
                .unwrap_or_else(|e| device_failed(e))
                .rgb
        })
    }

    /// The current Gaussians (brought back from the device first).
    pub fn gaussians(&mut self) -> &Gaussians {
        self.sync();
        &self.state.g
    }

    /// The densification statistics gathered since the last refinement: per Gaussian, the
    /// summed norm of its screen-space gradient and the number of renders that saw it
    /// (brought back from the device first).
    pub fn densify_statistics(&mut self) -> (&[f32], &[u32]) {
        self.sync();
        (&self.state.densifier.grad2d, &self.state.densifier.count)
    }

    /// Steps taken so far.
    pub fn steps_done(&self) -> u64 {
        self.step
    }
    /// The scene scale in use.
    pub fn scene_scale(&self) -> f64 {
        self.scene_scale
    }
    /// The extent the large-Gaussian prune measures scales against (the scene scale unless
    /// `densify.prune_extent` is `Content`).
    pub fn prune_extent(&self) -> f64 {
        self.prune_extent
    }
    /// The densification schedule in use.
    pub fn densify_schedule(&self) -> DensifySchedule {
        self.dsched
    }
    /// The arguments.
    pub fn args(&self) -> &TrainArgs {
        &self.args
    }
    /// The Gaussians, ending the training.
    pub fn into_gaussians(mut self) -> Gaussians {
        self.sync();
        self.state.g
    }

    /// Appends everything that the next steps depend on to a checkpoint: the Gaussians, the
    /// optimiser's moments, the densification statistics, the step and the position in the
    /// shuffled view order. (Every other random choice is drawn from a stream keyed by the
    /// step, so nothing else carries over.)
    pub fn write_state(&mut self, w: &mut augsplat_core::state::StateWriter) {
        self.sync();
        w.tag("trainer");
        w.u64(self.step);
        w.u64(self.epoch);
        w.u64(self.real_pos as u64);
        w.usizes(&self.real_order);
        w.f64(self.scene_scale);
        w.f32s(&self.state.densifier.grad2d);
        w.u32s(&self.state.densifier.count);
        self.state.adam.write_state(w);
        self.state.g.write_state(w);
    }

    /// Continues from a state [`Trainer::write_state`] wrote for the same `args` and inputs.
    pub fn restore_state(
        &mut self,
        r: &mut augsplat_core::state::StateReader<'_>,
    ) -> Result<(), augsplat_core::state::StateError> {
        use augsplat_core::state::StateError;
        r.tag("trainer")?;
        let step = r.u64()?;
        let epoch = r.u64()?;
        let real_pos = r.u64()? as usize;
        let real_order = r.usizes()?;
        let scene_scale = r.f64()?;
        let grad2d = r.f32s()?;
        let count = r.u32s()?;
        let adam = Adam::read_state(r)?;
        let g = Gaussians::read_state(r)?;
        let n = g.len();
        if grad2d.len() != n || count.len() != n || adam.len() != n {
            return Err(StateError(format!(
                "{n} Gaussians but statistics for {} and moments for {}",
                grad2d.len(),
                adam.len()
            )));
        }
        if real_order.iter().any(|&i| i >= self.real.len()) || real_pos > real_order.len() {
            return Err(StateError(
                "the view order names views that do not exist".into(),
            ));
        }
        self.step = step;
        self.epoch = epoch;
        self.real_pos = real_pos;
        self.real_order = real_order;
        self.scene_scale = scene_scale;
        self.state = TrainState {
            g,
            adam,
            densifier: Densifier { grad2d, count },
        };
        self.device.discard();
        self.in_flight.clear();
        self.finished.clear();
        Ok(())
    }

    fn next_real(&mut self) -> Option<usize> {
        let n = self.real.len();
        if n == 0 {
            return None;
        }
        if self.real_pos >= self.real_order.len() {
            self.real_order = (0..n).collect();
            Rng::stream(self.args.seed ^ 0x5EA1, self.epoch).shuffle(&mut self.real_order);
            self.epoch += 1;
            self.real_pos = 0;
        }
        let i = self.real_order[self.real_pos];
        self.real_pos += 1;
        Some(i)
    }

    /// Adds one view, the step's `render`-th render, to the step on the device (with
    /// DropGaussian's factors for that render when it is on); its (unweighted loss, pairs)
    /// come from [`crate::device::TrainingDevice::end_views`].
    fn add_view(&mut self, view: ViewTask<'_>, settings: &RenderSettings, render: u64) {
        let factors = self.args.drop_gaussians.as_ref().and_then(|d| {
            let n = self.device.gaussians(&self.state);
            d.factors(self.args.seed, self.step, self.args.steps, render, n)
        });
        let dropped;
        let settings = match factors {
            Some(f) => {
                dropped = RenderSettings {
                    opacity_scale: Some(f),
                    ..settings.clone()
                };
                &dropped
            }
            None => settings,
        };
        self.device
            .add_view(&mut self.state, view, settings)
            .unwrap_or_else(|e| device_failed(e))
    }

    /// One optimisation step, resolved before it returns: its report. (Reports of earlier
    /// steps that [`Trainer::advance`] left in flight wait for the next `advance` or
    /// [`Trainer::finish_steps`].)
    pub fn step(&mut self) -> StepReport {
        self.record_step();
        self.resolve(0);
        self.finished
            .pop_back()
            .expect("the step just recorded is resolved")
    }

    /// Records the next step and resolves all but the newest [`STEPS_IN_FLIGHT`] steps: the
    /// reports of the steps resolved since the last call, oldest first. On the CPU that is
    /// this step's; on a GPU usually the one before, whose losses and pair counts come back
    /// while the device runs this one, so the device never waits for the host to record.
    /// Every result is the same as [`Trainer::step`]'s, bit for bit.
    pub fn advance(&mut self) -> Vec<StepReport> {
        self.record_step();
        self.resolve(STEPS_IN_FLIGHT);
        self.finished.drain(..).collect()
    }

    /// Resolves every step in flight: the reports not taken yet, oldest first.
    pub fn finish_steps(&mut self) -> Vec<StepReport> {
        self.resolve(0);
        self.finished.drain(..).collect()
    }

    /// Records one optimisation step on the device; its report waits in flight or, once
    /// resolved, in `finished`.
    fn record_step(&mut self) {
        let step = self.step;
        let plan = self.args.schedule.plan(step);
        self.reset_at_switch(&plan);
        let settings = self.args.render_settings(step);
        let sh_active =
            3 * crate::gaussians::sh_coeffs(settings.sh_degree.min(self.state.g.sh_degree));
        self.device
            .begin_step(&mut self.state, sh_active)
            .unwrap_or_else(|e| device_failed(e));
        let densify_on = self.args.densify.enabled && step < self.dsched.stop;
        // The step's views: the real one, then the synthetic batch.
        let mut views = Vec::new();
        let real = plan.real_weight > 0.0;
        if real {
            if let Some(i) = self.next_real() {
                views.push(ViewTask {
                    source: self.real,
                    index: i,
                    synthetic: false,
                    scale: plan.real_weight,
                    stats: densify_on.then(|| self.args.synthetic.stat_factor(plan.real_weight)),
                });
            }
        }
        let real_views = views.len();
        if let (true, Some(src)) = (
            plan.synthetic_weight > 0.0 && plan.synthetic_batch > 0,
            self.synthetic,
        ) {
            let batch = plan.synthetic_batch.min(self.usable_synth.len());
            if batch > 0 {
                let scale = plan.synthetic_weight / batch as f64;
                // gsplat's `× n_cameras` for the batch, and the weight's inverse when the
                // statistic is unweighted.
                let stats = (densify_on && self.args.synthetic.densify_from_synthetic)
                    .then(|| batch as f32 * self.args.synthetic.stat_factor(plan.synthetic_weight));
                for i in self.draw_synthetic(step, batch) {
                    views.push(ViewTask {
                        source: src,
                        index: i,
                        synthetic: true,
                        scale,
                        stats,
                    });
                }
            }
        }
        for (k, view) in views.iter().enumerate() {
            // The render index: 0 for the real view, 1 + k for the batch's k-th.
            let render = (k + 1 - real_views) as u64;
            self.add_view(*view, &settings, render);
        }
        let results = self
            .device
            .end_views(&mut self.state, &views, &settings)
            .unwrap_or_else(|e| device_failed(e));
        let lr = self
            .args
            .learning_rates
            .means_at(step, self.args.steps, self.scene_scale);
        self.device
            .adam_step(
                &mut self.state,
                &self.args.learning_rates,
                lr,
                self.args.adam.is_dense(),
            )
            .unwrap_or_else(|e| device_failed(e));
        let f = InFlight {
            report: StepReport {
                step,
                ..Default::default()
            },
            views,
            settings: settings.clone(),
            real_views,
            real_weight: plan.real_weight,
            synthetic_weight: plan.synthetic_weight,
        };
        match results {
            Some(r) => self.finished.push_back(f.complete(&r)),
            None => self.in_flight.push_back(f),
        }
        let refine = self.post_update(step, &settings);
        self.step += 1;
        let gaussians = self.device.gaussians(&self.state);
        // This step is the newest: the last in flight, or the last resolved.
        let rep = match self.in_flight.back_mut() {
            Some(f) => &mut f.report,
            None => self
                .finished
                .back_mut()
                .expect("the step just recorded is in flight or resolved"),
        };
        rep.refine = refine;
        rep.gaussians = gaussians;
    }

    /// Staged's opacity reset at its switch, or Dual's at its switch-off, when asked for
    /// (clears the moments and the densification statistics too).
    fn reset_at_switch(&mut self, plan: &crate::schedule::StepPlan) {
        if plan.switch {
            if let Schedule::Staged {
                reset_at_switch: true,
                ..
            }
            | Schedule::Dual {
                reset_at_off: true, ..
            } = self.args.schedule
            {
                // The reset changes the state behind the steps in flight: they resolve first.
                self.resolve(0);
                self.device
                    .reset_for_switch(&mut self.state, 0.1)
                    .unwrap_or_else(|e| device_failed(e));
            }
        }
    }

    /// `b` synthetic views of the usable pool, drawn without replacement from a stream keyed
    /// by the step (partial Fisher–Yates on a copy).
    fn draw_synthetic(&self, step: u64, b: usize) -> Vec<usize> {
        let mut ids = self.usable_synth.clone();
        let mut rng = Rng::stream(self.args.seed ^ 0x5F17, step);
        for k in 0..b {
            let j = k + rng.below((ids.len() - k) as u64) as usize;
            ids.swap(k, j);
        }
        ids.truncate(b);
        ids
    }

    /// Densification and opacity resets after the step's update, on the device that holds
    /// the state ([`crate::device::TrainingDevice::post_update`]).
    fn post_update(&mut self, step: u64, settings: &RenderSettings) -> densify::RefineReport {
        if !densify::acts_at(step, &self.dsched, &self.args.densify) {
            return Default::default();
        }
        // The refinement reads the statistics of every step before it.
        self.resolve(0);
        // For a `KeepVisible` reset: each Gaussian's visibility in the real views.
        let cameras: Vec<&Camera> = (0..self.real.len()).map(|i| self.real.camera(i)).collect();
        let r = densify::gpu::Refinement {
            step,
            sched: &self.dsched,
            args: &self.args.densify,
            extents: Extents {
                scene: self.scene_scale,
                prune: self.prune_extent,
            },
            seed: self.args.seed ^ 0xDE45,
            views: densify::VisibilityViews {
                cameras: &cameras,
                antialiased: settings.antialiased,
                near: settings.near,
            },
        };
        self.device
            .post_update(&mut self.state, &r)
            .unwrap_or_else(|e| device_failed(e))
    }
}

/// Held-out evaluation of one set of Gaussians: the mean over views of
/// [`augsplat_metrics::measure::Measurement`] (LPIPS and the average error
/// `(MSE·√(1−SSIM)·LPIPS)^⅓` when a model is given), the definition `Evaluate` uses too, so a
/// curve and an evaluation agree.
pub type Evaluation = augsplat_metrics::measure::Measurement;

/// Error of an evaluation (a metric rejected an image).
#[derive(Debug, thiserror::Error)]
#[error("evaluating view {view}: {source}")]
pub struct EvalError {
    /// The view's name.
    pub view: String,
    /// The metric's error.
    #[source]
    pub source: augsplat_metrics::MetricsError,
}

/// Renders every view (colour clamped to [0, 1], as gsplat's evaluation), measures it with
/// [`augsplat_metrics::measure::measure`] and averages over views
/// ([`augsplat_metrics::measure::mean`]). A view rendered exactly has an infinite PSNR (the
/// one PSNR convention, see `augsplat_metrics::measure`), and so has the mean. No views: all
/// zeros.
pub fn evaluate(
    g: &Gaussians,
    views: &[RealView],
    settings: &RenderSettings,
    lpips: Option<&augsplat_metrics::lpips::Lpips>,
) -> Result<Evaluation, EvalError> {
    evaluate_with(views, lpips, &mut |cam| crate::render(g, cam, settings).rgb)
}

/// [`evaluate`] of the colour images `render` gives for each view's camera.
fn evaluate_with(
    views: &[RealView],
    lpips: Option<&augsplat_metrics::lpips::Lpips>,
    render: &mut dyn FnMut(&Camera) -> Vec<f32>,
) -> Result<Evaluation, EvalError> {
    use augsplat_core::ImageF32;
    use augsplat_metrics::measure;
    let mut ms = Vec::with_capacity(views.len());
    for v in views {
        let rgb = render(&v.camera);
        let (w, h) = (v.camera.width, v.camera.height);
        let pred = ImageF32::from_vec(w, h, 3, rgb.iter().map(|x| x.clamp(0.0, 1.0)).collect());
        let gt = ImageF32::from_vec(w, h, 3, v.image.clone());
        ms.push(
            measure::measure(&pred, &gt, lpips).map_err(|source| EvalError {
                view: v.name.clone(),
                source,
            })?,
        );
    }
    Ok(measure::mean(&ms).unwrap_or_default())
}
