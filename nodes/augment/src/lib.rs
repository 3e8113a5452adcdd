//! augsplat-augment: AugSplat's augmentation stage (docs/design.md, *The method*).
//!
//! - [`poses`]: synthetic camera poses near the training cameras (jittered copies and
//!   neighbour interpolations, then N drawn), with a report of how near they stay;
//! - [`aggregate`]: ensemble aggregation kernels — per-pixel median target and variance-based
//!   confidence weights `(1 − V_norm)^γ`;
//! - [`ensemble`]: a whole ensemble's render sets → the synthetic set (the library side of
//!   `AggregateEnsemble`);
//! - [`nodes`]: the node kinds `SynthesizePoses`, `AggregateEnsemble` and `ScenePoses` (the
//!   poses of a scene's real views, e.g. to render the ensemble at the held-out views).
//!
//! Rendering the ensemble at the poses is a separate node (`RenderField`), so changing γ
//! reruns only the aggregation and what follows it.

pub mod aggregate;
pub mod ensemble;
pub mod nodes;
pub mod poses;

pub use nodes::{AggregateEnsemble, ScenePoses, SynthesizePoses};

/// Registers this family's node kinds.
pub fn register(registry: &mut augsplat_graph::Registry) {
    registry.register::<SynthesizePoses>();
    registry.register::<AggregateEnsemble>();
    registry.register::<ScenePoses>();
}
