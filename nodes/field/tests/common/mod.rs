//! A small procedural scene, ray-traced analytically, for the field's tests: three shaded
//! spheres on a checkered ground inside a colour-gradient dome, seen by cameras on an orbit.
#![allow(dead_code)]
#![allow(clippy::needless_range_loop)]

use augsplat_core::image::{write_exr, write_png};
use augsplat_core::linalg::{self, Vec3};
use augsplat_core::{Camera, ImageF32, Rng, Scene, SceneView};
use std::path::Path;

const SPHERES: [([f64; 3], f64, [f64; 3]); 3] = [
    ([0.0, 0.0, 0.0], 0.3, [0.9, 0.2, 0.2]),
    ([0.45, 0.2, -0.1], 0.2, [0.2, 0.8, 0.3]),
    ([-0.35, -0.3, -0.05], 0.25, [0.2, 0.3, 0.9]),
];
const GROUND_Y: f64 = 0.3; // ground plane y = +0.3 (y points down in OpenCV-like world)
const DOME: f64 = 3.0;

/// Traces a ray: (colour, distance).
pub fn trace(o: Vec3, d: Vec3) -> ([f64; 3], f64) {
    let light = linalg::normalize([0.4, -1.0, -0.3]);
    let mut best = (f64::INFINITY, [0.0; 3]);
    for (c, r, col) in SPHERES {
        let oc = linalg::sub(o, c);
        let b = linalg::dot(oc, d);
        let cc = linalg::dot(oc, oc) - r * r;
        let disc = b * b - cc;
        if disc > 0.0 {
            let t = -b - disc.sqrt();
            if t > 1e-6 && t < best.0 {
                let p = linalg::add(o, linalg::scale(d, t));
                let n = linalg::scale(linalg::sub(p, c), 1.0 / r);
                let shade = 0.35 + 0.65 * linalg::dot(n, light).max(0.0);
                let stripe = 0.85 + 0.15 * (12.0 * n[1]).sin();
                best = (t, col.map(|v| v * shade * stripe));
            }
        }
    }
    if d[1].abs() > 1e-9 {
        let t = (GROUND_Y - o[1]) / d[1];
        let p = linalg::add(o, linalg::scale(d, t));
        if t > 1e-6 && t < best.0 && p[0] * p[0] + p[2] * p[2] < 4.0 {
            let check = ((p[0] * 4.0).floor() + (p[2] * 4.0).floor()).rem_euclid(2.0);
            let v = 0.35 + 0.4 * check;
            best = (t, [v, v * 0.9, v * 0.7]);
        }
    }
    if best.0.is_infinite() {
        let b = linalg::dot(o, d);
        let cc = linalg::dot(o, o) - DOME * DOME;
        let t = -b + (b * b - cc).max(0.0).sqrt();
        let p = linalg::add(o, linalg::scale(d, t));
        let u = linalg::normalize(p);
        best = (t, [0.5 + 0.3 * u[0], 0.55 - 0.25 * u[1], 0.6 + 0.3 * u[2]]);
    }
    (best.1, best.0)
}

/// A camera at `centre` looking at the origin (OpenCV axes, world y down).
pub fn look_at(centre: Vec3, w: u32, h: u32) -> Camera {
    let f = linalg::normalize(linalg::scale(centre, -1.0));
    let down = [0.0, 1.0, 0.0];
    let right = linalg::normalize(linalg::cross(down, f));
    let down = linalg::cross(f, right);
    let r = [right, down, f];
    let t = linalg::scale(linalg::mat3_vec(&r, centre), -1.0);
    let focal = 0.5 * w as f64 / (30f64.to_radians()).tan();
    Camera {
        width: w,
        height: h,
        fx: focal,
        fy: focal,
        cx: w as f64 / 2.0,
        cy: h as f64 / 2.0,
        world_to_camera: linalg::mat4_from_rt(&r, t),
    }
}

/// Renders an image (2×2 supersampled) and the exact optical-axis depth of pixel centres.
pub fn render(cam: &Camera) -> (ImageF32, Vec<f32>) {
    let (w, h) = (cam.width, cam.height);
    let mut img = ImageF32::new(w, h, 3);
    let mut depth = vec![0f32; (w * h) as usize];
    let fwd = cam.forward();
    for i in 0..h {
        for j in 0..w {
            let mut acc = [0f64; 3];
            for s in 0..4 {
                let (u, v) = (
                    j as f64 + 0.25 + 0.5 * (s % 2) as f64,
                    i as f64 + 0.25 + 0.5 * (s / 2) as f64,
                );
                let (o, d) = cam.ray(u, v);
                let (c, _) = trace(o, d);
                for k in 0..3 {
                    acc[k] += c[k] / 4.0;
                }
            }
            for k in 0..3 {
                img.set(j, i, k as u32, acc[k] as f32);
            }
            let (o, d) = cam.pixel_ray(i, j);
            let (_, t) = trace(o, d);
            depth[(i * w + j) as usize] = (t * linalg::dot(d, fwd)) as f32;
        }
    }
    (img, depth)
}

/// Orbit cameras: radius 1.2, alternating heights, all looking at the origin.
pub fn orbit(n: usize, w: u32, h: u32) -> Vec<Camera> {
    (0..n)
        .map(|k| {
            let a = 2.0 * std::f64::consts::PI * k as f64 / n as f64;
            let y = if k % 2 == 0 { -0.35 } else { -0.15 };
            look_at([1.2 * a.cos(), y, 1.2 * a.sin()], w, h)
        })
        .collect()
}

/// Writes a scene folder with the given cameras. With `depth_fraction > 0` every view gets a
/// sparse depth map (that fraction of pixels, weight 1, chosen with `seed`). Returns the exact
/// depth maps.
pub fn write_scene(dir: &Path, cams: &[Camera], depth_fraction: f64, seed: u64) -> Vec<Vec<f32>> {
    std::fs::create_dir_all(dir.join("images")).unwrap();
    std::fs::create_dir_all(dir.join("depth")).unwrap();
    let mut views = Vec::new();
    let mut exact = Vec::new();
    let mut rng = Rng::new(seed);
    for (k, cam) in cams.iter().enumerate() {
        let name = format!("v{k:02}");
        let (img, depth) = render(cam);
        write_png(&dir.join(format!("images/{name}.png")), &img).unwrap();
        let depth_rel = if depth_fraction > 0.0 {
            let mut z = vec![0f32; depth.len()];
            let mut wt = vec![0f32; depth.len()];
            for p in 0..depth.len() {
                if rng.next_f64() < depth_fraction {
                    z[p] = depth[p];
                    wt[p] = 1.0;
                }
            }
            let rel = format!("depth/{name}.exr");
            write_exr(
                &dir.join(&rel),
                cam.width,
                cam.height,
                &[("Z", &z), ("W", &wt)],
            )
            .unwrap();
            Some(rel)
        } else {
            None
        };
        views.push(SceneView {
            name: name.clone(),
            image: format!("images/{name}.png"),
            depth: depth_rel,
            camera: cam.clone(),
        });
        exact.push(depth);
    }
    Scene {
        source: "field test scene".into(),
        views,
        near: 0.05,
        far: 4.5,
        normalization: Default::default(),
        has_points: false,
    }
    .save(dir)
    .unwrap();
    exact
}

/// Train/test scenes in `root/train`, `root/test`: `n` orbit views, every 4th held out.
pub fn split_scene(
    root: &Path,
    n: usize,
    w: u32,
    h: u32,
    depth_fraction: f64,
) -> (Vec<Camera>, Vec<Camera>) {
    let cams = orbit(n, w, h);
    let train: Vec<Camera> = cams
        .iter()
        .enumerate()
        .filter(|(k, _)| k % 4 != 1)
        .map(|(_, c)| c.clone())
        .collect();
    let test: Vec<Camera> = cams
        .iter()
        .enumerate()
        .filter(|(k, _)| k % 4 == 1)
        .map(|(_, c)| c.clone())
        .collect();
    write_scene(&root.join("train"), &train, depth_fraction, 7);
    write_scene(&root.join("test"), &test, 0.0, 8);
    (train, test)
}
