//! Which instruction set the kernels run: one answer for every kernel family.
//!
//! Each vectorised kernel in augsplat exists as a *portable twin* (plain Rust, the readable
//! statement of the maths) and as variants compiled for wider instruction sets. This module
//! owns the one list of those tiers ([`Isa`]), the one feature set that each tier stands for,
//! the one cached detection ([`Isa::detect`]), the dispatch level that kernels consult
//! ([`active`]), and the [`multiversion!`](crate::multiversion) macro that compiles one
//! function body for every tier.
//!
//! # Tiers
//!
//! | tier | target features a variant is compiled with | runs on |
//! |---|---|---|
//! | [`Isa::Portable`] | the build's baseline (SSE2 on x86-64) | every CPU |
//! | [`Isa::Avx2`] | `avx2,fma,bmi1,popcnt` ([`AVX2_FEATURES`]) | Haswell / Zen and later, every AVX-512 CPU |
//!
//! A variant compiled for a tier must be bit-identical to the portable twin (fused
//! multiply-adds written as `mul_add`, fixed reduction orders); the tests of every kernel
//! family run each tier through [`for_each_isa`] and compare bits.
//!
//! One documented exception: the dense layers of the radiance field and the convolutions of
//! LPIPS fuse their multiply-adds in the AVX2 tier but not on the portable path (a software
//! `fma` would make CPUs without FMA many times slower). Their AVX2 kernels are tested bit for
//! bit against the portable kernels *run with fused multiply-adds*; a machine without AVX2
//! gives results that differ from an AVX2 machine's in the last bits for those two kernels.
//!
//! # Choosing the tier
//!
//! [`active`] is the widest tier the CPU supports, capped by the environment variable
//! `AUGSPLAT_ISA` (`portable` or `avx2`; useful to measure what a variant gains) and, inside
//! [`with_isa`], by the tier a test forces.

use std::sync::atomic::{AtomicU8, Ordering};
use std::sync::{Mutex, OnceLock};

/// The target features of the [`Isa::Avx2`] tier, as written in
/// `#[target_feature(enable = "avx2,fma,bmi1,popcnt")]` (an attribute needs the literal; a
/// test checks that the detection and this list agree).
pub const AVX2_FEATURES: &str = "avx2,fma,bmi1,popcnt";

/// An instruction-set tier that kernels are compiled for, narrowest first.
#[derive(Clone, Copy, Debug, PartialEq, Eq, PartialOrd, Ord, Hash)]
pub enum Isa {
    /// Plain Rust at the build's baseline target.
    Portable,
    /// AVX2 with FMA, BMI1 and POPCNT (x86-64 only).
    Avx2,
}

impl Isa {
    /// Every tier compiled into this build for this architecture, narrowest first.
    pub fn compiled() -> &'static [Isa] {
        #[cfg(target_arch = "x86_64")]
        {
            &[Isa::Portable, Isa::Avx2]
        }
        #[cfg(not(target_arch = "x86_64"))]
        {
            &[Isa::Portable]
        }
    }

    /// The widest tier this CPU supports (detected once per process).
    pub fn detect() -> Isa {
        static DETECTED: OnceLock<Isa> = OnceLock::new();
        *DETECTED.get_or_init(|| {
            if Isa::Avx2.cpu_has() {
                Isa::Avx2
            } else {
                Isa::Portable
            }
        })
    }

    /// Whether this CPU can run the tier's variants.
    pub fn supported(self) -> bool {
        self <= Isa::detect()
    }

    /// The feature test behind [`Isa::detect`]: every feature of the tier's set.
    fn cpu_has(self) -> bool {
        match self {
            Isa::Portable => true,
            Isa::Avx2 => {
                #[cfg(target_arch = "x86_64")]
                {
                    std::arch::is_x86_feature_detected!("avx2")
                        && std::arch::is_x86_feature_detected!("fma")
                        && std::arch::is_x86_feature_detected!("bmi1")
                        && std::arch::is_x86_feature_detected!("popcnt")
                }
                #[cfg(not(target_arch = "x86_64"))]
                {
                    false
                }
            }
        }
    }

    /// The tier's name as `AUGSPLAT_ISA` spells it (`portable`, `avx2`).
    pub fn name(self) -> &'static str {
        match self {
            Isa::Portable => "portable",
            Isa::Avx2 => "avx2",
        }
    }

    /// Parses a tier name (`portable`, `avx2`), case-insensitively.
    pub fn from_name(name: &str) -> Option<Isa> {
        match name.trim().to_ascii_lowercase().as_str() {
            "portable" | "scalar" | "none" => Some(Isa::Portable),
            "avx2" => Some(Isa::Avx2),
            _ => None,
        }
    }

    fn code(self) -> u8 {
        self as u8
    }

    fn from_code(c: u8) -> Isa {
        match c {
            0 => Isa::Portable,
            _ => Isa::Avx2,
        }
    }
}

impl std::fmt::Display for Isa {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(self.name())
    }
}

/// The cap that `AUGSPLAT_ISA` sets (read once); an unknown value is reported on stderr once
/// and ignored.
fn env_cap() -> Isa {
    static CAP: OnceLock<Isa> = OnceLock::new();
    *CAP.get_or_init(|| match std::env::var("AUGSPLAT_ISA") {
        Ok(v) => match Isa::from_name(&v) {
            Some(isa) => isa,
            None => {
                eprintln!(
                    "warning: AUGSPLAT_ISA={v:?} is not a tier (use `portable` or `avx2`); ignored"
                );
                Isa::Avx2
            }
        },
        Err(_) => Isa::Avx2,
    })
}

/// No tier forced (see [`with_isa`]).
const NOT_FORCED: u8 = u8::MAX;
static FORCED: AtomicU8 = AtomicU8::new(NOT_FORCED);
static FORCE_LOCK: Mutex<()> = Mutex::new(());

/// The tier kernels dispatch to now: the forced tier inside [`with_isa`], else the widest
/// tier the CPU supports capped by `AUGSPLAT_ISA`. Every tier gives the same bits, so this
/// changes only speed.
#[inline]
pub fn active() -> Isa {
    let forced = FORCED.load(Ordering::Relaxed);
    if forced != NOT_FORCED {
        return Isa::from_code(forced).min(Isa::detect());
    }
    Isa::detect().min(env_cap())
}

/// Runs `f` with every kernel dispatching to `isa` (capped by what the CPU supports), holding a
/// process-wide lock so forcing scopes never interleave.
///
/// The forced tier is process-wide: kernels that other threads call meanwhile see it too. For
/// bit-identical kernels that changes only speed; a test that compares two runs of the field's
/// dense layers or the LPIPS convolutions (see the module docs) must run them inside one
/// `with_isa` scope (or in a test binary that forces nothing), so that no forcing test in the
/// same process can switch their tier between the runs.
pub fn with_isa<R>(isa: Isa, f: impl FnOnce() -> R) -> R {
    let _guard = FORCE_LOCK.lock().unwrap_or_else(|e| e.into_inner());
    struct Reset;
    impl Drop for Reset {
        fn drop(&mut self) {
            FORCED.store(NOT_FORCED, Ordering::SeqCst);
        }
    }
    FORCED.store(isa.code(), Ordering::SeqCst);
    let _reset = Reset;
    f()
}

/// Runs `f` once per compiled tier that this CPU supports, each inside [`with_isa`], and
/// returns the results with their tier, narrowest first.
///
/// Tiers the CPU lacks are never a silent pass: each is printed on stderr as not run, with the
/// test's `what`. Under `CI=true` a tier that *is* supported always runs (nothing here skips
/// one), and a CI machine that lacks a tier the project's CI is meant to cover
/// (`AUGSPLAT_CI_ISA`, e.g. `avx2`) fails the test.
pub fn for_each_isa<R>(what: &str, mut f: impl FnMut(Isa) -> R) -> Vec<(Isa, R)> {
    let mut out = Vec::new();
    let mut not_run = Vec::new();
    for &isa in Isa::compiled() {
        if isa.supported() {
            out.push((isa, with_isa(isa, || f(isa))));
        } else {
            not_run.push(isa);
        }
    }
    let ran: Vec<&str> = out.iter().map(|(i, _)| i.name()).collect();
    if not_run.is_empty() {
        eprintln!("{what}: ran every tier ({})", ran.join(", "));
    } else {
        let missing: Vec<&str> = not_run.iter().map(|i| i.name()).collect();
        eprintln!(
            "{what}: ran {}; NOT RUN (this CPU lacks them): {}",
            ran.join(", "),
            missing.join(", ")
        );
    }
    if std::env::var("CI").is_ok_and(|v| v == "true") {
        if let Ok(required) = std::env::var("AUGSPLAT_CI_ISA") {
            if let Some(req) = Isa::from_name(&required) {
                assert!(
                    req.supported(),
                    "{what}: CI requires the {req} tier (AUGSPLAT_CI_ISA) but this CPU lacks it"
                );
            }
        }
    }
    out
}

/// Defines a function once per instruction-set tier from one `#[inline(always)]` body and
/// dispatches by [`active`](crate::simd::active).
///
/// ```ignore
/// augsplat_core::multiversion!(pub(crate) fn band(a: &[f32], b: &mut [f32]) -> f64 => band_body);
/// ```
///
/// The body is compiled for [`Isa::Avx2`] (with [`AVX2_FEATURES`]) and for the baseline; the
/// results are identical as long as the body writes fused multiply-adds as `mul_add` and sums
/// in a fixed order.
#[macro_export]
macro_rules! multiversion {
    ($vis:vis fn $name:ident($($a:ident : $t:ty),* $(,)?) $(-> $r:ty)? => $body:path) => {
        #[allow(clippy::too_many_arguments)]
        $vis fn $name($($a: $t),*) $(-> $r)? {
            #[cfg(target_arch = "x86_64")]
            {
                #[target_feature(enable = "avx2,fma,bmi1,popcnt")]
                #[allow(clippy::too_many_arguments)]
                unsafe fn v256($($a: $t),*) $(-> $r)? {
                    $body($($a),*)
                }
                if $crate::simd::active() == $crate::simd::Isa::Avx2 {
                    // SAFETY: `active` returns `Avx2` only on CPUs with every feature enabled.
                    return unsafe { v256($($a),*) };
                }
            }
            $body($($a),*)
        }
    };
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn detection_matches_the_feature_list() {
        #[cfg(target_arch = "x86_64")]
        {
            let all = AVX2_FEATURES.split(',').all(|f| match f {
                "avx2" => std::arch::is_x86_feature_detected!("avx2"),
                "fma" => std::arch::is_x86_feature_detected!("fma"),
                "bmi1" => std::arch::is_x86_feature_detected!("bmi1"),
                "popcnt" => std::arch::is_x86_feature_detected!("popcnt"),
                other => panic!("feature {other} is not checked by Isa::detect"),
            });
            assert_eq!(all, Isa::Avx2.supported());
        }
        assert!(Isa::Portable.supported());
        assert!(Isa::compiled().contains(&Isa::detect()));
    }

    #[test]
    fn forcing_caps_the_active_tier_and_resets() {
        let top = Isa::detect();
        let inside = with_isa(Isa::Portable, active);
        assert_eq!(inside, Isa::Portable);
        let forced_top = with_isa(Isa::Avx2, active);
        assert_eq!(forced_top, top.min(Isa::Avx2));
        // After the scope, nothing is forced.
        assert_eq!(FORCED.load(Ordering::SeqCst), NOT_FORCED);
    }

    #[test]
    fn every_supported_tier_runs() {
        let ran = for_each_isa("simd self-test", |isa| (isa, active()));
        for (isa, (seen, act)) in &ran {
            assert_eq!(isa, seen);
            assert_eq!(act, isa);
        }
        let supported = Isa::compiled().iter().filter(|i| i.supported()).count();
        assert_eq!(ran.len(), supported);
    }

    #[test]
    fn names_round_trip() {
        for &isa in Isa::compiled() {
            assert_eq!(Isa::from_name(isa.name()), Some(isa));
        }
        assert_eq!(Isa::from_name("AVX2"), Some(Isa::Avx2));
        assert_eq!(Isa::from_name("avx512"), None);
    }

    multiversion!(fn dot(a: &[f32], b: &[f32]) -> f32 => dot_body);

    #[inline(always)]
    fn dot_body(a: &[f32], b: &[f32]) -> f32 {
        a.iter().zip(b).fold(0.0f32, |s, (x, y)| x.mul_add(*y, s))
    }

    #[test]
    fn multiversioned_function_gives_the_same_bits_in_every_tier() {
        let a: Vec<f32> = (0..1000).map(|i| (i as f32 * 0.37).sin()).collect();
        let b: Vec<f32> = (0..1000).map(|i| (i as f32 * 0.11).cos()).collect();
        let r = for_each_isa("multiversion dot", |_| dot(&a, &b).to_bits());
        assert!(r.iter().all(|(_, v)| *v == r[0].1));
    }
}
