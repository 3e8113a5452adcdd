//! Densification on the GPU (`densify.wgsl`): a refinement step of
//! [`super::Densifier::step_post_update`] run on the training state's buffers, with the CPU's
//! decisions and the CPU's new set.
//!
//! One refinement is two submissions and one wait:
//! 1. `decide` tests every Gaussian against boundaries the host computed with the CPU's own
//!    expressions ([`super::thresholds`]); prefix sums rank the clone and split candidates;
//!    `take` applies the cap (clones first, then splits, in index order), marks what survives
//!    the prune and writes each taken split's parent; prefix sums place the survivors. The
//!    host reads the totals and the parents back (the one wait).
//! 2. The host draws the split children exactly as the CPU does ([`super::split_children`],
//!    the same seeded stream, in the same order, in f64) and prunes them with the CPU's
//!    [`super::PruneRule`]; `compact` writes the survivors and then the clones of every
//!    parameter and moment array into new buffers, the children are copied in after them
//!    (their colours gathered from their parents), and the statistics start at zero.
//!
//! An opacity reset (`Periodic`) clamps the logits on the device (`clamp_logits`) and clears
//! the opacity moments. A `KeepVisible` reset measures each Gaussian's visibility in the
//! training views on the device too (`keep_visible.wgsl`: the projection with unit opacity
//! from each view, then each Gaussian's peak alpha and its clamp, in f32, so within rounding
//! of the host's f64 caps). Sets whose arrays exceed one storage binding refine on the host
//! instead (the device's refinement declines them).

use super::thresholds::{grow_keys, log_scale_key_at_most, ord_key};
use super::{
    split_children, DensifyArgs, DensifySchedule, Extents, OpacityReset, PruneRule, RefineReport,
    SplitChild, SplitParent, VisibilityViews, KEEP_VISIBLE_ALPHA, KEEP_VISIBLE_MAX_OPACITY,
};
use crate::gpu::{f32_words, GpuBuffer, GpuContext, GpuError, GpuScene};
use crate::train::gpu::GpuTrainer;
use augsplat_core::Rng;

/// The largest count bound the grow table is built for; a larger bound refines on the host.
const MAX_TABLE: u64 = 1 << 20;

/// Words per split parent record (`take` in `densify.wgsl`): index, mean, log-scales,
/// quaternion, opacity logit.
const PARENT_WORDS: usize = 12;

/// One call of [`super::Densifier::step_post_update`]'s arguments that the device needs.
#[derive(Clone, Copy, Debug)]
pub struct Refinement<'a> {
    /// The step just taken.
    pub step: u64,
    /// The run's schedule.
    pub sched: &'a DensifySchedule,
    /// The strategy's settings.
    pub args: &'a DensifyArgs,
    /// The lengths scales are compared with.
    pub extents: Extents,
    /// The seed of the split children's stream (drawn per step).
    pub seed: u64,
    /// The views a `KeepVisible` reset measures visibility in.
    pub views: VisibilityViews<'a>,
}

impl Refinement<'_> {
    /// Whether this step grows and prunes (a refinement step).
    pub fn grows(&self) -> bool {
        super::acts_at(self.step, self.sched, self.args)
            && self.step > self.sched.start
            && self.step.is_multiple_of(self.sched.every)
    }

    /// Whether this step resets opacities, and how.
    pub fn reset(&self) -> Option<OpacityReset> {
        (super::acts_at(self.step, self.sched, self.args)
            && self.sched.reset_due(self.step)
            && self.args.reset != OpacityReset::Never)
            .then_some(self.args.reset)
    }
}

/// The compiled densification kernels.
pub(crate) struct Kernels {
    decide: wgpu::ComputePipeline,
    take: wgpu::ComputePipeline,
    compact: wgpu::ComputePipeline,
    gather: wgpu::ComputePipeline,
    clamp_logits: wgpu::ComputePipeline,
    peak_ratio: wgpu::ComputePipeline,
    keep_visible: wgpu::ComputePipeline,
}

impl Kernels {
    pub(crate) fn new(m: crate::gpu::ModuleSetup<'_>) -> Kernels {
        let [decide, take, compact, gather, clamp_logits] = crate::gpu::pipelines(
            m,
            "densify.wgsl",
            include_str!("densify.wgsl"),
            ["decide", "take", "compact", "gather", "clamp_logits"],
        );
        let [peak_ratio, keep_visible] = crate::gpu::pipelines(
            m,
            "keep_visible.wgsl",
            include_str!("keep_visible.wgsl"),
            ["peak_ratio", "keep_visible"],
        );
        Kernels {
            decide,
            take,
            compact,
            gather,
            clamp_logits,
            peak_ratio,
            keep_visible,
        }
    }
}

/// A split child that survives the prune, with what it takes from its parent.
struct Child {
    parent: u32,
    geometry: SplitChild,
    quat: [f32; 4],
    logit: f32,
}

/// What the first submission of a growing refinement found.
struct Decisions {
    /// The buffers the second submission reads: survivors' and clones' positions.
    keep_old: GpuBuffer,
    keep_clone: GpuBuffer,
    kept_old: u32,
    kept_clone: u32,
    cloned: u32,
    split: u32,
    children: Vec<Child>,
}

impl GpuTrainer {
    /// Runs the refinement `r` on the device: grows and prunes when due, then resets
    /// opacities when due. `count_bound` bounds every Gaussian's view count since the
    /// statistics were last cleared. `None` (with the state untouched) when the device cannot
    /// do it: arrays wider than one binding, or too large a bound; the caller then refines
    /// on the host.
    pub(crate) fn refine(
        &mut self,
        ctx: &GpuContext,
        r: &Refinement<'_>,
        count_bound: u64,
    ) -> Result<Option<RefineReport>, GpuError> {
        let mut rep = RefineReport::default();
        let reset = r.reset();
        if !self.binds_whole(ctx, self.len() as u64) {
            return Ok(None);
        }
        let kernels = ctx.kernels_of(Kernels::new)?;
        if r.grows() {
            if count_bound >= MAX_TABLE {
                return Ok(None);
            }
            let Some(d) = self.decide(ctx, &kernels, r, count_bound as u32)? else {
                return Ok(None);
            };
            let n = self.len() as u64;
            let new_n = u64::from(d.kept_old) + u64::from(d.kept_clone) + d.children.len() as u64;
            if !self.binds_whole(ctx, new_n) {
                return Ok(None);
            }
            rep.cloned = d.cloned as usize;
            rep.split = d.split as usize;
            rep.pruned = (n + u64::from(d.cloned) + u64::from(d.split) - new_n) as usize;
            self.rebuild(ctx, &kernels, &d, new_n as u32)?;
        }
        let value = 2.0 * r.args.prune_opacity;
        match reset {
            Some(OpacityReset::Periodic) => self.reset_opacities(ctx, &kernels, value)?,
            Some(OpacityReset::KeepVisible) => {
                self.reset_keep_visible(ctx, &kernels, value, &r.views)?
            }
            Some(OpacityReset::Never) | None => {}
        }
        rep.reset = reset.is_some();
        Ok(Some(rep))
    }

    /// Whether every array of a set of `n` Gaussians (and the split parents' records) fits
    /// one storage binding, and every (Gaussian, word) invocation one dispatch.
    fn binds_whole(&self, ctx: &GpuContext, n: u64) -> bool {
        let widest = (3 * u64::from(self.scene.coeffs)).max(PARENT_WORDS as u64);
        4 * widest * (n + 1) <= ctx.binding_limit() && widest * (n + 1) < u64::from(u32::MAX)
    }

    /// The first submission: decisions, cap, survivors, split parents; one read-back.
    fn decide(
        &self,
        ctx: &GpuContext,
        kr: &Kernels,
        r: &Refinement<'_>,
        count_bound: u32,
    ) -> Result<Option<Decisions>, GpuError> {
        let args = r.args;
        let n = self.scene.n;
        let nn = u64::from(n);
        let table = grow_keys(args.grad_threshold, count_bound);
        let rule = PruneRule::new(args, r.extents.prune, r.sched.large_prune_active(r.step));
        let boundary = |bound: f64| {
            log_scale_key_at_most(bound).ok_or_else(|| {
                GpuError::Invalid(format!("densification scale bound {bound} is not ≥ 0"))
            })
        };
        let clone_key = boundary(args.grow_scale3d * r.extents.scene)?;
        let big_key = boundary(rule.big)?;
        let room = if args.max_gaussians == 0 {
            u32::MAX
        } else {
            args.max_gaussians
                .saturating_sub(n as usize)
                .min(u32::MAX as usize) as u32
        };
        ctx.scoped(|| {
            let rank = |what: &str| ctx.storage(what, 4 * (nn + 1));
            let clone_rank = rank("clone candidates")?;
            let split_rank = rank("split candidates")?;
            let keep_old = rank("survivors")?;
            let keep_clone = rank("surviving clones")?;
            let pruned = ctx.storage("pruned", 4 * nn)?;
            let parents = ctx.storage("split parents", 4 * PARENT_WORDS as u64 * nn)?;
            let overflow = ctx.storage("count overflow", 4)?;
            let grow_table = ctx.storage_init("grow boundaries", &table)?;
            let consts = ctx.uniform(
                "densify constants",
                &[
                    n,
                    table.len() as u32,
                    clone_key,
                    ord_key(rule.thr_logit),
                    big_key,
                    u32::from(rule.large),
                    1,
                    room,
                ],
            );
            let sc = &self.scene;
            let groups = ctx.groups(n.div_ceil(256));
            let mut enc = ctx.encoder();
            ctx.dispatch(
                &mut enc,
                &kr.decide,
                &[
                    (0, &consts),
                    (1, &self.grad2d),
                    (2, &self.count),
                    (3, &sc.scales),
                    (4, &sc.logits),
                    (5, &sc.means),
                    (6, &grow_table),
                    (7, &clone_rank),
                    (8, &split_rank),
                    (9, &pruned),
                    (10, &overflow),
                ],
                groups,
            );
            ctx.record_scan(&mut enc, &clone_rank, n + 1)?;
            ctx.record_scan(&mut enc, &split_rank, n + 1)?;
            ctx.dispatch(
                &mut enc,
                &kr.take,
                &[
                    (0, &consts),
                    (3, &sc.scales),
                    (4, &sc.logits),
                    (5, &sc.means),
                    (7, &clone_rank),
                    (8, &split_rank),
                    (9, &pruned),
                    (11, &sc.quats),
                    (12, &keep_old),
                    (13, &keep_clone),
                    (14, &parents),
                ],
                groups,
            );
            ctx.record_scan(&mut enc, &keep_old, n + 1)?;
            ctx.record_scan(&mut enc, &keep_clone, n + 1)?;
            let words = ctx.read_after(
                enc,
                &[
                    (&clone_rank, nn, 1),
                    (&split_rank, nn, 1),
                    (&keep_old, nn, 1),
                    (&keep_clone, nn, 1),
                    (&overflow, 0, 1),
                    (&parents, 0, PARENT_WORDS * n as usize),
                ],
            )?;
            let word = |k: usize| words[k][0];
            if word(4) != 0 {
                return Err(GpuError::Invalid(format!(
                    "a Gaussian's view count exceeds the trainer's bound {count_bound}"
                )));
            }
            let cloned = word(0).min(room);
            let split = word(1).min(room - cloned);
            let rule = &rule;
            let log_div = (args.split_factor as f32).ln();
            let mut rng = Rng::stream(r.seed, r.step);
            let mut children = Vec::new();
            for rec in words[5].chunks_exact(PARENT_WORDS).take(split as usize) {
                let f = |k: usize| f32::from_bits(rec[k]);
                let parent = SplitParent {
                    mean: [f(1), f(2), f(3)],
                    log_scales: [f(4), f(5), f(6)],
                    quat: [f(7), f(8), f(9), f(10)],
                };
                let logit = f(11);
                for geometry in split_children(&parent, log_div, &mut rng) {
                    if !rule.prunes(logit, &geometry.log_scales, &geometry.mean) {
                        children.push(Child {
                            parent: rec[0],
                            geometry,
                            quat: parent.quat,
                            logit,
                        });
                    }
                }
            }
            Ok(Some(Decisions {
                keep_old,
                keep_clone,
                kept_old: word(2),
                kept_clone: word(3),
                cloned,
                split,
                children,
            }))
        })
    }

    /// The second submission: the new set of `new_n` Gaussians in new buffers (survivors,
    /// clones, children; zero moments for the new ones, zero statistics), no wait.
    fn rebuild(
        &mut self,
        ctx: &GpuContext,
        kr: &Kernels,
        d: &Decisions,
        new_n: u32,
    ) -> Result<(), GpuError> {
        let n = self.scene.n;
        let k3 = 3 * self.scene.coeffs;
        let nn = u64::from(new_n);
        let base = u64::from(d.kept_old + d.kept_clone);
        let kids = d.children.len() as u64;
        ctx.scoped(|| {
            let mut enc = ctx.encoder();
            let compact = |enc: &mut augsplat_render::gpu::Encoder,
                           src: &wgpu::Buffer,
                           what: &str,
                           width: u32,
                           copy_clones: bool|
             -> Result<GpuBuffer, GpuError> {
                let dst = ctx.storage_items(what, 4 * u64::from(width) * nn)?;
                let u = ctx.uniform(
                    "compact constants",
                    &[n, width, d.kept_old, u32::from(copy_clones)],
                );
                ctx.dispatch(
                    enc,
                    &kr.compact,
                    &[
                        (15, &u),
                        (16, src),
                        (17, &dst),
                        (18, &d.keep_old),
                        (19, &d.keep_clone),
                    ],
                    ctx.groups((n * width).div_ceil(256)),
                );
                Ok(dst)
            };
            // A parameter array: the children's values after the clones.
            let param = |enc: &mut augsplat_render::gpu::Encoder,
                         src: &wgpu::Buffer,
                         what: &str,
                         width: u32,
                         values: &dyn Fn(&Child) -> Vec<f32>|
             -> Result<GpuBuffer, GpuError> {
                let dst = compact(enc, src, what, width, true)?;
                if kids > 0 {
                    let words = f32_words(d.children.iter().flat_map(values));
                    let up = ctx.storage_items_init("split children", &words)?;
                    let w = 4 * u64::from(width);
                    enc.copy_buffer_to_buffer(&up, 0, &dst, w * base, w * kids);
                }
                Ok(dst)
            };
            let sc = &self.scene;
            let means = param(&mut enc, &sc.means, "means", 3, &|c| {
                c.geometry.mean.to_vec()
            })?;
            let scales = param(&mut enc, &sc.scales, "log-scales", 3, &|c| {
                c.geometry.log_scales.to_vec()
            })?;
            let quats = param(&mut enc, &sc.quats, "quaternions", 4, &|c| c.quat.to_vec())?;
            let logits = param(&mut enc, &sc.logits, "opacity logits", 1, &|c| {
                vec![c.logit]
            })?;
            let sh = compact(&mut enc, &sc.sh, "SH coefficients", k3, true)?;
            if kids > 0 {
                let from: Vec<u32> = d.children.iter().map(|c| c.parent).collect();
                let rows = ctx.storage_init("split parents' rows", &from)?;
                let u = ctx.uniform("gather constants", &[kids as u32, k3, base as u32, 0]);
                ctx.dispatch(
                    &mut enc,
                    &kr.gather,
                    &[(20, &u), (16, &sc.sh), (17, &sh), (21, &rows)],
                    ctx.groups((kids as u32 * k3).div_ceil(256)),
                );
            }
            let mut moments = Vec::with_capacity(self.moments.len());
            let widths = crate::train::gpu::moment_widths(self.scene.coeffs);
            for ((m, v), width) in self.moments.iter().zip(widths) {
                moments.push((
                    compact(&mut enc, m, "Adam first moments", width, false)?,
                    compact(&mut enc, v, "Adam second moments", width, false)?,
                ));
            }
            ctx.submit_no_wait(enc)?;
            self.acc_grads = ctx.storage_items(
                "step gradients",
                4 * crate::backward::gpu::PARAM_GRAD_STRIDE as u64 * nn,
            )?;
            self.acc_sh = ctx.storage_items("step SH gradients", 4 * u64::from(k3) * nn)?;
            self.acc_visible = ctx.storage_items("step visibility", 4 * nn)?;
            self.grad2d = ctx.storage_items("densification sums", 4 * nn)?;
            self.count = ctx.storage_items("densification counts", 4 * nn)?;
            self.moments = moments;
            self.scene = GpuScene {
                n: new_n,
                coeffs: self.scene.coeffs,
                sh_degree: self.scene.sh_degree,
                means,
                scales,
                quats,
                logits,
                sh,
            };
            Ok(())
        })
    }

    /// The opacity reset of a Staged switch or Dual's switch-off: logits clamped to
    /// `logit(value)`, then every moment and the densification statistics cleared (the
    /// host clears Adam's step counters). Kept for the next submission.
    pub(crate) fn reset_for_switch(&self, ctx: &GpuContext, value: f64) -> Result<(), GpuError> {
        let kernels = ctx.kernels_of(Kernels::new)?;
        ctx.scoped(|| {
            let mut enc = ctx.encoder();
            self.record_clamp(ctx, &kernels, &mut enc, value);
            for (m, v) in &self.moments {
                enc.clear_buffer(m, 0, None);
                enc.clear_buffer(v, 0, None);
            }
            enc.clear_buffer(&self.grad2d, 0, None);
            enc.clear_buffer(&self.count, 0, None);
            ctx.defer(enc)
        })
    }

    /// `KeepVisible` opacity reset ([`super::reset_opacities_keep_visible`] with
    /// [`super::peak_alpha_ratios`], in f32): each Gaussian projected with unit opacity
    /// from every view of `views`, its largest alpha per unit opacity kept, its logit clamped
    /// to that of `max(value, floor)` ([`super::keep_visible_floor`]); the opacity moments
    /// cleared. Kept for the next submission, without a wait.
    fn reset_keep_visible(
        &self,
        ctx: &GpuContext,
        kr: &Kernels,
        value: f64,
        views: &VisibilityViews<'_>,
    ) -> Result<(), GpuError> {
        use augsplat_render::forward::gpu::{
            camera_words, record_projection, tile_grid, Projection, SPLAT_STRIDE,
        };
        let n = self.scene.n;
        if n == 0 {
            return Ok(());
        }
        let nn = u64::from(n);
        // The CPU's unit opacity (1 − 2⁻²⁴): the projection's opacity is the compensation.
        let unit_logit = 16.6f32.to_bits();
        let settings = crate::RenderSettings {
            antialiased: views.antialiased,
            near: views.near,
            sh_degree: 0,
            ..Default::default()
        };
        let consts = |w: u32, h: u32| {
            [
                n,
                w,
                h,
                (value as f32).to_bits(),
                (KEEP_VISIBLE_ALPHA as f32).to_bits(),
                (KEEP_VISIBLE_MAX_OPACITY as f32).to_bits(),
                0,
                0,
            ]
        };
        ctx.scoped(|| {
            let unit =
                ctx.storage_items_init("unit opacity logits", &vec![unit_logit; n as usize])?;
            let ratios = ctx.storage_items("peak alpha ratios", 4 * nn)?;
            let splats = ctx.storage_items("splats", 4 * SPLAT_STRIDE * nn)?;
            let rects = ctx.storage_items("tile rectangles", 16 * nn)?;
            let keys = ctx.storage_items("depth keys", 4 * nn)?;
            let mut enc = ctx.encoder();
            for cam in views.cameras {
                let words = camera_words(&self.scene, cam, &settings, tile_grid(cam)?);
                let out = Projection {
                    splats: &splats,
                    rects: &rects,
                    keys: &keys,
                };
                record_projection(ctx, &mut enc, &self.scene, &unit, &words, out)?;
                ctx.dispatch_items(
                    &mut enc,
                    &kr.peak_ratio,
                    (&consts(cam.width, cam.height), 0),
                    &[(1, &splats, SPLAT_STRIDE), (2, &rects, 4), (3, &ratios, 1)],
                    n,
                    1,
                )?;
            }
            ctx.dispatch_items(
                &mut enc,
                &kr.keep_visible,
                (&consts(0, 0), 0),
                &[(3, &ratios, 1), (4, &self.scene.logits, 1)],
                n,
                1,
            )?;
            let (m, v) = &self.moments[crate::train::gpu::OPACITY_GROUP];
            enc.clear_buffer(m, 0, None);
            enc.clear_buffer(v, 0, None);
            ctx.defer(enc)
        })
    }

    /// `Periodic` opacity reset: logits clamped to `logit(value)`, opacity moments cleared.
    /// Kept for the next submission.
    fn reset_opacities(&self, ctx: &GpuContext, kr: &Kernels, value: f64) -> Result<(), GpuError> {
        ctx.scoped(|| {
            let mut enc = ctx.encoder();
            self.record_clamp(ctx, kr, &mut enc, value);
            let (m, v) = &self.moments[crate::train::gpu::OPACITY_GROUP];
            enc.clear_buffer(m, 0, None);
            enc.clear_buffer(v, 0, None);
            ctx.defer(enc)
        })
    }

    /// Records every logit clamped to at most `logit(value)` (a NaN becomes the cap).
    fn record_clamp(
        &self,
        ctx: &GpuContext,
        kr: &Kernels,
        enc: &mut augsplat_render::gpu::Encoder,
        value: f64,
    ) {
        let cap = crate::init::logit(value) as f32;
        let n = self.scene.n;
        let u = ctx.uniform(
            "opacity reset constants",
            &[n, cap.to_bits(), ord_key(cap), 0],
        );
        ctx.dispatch(
            enc,
            &kr.clamp_logits,
            &[(22, &u), (23, &self.scene.logits)],
            ctx.groups(n.div_ceil(256)),
        );
    }
}
