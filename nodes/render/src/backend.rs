//! The choice of device a node computes on.

/// Where a node computes (splatting, radiance fields): part of the node's args, hence of its
/// key (left out when it is the CPU, so adding the field kept every existing key).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
pub enum Backend {
    /// The CPU kernels (all cores; identical bytes on every machine).
    #[default]
    Cpu,
    /// The GPU through wgpu (identical bytes run to run on one adapter; an error when the
    /// machine has no adapter, never a silent fall-back to the CPU).
    Gpu,
}

impl Backend {
    /// The names a command line accepts, in the order of the variants.
    pub const NAMES: [&'static str; 2] = ["cpu", "gpu"];

    /// Whether this is the CPU (the default, left out of serialised args).
    pub fn is_cpu(&self) -> bool {
        *self == Backend::Cpu
    }
}

impl std::fmt::Display for Backend {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(Backend::NAMES[*self as usize])
    }
}

impl std::str::FromStr for Backend {
    type Err = String;
    /// `cpu` or `gpu`, in any case.
    fn from_str(s: &str) -> Result<Backend, String> {
        match s.to_ascii_lowercase().as_str() {
            "cpu" => Ok(Backend::Cpu),
            "gpu" => Ok(Backend::Gpu),
            _ => Err(format!(
                "unknown backend {s:?}: expected one of {}",
                Backend::NAMES.join(", ")
            )),
        }
    }
}
