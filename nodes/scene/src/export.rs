//! Export of a scene artifact to COLMAP (text or binary) and to transforms.json, in the scene's original
//! frame (the import normalisation is inverted), so results go back into other tools.
//!
//! - COLMAP text or binary: `sparse/0/{cameras,images,points3D}.{txt,bin}` plus `images/<name>.png`. One
//!   `PINHOLE` camera per distinct intrinsics; image ids follow the view order (1-based); each
//!   point's keypoints are its exact projections into the views of its track (the scene
//!   stores no keypoints), so their reprojection error is 0 by construction while the point's
//!   stored `ERROR` field keeps the value the scene had.
//! - transforms.json: camera-to-world in OpenGL axes, per-frame `fl_x fl_y cx cy w h`,
//!   `file_path` = `images/<name>.png`, plus `images/`, and the points (when the scene has
//!   any) as nerfstudio keeps them: `sparse_pc.ply` named by `ply_file_path`.

use crate::colmap::{ColmapCamera, ColmapImage, ColmapModel, ColmapPoint};
use crate::error::{Result, SceneError};
use crate::import::original_camera;
use crate::intrinsics::{Distortion, Intrinsics, ModelKind};
use augsplat_core::linalg;
use augsplat_core::{PointCloud, Scene};
use serde::{Deserialize, Serialize};
use std::path::Path;

/// The points' file of a transforms.json export (nerfstudio's name).
pub const SPARSE_PLY: &str = "sparse_pc.ply";

/// Export formats.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
pub enum ExportFormat {
    /// COLMAP text model plus images.
    #[default]
    ColmapText,
    /// COLMAP binary model plus images.
    ColmapBinary,
    /// nerfstudio / instant-ngp transforms.json plus images.
    Transforms,
}

fn copy_images(scene: &Scene, src: &Path, out: &Path) -> Result<Vec<String>> {
    let dir = out.join("images");
    std::fs::create_dir_all(&dir).map_err(|e| SceneError::io(&dir, e))?;
    let mut names = Vec::with_capacity(scene.views.len());
    for v in &scene.views {
        let from = src.join(&v.image);
        let ext = Path::new(&v.image)
            .extension()
            .and_then(|e| e.to_str())
            .unwrap_or("png");
        let file = format!("{}.{ext}", v.name);
        std::fs::copy(&from, dir.join(&file)).map_err(|e| SceneError::io(&from, e))?;
        names.push(file);
    }
    Ok(names)
}

/// The scene as a COLMAP model in the original frame (image names as given).
pub fn to_colmap(scene: &Scene, cloud: &PointCloud, image_names: &[String]) -> ColmapModel {
    let n = &scene.normalization;
    let mut model = ColmapModel::default();
    let mut cam_ids = Vec::with_capacity(scene.views.len());
    for v in &scene.views {
        let c = &v.camera;
        let intr = Intrinsics {
            kind: ModelKind::Pinhole,
            width: c.width,
            height: c.height,
            fx: c.fx,
            fy: c.fy,
            cx: c.cx,
            cy: c.cy,
            distortion: Distortion::default(),
        };
        let id = match model.cameras.values().find(|k| k.intrinsics == intr) {
            Some(k) => k.id,
            None => {
                let id = model.cameras.len() as u32 + 1;
                model.cameras.insert(
                    id,
                    ColmapCamera {
                        id,
                        intrinsics: intr,
                    },
                );
                id
            }
        };
        cam_ids.push(id);
    }
    let originals: Vec<_> = scene
        .views
        .iter()
        .map(|v| original_camera(&v.camera, n))
        .collect();
    for (k, cam) in originals.iter().enumerate() {
        let (r, t) = linalg::rt_from_mat4(&cam.world_to_camera);
        let id = k as u32 + 1;
        model.images.insert(
            id,
            ColmapImage {
                id,
                qvec: linalg::mat3_to_quat(&r),
                tvec: t,
                camera_id: cam_ids[k],
                name: image_names[k].clone(),
                points2d: Vec::new(),
            },
        );
    }
    for i in 0..cloud.len() {
        let q = cloud.positions[i];
        let p = n.invert([q[0] as f64, q[1] as f64, q[2] as f64]);
        let pid = i as u64 + 1;
        let mut track = Vec::new();
        for &t in cloud.track(i) {
            let cam = &originals[t as usize];
            let (u, v, z) = cam.project(p);
            if z.is_nan() || z <= 0.0 {
                continue;
            }
            let img = model.images.get_mut(&(t + 1)).expect("image of every view");
            track.push((t + 1, img.points2d.len() as u32));
            img.points2d.push(([u, v], pid as i64));
        }
        let c = cloud.colors[i];
        model.points.push(ColmapPoint {
            id: pid,
            xyz: p,
            rgb: c.map(augsplat_core::image::to_u8),
            error: cloud.errors[i] as f64,
            track,
        });
    }
    model
}

/// Exports the scene in folder `src` to `out` in `format`.
pub fn export_scene(src: &Path, out: &Path, format: ExportFormat) -> Result<()> {
    let scene = Scene::load(src)?;
    let cloud = scene.load_points(src)?;
    crate::import::check_scene(&scene, &cloud, src)?;
    let names = copy_images(&scene, src, out)?;
    match format {
        ExportFormat::ColmapText | ExportFormat::ColmapBinary => {
            let dir = out.join("sparse").join("0");
            std::fs::create_dir_all(&dir).map_err(|e| SceneError::io(&dir, e))?;
            let model = to_colmap(&scene, &cloud, &names);
            if format == ExportFormat::ColmapText {
                model.save_text(&dir)
            } else {
                model.save_binary(&dir)
            }
        }
        ExportFormat::Transforms => {
            let n = &scene.normalization;
            let frames: Vec<serde_json::Value> = scene
                .views
                .iter()
                .zip(&names)
                .map(|(v, file)| {
                    let cam = original_camera(&v.camera, n);
                    let mut c2w = linalg::rigid_inverse(&cam.world_to_camera);
                    // OpenCV camera axes → OpenGL (flip y and z).
                    for row in c2w.iter_mut().take(3) {
                        row[1] = -row[1];
                        row[2] = -row[2];
                    }
                    serde_json::json!({
                        "file_path": format!("images/{file}"),
                        "transform_matrix": c2w,
                        "fl_x": cam.fx, "fl_y": cam.fy, "cx": cam.cx, "cy": cam.cy,
                        "w": cam.width, "h": cam.height,
                    })
                })
                .collect();
            let mut json = serde_json::json!({
                "camera_model": "OPENCV",
                "frames": frames,
            });
            if !cloud.is_empty() {
                // The points as nerfstudio keeps them: a PLY in the transforms' frame.
                let positions: Vec<[f64; 3]> = cloud
                    .positions
                    .iter()
                    .map(|q| n.invert(q.map(f64::from)))
                    .collect();
                let ply = out.join(SPARSE_PLY);
                crate::ply_points::write_points_ply(&ply, &positions, &cloud.colors)?;
                json["ply_file_path"] = serde_json::json!(SPARSE_PLY);
            }
            let path = out.join("transforms.json");
            let text = serde_json::to_string_pretty(&json).expect("JSON values serialise");
            std::fs::write(&path, text).map_err(|e| SceneError::io(&path, e))
        }
    }
}
