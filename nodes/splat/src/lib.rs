//! augsplat-splat: differentiable 3D Gaussian splatting on the CPU, and its training.
//!
//! The maths is gsplat's classic rasteriser (docs/design.md, *Projection* and *Compositing*):
//! each Gaussian is projected with an EWA Jacobian ([`project`]) and coloured by its
//! spherical harmonics ([`sh`]); the projected Gaussians are binned into 16×16 tiles in
//! depth order ([`tiles`]) and composited front to back per tile ([`forward`]); the analytic
//! backward pass walks each tile back to front and sums each Gaussian's pair gradients in a
//! fixed order ([`mod@backward`]), so gradients are bit-identical for any thread count.
//! [`mod@render`] holds the public entry points and [`mod@reference`] an untiled f64 renderer for
//! the tests.
//!
//! Training: [`loss`] (L1, L2, weighted L2, fused SSIM), [`adam`], [`densify`] (gsplat's
//! default strategy), [`init`] (initial Gaussians), [`supervision`] and [`schedule`] (real
//! and synthetic views: Baseline, Staged, Dual), [`train`] (one step), [`fit`] (a whole run:
//! evaluation cadence, patience, checkpoint choice) and the node kind in [`node`].
//!
//! # Kernel families
//!
//! Each hot kernel is a folder: `mod.rs` (what the operation is, and dispatch by the tier of
//! [`augsplat_core::simd`]), the portable twin that states the maths (`tile.rs`, `portable.rs`,
//! `fused.rs`), one file per instruction set (`avx2.rs`), and `tests.rs` comparing every tier
//! bit for bit against the twin; the f64 references live in [`mod@reference`] and
//! [`loss::reference`].
//!
//! | family | portable twin | AVX2 | other files |
//! |---|---|---|---|
//! | [`forward`] | `tile.rs` | `avx2.rs` | `exp2.rs` (the exponential, row geometry), `project_chunk.rs` |
//! | [`mod@backward`] | `tile.rs` | `avx2.rs` | `gaussian.rs` (per-Gaussian sums, projection and SH backward) |
//! | `lanes` (f64 × 8 for projection and SH) | `portable.rs` | `avx2.rs` | `math.rs` (exp, ln, sigmoid) |
//! | [`loss`] | `fused.rs` | `pair_avx2.rs` | `reference.rs` |
//! | [`adam`] | `mod.rs` (one body, compiled per tier by `augsplat_core::multiversion!`) | | |

pub mod adam;
pub mod backward;
mod buffers;
pub mod constants;
pub mod densify;
pub mod device;
pub mod error;
pub mod fit;
pub mod forward;
pub mod gaussians;
pub mod gpu;
pub mod init;
pub mod inputs;
mod lanes;
pub mod loss;
pub mod node;
pub mod ply;
pub mod project;
pub mod reference;
pub mod render;
pub mod schedule;
pub mod sh;
pub mod supervision;
pub mod tiles;
pub mod train;

pub use device::{Backend, Device};
pub use error::SplatError;
pub use gaussians::Gaussians;
pub use node::{register, OptimizeSplats};
pub use ply::{read_ply, write_ply};
pub use render::{
    backward, backward_add, render, render_masked, Gradients, RenderOutput, RenderSettings,
    RenderStats,
};
