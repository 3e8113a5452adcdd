//! Per-view depth for depth supervision.
//!
//! **Sparse (DS-NeRF style)**: each point whose track has at least `min_track` views is
//! projected into every view of its track; the pixel it falls in gets Z = its depth along the
//! optical axis (the nearest point wins when several fall in one pixel) and W = exp(−(e/σ)²),
//! where e is the point's mean reprojection error and σ is `sigma_px` or, by default, the
//! mean error over the points used (DS-NeRF's weighting, without its factor 2 so W ∈ [0, 1]).
//! Points with unknown error (0) get W = 1. Every other pixel is Z = W = 0.
//!
//! **Dense**: a folder of per-view maps named `<view name>.exr` (a channel `Z`, `Y`, `R` or
//! `depth`, in source units) or `<view name>.png` (16-bit grey; depth = raw value ×
//! `png_scale`, source units). Depth is converted to normalised units by the scene's
//! normalisation scale; maps must have the view's size or an integer multiple of it (sampled
//! at pixel centres). W = `dense_weight` where Z > 0.

use crate::error::{Result, SceneError};
use augsplat_core::{PointCloud, Scene};
use std::path::Path;

/// A depth plane and its weight plane, row-major, view size.
#[derive(Clone, Debug, PartialEq)]
pub struct DepthMap {
    /// Depth along the optical axis (0 = unknown).
    pub z: Vec<f32>,
    /// Confidence in [0, 1] (0 = unknown).
    pub w: Vec<f32>,
}

/// The σ used for the weights: `sigma_px` or the mean error of the points whose track has at
/// least `min_track` views (1 when that mean is not positive).
pub fn weight_sigma(cloud: &PointCloud, min_track: usize, sigma_px: Option<f64>) -> f64 {
    if let Some(s) = sigma_px {
        return s;
    }
    let (mut s, mut n) = (0.0, 0usize);
    for i in 0..cloud.len() {
        if cloud.track(i).len() >= min_track {
            s += cloud.errors[i] as f64;
            n += 1;
        }
    }
    if n > 0 && s > 0.0 {
        s / n as f64
    } else {
        1.0
    }
}

/// Sparse depth of view `view` of `scene` from `cloud` (see the module docs).
pub fn sparse_depth(
    scene: &Scene,
    cloud: &PointCloud,
    view: usize,
    min_track: usize,
    sigma: f64,
) -> DepthMap {
    let cam = &scene.views[view].camera;
    let (w, h) = (cam.width as usize, cam.height as usize);
    let mut z = vec![0f32; w * h];
    let mut wt = vec![0f32; w * h];
    for i in 0..cloud.len() {
        let track = cloud.track(i);
        if track.len() < min_track || !track.contains(&(view as u32)) {
            continue;
        }
        let p = cloud.positions[i];
        let (u, v, d) = cam.project([p[0] as f64, p[1] as f64, p[2] as f64]);
        // NaN fails every comparison, so it is skipped too.
        let inside = d > 0.0 && u >= 0.0 && v >= 0.0 && u < w as f64 && v < h as f64;
        if !inside {
            continue;
        }
        let k = v as usize * w + u as usize;
        let d = d as f32;
        if z[k] == 0.0 || d < z[k] {
            z[k] = d;
            let e = cloud.errors[i] as f64;
            wt[k] = if e > 0.0 {
                (-(e / sigma).powi(2)).exp() as f32
            } else {
                1.0
            };
        }
    }
    DepthMap { z, w: wt }
}

/// Reads a dense depth map for view `view` from `dir`, if one exists (see the module docs).
pub fn dense_depth(
    scene: &Scene,
    view: usize,
    dir: &Path,
    png_scale: f64,
    weight: f32,
) -> Result<Option<DepthMap>> {
    let v = &scene.views[view];
    let exr = dir.join(format!("{}.exr", v.name));
    let png = dir.join(format!("{}.png", v.name));
    let (mw, mh, values, path) = if exr.is_file() {
        let img = augsplat_core::image::read_exr(&exr)?;
        let ch = ["Z", "Y", "R", "depth"]
            .iter()
            .find_map(|n| img.channel(n))
            .ok_or_else(|| {
                SceneError::format(
                    &exr,
                    format!("no depth channel Z, Y, R or depth (has {:?})", img.names()),
                )
            })?;
        (
            img.width,
            img.height,
            ch.iter().map(|&x| x as f64).collect::<Vec<_>>(),
            exr,
        )
    } else if png.is_file() {
        let dynimg = image::open(&png)
            .map_err(|e| SceneError::format(&png, format!("not a readable image: {e}")))?;
        if !matches!(dynimg, image::DynamicImage::ImageLuma16(_)) {
            return Err(SceneError::format(
                &png,
                "a depth PNG must be 16-bit greyscale",
            ));
        }
        let g = dynimg.to_luma16();
        let (w, h) = g.dimensions();
        (
            w,
            h,
            g.into_raw()
                .into_iter()
                .map(|x| x as f64 * png_scale)
                .collect(),
            png,
        )
    } else {
        return Ok(None);
    };
    let (w, h) = (v.camera.width, v.camera.height);
    if mw % w != 0 || mh % h != 0 || mw / w != mh / h {
        return Err(SceneError::format(
            &path,
            format!("depth map is {mw}×{mh}, but view {} is {w}×{h} (need the same size or an integer multiple)", v.name),
        ));
    }
    let f = (mw / w) as usize;
    let s = scene.normalization.scale;
    let mut z = vec![0f32; (w * h) as usize];
    let mut wt = vec![0f32; (w * h) as usize];
    for i in 0..h as usize {
        for j in 0..w as usize {
            let src = (i * f + f / 2) * mw as usize + j * f + f / 2;
            let d = values[src];
            if d.is_finite() && d > 0.0 {
                z[i * w as usize + j] = (d * s) as f32;
                wt[i * w as usize + j] = weight;
            }
        }
    }
    Ok(Some(DepthMap { z, w: wt }))
}

#[cfg(test)]
mod tests {
    use super::*;
    use augsplat_core::linalg::{mat4_from_rt, IDENTITY3};
    use augsplat_core::{Camera, SceneView};

    fn scene() -> Scene {
        let cam = Camera {
            width: 8,
            height: 6,
            fx: 8.0,
            fy: 8.0,
            cx: 4.0,
            cy: 3.0,
            world_to_camera: mat4_from_rt(&IDENTITY3, [0.0; 3]),
        };
        Scene {
            source: "t".into(),
            views: vec![SceneView {
                name: "a".into(),
                image: "images/a.png".into(),
                depth: None,
                camera: cam,
            }],
            near: 0.1,
            far: 10.0,
            normalization: Default::default(),
            has_points: true,
        }
    }

    #[test]
    fn nearest_point_wins_and_weights_follow_errors() {
        let s = scene();
        let cloud = PointCloud {
            // Two points in pixel (row 3, col 4), depths 2 and 1; one point with a short track.
            positions: vec![
                [0.1, 0.1, 2.0],
                [0.05, 0.05, 1.0],
                [0.0, 0.0, 3.0],
                [-0.9, -0.7, 2.0],
            ],
            colors: vec![[0.0; 3]; 4],
            errors: vec![0.5, 1.0, 0.0, 0.5],
            track_offsets: vec![0, 2, 4, 5, 7],
            track_views: vec![0, 1, 0, 1, 0, 0, 1],
        };
        let sigma = weight_sigma(&cloud, 2, None);
        assert!((sigma - (0.5 + 1.0 + 0.5) / 3.0).abs() < 1e-6);
        let d = sparse_depth(&s, &cloud, 0, 2, sigma);
        let k = 3 * 8 + 4;
        assert_eq!(d.z[k], 1.0);
        let want = (-(1.0f64 / sigma).powi(2)).exp() as f32;
        assert!((d.w[k] - want).abs() < 1e-6);
        // Point 3 projects to u = 8·(−0.45)+4 = 0.4, v = 8·(−0.35)+3 = 0.2 → pixel (0, 0).
        assert_eq!(d.z[0], 2.0);
        // The single-view point (track 1) is ignored with min_track 2.
        assert_eq!(d.z.iter().filter(|&&z| z > 0.0).count(), 2);
        assert_eq!(d.w.iter().filter(|&&w| w > 0.0).count(), 2);
    }

    #[test]
    fn dense_exr_is_scaled_and_sized() {
        let mut s = scene();
        s.normalization.scale = 0.5;
        let dir = tempfile::tempdir().unwrap();
        let z: Vec<f32> = (0..16 * 12).map(|i| 1.0 + i as f32).collect();
        augsplat_core::image::write_exr(&dir.path().join("a.exr"), 16, 12, &[("Z", &z)]).unwrap();
        let d = dense_depth(&s, 0, dir.path(), 0.001, 1.0).unwrap().unwrap();
        // Output pixel (0,0) samples source (1,1) = 1 + 17 = 18, scaled by 0.5.
        assert_eq!(d.z[0], 9.0);
        augsplat_core::image::write_exr(&dir.path().join("a.exr"), 5, 5, &[("Z", &[1.0; 25])])
            .unwrap();
        let e = dense_depth(&s, 0, dir.path(), 0.001, 1.0)
            .unwrap_err()
            .to_string();
        assert!(e.contains("a.exr"), "{e}");
        assert!(dense_depth(&s, 0, &dir.path().join("none"), 0.001, 1.0)
            .unwrap()
            .is_none());
        // A 16-bit PNG: raw value × png_scale, then the normalisation scale; 0 stays unknown.
        std::fs::remove_file(dir.path().join("a.exr")).unwrap();
        let raw: Vec<u16> = (0..8 * 6)
            .map(|i| if i == 5 { 0 } else { 1000 + i as u16 })
            .collect();
        image::ImageBuffer::<image::Luma<u16>, _>::from_raw(8, 6, raw)
            .unwrap()
            .save(dir.path().join("a.png"))
            .unwrap();
        let d = dense_depth(&s, 0, dir.path(), 0.001, 0.5).unwrap().unwrap();
        assert!((d.z[7] - 1.007 * 0.5).abs() < 1e-6 && d.w[7] == 0.5);
        assert_eq!((d.z[5], d.w[5]), (0.0, 0.0));
        // An 8-bit PNG is refused (its scale would be ambiguous).
        image::GrayImage::new(8, 6)
            .save(dir.path().join("a.png"))
            .unwrap();
        let e = dense_depth(&s, 0, dir.path(), 0.001, 1.0)
            .unwrap_err()
            .to_string();
        assert!(e.contains("16-bit"), "{e}");
    }
}
