//! A custom augmentation node in your own crate, reusing the whole `augsplat` CLI.
//!
//! `Grayscale` reads every PNG of an input folder, mixes RGB to luminance with a
//! user-chosen strength and writes the results to its `images` output. Register it, then
//! use `kind: "Grayscale"` in any pipeline:
//!
//! ```text
//! cargo run --example custom_node -- run my.ron
//! ```
//! with `my.ron` holding, for instance,
//! ```text
//! ( nodes: {
//!     "photos": (kind: "Command", args: (program: "cp", args: ["-r", "{in:src}/.", "{out:out}"],
//!                inputs: ["src"]), inputs: { "src": Path("photos") }),
//!     "gray": (kind: "Grayscale", args: (strength: 0.8), inputs: { "images": "photos" }),
//! } )
//! ```

use augsplat_core::image::{read_rgb, write_png};
use augsplat_graph::{InputDecl, Node, NodeError, RunContext};
use serde::{Deserialize, Serialize};

/// Args: how far to move each pixel towards its luminance (0 = unchanged, 1 = gray).
#[derive(Clone, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
struct GrayscaleArgs {
    strength: f32,
}

impl Default for GrayscaleArgs {
    fn default() -> Self {
        GrayscaleArgs { strength: 1.0 }
    }
}

struct Grayscale;

impl Node for Grayscale {
    const KIND: &'static str = "Grayscale";
    const VERSION: u32 = 1;
    type Args = GrayscaleArgs;

    fn inputs(_: &GrayscaleArgs) -> Vec<InputDecl> {
        vec![InputDecl::one("images")]
    }
    fn outputs(_: &GrayscaleArgs) -> Vec<String> {
        vec!["images".into()]
    }
    fn validate(args: &GrayscaleArgs) -> Result<(), String> {
        if !(0.0..=1.0).contains(&args.strength) {
            return Err(format!(
                "strength must lie in [0, 1], got {}",
                args.strength
            ));
        }
        Ok(())
    }
    fn run(args: &GrayscaleArgs, ctx: &mut RunContext) -> Result<(), NodeError> {
        let (src, dst) = (
            ctx.input("images")?.to_path_buf(),
            ctx.output("images")?.to_path_buf(),
        );
        let mut names: Vec<_> = std::fs::read_dir(&src)?
            .filter_map(|e| e.ok().map(|e| e.file_name()))
            .collect();
        names.sort(); // deterministic order
        let pngs: Vec<_> = names
            .into_iter()
            .filter(|n| n.to_string_lossy().ends_with(".png"))
            .collect();
        for (i, name) in pngs.iter().enumerate() {
            let mut img = read_rgb(&src.join(name))
                .map_err(|e| NodeError::from(e).context(src.join(name).display()))?;
            for px in img.data.chunks_exact_mut(3) {
                let y = 0.2126 * px[0] + 0.7152 * px[1] + 0.0722 * px[2];
                for c in px.iter_mut() {
                    *c += args.strength * (y - *c);
                }
            }
            write_png(&dst.join(name), &img)?;
            ctx.progress(i as u64 + 1, pngs.len() as u64, &name.to_string_lossy());
        }
        Ok(())
    }
}

fn main() -> std::process::ExitCode {
    let mut registry = augsplat::builtin_registry();
    registry.register::<Grayscale>();
    augsplat::main_with(registry)
}
