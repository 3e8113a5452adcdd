//! Held-out quality and wall time of ensemble members on the real captures in
//! `../shared/data` (skips with a message when absent):
//!
//! `cargo run --release -p augsplat-field --example real_data -- <fern|bonsai> [members]
//! [steps] [rays_per_step] [extra_downscale]`
//!
//! - fern: LLFF `images_8` (504×378) + `poses_bounds.npy`; every 8th view held out (17/3).
//! - bonsai: `colmap30_undistorted` (25 registered PINHOLE views, 800×533 JPEG), downscaled
//!   ×8 (100×67, the paper's 1/8); every 8th view held out (21/4).
//!
//! Prints per member the held-out PSNR and training time, the PSNR of the per-pixel median of
//! the members' renders, and the time to render one held-out view. Tiny loaders live here so
//! the example does not depend on the scene crate.
#![allow(clippy::needless_range_loop)]

use augsplat_core::linalg::{self, Mat4};
use augsplat_core::{Camera, Scene, SceneView};
use augsplat_field::field::Field;
use augsplat_field::node::TrainFieldArgs;
use augsplat_field::train::{self, ViewData};
use std::path::Path;
use std::time::Instant;

/// Cameras, interleaved RGB images, near and far (normalised units).
type Loaded = (Vec<Camera>, Vec<Vec<f32>>, f64, f64);

fn normalise(cams: &mut [Camera]) -> f64 {
    let n = cams.len() as f64;
    let mut c = [0f64; 3];
    for cam in cams.iter() {
        let p = cam.center();
        for k in 0..3 {
            c[k] += p[k] / n;
        }
    }
    let spread = cams
        .iter()
        .map(|cam| linalg::norm(linalg::sub(cam.center(), c)))
        .fold(0f64, f64::max)
        .max(1e-9);
    let s = 1.0 / spread;
    for cam in cams.iter_mut() {
        // p_n = (p − c)·s; world_to_camera of the normalised frame: R, (t + R c)·s.
        let (r, t) = linalg::rt_from_mat4(&cam.world_to_camera);
        let rc = linalg::mat3_vec(&r, c);
        cam.world_to_camera = linalg::mat4_from_rt(&r, linalg::scale(linalg::add(t, rc), s));
    }
    s
}

fn load_fern(dir: &Path) -> Result<Loaded, String> {
    let (shape, v) = augsplat_core::image::read_npy_array(&dir.join("poses_bounds.npy"))
        .map_err(|e| e.to_string())?;
    if shape.len() != 2 || shape[1] != 17 {
        return Err(format!(
            "poses_bounds.npy has shape {shape:?}, expected N×17"
        ));
    }
    let mut cams = Vec::new();
    let mut imgs = Vec::new();
    let (mut near, mut far) = (f64::INFINITY, 0f64);
    for i in 0..shape[0] {
        let row = &v[i * 17..(i + 1) * 17];
        let m = |r: usize, c: usize| row[r * 5 + c];
        let img = augsplat_core::image::read_rgb(&dir.join(format!("images_8/image{i:03}.png")))
            .map_err(|e| e.to_string())?;
        let f = m(2, 4) * img.width as f64 / m(1, 4);
        // Columns: down, right, back → OpenCV x = right, y = down, z = −back.
        let x = [m(0, 1), m(1, 1), m(2, 1)];
        let y = [m(0, 0), m(1, 0), m(2, 0)];
        let z = [-m(0, 2), -m(1, 2), -m(2, 2)];
        let c = [m(0, 3), m(1, 3), m(2, 3)];
        let r = [x, y, z];
        let t = linalg::scale(linalg::mat3_vec(&r, c), -1.0);
        let w2c: Mat4 = linalg::mat4_from_rt(&r, t);
        cams.push(Camera {
            width: img.width,
            height: img.height,
            fx: f,
            fy: f,
            cx: img.width as f64 / 2.0,
            cy: img.height as f64 / 2.0,
            world_to_camera: w2c,
        });
        near = near.min(row[15]);
        far = far.max(row[16]);
        imgs.push(img.data);
    }
    let s = normalise(&mut cams);
    Ok((cams, imgs, 0.9 * near * s, 1.1 * far * s))
}

fn quat_to_r(q: [f64; 4]) -> [[f64; 3]; 3] {
    linalg::quat_to_mat3(q)
}

fn load_bonsai(dir: &Path) -> Result<Loaded, String> {
    let txt = |f: &str| {
        std::fs::read_to_string(dir.join("sparse_txt").join(f)).map_err(|e| format!("{f}: {e}"))
    };
    let cameras = txt("cameras.txt")?;
    let line = cameras
        .lines()
        .find(|l| !l.starts_with('#') && !l.trim().is_empty())
        .ok_or("no camera")?;
    let p: Vec<&str> = line.split_whitespace().collect();
    if p.get(1) != Some(&"PINHOLE") {
        return Err("expected a PINHOLE camera".into());
    }
    let num = |s: &str| s.parse::<f64>().map_err(|e| e.to_string());
    let (w, h, fx, fy, cx, cy) = (
        num(p[2])? as u32,
        num(p[3])? as u32,
        num(p[4])?,
        num(p[5])?,
        num(p[6])?,
        num(p[7])?,
    );
    let images = txt("images.txt")?;
    let mut entries = Vec::new();
    let mut lines = images.lines().filter(|l| !l.starts_with('#'));
    while let Some(l) = lines.next() {
        let _points = lines.next();
        let q: Vec<&str> = l.split_whitespace().collect();
        if q.len() < 10 {
            continue;
        }
        let quat = [num(q[1])?, num(q[2])?, num(q[3])?, num(q[4])?];
        let t = [num(q[5])?, num(q[6])?, num(q[7])?];
        entries.push((q[9].to_string(), quat, t));
    }
    entries.sort_by(|a, b| a.0.cmp(&b.0));
    let pts = txt("points3D.txt")?;
    let points: Vec<[f64; 3]> = pts
        .lines()
        .filter(|l| !l.starts_with('#'))
        .filter_map(|l| {
            let v: Vec<f64> = l
                .split_whitespace()
                .skip(1)
                .take(3)
                .filter_map(|s| s.parse().ok())
                .collect();
            (v.len() == 3).then(|| [v[0], v[1], v[2]])
        })
        .collect();
    let mut cams = Vec::new();
    let mut imgs = Vec::new();
    for (name, q, t) in &entries {
        let img = augsplat_core::image::read_rgb(&dir.join("images").join(name))
            .map_err(|e| e.to_string())?;
        let cam = Camera {
            width: w,
            height: h,
            fx,
            fy,
            cx,
            cy,
            world_to_camera: linalg::mat4_from_rt(&quat_to_r(*q), *t),
        };
        let small = img.downscale(8);
        imgs.push(small.data.clone());
        cams.push(cam.resized(small.width, small.height));
    }
    // Depth range of the points over all views (original units), then normalise.
    let mut depths: Vec<f64> = Vec::new();
    for cam in &cams {
        for p in &points {
            let z = cam.to_camera(*p)[2];
            if z > 0.0 {
                depths.push(z);
            }
        }
    }
    depths.sort_by(|a, b| a.total_cmp(b));
    let q = |f: f64| depths[((depths.len() - 1) as f64 * f) as usize];
    let (near, far) = (0.5 * q(0.01), 3.0 * q(0.99));
    let s = normalise(&mut cams);
    Ok((cams, imgs, near * s, far * s))
}

fn main() {
    let args: Vec<String> = std::env::args().collect();
    let which = args.get(1).cloned().unwrap_or_else(|| "fern".into());
    let members: usize = args.get(2).and_then(|s| s.parse().ok()).unwrap_or(1);
    let steps: u32 = args.get(3).and_then(|s| s.parse().ok()).unwrap_or(500);
    let rays: u32 = args.get(4).and_then(|s| s.parse().ok()).unwrap_or(1024);
    let extra: u32 = args
        .get(5)
        .and_then(|s| s.parse().ok())
        .unwrap_or(if which == "fern" { 2 } else { 1 });
    let data = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../../shared/data");
    let loaded = match which.as_str() {
        "fern" => load_fern(&data.join("fern")),
        _ => load_bonsai(&data.join("bonsai/colmap30_undistorted")),
    };
    let (cams, imgs, near, far) = match loaded {
        Ok(v) => v,
        Err(e) => {
            eprintln!("skipping: cannot load {which} from {}: {e}", data.display());
            return;
        }
    };
    let mut train_views = Vec::new();
    let mut test_views = Vec::new();
    for (i, (cam, rgb)) in cams.iter().zip(imgs).enumerate() {
        let img = augsplat_core::ImageF32::from_vec(cam.width, cam.height, 3, rgb).downscale(extra);
        let v = ViewData {
            name: format!("{i}"),
            camera: cam.resized(img.width, img.height),
            rgb: img.data,
            depth: None,
        };
        if i % 8 == 0 {
            test_views.push(v);
        } else {
            train_views.push(v);
        }
    }
    let scene = Scene {
        source: which.clone(),
        views: train_views
            .iter()
            .map(|v| SceneView {
                name: v.name.clone(),
                image: String::new(),
                depth: None,
                camera: v.camera.clone(),
            })
            .collect(),
        near,
        far,
        normalization: Default::default(),
        has_points: false,
    };
    let threads = rayon::current_num_threads();
    println!(
        "{which}: {} train / {} test views at {}×{}, near {near:.3} far {far:.3}, {members} member(s) × {steps} steps × {rays} rays, {threads} threads",
        train_views.len(),
        test_views.len(),
        train_views[0].camera.width,
        train_views[0].camera.height
    );
    let mut renders: Vec<Vec<Vec<f32>>> = Vec::new();
    for m in 0..members {
        let a = TrainFieldArgs {
            seed: m as u64,
            steps,
            rays_per_step: rays,
            log2_table_size: std::env::var("LOG2T")
                .ok()
                .and_then(|v| v.parse().ok())
                .unwrap_or(16),
            eval_every: std::env::var("EVAL_EVERY")
                .ok()
                .and_then(|v| v.parse().ok())
                .unwrap_or(0),
            depth_loss_weight: 0.0,
            ..TrainFieldArgs::default()
        };
        let cfg = a.field_config(&scene, train_views.len()).expect("config");
        let field = Field::new(cfg).expect("field");
        let t0 = Instant::now();
        let mut last_print = Instant::now();
        let mut samples = 0u64;
        let mut on_step = |r: train::StepReport<'_>| {
            samples += r.stats.samples;
            if last_print.elapsed().as_secs_f64() > 30.0 {
                println!(
                    "  step {}: loss {:.5}, {:.0} samples/step",
                    r.step, r.stats.rgb_loss, r.stats.samples as f64
                );
                last_print = Instant::now();
            }
        };
        let (state, curve) = train::train(
            &field,
            &train_views,
            Some(&test_views),
            &a.options(),
            &mut on_step,
        )
        .expect("training");
        let secs = t0.elapsed().as_secs_f64();
        for p in &curve.points {
            println!(
                "  member {m}: step {} held-out PSNR {:.2} dB (train loss {:.5})",
                p.step, p.psnr, p.loss
            );
        }
        println!(
            "  member {m}: {secs:.1} s total incl. evaluation, {:.0} samples/step on average, occupancy {:.1}%",
            samples as f64 / steps as f64,
            100.0 * state.occupancy.occupied_fraction()
        );
        let t1 = Instant::now();
        let imgs: Vec<Vec<f32>> = test_views
            .iter()
            .map(|v| {
                train::render_camera(
                    &field,
                    &state.params,
                    &state.occupancy,
                    &v.camera,
                    [0.0; 3],
                    256,
                )
                .rgb
            })
            .collect();
        println!(
            "  member {m}: rendering {} held-out views of {}×{} took {:.2} s ({:.2} s per view)",
            test_views.len(),
            test_views[0].camera.width,
            test_views[0].camera.height,
            t1.elapsed().as_secs_f64(),
            t1.elapsed().as_secs_f64() / test_views.len() as f64
        );
        if std::env::var("RENDER_COMPARE").is_ok() {
            compare_render(&field, &state, &test_views[0]);
        }
        renders.push(imgs);
    }
    if members > 1 {
        let mut ps = 0.0;
        for (k, v) in test_views.iter().enumerate() {
            let med: Vec<f32> = (0..v.rgb.len())
                .map(|j| {
                    let mut vals: Vec<f32> = renders.iter().map(|r| r[k][j]).collect();
                    vals.sort_by(|a, b| a.total_cmp(b));
                    vals[vals.len() / 2]
                })
                .collect();
            ps += train::psnr(&med, &v.rgb).0;
        }
        println!(
            "median of {members} members: held-out PSNR {:.2} dB",
            ps / test_views.len() as f64
        );
    }
}

/// Times one held-out view rendered by `render_camera` (densities stop at early termination)
/// against a full-density render of the same rays (every marched sample evaluated), best of
/// three each, and prints the largest differences.
fn compare_render(field: &Field, state: &train::TrainState, view: &ViewData) {
    use augsplat_field::field::{ChunkState, RayInput};
    use rayon::prelude::*;
    let cam = &view.camera;
    let best = |f: &mut dyn FnMut() -> Vec<f32>| {
        let mut b = f64::INFINITY;
        let mut out = Vec::new();
        for _ in 0..3 {
            let t0 = Instant::now();
            out = f();
            b = b.min(t0.elapsed().as_secs_f64());
        }
        (b, out)
    };
    let (t_stop, rgb_stop) = best(&mut || {
        train::render_camera(field, &state.params, &state.occupancy, cam, [0.0; 3], 256).rgb
    });
    let mean = field.mean_embedding(&state.params);
    let (w, h) = (cam.width as usize, cam.height as usize);
    let (t_full, rgb_full) = best(&mut || {
        let parts: Vec<Vec<f32>> = (0..(w * h).div_ceil(256))
            .into_par_iter()
            .map(|c| {
                let mut st = ChunkState::default();
                st.min_color_weight = augsplat_field::constants::RENDER_MIN_COLOR_WEIGHT;
                let rays: Vec<RayInput> = (c * 256..((c + 1) * 256).min(w * h))
                    .map(|p| {
                        let (o, d) = cam.pixel_ray((p / w) as u32, (p % w) as u32);
                        RayInput {
                            origin: o.map(|x| x as f32),
                            dir: d.map(|x| x as f32),
                            image: u32::MAX,
                            background: [0.0; 3],
                        }
                    })
                    .collect();
                field.forward_chunk(
                    &state.params,
                    &state.occupancy,
                    &rays,
                    &|_| 0.5,
                    &mean,
                    &mut st,
                );
                st.out.iter().flat_map(|o| o.rgb).collect()
            })
            .collect();
        parts.concat()
    });
    let diff = rgb_stop
        .iter()
        .zip(&rgb_full)
        .map(|(a, b)| (a - b).abs())
        .fold(0f32, f32::max);
    println!(
        "  render of one {}×{} view (best of 3): {:.3} s with densities stopped at early termination, {:.3} s evaluating every marched sample; PSNR {:.3} / {:.3} dB; max |Δrgb| {:.2e}",
        w,
        h,
        t_stop,
        t_full,
        train::psnr(&rgb_stop, &view.rgb).0,
        train::psnr(&rgb_full, &view.rgb).0,
        diff
    );
}
