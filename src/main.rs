//! The `augsplat` binary: the CLI with every built-in node kind.

fn main() -> std::process::ExitCode {
    augsplat::main_with(augsplat::builtin_registry())
}
