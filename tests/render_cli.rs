//! `augsplat render` through the binary: a good camera renders; a camera that is not rigid or
//! is absurdly large is refused with a message that shows what is wrong.

use std::path::Path;
use std::process::Command;

fn render(dir: &Path, camera: &serde_json::Value) -> (bool, String) {
    std::fs::write(dir.join("cam.json"), camera.to_string()).unwrap();
    let out = dir.join("out.png").display().to_string();
    render_with(dir, &["--out", &out], &[])
}

#[test]
fn render_refuses_non_rigid_and_huge_cameras() {
    let dir = tempfile::tempdir().unwrap();
    let mut g = augsplat_splat::Gaussians::empty(0);
    for i in 0..4 {
        g.means.push([i as f32 * 0.1 - 0.15, 0.0, 0.0]);
        g.log_scales.push([-2.0; 3]);
        g.quats.push([1.0, 0.0, 0.0, 0.0]);
        g.opacity_logits.push(2.0);
        g.sh.extend_from_slice(&[1.0, 0.5, 0.2]);
    }
    augsplat_splat::write_ply(&dir.path().join("g.ply"), &g).unwrap();
    let camera = |w: u32, m: [[f64; 4]; 4]| {
        serde_json::json!({
            "width": w, "height": 24, "fx": 30.0, "fy": 30.0, "cx": w as f64 / 2.0, "cy": 12.0,
            "world_to_camera": m,
        })
    };
    let rigid = [
        [1.0, 0.0, 0.0, 0.0],
        [0.0, 1.0, 0.0, 0.0],
        [0.0, 0.0, 1.0, 2.0],
        [0.0, 0.0, 0.0, 1.0],
    ];
    let (ok, text) = render(dir.path(), &camera(32, rigid));
    assert!(ok, "{text}");
    assert!(dir.path().join("out.png").is_file());

    let mut skewed = rigid;
    skewed[0][1] = 0.3;
    let (ok, text) = render(dir.path(), &camera(32, skewed));
    assert!(!ok);
    assert!(
        text.contains("cam.json")
            && text.contains("not a rotation")
            && text.contains("[1, 0.3, 0, 0]"),
        "{text}"
    );
    let (ok, text) = render(dir.path(), &camera(100_000, rigid));
    assert!(!ok);
    assert!(text.contains("largest supported side"), "{text}");
}

/// Runs `augsplat render` with `extra` arguments and the environment `env`.
fn render_with(dir: &Path, extra: &[&str], env: &[(&str, &str)]) -> (bool, String) {
    let mut cmd = Command::new(env!("CARGO_BIN_EXE_augsplat"));
    cmd.args(["render", "--splats"])
        .arg(dir.join("g.ply"))
        .arg("--camera")
        .arg(dir.join("cam.json"))
        .args(extra);
    for (k, v) in env {
        cmd.env(k, v);
    }
    let out = cmd.output().unwrap();
    (
        out.status.success(),
        format!(
            "{}{}",
            String::from_utf8_lossy(&out.stdout),
            String::from_utf8_lossy(&out.stderr)
        ),
    )
}

#[test]
fn render_on_the_gpu_writes_what_the_cpu_writes() {
    let dir = tempfile::tempdir().unwrap();
    let cam = augsplat_testkit::cameras::facing(48, 40, 4.0);
    let g = augsplat_splat::Gaussians::random_cloud(800, 4.0 / cam.fx, 5);
    augsplat_splat::write_ply(&dir.path().join("g.ply"), &g).unwrap();
    std::fs::write(
        dir.path().join("cam.json"),
        serde_json::to_string(&cam).unwrap(),
    )
    .unwrap();
    // Asking for the GPU where wgpu finds no adapter (here: only Metal allowed, on Linux) is
    // an error that says so — never a silent CPU render.
    if cfg!(target_os = "linux") {
        let (ok, text) = render_with(
            dir.path(),
            &["--out", "x.png", "--backend", "gpu"],
            &[("WGPU_BACKEND", "metal")],
        );
        assert!(!ok && text.contains("no GPU adapter was found"), "{text}");
        assert!(!dir.path().join("x.png").exists());
    }
    let p = |name: &str| dir.path().join(name).display().to_string();
    let (ok, text) = render_with(dir.path(), &["--out", &p("cpu.npy")], &[]);
    assert!(ok, "{text}");
    let (ok, text) = render_with(
        dir.path(),
        &[
            "--out",
            &p("gpu.npy"),
            "--alpha-out",
            &p("gpu_a.exr"),
            "--depth-out",
            &p("gpu_d.png"),
            "--backend",
            "gpu",
        ],
        &[],
    );
    if !ok && text.contains("no GPU adapter was found") {
        augsplat_testkit::skip("render_on_the_gpu_writes_what_the_cpu_writes", &text);
        return;
    }
    assert!(ok, "{text}");
    assert!(text.contains("GPU: "), "{text}");
    let a = augsplat_core::image::read_npy(&dir.path().join("cpu.npy")).unwrap();
    let b = augsplat_core::image::read_npy(&dir.path().join("gpu.npy")).unwrap();
    let worst = a
        .data
        .iter()
        .zip(&b.data)
        .map(|(x, y)| (x - y).abs())
        .fold(0.0f32, f32::max);
    assert!(worst <= 1e-4, "GPU vs CPU: {worst}");
    assert!(dir.path().join("gpu_a.exr").is_file() && dir.path().join("gpu_d.png").is_file());
    // Gradients on each backend: the same PLY layout, values within 1e-3 of each group's
    // largest.
    let target = augsplat_core::ImageF32::from_vec(48, 40, 3, vec![0.25; 48 * 40 * 3]);
    augsplat_core::image::write_npy(&dir.path().join("t.npy"), &target).unwrap();
    let mut grads = Vec::new();
    for backend in ["cpu", "gpu"] {
        let out = format!("grads_{backend}.ply");
        let (ok, text) = render_with(
            dir.path(),
            &[
                "--out",
                &p("g2.png"),
                "--loss-target",
                &p("t.npy"),
                "--grads-out",
                &p(&out),
                "--backend",
                backend,
            ],
            &[],
        );
        assert!(ok, "{text}");
        assert!(text.contains("loss "), "{text}");
        grads.push(augsplat_splat::read_ply(&dir.path().join(&out)).unwrap());
    }
    assert_eq!(grads[1].len(), 800);
    let group = |f: &dyn Fn(&augsplat_splat::Gaussians) -> Vec<f32>| {
        let (a, b) = (f(&grads[0]), f(&grads[1]));
        let scale = a.iter().fold(0.0f32, |m, v| m.max(v.abs()));
        let worst = a
            .iter()
            .zip(&b)
            .fold(0.0f32, |m, (x, y)| m.max((x - y).abs()));
        assert!(worst <= 1e-3 * scale.max(1e-12), "{worst} of {scale}");
    };
    group(&|g| g.means.iter().flatten().copied().collect());
    group(&|g| g.log_scales.iter().flatten().copied().collect());
    group(&|g| g.quats.iter().flatten().copied().collect());
    group(&|g| g.opacity_logits.clone());
    group(&|g| g.sh.clone());
}
