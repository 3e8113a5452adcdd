//! `augsplat render` through the binary: a good camera renders; a camera that is not rigid or
//! is absurdly large is refused with a message that shows what is wrong.

use std::path::Path;
use std::process::Command;

fn render(dir: &Path, camera: &serde_json::Value) -> (bool, String) {
    let cam = dir.join("cam.json");
    std::fs::write(&cam, camera.to_string()).unwrap();
    let out = Command::new(env!("CARGO_BIN_EXE_augsplat"))
        .args(["render", "--splats"])
        .arg(dir.join("g.ply"))
        .arg("--camera")
        .arg(&cam)
        .arg("--out")
        .arg(dir.join("out.png"))
        .output()
        .unwrap();
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
