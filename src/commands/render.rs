//! `augsplat render`: renders a Gaussian splat PLY (Inria layout) from a camera, and
//! optionally the gradients of an L2 loss against a target image (for checking gradients
//! against other implementations).

use super::CmdResult;
use augsplat_core::image::{read_npy, write_exr, write_npy, write_png};
use augsplat_core::{Camera, ImageF32};
use augsplat_splat::{read_ply, write_ply, Backend, Device, Gaussians, RenderSettings};
use std::path::{Path, PathBuf};

/// Arguments of `augsplat render`.
#[derive(clap::Args)]
pub struct Args {
    /// The Gaussians: an Inria-layout PLY (binary little-endian float32).
    #[arg(long)]
    pub splats: PathBuf,
    /// The camera: JSON `{"width","height","fx","fy","cx","cy","world_to_camera"}` with a
    /// 4×4 row-major world-to-camera matrix in OpenCV axes (x right, y down, z forward).
    #[arg(long)]
    pub camera: PathBuf,
    /// The colour image: `.png` (8-bit, clamped), `.exr` (float R,G,B) or `.npy` (float32 H×W×3).
    #[arg(long)]
    pub out: PathBuf,
    /// Active SH degree (clamped to the degree stored in the PLY).
    #[arg(long, default_value_t = 3)]
    pub sh_degree: u32,
    /// Background colour composited behind the Gaussians, `R,G,B` in [0, 1].
    #[arg(long, default_value = "0,0,0", value_parser = parse_rgb)]
    pub background: [f32; 3],
    /// Also write the accumulated alpha (`.png`, `.exr` with channel A, or `.npy` H×W).
    #[arg(long)]
    pub alpha_out: Option<PathBuf>,
    /// Also write the expected depth, normalised by alpha (`.exr` channel D, `.npy` H×W, or
    /// `.png` scaled to [0, 1] by the maximum depth).
    #[arg(long)]
    pub depth_out: Option<PathBuf>,
    /// Upper clamp of the per-pixel alpha (gsplat ≥ 1.6: 0.99; gsplat 1.5: 0.999).
    #[arg(long, default_value_t = 0.99)]
    pub max_alpha: f32,
    /// Antialiased mode: multiply opacities by the screen-space blur compensation.
    #[arg(long)]
    pub antialiased: bool,
    /// Target image (`.npy` float32 H×W×3) for L = mean over H·W·3 of (render − target)².
    #[arg(long, requires = "grads_out")]
    pub loss_target: Option<PathBuf>,
    /// Where to write dL/d(each raw PLY field), in the input's PLY layout (needs `--loss-target`).
    #[arg(long, requires = "loss_target")]
    pub grads_out: Option<PathBuf>,
    /// Where to render (and, with `--grads-out`, back-propagate): `cpu` (default) or `gpu`
    /// (wgpu: Vulkan, Metal, DX12 or GL; an error when the machine has no GPU adapter).
    #[arg(long, default_value_t = Backend::Cpu, value_parser = parse_backend)]
    pub backend: Backend,
}

/// `--backend`: the names [`Backend`] accepts, listed in the help and in errors.
fn parse_backend(s: &str) -> Result<Backend, String> {
    s.parse()
}

pub(crate) fn parse_rgb(s: &str) -> Result<[f32; 3], String> {
    let parts: Vec<&str> = s.split(',').map(str::trim).collect();
    if parts.len() != 3 {
        return Err(format!("expected R,G,B (three numbers), got `{s}`"));
    }
    let mut rgb = [0.0f32; 3];
    for (v, p) in rgb.iter_mut().zip(&parts) {
        *v = p
            .parse()
            .map_err(|_| format!("`{p}` in `{s}` is not a number"))?;
        if !v.is_finite() {
            return Err(format!("`{p}` in `{s}` is not finite"));
        }
    }
    Ok(rgb)
}

fn read_camera(path: &Path) -> Result<Camera, String> {
    let text = std::fs::read_to_string(path).map_err(|e| format!("{}: {e}", path.display()))?;
    let cam: Camera = serde_json::from_str(&text).map_err(|e| {
        format!(
            "{}: not a camera JSON ({e}); expected {{\"width\", \"height\", \"fx\", \"fy\", \"cx\", \"cy\", \"world_to_camera\": 4×4 row-major}}",
            path.display()
        )
    })?;
    cam.validate()
        .map_err(|e| format!("{}: invalid camera: {e}", path.display()))?;
    Ok(cam)
}

fn extension(path: &Path) -> String {
    path.extension()
        .and_then(|e| e.to_str())
        .unwrap_or("")
        .to_ascii_lowercase()
}

/// Writes an image with `channels` interleaved values per pixel; `names` are the EXR
/// channel names.
fn write_image(
    path: &Path,
    width: u32,
    height: u32,
    data: Vec<f32>,
    names: &[&str],
) -> Result<(), String> {
    let c = names.len() as u32;
    let img = ImageF32::from_vec(width, height, c, data);
    let res = match extension(path).as_str() {
        "png" => write_png(path, &img),
        "npy" => write_npy(path, &img),
        "exr" => {
            let planes: Vec<Vec<f32>> = (0..c).map(|ch| img.channel(ch)).collect();
            let chans: Vec<(&str, &[f32])> = names
                .iter()
                .zip(&planes)
                .map(|(n, p)| (*n, p.as_slice()))
                .collect();
            write_exr(path, width, height, &chans)
        }
        other => {
            return Err(format!(
                "{}: unknown image extension `{other}` (use .png, .exr or .npy)",
                path.display()
            ))
        }
    };
    res.map_err(|e| e.to_string())
}

/// Runs `augsplat render`.
pub fn run(args: Args) -> CmdResult {
    let g = read_ply(&args.splats).map_err(|e| e.to_string())?;
    let cam = read_camera(&args.camera)?;
    if !(args.max_alpha > 0.0 && args.max_alpha < 1.0) {
        return Err(format!(
            "--max-alpha {} must lie strictly between 0 and 1",
            args.max_alpha
        ));
    }
    if args.sh_degree > 3 {
        return Err(format!(
            "--sh-degree {} is above 3 (the highest supported)",
            args.sh_degree
        ));
    }
    let s = RenderSettings {
        sh_degree: args.sh_degree,
        background: args.background,
        max_alpha: args.max_alpha,
        antialiased: args.antialiased,
        ..Default::default()
    };
    // Read the target before the (possibly long) render so a bad path fails fast.
    let target = match &args.loss_target {
        Some(p) => {
            let t = read_npy(p).map_err(|e| e.to_string())?;
            if t.width != cam.width || t.height != cam.height || t.channels != 3 {
                return Err(format!(
                    "{}: target is {}×{}×{}, the camera renders {}×{}×3 (H×W×C)",
                    p.display(),
                    t.height,
                    t.width,
                    t.channels,
                    cam.height,
                    cam.width
                ));
            }
            Some(t)
        }
        None => None,
    };
    let device = Device::open(args.backend).map_err(|e| e.to_string())?;
    if let Some(adapter) = device.adapter() {
        eprintln!("GPU: {adapter}");
    }
    let model = device.upload(&g).map_err(|e| e.to_string())?;
    let out = model.render(&cam, &s).map_err(|e| e.to_string())?;
    let (w, h) = (cam.width, cam.height);
    write_image(&args.out, w, h, out.rgb.clone(), &["R", "G", "B"])?;
    if let Some(p) = &args.alpha_out {
        write_image(p, w, h, out.alpha.clone(), &["A"])?;
    }
    if let Some(p) = &args.depth_out {
        let data = if extension(p) == "png" {
            let m = out.depth.iter().fold(0.0f32, |a, b| a.max(*b));
            out.depth
                .iter()
                .map(|d| if m > 0.0 { d / m } else { 0.0 })
                .collect()
        } else {
            out.depth.clone()
        };
        write_image(p, w, h, data, &["D"])?;
    }
    let st = out.stats;
    eprintln!(
        "rendered {}×{}: {} Gaussians visible, {} culled, {} invalid; {} composited pairs",
        w, h, st.visible, st.culled, st.invalid, st.pairs
    );
    if let (Some(t), Some(gpath)) = (target, &args.grads_out) {
        let n = out.rgb.len() as f64;
        let mut loss = 0.0f64;
        let d_rgb: Vec<f32> = out
            .rgb
            .iter()
            .zip(&t.data)
            .map(|(r, t)| {
                let d = (*r - *t) as f64;
                loss += d * d;
                (2.0 * d / n) as f32
            })
            .collect();
        loss /= n;
        let gr = model
            .backward(&cam, &s, &d_rgb)
            .map_err(|e| e.to_string())?;
        let gg = Gaussians {
            means: gr.means,
            log_scales: gr.log_scales,
            quats: gr.quats,
            opacity_logits: gr.opacity_logits,
            sh: gr.sh,
            sh_degree: g.sh_degree,
        };
        write_ply(gpath, &gg).map_err(|e| e.to_string())?;
        println!("loss {loss:.9e}");
    }
    Ok(())
}
