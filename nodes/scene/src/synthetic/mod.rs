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
use augsplat_core::linalg::{self, Vec3};
use augsplat_core::scene::POINTS_FILE;
use augsplat_core::{Camera, ImageF32, PointCloud, Rng, Scene, SceneView};
use rayon::prelude::*;
use serde::{Deserialize, Serialize};
use std::path::Path;
use world::World;

#[cfg(test)]
mod tests;
mod world;

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

/// Relative distance of `p` from the ray-traced surface a view sees: `|z − Z| / Z` for the
/// point's depth `z` and the exact depth `Z` (`exact_depth/<name>.exr`, channel `Z`) at its
/// pixel or one of the 8 around it, whichever is nearest (a point on a silhouette may round
/// to the pixel across the edge); `None` outside the image.
pub fn surface_error(depth: &[f32], cam: &Camera, p: Vec3) -> Option<f64> {
    let (u, v, z) = cam.project(p);
    let (x, y) = (u.floor() as i64, v.floor() as i64);
    let (w, h) = (cam.width as i64, cam.height as i64);
    if z.is_nan() || z <= 0.0 || x < 0 || y < 0 || x >= w || y >= h {
        return None;
    }
    let mut best = f64::INFINITY;
    for (px, py) in (-1..=1).flat_map(|dx| (-1..=1).map(move |dy| (x + dx, y + dy))) {
        if px >= 0 && py >= 0 && px < w && py < h {
            let exact = depth[(py * w + px) as usize] as f64;
            best = best.min((z - exact).abs() / exact);
        }
    }
    Some(best)
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
