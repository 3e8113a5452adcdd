//! augsplat-field: the radiance-field ensemble member of AugSplat, on the CPU and the GPU.
//!
//! A nerfacto-like field — multiresolution hash encoding ([`hashgrid`]), density MLP with
//! truncated exp and colour MLP on geometry features + SH-encoded view direction ([`field`],
//! [`mlp`], [`sh`]), mip-NeRF 360 contraction ([`contraction`]) — sampled through an occupancy
//! grid over contracted space ([`occupancy`]) and volume-rendered with analytic gradients
//! ([`volume`]). Training ([`train`]) uses Adam over fixed ray chunks with a fixed-order
//! gradient reduction, so results are bit-identical for any thread count. [`mod@reference`] holds
//! naive f64 versions of every kernel for tests. The node kinds are in [`node`].
//!
//! The GPU path ([`gpu`], `backend: Gpu` on the nodes) runs the same maths through wgpu on the
//! splatting's context: marching, the hash encoding and its deterministic table gradients
//! ([`hashgrid::gpu`]), both MLPs ([`mlp::gpu`]), volume rendering, the losses and their
//! backward, the occupancy grid and Adam, for training and for rendering.

// Kernels index several parallel arrays (SoA rows, accumulators, weights) with one index;
// iterator zips over four or five slices would hide the maths.
#![allow(clippy::needless_range_loop)]

pub mod checkpoint;
pub mod constants;
pub mod contraction;
pub mod error;
pub mod field;
pub mod gpu;
pub mod hashgrid;
pub mod io;
pub mod mlp;
pub mod node;
pub mod occupancy;
pub mod reference;
pub mod render;
pub mod sh;
pub mod train;
pub mod volume;

pub use error::FieldError;
/// The node kinds' module under its former name (`augsplat_field::nodes::…` paths still
/// resolve); the module is [`node`], as in every node family.
pub use node as nodes;
pub use node::{RenderField, RenderFieldArgs, TrainField, TrainFieldArgs};

/// Registers `TrainField` and `RenderField`.
pub fn register(registry: &mut augsplat_graph::Registry) {
    registry.register::<TrainField>();
    registry.register::<RenderField>();
}

#[cfg(test)]
mod tests {
    #[test]
    fn the_former_module_name_still_resolves() {
        let _: fn() -> crate::nodes::TrainFieldArgs = crate::node::TrainFieldArgs::default;
        let _: fn() -> crate::nodes::RenderFieldArgs = crate::node::RenderFieldArgs::default;
    }
}
