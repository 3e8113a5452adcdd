//! The radiance field: hash encoding → density MLP (truncated exp, geometry features) →
//! colour MLP (geometry features ‖ SH(direction) ‖ optional appearance embedding, sigmoid),
//! plus ray marching through the occupancy grid and the per-chunk forward and backward passes
//! that training and rendering share.
//!
//! All parameters live in one flat `Vec<f32>`: hash table, density MLP, colour MLP, appearance
//! embeddings, in that order. A chunk of rays is processed by one thread with its own
//! [`ChunkState`]; nothing in a chunk depends on which thread runs it.
//!
//! The chunk's backward pass ([`Field::add_ray_output_grad`], [`Field::backward_chunk`]) is in
//! `backward.rs`.

use crate::constants::{
    GEO_FEAT_DIM, MAX_MARCH_ITERATIONS, SH_COMPONENTS, TRUNC_EXP_MAX, TRUNC_EXP_MIN,
};
use crate::contraction::{contract, max_stretch};
use crate::error::FieldError;
use crate::hashgrid::{HashGrid, HashGridConfig, PointBatch};
use crate::mlp::{padded, BackwardScratch, Mlp};
use crate::occupancy::OccupancyGrid;
use crate::sh::sh_encode;
use crate::volume;
use serde::{Deserialize, Serialize};

mod backward;

/// Everything needed to rebuild a field from its parameters (stored as `config.json`).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct FieldConfig {
    /// Hash encoding.
    pub grid: HashGridConfig,
    /// Width of the hidden layers of both MLPs.
    pub hidden_width: u32,
    /// Appearance embedding width (0 = none).
    pub appearance_dim: u32,
    /// Number of training images (rows of the embedding table).
    pub n_images: u32,
    /// Contraction centre (world units).
    pub center: [f64; 3],
    /// World distance that maps to field radius 1.
    pub radius: f64,
    /// Near bound along rays (world units).
    pub near: f64,
    /// Far bound along rays (world units).
    pub far: f64,
    /// Marching steps across the contracted ball's diameter (4 contracted units).
    pub march_steps: u32,
    /// Occupancy grid cells per axis.
    pub occupancy_resolution: u32,
}

impl FieldConfig {
    /// Checks ranges.
    pub fn validate(&self) -> Result<(), FieldError> {
        let bad = |m: String| Err(FieldError::Config(m));
        if !(self.radius.is_finite() && self.radius > 0.0) {
            return bad(format!(
                "contraction radius {} must be positive and finite",
                self.radius
            ));
        }
        if !(self.near.is_finite()
            && self.far.is_finite()
            && self.near >= 0.0
            && self.far > self.near)
        {
            return bad(format!(
                "near {} / far {} must satisfy 0 ≤ near < far",
                self.near, self.far
            ));
        }
        if self.center.iter().any(|v| !v.is_finite()) {
            return bad("contraction centre is not finite".into());
        }
        if !(4..=4096).contains(&self.march_steps) {
            return bad(format!(
                "march_steps = {} must be in 4..=4096",
                self.march_steps
            ));
        }
        if !(4..=512).contains(&self.occupancy_resolution) {
            return bad(format!(
                "occupancy_resolution = {} must be in 4..=512",
                self.occupancy_resolution
            ));
        }
        if !(8..=512).contains(&self.hidden_width) {
            return bad(format!(
                "hidden_width = {} must be in 8..=512",
                self.hidden_width
            ));
        }
        if self.appearance_dim > 256 {
            return bad(format!(
                "appearance_dim = {} must be ≤ 256",
                self.appearance_dim
            ));
        }
        Ok(())
    }
    /// Contracted-space step `Δ`.
    pub fn contracted_step(&self) -> f32 {
        4.0 / self.march_steps as f32
    }
}

/// The field's architecture and parameter layout.
#[derive(Clone, Debug)]
pub struct Field {
    /// The configuration.
    pub config: FieldConfig,
    /// Hash encoding layout (parameters at the start of the vector).
    pub grid: HashGrid,
    /// `L·F → hidden → 1 + 15` (density pre-activation, geometry features).
    pub density: Mlp,
    /// `15 + 16 + E → hidden → hidden → 3`.
    pub color: Mlp,
    /// Offset of the density MLP.
    pub density_offset: usize,
    /// Offset of the colour MLP.
    pub color_offset: usize,
    /// Offset of the appearance embeddings (`n_images × E`).
    pub embedding_offset: usize,
    /// Total parameters.
    pub n_params: usize,
}

/// One ray to render or train on.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct RayInput {
    /// Origin (world).
    pub origin: [f32; 3],
    /// Unit direction (world).
    pub dir: [f32; 3],
    /// Training image whose embedding to use; `u32::MAX` = the mean embedding.
    pub image: u32,
    /// Background colour composited behind the ray.
    pub background: [f32; 3],
}

/// Per-ray results of a forward pass.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct RayOutput {
    /// Composited colour including the background.
    pub rgb: [f32; 3],
    /// Accumulated opacity `Σ w`.
    pub acc: f32,
    /// Premultiplied distance `Σ w t` (divide by `acc` for the expected distance).
    pub depth: f32,
}

/// Activations and gradients of one chunk of rays (structure of arrays).
#[derive(Clone, Debug, Default)]
pub struct ChunkState {
    /// Sample positions in `[0, 1]³` (contracted, rescaled) — x, y, z.
    pub px: Vec<f32>,
    /// See `px`.
    pub py: Vec<f32>,
    /// See `px`.
    pub pz: Vec<f32>,
    /// Distance along the ray (sample midpoint).
    pub t: Vec<f32>,
    /// Sample length (world).
    pub dt: Vec<f32>,
    /// Contracted-space midpoint coordinate (for the distortion loss).
    pub m: Vec<f32>,
    /// Samples of ray `r` are `ray_start[r]..ray_start[r + 1]`.
    pub ray_start: Vec<usize>,
    /// Samples with colour per ray (early termination).
    pub n_color: Vec<usize>,
    /// Padded sample count.
    pub ld: usize,
    /// Encoding (`L·F × ld`).
    pub enc: Vec<f32>,
    /// Density MLP activations.
    pub dens_acts: Vec<Vec<f32>>,
    /// Densities.
    pub sigma: Vec<f32>,
    /// Weights.
    pub w: Vec<f32>,
    /// Indices of the samples that get a colour, ray by ray.
    pub alive: Vec<u32>,
    /// Samples whose weight is below this get no colour evaluation (rendering only: the
    /// backward pass needs 0, i.e. every sample before early termination).
    pub min_color_weight: f32,
    /// Rendering only: evaluate densities ray segment by ray segment and stop once a ray's
    /// transmittance has fallen below the early-termination threshold, dropping its later
    /// samples. Colour and every kept weight are unchanged; the opacity and depth sums lose
    /// the post-termination mass (less than the threshold, 1e-4). Training must leave this off
    /// (the backward pass uses every sample).
    pub stop_at_termination: bool,
    /// Padded alive count.
    pub ldc: usize,
    /// Colour MLP input.
    pub col_in: Vec<f32>,
    /// Colour MLP activations.
    pub col_acts: Vec<Vec<f32>>,
    /// Sigmoid colours (`3 × ldc`).
    pub rgb: Vec<f32>,
    /// Per-ray outputs.
    pub out: Vec<RayOutput>,
    /// `∂L/∂w_i` (filled by the loss).
    pub g: Vec<f32>,
    /// `∂L/∂c` for alive samples (`3 × ldc`, filled by the loss).
    pub d_rgb: Vec<f32>,
    /// `∂L/∂enc` after the backward pass (`L·F × ld`).
    pub d_enc: Vec<f32>,
    mlp_scratch: BackwardScratch,
    scratch2: Vec<f32>,
    d_sigma: Vec<f32>,
    d_cin: Vec<f32>,
    /// Each active ray's sample range of the current segment round.
    seg_ranges: Vec<(usize, usize)>,
    /// Runs of consecutive coloured samples: (first column, first sample, length).
    alive_runs: Vec<(usize, usize, usize)>,
    seg_px: Vec<f32>,
    seg_py: Vec<f32>,
    seg_pz: Vec<f32>,
    seg_out: Vec<f32>,
    render_out: Vec<f32>,
    ray_cursor: Vec<usize>,
    ray_keep: Vec<usize>,
    ray_trans: Vec<f32>,
    active: Vec<u32>,
    /// Sample counts of the last forward pass (see [`SampleCounters`]).
    pub counters: SampleCounters,
}

/// What one forward pass evaluated, summed over its rays: the cost model of rendering.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct SampleCounters {
    /// Marching steps taken (occupied or not).
    pub steps: u64,
    /// Samples in occupied cells (what a renderer without early termination evaluates).
    pub marched: u64,
    /// Samples evaluated by the density network.
    pub density: u64,
    /// Samples evaluated by the colour network.
    pub color: u64,
}

impl SampleCounters {
    /// Adds another pass's counts.
    pub fn add(&mut self, o: &SampleCounters) {
        self.steps += o.steps;
        self.marched += o.marched;
        self.density += o.density;
        self.color += o.color;
    }
}

impl ChunkState {
    /// Number of samples.
    pub fn n(&self) -> usize {
        self.t.len()
    }
    /// The samples' contracted positions as a batch for the hash encoding (its gradient
    /// [`ChunkState::d_enc`] has the same row stride).
    pub fn points(&self) -> PointBatch<'_> {
        PointBatch {
            px: &self.px,
            py: &self.py,
            pz: &self.pz,
            n: self.n(),
            ld: self.ld,
        }
    }
}

#[inline]
#[allow(clippy::manual_clamp)] // clamp() would keep NaN; max/min map it to a bound
fn trunc_exp(x: f32) -> f32 {
    // `max`/`min` map NaN to the bound (f32::max returns the non-NaN operand): a NaN
    // pre-activation becomes an (almost) empty sample instead of poisoning the ray.
    x.max(TRUNC_EXP_MIN).min(TRUNC_EXP_MAX).exp()
}

#[inline]
fn sigmoid(x: f32) -> f32 {
    if x.is_nan() {
        return 0.5;
    }
    1.0 / (1.0 + (-x).exp())
}

impl Field {
    /// Builds the layout for a configuration.
    pub fn new(config: FieldConfig) -> Result<Field, FieldError> {
        config.validate()?;
        let grid = HashGrid::new(config.grid.clone())?;
        let h = config.hidden_width as usize;
        let density = Mlp::new(grid.output_dim(), h, 1, 1 + GEO_FEAT_DIM);
        let e = config.appearance_dim as usize;
        let color = Mlp::new(GEO_FEAT_DIM + SH_COMPONENTS + e, h, 2, 3);
        let density_offset = grid.n_params();
        let color_offset = density_offset + density.n_params();
        let embedding_offset = color_offset + color.n_params();
        let n_params = embedding_offset + config.n_images as usize * e;
        Ok(Field {
            config,
            grid,
            density,
            color,
            density_offset,
            color_offset,
            embedding_offset,
            n_params,
        })
    }

    /// Seeded initial parameters.
    pub fn init_params(&self, seed: u64) -> Vec<f32> {
        let mut p = vec![0f32; self.n_params];
        let mut rng = augsplat_core::Rng::stream(seed, 0x6772_6964);
        self.grid.init(&mut p[..self.density_offset], &mut rng);
        self.density
            .init(&mut p[self.density_offset..self.color_offset], &mut rng);
        self.color
            .init(&mut p[self.color_offset..self.embedding_offset], &mut rng);
        for v in &mut p[self.embedding_offset..] {
            *v = (rng.normal() * 0.1) as f32;
        }
        p
    }

    /// The mean appearance embedding (empty when embeddings are off).
    pub fn mean_embedding(&self, params: &[f32]) -> Vec<f32> {
        self.mean_of_embeddings(&params[self.embedding_offset..])
    }

    /// The mean of the embedding rows `emb` (`n_images × E`, the parameters from
    /// [`Field::embedding_offset`] on); empty when embeddings are off.
    pub fn mean_of_embeddings(&self, emb: &[f32]) -> Vec<f32> {
        let e = self.config.appearance_dim as usize;
        let n = self.config.n_images as usize;
        let mut m = vec![0f32; e];
        if e == 0 || n == 0 {
            return m;
        }
        for i in 0..n {
            for k in 0..e {
                m[k] += emb[i * e + k];
            }
        }
        m.iter_mut().for_each(|v| *v /= n as f32);
        m
    }

    /// World point to field units.
    #[inline]
    pub fn to_field(&self, p: [f32; 3]) -> [f32; 3] {
        let c = self.config.center;
        let s = 1.0 / self.config.radius as f32;
        [
            (p[0] - c[0] as f32) * s,
            (p[1] - c[1] as f32) * s,
            (p[2] - c[2] as f32) * s,
        ]
    }

    /// Marches one ray from near to far with steps that are (at most) `Δ` in contracted
    /// space, keeping the samples whose contracted midpoint lies in an occupied cell.
    /// `jitter ∈ [0, 1)` shifts the whole ray's stepping (stratified training samples).
    pub fn march(&self, ray: &RayInput, occ: &OccupancyGrid, jitter: f32, st: &mut ChunkState) {
        let delta = self.config.contracted_step();
        let rw = self.config.radius as f32;
        let near = self.config.near as f32;
        let far = self.config.far as f32;
        let o = self.to_field(ray.origin);
        let d = ray.dir;
        let at = |t: f32| {
            [
                o[0] + d[0] * t / rw,
                o[1] + d[1] * t / rw,
                o[2] + d[2] * t / rw,
            ]
        };
        let step_at = |t: f32| {
            let x = at(t);
            let r = (x[0] * x[0] + x[1] * x[1] + x[2] * x[2]).sqrt();
            delta * rw / max_stretch(r)
        };
        let mut t = near + jitter * step_at(near);
        let mut k = 0u32;
        while t < far && k < MAX_MARCH_ITERATIONS {
            let dt = step_at(t).min(far - t).max(1e-6);
            let tm = t + 0.5 * dt;
            let c = contract(at(tm));
            if occ.is_occupied(c) {
                st.px.push((c[0] + 2.0) * 0.25);
                st.py.push((c[1] + 2.0) * 0.25);
                st.pz.push((c[2] + 2.0) * 0.25);
                st.t.push(tm);
                st.dt.push(dt);
                st.m.push((k as f32 + 0.5) * delta);
            }
            t += dt;
            k += 1;
        }
        st.counters.steps += k as u64;
    }

    /// Density of points given in `[0, 1]³` hash coordinates (for occupancy updates).
    pub fn density_batch(
        &self,
        params: &[f32],
        px: &[f32],
        py: &[f32],
        pz: &[f32],
        st: &mut ChunkState,
    ) -> Vec<f32> {
        let n = px.len();
        let ld = padded(n);
        st.enc.resize(self.grid.output_dim() * ld, 0.0);
        let pts = PointBatch { px, py, pz, n, ld };
        self.grid
            .encode(&params[..self.density_offset], pts, &mut st.enc);
        self.density.forward(
            &params[self.density_offset..self.color_offset],
            &st.enc,
            ld,
            &mut st.dens_acts,
        );
        let out = &st.dens_acts[st.dens_acts.len() - 1];
        (0..n).map(|i| trunc_exp(out[i])).collect()
    }

    /// Rendering: evaluates the density network on the marched samples in growing segments
    /// per ray (16, 32, 64, then 128 samples), all rays of a round in one batch, and stops a
    /// ray after the sample at which its transmittance falls below the threshold — computed
    /// exactly as [`volume::weights_forward`] does, so every kept density, weight and the
    /// colour cut are bit-identical to a full evaluation. The chunk's sample arrays are then
    /// compacted to the kept samples and `render_out` holds their density-network outputs
    /// (`(1 + GEO_FEAT_DIM) × ld`).
    fn densities_until_termination(&self, params: &[f32], st: &mut ChunkState) {
        let n = st.n();
        let nr = st.ray_start.len() - 1;
        let rows = 1 + GEO_FEAT_DIM;
        let lf = self.grid.output_dim();
        let table = &params[..self.density_offset];
        let dp = &params[self.density_offset..self.color_offset];
        // Outputs by original sample index (row stride `ld`, the padded count, so that when no
        // ray terminates the buffer is already the network-output layout and is swapped in);
        // only evaluated samples are read.
        let ld_all = padded(n);
        st.seg_out.resize(rows * ld_all, 0.0);
        st.ray_cursor.clear();
        st.ray_cursor.extend_from_slice(&st.ray_start[..nr]);
        st.ray_keep.clear();
        st.ray_keep.extend_from_slice(&st.ray_start[1..]);
        st.ray_trans.clear();
        st.ray_trans.resize(nr, 1.0);
        st.active.clear();
        st.active.extend(
            (0..nr as u32).filter(|&r| st.ray_start[r as usize + 1] > st.ray_start[r as usize]),
        );
        let mut round = 0u32;
        while !st.active.is_empty() {
            let seg = 16usize << round.min(3);
            round += 1;
            // Each active ray's next samples are one contiguous range of the chunk's arrays:
            // positions are gathered and outputs scattered range by range.
            st.seg_ranges.clear();
            for &r in &st.active {
                let r = r as usize;
                let a = st.ray_cursor[r];
                let b = (a + seg).min(st.ray_start[r + 1]);
                st.seg_ranges.push((a, b));
            }
            let nb: usize = st.seg_ranges.iter().map(|&(a, b)| b - a).sum();
            st.counters.density += nb as u64;
            let ldb = padded(nb);
            for (dst, src) in [
                (&mut st.seg_px, &st.px),
                (&mut st.seg_py, &st.py),
                (&mut st.seg_pz, &st.pz),
            ] {
                dst.clear();
                for &(a, b) in &st.seg_ranges {
                    dst.extend_from_slice(&src[a..b]);
                }
            }
            st.enc.resize(lf * ldb, 0.0);
            let pts = PointBatch {
                px: &st.seg_px,
                py: &st.seg_py,
                pz: &st.seg_pz,
                n: nb,
                ld: ldb,
            };
            self.grid.encode(table, pts, &mut st.enc);
            self.density.forward(dp, &st.enc, ldb, &mut st.dens_acts);
            let out = &st.dens_acts[st.dens_acts.len() - 1];
            for k in 0..rows {
                let dst = &mut st.seg_out[k * ld_all..(k + 1) * ld_all];
                let mut j = k * ldb;
                for &(a, b) in &st.seg_ranges {
                    dst[a..b].copy_from_slice(&out[j..j + (b - a)]);
                    j += b - a;
                }
            }
            // Transmittance along each active ray's new samples (as `weights_forward`).
            let mut still = 0;
            for q in 0..st.active.len() {
                let r = st.active[q] as usize;
                let a = st.ray_cursor[r];
                let end = st.ray_start[r + 1];
                let b = (a + seg).min(end);
                let mut t = st.ray_trans[r];
                let mut stopped = false;
                for i in a..b {
                    let sigma = trunc_exp(st.seg_out[i]);
                    let trans = (-sigma * st.dt[i]).exp();
                    t *= trans;
                    if t < crate::constants::TRANSMITTANCE_THRESHOLD {
                        st.ray_keep[r] = i + 1;
                        stopped = true;
                        break;
                    }
                }
                st.ray_trans[r] = t;
                st.ray_cursor[r] = b;
                if !stopped && b < end {
                    st.active[still] = r as u32;
                    still += 1;
                }
            }
            st.active.truncate(still);
        }
        if st.ray_keep[..nr] == st.ray_start[1..] {
            // No ray stopped early: every sample is kept and `seg_out` already holds every
            // row at stride `ld` (padding columns are never read).
            st.ld = ld_all;
            std::mem::swap(&mut st.render_out, &mut st.seg_out);
            return;
        }
        // Compact the samples to the kept ones (in place: kept indices never run ahead).
        let mut o = 0;
        let mut starts = Vec::with_capacity(nr + 1);
        for r in 0..nr {
            starts.push(o);
            for i in st.ray_start[r]..st.ray_keep[r] {
                st.px[o] = st.px[i];
                st.py[o] = st.py[i];
                st.pz[o] = st.pz[i];
                st.t[o] = st.t[i];
                st.dt[o] = st.dt[i];
                st.m[o] = st.m[i];
                o += 1;
            }
        }
        starts.push(o);
        let kept = o;
        for v in [
            &mut st.px, &mut st.py, &mut st.pz, &mut st.t, &mut st.dt, &mut st.m,
        ] {
            v.truncate(kept);
        }
        let ld = padded(kept);
        st.ld = ld;
        st.render_out.clear();
        st.render_out.resize(rows * ld, 0.0);
        let mut o = 0;
        for r in 0..nr {
            for i in st.ray_start[r]..st.ray_keep[r] {
                for k in 0..rows {
                    st.render_out[k * ld + o] = st.seg_out[k * ld_all + i];
                }
                o += 1;
            }
        }
        st.ray_start = starts;
    }

    /// Forward pass over a chunk of rays: marching, encoding, density, weights, early
    /// termination, colour of the surviving samples, compositing. `jitter(r)` gives ray `r`'s
    /// stratification offset. `mean_emb` is used for rays with `image == u32::MAX`.
    pub fn forward_chunk(
        &self,
        params: &[f32],
        occ: &OccupancyGrid,
        rays: &[RayInput],
        jitter: &dyn Fn(usize) -> f32,
        mean_emb: &[f32],
        st: &mut ChunkState,
    ) {
        for v in [
            &mut st.px, &mut st.py, &mut st.pz, &mut st.t, &mut st.dt, &mut st.m,
        ] {
            v.clear();
        }
        st.ray_start.clear();
        st.counters = SampleCounters::default();
        for (r, ray) in rays.iter().enumerate() {
            st.ray_start.push(st.t.len());
            self.march(ray, occ, jitter(r), st);
        }
        st.ray_start.push(st.t.len());
        st.counters.marched = st.t.len() as u64;
        if st.stop_at_termination {
            self.densities_until_termination(params, st);
        } else {
            let n = st.n();
            let ld = padded(n);
            st.ld = ld;
            let lf = self.grid.output_dim();
            // `encode` writes every entry (padding columns included): no clearing needed.
            st.enc.resize(lf * ld, 0.0);
            let pts = PointBatch {
                px: &st.px,
                py: &st.py,
                pz: &st.pz,
                n,
                ld,
            };
            self.grid
                .encode(&params[..self.density_offset], pts, &mut st.enc);
            let dp = &params[self.density_offset..self.color_offset];
            self.density.forward(dp, &st.enc, ld, &mut st.dens_acts);
            st.counters.density = n as u64;
        }
        let n = st.n();
        let ld = st.ld;
        let dout: &[f32] = if st.stop_at_termination {
            &st.render_out
        } else {
            &st.dens_acts[st.dens_acts.len() - 1]
        };
        st.sigma.clear();
        st.sigma.extend((0..n).map(|i| trunc_exp(dout[i])));
        st.w.clear();
        st.w.resize(n, 0.0);
        st.n_color.clear();
        st.alive.clear();
        for r in 0..rays.len() {
            let (a, b) = (st.ray_start[r], st.ray_start[r + 1]);
            let nc = volume::weights_forward(&st.sigma[a..b], &st.dt[a..b], &mut st.w[a..b]);
            let before = st.alive.len();
            let minw = st.min_color_weight;
            st.alive
                .extend((a..a + nc).filter(|&i| st.w[i] >= minw).map(|i| i as u32));
            st.n_color.push(st.alive.len() - before);
        }
        // Colour network on the surviving samples.
        let nc = st.alive.len();
        st.counters.color = nc as u64;
        let ldc = padded(nc);
        st.ldc = ldc;
        let e = self.config.appearance_dim as usize;
        let cin = GEO_FEAT_DIM + SH_COMPONENTS + e;
        // Columns `< nc` are written below; only the padding columns need zeros.
        st.col_in.resize(cin * ldc, 0.0);
        for k in 0..cin {
            st.col_in[k * ldc + nc..(k + 1) * ldc].fill(0.0);
        }
        // Row by row (each destination row is written sequentially; the same values as
        // filling column by column): geometry features gathered from the density output,
        // then each ray's view-direction encoding and embedding over its coloured samples.
        {
            // The coloured samples come in runs of consecutive indices (usually one per
            // ray): rows are copied run by run.
            st.alive_runs.clear();
            let mut j = 0;
            while j < nc {
                let first = st.alive[j] as usize;
                let mut len = 1;
                while j + len < nc && st.alive[j + len] as usize == first + len {
                    len += 1;
                }
                st.alive_runs.push((j, first, len));
                j += len;
            }
            let (geo, rest) = st.col_in.split_at_mut(GEO_FEAT_DIM * ldc);
            for k in 0..GEO_FEAT_DIM {
                let src = &dout[(1 + k) * ld..(2 + k) * ld];
                let dst = &mut geo[k * ldc..k * ldc + nc];
                for &(j, first, len) in &st.alive_runs {
                    dst[j..j + len].copy_from_slice(&src[first..first + len]);
                }
            }
            let mut j = 0;
            for (r, ray) in rays.iter().enumerate() {
                let cnt = st.n_color[r];
                let sh = sh_encode(ray.dir);
                for k in 0..SH_COMPONENTS {
                    rest[k * ldc + j..k * ldc + j + cnt].fill(sh[k]);
                }
                if e > 0 {
                    let emb: &[f32] = if ray.image == u32::MAX || ray.image >= self.config.n_images
                    {
                        mean_emb
                    } else {
                        let o = self.embedding_offset + ray.image as usize * e;
                        &params[o..o + e]
                    };
                    for k in 0..e {
                        let row = (SH_COMPONENTS + k) * ldc;
                        rest[row + j..row + j + cnt].fill(emb[k]);
                    }
                }
                j += cnt;
            }
        }
        let cp = &params[self.color_offset..self.embedding_offset];
        self.color.forward(cp, &st.col_in, ldc, &mut st.col_acts);
        let cout = &st.col_acts[st.col_acts.len() - 1];
        st.rgb.resize(3 * ldc, 0.0);
        for k in 0..3 {
            st.rgb[k * ldc + nc..(k + 1) * ldc].fill(0.0);
        }
        for k in 0..3 {
            for j in 0..nc {
                st.rgb[k * ldc + j] = sigmoid(cout[k * ldc + j]);
            }
        }
        // Compositing.
        st.out.clear();
        let mut j0 = 0;
        for (r, ray) in rays.iter().enumerate() {
            let (a, b) = (st.ray_start[r], st.ray_start[r + 1]);
            let ncr = st.n_color[r];
            // Σ w_i c_i over the ray's coloured samples (in sample order, as
            // `volume::composite_color` sums).
            let mut c = [0f32; 3];
            for q in 0..ncr {
                let j = j0 + q;
                let wi = st.w[st.alive[j] as usize];
                for k in 0..3 {
                    c[k] += wi * st.rgb[k * ldc + j];
                }
            }
            let (acc, depth) = volume::opacity_depth(&st.w[a..b], &st.t[a..b]);
            let bg = ray.background;
            st.out.push(RayOutput {
                rgb: [
                    c[0] + (1.0 - acc) * bg[0],
                    c[1] + (1.0 - acc) * bg[1],
                    c[2] + (1.0 - acc) * bg[2],
                ],
                acc,
                depth,
            });
            j0 += ncr;
        }
        st.g.clear();
        st.g.resize(n, 0.0);
        st.d_rgb.clear();
        st.d_rgb.resize(3 * ldc, 0.0);
    }
}
