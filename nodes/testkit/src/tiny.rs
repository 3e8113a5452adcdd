//! The tiny sizes at which the tests run the method pipelines.
//!
//! `tests/tiny.ron` is the demo at these sizes; [`SETS`] are the same values as `--set`
//! overrides, for tests that run other pipelines (the sweeps) at the same sizes. A CLI test
//! checks that `augsplat expand tests/tiny.ron` equals the demo expanded with [`SETS`].

/// A 48×40 scene of 12 views (large enough for LPIPS-alex), fields of 10 steps, 6 synthetic poses at 16×12, 20 Gaussian
/// steps, LPIPS off: the tests check structure, not quality.
pub const SETS: &[&str] = &[
    "scene.width=48",
    "scene.height=40",
    "scene.views=12",
    "scene.points=400",
    "scene.supersample=1",
    "split.count=None",
    "field.steps=10",
    "field.rays_per_step=64",
    "field.chunk_rays=32",
    "field.levels=4",
    "field.log2_table_size=10",
    "field.max_resolution=64",
    "field.march_steps=16",
    "field.occupancy_resolution=16",
    "poses.count=6",
    "poses.downscale=2",
    "params.gs_steps=20",
    "params.eval_every=10",
    "params.warmup=10",
    "params.synthetic_batch=2",
    "params.lpips=None",
];

/// `tests/tiny.ron` in the workspace.
pub fn pipeline() -> std::path::PathBuf {
    crate::workspace_root().join("tests/tiny.ron")
}

/// The scene gate's rehearsal (`pipelines/fragments/gate.ron`) at the same tiny sizes.
pub const GATE_SETS: &[&str] = &[
    "params.gate_field_steps=10",
    "params.gate_gs_steps=20",
    "params.gate_eval_every=10",
    "params.gate_synthetic=4",
    "params.gate_synthetic_batch=2",
    "params.gate_warmup=5",
    "gate_field.rays_per_step=64",
    "gate_field.chunk_rays=32",
    "gate_field.levels=4",
    "gate_field.log2_table_size=10",
    "gate_field.max_resolution=64",
    "gate_field.march_steps=16",
    "gate_field.occupancy_resolution=16",
    "gate_field.occupancy_warmup=4",
];

/// [`SETS`] without the generated scene's sizes, for pipelines that import a scene instead.
pub fn sets_without_scene() -> impl Iterator<Item = &'static str> {
    SETS.iter().copied().filter(|s| !s.starts_with("scene."))
}
