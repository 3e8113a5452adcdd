//! The WGSL prelude: every constant a kernel shares with the Rust side, and the small maths
//! several kernels use, written once and put in front of every kernel's source when it is
//! compiled ([`shader_module`]). The values come from the Rust constants themselves, so a
//! kernel cannot disagree with the CPU code it twins; a kernel that declared one of these
//! names again would not compile (WGSL refuses a second module-scope declaration), and the
//! tests below check that none does.
//!
//! A float is written as the decimal of its exact `f32` value (as `f64`, shortest form), so
//! the WGSL compiler reads back the very bits the Rust side holds.

use crate::constants as c;

/// A value the prelude declares.
enum Value {
    /// A `u32`.
    U32(u64),
    /// An `f32`, from an `f32` or an `f64` constant (rounded as `as f32` rounds).
    F32(f32),
}

/// The constants, by WGSL name, with their Rust sources.
fn constants() -> Vec<(&'static str, Value)> {
    use Value::{F32, U32};
    let mut v = vec![
        // Buffer layouts (`forward/gpu.rs`, `backward/gpu.rs`).
        ("SPLAT_STRIDE", U32(crate::forward::gpu::SPLAT_STRIDE)),
        (
            "IMAGE_STRIDE",
            U32(crate::forward::gpu::IMAGE_STRIDE as u64),
        ),
        ("PAIR_STRIDE", U32(crate::backward::gpu::PAIR_STRIDE)),
        ("SCREEN_STRIDE", U32(super::SCREEN_GRAD_STRIDE as u64)),
        ("GRAD_STRIDE", U32(super::PARAM_GRAD_STRIDE as u64)),
        (
            "TILES_PAST_LOOP_CAP",
            U32(crate::forward::gpu::TILES_PAST_LOOP_CAP as u64),
        ),
        // The rasteriser's numbers (`constants.rs`).
        ("ALPHA_THRESHOLD", F32(c::ALPHA_THRESHOLD)),
        ("TRANSMITTANCE_THRESHOLD", F32(c::TRANSMITTANCE_THRESHOLD)),
        ("DEPTH_ALPHA_EPS", F32(c::DEPTH_ALPHA_EPS)),
        ("EPS2D", F32(c::EPS2D as f32)),
        ("MAX_EXTEND", F32(c::MAX_EXTEND as f32)),
        (
            "MIN_COMPENSATION_RATIO",
            F32(c::MIN_COMPENSATION_RATIO as f32),
        ),
        ("MIN_QUAT_NORM2", F32(c::MIN_QUAT_NORM2 as f32)),
        ("TILE", F32(c::TILE as f32)),
        // Spherical harmonics (`constants.rs`).
        ("C0", F32(c::C0 as f32)),
        ("C1", F32(c::C1 as f32)),
    ];
    const C2: [&str; 5] = ["C20", "C21", "C22", "C23", "C24"];
    const C3: [&str; 7] = ["C30", "C31", "C32", "C33", "C34", "C35", "C36"];
    v.extend(C2.iter().zip(c::C2).map(|(n, x)| (*n, F32(x as f32))));
    v.extend(C3.iter().zip(c::C3).map(|(n, x)| (*n, F32(x as f32))));
    v
}

/// Maths several kernels share.
const SHARED_MATHS: &str = "
// Whether `v` is finite (NaN fails both comparisons; ±∞ fails one).
fn finite(v: f32) -> bool {
    return v >= -3.4028235e38 && v <= 3.4028235e38;
}
";

/// The WGSL declaration of a `u32` constant `name` holding `value`.
pub fn constant_u32(name: &str, value: u64) -> String {
    format!("const {name}: u32 = {value}u;\n")
}

/// The WGSL declaration of an `f32` constant `name` holding exactly `value`'s bits.
pub fn constant_f32(name: &str, value: f32) -> String {
    format!("const {name}: f32 = {:?};\n", f64::from(value))
}

/// The prelude's text.
pub fn prelude() -> String {
    let mut s = String::from("// Generated from the Rust constants (gpu/prelude.rs).\n");
    for (name, value) in constants() {
        s.push_str(&match value {
            Value::U32(x) => constant_u32(name, x),
            Value::F32(x) => constant_f32(name, x),
        });
    }
    s.push_str(SHARED_MATHS);
    s
}

/// A kernel's WGSL module: the prelude, the family's own generated declarations `extra`
/// (e.g. [`constant_u32`] lines from its Rust constants), then `src`, with its `var<uniform>`
/// parameters read from storage buffers when `params_as_storage` (the same layout: every
/// parameter block holds 32-bit scalars and 16-byte vectors only).
pub fn shader_module(
    device: &wgpu::Device,
    label: &str,
    extra: &str,
    src: &str,
    params_as_storage: bool,
) -> wgpu::ShaderModule {
    let body = if params_as_storage {
        src.replace("var<uniform>", "var<storage, read>")
    } else {
        src.to_string()
    };
    let full = prelude() + extra + "\n" + &body;
    device.create_shader_module(wgpu::ShaderModuleDescriptor {
        label: Some(label),
        source: wgpu::ShaderSource::Wgsl(full.into()),
    })
}

/// Every kernel's source in this crate, by file name (for the tests).
#[cfg(test)]
const SOURCES: &[(&str, &str)] = &[
    ("project.wgsl", include_str!("../project/project.wgsl")),
    (
        "project_vjp.wgsl",
        include_str!("../project/project_vjp.wgsl"),
    ),
    ("forward.wgsl", include_str!("../forward/forward.wgsl")),
    ("backward.wgsl", include_str!("../backward/backward.wgsl")),
    (
        "backward_atomic.wgsl",
        include_str!("../backward/backward_atomic.wgsl"),
    ),
    ("scan.wgsl", include_str!("scan.wgsl")),
    ("sort.wgsl", include_str!("sort.wgsl")),
];

/// The module-scope `const` names a WGSL source declares.
pub fn declared_constants(src: &str) -> Vec<String> {
    src.lines()
        .filter_map(|l| l.strip_prefix("const "))
        .filter_map(|rest| rest.split(':').next())
        .map(|n| n.trim().to_string())
        .collect()
}

/// The names the prelude declares (its constants and `finite`): a kernel that declared one
/// again would not compile.
pub fn prelude_names() -> Vec<&'static str> {
    let mut names: Vec<&str> = constants().iter().map(|(n, _)| *n).collect();
    names.push("finite");
    names
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn no_kernel_declares_a_prelude_constant_again() {
        let shared = prelude_names();
        for (file, src) in SOURCES {
            for name in declared_constants(src) {
                assert!(
                    !shared.contains(&name.as_str()),
                    "{file} declares {name}, which the prelude generates from the Rust constant"
                );
            }
            assert!(
                !src.contains("fn finite("),
                "{file} defines finite(), which the prelude holds"
            );
        }
    }

    #[test]
    fn the_prelude_writes_the_rust_bits() {
        let text = prelude();
        for (name, value) in constants() {
            let line = text
                .lines()
                .find(|l| l.starts_with(&format!("const {name}:")))
                .unwrap_or_else(|| panic!("{name} missing"));
            let literal = line.split('=').nth(1).unwrap().trim().trim_end_matches(';');
            match value {
                Value::U32(x) => assert_eq!(literal, format!("{x}u")),
                // The decimal reads back (as WGSL reads an abstract float: f64, then f32)
                // to the same bits.
                Value::F32(x) => {
                    let back = literal.parse::<f64>().unwrap() as f32;
                    assert_eq!(back.to_bits(), x.to_bits(), "{name}: {literal}");
                }
            }
        }
        // The values the kernels held before the prelude existed.
        let f = |n: &str| match constants().into_iter().find(|(k, _)| *k == n) {
            Some((_, Value::F32(x))) => x,
            _ => panic!("{n}"),
        };
        assert_eq!(f("ALPHA_THRESHOLD"), 0.003_921_568_627_450_98_f64 as f32);
        assert_eq!(f("MIN_COMPENSATION_RATIO"), 0.000_025_f64 as f32);
        assert_eq!(f("C31"), 2.890_611_442_640_554_f64 as f32);
    }
}
