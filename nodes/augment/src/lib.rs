//! augsplat-augment: AugSplat's augmentation stage (docs/design.md, *The method*).
//!
//! - [`poses`]: synthetic camera poses near the training cameras (jittered copies and
//!   neighbour interpolations, then N drawn), with a report of how near they stay;
//! - [`aggregate`]: ensemble aggregation kernels — per-pixel median target and variance-based
//!   confidence weights `(1 − V_norm)^γ`;
//! - [`ensemble`]: a whole ensemble's render sets → the synthetic set (the library side of
//!   `AggregateEnsemble`);
//! - [`node`]: the node kinds `SynthesizePoses`, `AggregateEnsemble` and `ScenePoses` (the
//!   poses of a scene's real views, e.g. to render the ensemble at the held-out views).
//!
//! Rendering the ensemble at the poses is a separate node (`RenderField`), so changing γ
//! reruns only the aggregation and what follows it.

pub mod aggregate;
pub mod ensemble;
pub mod node;
pub mod poses;

/// The node kinds' module under its former name (`augsplat_augment::nodes::…` paths still
/// resolve); the module is [`node`], as in every node family.
pub use node as nodes;
pub use node::{AggregateEnsemble, ScenePoses, SynthesizePoses};

/// Registers this family's node kinds.
pub fn register(registry: &mut augsplat_graph::Registry) {
    registry.register::<SynthesizePoses>();
    registry.register::<AggregateEnsemble>();
    registry.register::<ScenePoses>();
}

#[cfg(test)]
mod tests {
    #[test]
    fn the_former_module_name_still_resolves() {
        let _: fn() -> crate::nodes::ScenePosesArgs = crate::node::ScenePosesArgs::default;
        assert_eq!(crate::nodes::POSES_REPORT, crate::node::POSES_REPORT);
    }
}
