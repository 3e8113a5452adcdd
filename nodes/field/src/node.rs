//! The node kinds: `TrainField` (one ensemble member) and `RenderField`.

use crate::error::FieldError;
use crate::field::{Field, FieldConfig};
use crate::hashgrid::HashGridConfig;
use crate::io::{self, WeightsMeta};
use crate::train::{self, TrainOptions};
use augsplat_core::artifacts::{self, files, PoseSet, RenderSet, RenderedView};
use augsplat_graph::{InputDecl, Node, NodeError, RunContext, Threads};
use augsplat_render::gpu::GpuContext;
use augsplat_render::Backend;
use rayon::prelude::*;
use serde::{Deserialize, Serialize};
use std::sync::atomic::{AtomicU64, Ordering};

/// Arguments of [`TrainField`].
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct TrainFieldArgs {
    /// Seed of the initialisation and of every ray batch (one per ensemble member).
    pub seed: u64,
    /// Optimisation steps.
    pub steps: u32,
    /// Rays per step.
    pub rays_per_step: u32,
    /// Rays per parallel chunk (part of the result's definition: changing it changes the
    /// order of gradient sums).
    pub chunk_rays: u32,
    /// Hash-grid levels.
    pub levels: u32,
    /// Features per level.
    pub features_per_level: u32,
    /// log2 of the hash-table size per level.
    pub log2_table_size: u32,
    /// Coarsest grid resolution.
    pub base_resolution: u32,
    /// Finest grid resolution.
    pub max_resolution: u32,
    /// Hidden width of both MLPs.
    pub hidden_width: u32,
    /// Learn a per-image appearance embedding (renders use the mean embedding).
    pub appearance_embedding: bool,
    /// Width of the appearance embedding.
    pub appearance_dim: u32,
    /// Initial Adam learning rate.
    pub learning_rate: f32,
    /// Final learning rate as a fraction of the initial one (exponential decay).
    pub lr_final_factor: f32,
    /// Weight of the DS-NeRF depth loss (0 = off; needs depth maps in the scene).
    pub depth_loss_weight: f32,
    /// Spread of the depth loss, relative to the target depth.
    pub depth_sigma: f32,
    /// Weight of the distortion loss (0 = off).
    pub distortion_loss_weight: f32,
    /// Random per-ray background while training (forces opaque geometry).
    pub random_background: bool,
    /// Background for evaluation and rendering (and training when not random).
    pub background: [f32; 3],
    /// World distance mapped to the contraction's unit ball (0 = automatic: the largest of the
    /// camera spread around their mean and the scene's near bound).
    pub contraction_radius: f64,
    /// Marching steps across the contracted ball's diameter.
    pub march_steps: u32,
    /// Occupancy grid cells per axis.
    pub occupancy_resolution: u32,
    /// Steps before the first occupancy update.
    pub occupancy_warmup: u32,
    /// Held-out evaluation every this many steps (0 = only at the end).
    pub eval_every: u32,
    /// Integer downscale of the training (and test) images.
    pub downscale: u32,
    /// Where the field trains: `Cpu` (default) or `Gpu` (wgpu: marching, both networks, the
    /// losses, the hash table's gradient, the occupancy grid and Adam on the device; identical
    /// bytes run to run on one adapter, within the tests' tolerances of the CPU). Left out of
    /// the serialised args when `Cpu`, so CPU keys did not change when it was added.
    #[serde(skip_serializing_if = "Backend::is_cpu")]
    pub backend: Backend,
}

impl Default for TrainFieldArgs {
    fn default() -> Self {
        TrainFieldArgs {
            seed: 0,
            steps: 2000,
            rays_per_step: 1024,
            chunk_rays: 64,
            levels: 16,
            features_per_level: 2,
            log2_table_size: 17,
            base_resolution: 16,
            max_resolution: 2048,
            hidden_width: 64,
            appearance_embedding: false,
            appearance_dim: 16,
            learning_rate: 1e-2,
            lr_final_factor: 0.1,
            depth_loss_weight: 0.1,
            depth_sigma: 0.05,
            distortion_loss_weight: 0.0,
            random_background: true,
            background: [0.0; 3],
            contraction_radius: 0.0,
            march_steps: 128,
            occupancy_resolution: 64,
            occupancy_warmup: 256,
            eval_every: 0,
            downscale: 1,
            backend: Backend::Cpu,
        }
    }
}

impl TrainFieldArgs {
    /// Training options for the loop.
    pub fn options(&self) -> TrainOptions {
        TrainOptions {
            seed: self.seed,
            steps: self.steps,
            rays_per_step: self.rays_per_step,
            chunk_rays: self.chunk_rays,
            learning_rate: self.learning_rate,
            lr_final_factor: self.lr_final_factor,
            depth_loss_weight: self.depth_loss_weight,
            depth_sigma: self.depth_sigma,
            distortion_loss_weight: self.distortion_loss_weight,
            random_background: self.random_background,
            background: self.background,
            occupancy_warmup: self.occupancy_warmup,
            eval_every: self.eval_every,
        }
    }

    /// The field configuration for a scene.
    pub fn field_config(
        &self,
        scene: &augsplat_core::Scene,
        n_images: usize,
    ) -> Result<FieldConfig, FieldError> {
        let n = scene.views.len().max(1) as f64;
        let mut center = [0f64; 3];
        for v in &scene.views {
            let c = v.camera.center();
            for k in 0..3 {
                center[k] += c[k] / n;
            }
        }
        let spread = scene
            .views
            .iter()
            .map(|v| {
                let c = v.camera.center();
                ((c[0] - center[0]).powi(2)
                    + (c[1] - center[1]).powi(2)
                    + (c[2] - center[2]).powi(2))
                .sqrt()
            })
            .fold(0f64, f64::max);
        let radius = if self.contraction_radius > 0.0 {
            self.contraction_radius
        } else {
            spread.max(scene.near).max(1e-3)
        };
        let cfg = FieldConfig {
            grid: HashGridConfig {
                levels: self.levels,
                features_per_level: self.features_per_level,
                log2_table_size: self.log2_table_size,
                base_resolution: self.base_resolution,
                max_resolution: self.max_resolution,
            },
            hidden_width: self.hidden_width,
            appearance_dim: if self.appearance_embedding {
                self.appearance_dim
            } else {
                0
            },
            n_images: n_images as u32,
            center,
            radius,
            near: scene.near,
            far: scene.far,
            march_steps: self.march_steps,
            occupancy_resolution: self.occupancy_resolution,
        };
        cfg.validate()?;
        Ok(cfg)
    }
}

/// Trains one radiance-field ensemble member.
///
/// Inputs: `train` (scene folder, optional depth maps), optional `test` (held-out scene for
/// PSNR). Output: `weights` (`field.safetensors`, `config.json`, `curve.json`).
pub struct TrainField;

impl Node for TrainField {
    const KIND: &'static str = "TrainField";
    const VERSION: u32 = 3;
    type Args = TrainFieldArgs;

    fn inputs(_: &Self::Args) -> Vec<InputDecl> {
        vec![InputDecl::one("train"), InputDecl::optional("test")]
    }
    fn outputs(_: &Self::Args) -> Vec<String> {
        vec!["weights".into()]
    }
    fn threads(_: &Self::Args) -> Threads {
        Threads::All
    }
    fn validate(a: &Self::Args) -> Result<(), String> {
        if a.steps == 0 || a.rays_per_step == 0 || a.chunk_rays == 0 {
            return Err("steps, rays_per_step and chunk_rays must be positive".into());
        }
        if !(a.learning_rate.is_finite() && a.learning_rate > 0.0 && a.learning_rate <= 1.0) {
            return Err(format!(
                "learning_rate = {} must be in (0, 1]",
                a.learning_rate
            ));
        }
        if !(a.lr_final_factor.is_finite() && a.lr_final_factor > 0.0 && a.lr_final_factor <= 1.0) {
            return Err(format!(
                "lr_final_factor = {} must be in (0, 1]",
                a.lr_final_factor
            ));
        }
        for (n, v) in [
            ("depth_loss_weight", a.depth_loss_weight),
            ("distortion_loss_weight", a.distortion_loss_weight),
        ] {
            if !(v.is_finite() && v >= 0.0) {
                return Err(format!("{n} = {v} must be finite and ≥ 0"));
            }
        }
        if !(a.depth_sigma.is_finite() && a.depth_sigma > 0.0) {
            return Err(format!("depth_sigma = {} must be positive", a.depth_sigma));
        }
        if !(a.contraction_radius.is_finite() && a.contraction_radius >= 0.0) {
            return Err(format!(
                "contraction_radius = {} must be ≥ 0 (0 = automatic)",
                a.contraction_radius
            ));
        }
        if a.downscale == 0 {
            return Err("downscale must be ≥ 1".into());
        }
        if a.background.iter().any(|v| !v.is_finite()) {
            return Err("background must be finite".into());
        }
        HashGrid::new(HashGridConfig {
            levels: a.levels,
            features_per_level: a.features_per_level,
            log2_table_size: a.log2_table_size,
            base_resolution: a.base_resolution,
            max_resolution: a.max_resolution,
        })
        .map_err(|e| e.to_string())?;
        Ok(())
    }
    fn run(a: &Self::Args, ctx: &mut RunContext) -> Result<(), NodeError> {
        let train_dir = ctx.input("train")?.to_path_buf();
        let (scene, views) = train::load_views(&train_dir, a.downscale)?;
        let test = match ctx.optional_input("test") {
            Some(d) => Some(train::load_views(d, a.downscale)?.1),
            None => None,
        };
        let cfg = a.field_config(&scene, views.len())?;
        let field = Field::new(cfg)?;
        ctx.log(format!(
            "TrainField seed {}: {} views, {} params, radius {:.3}, near {:.3}, far {:.3}",
            a.seed,
            views.len(),
            field.n_params,
            field.config.radius,
            field.config.near,
            field.config.far
        ));
        let start = std::time::Instant::now();
        let opts = a.options();
        let steps = a.steps;
        let gpu = open_gpu(a.backend)?;
        if let Some(g) = &gpu {
            ctx.log(format!("training on the GPU: {}", g.adapter()));
        }
        let (state, curve) = {
            let ctx_ref = &*ctx;
            let mut on_step = |r: train::StepReport<'_>| {
                if r.step.is_multiple_of(10) || r.step == steps {
                    ctx_ref.progress(
                        r.step as u64,
                        steps as u64,
                        &format!("loss {:.5}", r.stats.rgb_loss),
                    );
                }
            };
            let mut save = |bytes: Vec<u8>| {
                ctx_ref
                    .save_checkpoint(&bytes)
                    .map_err(|e| e.message().to_string())
            };
            let mut log = |line: String| ctx_ref.log(line);
            let checkpoints = ctx_ref
                .checkpoint_every()
                .map(|every| train::FieldCheckpoints {
                    every,
                    resume: ctx_ref.load_checkpoint(),
                    save: &mut save,
                    log: &mut log,
                });
            match &gpu {
                Some(g) => crate::gpu::train::train_gpu(
                    g,
                    &field,
                    &views,
                    test.as_deref(),
                    &opts,
                    checkpoints,
                    &mut on_step,
                )?,
                None => train::train_resumable(
                    &field,
                    &views,
                    test.as_deref(),
                    &opts,
                    checkpoints,
                    &mut on_step,
                )?,
            }
        };
        for p in &curve.points {
            ctx.log(format!(
                "step {}: held-out PSNR {:.3} dB, train loss {:.5}",
                p.step, p.psnr, p.loss
            ));
        }
        ctx.log(format!(
            "trained {} steps in {:.1} s; skipped {} non-finite steps; occupancy {:.1}%",
            steps,
            start.elapsed().as_secs_f64(),
            state.skipped_steps,
            100.0 * state.occupancy.occupied_fraction()
        ));
        let out = ctx.output("weights")?.to_path_buf();
        let meta = WeightsMeta {
            field: field.config.clone(),
            background: a.background,
            steps,
            skipped_steps: state.skipped_steps,
            nonfinite_values: state.nonfinite_values,
        };
        io::save(&out, &meta, &field, &state.params, &state.occupancy)?;
        artifacts::write_json(&out.join(files::CURVE), &curve)?;
        if let Some(g) = &gpu {
            artifacts::write_json(&out.join(DEVICE_FILE), g.adapter())?;
        }
        Ok(())
    }
}

use crate::hashgrid::HashGrid;

/// The file naming the GPU adapter an output was computed on (absent for the CPU).
pub const DEVICE_FILE: &str = "device.json";

/// The GPU context a node's `backend` asks for: none for the CPU, an error naming what was
/// found when the machine has no adapter (never a fall-back to the CPU).
fn open_gpu(backend: Backend) -> Result<Option<GpuContext>, NodeError> {
    match backend {
        Backend::Cpu => Ok(None),
        Backend::Gpu => GpuContext::new()
            .map(Some)
            .map_err(|e| NodeError::new(format!("backend: Gpu: {e}"))),
    }
}

/// Arguments of [`RenderField`].
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct RenderFieldArgs {
    /// Rays per parallel chunk (does not change the result).
    pub chunk_rays: u32,
    /// Extra integer downscale applied to the poses' cameras.
    pub downscale: u32,
    /// Background colour; `None` = the one stored with the weights.
    pub background: Option<[f32; 3]>,
    /// Where the views render: `Cpu` (default) or `Gpu` (wgpu, the views' rays batched into
    /// shared passes). Left out of the serialised args when `Cpu`.
    #[serde(skip_serializing_if = "Backend::is_cpu")]
    pub backend: Backend,
}

impl Default for RenderFieldArgs {
    fn default() -> Self {
        RenderFieldArgs {
            chunk_rays: 256,
            downscale: 1,
            background: None,
            backend: Backend::Cpu,
        }
    }
}

/// Renders a trained field at a set of poses.
///
/// Inputs: `weights` (from [`TrainField`]), `poses` (`poses.json`). Output: `renders`
/// (`renders.json` + `view_NNNN.exr` with channels R, G, B, D (expected depth along the
/// optical axis, 0 where nothing was hit), A (accumulated opacity)).
pub struct RenderField;

impl Node for RenderField {
    const KIND: &'static str = "RenderField";
    const VERSION: u32 = 3;
    type Args = RenderFieldArgs;

    fn inputs(_: &Self::Args) -> Vec<InputDecl> {
        vec![InputDecl::one("weights"), InputDecl::one("poses")]
    }
    fn outputs(_: &Self::Args) -> Vec<String> {
        vec!["renders".into()]
    }
    fn threads(_: &Self::Args) -> Threads {
        Threads::All
    }
    fn validate(a: &Self::Args) -> Result<(), String> {
        if a.chunk_rays == 0 || a.downscale == 0 {
            return Err("chunk_rays and downscale must be ≥ 1".into());
        }
        if let Some(b) = a.background {
            if b.iter().any(|v| !v.is_finite()) {
                return Err("background must be finite".into());
            }
        }
        Ok(())
    }
    fn run(a: &Self::Args, ctx: &mut RunContext) -> Result<(), NodeError> {
        let loaded = io::load(ctx.input("weights")?)?;
        let poses_path = ctx.input("poses")?.join(files::POSES);
        let poses: PoseSet = artifacts::read_json(&poses_path)?;
        let out = ctx.output("renders")?.to_path_buf();
        let bg = a.background.unwrap_or(loaded.meta.background);
        let total = poses.views.len() as u64;
        // Cameras are checked first, in order, so that a bad pose is reported before any work.
        let mut cams = Vec::with_capacity(poses.views.len());
        for pv in &poses.views {
            pv.camera.validate().map_err(|e| {
                NodeError::new(format!("{}: pose {}: {e}", poses_path.display(), pv.name))
            })?;
            cams.push(pv.camera.downscaled(a.downscale));
        }
        let done = AtomicU64::new(0);
        let ctx_ref = &*ctx;
        // Writes view `i`'s planes and reports progress.
        let write = |i: usize,
                     cam: augsplat_core::Camera,
                     name: &str,
                     img: &train::RenderedImage|
         -> Result<(RenderedView, u64, train::RenderStats), NodeError> {
            let file = format!("view_{i:04}.exr");
            let plane = |c: usize| {
                img.rgb
                    .iter()
                    .skip(c)
                    .step_by(3)
                    .copied()
                    .collect::<Vec<f32>>()
            };
            let (r, g, b) = (plane(0), plane(1), plane(2));
            augsplat_core::image::write_exr(
                &out.join(&file),
                cam.width,
                cam.height,
                &[
                    ("R", &r),
                    ("G", &g),
                    ("B", &b),
                    ("D", &img.depth),
                    ("A", &img.acc),
                ],
            )?;
            let rays = cam.width as u64 * cam.height as u64;
            let finished = done.fetch_add(1, Ordering::Relaxed) + 1;
            ctx_ref.progress(finished, total, name);
            Ok((
                RenderedView {
                    name: name.to_string(),
                    camera: cam,
                    file,
                },
                rays,
                img.stats,
            ))
        };
        let gpu = open_gpu(a.backend)?;
        let views: Vec<(RenderedView, u64, train::RenderStats)> = match &gpu {
            Some(g) => {
                ctx_ref.log(format!("rendering on the GPU: {}", g.adapter()));
                let images = crate::gpu::render::render_cameras_gpu(
                    g,
                    &loaded.field,
                    &loaded.params,
                    &loaded.occupancy,
                    &cams,
                    bg,
                )
                .map_err(|e| NodeError::new(e.to_string()))?;
                let mut views = Vec::with_capacity(cams.len());
                for (i, ((cam, pv), img)) in
                    cams.into_iter().zip(&poses.views).zip(&images).enumerate()
                {
                    views.push(write(i, cam, &pv.name, img)?);
                }
                views
            }
            // Views render in parallel, each in parallel chunks (rayon balances the two
            // levels): no barrier between views, and each view's file is written by the thread
            // that rendered it. Every view's pixels are the same as rendered alone.
            None => cams
                .into_par_iter()
                .zip(poses.views.par_iter())
                .enumerate()
                .map(|(i, (cam, pv))| {
                    let img = train::render_camera(
                        &loaded.field,
                        &loaded.params,
                        &loaded.occupancy,
                        &cam,
                        bg,
                        a.chunk_rays as usize,
                    );
                    write(i, cam, &pv.name, &img)
                })
                .collect::<Result<_, _>>()?,
        };
        let mut set = RenderSet::default();
        let (mut rays, mut stats) = (0u64, train::RenderStats::default());
        for (view, r, s) in views {
            rays += r;
            stats.add(&s);
            set.views.push(view);
        }
        artifacts::write_json(&out.join(files::RENDERS), &set)?;
        if let Some(g) = &gpu {
            artifacts::write_json(&out.join(DEVICE_FILE), g.adapter())?;
        }
        let per_ray = |v: u64| v as f64 / rays.max(1) as f64;
        ctx.log(format!(
            "{total} views, {rays} rays; per ray: {:.1} marching steps, {:.1} samples in occupied cells, {:.1} through the density network (early termination), {:.1} through the colour network",
            per_ray(stats.steps),
            per_ray(stats.marched),
            per_ray(stats.density),
            per_ray(stats.color)
        ));
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// `backend: Cpu` is left out of the serialised args (so no key from before the field
    /// had a backend moved); `Gpu` is written and read back.
    #[test]
    fn the_cpu_backend_is_left_out_of_the_args() {
        let cpu = serde_json::to_string(&TrainFieldArgs::default()).unwrap();
        assert!(!cpu.contains("backend"), "{cpu}");
        let cpu = serde_json::to_string(&RenderFieldArgs::default()).unwrap();
        assert!(!cpu.contains("backend"), "{cpu}");
        let gpu = TrainFieldArgs {
            backend: Backend::Gpu,
            ..TrainFieldArgs::default()
        };
        let text = serde_json::to_string(&gpu).unwrap();
        assert!(text.contains("\"backend\":\"Gpu\""), "{text}");
        let back: TrainFieldArgs = serde_json::from_str(&text).unwrap();
        assert_eq!(back, gpu);
        let render: RenderFieldArgs = ron::from_str("(backend: Gpu)").unwrap();
        assert_eq!(render.backend, Backend::Gpu);
    }
}
