//! The `EvaluateEnsemble` node: member and median metrics against a direct f64 computation
//! (odd and even M), renders clamped, and clear errors for missing views and size mismatches.

use augsplat_core::artifacts::{files, write_json, RenderSet, RenderedView};
use augsplat_core::{image, Camera, ImageF32, Rng, Scene, SceneView};
use augsplat_graph::{Node, RunContext};
use augsplat_report::ensemble::{EnsembleMetrics, EvaluateEnsembleArgs, EvaluateEnsembleNode};
use augsplat_report::evaluate::LpipsNet;
use std::path::{Path, PathBuf};

const W: u32 = 20;
const H: u32 = 14;

fn camera() -> Camera {
    Camera {
        width: W,
        height: H,
        fx: 18.0,
        fy: 18.0,
        cx: 10.0,
        cy: 7.0,
        world_to_camera: [
            [1.0, 0.0, 0.0, 0.0],
            [0.0, 1.0, 0.0, 0.0],
            [0.0, 0.0, 1.0, 0.0],
            [0.0, 0.0, 0.0, 1.0],
        ],
    }
}

/// A test scene of `views` random images; returns them as written (8-bit quantised).
fn scene(dir: &Path, views: usize, rng: &mut Rng) -> Vec<ImageF32> {
    std::fs::create_dir_all(dir.join("images")).unwrap();
    let mut vs = Vec::new();
    let mut gts = Vec::new();
    for i in 0..views {
        let data = (0..W * H * 3).map(|_| rng.next_f32()).collect();
        let rel = format!("images/t{i}.png");
        image::write_png(&dir.join(&rel), &ImageF32::from_vec(W, H, 3, data)).unwrap();
        gts.push(image::read_rgb(&dir.join(&rel)).unwrap());
        vs.push(SceneView {
            name: format!("t{i}"),
            image: rel,
            depth: None,
            camera: camera(),
        });
    }
    Scene {
        source: "fixture".into(),
        views: vs,
        near: 0.1,
        far: 10.0,
        normalization: Default::default(),
        has_points: false,
    }
    .save(dir)
    .unwrap();
    gts
}

/// One member's render folder: the ground truth plus noise (some values outside [0, 1]),
/// views written in reverse order so lookup must go by name.
fn member(
    dir: &Path,
    gts: &[ImageF32],
    noise: f32,
    rng: &mut Rng,
    size: (u32, u32),
) -> Vec<Vec<f32>> {
    std::fs::create_dir_all(dir).unwrap();
    let mut set = RenderSet::default();
    let mut imgs = vec![Vec::new(); gts.len()];
    for i in (0..gts.len()).rev() {
        let (w, h) = size;
        let n = (w * h) as usize;
        let mut planes = vec![vec![0f32; n]; 3];
        let mut inter = vec![0f32; 3 * n];
        for p in 0..n {
            for c in 0..3 {
                let base = if p < (W * H) as usize {
                    gts[i].data[p * 3 + c]
                } else {
                    0.5
                };
                let v = base + noise * (rng.next_f32() - 0.5);
                planes[c][p] = v;
                inter[p * 3 + c] = v;
            }
        }
        let file = format!("view_{i:04}.exr");
        let d = vec![1f32; n];
        image::write_exr(
            &dir.join(&file),
            w,
            h,
            &[
                ("R", &planes[0]),
                ("G", &planes[1]),
                ("B", &planes[2]),
                ("D", &d),
                ("A", &d),
            ],
        )
        .unwrap();
        set.views.push(RenderedView {
            name: format!("t{i}"),
            camera: camera().resized(w, h),
            file,
        });
        imgs[i] = inter;
    }
    write_json(&dir.join(files::RENDERS), &set).unwrap();
    imgs
}

fn run(root: &Path, members: &[PathBuf], test: &Path) -> Result<EnsembleMetrics, String> {
    let out = root.join("out");
    let _ = std::fs::remove_dir_all(&out);
    let mut ctx = RunContext::standalone(
        vec![
            ("members".into(), members.to_vec()),
            ("test".into(), vec![test.to_path_buf()]),
        ],
        &["eval"],
        &out,
        0,
        1,
    )
    .unwrap();
    let args = EvaluateEnsembleArgs {
        lpips: LpipsNet::None,
        ..Default::default()
    };
    EvaluateEnsembleNode::run(&args, &mut ctx).map_err(|e| e.to_string())?;
    let text = std::fs::read_to_string(out.join("eval/metrics.json")).unwrap();
    assert!(out.join("eval/metrics.csv").is_file());
    assert!(out.join("eval/renders").is_dir());
    Ok(serde_json::from_str(&text).unwrap())
}

/// PSNR of `img` (clamped to [0, 1]) against `gt`, in f64.
fn psnr(img: &[f64], gt: &ImageF32) -> f64 {
    let mse: f64 = img
        .iter()
        .zip(&gt.data)
        .map(|(a, b)| (a.clamp(0.0, 1.0) - *b as f64).powi(2))
        .sum::<f64>()
        / img.len() as f64;
    -10.0 * mse.log10()
}

#[test]
fn member_and_median_metrics_match_a_direct_computation() {
    for m in [3usize, 4] {
        let tmp = tempfile::tempdir().unwrap();
        let mut rng = Rng::new(7 + m as u64);
        let test = tmp.path().join("test");
        let gts = scene(&test, 2, &mut rng);
        let mut dirs = Vec::new();
        let mut renders = Vec::new();
        for j in 0..m {
            let d = tmp.path().join(format!("m{j}"));
            renders.push(member(&d, &gts, 0.1 + 0.1 * j as f32, &mut rng, (W, H)));
            dirs.push(d);
        }
        let got = run(tmp.path(), &dirs, &test).unwrap();
        assert_eq!(got.members, m);
        assert_eq!(got.member.len(), m);
        for (v, gt) in gts.iter().enumerate() {
            // Members, clamped.
            for (j, member_renders) in renders.iter().enumerate() {
                let img: Vec<f64> = member_renders[v].iter().map(|&x| x as f64).collect();
                let want = psnr(&img, gt);
                let have = got.member[j].views[v].metrics.psnr;
                assert!(
                    (want - have).abs() < 1e-6,
                    "M {m} member {j} view {v}: {want} vs {have}"
                );
            }
            // Median of the clamped members, per pixel and channel (mean of the middle two for
            // an even M), computed in f64 here.
            let median: Vec<f64> = (0..gt.data.len())
                .map(|k| {
                    let mut vals: Vec<f64> = (0..m)
                        .map(|j| (renders[j][v][k] as f64).clamp(0.0, 1.0))
                        .collect();
                    vals.sort_by(f64::total_cmp);
                    if m % 2 == 1 {
                        vals[m / 2]
                    } else {
                        0.5 * (vals[m / 2 - 1] + vals[m / 2])
                    }
                })
                .collect();
            let want = psnr(&median, gt);
            let have = got.median.views[v].metrics.psnr;
            assert!(
                (want - have).abs() < 1e-4,
                "M {m} median view {v}: {want} vs {have}"
            );
        }
        // The median of noisy members beats the average member here.
        assert!(got.median.mean.psnr > got.member_mean.psnr, "{got:?}");
        assert!(got.median.mean.lpips.is_none() && got.member_mean.avg_error.is_none());
    }
}

#[test]
fn missing_views_and_wrong_sizes_are_clear_errors() {
    let tmp = tempfile::tempdir().unwrap();
    let mut rng = Rng::new(1);
    let test = tmp.path().join("test");
    let gts = scene(&test, 2, &mut rng);
    let good = tmp.path().join("good");
    member(&good, &gts, 0.1, &mut rng, (W, H));
    // A render at another resolution.
    let small = tmp.path().join("small");
    member(&small, &gts, 0.1, &mut rng, (W / 2, H / 2));
    let err = run(tmp.path(), &[good.clone(), small.clone()], &test).unwrap_err();
    assert!(err.contains("is 10×7, its ground truth 20×14"), "{err}");
    assert!(err.contains("small"), "{err}");
    // A member without one of the test views.
    let partial = tmp.path().join("partial");
    member(&partial, &gts[..1], 0.1, &mut rng, (W, H));
    let err = run(tmp.path(), &[good.clone(), partial], &test).unwrap_err();
    assert!(err.contains("no render of the test view \"t1\""), "{err}");
    assert!(err.contains("renders.json"), "{err}");
    // No members at all.
    let err = run(tmp.path(), &[], &test).unwrap_err();
    assert!(err.contains("no render sets"), "{err}");
}
