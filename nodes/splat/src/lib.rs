//! augsplat-splat: training 3D Gaussian splats on the renderer of `augsplat-render`, and the
//! `OptimizeSplats` node.
//!
//! Training: [`loss`] (L1, L2, weighted L2, fused SSIM), [`adam`], [`densify`] (gsplat's
//! default strategy), [`init`] (initial Gaussians), [`supervision`] and [`schedule`] (real
//! and synthetic views: Baseline, Staged, Dual), [`train`] (one step, written once over the
//! [`device`] seam: the CPU or the GPU), [`fit`] (a whole run: evaluation cadence, patience,
//! checkpoint choice), [`inputs`] (what a run reads from folders) and the node kind in
//! [`node`]. The renderer's modules are re-exported under their own names, so
//! `augsplat_splat::render`, `augsplat_splat::gpu` and the rest keep working.
//!
//! # Kernel families
//!
//! As in the renderer, each hot kernel is a folder with its portable twin, one file per
//! instruction set or backend and its tests:
//!
//! | family | portable twin | AVX2 | GPU | other files |
//! |---|---|---|---|---|
//! | [`loss`] | `fused.rs` | `pair_avx2.rs` | `gpu.rs`, `loss.wgsl` | `reference.rs` |
//! | [`adam`] | `mod.rs` (one body, compiled per tier by `augsplat_core::multiversion!`) | | `gpu.rs`, `adam.wgsl` | |
//! | [`train`] (the GPU's training state) | | | `gpu.rs`, `accumulate.wgsl` | |

pub mod adam;
pub mod densify;
pub mod device;
pub mod dropout;
pub mod fit;
pub mod gpu;
pub mod init;
pub mod inputs;
pub mod loss;
pub mod node;
pub mod schedule;
pub mod supervision;
pub mod train;

pub use augsplat_render::{
    backward, constants, error, forward, gaussians, ply, project, reference, render, sh, tiles,
};
pub use augsplat_render::{
    backward_add, read_ply, render_masked, write_ply, Gaussians, Gradients, RenderOutput,
    RenderSettings, RenderStats, SplatError,
};
pub use device::{Backend, Device};
pub use node::{register, OptimizeSplats};
