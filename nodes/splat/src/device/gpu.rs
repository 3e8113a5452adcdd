//! The GPU device: the WGSL kernels through one shared [`GpuContext`], with the training state
//! kept in GPU buffers between steps ([`crate::gpu::GpuTrainer`]).

use super::{DeviceModel, Frame, SplatDevice, StepViews, TrainState, TrainingDevice, ViewTask};
use crate::adam::{GpuStepConst, LearningRates};
use crate::densify::{gpu::Refinement, RefineReport};
use crate::gpu::{
    backward_gpu, render_scene, AdapterSummary, GpuContext, GpuError, GpuScene, GpuTarget,
    GpuTrainer, PendingView, ReadTicket, ViewLoss, ViewResult,
};
use crate::{Gaussians, Gradients, RenderSettings};
use augsplat_core::Camera;
use std::collections::{hash_map::Entry, HashMap, VecDeque};
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
        Box::new(GpuTraining::new(self.0.clone()))
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

/// The pixels of views a submission gathers before it goes to the device: a step's small
/// synthetic views (a batch of 20 at 1/8 of bonsai's 800×533 is 133k pixels) go in one
/// submission with the step's clears and the last step's Adam update, while a view this
/// large or larger is submitted at once, so that the device starts on it while the host
/// records the next.
pub(crate) const SUBMIT_PIXELS: u64 = 1 << 18;

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
    /// The most pairs of any view of each size (width, height) at its last pass: a view's
    /// first pass is sized from them, so that it need not wait for its own count (a pass
    /// that outgrows them runs again, counted first, with the same results).
    pairs_by_size: HashMap<(u32, u32), u32>,
    /// Steps whose views ran again from a pass that outgrew its slots.
    overflows: u64,
    /// The step's views whose loss and counts are still on the device.
    pending: Vec<PendingView>,
    /// The steps whose results are on their way back, oldest first.
    in_flight: VecDeque<InFlightStep>,
    /// The pixels of the views kept for the next submission ([`SUBMIT_PIXELS`]).
    kept_pixels: u64,
    /// A bound on every Gaussian's view count in the GPU's statistics: the largest count
    /// uploaded, plus the views added with the statistic since.
    count_bound: u64,
}

impl GpuTraining {
    /// A training run's GPU half with nothing on the device yet.
    fn new(ctx: Arc<GpuContext>) -> GpuTraining {
        GpuTraining {
            ctx,
            state: None,
            ahead: false,
            targets: HashMap::new(),
            sh_active: 0,
            count_bound: 0,
            tile_pairs: HashMap::new(),
            pairs_by_size: HashMap::new(),
            overflows: 0,
            pending: Vec::new(),
            in_flight: VecDeque::new(),
            kept_pixels: 0,
        }
    }

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

    /// Records one view on the uploaded state with `slots` pair slots (counted first when
    /// `None`).
    fn record_view(
        &mut self,
        view: ViewTask<'_>,
        s: &RenderSettings,
        slots: Option<u32>,
    ) -> Result<PendingView, GpuError> {
        let ctx = self.ctx.clone();
        let (src, i) = (view.source, view.index);
        let key = (view.synthetic, i);
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
        let state = self.state.as_ref().ok_or_else(|| {
            GpuError::Invalid("a view was added before the state was uploaded".into())
        })?;
        let out = state.add_view(
            &ctx,
            src.camera(i),
            s,
            loss,
            view.stats,
            self.sh_active,
            slots,
        );
        // Submitted once enough is kept: the next view reuses the buffers this one let go
        // (while encoders are kept, the pool waits: `GpuContext::reclaim`).
        let cam = src.camera(i);
        self.kept_pixels += u64::from(cam.width) * u64::from(cam.height);
        if self.kept_pixels >= SUBMIT_PIXELS {
            self.kept_pixels = 0;
            ctx.flush()?;
        }
        ctx.reclaim();
        out
    }

    /// An error unless every step is resolved: the state may lack a step's update until the
    /// trainer resolves it ([`TrainingDevice::resolve`]).
    fn settled(&self) -> Result<(), GpuError> {
        match self.in_flight.len() {
            0 => Ok(()),
            k => Err(GpuError::Invalid(format!(
                "{k} training steps are still in flight: resolve them first"
            ))),
        }
    }

    /// Keeps each view's pair counts for its next pass (and its size's largest); the index
    /// of the first view whose pass outgrew its slots.
    fn note_counts(
        &mut self,
        views: &[ViewTask<'_>],
        results: &[ViewResult],
    ) -> Result<Option<usize>, GpuError> {
        let mut overflowed = None;
        for (k, r) in results.iter().enumerate() {
            let v = views.get(k).ok_or_else(|| {
                GpuError::Invalid(format!("{} views added, {} given", k + 1, views.len()))
            })?;
            self.tile_pairs.insert((v.synthetic, v.index), r.tile_pairs);
            self.note_size(v.source.camera(v.index), r.tile_pairs);
            if r.overflowed && overflowed.is_none() {
                overflowed = Some(k);
            }
        }
        Ok(overflowed)
    }

    /// Raises the most pairs seen in a pass of a view of `cam`'s size to `tile_pairs`.
    fn note_size(&mut self, cam: &Camera, tile_pairs: u32) {
        let largest = self
            .pairs_by_size
            .entry((cam.width, cam.height))
            .or_default();
        *largest = (*largest).max(tile_pairs);
    }

    /// Runs `views` in order, each pass counted first (so none outgrows its slots), and waits
    /// for their results.
    fn run_counted(
        &mut self,
        st: &mut TrainState,
        views: &[ViewTask<'_>],
        s: &RenderSettings,
    ) -> Result<Vec<(f64, u64)>, GpuError> {
        let ctx = self.ctx.clone();
        let mut pending = Vec::with_capacity(views.len());
        for v in views {
            pending.push(self.record_view(*v, s, None)?);
        }
        let results = self.state(st)?.finish(&ctx, &pending)?;
        self.kept_pixels = 0;
        drop(pending);
        ctx.reclaim();
        if let Some(k) = self.note_counts(views, &results)? {
            return Err(GpuError::Invalid(format!(
                "view {k} of a step run again outgrew the slots it counted"
            )));
        }
        Ok(results.iter().map(|r| (r.loss, r.pairs)).collect())
    }

    /// Records a step's update again, with the constants it was first recorded with.
    fn replay_update(
        &mut self,
        st: &mut TrainState,
        update: Option<([GpuStepConst; 5], bool)>,
    ) -> Result<(), GpuError> {
        if let Some((consts, dense)) = update {
            let ctx = self.ctx.clone();
            self.state(st)?.adam_step(&ctx, &consts, dense)?;
        }
        Ok(())
    }
}

/// A step whose views' results are on their way back ([`TrainingDevice::resolve`]).
struct InFlightStep {
    /// The views, as recorded.
    views: Vec<PendingView>,
    /// Their losses' and counts' read-back.
    ticket: ReadTicket,
    /// The step's active SH width.
    sh_active: usize,
    /// The step's update once recorded: Adam's constants and whether it is dense.
    adam: Option<([GpuStepConst; 5], bool)>,
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
    ) -> Result<(), GpuError> {
        self.state(st)?;
        if view.stats.is_some() {
            self.count_bound += 1;
        }
        // Sized from the view's last pass, or at its first from the largest pass of a view of
        // its size: no wait for its pair count (the first view of a size counts first).
        let key = (view.synthetic, view.index);
        let cam = view.source.camera(view.index);
        let slots = self
            .tile_pairs
            .get(&key)
            .or_else(|| self.pairs_by_size.get(&(cam.width, cam.height)))
            .map(|&c| pair_slots(c));
        let pending = self.record_view(view, s, slots)?;
        if slots.is_none() {
            // Counted first: the next views of its size start from its count.
            self.note_size(cam, pending.slots);
        }
        self.pending.push(pending);
        Ok(())
    }

    fn end_views(
        &mut self,
        st: &mut TrainState,
        views: &[ViewTask<'_>],
        _s: &RenderSettings,
    ) -> Result<Option<Vec<(f64, u64)>>, GpuError> {
        let pending = std::mem::take(&mut self.pending);
        if pending.len() != views.len() {
            return Err(GpuError::Invalid(format!(
                "{} views added, {} given",
                pending.len(),
                views.len()
            )));
        }
        // Submitted with the step's last views, collected by `resolve` (a step later in a
        // training loop, while the device runs the next step).
        let ctx = self.ctx.clone();
        let ticket = self.state(st)?.read_later(&ctx, &pending)?;
        self.kept_pixels = 0;
        // Everything recorded so far is submitted: the buffers the step let go are free
        // (those its results sit in go when it is resolved).
        ctx.reclaim();
        self.in_flight.push_back(InFlightStep {
            views: pending,
            ticket,
            sh_active: self.sh_active,
            adam: None,
        });
        Ok(None)
    }

    fn in_flight(&self) -> usize {
        self.in_flight.len()
    }

    fn resolve(
        &mut self,
        st: &mut TrainState,
        steps: &[StepViews<'_>],
        keep: usize,
    ) -> Result<Vec<Vec<(f64, u64)>>, GpuError> {
        if steps.len() != self.in_flight.len() {
            return Err(GpuError::Invalid(format!(
                "{} steps in flight, {} given",
                self.in_flight.len(),
                steps.len()
            )));
        }
        let ctx = self.ctx.clone();
        let mut out: Vec<Vec<(f64, u64)>> = Vec::with_capacity(steps.len());
        while self.in_flight.len() > keep {
            let Some(step) = self.in_flight.pop_front() else {
                break;
            };
            let at = steps[out.len()];
            let words = step.ticket.wait(&ctx)?;
            let results = GpuTrainer::results(ctx.adapter(), &step.views, &words)?;
            drop(step.views);
            ctx.reclaim();
            let overflowed = self.note_counts(at.views, &results)?;
            let kept = overflowed.unwrap_or(results.len());
            let mut done: Vec<(f64, u64)> =
                results[..kept].iter().map(|r| (r.loss, r.pairs)).collect();
            let Some(k) = overflowed else {
                out.push(done);
                continue;
            };
            // The views from the first that outgrew its slots added nothing, and the flag
            // kept every later step's clears, sums and updates from running: this step runs
            // again from that view, each pass counted first, then every later step whole.
            self.overflows += 1;
            self.state(st)?.clear_overflow(&ctx)?;
            self.sh_active = step.sh_active;
            done.extend(self.run_counted(st, &at.views[k..], at.settings)?);
            self.replay_update(st, step.adam)?;
            out.push(done);
            for later in std::mem::take(&mut self.in_flight) {
                let at = steps[out.len()];
                drop(later.ticket);
                drop(later.views);
                self.sh_active = later.sh_active;
                self.state(st)?.begin_step(&ctx)?;
                let done = self.run_counted(st, at.views, at.settings)?;
                self.replay_update(st, later.adam)?;
                out.push(done);
            }
        }
        Ok(out)
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
        if let Some(step) = self.in_flight.back_mut() {
            if step.adam.replace((consts, dense)).is_some() {
                return Err(GpuError::Invalid(
                    "two updates recorded for one step".into(),
                ));
            }
        }
        self.ahead = true;
        Ok(())
    }

    fn sync(&mut self, st: &mut TrainState) -> Result<(), GpuError> {
        self.settled()?;
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
        self.pending.clear();
        self.in_flight.clear();
    }

    fn post_update(
        &mut self,
        st: &mut TrainState,
        r: &Refinement<'_>,
    ) -> Result<RefineReport, GpuError> {
        self.settled()?;
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
            // A set wider than one binding: on the host.
            None => {
                self.release(st)?;
                Ok(super::refine_on_host(st, r))
            }
        }
    }

    fn reset_for_switch(&mut self, st: &mut TrainState, value: f64) -> Result<(), GpuError> {
        self.settled()?;
        let Some(state) = &self.state else {
            super::reset_for_switch_on_host(st, value);
            return Ok(());
        };
        state.reset_for_switch(&self.ctx, value)?;
        // The step counters live on the host; its moments and statistics are stale until the
        // next sync, which brings the device's back.
        st.adam.clear();
        st.densifier.clear();
        self.count_bound = 0;
        self.ahead = true;
        Ok(())
    }

    fn gaussians(&self, st: &TrainState) -> usize {
        self.state.as_ref().map_or(st.g.len(), GpuTrainer::len)
    }

    fn render(
        &mut self,
        st: &mut TrainState,
        cam: &Camera,
        s: &RenderSettings,
    ) -> Result<Frame, GpuError> {
        self.settled()?;
        let ctx = self.ctx.clone();
        let state = self.state(st)?;
        let f = render_scene(&ctx, state.scene(), cam, s)?;
        Ok(Frame {
            width: f.width,
            height: f.height,
            rgb: f.rgb,
            alpha: f.alpha,
            depth: f.depth,
            stats: f.stats,
        })
    }
}

#[cfg(test)]
mod tests {
    //! Views sized too small run again from the first that outgrew its slots: the same
    //! results and the same bits in the step's sums as views counted first — also when the
    //! step is resolved a step late, behind a step recorded on the flagged state. Skips
    //! without an adapter (fails under `CI=true`).

    use super::*;
    use crate::adam::Adam;
    use crate::densify::Densifier;
    use crate::train::{RealImages, RealLoss, RealView};

    /// A context, or `None` when the test skips.
    fn context(test: &str) -> Option<Arc<GpuContext>> {
        match GpuContext::new() {
            Ok(c) => Some(Arc::new(c)),
            Err(e @ GpuError::NoAdapter { .. }) => {
                augsplat_testkit::skip(test, &e.to_string());
                None
            }
            Err(e) => panic!("{test}: {e}"),
        }
    }

    /// Three 64×48 views of a striped target, side by side.
    fn photos() -> RealImages {
        let views: Vec<RealView> = (0..3)
            .map(|k| {
                let x = 0.1 * k as f64;
                RealView {
                    name: format!("view {k}"),
                    camera: augsplat_testkit::cameras::square_pixels(
                        64,
                        48,
                        [
                            [1.0, 0.0, 0.0, x],
                            [0.0, 1.0, 0.0, 0.0],
                            [0.0, 0.0, 1.0, 4.0],
                            [0.0, 0.0, 0.0, 1.0],
                        ],
                    ),
                    image: (0..64 * 48 * 3)
                        .map(|p| ((p + k) % 13) as f32 / 12.0)
                        .collect(),
                }
            })
            .collect();
        RealImages {
            views,
            loss: RealLoss::default(),
        }
    }

    /// A fresh training state of `g`.
    fn fresh(g: &Gaussians) -> TrainState {
        TrainState {
            adam: Adam::new(g.len(), g.coeffs()),
            densifier: Densifier::new(g.len()),
            g: g.clone(),
        }
    }

    /// A GPU training half whose views' passes are sized from `estimates` (None: counted
    /// first).
    fn training(ctx: &Arc<GpuContext>, estimates: [Option<u32>; 3]) -> GpuTraining {
        let mut t = GpuTraining::new(ctx.clone());
        for (k, e) in estimates.iter().enumerate() {
            if let Some(c) = e {
                t.tile_pairs.insert((false, k), *c);
            }
        }
        t
    }

    /// Records one step of `views` with its update (which reads the step's sums and leaves
    /// them as they are).
    fn record(t: &mut GpuTraining, st: &mut TrainState, views: &[ViewTask<'_>]) {
        let s = RenderSettings::default();
        t.begin_step(st, 12).unwrap();
        for v in views {
            t.add_view(st, *v, &s).unwrap();
        }
        assert_eq!(t.end_views(st, views, &s).unwrap(), None);
        t.adam_step(st, &LearningRates::default(), 1.6e-4, false)
            .unwrap();
    }

    #[test]
    fn views_that_outgrew_their_slots_run_again_in_order() {
        let test = "views_that_outgrew_their_slots_run_again_in_order";
        let Some(ctx) = context(test) else { return };
        let real = photos();
        let g = Gaussians::random_cloud(1500, 8.0 / 64.0, 9);
        let n = g.len();
        let s = RenderSettings::default();
        let tasks: Vec<ViewTask<'_>> = (0..3)
            .map(|index| ViewTask {
                source: &real,
                index,
                synthetic: false,
                scale: 1.0,
                stats: Some(1.0),
            })
            .collect();
        let run = |estimates: [Option<u32>; 3]| {
            let mut t = training(&ctx, estimates);
            let mut st = fresh(&g);
            record(&mut t, &mut st, &tasks);
            let step = StepViews {
                views: &tasks,
                settings: &s,
            };
            let results = t.resolve(&mut st, &[step], 0).unwrap().remove(0);
            let state = t.state.as_ref().unwrap();
            let sums = [
                ctx.read_words(&state.acc_grads, crate::gpu::PARAM_GRAD_STRIDE * n),
                ctx.read_words(&state.grad2d, n),
                ctx.read_words(&state.count, n),
            ]
            .map(Result::unwrap);
            (results, sums, t.overflows, t.tile_pairs.clone())
        };
        let (counted, counted_sums, none, pairs) = run([None; 3]);
        assert_eq!(none, 0);
        let least = (0..3).map(|k| pairs[&(false, k)]).min().unwrap();
        assert!(
            least > 1100,
            "every view outgrows the smallest slots: {pairs:?}"
        );
        // View 0 sized well, views 1 and 2 far too small; then all too small.
        for estimates in [[Some(10 * least), Some(0), Some(0)], [Some(0); 3]] {
            let (results, sums, overflows, _) = run(estimates);
            assert_eq!(overflows, 1, "{estimates:?}");
            assert_eq!(results, counted, "{estimates:?}");
            assert!(
                sums == counted_sums,
                "{estimates:?}: the step's sums differ"
            );
        }
    }

    #[test]
    fn a_step_that_outgrew_its_slots_runs_again_with_the_step_recorded_behind_it() {
        let test = "a_step_that_outgrew_its_slots_runs_again_with_the_step_recorded_behind_it";
        let Some(ctx) = context(test) else { return };
        let real = photos();
        let g = Gaussians::random_cloud(1500, 8.0 / 64.0, 9);
        let s = RenderSettings::default();
        let task = |index| ViewTask {
            source: &real,
            index,
            synthetic: false,
            scale: 1.0,
            stats: Some(1.0),
        };
        let first = [task(0), task(1), task(2)];
        let second = [task(2), task(0)];
        let steps = [
            StepViews {
                views: &first,
                settings: &s,
            },
            StepViews {
                views: &second,
                settings: &s,
            },
        ];
        // Two steps, each resolved before the next is recorded, every pass counted first.
        let mut t = training(&ctx, [None; 3]);
        let mut want = fresh(&g);
        record(&mut t, &mut want, &first);
        let mut want_results = t.resolve(&mut want, &steps[..1], 0).unwrap();
        record(&mut t, &mut want, &second);
        want_results.extend(t.resolve(&mut want, &steps[1..], 0).unwrap());
        t.sync(&mut want).unwrap();
        assert_eq!(t.overflows, 0);
        let before = ctx.draining_waits();
        // The same two steps, the second recorded before the first is resolved, with view
        // 1's pass far too small: the first step's views from view 1 on and its update, and
        // the whole second step, ran on the flagged state and changed nothing.
        let mut t = training(&ctx, [Some(100_000), Some(0), Some(100_000)]);
        let mut got = fresh(&g);
        record(&mut t, &mut got, &first);
        record(&mut t, &mut got, &second);
        assert_eq!(t.in_flight(), 2);
        assert!(
            t.sync(&mut got).is_err(),
            "the state is not read while steps are in flight"
        );
        let waits = ctx.host_waits();
        let results = t.resolve(&mut got, &steps, 1).unwrap();
        assert!(ctx.host_waits() > waits);
        assert_eq!(t.overflows, 1);
        assert_eq!(t.in_flight(), 0, "the step behind ran again too");
        assert_eq!(results, want_results);
        t.sync(&mut got).unwrap();
        assert!(got.g == want.g, "the Gaussians differ");
        assert!(got.adam == want.adam, "Adam's moments differ");
        assert_eq!(got.densifier.count, want.densifier.count);
        assert_eq!(got.densifier.grad2d, want.densifier.grad2d);
        assert!(ctx.draining_waits() > before);
        // Without an overflow the first step resolves while the second is queued behind
        // it: that wait leaves the device busy.
        let mut t = training(&ctx, [Some(100_000); 3]);
        let mut lagged = fresh(&g);
        record(&mut t, &mut lagged, &first);
        record(&mut t, &mut lagged, &second);
        let draining = ctx.draining_waits();
        let waits = ctx.host_waits();
        let mut results = t.resolve(&mut lagged, &steps, 1).unwrap();
        assert_eq!(
            (ctx.host_waits() - waits, ctx.draining_waits() - draining),
            (1, 0)
        );
        assert_eq!(t.in_flight(), 1);
        results.extend(t.resolve(&mut lagged, &steps[1..], 0).unwrap());
        assert_eq!(results, want_results);
        t.sync(&mut lagged).unwrap();
        assert!(lagged.g == want.g, "the Gaussians differ");
        assert!(lagged.adam == want.adam, "Adam's moments differ");
    }

    /// A view with a tile past the adapter's loop cap (lavapipe: 65,535 iterations an
    /// invocation) fails the step with an error naming the limit, where its loss would
    /// otherwise have come from a tile cut short; on an adapter without a cap it trains.
    #[test]
    fn a_view_with_a_tile_past_the_loop_cap_fails_its_step() {
        let test = "a_view_with_a_tile_past_the_loop_cap_fails_its_step";
        let Some(ctx) = context(test) else { return };
        let cap = crate::forward::gpu::tile_pair_cap(ctx.adapter());
        // One 16×16 view (one tile) of 70,000 faint Gaussians, nearly all binned into it.
        let camera = augsplat_testkit::cameras::facing(16, 16, 4.0);
        let mut g = Gaussians::random_cloud(70_000, 4.0 / camera.fx, 7);
        let scale = (2.0 * 4.0 / camera.fx as f32).ln();
        for (l, s) in g.opacity_logits.iter_mut().zip(g.log_scales.iter_mut()) {
            *l = -5.3;
            *s = [scale + 0.3, scale, scale - 0.3];
        }
        let real = RealImages {
            views: vec![RealView {
                name: "one tile".into(),
                camera,
                image: vec![0.5; 16 * 16 * 3],
            }],
            loss: RealLoss::default(),
        };
        let task = ViewTask {
            source: &real,
            index: 0,
            synthetic: false,
            scale: 1.0,
            stats: Some(1.0),
        };
        let s = RenderSettings::default();
        let mut t = GpuTraining::new(ctx.clone());
        let mut st = fresh(&g);
        let mut step = || -> Result<Vec<(f64, u64)>, GpuError> {
            t.begin_step(&mut st, 12)?;
            t.add_view(&mut st, task, &s)?;
            t.end_views(&mut st, &[task], &s)?;
            let views = [task];
            let step = StepViews {
                views: &views,
                settings: &s,
            };
            Ok(t.resolve(&mut st, &[step], 0)?.remove(0))
        };
        match (cap, step()) {
            (0, Ok(results)) => eprintln!("{test}: no loop cap; the step trained: {results:?}"),
            (0, Err(e)) => panic!("{test}: {e}"),
            (cap, Ok(results)) => panic!("{test}: a tile past {cap} pairs trained: {results:?}"),
            (cap, Err(e)) => {
                let msg = e.to_string();
                assert!(
                    msg.contains(&cap.to_string()) && msg.contains("backend: Cpu"),
                    "{msg}"
                );
            }
        }
    }
}
