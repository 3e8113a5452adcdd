//! Differentiable 3D Gaussian splatting on the CPU.

pub mod gaussians;

pub use gaussians::Gaussians;
