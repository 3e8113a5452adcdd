//! Golden values from public implementations (`../shared/data/metrics/golden.json`) and the
//! published LPIPS distances. Skipped with a message when the shared data folder is absent.

use augsplat_core::image::read_rgb;
use augsplat_metrics::lpips::{bundled_weights, Backbone, Lpips};
use augsplat_metrics::{psnr, ssim, ssim_valid};
use std::path::PathBuf;

fn data_dir() -> Option<PathBuf> {
    augsplat_testkit::data::shared_data("metrics golden values", "metrics/golden.json")
}

fn golden(d: &std::path::Path) -> Vec<serde_json::Value> {
    let text = std::fs::read_to_string(d.join("metrics/golden.json")).unwrap();
    let v: serde_json::Value = serde_json::from_str(&text).unwrap();
    v["pairs"].as_array().unwrap().clone()
}

#[test]
fn psnr_and_ssim_match_golden() {
    let Some(d) = data_dir() else { return };
    let mut checked = 0;
    for pair in golden(&d) {
        let a = read_rgb(&d.join(pair["a"].as_str().unwrap())).unwrap();
        let b = read_rgb(&d.join(pair["b"].as_str().unwrap())).unwrap();
        let name = format!("{} / {}", pair["a"], pair["b"]);
        if let Some(g) = pair["psnr"].as_f64() {
            let v = psnr(&a, &b).unwrap();
            assert!((v - g).abs() < 1e-4, "{name}: psnr {v} vs {g}");
            checked += 1;
        }
        if let Some(g) = pair["ssim_torchmetrics"].as_f64() {
            let v = ssim(&a, &b).unwrap();
            assert!((v - g).abs() < 1e-4, "{name}: ssim {v} vs {g}");
            checked += 1;
        }
        if let Some(g) = pair["ssim_valid"].as_f64() {
            let v = ssim_valid(&a, &b).unwrap();
            assert!((v - g).abs() < 1e-4, "{name}: ssim_valid {v} vs {g}");
            checked += 1;
        }
    }
    assert_eq!(checked, 9);
}

fn lpips_golden(backbone: &str, max_pixels: usize) {
    let Some(d) = data_dir() else { return };
    let model = Lpips::load(&d.join(format!("lpips/lpips_{backbone}_v0.1.safetensors"))).unwrap();
    let mut checked = 0;
    for pair in golden(&d) {
        let a = read_rgb(&d.join(pair["a"].as_str().unwrap())).unwrap();
        let b = read_rgb(&d.join(pair["b"].as_str().unwrap())).unwrap();
        if a.pixels() > max_pixels {
            continue;
        }
        let g = pair[format!("lpips_{backbone}")].as_f64().unwrap();
        let v = model.distance(&a, &b).unwrap();
        eprintln!(
            "{} / {}: lpips_{backbone} {v} (golden {g})",
            pair["a"], pair["b"]
        );
        assert!(
            (v - g).abs() < 1e-4,
            "{}/{}: {v} vs {g}",
            pair["a"],
            pair["b"]
        );
        checked += 1;
    }
    assert!(checked >= 3);
}

#[test]
fn lpips_alex_matches_golden() {
    lpips_golden("alex", usize::MAX);
}

#[test]
fn lpips_vgg_matches_golden_small_images() {
    lpips_golden("vgg", 64 * 64);
}

/// VGG on the 504×378 pairs costs several seconds per pair: run by hand with
/// `cargo test -p augsplat-metrics --release --test golden -- --ignored`.
#[test]
#[ignore]
fn lpips_vgg_matches_golden_full_size() {
    lpips_golden("vgg", usize::MAX);
}

/// The shipped float16 AlexNet weights give LPIPS within 1e-4 of the float32 weights (and of
/// the golden values) on every golden pair, the LPIPS example images included.
#[test]
fn shipped_f16_alex_matches_f32_weights() {
    let Some(d) = data_dir() else { return };
    let f32_model = Lpips::load(&d.join("lpips/lpips_alex_v0.1.safetensors")).unwrap();
    let shipped = bundled_weights(Backbone::Alex).expect("the shipped LPIPS-alex weights");
    let f16_model = Lpips::load(&shipped).unwrap();
    assert_eq!(f16_model.backbone(), Backbone::Alex);
    let mut worst = 0f64;
    let mut checked = 0;
    for pair in golden(&d) {
        let a = read_rgb(&d.join(pair["a"].as_str().unwrap())).unwrap();
        let b = read_rgb(&d.join(pair["b"].as_str().unwrap())).unwrap();
        let g = pair["lpips_alex"].as_f64().unwrap();
        let v32 = f32_model.distance(&a, &b).unwrap();
        let v16 = f16_model.distance(&a, &b).unwrap();
        eprintln!(
            "{} / {}: lpips_alex f16 {v16} f32 {v32} (|diff| {:.2e}, golden {g})",
            pair["a"],
            pair["b"],
            (v16 - v32).abs()
        );
        assert!((v16 - v32).abs() < 1e-4, "{pair}: f16 {v16} vs f32 {v32}");
        assert!((v16 - g).abs() < 1e-4, "{pair}: f16 {v16} vs golden {g}");
        worst = worst.max((v16 - v32).abs());
        checked += 1;
    }
    eprintln!("max |LPIPS_f16 - LPIPS_f32| over {checked} pairs: {worst:.3e}");
    assert_eq!(checked, 6);
}
