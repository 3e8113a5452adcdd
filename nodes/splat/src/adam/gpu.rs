//! Adam on the GPU (`adam.wgsl`): one dispatch per parameter group with the constants the
//! CPU's [`super::Adam`] computes ([`super::GpuStepConst`]); the training state records it
//! (`train/gpu.rs`).

/// The compiled Adam kernel.
pub(crate) struct Kernels {
    /// One group's update.
    pub(crate) adam: wgpu::ComputePipeline,
}

impl Kernels {
    pub(crate) fn new(m: crate::gpu::ModuleSetup<'_>) -> Kernels {
        let [adam] = crate::gpu::pipelines(m, "adam.wgsl", include_str!("adam.wgsl"), ["adam"]);
        Kernels { adam }
    }
}
