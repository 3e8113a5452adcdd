//! Adam over the Gaussian parameter groups. [`Adam::step`] updates the Gaussians its mask
//! marks: a trainer passes all of them ([`AdamUpdates::Dense`], torch's Adam as gsplat
//! `simple_trainer` uses it, the default) or only those visible in the step
//! ([`AdamUpdates::Selective`], gsplat's `SelectiveAdam`: invisible Gaussians keep their
//! parameters *and* their moments). Every group's step counter advances every step, so bias
//! correction follows the global step.
//!
//! Defaults are gsplat `simple_trainer`'s: means 1.6e-4 × scene scale decaying exponentially
//! to 1 % over the run (`lr_t = lr_0 · 0.01^(t/T)`), log-scales 5e-3, quaternions 1e-3,
//! opacity logits 5e-2, SH DC 2.5e-3, higher SH 2.5e-3/20, β = (0.9, 0.999), ε = 1e-15.
//! The update is torch's: `p ← p − (lr / (1−β1ᵗ)) · m / (√v / √(1−β2ᵗ) + ε)`.
//!
//! The state is structure-of-arrays, one flat `m`/`v` pair per group aligned with the
//! [`Gaussians`] layout, so densification can remove and append Gaussians while keeping every
//! survivor's moments ([`Adam::retain`], [`Adam::append_zeros`]).

use crate::Gaussians;
pub use augsplat_render::ParamGrads;
use rayon::prelude::*;
use serde::{Deserialize, Serialize};

/// Gaussians per parallel chunk of the update (fixed; the update is element-wise anyway).
const CHUNK: usize = 2048;
/// Values per SIMD block of the update.
const LANES: usize = 16;

/// Learning rates of the parameter groups (gsplat simple_trainer defaults).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct LearningRates {
    /// Means, multiplied by the scene scale.
    pub means: f64,
    /// Factor the means rate decays to by the last step (exponentially).
    pub means_final_factor: f64,
    /// Log-scales.
    pub scales: f64,
    /// Raw quaternions.
    pub quats: f64,
    /// Opacity logits.
    pub opacities: f64,
    /// SH DC coefficients.
    pub sh0: f64,
    /// Higher SH coefficients.
    pub shn: f64,
    /// Adam β1.
    pub beta1: f64,
    /// Adam β2.
    pub beta2: f64,
    /// Adam ε.
    pub eps: f64,
}

impl Default for LearningRates {
    fn default() -> Self {
        LearningRates {
            means: 1.6e-4,
            means_final_factor: 0.01,
            scales: 5e-3,
            quats: 1e-3,
            opacities: 5e-2,
            sh0: 2.5e-3,
            shn: 2.5e-3 / 20.0,
            beta1: 0.9,
            beta2: 0.999,
            eps: 1e-15,
        }
    }
}

impl LearningRates {
    /// Checks that rates are finite and non-negative and betas in [0, 1).
    pub fn validate(&self) -> Result<(), String> {
        for (n, v) in [
            ("means", self.means),
            ("means_final_factor", self.means_final_factor),
            ("scales", self.scales),
            ("quats", self.quats),
            ("opacities", self.opacities),
            ("sh0", self.sh0),
            ("shn", self.shn),
            ("eps", self.eps),
        ] {
            if !v.is_finite() || v < 0.0 {
                return Err(format!("learning_rates.{n} = {v} must be finite and ≥ 0"));
            }
        }
        for (n, v) in [("beta1", self.beta1), ("beta2", self.beta2)] {
            if !(0.0..1.0).contains(&v) {
                return Err(format!("learning_rates.{n} = {v} must be in [0, 1)"));
            }
        }
        Ok(())
    }

    /// The means learning rate at `step` of a `total`-step run for a scene of `scene_scale`:
    /// `means · scene_scale · final^(step/total)` (gsplat's ExponentialLR with
    /// γ = final^(1/total)).
    pub fn means_at(&self, step: u64, total: u64, scene_scale: f64) -> f64 {
        let frac = if total == 0 {
            0.0
        } else {
            step as f64 / total as f64
        };
        self.means * scene_scale * self.means_final_factor.powf(frac)
    }
}

/// First and second moments of one parameter group.
#[derive(Clone, Debug, Default, PartialEq)]
struct Moments {
    m: Vec<f32>,
    v: Vec<f32>,
    /// Values per Gaussian.
    width: usize,
}

impl Moments {
    fn new(width: usize) -> Self {
        Moments {
            m: Vec::new(),
            v: Vec::new(),
            width,
        }
    }
    fn resize(&mut self, n: usize) {
        self.m.resize(n * self.width, 0.0);
        self.v.resize(n * self.width, 0.0);
    }
    fn retain(&mut self, keep: &[bool]) {
        let w = self.width;
        let mut out = 0;
        for (i, &k) in keep.iter().enumerate() {
            if k {
                if out != i {
                    self.m.copy_within(i * w..(i + 1) * w, out * w);
                    self.v.copy_within(i * w..(i + 1) * w, out * w);
                }
                out += 1;
            }
        }
        self.m.truncate(out * w);
        self.v.truncate(out * w);
    }
    fn clear(&mut self) {
        self.m.iter_mut().for_each(|x| *x = 0.0);
        self.v.iter_mut().for_each(|x| *x = 0.0);
    }
}

/// The per-step rates and constants handed to the update kernel.
#[derive(Clone, Copy, Debug)]
struct StepConst {
    /// lr / (1 − β1ᵗ) for the first `split` values of a Gaussian.
    step_a: f32,
    /// Same for the values from `split` on.
    step_b: f32,
    split: usize,
    /// Leading values of each Gaussian to update (the rest are known no-ops).
    cols: usize,
    b1: f32,
    b2: f32,
    /// 1 / √(1 − β2ᵗ).
    inv_sqrt_bc2: f32,
    eps: f32,
}

/// The Adam update of one value (torch's formula, see the module docs); returns the new
/// parameter, updates the moments in place. Plain multiplies and adds in a fixed order (Rust
/// never fuses them), so every instruction set gives the same bits as the scalar code.
#[inline(always)]
fn adam_elem(p: f32, g: f32, m: &mut f32, v: &mut f32, step: f32, c: &StepConst) -> f32 {
    let mn = c.b1 * *m + (1.0 - c.b1) * g;
    let vn = c.b2 * *v + (1.0 - c.b2) * g * g;
    *m = mn;
    *v = vn;
    p - step * mn / (vn.sqrt() * c.inv_sqrt_bc2 + c.eps)
}

/// The update of a contiguous run of values that share one step size, in blocks of
/// [`LANES`] (vectorised) and a scalar tail.
#[inline(always)]
fn adam_flat(p: &mut [f32], g: &[f32], m: &mut [f32], v: &mut [f32], step: f32, c: &StepConst) {
    let n = p.len();
    let (g, m, v) = (&g[..n], &mut m[..n], &mut v[..n]);
    let full = n / LANES * LANES;
    for (((pc, gc), mc), vc) in p[..full]
        .chunks_exact_mut(LANES)
        .zip(g[..full].chunks_exact(LANES))
        .zip(m[..full].chunks_exact_mut(LANES))
        .zip(v[..full].chunks_exact_mut(LANES))
    {
        for l in 0..LANES {
            pc[l] = adam_elem(pc[l], gc[l], &mut mc[l], &mut vc[l], step, c);
        }
    }
    for i in full..n {
        p[i] = adam_elem(p[i], g[i], &mut m[i], &mut v[i], step, c);
    }
}

/// The update of one block of [`LANES`] values, each with its own step size.
#[inline(always)]
fn adam_lanes(
    p: &mut [f32],
    g: &[f32],
    m: &mut [f32],
    v: &mut [f32],
    steps: &[f32; LANES],
    c: &StepConst,
) {
    let (p, g, m, v) = (
        &mut p[..LANES],
        &g[..LANES],
        &mut m[..LANES],
        &mut v[..LANES],
    );
    for l in 0..LANES {
        p[l] = adam_elem(p[l], g[l], &mut m[l], &mut v[l], steps[l], c);
    }
}

/// The update of one chunk of a group (`first` = index of its first Gaussian): only runs of
/// visible Gaussians are touched; each run is one flat update when the group has a single
/// step size, else the first `split` values of each Gaussian use `step_a` and the rest
/// `step_b` (per-lane step sizes, so the SH group's 3 + 45 split stays vectorised).
#[inline(always)]
#[allow(clippy::too_many_arguments)]
fn update_chunk_body(
    p: &mut [f32],
    g: &[f32],
    m: &mut [f32],
    v: &mut [f32],
    visible: &[bool],
    w: usize,
    c: &StepConst,
) {
    let n = visible.len();
    let cols = c.cols.min(w);
    let split = c.split.min(cols);
    let uniform = (split == cols || c.step_a == c.step_b) && cols == w;
    let mut i = 0;
    while i < n {
        if !visible[i] {
            i += 1;
            continue;
        }
        let start = i;
        while i < n && visible[i] {
            i += 1;
        }
        let r = start * w..i * w;
        let (pr, gr, mr, vr) = (
            &mut p[r.clone()],
            &g[r.clone()],
            &mut m[r.clone()],
            &mut v[r],
        );
        if uniform {
            adam_flat(pr, gr, mr, vr, c.step_a, c);
        } else {
            for (((pg, gg), mg), vg) in pr
                .chunks_exact_mut(w)
                .zip(gr.chunks_exact(w))
                .zip(mr.chunks_exact_mut(w))
                .zip(vr.chunks_exact_mut(w))
            {
                // Whole blocks with a step size per lane (the split falls inside a block:
                // SH DC and rest), then a scalar tail; the same per-value update as the
                // flat runs.
                let blocks = cols / LANES;
                for b in 0..blocks {
                    let steps: [f32; LANES] = std::array::from_fn(|l| {
                        if b * LANES + l < split {
                            c.step_a
                        } else {
                            c.step_b
                        }
                    });
                    let r = b * LANES..(b + 1) * LANES;
                    adam_lanes(
                        &mut pg[r.clone()],
                        &gg[r.clone()],
                        &mut mg[r.clone()],
                        &mut vg[r],
                        &steps,
                        c,
                    );
                }
                for k in blocks * LANES..cols {
                    let step = if k < split { c.step_a } else { c.step_b };
                    pg[k] = adam_elem(pg[k], gg[k], &mut mg[k], &mut vg[k], step, c);
                }
            }
        }
    }
}

augsplat_core::multiversion!(fn update_chunk(
    p: &mut [f32],
    g: &[f32],
    m: &mut [f32],
    v: &mut [f32],
    visible: &[bool],
    w: usize,
    c: &StepConst,
) => update_chunk_body);

/// The update kernel of one group: element-wise, only for visible Gaussians, in parallel
/// over fixed chunks of Gaussians (every value is written by one task: deterministic).
fn update_group(p: &mut [f32], g: &[f32], st: &mut Moments, visible: &[bool], c: StepConst) {
    let w = st.width;
    debug_assert_eq!(p.len(), visible.len() * w);
    debug_assert_eq!(g.len(), p.len());
    p.par_chunks_mut(CHUNK * w)
        .zip(g.par_chunks(CHUNK * w))
        .zip(st.m.par_chunks_mut(CHUNK * w))
        .zip(st.v.par_chunks_mut(CHUNK * w))
        .zip(visible.par_chunks(CHUNK))
        .for_each(|((((pc, gc), mc), vc), vis)| update_chunk(pc, gc, mc, vc, vis, w, &c));
}

/// Which Gaussians an Adam step updates.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
pub enum AdamUpdates {
    /// Every Gaussian (torch's Adam, as gsplat `simple_trainer` uses it by default,
    /// `visible_adam=False`): one that is not visible in the step still moves by its decaying
    /// momentum. The default: on the parity case (`tests/gsplat_parity.rs`) it is what makes
    /// augsplat's curve follow an independent gsplat trainer's from the first steps.
    #[default]
    Dense,
    /// Only the Gaussians visible in the step's renders (gsplat's `SelectiveAdam`,
    /// `visible_adam=True`): the others keep their parameters and moments. augsplat's
    /// behaviour before `OptimizeSplats` version 6; 0.9 dB behind at step 100 and 1.7 dB at
    /// step 1,000 on the parity case.
    Selective,
}

impl AdamUpdates {
    /// Whether this is the default (left out of serialised args).
    pub fn is_dense(&self) -> bool {
        *self == AdamUpdates::Dense
    }
}

/// Which parameter group a rate or a reset refers to.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Group {
    /// Means.
    Means,
    /// Log-scales.
    Scales,
    /// Quaternions.
    Quats,
    /// Opacity logits.
    Opacities,
    /// All SH coefficients (DC and higher).
    Sh,
}

/// Adam state for a [`Gaussians`] set.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Adam {
    means: Moments,
    scales: Moments,
    quats: Moments,
    opacities: Moments,
    sh: Moments,
    /// Steps taken per group (groups can be reset independently).
    steps: [u64; 5],
    n: usize,
    /// Leading SH values per Gaussian whose moments may be non-zero (the others are all
    /// zero: never updated since the state was created or cleared).
    sh_touched: usize,
}

impl Adam {
    /// Fresh state for `n` Gaussians with `coeffs` SH coefficients per channel.
    pub fn new(n: usize, coeffs: usize) -> Self {
        let mut a = Adam {
            means: Moments::new(3),
            scales: Moments::new(3),
            quats: Moments::new(4),
            opacities: Moments::new(1),
            sh: Moments::new(3 * coeffs),
            steps: [0; 5],
            n: 0,
            sh_touched: 0,
        };
        a.append_zeros(n);
        a
    }

    /// Number of Gaussians tracked.
    pub fn len(&self) -> usize {
        self.n
    }
    /// Whether no Gaussians are tracked.
    pub fn is_empty(&self) -> bool {
        self.n == 0
    }
    /// Steps taken by `group` since its last reset.
    pub fn steps(&self, group: Group) -> u64 {
        self.steps[group as usize]
    }

    fn groups_mut(&mut self) -> [&mut Moments; 5] {
        [
            &mut self.means,
            &mut self.scales,
            &mut self.quats,
            &mut self.opacities,
            &mut self.sh,
        ]
    }

    /// Appends the whole state to a checkpoint.
    pub fn write_state(&self, w: &mut augsplat_core::state::StateWriter) {
        w.tag("adam");
        w.u64(self.n as u64);
        w.u64(self.sh_touched as u64);
        for s in self.steps {
            w.u64(s);
        }
        for g in [
            &self.means,
            &self.scales,
            &self.quats,
            &self.opacities,
            &self.sh,
        ] {
            w.u64(g.width as u64);
            w.f32s(&g.m);
            w.f32s(&g.v);
        }
    }

    /// The state [`Adam::write_state`] wrote.
    pub fn read_state(
        r: &mut augsplat_core::state::StateReader<'_>,
    ) -> Result<Adam, augsplat_core::state::StateError> {
        use augsplat_core::state::StateError;
        r.tag("adam")?;
        let n = r.u64()? as usize;
        let sh_touched = r.u64()? as usize;
        let mut steps = [0u64; 5];
        for s in &mut steps {
            *s = r.u64()?;
        }
        let mut groups = Vec::with_capacity(5);
        for _ in 0..5 {
            let width = r.u64()? as usize;
            let m = r.f32s()?;
            let v = r.f32s()?;
            if m.len() != n * width || v.len() != n * width {
                return Err(StateError(format!(
                    "Adam moments of {} values for {n} Gaussians of width {width}",
                    m.len()
                )));
            }
            groups.push(Moments { m, v, width });
        }
        let mut it = groups.into_iter();
        let mut next = || it.next().expect("five groups");
        Ok(Adam {
            means: next(),
            scales: next(),
            quats: next(),
            opacities: next(),
            sh: next(),
            steps,
            n,
            sh_touched,
        })
    }

    /// Keeps the moments of the Gaussians with `keep[i]`, in order (densification pruning).
    pub fn retain(&mut self, keep: &[bool]) {
        assert_eq!(
            keep.len(),
            self.n,
            "Adam::retain: mask length differs from the state"
        );
        for g in self.groups_mut() {
            g.retain(keep);
        }
        self.n = keep.iter().filter(|&&k| k).count();
    }
    /// Appends zero moments for `count` new Gaussians (clones and split children).
    pub fn append_zeros(&mut self, count: usize) {
        self.n += count;
        let n = self.n;
        for g in self.groups_mut() {
            g.resize(n);
        }
    }
    /// Resizes every group to `n` Gaussians (zero moments for new ones), for a state whose
    /// values are then overwritten (the GPU trainer's download after densifying there).
    pub(crate) fn set_len(&mut self, n: usize) {
        self.n = n;
        for g in self.groups_mut() {
            g.resize(n);
        }
    }

    /// Zeroes the moments of one group (e.g. after an opacity reset). The group's step
    /// counter is kept, as gsplat does.
    pub fn clear_group(&mut self, group: Group) {
        self.groups_mut()[group as usize].clear();
        if group == Group::Sh {
            self.sh_touched = 0;
        }
    }
    /// Zeroes every moment and step counter (a fresh optimiser, e.g. at a Staged switch).
    pub fn clear(&mut self) {
        for g in self.groups_mut() {
            g.clear();
        }
        self.steps = [0; 5];
        self.sh_touched = 0;
    }
    /// The first and second moments of group `group` (flat, Gaussian-major), for tests.
    pub fn moments(&self, group: Group) -> (&[f32], &[f32]) {
        let g = [
            &self.means,
            &self.scales,
            &self.quats,
            &self.opacities,
            &self.sh,
        ][group as usize];
        (&g.m, &g.v)
    }

    /// One Adam step over every group. `means_lr` is the already-scheduled rate of the means
    /// (see [`LearningRates::means_at`]); the other rates come from `lr`. Only Gaussians with
    /// `grads.visible[i]` change. SH values beyond `grads.sh_active` (whose gradients are
    /// promised zero) are skipped while their moments are zero, see [`ParamGrads::sh_active`].
    /// With `eps = 0` such values would be `0/0` in torch; here they stay unchanged.
    ///
    /// Panics if the gradient, parameter and state sizes disagree (a programming error).
    pub fn step(
        &mut self,
        g: &mut Gaussians,
        grads: &ParamGrads,
        lr: &LearningRates,
        means_lr: f64,
    ) {
        let n = g.len();
        assert_eq!(
            self.n, n,
            "Adam state tracks {} Gaussians, parameters have {n}",
            self.n
        );
        assert_eq!(
            grads.len(),
            n,
            "gradients for {} Gaussians, parameters have {n}",
            grads.len()
        );
        assert_eq!(grads.visible.len(), n);
        assert_eq!(grads.sh.len(), g.sh.len());
        assert_eq!(
            self.sh.width * n,
            g.sh.len(),
            "Adam SH state width differs from the set"
        );
        let c = self.next_consts(grads.sh_active, lr, means_lr);
        let vis = &grads.visible;
        update_group(
            g.means.as_flattened_mut(),
            grads.means.as_flattened(),
            &mut self.means,
            vis,
            c[0],
        );
        update_group(
            g.log_scales.as_flattened_mut(),
            grads.log_scales.as_flattened(),
            &mut self.scales,
            vis,
            c[1],
        );
        update_group(
            g.quats.as_flattened_mut(),
            grads.quats.as_flattened(),
            &mut self.quats,
            vis,
            c[2],
        );
        update_group(
            &mut g.opacity_logits,
            &grads.opacity_logits,
            &mut self.opacities,
            vis,
            c[3],
        );
        update_group(&mut g.sh, &grads.sh, &mut self.sh, vis, c[4]);
    }

    /// Counts one more step of every group and returns each group's constants for it (the
    /// means, scales, quaternions, opacities and SH, in that order): the bias-corrected step
    /// sizes in f64 rounded to f32, and for the SH the leading values to update (see
    /// [`ParamGrads::sh_active`]). [`Adam::step`] and the GPU's Adam use these same numbers.
    fn next_consts(
        &mut self,
        sh_active: usize,
        lr: &LearningRates,
        means_lr: f64,
    ) -> [StepConst; 5] {
        let (b1, b2) = (lr.beta1, lr.beta2);
        let steps = &mut self.steps;
        let mut konst = |idx: usize, lr_a: f64, lr_b: f64, split: usize| {
            steps[idx] += 1;
            let t = steps[idx] as i32;
            let bc1 = 1.0 - b1.powi(t);
            let bc2 = 1.0 - b2.powi(t);
            StepConst {
                step_a: (lr_a / bc1) as f32,
                step_b: (lr_b / bc1) as f32,
                split,
                cols: usize::MAX,
                b1: b1 as f32,
                b2: b2 as f32,
                inv_sqrt_bc2: (1.0 / bc2.sqrt()) as f32,
                eps: lr.eps as f32,
            }
        };
        let c0 = konst(0, means_lr, means_lr, 3);
        let c1 = konst(1, lr.scales, lr.scales, 3);
        let c2 = konst(2, lr.quats, lr.quats, 4);
        let c3 = konst(3, lr.opacities, lr.opacities, 1);
        let c4 = konst(4, lr.sh0, lr.shn, 3);
        let cols = sh_active.max(self.sh_touched).min(self.sh.width);
        self.sh_touched = cols;
        [c0, c1, c2, c3, StepConst { cols, ..c4 }]
    }

    /// One step's constants for the GPU's Adam (`adam.wgsl`), per group in the order of
    /// [`Adam::next_consts`]: counts the step as [`Adam::step`] does; the moments are then
    /// updated on the GPU (see [`Adam::moments_mut`] to bring them back).
    pub(crate) fn next_gpu_consts(
        &mut self,
        sh_active: usize,
        lr: &LearningRates,
        means_lr: f64,
    ) -> [GpuStepConst; 5] {
        let widths = self.widths();
        let c = self.next_consts(sh_active, lr, means_lr);
        std::array::from_fn(|k| GpuStepConst {
            width: widths[k],
            step_a: c[k].step_a,
            step_b: c[k].step_b,
            split: c[k].split.min(widths[k]),
            cols: c[k].cols.min(widths[k]),
            b1: c[k].b1,
            b2: c[k].b2,
            inv_sqrt_bc2: c[k].inv_sqrt_bc2,
            eps: c[k].eps,
        })
    }

    /// Values per Gaussian of each group (means, scales, quaternions, opacities, SH).
    pub(crate) fn widths(&self) -> [usize; 5] {
        [
            self.means.width,
            self.scales.width,
            self.quats.width,
            self.opacities.width,
            self.sh.width,
        ]
    }

    /// The first and second moments of one group, writable (the GPU trainer copies its
    /// moments back here).
    pub(crate) fn moments_mut(&mut self, group: Group) -> (&mut Vec<f32>, &mut Vec<f32>) {
        let m = match group {
            Group::Means => &mut self.means,
            Group::Scales => &mut self.scales,
            Group::Quats => &mut self.quats,
            Group::Opacities => &mut self.opacities,
            Group::Sh => &mut self.sh,
        };
        (&mut m.m, &mut m.v)
    }
}

/// One group's constants of one Adam step, for the GPU kernel (`adam.wgsl`).
#[derive(Clone, Copy, Debug)]
pub(crate) struct GpuStepConst {
    /// Values per Gaussian.
    pub width: usize,
    /// lr / (1 − β1ᵗ) for the first `split` values of a Gaussian.
    pub step_a: f32,
    /// Same for the values from `split` on.
    pub step_b: f32,
    /// See `step_a`.
    pub split: usize,
    /// Leading values of each Gaussian to update.
    pub cols: usize,
    /// β1.
    pub b1: f32,
    /// β2.
    pub b2: f32,
    /// 1 / √(1 − β2ᵗ).
    pub inv_sqrt_bc2: f32,
    /// ε.
    pub eps: f32,
}

pub(crate) mod gpu;
#[cfg(test)]
mod tests;
