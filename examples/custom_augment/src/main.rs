//! The `augsplat` CLI with the example's `EnsembleMean` kind registered.

fn main() -> std::process::ExitCode {
    let mut registry = augsplat::builtin_registry();
    augsplat_custom_augment::register(&mut registry);
    augsplat::main_with(registry)
}
