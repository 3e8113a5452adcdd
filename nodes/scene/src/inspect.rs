//! What `augsplat inspect PATH` reports about a scene on disk, in any supported format.
//!
//! PATH may be an augsplat scene folder (`scene.json`), a COLMAP model folder (cameras.bin or
//! cameras.txt) or a folder holding one in `sparse/0`, `sparse`, `sparse_txt` or
//! `colmap/sparse/0`, a transforms.json file or a folder holding one, or an LLFF folder
//! (`poses_bounds.npy`). Models are described as stored (no normalisation, no images read
//! except for their sizes where a format needs them).

use crate::colmap::{is_model_dir, ColmapModel};
use crate::error::{Result, SceneError};
use crate::import::camera_centre;
use crate::source::{list_images, load_transforms};
use augsplat_core::linalg::Vec3;
use augsplat_core::Scene;
use serde::Serialize;
use std::path::Path;

/// One group of intrinsics and how many images use it.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct IntrinsicsInfo {
    /// Camera model (COLMAP name, or PINHOLE).
    pub model: String,
    /// Image width, pixels.
    pub width: u32,
    /// Image height, pixels.
    pub height: u32,
    /// Focal length x.
    pub fx: f64,
    /// Focal length y.
    pub fy: f64,
    /// Principal point x.
    pub cx: f64,
    /// Principal point y.
    pub cy: f64,
    /// Distortion (k1, k2, k3, k4, p1, p2).
    pub distortion: [f64; 6],
    /// Number of images with these intrinsics.
    pub images: usize,
}

/// An axis-aligned box.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct Aabb {
    /// Minimum corner.
    pub min: Vec3,
    /// Maximum corner.
    pub max: Vec3,
}

impl Aabb {
    fn of(points: impl Iterator<Item = Vec3>) -> Option<Aabb> {
        let mut b: Option<Aabb> = None;
        for p in points {
            let bb = b.get_or_insert(Aabb { min: p, max: p });
            for (k, &x) in p.iter().enumerate() {
                bb.min[k] = bb.min[k].min(x);
                bb.max[k] = bb.max[k].max(x);
            }
        }
        b
    }
}

/// The inspection report.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct Report {
    /// The path inspected.
    pub path: String,
    /// The format found, in words.
    pub format: String,
    /// Number of distinct cameras (intrinsics groups).
    pub cameras: usize,
    /// Number of registered images / views / frames.
    pub registered_images: usize,
    /// Intrinsics groups.
    pub intrinsics: Vec<IntrinsicsInfo>,
    /// Number of sparse points.
    pub points: usize,
    /// Number of point observations (track entries).
    pub observations: usize,
    /// Mean reprojection error, pixels (COLMAP's definition), when computable.
    pub mean_reprojection_error: Option<f64>,
    /// How the error was obtained ("recomputed from keypoints" or "mean of stored per-point
    /// errors").
    pub reprojection_error_source: Option<String>,
    /// Bounds of the camera centres.
    pub camera_bounds: Option<Aabb>,
    /// Bounds of the points.
    pub point_bounds: Option<Aabb>,
    /// Near and far bounds, when the format has them.
    pub near_far: Option<(f64, f64)>,
    /// Anything notable (skipped frames, unregistered photos).
    pub notes: Vec<String>,
}

fn group_intrinsics(
    list: impl Iterator<Item = crate::intrinsics::Intrinsics>,
) -> Vec<IntrinsicsInfo> {
    let mut groups: Vec<IntrinsicsInfo> = Vec::new();
    for i in list {
        let d = i.distortion;
        let info = IntrinsicsInfo {
            model: i.kind.colmap_name().to_string(),
            width: i.width,
            height: i.height,
            fx: i.fx,
            fy: i.fy,
            cx: i.cx,
            cy: i.cy,
            distortion: [d.k1, d.k2, d.k3, d.k4, d.p1, d.p2],
            images: 1,
        };
        match groups.iter_mut().find(|g| {
            IntrinsicsInfo {
                images: g.images,
                ..info.clone()
            } == **g
        }) {
            Some(g) => g.images += 1,
            None => groups.push(info),
        }
    }
    groups
}

/// Inspects `path` (see the module docs).
pub fn inspect(path: &Path) -> Result<Report> {
    if !path.exists() {
        return Err(SceneError::missing(path, "path"));
    }
    if path.is_file() {
        if path.extension().is_some_and(|e| e == "json") {
            return inspect_transforms(path);
        }
        return Err(SceneError::format(
            path,
            "not a scene: expected a folder (scene, COLMAP, LLFF) or a transforms JSON file",
        ));
    }
    if path.join(augsplat_core::scene::SCENE_FILE).is_file() {
        return inspect_scene(path);
    }
    if path.join("transforms.json").is_file() {
        return inspect_transforms(&path.join("transforms.json"));
    }
    if path.join("poses_bounds.npy").is_file() {
        return inspect_llff(path);
    }
    for c in [".", "sparse/0", "sparse", "sparse_txt", "colmap/sparse/0"] {
        let d = if c == "." {
            path.to_path_buf()
        } else {
            path.join(c)
        };
        if is_model_dir(&d) {
            return inspect_colmap(&d, path);
        }
    }
    Err(SceneError::format(
        path,
        "no supported scene here: no scene.json, transforms.json, poses_bounds.npy or COLMAP model",
    ))
}

fn inspect_colmap(dir: &Path, root: &Path) -> Result<Report> {
    let model = ColmapModel::load(dir)?;
    let binary = dir.join("cameras.bin").is_file();
    let err = model.mean_reprojection_error();
    let mut notes = Vec::new();
    let images_dir = root.join("images");
    if images_dir.is_dir() {
        let missing = model
            .images
            .values()
            .filter(|i| !images_dir.join(&i.name).is_file())
            .count();
        if missing > 0 {
            notes.push(format!(
                "{missing} registered images are missing from {}",
                images_dir.display()
            ));
        }
    }
    if err.is_none() && !model.points.is_empty() {
        notes.push("the model stores no keypoints: reprojection error not computable".into());
    }
    Ok(Report {
        path: dir.display().to_string(),
        format: format!("COLMAP {}", if binary { "binary" } else { "text" }),
        cameras: model.cameras.len(),
        registered_images: model.images.len(),
        intrinsics: group_intrinsics(
            model
                .images
                .values()
                .map(|i| model.cameras[&i.camera_id].intrinsics),
        ),
        points: model.points.len(),
        observations: model.points.iter().map(|p| p.track.len()).sum(),
        mean_reprojection_error: err.map(|e| e.0),
        reprojection_error_source: err.map(|_| "recomputed from keypoints".to_string()),
        camera_bounds: Aabb::of(
            model
                .images
                .values()
                .map(|i| camera_centre(&i.world_to_camera())),
        ),
        point_bounds: Aabb::of(model.points.iter().map(|p| p.xyz)),
        near_far: None,
        notes,
    })
}

fn inspect_transforms(file: &Path) -> Result<Report> {
    let raw = load_transforms(file)?;
    Ok(Report {
        path: file.display().to_string(),
        format: "transforms.json".into(),
        cameras: group_intrinsics(raw.views.iter().map(|v| v.intrinsics)).len(),
        registered_images: raw.views.len(),
        intrinsics: group_intrinsics(raw.views.iter().map(|v| v.intrinsics)),
        points: 0,
        observations: 0,
        mean_reprojection_error: None,
        reprojection_error_source: None,
        camera_bounds: Aabb::of(raw.views.iter().map(|v| camera_centre(&v.world_to_camera))),
        point_bounds: None,
        near_far: None,
        notes: raw.warnings,
    })
}

fn inspect_llff(dir: &Path) -> Result<Report> {
    // Use the most downscaled images_N folder whose image count matches the poses (as the
    // importer does when its `images_<llff_factor>` is absent).
    let npy = dir.join("poses_bounds.npy");
    let (shape, _) = augsplat_core::image::read_npy_array(&npy)?;
    let rows = shape.first().copied().unwrap_or(0);
    let folders = crate::source::llff_image_folders(dir)?;
    let mut notes = Vec::new();
    for (f, p) in &folders {
        notes.push(format!(
            "images folder {} (factor {f}): {} images",
            p.display(),
            list_images(p).map(|v| v.len()).unwrap_or(0)
        ));
    }
    let chosen = folders
        .iter()
        .rev()
        .find(|(_, p)| list_images(p).is_ok_and(|v| v.len() == rows))
        .ok_or_else(|| {
            SceneError::format(
                dir,
                format!("no images folder (images, images_N) holds the {rows} images poses_bounds.npy describes"),
            )
        })?;
    let raw = crate::source::load_llff(dir, &chosen.1)?;
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
    notes.push(format!("intrinsics shown for {}", chosen.1.display()));
    Ok(Report {
        path: dir.display().to_string(),
        format: "LLFF".into(),
        cameras: group_intrinsics(raw.views.iter().map(|v| v.intrinsics)).len(),
        registered_images: raw.views.len(),
        intrinsics: group_intrinsics(raw.views.iter().map(|v| v.intrinsics)),
        points: 0,
        observations: 0,
        mean_reprojection_error: None,
        reprojection_error_source: None,
        camera_bounds: Aabb::of(raw.views.iter().map(|v| camera_centre(&v.world_to_camera))),
        point_bounds: None,
        near_far: Some((near, far)),
        notes,
    })
}

fn inspect_scene(dir: &Path) -> Result<Report> {
    let scene = Scene::load(dir)?;
    let cloud = scene.load_points(dir)?;
    let intr = scene.views.iter().map(|v| crate::intrinsics::Intrinsics {
        kind: crate::intrinsics::ModelKind::Pinhole,
        width: v.camera.width,
        height: v.camera.height,
        fx: v.camera.fx,
        fy: v.camera.fy,
        cx: v.camera.cx,
        cy: v.camera.cy,
        distortion: Default::default(),
    });
    let groups = group_intrinsics(intr);
    let err = (!cloud.is_empty())
        .then(|| cloud.errors.iter().map(|&e| e as f64).sum::<f64>() / cloud.len() as f64);
    let n = &scene.normalization;
    Ok(Report {
        path: dir.display().to_string(),
        format: "augsplat scene".into(),
        cameras: groups.len(),
        registered_images: scene.views.len(),
        intrinsics: groups,
        points: cloud.len(),
        observations: cloud.track_views.len(),
        mean_reprojection_error: err,
        reprojection_error_source: err.map(|_| "mean of stored per-point errors".to_string()),
        camera_bounds: Aabb::of(scene.views.iter().map(|v| v.camera.center())),
        point_bounds: Aabb::of(
            cloud
                .positions
                .iter()
                .map(|p| [p[0] as f64, p[1] as f64, p[2] as f64]),
        ),
        near_far: Some((scene.near, scene.far)),
        notes: vec![
            format!("source: {}", scene.source),
            format!(
                "normalised frame: p_norm = (p − {:?}) · {}",
                n.center, n.scale
            ),
            format!(
                "{} views with depth maps",
                scene.views.iter().filter(|v| v.depth.is_some()).count()
            ),
        ],
    })
}

/// The report as readable text.
pub fn format_text(r: &Report) -> String {
    use std::fmt::Write as _;
    let mut s = String::new();
    let _ = writeln!(s, "{} ({})", r.path, r.format);
    let _ = writeln!(s, "  cameras:            {}", r.cameras);
    let _ = writeln!(s, "  registered images:  {}", r.registered_images);
    for i in &r.intrinsics {
        let _ = write!(
            s,
            "  intrinsics:         {} {}×{} fx {:.4} fy {:.4} cx {:.4} cy {:.4}",
            i.model, i.width, i.height, i.fx, i.fy, i.cx, i.cy
        );
        if i.distortion.iter().any(|&d| d != 0.0) {
            let d = i.distortion;
            let _ = write!(
                s,
                " k1 {:.6} k2 {:.6} k3 {:.6} k4 {:.6} p1 {:.6} p2 {:.6}",
                d[0], d[1], d[2], d[3], d[4], d[5]
            );
        }
        let _ = writeln!(s, " ({} images)", i.images);
    }
    let _ = writeln!(s, "  points:             {}", r.points);
    if r.points > 0 {
        let _ = writeln!(
            s,
            "  observations:       {} (mean track length {:.3})",
            r.observations,
            r.observations as f64 / r.points as f64
        );
    }
    if let (Some(e), Some(src)) = (r.mean_reprojection_error, &r.reprojection_error_source) {
        let _ = writeln!(s, "  mean reproj. error: {e:.6} px ({src})");
    }
    let fmt = |v: Vec3| format!("({:.4}, {:.4}, {:.4})", v[0], v[1], v[2]);
    if let Some(b) = &r.camera_bounds {
        let _ = writeln!(s, "  camera bounds:      {} … {}", fmt(b.min), fmt(b.max));
    }
    if let Some(b) = &r.point_bounds {
        let _ = writeln!(s, "  point bounds:       {} … {}", fmt(b.min), fmt(b.max));
    }
    if let Some((n, f)) = r.near_far {
        let _ = writeln!(s, "  near / far:         {n:.4} / {f:.4}");
    }
    for n in &r.notes {
        let _ = writeln!(s, "  note: {n}");
    }
    s
}
