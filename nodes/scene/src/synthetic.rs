//! The generated default scene: a deterministic, exactly ray-traced procedural scene.
//!
//! Content (design frame, z up, metres-like units): a textured ground disk (soft checker of
//! 0.5-unit cells over a colour gradient, radius 3.2), two textured spheres (soft latitude
//! stripes; a checker in longitude/latitude), a rotated box with a different colour and a
//! soft grid per face, a small gradient sphere, and a background dome (radius 6: a sky
//! gradient with a low-frequency azimuthal tint above the horizon, a darker soft band below).
//! Shading is Lambertian with one directional light and ambient light, plus a mild, broad
//! Blinn–Phong highlight on the spheres (`specular`) for some view dependence; no shadows.
//!
//! Every pixel averages `supersample²` rays on a fixed regular grid inside the pixel (no
//! aliasing, no randomness). Exact depth is the optical-axis depth of the pixel-centre ray.
//! Cameras: `Orbit` (around the objects, elevation varying 20°–35°) or `Forward` (a shallow
//! arc in front, all looking the same direction). Sparse points: pixels drawn with the seed in
//! random views, traced to the surface, kept when at least two views see the surface point
//! (projection inside the image and unoccluded); the stored position gets Gaussian noise of
//! `point_noise` (normalised units), and the stored error is the mean pixel distance between
//! the noisy and exact projections over the track.
//!
//! Output folder: the scene artifact plus `exact_depth/<name>.exr` (channel `Z`, normalised
//! units, depth along the optical axis of the pixel-centre ray). The scene is normalised with
//! the import policy ([`crate::import::normalization_for`]).

use crate::error::{Result, SceneError};
use crate::import::{normalization_for, normalize_pose, NormalizeMode};
use augsplat_core::image::{write_exr, write_png};
use augsplat_core::linalg::{self, Mat3, Vec3};
use augsplat_core::scene::POINTS_FILE;
use augsplat_core::{Camera, ImageF32, PointCloud, Rng, Scene, SceneView};
use rayon::prelude::*;
use serde::{Deserialize, Serialize};
use std::path::Path;

/// Camera layout of the generated scene.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
pub enum Layout {
    /// Cameras on an orbit around the objects.
    #[default]
    Orbit,
    /// Cameras on a shallow arc in front of the objects, all looking the same way.
    Forward,
}

/// Parameters of the generated scene.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct SyntheticParams {
    /// Image width, pixels.
    pub width: u32,
    /// Image height, pixels.
    pub height: u32,
    /// Number of views.
    pub views: u32,
    /// Camera layout.
    pub layout: Layout,
    /// Seed of the point sampling and point noise.
    pub seed: u64,
    /// Number of sparse points.
    pub points: u32,
    /// Standard deviation of the noise added to point positions (normalised units).
    pub point_noise: f64,
    /// Rays per pixel along each axis (4 ⇒ 16 rays per pixel).
    pub supersample: u32,
    /// Strength of the highlight on the spheres (0 = purely diffuse).
    pub specular: f64,
    /// Horizontal field of view, degrees.
    pub fov_deg: f64,
}

impl Default for SyntheticParams {
    fn default() -> Self {
        SyntheticParams {
            width: 128,
            height: 96,
            views: 30,
            layout: Layout::Orbit,
            seed: 0,
            points: 3000,
            point_noise: 0.003,
            supersample: 4,
            specular: 0.12,
            fov_deg: 60.0,
        }
    }
}

impl SyntheticParams {
    /// Checks ranges.
    pub fn validate(&self) -> std::result::Result<(), String> {
        if self.width == 0 || self.height == 0 || self.width > 8192 || self.height > 8192 {
            return Err(format!(
                "image size {}×{} must be within 1..=8192",
                self.width, self.height
            ));
        }
        if self.views < 1 || self.views > 10_000 {
            return Err(format!("views = {} must be within 1..=10000", self.views));
        }
        if self.supersample < 1 || self.supersample > 16 {
            return Err(format!(
                "supersample = {} must be within 1..=16",
                self.supersample
            ));
        }
        if !(self.fov_deg > 1.0 && self.fov_deg < 170.0) {
            return Err(format!(
                "fov_deg = {} must be within (1, 170)",
                self.fov_deg
            ));
        }
        if !(self.point_noise >= 0.0 && self.point_noise.is_finite()) {
            return Err(format!(
                "point_noise = {} must be finite and ≥ 0",
                self.point_noise
            ));
        }
        if !(self.specular >= 0.0 && self.specular <= 1.0) {
            return Err(format!(
                "specular = {} must be within [0, 1]",
                self.specular
            ));
        }
        Ok(())
    }
}

/// A surface hit.
#[derive(Clone, Copy, Debug)]
struct Hit {
    t: f64,
    p: Vec3,
    n: Vec3,
    obj: u8,
}

const DOME_RADIUS: f64 = 6.0;
const GROUND_RADIUS: f64 = 3.2;
const OBJ_DOME: u8 = 0;
const OBJ_GROUND: u8 = 1;

struct Sphere {
    c: Vec3,
    r: f64,
}

/// The fixed world.
struct World {
    spheres: [Sphere; 3],
    box_c: Vec3,
    box_h: Vec3,
    /// World-to-box rotation.
    box_r: Mat3,
    light: Vec3,
    specular: f64,
}

impl World {
    fn new(specular: f64) -> World {
        World {
            spheres: [
                Sphere {
                    c: [0.6, 0.3, 0.45],
                    r: 0.45,
                },
                Sphere {
                    c: [-0.7, 0.55, 0.3],
                    r: 0.3,
                },
                Sphere {
                    c: [0.15, -0.25, 0.16],
                    r: 0.16,
                },
            ],
            box_c: [-0.25, -0.75, 0.35],
            box_h: [0.35, 0.25, 0.35],
            box_r: linalg::transpose3(&linalg::axis_angle([0.0, 0.0, 1.0], 0.5)),
            light: linalg::normalize([0.5, -0.4, 0.8]),
            specular,
        }
    }

    /// The nearest hit along the ray (every ray from inside the dome hits something).
    fn trace(&self, o: Vec3, d: Vec3) -> Hit {
        let mut best = dome_hit(o, d);
        // Ground plane z = 0 (disk).
        if d[2] < -1e-12 {
            let t = -o[2] / d[2];
            if t > 1e-9 && t < best.t {
                let p = linalg::add(o, linalg::scale(d, t));
                if p[0] * p[0] + p[1] * p[1] < GROUND_RADIUS * GROUND_RADIUS {
                    best = Hit {
                        t,
                        p,
                        n: [0.0, 0.0, 1.0],
                        obj: OBJ_GROUND,
                    };
                }
            }
        }
        for (k, s) in self.spheres.iter().enumerate() {
            if let Some(t) = sphere_near(o, d, s.c, s.r) {
                if t < best.t {
                    let p = linalg::add(o, linalg::scale(d, t));
                    best = Hit {
                        t,
                        p,
                        n: linalg::scale(linalg::sub(p, s.c), 1.0 / s.r),
                        obj: 2 + k as u8,
                    };
                }
            }
        }
        // Oriented box: slab test in box coordinates.
        let ol = linalg::mat3_vec(&self.box_r, linalg::sub(o, self.box_c));
        let dl = linalg::mat3_vec(&self.box_r, d);
        let (mut t0, mut t1, mut axis, mut sign) = (f64::NEG_INFINITY, f64::INFINITY, 0usize, 1.0);
        let mut ok = true;
        for a in 0..3 {
            if dl[a].abs() < 1e-15 {
                if ol[a].abs() > self.box_h[a] {
                    ok = false;
                }
                continue;
            }
            let ta = (-self.box_h[a] - ol[a]) / dl[a];
            let tb = (self.box_h[a] - ol[a]) / dl[a];
            let (lo, hi) = if ta < tb { (ta, tb) } else { (tb, ta) };
            if lo > t0 {
                t0 = lo;
                axis = a;
                sign = if dl[a] > 0.0 { -1.0 } else { 1.0 };
            }
            t1 = t1.min(hi);
        }
        if ok && t0 <= t1 && t0 > 1e-9 && t0 < best.t {
            let mut nl = [0.0; 3];
            nl[axis] = sign;
            best = Hit {
                t: t0,
                p: linalg::add(o, linalg::scale(d, t0)),
                n: linalg::mat3_vec(&linalg::transpose3(&self.box_r), nl),
                obj: 5 + axis as u8 * 2 + (sign > 0.0) as u8,
            };
        }
        best
    }

    /// Albedo (or emitted colour for the dome) at a hit.
    fn albedo(&self, h: &Hit) -> Vec3 {
        let p = h.p;
        match h.obj {
            OBJ_DOME => {
                let dir = linalg::scale(p, 1.0 / DOME_RADIUS);
                let el = dir[2].clamp(-1.0, 1.0);
                let az = dir[1].atan2(dir[0]);
                if el >= 0.0 {
                    let s = el.powf(0.6);
                    let tint = 0.05 * (3.0 * az).sin();
                    [
                        lerp(0.85, 0.25, s) + tint,
                        lerp(0.88, 0.45, s) + 0.5 * tint,
                        lerp(0.92, 0.85, s) - tint,
                    ]
                } else {
                    let band = 0.5 + 0.5 * (2.0 * az).cos();
                    let s = (-el).powf(0.5);
                    [
                        lerp(0.55, 0.3, s) + 0.06 * band,
                        lerp(0.5, 0.28, s) + 0.04 * band,
                        lerp(0.45, 0.25, s),
                    ]
                }
            }
            OBJ_GROUND => {
                let c = soft_checker(p[0] / 0.5, p[1] / 0.5, 0.12);
                let g = 0.5 + 0.5 * (0.7 * p[0] - 0.5 * p[1]).sin();
                let base_a = [0.82, 0.74, 0.58];
                let base_b = [0.45, 0.5, 0.38];
                let a = lerp3(base_a, base_b, c);
                [
                    a[0] * (0.85 + 0.15 * g),
                    a[1],
                    a[2] * (0.9 + 0.1 * (1.0 - g)),
                ]
            }
            2 => {
                // Big sphere: soft latitude stripes, red/yellow.
                let n = h.n;
                let lat = n[2].clamp(-1.0, 1.0).asin();
                let s = 0.5 + 0.5 * (lat * 8.0).sin();
                lerp3([0.85, 0.2, 0.15], [0.95, 0.8, 0.25], s)
            }
            3 => {
                // Blue sphere: checker in longitude/latitude.
                let n = h.n;
                let lat = n[2].clamp(-1.0, 1.0).asin();
                let lon = n[1].atan2(n[0]);
                let c = soft_checker(
                    lon * 4.0 / std::f64::consts::PI,
                    lat * 4.0 / std::f64::consts::PI,
                    0.1,
                );
                lerp3([0.15, 0.3, 0.8], [0.75, 0.85, 0.95], c)
            }
            4 => {
                // Small sphere: smooth green gradient.
                let s = 0.5 + 0.5 * h.n[2];
                lerp3([0.1, 0.45, 0.15], [0.6, 0.9, 0.4], s)
            }
            _ => {
                // Box faces: a hue per face and a soft grid.
                let face = (h.obj - 5) as usize;
                let hues = [
                    [0.7, 0.35, 0.75],
                    [0.35, 0.7, 0.7],
                    [0.9, 0.55, 0.3],
                    [0.5, 0.5, 0.85],
                    [0.8, 0.8, 0.8],
                    [0.6, 0.75, 0.35],
                ];
                let pl = linalg::mat3_vec(&self.box_r, linalg::sub(p, self.box_c));
                let axis = face / 2;
                let (a, b) = ((axis + 1) % 3, (axis + 2) % 3);
                let g = soft_grid(pl[a] / 0.2333, pl[b] / 0.2333, 0.15);
                let c = hues[face];
                lerp3(c, linalg::scale(c, 0.45), g)
            }
        }
    }

    /// Shaded colour seen along direction `d` at hit `h`.
    fn shade(&self, h: &Hit, d: Vec3) -> Vec3 {
        let a = self.albedo(h);
        if h.obj == OBJ_DOME {
            return a;
        }
        let ndl = linalg::dot(h.n, self.light).max(0.0);
        let lit = 0.4 + 0.6 * ndl;
        let mut c = linalg::scale(a, lit);
        if (2..=4).contains(&h.obj) && self.specular > 0.0 {
            let half = linalg::normalize(linalg::sub(self.light, d));
            let s = linalg::dot(h.n, half).max(0.0).powi(8) * self.specular;
            c = linalg::add(c, [s, s, s]);
        }
        c
    }
}

fn lerp(a: f64, b: f64, t: f64) -> f64 {
    a + (b - a) * t
}

fn lerp3(a: Vec3, b: Vec3, t: f64) -> Vec3 {
    linalg::lerp(a, b, t)
}

/// A checker in [0, 1] with smoothed edges (`soft` is the edge half-width in cells).
fn soft_checker(u: f64, v: f64, soft: f64) -> f64 {
    let su = smooth_square(u, soft);
    let sv = smooth_square(v, soft);
    // XOR of two soft square waves in [0, 1].
    su + sv - 2.0 * su * sv
}

/// A square wave of period 2 in [0, 1] with linear ramps of half-width `soft`.
fn smooth_square(x: f64, soft: f64) -> f64 {
    let f = x.rem_euclid(2.0);
    if f < 1.0 {
        ramp(f, soft)
    } else {
        1.0 - ramp(f - 1.0, soft)
    }
}

/// 0 in the middle of [0, 1], rising to 0.5 at the edges over `soft` (continuous across them).
fn ramp(f: f64, soft: f64) -> f64 {
    let d = f.min(1.0 - f);
    if d >= soft {
        0.0
    } else {
        0.5 * (1.0 - d / soft)
    }
}

/// 1 on grid lines (unit spacing), 0 between, with soft edges of half-width `w`.
fn soft_grid(u: f64, v: f64, w: f64) -> f64 {
    let line = |x: f64| {
        let d = (x - x.round()).abs();
        (1.0 - d / w).clamp(0.0, 1.0)
    };
    line(u).max(line(v))
}

fn dome_hit(o: Vec3, d: Vec3) -> Hit {
    // Far root of |o + t d| = R (o is inside the dome).
    let b = linalg::dot(o, d);
    let c = linalg::dot(o, o) - DOME_RADIUS * DOME_RADIUS;
    let t = -b + (b * b - c).max(0.0).sqrt();
    let p = linalg::add(o, linalg::scale(d, t));
    Hit {
        t,
        p,
        n: linalg::scale(p, -1.0 / DOME_RADIUS),
        obj: OBJ_DOME,
    }
}

fn sphere_near(o: Vec3, d: Vec3, c: Vec3, r: f64) -> Option<f64> {
    let oc = linalg::sub(o, c);
    let b = linalg::dot(oc, d);
    let cc = linalg::dot(oc, oc) - r * r;
    let disc = b * b - cc;
    if disc < 0.0 {
        return None;
    }
    let s = disc.sqrt();
    let t = -b - s;
    if t > 1e-9 {
        Some(t)
    } else {
        let t2 = -b + s;
        (t2 > 1e-9).then_some(t2)
    }
}

/// World-to-camera (OpenCV axes) looking from `c` along `forward`, with world up +z.
fn look_along(c: Vec3, forward: Vec3) -> augsplat_core::linalg::Mat4 {
    let z = linalg::normalize(forward);
    let x = linalg::normalize(linalg::cross(z, [0.0, 0.0, 1.0]));
    let y = linalg::cross(z, x);
    let r = [x, y, z];
    let t = linalg::scale(linalg::mat3_vec(&r, c), -1.0);
    linalg::mat4_from_rt(&r, t)
}

/// The cameras of the generated scene in the design frame.
fn design_cameras(p: &SyntheticParams) -> Vec<Camera> {
    let fx = 0.5 * p.width as f64 / (0.5 * p.fov_deg.to_radians()).tan();
    let n = p.views as usize;
    (0..n)
        .map(|i| {
            let w2c = match p.layout {
                Layout::Orbit => {
                    let az = std::f64::consts::TAU * i as f64 / n as f64;
                    let el = (27.5
                        + 7.5 * (std::f64::consts::TAU * 2.0 * i as f64 / n as f64).sin())
                    .to_radians();
                    let r = 2.6;
                    let target = [0.0, 0.0, 0.3];
                    let c = [
                        r * el.cos() * az.cos(),
                        r * el.cos() * az.sin(),
                        target[2] + r * el.sin(),
                    ];
                    look_along(c, linalg::sub(target, c))
                }
                Layout::Forward => {
                    let s = if n > 1 {
                        i as f64 / (n - 1) as f64 * 2.0 - 1.0
                    } else {
                        0.0
                    };
                    let ang = s * 0.35;
                    let c = [
                        2.6 * ang.sin(),
                        -2.6 * ang.cos() + 0.3 * s * s,
                        0.9 + 0.15 * (3.0 * s).sin(),
                    ];
                    look_along(c, [0.0, 1.0, -0.28])
                }
            };
            Camera {
                width: p.width,
                height: p.height,
                fx,
                fy: fx,
                cx: p.width as f64 / 2.0,
                cy: p.height as f64 / 2.0,
                world_to_camera: w2c,
            }
        })
        .collect()
}

/// Renders one view (design frame): supersampled RGB and exact pixel-centre depth.
fn render_view(world: &World, cam: &Camera, ss: u32) -> (ImageF32, Vec<f32>) {
    let (w, h) = (cam.width as usize, cam.height as usize);
    let mut img = ImageF32::new(cam.width, cam.height, 3);
    let mut depth = vec![0f32; w * h];
    let fwd = cam.forward();
    let inv = 1.0 / (ss * ss) as f64;
    img.data
        .par_chunks_mut(w * 3)
        .zip(depth.par_chunks_mut(w))
        .enumerate()
        .for_each(|(i, (row, drow))| {
            for j in 0..w {
                let mut acc = [0.0; 3];
                for a in 0..ss {
                    for b in 0..ss {
                        let u = j as f64 + (b as f64 + 0.5) / ss as f64;
                        let v = i as f64 + (a as f64 + 0.5) / ss as f64;
                        let (o, d) = cam.ray(u, v);
                        let hit = world.trace(o, d);
                        acc = linalg::add(acc, world.shade(&hit, d));
                    }
                }
                for k in 0..3 {
                    row[j * 3 + k] = (acc[k] * inv) as f32;
                }
                let (o, d) = cam.pixel_ray(i as u32, j as u32);
                let hit = world.trace(o, d);
                drow[j] = (hit.t * linalg::dot(d, fwd)) as f32;
            }
        });
    (img, depth)
}

/// Whether design-frame point `p` (on a surface) is seen by `cam`: inside the image, in
/// front, and the first hit from the camera towards it is the point itself.
fn sees(world: &World, cam: &Camera, p: Vec3) -> bool {
    let (u, v, z) = cam.project(p);
    if !(z > 1e-6 && u >= 0.0 && v >= 0.0 && u < cam.width as f64 && v < cam.height as f64) {
        return false;
    }
    let c = cam.center();
    let to = linalg::sub(p, c);
    let dist = linalg::norm(to);
    let hit = world.trace(c, linalg::scale(to, 1.0 / dist));
    (hit.t - dist).abs() < 1e-6 * (1.0 + dist)
}

/// Generates the scene into folder `out` and returns its description.
pub fn generate(params: &SyntheticParams, out: &Path) -> Result<Scene> {
    params.validate().map_err(SceneError::Invalid)?;
    let world = World::new(params.specular);
    let cams = design_cameras(params);
    let centres: Vec<Vec3> = cams.iter().map(|c| c.center()).collect();
    let norm = normalization_for(&centres, NormalizeMode::Cameras);
    let names: Vec<String> = (0..cams.len()).map(|i| format!("view_{i:03}")).collect();
    for sub in ["images", "exact_depth"] {
        let d = out.join(sub);
        std::fs::create_dir_all(&d).map_err(|e| SceneError::io(&d, e))?;
    }
    let mut views = Vec::with_capacity(cams.len());
    let (mut dmin, mut dmax) = (f64::INFINITY, 0f64);
    for (cam, name) in cams.iter().zip(&names) {
        let (img, depth) = render_view(&world, cam, params.supersample);
        let zn: Vec<f32> = depth
            .iter()
            .map(|&z| (z as f64 * norm.scale) as f32)
            .collect();
        for &z in &zn {
            dmin = dmin.min(z as f64);
            dmax = dmax.max(z as f64);
        }
        write_png(&out.join(format!("images/{name}.png")), &img)?;
        write_exr(
            &out.join(format!("exact_depth/{name}.exr")),
            cam.width,
            cam.height,
            &[("Z", &zn)],
        )?;
        views.push(SceneView {
            name: name.clone(),
            image: format!("images/{name}.png"),
            depth: None,
            camera: Camera {
                world_to_camera: normalize_pose(&cam.world_to_camera, &norm),
                ..cam.clone()
            },
        });
    }
    let cloud = sample_points(&world, &cams, params, &norm);
    cloud.save(&out.join(POINTS_FILE))?;
    let scene = Scene {
        source: format!(
            "SyntheticScene {}x{} {} views {:?} seed {}",
            params.width, params.height, params.views, params.layout, params.seed
        ),
        views,
        near: 0.8 * dmin,
        far: 1.2 * dmax,
        normalization: norm,
        has_points: !cloud.is_empty(),
    };
    scene.save(out)?;
    Ok(scene)
}

/// One accepted point sample: exact and noisy normalised positions, colour, track.
type Sample = (Vec3, Vec3, Vec3, Vec<u32>);

/// Samples the sparse points (see the module docs). Deterministic for any thread count:
/// attempts are independent streams and the first successes in attempt order are kept.
fn sample_points(
    world: &World,
    cams: &[Camera],
    p: &SyntheticParams,
    norm: &augsplat_core::scene::Normalization,
) -> PointCloud {
    let target = p.points as usize;
    let mut cloud = PointCloud::default();
    cloud.track_offsets.push(0);
    if target == 0 || cams.len() < 2 {
        return cloud;
    }
    let chunk = 256usize;
    let max_attempts = target * 8 + 1024;
    let mut attempt = 0usize;
    while cloud.len() < target && attempt < max_attempts {
        let batch: Vec<Option<Sample>> = (attempt..attempt + chunk)
            .into_par_iter()
            .map(|a| {
                let mut rng = Rng::stream(p.seed, a as u64);
                let vi = rng.below(cams.len() as u64) as usize;
                let cam = &cams[vi];
                let u = rng.uniform(0.0, cam.width as f64);
                let v = rng.uniform(0.0, cam.height as f64);
                let (o, d) = cam.ray(u, v);
                let hit = world.trace(o, d);
                let track: Vec<u32> = cams
                    .iter()
                    .enumerate()
                    .filter(|(k, c)| *k == vi || sees(world, c, hit.p))
                    .map(|(k, _)| k as u32)
                    .collect();
                if track.len() < 2 {
                    return None;
                }
                let color = world.shade(&hit, d);
                let pn = norm.apply(hit.p);
                let noise = [rng.normal(), rng.normal(), rng.normal()];
                let noisy = linalg::add(pn, linalg::scale(noise, p.point_noise));
                Some((pn, noisy, color, track))
            })
            .collect();
        attempt += chunk;
        for (exact, noisy, color, track) in batch.into_iter().flatten() {
            if cloud.len() >= target {
                break;
            }
            // Reprojection error of the noisy point against the exact one.
            let mut e = 0.0;
            for &t in &track {
                let cam = Camera {
                    world_to_camera: normalize_pose(&cams[t as usize].world_to_camera, norm),
                    ..cams[t as usize].clone()
                };
                let (u0, v0, _) = cam.project(exact);
                let (u1, v1, _) = cam.project(noisy);
                e += ((u1 - u0).powi(2) + (v1 - v0).powi(2)).sqrt();
            }
            cloud.positions.push(noisy.map(|x| x as f32));
            cloud.colors.push(color.map(|c| c.clamp(0.0, 1.0) as f32));
            cloud.errors.push((e / track.len() as f64) as f32);
            cloud.track_views.extend_from_slice(&track);
            cloud.track_offsets.push(cloud.track_views.len() as u32);
        }
    }
    cloud
}

#[cfg(test)]
mod tests {
    use super::*;

    fn small() -> SyntheticParams {
        SyntheticParams {
            width: 32,
            height: 24,
            views: 6,
            points: 200,
            supersample: 2,
            ..Default::default()
        }
    }

    #[test]
    fn checker_is_bounded_and_continuous() {
        let mut prev = soft_checker(-3.0, 0.3, 0.08);
        for k in 1..6000 {
            let x = -3.0 + k as f64 * 0.001;
            let c = soft_checker(x, 0.3, 0.08);
            assert!((0.0..=1.0).contains(&c));
            assert!((c - prev).abs() < 0.02, "jump at {x}: {prev} → {c}");
            prev = c;
        }
    }

    #[test]
    fn forward_layout_looks_one_way_and_orbit_surrounds() {
        let f = design_cameras(&SyntheticParams {
            layout: Layout::Forward,
            views: 9,
            ..Default::default()
        });
        let d0 = f[0].forward();
        for c in &f {
            assert!((linalg::dot(c.forward(), d0) - 1.0).abs() < 1e-12);
        }
        let o = design_cameras(&SyntheticParams::default());
        // Orbit cameras look at the target (0, 0, 0.3) from all sides.
        let mut sum = [0.0; 3];
        for c in &o {
            let to = linalg::normalize(linalg::sub([0.0, 0.0, 0.3], c.center()));
            assert!(linalg::dot(to, c.forward()) > 1.0 - 1e-12);
            sum = linalg::add(sum, c.forward());
        }
        assert!(linalg::norm([sum[0], sum[1], 0.0]) < 1e-9);
    }

    #[test]
    fn exact_depth_matches_independent_ray_sphere_geometry() {
        // The pixel-centre depth at the image centre of a camera looking at the big sphere's
        // centre equals (distance − radius) along the axis (the centre ray is the optical axis
        // up to half a pixel).
        let world = World::new(0.0);
        let s = &world.spheres[0];
        let c = [s.c[0] + 2.0, s.c[1] - 0.5, s.c[2] + 0.4];
        let w2c = look_along(c, linalg::sub(s.c, c));
        let cam = Camera {
            width: 33,
            height: 33,
            fx: 40.0,
            fy: 40.0,
            cx: 16.5,
            cy: 16.5,
            world_to_camera: w2c,
        };
        let (_, depth) = render_view(&world, &cam, 1);
        let want = linalg::norm(linalg::sub(s.c, c)) - s.r;
        assert!(
            (depth[16 * 33 + 16] as f64 - want).abs() < 1e-5,
            "{} vs {want}",
            depth[16 * 33 + 16]
        );
    }

    #[test]
    fn generated_scene_is_consistent_and_deterministic() {
        let p = small();
        let a = tempfile::tempdir().unwrap();
        let b = tempfile::tempdir().unwrap();
        let sa = rayon::ThreadPoolBuilder::new()
            .num_threads(1)
            .build()
            .unwrap()
            .install(|| generate(&p, a.path()).unwrap());
        let sb = rayon::ThreadPoolBuilder::new()
            .num_threads(2)
            .build()
            .unwrap()
            .install(|| generate(&p, b.path()).unwrap());
        assert_eq!(sa, sb);
        for f in [
            "scene.json",
            "points.safetensors",
            "images/view_003.png",
            "exact_depth/view_003.exr",
        ] {
            assert_eq!(
                std::fs::read(a.path().join(f)).unwrap(),
                std::fs::read(b.path().join(f)).unwrap(),
                "{f}"
            );
        }
        let cloud = sa.load_points(a.path()).unwrap();
        assert_eq!(cloud.len(), 200);
        // Normalised: mean camera centre at the origin, farthest camera at distance 1.
        let far = sa
            .views
            .iter()
            .map(|v| linalg::norm(v.camera.center()))
            .fold(0.0, f64::max);
        assert!((far - 1.0).abs() < 1e-9);
        // Noise-free points lie exactly at the exact depth of the pixel they project to
        // (within the depth change across a pixel), in every view of their track.
        let p0 = SyntheticParams {
            point_noise: 0.0,
            ..small()
        };
        let c = tempfile::tempdir().unwrap();
        let s0 = generate(&p0, c.path()).unwrap();
        let cl = s0.load_points(c.path()).unwrap();
        let mut close = 0;
        let mut total = 0;
        for i in 0..cl.len() {
            assert!(cl.track(i).len() >= 2);
            assert_eq!(cl.errors[i], 0.0);
            let t = cl.track(i)[0] as usize;
            let v = &s0.views[t];
            let exr = augsplat_core::image::read_exr(
                &c.path().join(format!("exact_depth/{}.exr", v.name)),
            )
            .unwrap();
            let z = exr.channel("Z").unwrap();
            let q = cl.positions[i];
            let (u, vv, d) = v.camera.project([q[0] as f64, q[1] as f64, q[2] as f64]);
            let k = vv as usize * v.camera.width as usize + u as usize;
            total += 1;
            if ((z[k] as f64 - d) / d).abs() < 0.05 {
                close += 1;
            }
        }
        assert!(close as f64 > 0.9 * total as f64, "{close}/{total}");
    }
}
