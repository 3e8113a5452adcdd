//! The trainer on the GPU: moving the state there and back, and the GPU's step (see
//! [`crate::gpu`]'s training state).

use super::{GpuTargets, StepReport, Trainer};
use crate::supervision::Supervision;

impl Trainer<'_> {
    /// Trains on `gpu` from now on: the Gaussians, Adam's moments and the densification
    /// statistics move to the GPU and stay there between steps (see
    /// [`crate::gpu`]); densification, opacity resets, evaluations and checkpoints bring them
    /// back to the host. A GPU failure in a later step ends the training with the device's
    /// message (a panic the engine reports as the node's failure).
    pub fn use_gpu(&mut self, gpu: std::sync::Arc<crate::gpu::GpuContext>) {
        self.sync_from_gpu();
        self.gpu_state = None;
        self.gpu_targets.clear();
        self.gpu = Some(gpu);
    }

    /// Copies the GPU's training state into `g`, `adam` and `densifier` if it is newer.
    pub(super) fn sync_from_gpu(&mut self) {
        if !self.gpu_ahead {
            return;
        }
        if let (Some(gpu), Some(st)) = (&self.gpu, &self.gpu_state) {
            st.download(gpu, &mut self.g, &mut self.adam, &mut self.densifier)
                .unwrap_or_else(|e| panic!("backend: Gpu: {e}"));
        }
        self.gpu_ahead = false;
    }

    /// Brings the state back from the GPU and drops the GPU's copy: the host is about to
    /// change it (the next step uploads it again).
    pub(super) fn take_back_from_gpu(&mut self) {
        self.sync_from_gpu();
        self.gpu_state = None;
    }

    /// [`Trainer::step`] on the GPU: the same views, losses, sums and Adam constants, with the
    /// state kept there ([`crate::gpu::GpuTrainer`]).
    pub(super) fn step_gpu(&mut self) -> StepReport {
        let step = self.step;
        let plan = self.args.schedule.plan(step);
        self.reset_at_switch(&plan);
        let settings = self.args.render_settings(step);
        let Some(gpu) = self.gpu.clone() else {
            unreachable!("step_gpu runs only with a GPU");
        };
        let fail = |e: crate::gpu::GpuError| -> ! { panic!("backend: Gpu: {e}") };
        if self.gpu_state.is_none() {
            let st = crate::gpu::GpuTrainer::upload(&gpu, &self.g, &self.adam, &self.densifier)
                .unwrap_or_else(|e| fail(e));
            self.gpu_state = Some(st);
        }
        let sh_active = 3 * crate::gaussians::sh_coeffs(settings.sh_degree.min(self.g.sh_degree));
        let mut rep = StepReport {
            step,
            ..Default::default()
        };
        let densify_on = self.args.densify.enabled && step < self.dsched.stop;
        let view = |st: &crate::gpu::GpuTrainer,
                    targets: &mut GpuTargets,
                    synthetic: bool,
                    src: &dyn Supervision,
                    i: usize,
                    scale: f64,
                    stats: Option<f32>| {
            let mut host = |rgb: &[f32], grad: &mut [f32]| src.loss(i, rgb, scale as f32, grad);
            let loss = match src.gpu_loss(i) {
                Some(v) => {
                    let target = match targets.entry((synthetic, i)) {
                        std::collections::hash_map::Entry::Occupied(e) => e.into_mut(),
                        std::collections::hash_map::Entry::Vacant(e) => e.insert(
                            crate::gpu::GpuTarget::upload(&gpu, v.target, v.weights)
                                .unwrap_or_else(|e| fail(e)),
                        ),
                    };
                    crate::gpu::ViewLoss::Gpu {
                        target,
                        loss: v.loss,
                        scale: scale as f32,
                    }
                }
                None => crate::gpu::ViewLoss::Host(&mut host),
            };
            st.add_view(&gpu, src.camera(i), &settings, loss, stats, sh_active)
                .unwrap_or_else(|e| fail(e))
        };
        if let Some(st) = &self.gpu_state {
            st.begin_step(&gpu).unwrap_or_else(|e| fail(e));
        }
        if plan.real_weight > 0.0 {
            if let Some(i) = self.next_real() {
                if let Some(st) = &self.gpu_state {
                    let stats =
                        densify_on.then(|| self.args.synthetic.stat_factor(plan.real_weight));
                    let (l, pairs) = view(
                        st,
                        &mut self.gpu_targets,
                        false,
                        self.real,
                        i,
                        plan.real_weight,
                        stats,
                    );
                    rep.real_loss = Some(l);
                    rep.loss += plan.real_weight * l;
                    rep.pairs += pairs;
                }
            }
        }
        if let (true, Some(src)) = (
            plan.synthetic_weight > 0.0 && plan.synthetic_batch > 0,
            self.synthetic,
        ) {
            let b = plan.synthetic_batch.min(self.usable_synth.len());
            if b > 0 {
                let ids = self.draw_synthetic(step, b);
                let scale = plan.synthetic_weight / b as f64;
                let want_stat = densify_on && self.args.synthetic.densify_from_synthetic;
                let mut sum = 0.0;
                if let Some(st) = &self.gpu_state {
                    for &i in &ids {
                        let (l, pairs) = view(
                            st,
                            &mut self.gpu_targets,
                            true,
                            src,
                            i,
                            scale,
                            want_stat.then(|| {
                                b as f32 * self.args.synthetic.stat_factor(plan.synthetic_weight)
                            }),
                        );
                        sum += l;
                        rep.pairs += pairs;
                    }
                }
                rep.synthetic_loss = Some(sum / b as f64);
                rep.loss += plan.synthetic_weight * sum / b as f64;
            }
        }
        let lr = self
            .args
            .learning_rates
            .means_at(step, self.args.steps, self.scene_scale);
        let consts = self
            .adam
            .next_gpu_consts(sh_active, &self.args.learning_rates, lr);
        if let Some(st) = &self.gpu_state {
            st.adam_step(&gpu, &consts, self.args.adam.is_dense())
                .unwrap_or_else(|e| fail(e));
        }
        self.gpu_ahead = true;
        rep.refine = self.post_update(step, &settings);
        self.step += 1;
        rep.gaussians = self.g.len();
        rep
    }
}
