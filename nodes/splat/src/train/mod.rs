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
//! With [`Trainer::use_gpu`] the same step runs on the GPU (`train/gpu.rs`): the state stays
//! there between steps and comes back for densification, resets, evaluations and
//! checkpoints. The arguments live in `train/args.rs`.

use crate::adam::{Adam, ParamGrads};
use crate::densify::{self, Densifier, DensifySchedule, Extents, PruneExtent};
pub use crate::schedule::{dual_lambda, dual_raw_weight, Schedule, StepPlan};
pub use crate::supervision::{RealImages, RealView, Supervision, SynthView, SyntheticImages};
use crate::{Gaussians, Gradients, RenderOutput, RenderSettings};
use augsplat_core::{Camera, Rng};
use rayon::prelude::*;

mod args;
mod gpu;

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

/// The training state.
pub struct Trainer<'a> {
    args: TrainArgs,
    g: Gaussians,
    adam: Adam,
    densifier: Densifier,
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
    d_rgb: Vec<f32>,
    /// The GPU (with `backend: Gpu`), the training state on it, and whether that state is
    /// newer than `g`, `adam` and `densifier` (which then hold the sizes but not the values).
    gpu: Option<std::sync::Arc<crate::gpu::GpuContext>>,
    gpu_state: Option<crate::gpu::GpuTrainer>,
    gpu_ahead: bool,
    /// The views' targets on the GPU, uploaded at their first use.
    gpu_targets: GpuTargets,
}

/// Targets on the GPU by (synthetic?, view index).
pub(super) type GpuTargets = std::collections::HashMap<(bool, usize), crate::gpu::GpuTarget>;

impl<'a> Trainer<'a> {
    /// A trainer starting from `g`. The SH storage of `g` must be `args.sh_degree`. With
    /// `densify.prune_extent: Content`, the prune's extent is measured here from `g` and the
    /// real views' cameras (see [`content_extent`]).
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
            densifier: Densifier::new(n),
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
            d_rgb: Vec::new(),
            gpu: None,
            gpu_state: None,
            gpu_ahead: false,
            gpu_targets: GpuTargets::new(),
            adam,
            g,
            args,
        }
    }

    /// The current Gaussians (brought back from the GPU first when it trains there).
    pub fn gaussians(&mut self) -> &Gaussians {
        self.sync_from_gpu();
        &self.g
    }

    /// The densification statistics gathered since the last refinement: per Gaussian, the
    /// summed norm of its screen-space gradient and the number of renders that saw it
    /// (brought back from the GPU first when it trains there).
    pub fn densify_statistics(&mut self) -> (&[f32], &[u32]) {
        self.sync_from_gpu();
        (&self.densifier.grad2d, &self.densifier.count)
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
        self.sync_from_gpu();
        self.g
    }

    /// Appends everything that the next steps depend on to a checkpoint: the Gaussians, the
    /// optimiser's moments, the densification statistics, the step and the position in the
    /// shuffled view order. (Every other random choice is drawn from a stream keyed by the
    /// step, so nothing else carries over.)
    pub fn write_state(&mut self, w: &mut augsplat_core::state::StateWriter) {
        self.sync_from_gpu();
        w.tag("trainer");
        w.u64(self.step);
        w.u64(self.epoch);
        w.u64(self.real_pos as u64);
        w.usizes(&self.real_order);
        w.f64(self.scene_scale);
        w.f32s(&self.densifier.grad2d);
        w.u32s(&self.densifier.count);
        self.adam.write_state(w);
        self.g.write_state(w);
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
        self.densifier = Densifier { grad2d, count };
        self.adam = adam;
        self.g = g;
        self.gpu_state = None;
        self.gpu_ahead = false;
        Ok(())
    }

    pub(super) fn next_real(&mut self) -> Option<usize> {
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

    /// Renders view `i` of `src`, adds `scale · dL/drgb`, back-propagates. Returns
    /// (unweighted-by-scale loss, the render's gradients, pairs).
    fn render_and_backward(
        &mut self,
        src: &dyn Supervision,
        i: usize,
        scale: f64,
        settings: &RenderSettings,
    ) -> (f64, Gradients, u64) {
        let cam = src.camera(i);
        let out: RenderOutput = crate::render_masked(&self.g, cam, settings, src.mask(i));
        self.d_rgb.clear();
        self.d_rgb.resize(out.rgb.len(), 0.0);
        let l = src.loss(i, &out.rgb, scale as f32, &mut self.d_rgb);
        let gr = crate::backward(&self.g, cam, settings, &out, &self.d_rgb, None, None);
        (l, gr, out.stats.pairs)
    }

    /// Renders view `i` of `src`, adds `scale · dL/drgb`, back-propagates into `acc`.
    /// Returns (unweighted-by-scale loss, pairs).
    fn render_and_add(
        g: &Gaussians,
        src: &dyn Supervision,
        i: usize,
        scale: f64,
        settings: &RenderSettings,
        d_rgb: &mut Vec<f32>,
        acc: &mut ParamGrads,
    ) -> (f64, u64) {
        let cam = src.camera(i);
        let out: RenderOutput = crate::render_masked(g, cam, settings, src.mask(i));
        d_rgb.clear();
        d_rgb.resize(out.rgb.len(), 0.0);
        let l = src.loss(i, &out.rgb, scale as f32, d_rgb);
        crate::backward_add(g, cam, &out, d_rgb, acc);
        (l, out.stats.pairs)
    }

    /// One optimisation step.
    pub fn step(&mut self) -> StepReport {
        if self.gpu.is_some() {
            return self.step_gpu();
        }
        let step = self.step;
        let plan = self.args.schedule.plan(step);
        self.reset_at_switch(&plan);
        let settings = self.args.render_settings(step);
        let n = self.g.len();
        let k3 = self.g.coeffs() * 3;
        let sh_active = 3 * crate::gaussians::sh_coeffs(settings.sh_degree.min(self.g.sh_degree));
        let mut acc: Option<ParamGrads> = None;
        let mut rep = StepReport {
            step,
            ..Default::default()
        };
        let densify_on = self.args.densify.enabled && step < self.dsched.stop;
        if plan.real_weight > 0.0 {
            if let Some(i) = self.next_real() {
                let src = self.real;
                let (l, gr, pairs) = self.render_and_backward(src, i, plan.real_weight, &settings);
                rep.real_loss = Some(l);
                rep.loss += plan.real_weight * l;
                rep.pairs += pairs;
                if densify_on && gr.means2d_abs.len() == n && gr.visible.len() == n {
                    let f = self.args.synthetic.stat_factor(plan.real_weight);
                    self.densifier
                        .accumulate_scaled(&gr.means2d_abs, &gr.visible, f);
                }
                merge_grads(&mut acc, gr, n, k3, sh_active);
            }
        }
        if plan.synthetic_weight > 0.0 && plan.synthetic_batch > 0 {
            if let Some(src) = self.synthetic {
                let pool = &self.usable_synth;
                let b = plan.synthetic_batch.min(pool.len());
                if b > 0 {
                    let ids = self.draw_synthetic(step, b);
                    let scale = plan.synthetic_weight / b as f64;
                    let mut sum = 0.0;
                    let want_stat = densify_on && self.args.synthetic.densify_from_synthetic;
                    for &i in &ids {
                        if want_stat {
                            let (l, gr, pairs) = self.render_and_backward(src, i, scale, &settings);
                            sum += l;
                            rep.pairs += pairs;
                            if want_stat && gr.means2d_abs.len() == n && gr.visible.len() == n {
                                // gsplat's `× n_cameras` for the batch, and the
                                // weight's inverse when the statistic is unweighted.
                                let f = b as f32
                                    * self.args.synthetic.stat_factor(plan.synthetic_weight);
                                self.densifier
                                    .accumulate_scaled(&gr.means2d_abs, &gr.visible, f);
                            }
                            merge_grads(&mut acc, gr, n, k3, sh_active);
                        } else {
                            // No statistic wanted: add straight into the step's sum (the
                            // same values as merging a fresh buffer, without N-sized
                            // buffers per view).
                            let a = acc.get_or_insert_with(|| ParamGrads {
                                sh_active,
                                ..ParamGrads::zeros(n, self.g.coeffs())
                            });
                            let (l, pairs) = Self::render_and_add(
                                &self.g,
                                src,
                                i,
                                scale,
                                &settings,
                                &mut self.d_rgb,
                                a,
                            );
                            sum += l;
                            rep.pairs += pairs;
                        }
                    }
                    rep.synthetic_loss = Some(sum / b as f64);
                    rep.loss += plan.synthetic_weight * sum / b as f64;
                }
            }
        }
        let lr = self
            .args
            .learning_rates
            .means_at(step, self.args.steps, self.scene_scale);
        let mut acc = acc.unwrap_or_else(|| ParamGrads {
            sh_active,
            ..ParamGrads::zeros(n, self.g.coeffs())
        });
        if self.args.adam == crate::adam::AdamUpdates::Dense {
            // The densification statistics were gathered above; Adam now sees every Gaussian.
            acc.visible.fill(true);
        }
        self.adam
            .step(&mut self.g, &acc, &self.args.learning_rates, lr);
        rep.refine = self.post_update(step, &settings);
        self.step += 1;
        rep.gaussians = self.g.len();
        rep
    }

    /// Staged's opacity reset at its switch, or Dual's at its switch-off, when asked for
    /// (clears the moments and the densification statistics too).
    pub(super) fn reset_at_switch(&mut self, plan: &crate::schedule::StepPlan) {
        if plan.switch {
            if let Schedule::Staged {
                reset_at_switch: true,
                ..
            }
            | Schedule::Dual {
                reset_at_off: true, ..
            } = self.args.schedule
            {
                self.take_back_from_gpu();
                densify::reset_opacities(&mut self.g, &mut self.adam, 0.1);
                self.adam.clear();
                self.densifier.clear();
            }
        }
    }

    /// `b` synthetic views of the usable pool, drawn without replacement from a stream keyed
    /// by the step (partial Fisher–Yates on a copy).
    pub(super) fn draw_synthetic(&self, step: u64, b: usize) -> Vec<usize> {
        let mut ids = self.usable_synth.clone();
        let mut rng = Rng::stream(self.args.seed ^ 0x5F17, step);
        for k in 0..b {
            let j = k + rng.below((ids.len() - k) as u64) as usize;
            ids.swap(k, j);
        }
        ids.truncate(b);
        ids
    }

    /// Densification and opacity resets after the step's update (on the host: a GPU state is
    /// brought back first, and uploaded again by the next step).
    pub(super) fn post_update(
        &mut self,
        step: u64,
        settings: &RenderSettings,
    ) -> densify::RefineReport {
        if !densify::acts_at(step, &self.dsched, &self.args.densify) {
            return Default::default();
        }
        self.take_back_from_gpu();
        // For a `KeepVisible` reset: each Gaussian's visibility in the real views.
        let real = self.real;
        let mut visibility = |g: &Gaussians| {
            let cams: Vec<&Camera> = (0..real.len()).map(|i| real.camera(i)).collect();
            densify::peak_alpha_ratios(g, &cams, settings.antialiased, settings.near as f64)
        };
        self.densifier.step_post_update(
            step,
            &self.dsched,
            &self.args.densify,
            &mut self.g,
            &mut self.adam,
            Extents {
                scene: self.scene_scale,
                prune: self.prune_extent,
            },
            self.args.seed ^ 0xDE45,
            &mut visibility,
        )
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
    use augsplat_core::ImageF32;
    use augsplat_metrics::measure;
    let mut ms = Vec::with_capacity(views.len());
    for v in views {
        let out = crate::render(g, &v.camera, settings);
        let (w, h) = (v.camera.width, v.camera.height);
        let pred = ImageF32::from_vec(w, h, 3, out.rgb.iter().map(|x| x.clamp(0.0, 1.0)).collect());
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
