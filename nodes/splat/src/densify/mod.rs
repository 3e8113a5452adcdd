//! Adaptive density control as gsplat's `DefaultStrategy` (classic mode, `absgrad = False`,
//! `revised_opacity = False`, no 2-D-radius rules).
//!
//! Per step ([`Densifier::accumulate`]) the per-view screen-space gradient statistic
//! `‖dL/d(mean2d)‖` — in NDC-normalised units (× width/2, × height/2) — is summed for each
//! visible Gaussian together with a visibility count. Every `every` steps in
//! `(start, stop)` ([`Densifier::step_post_update`]):
//! 1. **grow**: Gaussians whose average statistic exceeds `grad_threshold` are *cloned*
//!    (identical copy appended) when their largest scale ≤ `grow_scale3d · scene_scale`, and
//!    *split* otherwise: replaced by two children at positions drawn from the Gaussian
//!    (`μ + R·(s ⊙ n)`, n ~ N(0, I)) with scales divided by `split_factor` (1.6);
//! 2. **prune**: opacity < `prune_opacity`, and (after `reset_every` steps) largest scale >
//!    `prune_scale3d · extent`, the extent being the scene scale (gsplat) or, with
//!    [`PruneExtent::Content`], the larger of it and the content's own extent;
//! 3. the statistics are cleared.
//!
//! **Opacity reset** ([`OpacityReset`]): with `Periodic` (3DGS, gsplat ≤ 1.5.2, the default),
//! every `reset_every` steps (while `step < stop`) opacities are clamped to
//! `2 · prune_opacity` (0.01) and the opacity moments cleared. `Never` is gsplat 1.5.3 (whose
//! reset condition `step % reset_every == 0 & step > 0` is never true in Python).
//! `KeepVisible` resets on the same schedule but never below the opacity at which a
//! Gaussian's most visible pixel in the training views keeps an alpha of
//! [`KEEP_VISIBLE_ALPHA`] (twice the 1/255 cutoff): a full reset can push every pixel of a
//! small Gaussian under the cutoff, where its opacity gradient is exactly zero and it can
//! never recover. In every mode, pruning of oversized Gaussians starts after `reset_every`
//! steps (as gsplat, whether or not resets happen).
//!
//! Adam state stays aligned: clones and children get zero moments, survivors keep theirs.
//! The sample noise comes from a seeded [`Rng`] stream per refinement step, drawn in index
//! order, so densification is deterministic.
//!
//! Iteration counts are given for gsplat's 30 000-step schedule. With `scale_with_steps`, a
//! shorter run of T steps uses f = T / 30000 and s = max(f, 1/4): `stop` × f (refinement ends
//! half-way, as in gsplat), `start` and `reset_every` × s, and `every` unchanged (capped at a
//! quarter of the refinement window). Scaling `every` or `reset_every` by f itself makes a
//! short run refine 4× as often per view seen and reset opacities every few epochs, which
//! over-grows the set (measured: 170k Gaussians for a 128×96 scene in 3000 steps), see
//! [`DensifyArgs::scaled`].

pub mod gpu;
#[cfg(test)]
mod gpu_tests;
pub mod thresholds;

use crate::adam::{Adam, Group};
use crate::Gaussians;
use augsplat_core::{linalg, Rng};
use serde::{Deserialize, Serialize};

/// Densification parameters (gsplat DefaultStrategy defaults).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct DensifyArgs {
    /// Whether to densify, prune and reset at all.
    pub enabled: bool,
    /// Threshold on the view-averaged NDC-normalised screen-space gradient.
    pub grad_threshold: f64,
    /// Clone (≤) vs split (>) boundary on the largest scale, × scene scale.
    pub grow_scale3d: f64,
    /// Split children's scales are divided by this.
    pub split_factor: f64,
    /// Prune below this opacity.
    pub prune_opacity: f64,
    /// Prune Gaussians whose largest scale exceeds this × the prune extent (after the first
    /// reset).
    pub prune_scale3d: f64,
    /// What the prune extent is (see [`PruneExtent`]). Left out of the key when `Cameras`,
    /// so pipelines written before it existed keep their keys.
    #[serde(skip_serializing_if = "PruneExtent::is_cameras")]
    pub prune_extent: PruneExtent,
    /// First step at which refinement may happen (exclusive, as gsplat).
    pub start: u64,
    /// Refinement and opacity resets stop at this step.
    pub stop: u64,
    /// Refine every this many steps.
    pub every: u64,
    /// Reset opacities every this many steps (0 = never, and no pruning of large Gaussians).
    pub reset_every: u64,
    /// How opacities are reset (see [`OpacityReset`]). Left out of the key when `Periodic`,
    /// so pipelines written before it existed keep their keys.
    #[serde(skip_serializing_if = "OpacityReset::is_periodic")]
    pub reset: OpacityReset,
    /// Scale `start`, `stop`, `every`, `reset_every` for runs shorter than `reference_steps`.
    pub scale_with_steps: bool,
    /// The run length the iteration counts are given for.
    pub reference_steps: u64,
    /// Hard cap on the number of Gaussians (growth stops there; 0 = unlimited).
    pub max_gaussians: usize,
}

impl Default for DensifyArgs {
    fn default() -> Self {
        DensifyArgs {
            enabled: true,
            grad_threshold: 2e-4,
            grow_scale3d: 0.01,
            split_factor: 1.6,
            prune_opacity: 0.005,
            prune_scale3d: 0.1,
            prune_extent: PruneExtent::Cameras,
            start: 500,
            stop: 15_000,
            every: 100,
            reset_every: 3000,
            reset: OpacityReset::Periodic,
            scale_with_steps: true,
            reference_steps: 30_000,
            max_gaussians: 0,
        }
    }
}

/// How [`Densifier::step_post_update`] resets opacities every `reset_every` steps.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
pub enum OpacityReset {
    /// Clamp every opacity to `2 · prune_opacity` (3DGS; gsplat 1.5.2 and earlier).
    #[default]
    Periodic,
    /// No resets (gsplat 1.5.3's behaviour). Large Gaussians are still pruned after
    /// `reset_every` steps.
    Never,
    /// As `Periodic`, but no Gaussian goes below the opacity that keeps its most visible
    /// training-view pixel at alpha [`KEEP_VISIBLE_ALPHA`], so none loses its gradient.
    KeepVisible,
}

impl OpacityReset {
    /// Whether this is the default (serde's `skip_serializing_if`).
    pub fn is_periodic(&self) -> bool {
        *self == OpacityReset::Periodic
    }
}

/// What the large-Gaussian prune measures a Gaussian's largest scale against
/// (`prune_scale3d ×` this extent).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
pub enum PruneExtent {
    /// The scene scale: 1.1 × the cameras' largest distance from their centroid (gsplat's
    /// rule, the default). In a forward-facing capture (LLFF) the cameras span a small
    /// fraction of the depth range, so this prunes the large Gaussians the background needs.
    #[default]
    Cameras,
    /// The larger of the scene scale and the content's extent: 1.1 × the 90th percentile of
    /// the initial Gaussians' distances from the cameras' centroid
    /// ([`crate::train::content_extent`]). Where the content lies within the cameras' spread
    /// (a capture around an object) this is the scene scale.
    Content,
}

impl PruneExtent {
    /// Whether this is the default (serde's `skip_serializing_if`).
    pub fn is_cameras(&self) -> bool {
        *self == PruneExtent::Cameras
    }
}

/// The lengths that densification compares Gaussians' scales with.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Extents {
    /// The scene scale: the clone/split boundary is `grow_scale3d ×` this.
    pub scene: f64,
    /// The large-Gaussian prune removes scales above `prune_scale3d ×` this.
    pub prune: f64,
}

impl Extents {
    /// Both lengths equal to `scale` (gsplat's rule).
    pub fn uniform(scale: f64) -> Extents {
        Extents {
            scene: scale,
            prune: scale,
        }
    }
}

/// The alpha `KeepVisible` keeps at each Gaussian's most visible pixel: twice the
/// rasteriser's 1/255 cutoff.
pub const KEEP_VISIBLE_ALPHA: f64 = 2.0 / 255.0;

/// The iteration schedule actually used for a run.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct DensifySchedule {
    /// Refinement happens at steps `> start`.
    pub start: u64,
    /// … and `< stop`.
    pub stop: u64,
    /// … that are multiples of `every`.
    pub every: u64,
    /// Opacity reset period (0 = never).
    pub reset_every: u64,
}

impl DensifySchedule {
    /// Whether the refinement window reaches the first opacity reset: `false` when
    /// refinement stops at or before step `reset_every` (or there is no period), so that no
    /// reset falls inside it and the large-Gaussian prune (which starts after `reset_every`
    /// steps) never runs — the run's bytes are then the same for every
    /// [`OpacityReset`] mode and [`PruneExtent`]. With gsplat's schedule scaled to the run,
    /// runs of 1,500 steps or fewer never reach it; 3,000-step runs reset at step 750.
    pub fn reaches_reset(&self) -> bool {
        self.reset_every > 0 && self.stop > self.reset_every
    }

    /// The trainer's log line for a run of `steps` whose refinement window does not reach the
    /// first opacity reset ([`Self::reaches_reset`] is false): the reset mode and the
    /// large-Gaussian prune's extent cannot change such a run.
    pub fn short_run_note(&self, steps: u64) -> String {
        let why = if self.reset_every > 0 {
            format!("before the first opacity reset (step {})", self.reset_every)
        } else {
            "and densify.reset_every = 0 sets no reset period".to_string()
        };
        format!(
            "densification ends at step {} of {steps}, {why}: densify.reset and \
             densify.prune_extent change nothing in this run",
            self.stop
        )
    }

    /// Whether `step` is a step of the opacity-reset period (whatever the reset mode).
    pub fn reset_due(&self, step: u64) -> bool {
        self.reset_every > 0 && step > 0 && step.is_multiple_of(self.reset_every)
    }

    /// Whether a refinement at `step` also prunes oversized Gaussians (after the first reset
    /// period, as gsplat, whether or not resets happen).
    pub fn large_prune_active(&self, step: u64) -> bool {
        self.reset_every > 0 && step > self.reset_every
    }
}

impl DensifyArgs {
    /// Checks ranges.
    pub fn validate(&self) -> Result<(), String> {
        for (n, v) in [
            ("grad_threshold", self.grad_threshold),
            ("grow_scale3d", self.grow_scale3d),
            ("prune_opacity", self.prune_opacity),
            ("prune_scale3d", self.prune_scale3d),
        ] {
            if !v.is_finite() || v < 0.0 {
                return Err(format!("densify.{n} = {v} must be finite and ≥ 0"));
            }
        }
        if !(self.split_factor.is_finite() && self.split_factor > 0.0) {
            return Err(format!(
                "densify.split_factor = {} must be positive",
                self.split_factor
            ));
        }
        if self.prune_opacity >= 0.5 {
            return Err(format!(
                "densify.prune_opacity = {} must be < 0.5",
                self.prune_opacity
            ));
        }
        if self.every == 0 {
            return Err("densify.every must be ≥ 1".into());
        }
        if self.scale_with_steps && self.reference_steps == 0 {
            return Err("densify.reference_steps must be ≥ 1".into());
        }
        Ok(())
    }

    /// The schedule for a run of `steps` steps (see the module docs).
    pub fn scaled(&self, steps: u64) -> DensifySchedule {
        if !self.scale_with_steps || steps >= self.reference_steps {
            return DensifySchedule {
                start: self.start,
                stop: self.stop,
                every: self.every,
                reset_every: self.reset_every,
            };
        }
        let f = steps as f64 / self.reference_steps as f64;
        let s = f.max(0.25);
        let sc = |v: u64, f: f64| (v as f64 * f).round() as u64;
        let start = sc(self.start, s);
        let stop = sc(self.stop, f);
        DensifySchedule {
            start,
            stop,
            every: self.every.min((stop.saturating_sub(start) / 4).max(1)),
            reset_every: sc(self.reset_every, s),
        }
    }
}

/// What one refinement did.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct RefineReport {
    /// Gaussians cloned.
    pub cloned: usize,
    /// Gaussians split (each into two).
    pub split: usize,
    /// Gaussians pruned.
    pub pruned: usize,
    /// Whether opacities were reset.
    pub reset: bool,
}

/// Densification statistics and the refinement operations.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Densifier {
    /// Sum over views of the NDC-normalised screen-space gradient norm.
    pub grad2d: Vec<f32>,
    /// Number of views in which the Gaussian was visible.
    pub count: Vec<u32>,
}

/// Whether [`Densifier::step_post_update`] can change anything after `step`: a refinement
/// (clone, split, prune) or an opacity reset falls on it. On the other steps it returns at
/// once, so a trainer whose state lives elsewhere (the GPU) need not bring it back.
pub fn acts_at(step: u64, sched: &DensifySchedule, args: &DensifyArgs) -> bool {
    if !args.enabled || step >= sched.stop {
        return false;
    }
    let refine = step > sched.start && step.is_multiple_of(sched.every);
    let reset = sched.reset_due(step) && args.reset != OpacityReset::Never;
    refine || reset
}

impl Densifier {
    /// Empty statistics for `n` Gaussians.
    pub fn new(n: usize) -> Self {
        Densifier {
            grad2d: vec![0.0; n],
            count: vec![0; n],
        }
    }

    /// Adds one view's statistic: `means2d` is dL/d(mean2d) already in NDC-normalised units
    /// (× width/2, × height/2), `visible` marks Gaussians with radius > 0. Non-finite
    /// gradients are ignored.
    pub fn accumulate(&mut self, means2d: &[[f32; 2]], visible: &[bool]) {
        self.accumulate_scaled(means2d, visible, 1.0);
    }

    /// [`Densifier::accumulate`] of the statistic multiplied by `factor` (per component,
    /// before the norm: gsplat's `× n_cameras` for a batch of views).
    pub fn accumulate_scaled(&mut self, means2d: &[[f32; 2]], visible: &[bool], factor: f32) {
        assert_eq!(
            means2d.len(),
            self.grad2d.len(),
            "densify statistics size differs"
        );
        assert_eq!(visible.len(), self.grad2d.len());
        for ((&[x, y], &v), (s, c)) in means2d
            .iter()
            .zip(visible)
            .zip(self.grad2d.iter_mut().zip(self.count.iter_mut()))
        {
            if v {
                let (x, y) = (x * factor, y * factor);
                let n = (x * x + y * y).sqrt();
                if n.is_finite() {
                    *s += n;
                }
                *c += 1;
            }
        }
    }

    /// Clears the statistics.
    pub fn clear(&mut self) {
        self.grad2d.iter_mut().for_each(|x| *x = 0.0);
        self.count.iter_mut().for_each(|x| *x = 0);
    }

    /// Runs the strategy after the optimiser update of step `step` (the 0-based index of the
    /// step just taken, gsplat's `step`): refine when due, reset opacities when due (never at
    /// step 0). `visibility` gives, for a `KeepVisible` reset, each Gaussian's largest ratio
    /// of pixel alpha to opacity over the training views ([`peak_alpha_ratios`]); it is
    /// called only then.
    #[allow(clippy::too_many_arguments)]
    pub fn step_post_update(
        &mut self,
        step: u64,
        sched: &DensifySchedule,
        args: &DensifyArgs,
        g: &mut Gaussians,
        adam: &mut Adam,
        extents: Extents,
        seed: u64,
        visibility: &mut dyn FnMut(&Gaussians) -> Vec<f64>,
    ) -> RefineReport {
        let mut rep = RefineReport::default();
        if !acts_at(step, sched, args) {
            return rep;
        }
        if step > sched.start && step.is_multiple_of(sched.every) {
            let rng = &mut Rng::stream(seed, step);
            let (c, s) = self.grow(g, adam, args, extents.scene, rng);
            rep.cloned = c;
            rep.split = s;
            let past_reset = sched.large_prune_active(step);
            rep.pruned = self.prune(g, adam, args, extents.prune, past_reset);
            self.clear();
        }
        if sched.reset_due(step) {
            match args.reset {
                OpacityReset::Periodic => {
                    reset_opacities(g, adam, 2.0 * args.prune_opacity);
                    rep.reset = true;
                }
                OpacityReset::KeepVisible => {
                    let ratios = visibility(g);
                    reset_opacities_keep_visible(g, adam, 2.0 * args.prune_opacity, &ratios);
                    rep.reset = true;
                }
                OpacityReset::Never => {}
            }
        }
        rep
    }

    /// Clones and splits by the averaged statistic. Returns (cloned, split).
    pub fn grow(
        &mut self,
        g: &mut Gaussians,
        adam: &mut Adam,
        args: &DensifyArgs,
        scene_scale: f64,
        rng: &mut Rng,
    ) -> (usize, usize) {
        let n = g.len();
        assert_eq!(
            self.grad2d.len(),
            n,
            "densify statistics size differs from the set"
        );
        let limit = if args.max_gaussians == 0 {
            usize::MAX
        } else {
            args.max_gaussians
        };
        let mut clone = Vec::new();
        let mut split = Vec::new();
        for i in 0..n {
            let avg = self.grad2d[i] as f64 / self.count[i].max(1) as f64;
            if avg <= args.grad_threshold {
                continue;
            }
            let smax = max_log_scale(&g.log_scales[i]).exp();
            if smax as f64 <= args.grow_scale3d * scene_scale {
                clone.push(i);
            } else {
                split.push(i);
            }
        }
        // Respect the cap: clones first, then splits (each split adds one net Gaussian).
        let room = limit.saturating_sub(n);
        clone.truncate(room);
        split.truncate(room - clone.len());
        let (nc, ns) = (clone.len(), split.len());
        if nc + ns == 0 {
            return (0, 0);
        }
        // Clone: append identical copies.
        append_copies(g, &clone);
        adam.append_zeros(nc);
        for &i in &clone {
            self.grad2d.push(self.grad2d[i]);
            self.count.push(self.count[i]);
        }
        // Split: two children per parent, appended; parents removed.
        let k3 = g.coeffs() * 3;
        let log_div = (args.split_factor as f32).ln();
        for &i in &split {
            let parent = SplitParent {
                mean: g.means[i],
                log_scales: g.log_scales[i],
                quat: g.quats[i],
            };
            for child in split_children(&parent, log_div, rng) {
                g.means.push(child.mean);
                g.log_scales.push(child.log_scales);
                g.quats.push(g.quats[i]);
                g.opacity_logits.push(g.opacity_logits[i]);
                g.sh.extend_from_within(i * k3..(i + 1) * k3);
                self.grad2d.push(0.0);
                self.count.push(0);
            }
        }
        adam.append_zeros(2 * ns);
        if ns > 0 {
            let mut keep = vec![true; g.len()];
            for &i in &split {
                keep[i] = false;
            }
            self.retain_all(g, adam, &keep);
        }
        (nc, ns)
    }

    /// Removes transparent Gaussians and, when `prune_large`, those whose largest scale
    /// exceeds `prune_scale3d × extent`. Returns how many were removed. Gaussians with
    /// non-finite parameters are removed too.
    pub fn prune(
        &mut self,
        g: &mut Gaussians,
        adam: &mut Adam,
        args: &DensifyArgs,
        extent: f64,
        prune_large: bool,
    ) -> usize {
        let n = g.len();
        let rule = PruneRule::new(args, extent, prune_large);
        let keep: Vec<bool> = (0..n)
            .map(|i| !rule.prunes(g.opacity_logits[i], &g.log_scales[i], &g.means[i]))
            .collect();
        let removed = keep.iter().filter(|&&k| !k).count();
        if removed > 0 {
            self.retain_all(g, adam, &keep);
        }
        removed
    }

    fn retain_all(&mut self, g: &mut Gaussians, adam: &mut Adam, keep: &[bool]) {
        retain(g, keep);
        adam.retain(keep);
        let mut it = keep.iter();
        self.grad2d.retain(|_| *it.next().unwrap_or(&false));
        let mut it = keep.iter();
        self.count.retain(|_| *it.next().unwrap_or(&false));
    }
}

/// What a split child inherits from its parent's geometry.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct SplitParent {
    /// The parent's mean.
    pub mean: [f32; 3],
    /// The parent's log-scales.
    pub log_scales: [f32; 3],
    /// The parent's raw quaternion.
    pub quat: [f32; 4],
}

/// A split child's mean and log-scales (its quaternion, opacity and colour are the
/// parent's).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct SplitChild {
    /// Drawn from the parent: `μ + R·(s ⊙ n)`, n ~ N(0, I), in f64.
    pub mean: [f32; 3],
    /// The parent's log-scales minus `ln(split_factor)`.
    pub log_scales: [f32; 3],
}

/// The two children of one split, drawing six normals from `rng` (three per child, in
/// order): the one definition both the CPU's [`Densifier::grow`] and the GPU's refinement use,
/// so that a split gives the same bits on either device.
pub fn split_children(p: &SplitParent, log_div: f32, rng: &mut Rng) -> [SplitChild; 2] {
    let q = p.quat;
    let qn = {
        let l = q.iter().map(|v| (*v as f64).powi(2)).sum::<f64>().sqrt();
        if l > 0.0 && l.is_finite() {
            [
                q[0] as f64 / l,
                q[1] as f64 / l,
                q[2] as f64 / l,
                q[3] as f64 / l,
            ]
        } else {
            [1.0, 0.0, 0.0, 0.0]
        }
    };
    let r = linalg::quat_to_mat3(qn);
    let s: [f64; 3] = std::array::from_fn(|a| (p.log_scales[a] as f64).exp());
    std::array::from_fn(|_| {
        let z: [f64; 3] = std::array::from_fn(|a| rng.normal() * s[a]);
        let off = linalg::mat3_vec(&r, z);
        SplitChild {
            mean: std::array::from_fn(|a| (p.mean[a] as f64 + off[a]) as f32),
            log_scales: p.log_scales.map(|v| v - log_div),
        }
    })
}

/// The prune test of one refinement ([`Densifier::prune`]).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct PruneRule {
    /// Opacity logits below this are pruned.
    pub thr_logit: f32,
    /// Largest scales above this are pruned when `large` holds.
    pub big: f64,
    /// Whether oversized Gaussians are pruned (after the first reset period).
    pub large: bool,
}

impl PruneRule {
    /// The rule for `args` with the prune extent `extent`.
    pub fn new(args: &DensifyArgs, extent: f64, large: bool) -> PruneRule {
        PruneRule {
            thr_logit: crate::init::logit(args.prune_opacity) as f32,
            big: args.prune_scale3d * extent,
            large,
        }
    }

    /// Whether a Gaussian with these parameters is pruned: transparent (or a NaN opacity), a
    /// non-finite scale or mean, or (when `large`) a largest scale above `big`.
    pub fn prunes(&self, logit: f32, log_scales: &[f32; 3], mean: &[f32; 3]) -> bool {
        if logit.is_nan() || logit < self.thr_logit {
            return true;
        }
        let smax = max_log_scale(log_scales);
        if !smax.is_finite() || mean.iter().any(|v| !v.is_finite()) {
            return true;
        }
        self.large && (smax.exp() as f64) > self.big
    }
}

/// The largest of three log-scales, NaNs ignored (−∞ when all are NaN).
pub fn max_log_scale(log_scales: &[f32; 3]) -> f32 {
    log_scales.iter().cloned().fold(f32::NEG_INFINITY, f32::max)
}

/// Clamps every opacity to at most `value` (gsplat `reset_opa`) and clears the opacity
/// moments.
pub fn reset_opacities(g: &mut Gaussians, adam: &mut Adam, value: f64) {
    let cap = crate::init::logit(value) as f32;
    for o in &mut g.opacity_logits {
        *o = o.min(cap);
    }
    adam.clear_group(Group::Opacities);
}

/// The highest opacity a `KeepVisible` reset keeps a Gaussian at.
pub const KEEP_VISIBLE_MAX_OPACITY: f64 = 0.99;

/// The opacity below which a `KeepVisible` reset lowers no Gaussian whose largest pixel
/// alpha per unit opacity is `ratio` ([`peak_alpha_ratios`]): the one at which that pixel
/// keeps alpha [`KEEP_VISIBLE_ALPHA`], at most [`KEEP_VISIBLE_MAX_OPACITY`]; 0 for a Gaussian
/// that no opacity keeps visible (its peak pixel stays under the rasteriser's 1/255 cutoff
/// even at that ceiling, or it reaches no pixel).
pub fn keep_visible_floor(ratio: f64) -> f64 {
    let cutoff = f64::from(augsplat_render::constants::ALPHA_THRESHOLD);
    if KEEP_VISIBLE_MAX_OPACITY * ratio >= cutoff {
        (KEEP_VISIBLE_ALPHA / ratio).min(KEEP_VISIBLE_MAX_OPACITY)
    } else {
        0.0
    }
}

/// [`reset_opacities`] that lowers Gaussian `i` to no less than
/// [`keep_visible_floor`]`(ratios[i])`, where `ratios[i]` is its largest pixel alpha per unit
/// opacity ([`peak_alpha_ratios`]; 0 when it reaches no pixel). Opacities already below stay.
pub fn reset_opacities_keep_visible(
    g: &mut Gaussians,
    adam: &mut Adam,
    value: f64,
    ratios: &[f64],
) {
    assert_eq!(ratios.len(), g.len(), "one visibility ratio per Gaussian");
    for (o, &r) in g.opacity_logits.iter_mut().zip(ratios) {
        let cap = crate::init::logit(value.max(keep_visible_floor(r))) as f32;
        *o = o.min(cap);
    }
    adam.clear_group(Group::Opacities);
}

/// For each Gaussian, the largest over `cams` of its alpha at the pixel centre nearest its
/// projected centre, per unit opacity: the antialiasing compensation times the Gaussian
/// falloff there (0 when it is culled in every view). Parallel over Gaussians; the result does
/// not depend on the thread count.
pub fn peak_alpha_ratios(
    g: &Gaussians,
    cams: &[&augsplat_core::Camera],
    antialiased: bool,
    near: f64,
) -> Vec<f64> {
    use crate::project::{project, CameraModel, Outcome};
    use rayon::prelude::*;
    let models: Vec<(CameraModel, u32, u32)> = cams
        .iter()
        .map(|c| (CameraModel::new(c), c.width, c.height))
        .collect();
    // Opacity 1 − 2⁻²⁴ (logit 16.6): the projection's opacity is then the compensation.
    let unit_logit = 16.6f32;
    (0..g.len())
        .into_par_iter()
        .map(|i| {
            let mut best = 0f64;
            for (cam, w, h) in &models {
                let p = match project(
                    cam,
                    g.means[i],
                    g.log_scales[i],
                    g.quats[i],
                    unit_logit,
                    antialiased,
                    near,
                ) {
                    Outcome::Visible(p) => p,
                    _ => continue,
                };
                let px = (p.mean2d[0].floor().clamp(0.0, *w as f64 - 1.0)) + 0.5;
                let py = (p.mean2d[1].floor().clamp(0.0, *h as f64 - 1.0)) + 0.5;
                let (dx, dy) = (p.mean2d[0] - px, p.mean2d[1] - py);
                let power =
                    0.5 * (p.conic[0] * dx * dx + p.conic[2] * dy * dy) + p.conic[1] * dx * dy;
                let ratio = p.opacity * (-power.max(0.0)).exp();
                if ratio.is_finite() {
                    best = best.max(ratio);
                }
            }
            best
        })
        .collect()
}

/// The training views in which a `KeepVisible` reset measures each Gaussian's visibility
/// ([`peak_alpha_ratios`]), with the projection's settings.
#[derive(Clone, Copy, Debug)]
pub struct VisibilityViews<'a> {
    /// The views' cameras.
    pub cameras: &'a [&'a augsplat_core::Camera],
    /// Whether the projection compensates for the antialiasing blur.
    pub antialiased: bool,
    /// The near plane.
    pub near: f32,
}

impl VisibilityViews<'_> {
    /// No views (every Gaussian reaches no pixel).
    pub const NONE: VisibilityViews<'static> = VisibilityViews {
        cameras: &[],
        antialiased: false,
        near: 0.01,
    };

    /// [`peak_alpha_ratios`] of `g` in these views.
    pub fn peak_alpha_ratios(&self, g: &Gaussians) -> Vec<f64> {
        peak_alpha_ratios(g, self.cameras, self.antialiased, f64::from(self.near))
    }
}

/// Keeps the Gaussians with `keep[i]`, in order.
pub fn retain(g: &mut Gaussians, keep: &[bool]) {
    assert_eq!(
        keep.len(),
        g.len(),
        "retain: mask length differs from the set"
    );
    let k3 = g.coeffs() * 3;
    let mut out = 0;
    for (i, &k) in keep.iter().enumerate() {
        if k {
            if out != i {
                g.means[out] = g.means[i];
                g.log_scales[out] = g.log_scales[i];
                g.quats[out] = g.quats[i];
                g.opacity_logits[out] = g.opacity_logits[i];
                g.sh.copy_within(i * k3..(i + 1) * k3, out * k3);
            }
            out += 1;
        }
    }
    g.means.truncate(out);
    g.log_scales.truncate(out);
    g.quats.truncate(out);
    g.opacity_logits.truncate(out);
    g.sh.truncate(out * k3);
}

/// Appends copies of the Gaussians at `indices`.
pub fn append_copies(g: &mut Gaussians, indices: &[usize]) {
    let k3 = g.coeffs() * 3;
    for &i in indices {
        g.means.push(g.means[i]);
        g.log_scales.push(g.log_scales[i]);
        g.quats.push(g.quats[i]);
        g.opacity_logits.push(g.opacity_logits[i]);
        g.sh.extend_from_within(i * k3..(i + 1) * k3);
    }
}
