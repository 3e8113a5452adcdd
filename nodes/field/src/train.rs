//! The training loop: seeded ray batches over the training images, fixed ray chunks
//! processed in parallel, gradients reduced in chunk order (hash table: one level per task,
//! samples in chunk order), Adam with an exponential learning-rate decay, occupancy-grid
//! refreshes, periodic held-out PSNR, and guards against non-finite values.
//!
//! Every random number comes from [`Rng::stream`] keyed by (seed, step, chunk), and every sum
//! runs in an order fixed by the chunk layout, so results are bit-identical for any number of
//! threads.

pub use crate::checkpoint::FieldCheckpoints;
use crate::checkpoint::{read_field_checkpoint, write_field_checkpoint, FieldLoop};
use crate::constants::*;
use crate::contraction::{max_stretch, uncontract_radius};
use crate::error::FieldError;
use crate::field::{ChunkState, Field, RayInput};
use crate::hashgrid::PointBatch;
use crate::occupancy::OccupancyGrid;
pub use crate::render::{
    evaluate, psnr, render_camera, RenderStats, RenderedImage, RENDER_CHUNK_RAYS, RENDER_PASS_RAYS,
};
use crate::volume;
use augsplat_core::{Camera, Rng, Scene};
use rayon::prelude::*;
use std::path::Path;

thread_local! {
    /// Each worker thread's chunk state, kept across chunks and steps so its buffers are
    /// allocated once (a chunk overwrites everything it reads, so reuse cannot change results).
    static CHUNK_STATE: std::cell::RefCell<ChunkState> = std::cell::RefCell::new(ChunkState::default());
}

/// Runs `f` with this thread's reusable [`ChunkState`], set up for rendering (colour threshold
/// [`RENDER_MIN_COLOR_WEIGHT`], densities only until early termination) or for training /
/// density queries (neither).
pub(crate) fn with_chunk_state<R>(render: bool, f: impl FnOnce(&mut ChunkState) -> R) -> R {
    let setup = |st: &mut ChunkState| {
        st.min_color_weight = if render { RENDER_MIN_COLOR_WEIGHT } else { 0.0 };
        st.stop_at_termination = render;
    };
    CHUNK_STATE.with(|cell| match cell.try_borrow_mut() {
        Ok(mut st) => {
            setup(&mut st);
            f(&mut st)
        }
        // Re-entered on this thread (a nested parallel call ran here while the state was in
        // use): fall back to a fresh state.
        Err(_) => {
            let mut st = ChunkState::default();
            setup(&mut st);
            f(&mut st)
        }
    })
}

/// Float buffers handed from the chunk workers to the hash-table reduction and back, so each
/// step reuses the previous step's allocations (contents are always overwritten): sample
/// coordinates here, encoding gradients in [`ENC_POOL`] (one pool per kind, so a buffer comes
/// back to a role of its own size instead of being regrown).
static BUFFER_POOL: std::sync::Mutex<Vec<Vec<f32>>> = std::sync::Mutex::new(Vec::new());

/// Encoding-gradient buffers: swapped with the chunk state's (no copy), see [`BUFFER_POOL`].
static ENC_POOL: std::sync::Mutex<Vec<Vec<f32>>> = std::sync::Mutex::new(Vec::new());

/// Frees the pooled hand-off buffers (called when a training run ends; the pool refills on
/// the next step that needs it).
pub fn release_buffers() {
    for pool in [&BUFFER_POOL, &ENC_POOL] {
        if let Ok(mut p) = pool.lock() {
            p.clear();
            p.shrink_to_fit();
        }
    }
}

/// A pooled buffer holding a copy of `src`.
fn pooled_copy(src: &[f32]) -> Vec<f32> {
    let mut v = BUFFER_POOL
        .lock()
        .ok()
        .and_then(|mut p| p.pop())
        .unwrap_or_default();
    v.clear();
    v.extend_from_slice(src);
    v
}

/// Hands over `buf` truncated to `len` floats, leaving a pooled buffer (arbitrary contents) in
/// its place: for buffers the chunk state overwrites completely before reading them again.
fn pooled_swap(buf: &mut Vec<f32>, len: usize) -> Vec<f32> {
    let mut v = ENC_POOL
        .lock()
        .ok()
        .and_then(|mut p| p.pop())
        .unwrap_or_default();
    std::mem::swap(&mut v, buf);
    v.truncate(len);
    v
}

/// Returns buffers to a pool (bounded, so a one-off large step does not pin memory).
fn recycle(pool: &std::sync::Mutex<Vec<Vec<f32>>>, bufs: impl IntoIterator<Item = Vec<f32>>) {
    if let Ok(mut p) = pool.lock() {
        for b in bufs {
            if p.len() < 1024 {
                p.push(b);
            }
        }
    }
}

/// One training or evaluation view, loaded into memory.
#[derive(Clone, Debug)]
pub struct ViewData {
    /// Name of the view.
    pub name: String,
    /// Camera at the loaded resolution.
    pub camera: Camera,
    /// Interleaved RGB in [0, 1].
    pub rgb: Vec<f32>,
    /// Depth along the optical axis and its weight per pixel (0 = unknown), if the scene has it.
    pub depth: Option<(Vec<f32>, Vec<f32>)>,
}

/// Loads a scene folder's views, downscaled by an integer factor.
pub fn load_views(dir: &Path, downscale: u32) -> Result<(Scene, Vec<ViewData>), FieldError> {
    let scene = Scene::load(dir)?;
    if scene.views.is_empty() {
        return Err(FieldError::Data(format!(
            "{}: the scene has no views",
            dir.display()
        )));
    }
    let f = downscale.max(1);
    let mut views = Vec::with_capacity(scene.views.len());
    for (i, v) in scene.views.iter().enumerate() {
        v.camera
            .validate()
            .map_err(|e| FieldError::Data(format!("{}: view {}: {e}", dir.display(), v.name)))?;
        let img = scene.load_image(dir, i)?;
        if img.width != v.camera.width || img.height != v.camera.height {
            return Err(FieldError::Data(format!(
                "{}: image {}×{} does not match its camera {}×{}",
                dir.join(&v.image).display(),
                img.width,
                img.height,
                v.camera.width,
                v.camera.height
            )));
        }
        let small = img.downscale(f);
        let camera = v.camera.resized(small.width, small.height);
        let depth = match scene.load_depth(dir, i)? {
            None => None,
            Some((z, w)) => {
                if z.len() != img.pixels() || w.len() != img.pixels() {
                    return Err(FieldError::Data(format!(
                        "{}: depth map size does not match the image",
                        dir.join(v.depth.as_deref().unwrap_or("")).display()
                    )));
                }
                Some(downscale_depth(&z, &w, img.width, img.height, f))
            }
        };
        views.push(ViewData {
            name: v.name.clone(),
            camera,
            rgb: small.data,
            depth,
        });
    }
    Ok((scene, views))
}

/// Downscales a sparse depth map: each block keeps its most confident finite sample.
fn downscale_depth(z: &[f32], w: &[f32], width: u32, height: u32, f: u32) -> (Vec<f32>, Vec<f32>) {
    let (ow, oh) = (width.div_ceil(f), height.div_ceil(f));
    let mut zo = vec![0f32; (ow * oh) as usize];
    let mut wo = vec![0f32; (ow * oh) as usize];
    for y in 0..height {
        for x in 0..width {
            let i = (y * width + x) as usize;
            let (zz, ww) = (z[i], w[i]);
            if !(zz.is_finite() && ww.is_finite() && zz > 0.0 && ww > 0.0) {
                continue;
            }
            let o = ((y / f) * ow + x / f) as usize;
            if ww > wo[o] {
                wo[o] = ww;
                zo[o] = zz;
            }
        }
    }
    (zo, wo)
}

/// Training hyper-parameters (the node args minus the field architecture).
#[derive(Clone, Debug, PartialEq)]
pub struct TrainOptions {
    /// Seed of every random choice.
    pub seed: u64,
    /// Optimisation steps.
    pub steps: u32,
    /// Rays per step.
    pub rays_per_step: u32,
    /// Rays per parallel chunk (fixed: part of the result's definition).
    pub chunk_rays: u32,
    /// Initial learning rate.
    pub learning_rate: f32,
    /// Final learning rate as a fraction of the initial one (exponential decay).
    pub lr_final_factor: f32,
    /// Weight of the DS-NeRF depth loss (0 = off).
    pub depth_loss_weight: f32,
    /// Spread of the depth-loss Gaussian relative to the target distance.
    pub depth_sigma: f32,
    /// Weight of the distortion loss (0 = off).
    pub distortion_loss_weight: f32,
    /// Random background colour per ray while training (else `background`).
    pub random_background: bool,
    /// Background colour for evaluation (and training when not random).
    pub background: [f32; 3],
    /// Steps before the occupancy grid is first updated (all cells occupied until then).
    pub occupancy_warmup: u32,
    /// Evaluate held-out PSNR every this many steps (0 = only at the end).
    pub eval_every: u32,
}

/// Mutable training state.
#[derive(Clone, Debug)]
pub struct TrainState {
    /// Parameters.
    pub params: Vec<f32>,
    /// Occupancy grid.
    pub occupancy: OccupancyGrid,
    /// Steps skipped because gradients or losses were not finite.
    pub skipped_steps: u32,
    /// Non-finite gradient entries seen (and discarded).
    pub nonfinite_values: u64,
}

/// Statistics of one step.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct StepStats {
    /// Mean photometric loss (MSE over rays and channels).
    pub rgb_loss: f64,
    /// Mean depth loss over rays with depth.
    pub depth_loss: f64,
    /// Mean distortion loss.
    pub distortion_loss: f64,
    /// Field samples evaluated (density).
    pub samples: u64,
    /// Samples that reached the colour network.
    pub color_samples: u64,
    /// Whether the step was applied (false = skipped as non-finite).
    pub applied: bool,
}

struct ChunkResult {
    grad: Vec<f32>,
    d_enc: Vec<f32>,
    px: Vec<f32>,
    py: Vec<f32>,
    pz: Vec<f32>,
    n: usize,
    ld: usize,
    rgb_loss: f64,
    depth_loss: f64,
    dist_loss: f64,
    color_samples: usize,
}

/// A drawn training ray with its supervision.
#[derive(Clone, Copy, Debug)]
pub(crate) struct TrainRay {
    pub(crate) ray: RayInput,
    pub(crate) target: [f32; 3],
    /// Target distance along the ray and its weight (0 = none).
    pub(crate) depth: (f32, f32),
}

pub(crate) fn draw_ray(views: &[ViewData], rng: &mut Rng, opts: &TrainOptions) -> TrainRay {
    let v = rng.below(views.len() as u64) as usize;
    let view = &views[v];
    let (w, h) = (view.camera.width, view.camera.height);
    let p = rng.below(w as u64 * h as u64) as u32;
    let (i, j) = (p / w, p % w);
    let (o, d) = view.camera.pixel_ray(i, j);
    let fwd = view.camera.forward();
    let cos = (d[0] * fwd[0] + d[1] * fwd[1] + d[2] * fwd[2]).max(1e-6);
    let px = p as usize;
    let target = [view.rgb[3 * px], view.rgb[3 * px + 1], view.rgb[3 * px + 2]];
    let depth = match &view.depth {
        Some((z, wt)) if z[px] > 0.0 && wt[px] > 0.0 => ((z[px] as f64 / cos) as f32, wt[px]),
        _ => (0.0, 0.0),
    };
    let background = if opts.random_background {
        [rng.next_f32(), rng.next_f32(), rng.next_f32()]
    } else {
        opts.background
    };
    TrainRay {
        ray: RayInput {
            origin: o.map(|x| x as f32),
            dir: d.map(|x| x as f32),
            image: v as u32,
            background,
        },
        target,
        depth,
    }
}

/// Learning rate at a step: exponential decay from `lr` to `lr · final_factor`.
pub fn learning_rate(opts: &TrainOptions, step: u32) -> f32 {
    let f = (step as f64 / opts.steps.max(1) as f64).min(1.0);
    (opts.learning_rate as f64 * (opts.lr_final_factor.max(1e-8) as f64).powf(f)) as f32
}

/// The Adam optimiser over the flat parameter vector (updates run in parallel over fixed
/// blocks; each element's update is independent, so the result does not depend on threads).
#[derive(Clone, Debug)]
pub struct Adam {
    pub(crate) m: Vec<f32>,
    pub(crate) v: Vec<f32>,
    pub(crate) t: u32,
}

impl Adam {
    /// The updates applied so far (Adam's `t`: a rejected step does not count).
    pub fn applied_steps(&self) -> u32 {
        self.t
    }

    /// Zero state for `n` parameters.
    pub fn new(n: usize) -> Adam {
        Adam {
            m: vec![0.0; n],
            v: vec![0.0; n],
            t: 0,
        }
    }
    /// One update with learning rate `lr`.
    pub fn step(&mut self, params: &mut [f32], grad: &[f32], lr: f32) {
        self.t += 1;
        let bc1 = 1.0 - ADAM_BETA1.powi(self.t as i32);
        let bc2 = 1.0 - ADAM_BETA2.powi(self.t as i32);
        let step = lr / bc1;
        let inv_bc2 = 1.0 / bc2;
        const BLOCK: usize = 1 << 14;
        params
            .par_chunks_mut(BLOCK)
            .zip(grad.par_chunks(BLOCK))
            .zip(
                self.m
                    .par_chunks_mut(BLOCK)
                    .zip(self.v.par_chunks_mut(BLOCK)),
            )
            .for_each(|((p, g), (m, v))| {
                for i in 0..p.len() {
                    let gi = g[i];
                    m[i] = ADAM_BETA1 * m[i] + (1.0 - ADAM_BETA1) * gi;
                    v[i] = ADAM_BETA2 * v[i] + (1.0 - ADAM_BETA2) * gi * gi;
                    p[i] -= step * m[i] / ((v[i] * inv_bc2).sqrt() + ADAM_EPS);
                }
            });
    }
}

/// Cells per chunk of an occupancy refresh (each chunk draws from its own random stream).
pub(crate) const OCCUPANCY_CHUNK_CELLS: usize = 4096;

/// The jittered sample points of occupancy chunk `c` (cells `c·4096 ..`), seeded by
/// `(seed, step)`, in hash coordinates, with the world step the marcher takes there (0 outside
/// the contracted ball): `[px, py, pz, scale]`.
pub(crate) fn occupancy_points(
    field: &Field,
    occ: &OccupancyGrid,
    seed: u64,
    step: u32,
    c: usize,
) -> [Vec<f32>; 4] {
    let n = occ.len();
    let delta = field.config.contracted_step();
    let rw = field.config.radius as f32;
    let mut rng = Rng::stream(
        seed ^ 0x6f63_6375_7061_6e63,
        ((step as u64) << 32) | c as u64,
    );
    let lo = c * OCCUPANCY_CHUNK_CELLS;
    let hi = (lo + OCCUPANCY_CHUNK_CELLS).min(n);
    let mut px = Vec::with_capacity(hi - lo);
    let mut py = Vec::with_capacity(hi - lo);
    let mut pz = Vec::with_capacity(hi - lo);
    let mut scale = Vec::with_capacity(hi - lo);
    for i in lo..hi {
        let (corner, edge) = occ.cell_box(i);
        let p = [
            corner[0] + edge * rng.next_f32(),
            corner[1] + edge * rng.next_f32(),
            corner[2] + edge * rng.next_f32(),
        ];
        let rho = (p[0] * p[0] + p[1] * p[1] + p[2] * p[2]).sqrt();
        px.push((p[0] + 2.0) * 0.25);
        py.push((p[1] + 2.0) * 0.25);
        pz.push((p[2] + 2.0) * 0.25);
        // σ·step with the world step the marcher takes there; cells outside the
        // contracted ball are never visited.
        scale.push(if rho < CONTRACTED_RADIUS {
            delta * rw / max_stretch(uncontract_radius(rho))
        } else {
            0.0
        });
    }
    [px, py, pz, scale]
}

/// Refreshes the occupancy grid from the current density (one jittered point per cell,
/// seeded by `(seed, step)`).
pub fn update_occupancy(
    field: &Field,
    params: &[f32],
    occ: &mut OccupancyGrid,
    seed: u64,
    step: u32,
) {
    let n = occ.len();
    let occ_ro = occ.clone();
    let values: Vec<f32> = (0..n.div_ceil(OCCUPANCY_CHUNK_CELLS))
        .into_par_iter()
        .map(|c| {
            with_chunk_state(false, |st| {
                let [px, py, pz, scale] = occupancy_points(field, &occ_ro, seed, step, c);
                let sigma = field.density_batch(params, &px, &py, &pz, st);
                sigma
                    .iter()
                    .zip(&scale)
                    .map(|(s, k)| s * k)
                    .collect::<Vec<f32>>()
            })
        })
        .flatten_iter()
        .collect();
    occ.update(&values);
}

/// Runs one training step. `grad` is scratch of the parameters' length.
pub fn train_step(
    field: &Field,
    state: &mut TrainState,
    adam: &mut Adam,
    views: &[ViewData],
    opts: &TrainOptions,
    step: u32,
    grad: &mut Vec<f32>,
) -> Result<StepStats, FieldError> {
    let chunk = opts.chunk_rays.max(1) as usize;
    let total = opts.rays_per_step.max(1) as usize;
    let n_chunks = total.div_ceil(chunk);
    let params = &state.params;
    let occ = &state.occupancy;
    let mean_emb = field.mean_embedding(params);
    let nmlp = field.n_params - field.density_offset;
    let inv_rays = 1.0 / total as f32;
    let results: Vec<ChunkResult> = (0..n_chunks)
        .into_par_iter()
        .map(|c| {
            with_chunk_state(false, |st| {
                let mut rng = Rng::stream(opts.seed, ((step as u64) << 32) | c as u64);
                let count = chunk.min(total - c * chunk);
                let rays: Vec<TrainRay> = (0..count)
                    .map(|_| draw_ray(views, &mut rng, opts))
                    .collect();
                let jit: Vec<f32> = (0..count).map(|_| rng.next_f32()).collect();
                let inputs: Vec<RayInput> = rays.iter().map(|r| r.ray).collect();
                field.forward_chunk(params, occ, &inputs, &|r| jit[r], &mean_emb, st);
                let (mut rgb_loss, mut depth_loss, mut dist_loss) = (0f64, 0f64, 0f64);
                let longest = (0..count)
                    .map(|r| st.ray_start[r + 1] - st.ray_start[r])
                    .max()
                    .unwrap_or(0);
                let ds = vec![field.config.contracted_step(); longest];
                for (r, tr) in rays.iter().enumerate() {
                    let o = st.out[r];
                    let mut d = [0f32; 3];
                    for k in 0..3 {
                        let e = o.rgb[k] - tr.target[k];
                        rgb_loss += (e * e) as f64 / 3.0;
                        d[k] = 2.0 * e / 3.0 * inv_rays;
                    }
                    field.add_ray_output_grad(st, &inputs, r, d, 0.0, 0.0);
                    let (a, b) = (st.ray_start[r], st.ray_start[r + 1]);
                    if opts.depth_loss_weight > 0.0 && tr.depth.1 > 0.0 && b > a {
                        let scale = opts.depth_loss_weight * tr.depth.1 * inv_rays;
                        let s = (opts.depth_sigma * tr.depth.0).max(1e-4);
                        let l = volume::ds_nerf_depth(
                            &st.w[a..b],
                            &st.t[a..b],
                            &st.dt[a..b],
                            tr.depth.0,
                            s,
                            scale,
                            &mut st.g[a..b],
                        );
                        depth_loss += (l * tr.depth.1) as f64;
                    }
                    if opts.distortion_loss_weight > 0.0 && b > a {
                        let scale = opts.distortion_loss_weight * inv_rays;
                        let l = volume::distortion(
                            &st.w[a..b],
                            &st.m[a..b],
                            &ds[..b - a],
                            scale,
                            &mut st.g[a..b],
                        );
                        dist_loss += l as f64;
                    }
                }
                let mut g = vec![0f32; nmlp];
                field.backward_chunk(params, &inputs, st, &mut g);
                ChunkResult {
                    grad: g,
                    // `backward_chunk` rewrites every entry of `st.d_enc` it reads later,
                    // so the buffer is handed over instead of copied.
                    d_enc: pooled_swap(&mut st.d_enc, field.grid.output_dim() * st.ld),
                    px: pooled_copy(&st.px),
                    py: pooled_copy(&st.py),
                    pz: pooled_copy(&st.pz),
                    n: st.n(),
                    ld: st.ld,
                    rgb_loss,
                    depth_loss,
                    dist_loss,
                    color_samples: st.alive.len(),
                }
            })
        })
        .collect();
    // Reduce: MLP/embedding gradients in chunk order; hash table level by level.
    grad.clear();
    grad.resize(field.n_params, 0.0);
    let (ggrid, gmlp) = grad.split_at_mut(field.density_offset);
    for r in &results {
        for (a, b) in gmlp.iter_mut().zip(&r.grad) {
            *a += *b;
        }
    }
    let mut level_slices: Vec<(usize, &mut [f32])> = Vec::new();
    let mut rest = ggrid;
    for l in 0..field.grid.levels() {
        let len = field.grid.level_range(l).len();
        let (head, tail) = rest.split_at_mut(len);
        level_slices.push((l, head));
        rest = tail;
    }
    level_slices.into_par_iter().for_each(|(l, g)| {
        for r in &results {
            let pts = PointBatch {
                px: &r.px,
                py: &r.py,
                pz: &r.pz,
                n: r.n,
                ld: r.ld,
            };
            field.grid.backward_level(l, pts, &r.d_enc, g);
        }
    });
    let mut stats = StepStats::default();
    for r in &results {
        stats.rgb_loss += r.rgb_loss;
        stats.depth_loss += r.depth_loss;
        stats.distortion_loss += r.dist_loss;
        stats.samples += r.n as u64;
        stats.color_samples += r.color_samples as u64;
    }
    let mut enc_bufs = Vec::with_capacity(results.len());
    recycle(
        &BUFFER_POOL,
        results.into_iter().flat_map(|r| {
            enc_bufs.push(r.d_enc);
            [r.px, r.py, r.pz]
        }),
    );
    recycle(&ENC_POOL, enc_bufs);
    stats.rgb_loss /= total as f64;
    stats.depth_loss /= total as f64;
    stats.distortion_loss /= total as f64;
    // Guard: discard non-finite gradients.
    let bad = grad.par_iter().filter(|g| !g.is_finite()).count();
    let loss_ok = stats.rgb_loss.is_finite()
        && stats.depth_loss.is_finite()
        && stats.distortion_loss.is_finite();
    if bad > 0 || !loss_ok {
        state.nonfinite_values += bad as u64;
        state.skipped_steps += 1;
        stats.applied = false;
        return Ok(stats);
    }
    adam.step(&mut state.params, grad, learning_rate(opts, step));
    stats.applied = true;
    Ok(stats)
}

/// A run's starting point: fresh parameters, a full occupancy grid and a new loop, or what
/// the checkpoint to resume holds (a checkpoint that does not fit is logged and ignored).
pub(crate) fn start_or_resume(
    field: &Field,
    opts: &TrainOptions,
    ckpt: Option<&mut FieldCheckpoints<'_>>,
) -> (TrainState, FieldLoop) {
    let mut state = TrainState {
        params: field.init_params(opts.seed),
        occupancy: OccupancyGrid::full(field.config.occupancy_resolution),
        skipped_steps: 0,
        nonfinite_values: 0,
    };
    let mut lp = FieldLoop {
        step: 0,
        adam: Adam::new(field.n_params),
        curve: augsplat_core::artifacts::TrainingCurve {
            label: "field".into(),
            points: Vec::new(),
        },
        consecutive_bad: 0,
        loss_acc: (0.0, 0),
    };
    if let Some(c) = ckpt {
        if let Some(bytes) = c.resume.take() {
            match read_field_checkpoint(
                &bytes,
                field.n_params,
                field.config.occupancy_resolution,
                opts.steps,
            ) {
                Ok((s, l)) => {
                    state = s;
                    lp = l;
                    (c.log)(format!("resumed from the checkpoint at step {}", lp.step));
                }
                Err(e) => (c.log)(format!(
                    "cannot continue from the saved checkpoint ({e}); starting afresh"
                )),
            }
        }
    }
    (state, lp)
}

/// Counts a step in the loop: an applied step's loss goes into the next curve point and ends
/// a run of rejected steps; a rejected one lengthens it, an error once it is too long.
pub(crate) fn tally_step(
    lp: &mut FieldLoop,
    stats: &StepStats,
    step: u32,
) -> Result<(), FieldError> {
    if stats.applied {
        lp.consecutive_bad = 0;
        lp.loss_acc.0 += stats.rgb_loss;
        lp.loss_acc.1 += 1;
    } else {
        lp.consecutive_bad += 1;
        check_divergence(lp.consecutive_bad, step)?;
    }
    Ok(())
}

/// Adds the curve point of an evaluation after `done` steps (held-out PSNR and MSE, the mean
/// training loss since the last point; SSIM 0 and no time, so the curve is deterministic).
pub(crate) fn push_curve_point(lp: &mut FieldLoop, done: u32, psnr: f64, mse: f64) {
    lp.curve.points.push(augsplat_core::artifacts::CurvePoint {
        step: done as u64,
        psnr,
        ssim: 0.0,
        lpips: None,
        mse,
        avg_error: None,
        primitives: 0,
        seconds: 0.0,
        loss: if lp.loss_acc.1 > 0 {
            lp.loss_acc.0 / lp.loss_acc.1 as f64
        } else {
            0.0
        },
    });
    lp.loss_acc = (0.0, 0);
}

/// Saves a checkpoint of `state` and `lp` (whose `step` says where it is) and logs it.
pub(crate) fn save_checkpoint(
    c: &mut FieldCheckpoints<'_>,
    state: &TrainState,
    lp: &FieldLoop,
    steps: u32,
) {
    let done = lp.step;
    match (c.save)(write_field_checkpoint(state, lp, steps)) {
        Ok(()) => (c.log)(format!("checkpoint at step {done}")),
        Err(e) => (c.log)(format!(
            "warning: could not save the checkpoint at step {done}: {e}"
        )),
    }
}

/// Checks that a training run has not diverged.
pub fn check_divergence(consecutive_bad: u32, step: u32) -> Result<(), FieldError> {
    if consecutive_bad >= MAX_CONSECUTIVE_BAD_STEPS {
        return Err(FieldError::Diverged(format!(
            "{consecutive_bad} consecutive steps up to step {step} produced non-finite gradients or losses; \
             lower learning_rate or the loss weights"
        )));
    }
    Ok(())
}

/// Progress of a training run, reported after every step.
pub struct StepReport<'a> {
    /// Steps done.
    pub step: u32,
    /// Statistics of the last step.
    pub stats: &'a StepStats,
}

/// Trains a field from its initial parameters: the full loop with occupancy refreshes,
/// divergence guard and periodic evaluation on `test` (when given). Returns the final state
/// and the curve (held-out PSNR/MSE and training loss at each evaluation; SSIM is not computed
/// here and is written as 0; `seconds` is left 0 so the output stays deterministic).
pub fn train(
    field: &Field,
    views: &[ViewData],
    test: Option<&[ViewData]>,
    opts: &TrainOptions,
    on_step: &mut dyn FnMut(StepReport<'_>),
) -> Result<(TrainState, augsplat_core::artifacts::TrainingCurve), FieldError> {
    train_resumable(field, views, test, opts, None, on_step)
}

/// [`train`], saving its whole state every `checkpoints.every` steps and continuing from a
/// saved one: the result is the same, bit for bit, as a run that never stopped.
pub fn train_resumable(
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
    let mut grad = Vec::new();
    for step in lp.step..opts.steps {
        if step >= opts.occupancy_warmup
            && (step - opts.occupancy_warmup).is_multiple_of(OCCUPANCY_UPDATE_EVERY)
        {
            update_occupancy(field, &state.params, &mut state.occupancy, opts.seed, step);
        }
        let stats = train_step(
            field,
            &mut state,
            &mut lp.adam,
            views,
            opts,
            step,
            &mut grad,
        )?;
        tally_step(&mut lp, &stats, step)?;
        on_step(StepReport {
            step: step + 1,
            stats: &stats,
        });
        let done = step + 1;
        let eval_now = done == opts.steps || (opts.eval_every > 0 && done % opts.eval_every == 0);
        if eval_now {
            let (p, m) = match test {
                Some(t) if !t.is_empty() => evaluate(
                    field,
                    &state.params,
                    &state.occupancy,
                    t,
                    opts.background,
                    256,
                ),
                _ => (0.0, 0.0),
            };
            push_curve_point(&mut lp, done, p, m);
        }
        if let Some(c) = ckpt.as_mut() {
            if c.every > 0 && (done as u64).is_multiple_of(c.every) && done < opts.steps {
                lp.step = done;
                save_checkpoint(c, &state, &lp, opts.steps);
            }
        }
    }
    let curve = lp.curve;
    release_buffers();
    if state.params.iter().any(|p| !p.is_finite()) {
        return Err(FieldError::Diverged("parameters became non-finite".into()));
    }
    Ok((state, curve))
}
