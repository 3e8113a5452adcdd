//! Field training on the GPU: the CPU loop's twin ([`crate::train::train_resumable`]) with the
//! parameters, Adam's moments and the occupancy grid kept on the device.
//!
//! A step draws its rays on the host exactly as the CPU does (the same random streams, so the
//! same rays), uploads them, and waits once: for its sample count (the marching pass's prefix
//! sum), read together with the previous step's losses and verdict. That count is made a step
//! ahead, in a submission queued before the step that precedes it, so the host reads it while
//! the device runs that step (not across an occupancy refresh, which the count must follow);
//! Adam's bias corrections for both verdicts of the step still unread go with each step, and
//! the device picks the one that step's status calls for. Everything else — the
//! samples, both networks, the losses and their gradients, the guard and Adam — stays on the
//! device; a step whose gradient is not finite leaves the parameters alone there, as on the
//! CPU. The loop settles the last step (one more wait) only where it needs its numbers: at an
//! evaluation, a checkpoint and the end.

use super::render::{render_views_gpu, GpuFieldRef};
use super::*;
use crate::checkpoint::FieldLoop;
use crate::error::FieldError;
use crate::hashgrid::gpu::record_backward_fixed;
use crate::mlp::gpu::{record_mlp_backward, GpuMlp, InputGradOut};
use crate::occupancy::OccupancyGrid;
use crate::train::{
    draw_ray, learning_rate, occupancy_points, push_curve_point, save_checkpoint, start_or_resume,
    tally_step, Adam, FieldCheckpoints, StepReport, StepStats, TrainOptions, TrainState, ViewData,
    OCCUPANCY_CHUNK_CELLS,
};
use augsplat_core::Rng;

/// Words of a step's status (see `step.wgsl`).
const STATUS_WORDS: usize = 8;

/// The read of a pending step's status, if any.
fn status_part(pending: Option<&(u32, GpuBuffer, u32)>) -> Vec<(&wgpu::Buffer, u64, usize)> {
    pending
        .iter()
        .map(|(_, status, _)| (&**status, 0, STATUS_WORDS))
        .collect()
}

/// Cells per batch of an occupancy refresh on the GPU (16 of the CPU's chunks).
const OCCUPANCY_BATCH_CELLS: usize = 16 * OCCUPANCY_CHUNK_CELLS;

/// The rays of training step `step`, drawn as [`crate::train::train_step`] draws them (chunk
/// by chunk, each from its own stream: the rays, then their jitters), as ray records.
pub fn step_rays(views: &[ViewData], opts: &TrainOptions, step: u32) -> Vec<[f32; RAY_FLOATS]> {
    let chunk = opts.chunk_rays.max(1) as usize;
    let total = opts.rays_per_step.max(1) as usize;
    let mut out = Vec::with_capacity(total);
    for c in 0..total.div_ceil(chunk) {
        let mut rng = Rng::stream(opts.seed, ((step as u64) << 32) | c as u64);
        let count = chunk.min(total - c * chunk);
        let rays: Vec<_> = (0..count)
            .map(|_| draw_ray(views, &mut rng, opts))
            .collect();
        for tr in rays {
            let jitter = rng.next_f32();
            out.push(ray_record(&tr.ray, tr.target, tr.depth, jitter));
        }
    }
    out
}

/// A step's numbers once read: its statistics (loss sums over rays, not yet divided by the
/// ray count) and how many gradient values were not finite.
#[derive(Clone, Copy, Debug)]
pub struct Settled {
    /// The statistics.
    pub stats: StepStats,
    /// Non-finite gradient values (a level whose encoding gradient was not finite counts 1).
    pub nonfinite: u64,
}

/// The device-side state of a training run.
pub struct GpuTrainer<'a> {
    ctx: &'a GpuContext,
    field: &'a Field,
    params: GpuBuffer,
    adam_m: GpuBuffer,
    adam_v: GpuBuffer,
    /// Applied steps so far (Adam's `t`), as far as the host has read.
    adam_t: u32,
    ema: GpuBuffer,
    occupied: GpuBuffer,
    /// The last recorded step whose status is not read yet.
    pending: Option<(u32, GpuBuffer, u32)>,
    /// A step's rays, uploaded and counted while the step before ran ([`GpuTrainer::step`]).
    counted: Option<(u32, Counted)>,
    /// A status of zeros: the step before as Adam sees it when the host has counted it.
    no_previous: GpuBuffer,
}

/// A recorded step's device buffers that its callers may read.
pub struct StepBuffers {
    /// Samples of the step.
    pub n: u32,
    /// The parameter gradient.
    pub grad: GpuBuffer,
    /// Per-ray outputs ([`RAY_OUT_FLOATS`] each).
    pub ray_out: GpuBuffer,
    /// The step's status (see `step.wgsl`).
    pub status: GpuBuffer,
    /// Per hash level: the bits of its largest finite |encoding gradient| and a non-finite
    /// flag ([`crate::hashgrid::gpu::record_backward_fixed`]).
    pub levels: GpuBuffer,
}

impl<'a> GpuTrainer<'a> {
    /// Uploads a state and Adam's moments.
    pub fn new(
        ctx: &'a GpuContext,
        field: &'a Field,
        state: &TrainState,
        adam: &Adam,
    ) -> Result<GpuTrainer<'a>, GpuError> {
        let up = |what: &str, v: &[f32]| ctx.storage_init(what, &f32_words(v.iter().copied()));
        Ok(GpuTrainer {
            ctx,
            field,
            params: up("field parameters", &state.params)?,
            adam_m: up("adam m", &adam.m)?,
            adam_v: up("adam v", &adam.v)?,
            adam_t: adam.t,
            ema: up("occupancy ema", &state.occupancy.ema)?,
            occupied: ctx.storage_init("occupancy", &occupancy_words(&state.occupancy))?,
            pending: None,
            counted: None,
            no_previous: ctx.storage("no previous step status", 4 * STATUS_WORDS as u64)?,
        })
    }

    /// Records the passes of one step on `rays` up to the parameter gradient (no Adam) and
    /// returns its buffers; `before` is read in the same wait as the sample count.
    pub fn record_gradient(
        &self,
        rays: &[[f32; RAY_FLOATS]],
        opts: &TrainOptions,
        before: &[(&wgpu::Buffer, u64, usize)],
    ) -> Result<(StepBuffers, Vec<Vec<u32>>, augsplat_render::gpu::Encoder), GpuError> {
        let mut counted = count_samples(self.ctx, self.field, rays, &self.occupied, before)?;
        let earlier = std::mem::take(&mut counted.earlier);
        let (bufs, enc) = self.record_counted(counted, rays.len() as u32, opts)?;
        Ok((bufs, earlier, enc))
    }

    /// [`GpuTrainer::record_gradient`] of `n_rays` rays already counted.
    fn record_counted(
        &self,
        counted: Counted,
        n_rays: u32,
        opts: &TrainOptions,
    ) -> Result<(StepBuffers, augsplat_render::gpu::Encoder), GpuError> {
        let (ctx, field) = (self.ctx, self.field);
        let k = kernels(ctx)?;
        let Counted {
            rays: rays_buf,
            starts,
            n,
            ..
        } = counted;
        let budget = sample_budget(ctx, field);
        if n > budget {
            return Err(GpuError::Invalid(format!(
                "a step of {n_rays} rays marched {n} samples; this adapter holds at most {budget} \
                 per pass: lower rays_per_step"
            )));
        }
        let mut enc = ctx.encoder();
        let batch = RayBatch {
            rays: &rays_buf,
            occupied: &self.occupied,
            n_rays,
        };
        let marched = record_write(ctx, &mut enc, field, batch, starts, n)?;
        let ld = marched.ld;
        let params = &self.params;
        let dens = record_density(ctx, &mut enc, field, params, &marched.points, ld, n)?;
        let no_mean = ctx.storage("no mean embedding", 16)?;
        let color = record_color(
            ctx,
            &mut enc,
            field,
            params,
            &rays_buf,
            &marched,
            dens.out(),
            &no_mean,
            None,
        )?;
        let col =
            |rows: usize| ctx.storage("field sample gradient", 4 * rows as u64 * u64::from(ld));
        let wg = col(2)?;
        let d_dout = col(1 + GEO_FEAT_DIM)?;
        let dc2 = col(3)?;
        let ray_out = ctx.storage(
            "field ray outputs",
            4 * (RAY_OUT_FLOATS as u64) * u64::from(n_rays),
        )?;
        let inv_rays = 1.0 / n_rays.max(1) as f32;
        let u = ctx.uniform(
            "field params",
            &field_words(
                field,
                PassSettings {
                    n_rays,
                    ld,
                    n,
                    inv_rays,
                    depth_w: opts.depth_loss_weight,
                    depth_sigma: opts.depth_sigma,
                    dist_w: opts.distortion_loss_weight,
                    ..Default::default()
                },
            ),
        );
        let cout = &color.acts[color.acts.len() - 1];
        ctx.dispatch(
            &mut enc,
            &k.ray_train,
            &[
                (0, &u),
                (1, &rays_buf),
                (3, &marched.starts),
                (7, &marched.samp),
                (9, dens.out()),
                (15, cout),
                (16, &wg),
                (17, &d_dout),
                (18, &dc2),
                (19, &ray_out),
            ],
            ctx.groups(n_rays.div_ceil(256)),
        );
        let grad = ctx.storage("field gradient", 4 * field.n_params as u64)?;
        let e = field.config.appearance_dim;
        let d_emb = col(e.max(1) as usize)?;
        let geo = GEO_FEAT_DIM as u32;
        let mut outs = vec![InputGradOut {
            dst: &d_dout,
            rows: 0..geo,
            row0: 1,
        }];
        let emb_rows = geo + SH_COMPONENTS as u32;
        if e > 0 {
            outs.push(InputGradOut {
                dst: &d_emb,
                rows: emb_rows..emb_rows + e,
                row0: 0,
            });
        }
        let batch = GpuBatch {
            ld,
            cols: n,
            count: None,
        };
        record_mlp_backward(
            ctx,
            &mut enc,
            GpuMlp {
                mlp: &field.color,
                params,
                base: field.color_offset,
            },
            &color.input,
            &color.acts,
            &dc2,
            &grad,
            &outs,
            batch,
        )?;
        let lf = field.grid.output_dim() as u32;
        let d_enc = col(lf as usize)?;
        record_mlp_backward(
            ctx,
            &mut enc,
            GpuMlp {
                mlp: &field.density,
                params,
                base: field.density_offset,
            },
            &dens.enc,
            &dens.acts,
            &d_dout,
            &grad,
            &[InputGradOut {
                dst: &d_enc,
                rows: 0..lf,
                row0: 0,
            }],
            batch,
        )?;
        let levels =
            record_backward_fixed(ctx, &mut enc, &field.grid, &marched.points, &d_enc, &grad)?;
        let su = self.step_uniform(n_rays, ld, 0.0, false);
        if e > 0 {
            let ray_emb = ctx.storage("ray embedding gradient", 4 * u64::from(n_rays * e))?;
            ctx.dispatch(
                &mut enc,
                &k.emb_ray,
                &[
                    (0, &su),
                    (4, &ray_out),
                    (9, &d_emb),
                    (10, &marched.starts),
                    (11, &ray_emb),
                ],
                ctx.groups((n_rays * e).div_ceil(256)),
            );
            ctx.dispatch(
                &mut enc,
                &k.emb_reduce,
                &[(0, &su), (11, &ray_emb), (12, &rays_buf), (13, &grad)],
                ctx.groups((field.config.n_images * e).div_ceil(256)),
            );
        }
        let status = ctx.storage("field step status", 4 * STATUS_WORDS as u64)?;
        ctx.dispatch(
            &mut enc,
            &k.count_nonfinite,
            &[(0, &su), (1, &grad), (3, &status)],
            ctx.groups((field.n_params as u32).div_ceil(256)),
        );
        ctx.dispatch(
            &mut enc,
            &k.finish_step,
            &[(0, &su), (2, &status), (4, &ray_out), (5, &levels)],
            [1, 1],
        );
        Ok((
            StepBuffers {
                n,
                grad,
                ray_out,
                status,
                levels,
            },
            enc,
        ))
    }

    /// `step.wgsl`'s parameter block; `lr` sets Adam's step for the next applied step, which
    /// is one further when a step before it is `unresolved` (its status not read yet) and was
    /// applied: Adam picks between the two on the device.
    fn step_uniform(&self, n_rays: u32, ld: u32, lr: f32, unresolved: bool) -> GpuBuffer {
        // lr / (1 − β1^t) and 1 / (1 − β2^t), as the CPU's `Adam::step` computes them.
        let factors = |t: u32| {
            let bc1 = 1.0 - ADAM_BETA1.powi(t as i32);
            let bc2 = 1.0 - ADAM_BETA2.powi(t as i32);
            ((lr / bc1).to_bits(), (1.0 / bc2).to_bits())
        };
        let (step_size, inv_bc2) = factors(self.adam_t + 1 + u32::from(unresolved));
        let (step_size_skip, inv_bc2_skip) = factors(self.adam_t + 1);
        let field = self.field;
        self.ctx.uniform(
            "field step params",
            &[
                field.n_params as u32,
                n_rays,
                field.config.appearance_dim,
                field.config.n_images,
                field.embedding_offset as u32,
                field.grid.levels() as u32,
                ld,
                0,
                step_size,
                inv_bc2,
                ADAM_BETA1.to_bits(),
                (1.0 - ADAM_BETA1).to_bits(),
                ADAM_BETA2.to_bits(),
                (1.0 - ADAM_BETA2).to_bits(),
                ADAM_EPS.to_bits(),
                step_size_skip,
                inv_bc2_skip,
                0,
                0,
                0,
            ],
        )
    }

    /// Records training step `step` (Adam included) and submits it. With `next` (the step
    /// after it, when no occupancy refresh comes between them), that step's rays are drawn,
    /// uploaded and counted first, in a submission ahead of this step's, and the one wait here
    /// is for that count alone: the device runs this step while the host records the next.
    /// Without a count made ahead for it, this step counts its own samples first (a wait for
    /// an idle device). Returns the statistics of the step before (its number and stats) when
    /// a wait read them.
    pub fn step(
        &mut self,
        views: &[ViewData],
        opts: &TrainOptions,
        step: u32,
        next: Option<u32>,
    ) -> Result<Option<(u32, Settled)>, GpuError> {
        let n_rays = opts.rays_per_step.max(1);
        check_loop_cap(self.ctx, n_rays)?;
        self.ctx.count_training_step();
        // Everything recorded so far is submitted: the buffers earlier steps dropped can go
        // back to the pool.
        self.ctx.reclaim();
        let mut settled = None;
        let counted = match self.counted.take() {
            Some((s, c)) if s == step => c,
            _ => {
                let rays = step_rays(views, opts, step);
                let pending = self.pending.take();
                let before = status_part(pending.as_ref());
                let mut c = count_samples(self.ctx, self.field, &rays, &self.occupied, &before)?;
                settled = self.settled_from(pending, &c.earlier);
                c.earlier.clear();
                c
            }
        };
        let (bufs, mut enc) = self.record_counted(counted, n_rays, opts)?;
        let k = kernels(self.ctx)?;
        // The step before, when its status is not read yet: Adam's count depends on it.
        let unresolved = self.pending.as_ref().map(|(_, status, _)| &**status);
        let su = self.step_uniform(n_rays, 0, learning_rate(opts, step), unresolved.is_some());
        self.ctx.dispatch(
            &mut enc,
            &k.adam,
            &[
                (0, &su),
                (1, &bufs.grad),
                (2, &bufs.status),
                (6, &self.params),
                (7, &self.adam_m),
                (8, &self.adam_v),
                (14, unresolved.unwrap_or(&self.no_previous)),
            ],
            self.ctx.groups((self.field.n_params as u32).div_ceil(256)),
        );
        match next {
            Some(next) => {
                let rays = step_rays(views, opts, next);
                let pending = self.pending.take();
                let counting = count_later(
                    self.ctx,
                    self.field,
                    &rays,
                    &self.occupied,
                    &status_part(pending.as_ref()),
                )?;
                self.ctx.submit_no_wait(enc)?;
                // The count and the step before ran; this step may still be running.
                let mut c = counting.wait(self.ctx)?;
                if let Some(got) = self.settled_from(pending, &c.earlier) {
                    settled = Some(got);
                }
                c.earlier.clear();
                self.counted = Some((next, c));
            }
            None => match self.pending.take() {
                // The step before is still unread: its status goes in a submission of its
                // own ahead of this step, and the wait is for that alone.
                Some(pending) => {
                    let read = self.ctx.encoder();
                    let ticket = self.ctx.read_later(read, &status_part(Some(&pending)))?;
                    self.ctx.submit_no_wait(enc)?;
                    let words = ticket.wait(self.ctx)?;
                    settled = self.settled_from(Some(pending), &words);
                }
                None => self.ctx.submit_no_wait(enc)?,
            },
        }
        self.pending = Some((step, bufs.status, bufs.n));
        Ok(settled)
    }

    /// The statistics of `pending` from its status words, read as the first of `earlier`.
    fn settled_from(
        &mut self,
        pending: Option<(u32, GpuBuffer, u32)>,
        earlier: &[Vec<u32>],
    ) -> Option<(u32, Settled)> {
        let (s, _, n) = pending?;
        let words = earlier.first()?;
        Some((s, self.account(words, n)))
    }

    /// Reads the pending step's statistics (one wait), if a step is pending.
    pub fn settle(&mut self) -> Result<Option<(u32, Settled)>, GpuError> {
        let Some((s, status, n)) = self.pending.take() else {
            return Ok(None);
        };
        let words = self.ctx.read_words(&status, STATUS_WORDS)?;
        Ok(Some((s, self.account(&words, n))))
    }

    /// A step's statistics from its status words (and Adam's count when it was applied).
    fn account(&mut self, words: &[u32], n: u32) -> Settled {
        let applied = words[1] == 0;
        if applied {
            self.adam_t += 1;
        }
        let stats = StepStats {
            rgb_loss: f32::from_bits(words[2]) as f64,
            depth_loss: f32::from_bits(words[3]) as f64,
            distortion_loss: f32::from_bits(words[4]) as f64,
            samples: u64::from(n),
            color_samples: u64::from(words[5]),
            applied,
        };
        Settled {
            stats,
            nonfinite: u64::from(words[0]),
        }
    }

    /// Refreshes the occupancy grid as [`crate::train::update_occupancy`] does (the same
    /// jittered points), on the device, without waiting.
    pub fn update_occupancy(&self, seed: u64, step: u32) -> Result<(), GpuError> {
        let (ctx, field) = (self.ctx, self.field);
        let k = kernels(ctx)?;
        let res = field.config.occupancy_resolution;
        let shape = OccupancyGrid::full(res);
        let cells = shape.len();
        let mut enc = ctx.encoder();
        let chunks = cells.div_ceil(OCCUPANCY_CHUNK_CELLS);
        let per_batch = OCCUPANCY_BATCH_CELLS / OCCUPANCY_CHUNK_CELLS;
        for b in 0..chunks.div_ceil(per_batch) {
            let mut pts: [Vec<f32>; 4] = Default::default();
            for c in b * per_batch..((b + 1) * per_batch).min(chunks) {
                let part = occupancy_points(field, &shape, seed, step, c);
                for (dst, src) in pts.iter_mut().zip(part) {
                    dst.extend(src);
                }
            }
            let n = pts[0].len() as u32;
            let ld = batch_stride(n);
            let points = GpuPoints::upload(
                ctx,
                crate::hashgrid::PointBatch {
                    px: &pts[0],
                    py: &pts[1],
                    pz: &pts[2],
                    n: n as usize,
                    ld: ld as usize,
                },
            )?;
            let scale = ctx.storage_init("occupancy step", &f32_words(pts[3].iter().copied()))?;
            let dens = record_density(ctx, &mut enc, field, &self.params, &points, ld, n)?;
            let u = ctx.uniform(
                "field params",
                &field_words(
                    field,
                    PassSettings {
                        ld,
                        n,
                        first: (b * OCCUPANCY_BATCH_CELLS) as u32,
                        ..Default::default()
                    },
                ),
            );
            ctx.dispatch(
                &mut enc,
                &k.occ_values,
                &[(0, &u), (9, dens.out()), (21, &scale), (22, &self.ema)],
                ctx.groups(n.div_ceil(256)),
            );
        }
        let u = ctx.uniform(
            "field params",
            &field_words(
                field,
                PassSettings {
                    n: cells as u32,
                    ..Default::default()
                },
            ),
        );
        ctx.dispatch(
            &mut enc,
            &k.occ_flags,
            &[(0, &u), (22, &self.ema), (34, &self.occupied)],
            [1, 1],
        );
        ctx.submit_no_wait(enc)
    }

    /// The parameters, occupancy grid and Adam's moments, read back (one wait).
    pub fn download(&self) -> Result<(Vec<f32>, OccupancyGrid, Adam), GpuError> {
        let np = self.field.n_params;
        let cells = OccupancyGrid::full(self.field.config.occupancy_resolution).len();
        let enc = self.ctx.encoder();
        let words = self.ctx.read_after(
            enc,
            &[
                (&self.params, 0, np),
                (&self.adam_m, 0, np),
                (&self.adam_v, 0, np),
                (&self.ema, 0, cells),
                (&self.occupied, 0, cells),
            ],
        )?;
        let floats = |w: &Vec<u32>| w.iter().map(|b| f32::from_bits(*b)).collect::<Vec<f32>>();
        let occ = OccupancyGrid {
            res: self.field.config.occupancy_resolution,
            ema: floats(&words[3]),
            occupied: words[4].iter().map(|&o| o as u8).collect(),
        };
        let adam = Adam {
            m: floats(&words[1]),
            v: floats(&words[2]),
            t: self.adam_t,
        };
        Ok((floats(&words[0]), occ, adam))
    }

    /// The parameter and occupancy buffers, for rendering from the device state.
    pub fn model(&self) -> (&GpuBuffer, &GpuBuffer) {
        (&self.params, &self.occupied)
    }
}

/// Refuses a step of `n_rays` rays on an adapter whose loop cap it would pass
/// ([`augsplat_render::gpu::AdapterSummary::loop_cap`]): the step's loss sum and embedding
/// gradients each loop over its rays in one invocation (`finish_step`, `emb_reduce`), and a
/// capped adapter would end those loops early without a word.
fn check_loop_cap(ctx: &GpuContext, n_rays: u32) -> Result<(), GpuError> {
    // The loss sum's loop over the rays, plus its loop over the levels and a margin.
    const OTHER_ITERATIONS: u32 = 64;
    match ctx.adapter().loop_cap() {
        Some(cap) if n_rays > cap - OTHER_ITERATIONS => Err(GpuError::Invalid(format!(
            "{} ends a shader's loops after {cap} iterations, and a field step of {n_rays} rays \
             would pass that: use at most {} rays_per_step there, or backend: Cpu",
            ctx.adapter().name,
            cap - OTHER_ITERATIONS
        ))),
        _ => Ok(()),
    }
}

/// [`crate::train::train_resumable`] on the GPU: the same options, curve and checkpoints.
pub fn train_gpu(
    ctx: &GpuContext,
    field: &Field,
    views: &[ViewData],
    test: Option<&[ViewData]>,
    opts: &TrainOptions,
    checkpoints: Option<FieldCheckpoints<'_>>,
    on_step: &mut dyn FnMut(StepReport<'_>),
) -> Result<(TrainState, augsplat_core::artifacts::TrainingCurve), FieldError> {
    if views.is_empty() {
        return Err(FieldError::Data("no training views".into()));
    }
    let mut ckpt = checkpoints;
    let (mut state, mut lp) = start_or_resume(field, opts, ckpt.as_mut());
    let total = opts.rays_per_step.max(1) as f64;
    let run = ctx.scoped(|| {
        let mut trainer = GpuTrainer::new(ctx, field, &state, &lp.adam)?;
        let mut account = |lp: &mut FieldLoop,
                           state: &mut TrainState,
                           got: Option<(u32, Settled)>|
         -> Result<(), FieldError> {
            let Some((s, settled)) = got else {
                return Ok(());
            };
            let mut stats = settled.stats;
            stats.rgb_loss /= total;
            stats.depth_loss /= total;
            stats.distortion_loss /= total;
            if !stats.applied {
                state.skipped_steps += 1;
                state.nonfinite_values += settled.nonfinite;
            }
            tally_step(lp, &stats, s)?;
            on_step(StepReport {
                step: s + 1,
                stats: &stats,
            });
            Ok(())
        };
        let mut result: Result<(), FieldError> = Ok(());
        let refresh_at = |step: u32| {
            step >= opts.occupancy_warmup
                && (step - opts.occupancy_warmup).is_multiple_of(OCCUPANCY_UPDATE_EVERY)
        };
        for step in lp.step..opts.steps {
            if refresh_at(step) {
                trainer.update_occupancy(opts.seed, step)?;
            }
            // The next step's samples are counted while this one runs, unless the occupancy
            // grid they march through is refreshed first.
            let next = Some(step + 1).filter(|&s| s < opts.steps && !refresh_at(s));
            let prev = trainer.step(views, opts, step, next)?;
            if let Err(e) = account(&mut lp, &mut state, prev) {
                result = Err(e);
                break;
            }
            let done = step + 1;
            let eval_now =
                done == opts.steps || (opts.eval_every > 0 && done % opts.eval_every == 0);
            let ckpt_now = ckpt.as_ref().is_some_and(|c| {
                c.every > 0 && (done as u64).is_multiple_of(c.every) && done < opts.steps
            });
            if eval_now || ckpt_now {
                let last = trainer.settle()?;
                if let Err(e) = account(&mut lp, &mut state, last) {
                    result = Err(e);
                    break;
                }
            }
            if eval_now {
                let (p, m) = match test {
                    Some(t) if !t.is_empty() => evaluate_gpu(ctx, field, &trainer, t, opts)?,
                    _ => (0.0, 0.0),
                };
                push_curve_point(&mut lp, done, p, m);
            }
            if ckpt_now {
                if let Some(c) = ckpt.as_mut() {
                    lp.step = done;
                    let (params, occupancy, adam) = trainer.download()?;
                    state.params = params;
                    state.occupancy = occupancy;
                    lp.adam = adam;
                    save_checkpoint(c, &state, &lp, opts.steps);
                }
            }
        }
        if result.is_ok() {
            let last = trainer.settle()?;
            result = account(&mut lp, &mut state, last);
        }
        let (params, occupancy, adam) = trainer.download()?;
        state.params = params;
        state.occupancy = occupancy;
        lp.adam = adam;
        drop(trainer);
        ctx.reclaim();
        Ok(result)
    });
    run??;
    if state.params.iter().any(|p| !p.is_finite()) {
        return Err(FieldError::Diverged("parameters became non-finite".into()));
    }
    Ok((state, lp.curve))
}

/// Held-out PSNR and MSE of the device state, rendered on the GPU.
fn evaluate_gpu(
    ctx: &GpuContext,
    field: &Field,
    trainer: &GpuTrainer<'_>,
    views: &[ViewData],
    opts: &TrainOptions,
) -> Result<(f64, f64), GpuError> {
    let (params, occupied) = trainer.model();
    let e = field.config.appearance_dim as usize;
    let emb = if e > 0 {
        let n = field.config.n_images as usize * e;
        let w = ctx.read_after(ctx.encoder(), &[(params, field.embedding_offset as u64, n)])?;
        w[0].iter().map(|b| f32::from_bits(*b)).collect()
    } else {
        Vec::new()
    };
    let mean = mean_buffer(ctx, field.mean_of_embeddings(&emb))?;
    let model = GpuFieldRef {
        field,
        params,
        occupied,
        mean_emb: &mean,
    };
    let cams: Vec<_> = views.iter().map(|v| v.camera.clone()).collect();
    let images = render_views_gpu(ctx, &model, &cams, opts.background)?;
    let (mut p, mut m) = (0.0, 0.0);
    for (img, v) in images.iter().zip(views) {
        let (ps, ms) = crate::render::psnr(&img.rgb, &v.rgb);
        p += ps;
        m += ms;
    }
    let n = views.len().max(1) as f64;
    Ok((p / n, m / n))
}
