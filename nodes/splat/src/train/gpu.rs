//! The training step on the GPU: the Gaussians, Adam's moments, the step's gradient sums and
//! the densification statistics live in GPU buffers from one step to the next, so a step
//! sends nothing to the GPU but its camera and (for a loss computed on the host) one colour
//! gradient, and reads back only the loss and the pair counts, once per view, without waiting
//! for them ([`GpuTrainer::read_later`]): the training device collects them while the GPU
//! runs the next step.
//!
//! Per view ([`GpuTrainer::add_view`]): the forward kernels, the loss and its colour
//! gradient, the compositing backward, the projection backward, then `accumulate.wgsl` adds
//! the view's gradients to the step's sums (and the densification statistic to its sums) —
//! views one after another, so every sum has the CPU trainer's order. A view's forward pass
//! is sized from the view's last pair count (its first pass counts first: one more wait); a
//! pass whose pairs outgrew the slots adds nothing (the accumulation checks the count on the
//! device) and runs again, counted first, so the bytes never depend on the sizing. The flag is
//! sticky: the clears, sums and Adam updates of the steps recorded behind an overflowed one
//! change nothing until the host, a step later, has run them again. Per step
//! ([`GpuTrainer::adam_step`]): `adam/adam.wgsl` once per parameter group, with the constants
//! the CPU's `Adam` computes. Densification, every opacity reset (`Periodic`, `KeepVisible`,
//! and Staged's and Dual's at a switch) run on the device too (`densify/gpu.rs`, one wait per
//! refinement, none per reset). The trainer brings the state back to the host
//! ([`GpuTrainer::download`]) only where the CPU must see it: checkpoints, the end of the run,
//! and a set too wide for the device's densification; after the host changed it, it uploads
//! a new state.

use crate::adam::{Adam, GpuStepConst, Group};
use crate::backward::gpu::{
    pair_buffer, record_backward, record_vjp, PARAM_GRAD_STRIDE, SCREEN_GRAD_STRIDE,
};
use crate::densify::Densifier;
use crate::forward::gpu::{forward_pass_in, tile_grid, GpuScene, IMAGE_STRIDE};
use crate::gpu::{f32_words, GpuBuffer, GpuContext, GpuError, ReadTicket};
use crate::loss::gpu::{record_loss, GpuLoss, TargetBuffer};
use crate::render::{Cutoff, RenderSettings};
use crate::Gaussians;
use augsplat_core::Camera;

/// The parameter groups in the order of Adam's constants.
const GROUPS: [Group; 5] = [
    Group::Means,
    Group::Scales,
    Group::Quats,
    Group::Opacities,
    Group::Sh,
];

/// The index of the opacities in [`GROUPS`].
pub(crate) const OPACITY_GROUP: usize = 3;

/// Values per Gaussian of each group's moments, in the order of [`GROUPS`], for `coeffs` SH
/// coefficients per channel (as [`Adam::new`] lays them out).
pub(crate) fn moment_widths(coeffs: u32) -> [u32; 5] {
    [3, 3, 4, 1, 3 * coeffs]
}

/// How a view's loss and colour gradient are computed.
pub enum ViewLoss<'a> {
    /// On the host: the rendered colour (`H·W·3`) is read back, the closure writes
    /// `scale · dL/d(rgb)` into the zeroed buffer it gets and returns the loss; the gradient
    /// is sent to the GPU. `mask`: the view's pixel mask ([`crate::gpu::upload_mask`]).
    Host {
        /// The loss.
        loss: &'a mut dyn FnMut(&[f32], &mut [f32]) -> f64,
        /// The view's pixel mask, when it has one.
        mask: Option<&'a wgpu::Buffer>,
    },
    /// On the GPU (`loss/loss.wgsl`): the view's target, uploaded once, and its loss;
    /// `scale` multiplies the gradient.
    Gpu {
        /// The target colour (and weights).
        target: &'a GpuTarget,
        /// The loss.
        loss: GpuLoss,
        /// The gradient's factor.
        scale: f32,
    },
}

/// A view's target colour (`H·W·3`) and optional per-pixel weights (`H·W`) on the GPU. A
/// colour whose every value is a decoded byte's (`k / 255`, a photo as loaded) is kept as
/// bytes, a quarter of the memory, and read back to the same f32 values; any other (a
/// resized photo, a radiance field's render) and the weights stay f32.
pub struct GpuTarget {
    rgb: GpuBuffer,
    /// Whether `rgb` holds bytes ([`crate::loss::gpu::pack_u8`]).
    bytes: bool,
    weights: Option<GpuBuffer>,
    /// The pixel mask (`skip_below`), one word per pixel.
    mask: Option<GpuBuffer>,
}

impl GpuTarget {
    /// Whether the colour is kept as bytes.
    #[cfg(test)]
    pub(crate) fn is_bytes(&self) -> bool {
        self.bytes
    }

    /// Uploads a target: colour (`H·W·3`), optional weights (`H·W`) and optional pixel mask
    /// (`H·W`; ignored when it holds another number of values, as on the CPU).
    pub fn upload(
        ctx: &GpuContext,
        rgb: &[f32],
        weights: Option<&[f32]>,
        mask: Option<&[u8]>,
    ) -> Result<GpuTarget, GpuError> {
        Self::upload_as(ctx, rgb, weights, mask, true)
    }

    /// [`GpuTarget::upload`], keeping the colour as f32 unless `bytes_allowed`.
    pub(crate) fn upload_as(
        ctx: &GpuContext,
        rgb: &[f32],
        weights: Option<&[f32]>,
        mask: Option<&[u8]>,
        bytes_allowed: bool,
    ) -> Result<GpuTarget, GpuError> {
        ctx.scoped(|| {
            let pixels = rgb.len() / 3;
            let packed = bytes_allowed
                .then(|| crate::loss::gpu::pack_u8(rgb))
                .flatten();
            Ok(GpuTarget {
                bytes: packed.is_some(),
                rgb: match packed {
                    Some(words) => ctx.storage_init("target colour (bytes)", &words)?,
                    None => ctx.storage_init("target colour", &f32_words(rgb.iter().copied()))?,
                },
                weights: match weights {
                    Some(w) => {
                        Some(ctx.storage_init("target weights", &f32_words(w.iter().copied()))?)
                    }
                    None => None,
                },
                mask: crate::gpu::upload_mask(ctx, pixels, mask)?,
            })
        })
    }
}

/// What [`GpuTrainer::add_view`] did.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ViewResult {
    /// The view's loss (without the gradient's factor).
    pub loss: f64,
    /// The composited (Gaussian, pixel) pairs, as the CPU renderer counts them.
    pub pairs: u64,
    /// The (tile, Gaussian) pairs of the forward pass (the slots a later pass of this view
    /// needs, about).
    pub tile_pairs: u32,
    /// The pass had fewer slots than pairs: the view added nothing to the step.
    pub overflowed: bool,
}

/// A view recorded by [`GpuTrainer::add_view`] whose loss and counts are still on the device.
pub struct PendingView {
    /// The loss's partial sums (a loss on the GPU).
    sums: Option<crate::loss::gpu::LossSums>,
    /// The loss computed on the host.
    host_loss: f64,
    /// The composited pairs' per-block sums, and the number of blocks.
    pair_partials: Option<(GpuBuffer, usize)>,
    /// The forward pass's offsets, whose entry at the index holds the pair count.
    counts: Option<(GpuBuffer, u64)>,
    /// The forward pass's slots (its pairs, when it counted them first).
    pub(crate) slots: u32,
    /// A pass known to have overflowed (a loss on the host reads the count first), with its
    /// pair count.
    known_overflow: Option<u32>,
}

impl PendingView {
    fn overflowed(tile_pairs: u32) -> PendingView {
        PendingView {
            sums: None,
            host_loss: 0.0,
            pair_partials: None,
            counts: None,
            slots: 0,
            known_overflow: Some(tile_pairs),
        }
    }

    /// What to read back: the loss's partial sums, the pair partials, the pair count.
    fn parts(&self) -> Vec<(&wgpu::Buffer, u64, usize)> {
        let mut parts = self.sums.as_ref().map(|s| s.parts()).unwrap_or_default();
        if let Some((b, blocks)) = &self.pair_partials {
            parts.push((b, 0, *blocks));
        }
        if let Some((b, at)) = &self.counts {
            parts.push((b, *at, 1));
        }
        parts
    }

    /// The result from the words of [`Self::parts`]; an error when a tile of the view passed
    /// the adapter's loop cap ([`crate::forward::gpu::TILES_PAST_LOOP_CAP`]).
    fn result(
        &self,
        adapter: &augsplat_render::gpu::AdapterSummary,
        words: &[Vec<u32>],
    ) -> Result<ViewResult, GpuError> {
        if let Some(count) = self.known_overflow {
            return Ok(ViewResult {
                loss: 0.0,
                pairs: 0,
                tile_pairs: count,
                overflowed: true,
            });
        }
        let k = words.len();
        let count = words[k - 1][0];
        if count == crate::forward::gpu::TILES_PAST_LOOP_CAP {
            return Err(crate::forward::gpu::past_loop_cap_error(adapter));
        }
        let pairs = words[k - 2].iter().map(|&w| u64::from(w)).sum();
        let loss = match &self.sums {
            Some(sums) => sums.terms_from(&words[..k - 2]).0,
            None => self.host_loss,
        };
        Ok(ViewResult {
            loss,
            pairs,
            tile_pairs: count,
            overflowed: count > self.slots,
        })
    }
}

/// A training state on the GPU (see the module docs).
pub struct GpuTrainer {
    pub(crate) scene: GpuScene,
    /// First and second moments per group, in the order of [`GROUPS`].
    pub(crate) moments: Vec<(GpuBuffer, GpuBuffer)>,
    /// The step's summed gradients: `PARAM_GRAD_STRIDE` per Gaussian.
    pub(crate) acc_grads: GpuBuffer,
    /// The step's summed SH gradients, in the parameters' layout.
    pub(crate) acc_sh: GpuBuffer,
    /// Per Gaussian: visible in any of the step's views (1) or not (0).
    pub(crate) acc_visible: GpuBuffer,
    /// The step's overflow flag: set when a view's pairs outgrew its forward pass's slots;
    /// while it is set, views add nothing.
    overflow: GpuBuffer,
    /// The densification statistic's sums and counts.
    pub(crate) grad2d: GpuBuffer,
    pub(crate) count: GpuBuffer,
    /// The per-view sums and pair counts (`accumulate.wgsl`), compiled on the context once.
    kernels: std::sync::Arc<Kernels>,
    /// Adam (`adam.wgsl`), compiled on the context once.
    adam: std::sync::Arc<crate::adam::gpu::Kernels>,
}

impl GpuTrainer {
    /// Uploads the Gaussians, Adam's moments and the densification statistics.
    pub fn upload(
        ctx: &GpuContext,
        g: &Gaussians,
        adam: &Adam,
        stats: &Densifier,
    ) -> Result<GpuTrainer, GpuError> {
        let n = g.len();
        if adam.len() != n || stats.grad2d.len() != n || stats.count.len() != n {
            return Err(GpuError::Invalid(format!(
                "{n} Gaussians, moments for {}, statistics for {}",
                adam.len(),
                stats.grad2d.len()
            )));
        }
        let scene = GpuScene::upload(ctx, g)?;
        let kernels = ctx.kernels_of(Kernels::new)?;
        let adam_kernels = ctx.kernels_of(crate::adam::gpu::Kernels::new)?;
        ctx.scoped(|| {
            let mut moments = Vec::with_capacity(GROUPS.len());
            for group in GROUPS {
                let (m, v) = adam.moments(group);
                moments.push((
                    ctx.storage_items_init("Adam first moments", &f32_words(m.iter().copied()))?,
                    ctx.storage_items_init("Adam second moments", &f32_words(v.iter().copied()))?,
                ));
            }
            let nn = n as u64;
            Ok(GpuTrainer {
                acc_grads: ctx
                    .storage_items("step gradients", 4 * PARAM_GRAD_STRIDE as u64 * nn)?,
                acc_sh: ctx
                    .storage_items("step SH gradients", 4 * 3 * u64::from(scene.coeffs) * nn)?,
                acc_visible: ctx.storage_items("step visibility", 4 * nn)?,
                grad2d: ctx.storage_items_init(
                    "densification sums",
                    &f32_words(stats.grad2d.iter().copied()),
                )?,
                count: ctx.storage_items_init("densification counts", &stats.count)?,
                overflow: ctx.storage("step overflow flag", 4)?,
                moments,
                scene,
                kernels,
                adam: adam_kernels,
            })
        })
    }

    /// Number of Gaussians.
    pub fn len(&self) -> usize {
        self.scene.len()
    }

    /// The current Gaussians, to render from.
    pub fn scene(&self) -> &GpuScene {
        &self.scene
    }

    /// Copies the state back into the host's Gaussians, moments and statistics, which must
    /// have this state's sizes.
    pub fn download(
        &self,
        ctx: &GpuContext,
        g: &mut Gaussians,
        adam: &mut Adam,
        stats: &mut Densifier,
    ) -> Result<(), GpuError> {
        let n = self.len();
        let k = self.scene.coeffs as usize;
        if g.coeffs() != k {
            return Err(GpuError::Invalid(format!(
                "the host holds Gaussians with {} SH coefficients, the GPU {k}",
                g.coeffs()
            )));
        }
        // Densification on the GPU changes the count: the host's arrays follow.
        g.means.resize(n, [0.0; 3]);
        g.log_scales.resize(n, [0.0; 3]);
        g.quats.resize(n, [0.0; 4]);
        adam.set_len(n);
        let floats = |buf: &wgpu::Buffer, len: usize| -> Result<Vec<f32>, GpuError> {
            Ok(ctx
                .read_words(buf, len)?
                .into_iter()
                .map(f32::from_bits)
                .collect())
        };
        let sc = &self.scene;
        copy_rows(&floats(&sc.means, 3 * n)?, &mut g.means);
        copy_rows(&floats(&sc.scales, 3 * n)?, &mut g.log_scales);
        copy_rows(&floats(&sc.quats, 4 * n)?, &mut g.quats);
        g.opacity_logits = floats(&sc.logits, n)?;
        g.sh = floats(&sc.sh, 3 * k * n)?;
        let widths = adam.widths();
        for ((group, (m, v)), w) in GROUPS.iter().zip(&self.moments).zip(widths) {
            let (hm, hv) = adam.moments_mut(*group);
            *hm = floats(m, w * n)?;
            *hv = floats(v, w * n)?;
        }
        stats.grad2d = floats(&self.grad2d, n)?;
        stats.count = ctx.read_words(&self.count, n)?;
        Ok(())
    }

    /// Clears the step's overflow flag (before its views run again from an overflowed one).
    pub fn clear_overflow(&self, ctx: &GpuContext) -> Result<(), GpuError> {
        let mut enc = ctx.encoder();
        enc.clear_buffer(&self.overflow, 0, None);
        ctx.defer(enc)
    }

    /// Clears the step's gradient sums and visibility (before the step's first view), on the
    /// device unless the overflow flag is set: a step recorded behind one whose views are
    /// incomplete leaves that step's sums alone (the flag stays set until
    /// [`GpuTrainer::clear_overflow`]).
    pub fn begin_step(&self, ctx: &GpuContext) -> Result<(), GpuError> {
        ctx.scoped(|| {
            let mut enc = ctx.encoder();
            let n = self.scene.n;
            for (buf, width) in [
                (&self.acc_grads, PARAM_GRAD_STRIDE as u32),
                (&self.acc_sh, 3 * self.scene.coeffs),
                (&self.acc_visible, 1),
            ] {
                ctx.dispatch_items(
                    &mut enc,
                    &self.kernels.clear_sums,
                    (&[n, width, 0, 0, 0, 0, 0, 0], 0),
                    &[(16, buf, u64::from(width)), (13, &self.overflow, 0)],
                    n,
                    width,
                )?;
            }
            ctx.defer(enc)
        })
    }

    /// Renders the current Gaussians from `cam`, computes the view's loss, back-propagates it
    /// and adds the view's gradients to the step's sums; with `stats = Some(factor)` also adds
    /// the densification statistic (the screen-space mean gradient × `factor`, as
    /// `Densifier::accumulate_scaled`). `sh_active` is the number of leading SH values per
    /// Gaussian whose gradient may be non-zero. With `slots`, the forward pass has that many
    /// (tile, Gaussian) pair slots and nothing waits (a loss on the host waits for the
    /// image); the loss and the counts stay on the device until [`GpuTrainer::finish`]. A
    /// pass whose pairs exceed its slots sets the step's overflow flag: from then on no view
    /// of the step adds anything ([`ViewResult::overflowed`]), and the caller runs the views
    /// from the first overflowed one again, in order, with enough slots.
    #[allow(clippy::too_many_arguments)]
    pub fn add_view(
        &self,
        ctx: &GpuContext,
        cam: &Camera,
        s: &RenderSettings,
        loss: ViewLoss<'_>,
        stats: Option<f32>,
        sh_active: usize,
        slots: Option<u32>,
    ) -> Result<PendingView, GpuError> {
        let grid = tile_grid(cam)?;
        ctx.scoped(|| {
            let sc = &self.scene;
            let n = sc.n;
            let nn = u64::from(n);
            let sh_width = 3 * sc.coeffs;
            let mask = match &loss {
                ViewLoss::Gpu { target, .. } => target.mask.as_deref(),
                ViewLoss::Host { mask, .. } => *mask,
            };
            let st = forward_pass_in(ctx, sc, cam, s, grid, Cutoff::Hard, mask, slots)?;
            let (count_buf, count_at) = st.pair_count_at();
            let px = cam.width as usize * cam.height as usize;
            let mut enc = ctx.encoder();
            let (host_value, sums, d_rgb) = match loss {
                ViewLoss::Host { loss: f, .. } => {
                    let read = ctx.encoder();
                    let mut words = ctx.read_after(
                        read,
                        &[(&st.image, 0, IMAGE_STRIDE * px), (count_buf, count_at, 1)],
                    )?;
                    let count = words[1][0];
                    st.check_count(ctx, count)?;
                    if st.overflowed_in(count) {
                        // Nothing more of this view: the flag stops the step's later views.
                        let mut flag = ctx.encoder();
                        self.record_flag(ctx, &mut flag, &st)?;
                        ctx.defer(flag)?;
                        return Ok(PendingView::overflowed(count));
                    }
                    let img = words.swap_remove(0);
                    let rgb: Vec<f32> = img
                        .chunks_exact(IMAGE_STRIDE)
                        .flat_map(|p| p[..3].iter().map(|w| f32::from_bits(*w)))
                        .collect();
                    let mut grad = vec![0.0f32; rgb.len()];
                    let value = f(&rgb, &mut grad);
                    let d_rgb = ctx.storage_init("colour gradients", &f32_words(grad))?;
                    (value, None, d_rgb)
                }
                ViewLoss::Gpu {
                    target,
                    loss,
                    scale,
                } => {
                    let d_rgb = ctx.storage("colour gradients", 4 * 3 * px as u64)?;
                    let sums = record_loss(
                        ctx,
                        &mut enc,
                        &st.image,
                        IMAGE_STRIDE as u32,
                        TargetBuffer {
                            buf: &target.rgb,
                            bytes: target.bytes,
                        },
                        target.weights.as_deref(),
                        cam.width,
                        cam.height,
                        loss,
                        scale,
                        &d_rgb,
                    )?;
                    (0.0, Some(sums), d_rgb)
                }
            };
            let screen =
                ctx.storage_split("screen-space gradients", nn, SCREEN_GRAD_STRIDE as u64, 2)?;
            let view_grads =
                ctx.storage_items("view gradients", 4 * PARAM_GRAD_STRIDE as u64 * nn)?;
            let view_sh = ctx.storage_items("view SH gradients", 4 * u64::from(sh_width) * nn)?;
            let pair_grads = pair_buffer(ctx, &st)?;
            record_backward(ctx, &mut enc, &st, grid, &d_rgb, &screen, n, &pair_grads);
            record_vjp(ctx, &mut enc, sc, cam, s, &screen, (&view_grads, &view_sh))?;
            let sw = u64::from(sh_width);
            self.record_flag(ctx, &mut enc, &st)?;
            ctx.dispatch_items(
                &mut enc,
                &self.kernels.accumulate,
                (
                    &[
                        n,
                        sh_width,
                        (sh_active as u32).min(sh_width),
                        u32::from(stats.is_some()),
                        (0.5 * cam.width as f32).to_bits(),
                        (0.5 * cam.height as f32).to_bits(),
                        stats.unwrap_or(1.0).to_bits(),
                        0,
                    ],
                    0,
                ),
                &[
                    (1, &view_grads, PARAM_GRAD_STRIDE as u64),
                    (2, &view_sh, sw),
                    (3, &screen, SCREEN_GRAD_STRIDE as u64),
                    (4, &st.rects, 4),
                    (5, &self.acc_grads, PARAM_GRAD_STRIDE as u64),
                    (6, &self.acc_sh, sw),
                    (7, &self.acc_visible, 1),
                    (8, &self.grad2d, 1),
                    (9, &self.count, 1),
                    (13, &self.overflow, 0),
                ],
                n,
                1,
            )?;
            // The composited pairs, as the CPU renderer counts them: per-block sums on the
            // GPU, added here.
            let blocks = px.div_ceil(256);
            let pair_partials = ctx.storage("composited pairs per block", 4 * blocks as u64)?;
            let pair_consts =
                ctx.uniform("pair count constants", &[px as u32, blocks as u32, 0, 0]);
            ctx.dispatch(
                &mut enc,
                &self.kernels.count_pairs,
                &[(10, &pair_consts), (11, &st.info), (12, &pair_partials)],
                ctx.groups(blocks as u32),
            );
            ctx.defer(enc)?;
            let (counts, count_at) = (st.counts, u64::from(st.gaussians));
            Ok(PendingView {
                sums,
                host_loss: host_value,
                pair_partials: Some((pair_partials, blocks)),
                counts: Some((counts, count_at)),
                slots: st.pairs,
                known_overflow: None,
            })
        })
    }

    /// Records the check of `st`'s pair count against its slots into the step's overflow
    /// flag (`flag_overflow` in `accumulate.wgsl`).
    fn record_flag(
        &self,
        ctx: &GpuContext,
        enc: &mut augsplat_render::gpu::Encoder,
        st: &crate::forward::gpu::ForwardState,
    ) -> Result<(), GpuError> {
        let (counts, count_at) = st.pair_count_at();
        let u = ctx.uniform("overflow check", &[count_at as u32, st.pairs, 0, 0]);
        ctx.dispatch(
            enc,
            &self.kernels.flag_overflow,
            &[(14, &u), (15, counts), (13, &self.overflow)],
            [1, 1],
        );
        Ok(())
    }

    /// The results of `views` (in order), in one read-back.
    pub fn finish(
        &self,
        ctx: &GpuContext,
        views: &[PendingView],
    ) -> Result<Vec<ViewResult>, GpuError> {
        let words = self.read_later(ctx, views)?.wait(ctx)?;
        Self::results(ctx.adapter(), views, &words)
    }

    /// Submits the copies of `views`' losses and counts without waiting: their results are
    /// [`GpuTrainer::results`] of the ticket's words.
    pub fn read_later(
        &self,
        ctx: &GpuContext,
        views: &[PendingView],
    ) -> Result<ReadTicket, GpuError> {
        let parts: Vec<_> = views.iter().flat_map(PendingView::parts).collect();
        let enc = ctx.encoder();
        ctx.read_later(enc, &parts)
    }

    /// The results of `views` (in order) from the words of their read-back on `adapter`; an
    /// error when a tile of one of them passed the adapter's loop cap.
    pub fn results(
        adapter: &augsplat_render::gpu::AdapterSummary,
        views: &[PendingView],
        words: &[Vec<u32>],
    ) -> Result<Vec<ViewResult>, GpuError> {
        let mut at = 0;
        views
            .iter()
            .map(|v| {
                let k = v.parts().len();
                let r = v.result(adapter, &words[at..at + k]);
                at += k;
                r
            })
            .collect()
    }

    /// One Adam step over every group with the step's summed gradients; `dense` updates
    /// every Gaussian, otherwise only those visible in one of the step's views.
    pub fn adam_step(
        &self,
        ctx: &GpuContext,
        consts: &[GpuStepConst; 5],
        dense: bool,
    ) -> Result<(), GpuError> {
        ctx.scoped(|| {
            let sc = &self.scene;
            let n = sc.n;
            let params = [&sc.means, &sc.scales, &sc.quats, &sc.logits, &sc.sh];
            // Where each group's gradient sits: (buffer, stride, offset).
            let grads = [
                (&self.acc_grads, PARAM_GRAD_STRIDE as u32, 0),
                (&self.acc_grads, PARAM_GRAD_STRIDE as u32, 3),
                (&self.acc_grads, PARAM_GRAD_STRIDE as u32, 6),
                (&self.acc_grads, PARAM_GRAD_STRIDE as u32, 10),
                (&self.acc_sh, 3 * sc.coeffs, 0),
            ];
            let mut enc = ctx.encoder();
            for (k, c) in consts.iter().enumerate() {
                let (gbuf, stride, offset) = grads[k];
                let width = c.width as u32;
                let words = [
                    n,
                    width,
                    stride,
                    offset,
                    c.split as u32,
                    c.cols as u32,
                    u32::from(dense),
                    0,
                    c.step_a.to_bits(),
                    c.step_b.to_bits(),
                    c.b1.to_bits(),
                    c.b2.to_bits(),
                    c.inv_sqrt_bc2.to_bits(),
                    c.eps.to_bits(),
                    0,
                    0,
                ];
                // The gradient buffer is bound per Gaussian (its stride) and read at
                // `offset` inside each Gaussian's values.
                let w = u64::from(width);
                ctx.dispatch_items(
                    &mut enc,
                    &self.adam.adam,
                    (&words, 0),
                    &[
                        (1, params[k], w),
                        (2, gbuf, u64::from(stride)),
                        (3, &self.moments[k].0, w),
                        (4, &self.moments[k].1, w),
                        (5, &self.acc_visible, 1),
                        (6, &self.overflow, 0),
                    ],
                    n,
                    width,
                )?;
            }
            // Kept for the next submission, with the next step's views.
            ctx.defer(enc)
        })
    }
}

/// Copies a flat slice into fixed-width rows.
fn copy_rows<const W: usize>(flat: &[f32], rows: &mut [[f32; W]]) {
    for (r, c) in rows.iter_mut().zip(flat.chunks_exact(W)) {
        r.copy_from_slice(c);
    }
}

/// The compiled kernels of the GPU's training state (`accumulate.wgsl`): a view's gradients
/// into the step's sums, and the composited pairs per block.
pub(crate) struct Kernels {
    accumulate: wgpu::ComputePipeline,
    count_pairs: wgpu::ComputePipeline,
    flag_overflow: wgpu::ComputePipeline,
    clear_sums: wgpu::ComputePipeline,
}

impl Kernels {
    pub(crate) fn new(m: crate::gpu::ModuleSetup<'_>) -> Kernels {
        let [accumulate, count_pairs, flag_overflow, clear_sums] = crate::gpu::pipelines(
            m,
            "accumulate.wgsl",
            include_str!("accumulate.wgsl"),
            ["accumulate", "count_pairs", "flag_overflow", "clear_sums"],
        );
        Kernels {
            accumulate,
            count_pairs,
            flag_overflow,
            clear_sums,
        }
    }
}
