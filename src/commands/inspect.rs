//! `augsplat inspect`: describes a scene on disk (COLMAP binary/text, transforms.json, LLFF or
//! an augsplat scene folder): cameras, registered images, intrinsics, image size, points,
//! bounds and the mean reprojection error (COLMAP's definition).

use super::CmdResult;
use std::path::PathBuf;

/// Arguments of `augsplat inspect`.
#[derive(clap::Args)]
pub struct Args {
    /// The scene: a folder (augsplat scene, COLMAP model or a folder holding one in sparse/0,
    /// LLFF) or a transforms.json file.
    pub path: PathBuf,
    /// Print the report as JSON (for scripts).
    #[arg(long)]
    pub json: bool,
}

/// Runs `augsplat inspect`.
pub fn run(args: Args) -> CmdResult {
    let report = augsplat_scene::inspect::inspect(&args.path).map_err(|e| e.to_string())?;
    if args.json {
        let text = serde_json::to_string_pretty(&report).map_err(|e| e.to_string())?;
        println!("{text}");
    } else {
        print!("{}", augsplat_scene::inspect::format_text(&report));
    }
    Ok(())
}
