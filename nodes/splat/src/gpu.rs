//! The GPU backend: the renderer's ([`augsplat_render::gpu`], re-exported here) and the
//! trainer's kernels on the same context — the losses (`loss/gpu.rs`), Adam (`adam/gpu.rs`)
//! and the training state kept on the GPU between steps (`train/gpu.rs`).

pub use augsplat_render::gpu::*;

pub use crate::loss::gpu::{loss_gpu, pack_u8, u8_values_table, GpuLoss};
pub(crate) use crate::train::gpu::{GpuTarget, GpuTrainer, PendingView, ViewLoss, ViewResult};
