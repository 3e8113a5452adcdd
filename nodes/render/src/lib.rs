//! augsplat-render: the differentiable 3D Gaussian splatting renderer, on the CPU and on the
//! GPU, and the Inria PLY layout. The trainer (`augsplat-splat`) builds on it.
//!
//! The maths is gsplat's classic rasteriser (docs/design.md, *Projection* and *Compositing*):
//! each Gaussian is projected with an EWA Jacobian ([`project`]) and coloured by its
//! spherical harmonics ([`sh`]); the projected Gaussians are binned into 16×16 tiles in
//! depth order ([`tiles`]) and composited front to back per tile ([`forward`]); the analytic
//! backward pass walks each tile back to front and sums each Gaussian's pair gradients in a
//! fixed order ([`mod@backward`]), so gradients are bit-identical for any thread count.
//! [`mod@render`] holds the public entry points and [`mod@reference`] an untiled f64 renderer for
//! the tests. [`gpu`] runs the same maths in WGSL through wgpu, deterministically.
//!
//! # Kernel families
//!
//! Each hot kernel is a folder: `mod.rs` (what the operation is, and dispatch by the tier of
//! [`augsplat_core::simd`]), the portable twin that states the maths (`tile.rs`,
//! `portable.rs`), one file per instruction set or backend (`avx2.rs`; `gpu.rs` with its
//! `.wgsl`), and `tests.rs` comparing every tier bit for bit against the twin; the f64
//! references live in [`mod@reference`].
//!
//! | family | portable twin | AVX2 | GPU | other files |
//! |---|---|---|---|---|
//! | [`forward`] | `tile.rs` | `avx2.rs` | `gpu.rs`, `forward.wgsl` | `exp2.rs` (the exponential, row geometry), `project_chunk.rs` |
//! | [`mod@backward`] | `tile.rs` | `avx2.rs` | `gpu.rs`, `backward.wgsl` | `gaussian.rs` (per-Gaussian sums, projection and SH backward) |
//! | [`project`] | `mod.rs` | via `lanes` | `gpu.rs`, `project.wgsl`, `project_vjp.wgsl` | |
//! | `lanes` (f64 × 8 for projection and SH) | `portable.rs` | `avx2.rs` | | `math.rs` (exp, ln, sigmoid) |
//!
//! [`gpu`] holds what the GPU families share: the context, the buffer layout past one
//! binding, the WGSL prelude generated from the Rust constants, and sort and scan.

pub mod backend;
pub mod backward;
mod buffers;
pub mod constants;
pub mod error;
pub mod forward;
pub mod gaussians;
pub mod gpu;
mod lanes;
pub mod ply;
pub mod project;
pub mod reference;
pub mod render;
pub mod sh;
pub mod tiles;

pub use backend::Backend;
pub use backward::ParamGrads;
pub use error::SplatError;
pub use gaussians::Gaussians;
pub use ply::{read_ply, write_ply};
pub use render::{
    backward, backward_add, render, render_masked, Gradients, RenderOutput, RenderSettings,
    RenderStats,
};
