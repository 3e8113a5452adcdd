//! `augsplat view`: the report's interactive 3-D viewer as a page of its own, for any
//! Inria-layout PLY (augsplat's, gsplat's, the original 3DGS's), optionally with the cameras
//! of a scene and the ground truth of held-out views.

use super::CmdResult;
use augsplat_core::{image, Camera, Scene};
use augsplat_report::html;
use augsplat_report::viewer::{self, ViewerCamera, ViewerModel, DEFAULT_MAX_GAUSSIANS};
use augsplat_scene::node::{read_source, ImportSceneArgs};
use std::path::{Path, PathBuf};

/// Arguments of `augsplat view`.
#[derive(clap::Args)]
pub struct Args {
    /// Inria-layout PLYs (binary little-endian float32): one pane each, side by side on one
    /// camera.
    #[arg(required = true)]
    pub models: Vec<PathBuf>,
    /// The panes' labels, one per model, in order (default: the file names).
    #[arg(long = "label")]
    pub labels: Vec<String>,
    /// Cameras to draw as frusta and jump to: an augsplat scene folder (`scene.json`, the
    /// normalised frame augsplat's models live in) or a capture folder (COLMAP,
    /// transforms.json, LLFF: the original frame of gsplat's and the original 3DGS's models).
    #[arg(long)]
    pub scene: Option<PathBuf>,
    /// Held-out views, offered with their images as a ground-truth pane: a folder as for
    /// `--scene`.
    #[arg(long)]
    pub held_out: Option<PathBuf>,
    /// The page to write.
    #[arg(long, default_value = "view.html")]
    pub out: PathBuf,
    /// Cap on the Gaussians per pane (the most opaque are kept; 24 bytes each in the page).
    #[arg(long, default_value_t = DEFAULT_MAX_GAUSSIANS)]
    pub max_gaussians: usize,
    /// Background colour composited behind the Gaussians, `R,G,B` in [0, 1].
    #[arg(long, default_value = "0,0,0", value_parser = super::render::parse_rgb)]
    pub background: [f32; 3],
    /// Page title (default: the models' file names).
    #[arg(long)]
    pub title: Option<String>,
}

/// The views of a scene or capture folder: (name, camera, image path).
fn views_of(dir: &Path) -> Result<Vec<(String, Camera, PathBuf)>, String> {
    if dir.join("scene.json").is_file() {
        let scene = Scene::load(dir).map_err(|e| e.to_string())?;
        return Ok(scene
            .views
            .into_iter()
            .map(|v| (v.name, v.camera, dir.join(v.image)))
            .collect());
    }
    let raw = read_source(dir, &ImportSceneArgs::default()).map_err(|e| {
        format!(
            "{}: neither an augsplat scene folder (no scene.json) nor a capture augsplat reads: {e}",
            dir.display()
        )
    })?;
    Ok(raw
        .views
        .into_iter()
        .map(|v| {
            let cam = v.intrinsics.pinhole_camera(v.world_to_camera);
            (v.name, cam, v.image_path)
        })
        .collect())
}

/// Runs `augsplat view`.
pub fn run(args: Args) -> CmdResult {
    if !args.labels.is_empty() && args.labels.len() != args.models.len() {
        return Err(format!(
            "{} --label values for {} models: give one per model, in order, or none",
            args.labels.len(),
            args.models.len()
        ));
    }
    if args.max_gaussians == 0 {
        return Err("--max-gaussians must be at least 1".into());
    }
    if args.background.iter().any(|v| !(0.0..=1.0).contains(v)) {
        return Err(format!(
            "--background {:?} must be three values in [0, 1]",
            args.background
        ));
    }
    let mut models = Vec::new();
    for (i, path) in args.models.iter().enumerate() {
        let g = augsplat_splat::read_ply(path).map_err(|e| e.to_string())?;
        let packed = viewer::pack(&g, args.max_gaussians);
        if packed.count == 0 {
            return Err(format!(
                "{}: none of its {} Gaussians can be shown (all invalid or below 1/255 opacity)",
                path.display(),
                g.len()
            ));
        }
        let label = args.labels.get(i).cloned().unwrap_or_else(|| {
            path.file_name().map_or_else(
                || path.display().to_string(),
                |n| n.to_string_lossy().into(),
            )
        });
        models.push(ViewerModel { label, packed });
    }
    let mut cameras = Vec::new();
    if let Some(dir) = &args.scene {
        for (name, camera, _) in views_of(dir)? {
            camera
                .validate()
                .map_err(|e| format!("{}: camera of view {name:?}: {e}", dir.display()))?;
            cameras.push(ViewerCamera {
                name,
                held_out: false,
                camera,
                ground_truth: None,
            });
        }
    }
    if let Some(dir) = &args.held_out {
        for (name, camera, image_path) in views_of(dir)? {
            let img = image::read_rgb(&image_path).map_err(|e| e.to_string())?;
            let camera = if (camera.width, camera.height) == (img.width, img.height) {
                camera
            } else {
                camera.resized(img.width, img.height)
            };
            camera
                .validate()
                .map_err(|e| format!("{}: camera of view {name:?}: {e}", dir.display()))?;
            let uri = html::png_data_uri(&img).map_err(|e| e.to_string())?;
            cameras.push(ViewerCamera {
                name,
                held_out: true,
                camera,
                ground_truth: Some(uri),
            });
        }
    }
    let title = args.title.clone().unwrap_or_else(|| {
        models
            .iter()
            .map(|m| m.label.as_str())
            .collect::<Vec<_>>()
            .join(" · ")
    });
    let page = viewer::viewer_page(&title, &models, &cameras, args.background);
    std::fs::write(&args.out, &page).map_err(|e| format!("{}: {e}", args.out.display()))?;
    let shown: usize = models.iter().map(|m| m.packed.count).sum();
    let total: usize = models.iter().map(|m| m.packed.total).sum();
    println!(
        "wrote {} ({:.1} MB): {} pane(s), {shown} of {total} Gaussians, {} camera(s)",
        args.out.display(),
        page.len() as f64 / 1e6,
        models.len(),
        cameras.len()
    );
    Ok(())
}
