//! Registers every built-in augsplat node kind. Each family lives in its own crate under
//! `nodes/` and exposes `register(&mut Registry)`.

use augsplat_graph::Registry;

/// Registers the built-in node kinds of every family.
pub fn register_builtin(registry: &mut Registry) {
    augsplat_augment::register(registry);
    augsplat_field::register(registry);
    augsplat_report::register(registry);
    augsplat_scene::register(registry);
    augsplat_splat::register(registry);
}
