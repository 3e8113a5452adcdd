//! The projection's GPU kernels: `project.wgsl` (projection, culling, SH colour and the tile
//! rectangles, the twin of [`super::project`] and [`crate::sh`]) and `project_vjp.wgsl` (its
//! backward, the twin of `project_vjp_lanes` in `project/mod.rs`). The forward pass records the first
//! (`forward/gpu.rs`), the backward pass the second (`backward/gpu.rs`).

/// The compiled projection kernels.
pub(crate) struct Kernels {
    /// Projection and colour.
    pub(crate) project: wgpu::ComputePipeline,
    /// Gradients of the raw parameters from the screen-space ones.
    pub(crate) project_vjp: wgpu::ComputePipeline,
}

impl Kernels {
    pub(crate) fn new(m: crate::gpu::ModuleSetup<'_>) -> Kernels {
        let [project] =
            crate::gpu::pipelines(m, "project.wgsl", include_str!("project.wgsl"), ["project"]);
        let [project_vjp] = crate::gpu::pipelines(
            m,
            "project_vjp.wgsl",
            include_str!("project_vjp.wgsl"),
            ["project_vjp"],
        );
        Kernels {
            project,
            project_vjp,
        }
    }
}
