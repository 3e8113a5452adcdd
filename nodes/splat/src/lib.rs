//! Differentiable 3D Gaussian splatting on the CPU.

pub mod adam;
pub mod backward;
mod buffers;
pub mod constants;
pub mod densify;
pub mod error;
pub mod fit;
pub mod forward;
pub mod gaussians;
pub mod init;
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

pub use error::SplatError;
pub use gaussians::Gaussians;
pub use node::{register, OptimizeSplats};
pub use ply::{read_ply, write_ply};
pub use render::{
    backward, backward_add, render, render_masked, Gradients, RenderOutput, RenderSettings,
    RenderStats,
};
