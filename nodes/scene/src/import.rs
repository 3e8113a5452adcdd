//! Turning a [`RawScene`] into the scene artifact: normalisation, undistortion, downscaling,
//! near/far bounds, and writing the folder.
//!
//! **Normalisation** ([`NormalizeMode::Cameras`], the default): the centre is the mean of the
//! camera centres and the scale puts the farthest camera at distance 1 from it, so
//! `p_norm = (p_orig − centre) · scale` (stored in [`Normalization`]). It depends on the
//! cameras only, so a scene exported and re-imported gets the same normalised cameras. (For a
//! forward-facing capture this makes the content lie far away relative to the camera spread —
//! fern's near bound becomes ≫ 1; `None` keeps the original frame.)
//!
//! **Near/far**: with sparse points, from the depths of all observations: near = 0.8 × the
//! 0.5th percentile, far = 1.2 × the 99.5th percentile; else from per-view bounds the source
//! gives (LLFF: min near, max far); else from the cameras where their optical axes converge
//! ([`crate::bounds`]); else [`DEFAULT_NEAR`] and [`DEFAULT_FAR`], with a warning on the
//! terminal. Always in normalised units.

use crate::error::{Result, SceneError};
use crate::intrinsics::{downscale_camera, downscale_image, Intrinsics, UndistortMap};
use crate::source::RawScene;
use augsplat_core::image::{read_rgb, write_png};
use augsplat_core::linalg::{self, Mat4, Vec3};
use augsplat_core::scene::{Normalization, POINTS_FILE};
use augsplat_core::{Camera, PointCloud, Scene, SceneView};
use rayon::prelude::*;
use serde::{Deserialize, Serialize};
use std::path::Path;

/// Near bound used when neither points, bounds nor the cameras give one (normalised units).
pub const DEFAULT_NEAR: f64 = 0.05;
/// Far bound used when neither points, bounds nor the cameras give one (normalised units).
pub const DEFAULT_FAR: f64 = 100.0;

/// How to normalise the scene on import.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
pub enum NormalizeMode {
    /// Centre at the mean camera centre; farthest camera at distance 1.
    #[default]
    Cameras,
    /// Keep the source frame (identity normalisation).
    None,
}

/// Options of the import beyond the source itself.
#[derive(Clone, Debug, PartialEq)]
pub struct ImportOptions {
    /// Integer downscale factor (area averaging); 1 keeps the size.
    pub downscale: u32,
    /// Undistort distorted cameras to their pinhole part (else the distortion is dropped with
    /// a warning).
    pub undistort: bool,
    /// The normalisation policy.
    pub normalize: NormalizeMode,
}

impl Default for ImportOptions {
    fn default() -> Self {
        ImportOptions {
            downscale: 1,
            undistort: true,
            normalize: NormalizeMode::Cameras,
        }
    }
}

/// The normalisation of a set of camera centres under `mode`.
pub fn normalization_for(centres: &[Vec3], mode: NormalizeMode) -> Normalization {
    if mode == NormalizeMode::None || centres.is_empty() {
        return Normalization::default();
    }
    let n = centres.len() as f64;
    let mut c = [0.0; 3];
    for p in centres {
        c = linalg::add(c, *p);
    }
    c = linalg::scale(c, 1.0 / n);
    let r = centres
        .iter()
        .map(|p| linalg::norm(linalg::sub(*p, c)))
        .fold(0.0, f64::max);
    let scale = if r > 1e-12 && r.is_finite() {
        1.0 / r
    } else {
        1.0
    };
    Normalization { center: c, scale }
}

/// World-to-camera in the normalised frame: `t_n = s (R c + t)`.
pub fn normalize_pose(w2c: &Mat4, n: &Normalization) -> Mat4 {
    let (r, t) = linalg::rt_from_mat4(w2c);
    let tn = linalg::scale(linalg::add(linalg::mat3_vec(&r, n.center), t), n.scale);
    linalg::mat4_from_rt(&r, tn)
}

/// World-to-camera back in the original frame: `t = t_n / s − R c`.
pub fn denormalize_pose(w2c: &Mat4, n: &Normalization) -> Mat4 {
    let (r, tn) = linalg::rt_from_mat4(w2c);
    let t = linalg::sub(
        linalg::scale(tn, 1.0 / n.scale),
        linalg::mat3_vec(&r, n.center),
    );
    linalg::mat4_from_rt(&r, t)
}

/// The scene description, cameras and points of a raw scene, without touching images.
pub fn build_scene(raw: &RawScene, opts: &ImportOptions) -> Result<(Scene, PointCloud)> {
    if raw.views.is_empty() {
        return Err(SceneError::Invalid(format!(
            "no views left in {}",
            raw.source
        )));
    }
    if opts.downscale == 0 {
        return Err(SceneError::Invalid("downscale must be at least 1".into()));
    }
    let centres: Vec<Vec3> = raw
        .views
        .iter()
        .map(|v| camera_centre(&v.world_to_camera))
        .collect();
    let norm = normalization_for(&centres, opts.normalize);
    let mut views = Vec::with_capacity(raw.views.len());
    for v in &raw.views {
        let cam = v
            .intrinsics
            .pinhole_camera(normalize_pose(&v.world_to_camera, &norm));
        let cam = downscale_camera(&cam, opts.downscale);
        if cam.width == 0 || cam.height == 0 {
            return Err(SceneError::Invalid(format!(
                "view {}: image {}×{} is smaller than the downscale factor {}",
                v.name, v.intrinsics.width, v.intrinsics.height, opts.downscale
            )));
        }
        cam.validate()
            .map_err(|e| SceneError::format(&v.image_path, format!("view {}: {e}", v.name)))?;
        views.push(SceneView {
            name: v.name.clone(),
            image: format!("images/{}.png", v.name),
            depth: None,
            camera: cam,
        });
    }
    // Points.
    let p = &raw.points;
    let mut cloud = PointCloud::default();
    cloud.track_offsets.push(0);
    let mut depths = Vec::new();
    for i in 0..p.positions.len() {
        let mut track: Vec<u32> = p.tracks[i].iter().map(|o| o.view as u32).collect();
        track.sort_unstable();
        track.dedup();
        let pn = norm.apply(p.positions[i]);
        for &t in &track {
            let z = views[t as usize].camera.to_camera(pn)[2];
            if z > 0.0 {
                depths.push(z);
            }
        }
        cloud.positions.push(pn.map(|x| x as f32));
        cloud.colors.push(p.colors[i]);
        cloud.errors.push(p.errors[i] as f32);
        cloud.track_views.extend_from_slice(&track);
        cloud.track_offsets.push(cloud.track_views.len() as u32);
    }
    let (near, far) = if let Some(range) = crate::bounds::depth_range(&mut depths) {
        range
    } else if raw.views.iter().all(|v| v.bounds.is_some()) {
        let near = raw
            .views
            .iter()
            .filter_map(|v| v.bounds.map(|b| b.0))
            .fold(f64::INFINITY, f64::min);
        let far = raw
            .views
            .iter()
            .filter_map(|v| v.bounds.map(|b| b.1))
            .fold(0.0, f64::max);
        (near * norm.scale, far * norm.scale)
    } else {
        let cams: Vec<Camera> = views.iter().map(|v| v.camera.clone()).collect();
        match crate::bounds::from_cameras(&cams) {
            Ok(b) => (b.near, b.far),
            Err(_) => (DEFAULT_NEAR, DEFAULT_FAR),
        }
    };
    let has_points = !cloud.is_empty();
    Ok((
        Scene {
            source: raw.source.clone(),
            views,
            near,
            far,
            normalization: norm,
            has_points,
        },
        cloud,
    ))
}

/// The camera centre of a world-to-camera transform.
pub fn camera_centre(w2c: &Mat4) -> Vec3 {
    let (r, t) = linalg::rt_from_mat4(w2c);
    linalg::scale(linalg::mat3_vec(&linalg::transpose3(&r), t), -1.0)
}

/// Imports a raw scene into folder `out`: builds the description, then reads, checks,
/// undistorts, downscales and writes every image (views in parallel; the first error in view
/// order is returned, so errors are deterministic too). `log` receives warnings.
pub fn import_scene(
    raw: &RawScene,
    opts: &ImportOptions,
    out: &Path,
    log: &(dyn Fn(&str) + Sync),
) -> Result<Scene> {
    for w in &raw.warnings {
        log(&format!("warning: {w}"));
    }
    let (scene, cloud) = build_scene(raw, opts)?;
    if cloud.is_empty() && !raw.views.iter().all(|v| v.bounds.is_some()) {
        let cams: Vec<Camera> = scene.views.iter().map(|v| v.camera.clone()).collect();
        match crate::bounds::from_cameras(&cams) {
            Ok(b) => log(&format!(
                "no sparse points or per-view bounds: near/far {:.3}–{:.3} from the cameras \
                 (their optical axes converge at ({:.3}, {:.3}, {:.3}), depth {:.3}–{:.3}; \
                 the views share a ball of radius {:.3} around it)",
                b.near,
                b.far,
                b.focus[0],
                b.focus[1],
                b.focus[2],
                b.focus_depths.0,
                b.focus_depths.1,
                b.radius
            )),
            Err(why) => {
                let msg = format!(
                    "warning: ImportScene: {} has no sparse points and no per-view bounds, and \
                     the cameras do not determine any: {why}. Using the defaults {DEFAULT_NEAR}–{DEFAULT_FAR}: \
                     random Gaussians and field samples will mostly miss the scene. Give \
                     bounds (LLFF poses_bounds.npy) or a model with points",
                    raw.source
                );
                // On the terminal as well as in the log: the results will be poor.
                eprintln!("{msg}");
                log(&msg);
            }
        }
    }
    let images = out.join("images");
    std::fs::create_dir_all(&images).map_err(|e| SceneError::io(&images, e))?;
    // One undistortion map per distinct distorted intrinsics.
    let mut maps: Vec<(Intrinsics, UndistortMap)> = Vec::new();
    let mut dropped = false;
    for v in &raw.views {
        if v.intrinsics.is_distorted() {
            if opts.undistort {
                if !maps.iter().any(|(i, _)| *i == v.intrinsics) {
                    maps.push((v.intrinsics, UndistortMap::new(&v.intrinsics)));
                }
            } else {
                dropped = true;
            }
        }
    }
    if dropped {
        log("warning: undistort is off: lens distortion is ignored and the images are used as if pinhole");
    }
    let results: Vec<Result<()>> = raw
        .views
        .par_iter()
        .zip(&scene.views)
        .map(|(v, sv)| {
            let img = read_rgb(&v.image_path)?;
            let intr = &v.intrinsics;
            if (img.width, img.height) != (intr.width, intr.height) {
                return Err(SceneError::format(
                    &v.image_path,
                    format!(
                        "image is {}×{} but its camera (view {}) says {}×{}",
                        img.width, img.height, v.name, intr.width, intr.height
                    ),
                ));
            }
            let img = match maps.iter().find(|(i, _)| i == intr) {
                Some((_, map)) => map.apply(&img, &v.image_path)?,
                None => img,
            };
            let img = downscale_image(&img, opts.downscale);
            write_png(&out.join(&sv.image), &img)?;
            Ok(())
        })
        .collect();
    for r in results {
        r?;
    }
    if scene.has_points {
        cloud.save(&out.join(POINTS_FILE))?;
    }
    scene.save(out)?;
    Ok(scene)
}

/// Writes a scene description, its point cloud and the given images into `out` (used by the
/// split and depth nodes): copies each view's image from `src_dir`.
pub fn copy_scene(scene: &Scene, cloud: &PointCloud, src_dir: &Path, out: &Path) -> Result<()> {
    let images = out.join("images");
    std::fs::create_dir_all(&images).map_err(|e| SceneError::io(&images, e))?;
    for v in &scene.views {
        let from = src_dir.join(&v.image);
        let to = out.join(&v.image);
        if let Some(parent) = to.parent() {
            std::fs::create_dir_all(parent).map_err(|e| SceneError::io(parent, e))?;
        }
        std::fs::copy(&from, &to).map_err(|e| SceneError::io(&from, e))?;
    }
    let mut scene = scene.clone();
    scene.has_points = !cloud.is_empty();
    if scene.has_points {
        cloud.save(&out.join(POINTS_FILE))?;
    }
    scene.save(out)?;
    Ok(())
}

/// Checks a loaded scene for consistency (finite cameras, track indices in range).
pub fn check_scene(scene: &Scene, cloud: &PointCloud, dir: &Path) -> Result<()> {
    let file = dir.join(augsplat_core::scene::SCENE_FILE);
    if scene.views.is_empty() {
        return Err(SceneError::format(&file, "the scene has no views"));
    }
    for v in &scene.views {
        v.camera
            .validate()
            .map_err(|e| SceneError::format(&file, format!("view {}: {e}", v.name)))?;
    }
    if let Some(bad) = cloud
        .track_views
        .iter()
        .find(|&&t| t as usize >= scene.views.len())
    {
        return Err(SceneError::format(
            dir.join(POINTS_FILE),
            format!(
                "a track names view {bad}, but the scene has {} views",
                scene.views.len()
            ),
        ));
    }
    Ok(())
}

/// A camera in the original frame (for export): pose denormalised, intrinsics unchanged.
pub fn original_camera(cam: &Camera, n: &Normalization) -> Camera {
    Camera {
        world_to_camera: denormalize_pose(&cam.world_to_camera, n),
        ..cam.clone()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn normalisation_of_poses_matches_points() {
        let n = Normalization {
            center: [1.0, -2.0, 0.5],
            scale: 0.3,
        };
        let w2c = linalg::mat4_from_rt(&linalg::axis_angle([0.2, 1.0, -0.4], 1.1), [0.5, 0.2, 3.0]);
        let wn = normalize_pose(&w2c, &n);
        let p = [0.3, 0.7, -1.2];
        let a = crate::colmap::transform(&w2c, p);
        let b = crate::colmap::transform(&wn, n.apply(p));
        for k in 0..3 {
            assert!((a[k] * n.scale - b[k]).abs() < 1e-12);
        }
        let back = denormalize_pose(&wn, &n);
        for i in 0..4 {
            for j in 0..4 {
                assert!((back[i][j] - w2c[i][j]).abs() < 1e-12);
            }
        }
        let c = normalization_for(
            &[[1.0, 0.0, 0.0], [3.0, 0.0, 0.0], [2.0, 2.0, 0.0]],
            NormalizeMode::Cameras,
        );
        assert!((c.center[0] - 2.0).abs() < 1e-12 && (c.center[1] - 2.0 / 3.0).abs() < 1e-12);
        assert!((c.scale - 1.0 / (4.0f64 / 3.0)).abs() < 1e-12);
    }
}
