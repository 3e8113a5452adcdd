//! Readers of the three source formats into one format-neutral [`RawScene`] (original frame,
//! original image files, intrinsics with distortion, point tracks with keypoints).
//!
//! - COLMAP: a model folder (binary or text) plus an images folder; registered images whose
//!   file is missing are left out and listed in [`RawScene::missing_images`] (`ImportScene`
//!   refuses them unless `allow_missing_images` is set); photos that COLMAP did not register (listed in
//!   an `image_list.txt` next to the model, or else present in the images folder) are reported
//!   as skipped.
//! - transforms.json (nerfstudio / instant-ngp): camera-to-world in OpenGL axes (x right,
//!   y up, z back), converted here to OpenCV world-to-camera; global or per-frame intrinsics
//!   (`fl_x fl_y cx cy w h`, or `camera_angle_x`/`camera_angle_y`), `k1 k2 k3 k4 p1 p2`
//!   distortion; `aabb_scale` and other keys are ignored; frames whose image is missing are
//!   left out and listed likewise.
//! - LLFF: `poses_bounds.npy` (N×17: a 3×5 [R | t | (h, w, f)] camera-to-world in (down,
//!   right, back) axes at full resolution, then near and far) with an `images_N` folder; the
//!   intrinsics follow the actual size of the images in that folder, principal point at the
//!   image centre.

use crate::colmap::{self, ColmapModel};
use crate::error::{Result, SceneError};
use crate::intrinsics::{Distortion, Intrinsics, ModelKind};
use augsplat_core::linalg::{self, Mat4, Vec3};
use std::collections::{BTreeMap, BTreeSet};
use std::path::{Path, PathBuf};

/// One view of a source scene, before normalisation.
#[derive(Clone, Debug, PartialEq)]
pub struct RawView {
    /// Unique name (the image file's stem).
    pub name: String,
    /// The source image file.
    pub image_path: PathBuf,
    /// Intrinsics of the image as stored (possibly distorted).
    pub intrinsics: Intrinsics,
    /// World-to-camera, original frame, OpenCV axes.
    pub world_to_camera: Mat4,
    /// Near/far bounds the source gives for this view (LLFF), original units.
    pub bounds: Option<(f64, f64)>,
}

/// One observation of a point: the view and, when known, the keypoint position (pixels, in
/// the view's original distorted image).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Observation {
    /// Index into [`RawScene::views`].
    pub view: usize,
    /// Keypoint position, if the source stores it.
    pub keypoint: Option<[f64; 2]>,
}

/// Sparse points in the original frame.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct RawPoints {
    /// Positions.
    pub positions: Vec<Vec3>,
    /// RGB colours in [0, 1].
    pub colors: Vec<[f32; 3]>,
    /// Mean reprojection error per point as the source stored it (pixels).
    pub errors: Vec<f64>,
    /// Observations per point.
    pub tracks: Vec<Vec<Observation>>,
}

/// A source scene in its own frame.
#[derive(Clone, Debug, PartialEq)]
pub struct RawScene {
    /// Format and path, in words.
    pub source: String,
    /// Views sorted by name.
    pub views: Vec<RawView>,
    /// Sparse points (empty when the format has none).
    pub points: RawPoints,
    /// Warnings for the log (skipped images, ignored fields).
    pub warnings: Vec<String>,
    /// Image files of registered views (COLMAP images, transforms.json frames) that do not
    /// exist; those views are left out. `ImportScene` refuses them unless
    /// `allow_missing_images` is set.
    pub missing_images: Vec<PathBuf>,
}

/// The image extensions the importers look for.
pub const IMAGE_EXTENSIONS: [&str; 4] = ["png", "jpg", "jpeg", "exr"];

fn is_image_file(p: &Path) -> bool {
    p.is_file()
        && p.extension()
            .and_then(|e| e.to_str())
            .is_some_and(|e| IMAGE_EXTENSIONS.contains(&e.to_ascii_lowercase().as_str()))
}

/// Image files directly inside `dir`, sorted by file name.
pub fn list_images(dir: &Path) -> Result<Vec<PathBuf>> {
    let rd = std::fs::read_dir(dir).map_err(|e| SceneError::io(dir, e))?;
    let mut v: Vec<PathBuf> = rd
        .filter_map(|e| e.ok().map(|e| e.path()))
        .filter(|p| is_image_file(p))
        .collect();
    v.sort();
    Ok(v)
}

/// A view name from an image path: the file stem.
pub fn stem(p: &str) -> String {
    Path::new(p)
        .file_stem()
        .map(|s| s.to_string_lossy().into_owned())
        .unwrap_or_else(|| p.to_string())
}

/// Sorts views by name, rejecting duplicates; returns the permutation (old index → new).
fn sort_views(views: &mut Vec<RawView>, what: &Path) -> Result<Vec<usize>> {
    let mut order: Vec<usize> = (0..views.len()).collect();
    order.sort_by(|&a, &b| views[a].name.cmp(&views[b].name));
    for w in order.windows(2) {
        if views[w[0]].name == views[w[1]].name {
            return Err(SceneError::format(
                what,
                format!(
                    "two views would be called `{}` ({} and {}); view names are image file stems and must be unique",
                    views[w[0]].name,
                    views[w[0]].image_path.display(),
                    views[w[1]].image_path.display()
                ),
            ));
        }
    }
    let mut new_index = vec![0; views.len()];
    for (new, &old) in order.iter().enumerate() {
        new_index[old] = new;
    }
    let sorted: Vec<RawView> = order.iter().map(|&i| views[i].clone()).collect();
    *views = sorted;
    Ok(new_index)
}

/// Reads a COLMAP model folder with its images folder.
pub fn load_colmap(model_dir: &Path, images_dir: &Path) -> Result<RawScene> {
    let model = ColmapModel::load(model_dir)?;
    if !images_dir.is_dir() {
        return Err(SceneError::missing(images_dir, "images folder"));
    }
    let mut warnings = Vec::new();
    let mut views = Vec::new();
    let mut view_of_image: BTreeMap<u32, usize> = BTreeMap::new();
    let mut missing_images = Vec::new();
    for img in model.images.values() {
        let path = images_dir.join(&img.name);
        if !path.is_file() {
            missing_images.push(path.clone());
            warnings.push(format!(
                "skipping registered image {} ({}): file {} not found",
                img.id,
                img.name,
                path.display()
            ));
            continue;
        }
        view_of_image.insert(img.id, views.len());
        views.push(RawView {
            name: stem(&img.name),
            image_path: path,
            intrinsics: model.cameras[&img.camera_id].intrinsics,
            world_to_camera: img.world_to_camera(),
            bounds: None,
        });
    }
    // Report photos COLMAP did not register.
    let registered: BTreeSet<&str> = model.images.values().map(|i| i.name.as_str()).collect();
    let list = [model_dir.join("image_list.txt")]
        .into_iter()
        .chain(model_dir.parent().map(|p| p.join("image_list.txt")))
        .chain(
            model_dir
                .parent()
                .and_then(Path::parent)
                .map(|p| p.join("image_list.txt")),
        )
        .find(|p| p.is_file());
    let (inputs, origin): (Vec<String>, String) = match &list {
        Some(p) => (
            std::fs::read_to_string(p)
                .map_err(|e| SceneError::io(p, e))?
                .lines()
                .map(str::trim)
                .filter(|l| !l.is_empty() && !l.starts_with('#'))
                .map(str::to_string)
                .collect(),
            format!("listed in {}", p.display()),
        ),
        None => (Vec::new(), String::new()),
    };
    let unregistered: Vec<&String> = inputs
        .iter()
        .filter(|n| !registered.contains(n.as_str()))
        .collect();
    if !unregistered.is_empty() {
        warnings.push(format!(
            "skipping {} of {} photos {origin}: COLMAP did not register them ({})",
            unregistered.len(),
            inputs.len(),
            unregistered
                .iter()
                .map(|s| s.as_str())
                .collect::<Vec<_>>()
                .join(", ")
        ));
    } else if list.is_none() {
        let n_folder = list_images(images_dir)?.len();
        if n_folder > registered.len() {
            warnings.push(format!(
                "{} of the {} images in {} are not registered in the model and are skipped",
                n_folder - registered.len().min(n_folder),
                n_folder,
                images_dir.display()
            ));
        }
    }
    if views.is_empty() {
        return Err(SceneError::Invalid(format!(
            "no views left: none of the {} registered images of {} was found in {}",
            model.images.len(),
            model_dir.display(),
            images_dir.display()
        )));
    }
    let new_index = sort_views(&mut views, images_dir)?;
    let mut points = RawPoints::default();
    for p in &model.points {
        let mut track: Vec<Observation> = Vec::with_capacity(p.track.len());
        for &(iid, idx) in &p.track {
            let Some(&v) = view_of_image.get(&iid) else {
                continue;
            };
            let keypoint = model.images[&iid]
                .points2d
                .get(idx as usize)
                .map(|(xy, _)| *xy);
            track.push(Observation {
                view: new_index[v],
                keypoint,
            });
        }
        if track.is_empty() {
            continue;
        }
        points.positions.push(p.xyz);
        points.colors.push(p.rgb.map(|c| c as f32 / 255.0));
        points.errors.push(p.error);
        points.tracks.push(track);
    }
    Ok(RawScene {
        source: format!(
            "COLMAP model {} with images {}",
            model_dir.display(),
            images_dir.display()
        ),
        views,
        points,
        warnings,
        missing_images,
    })
}

/// Reads a transforms.json file; image paths are relative to its folder.
pub fn load_transforms(file: &Path) -> Result<RawScene> {
    let text = std::fs::read_to_string(file).map_err(|e| SceneError::io(file, e))?;
    let json: serde_json::Value = serde_json::from_str(&text)
        .map_err(|e| SceneError::format(file, format!("not valid JSON: {e}")))?;
    let root = json
        .as_object()
        .ok_or_else(|| SceneError::format(file, "expected a JSON object at the top level"))?;
    let frames = root
        .get("frames")
        .and_then(|f| f.as_array())
        .ok_or_else(|| SceneError::format(file, "no `frames` array"))?;
    let base = file.parent().unwrap_or(Path::new("."));
    let mut warnings = Vec::new();
    let mut missing_images = Vec::new();
    let mut views = Vec::new();
    for (k, frame) in frames.iter().enumerate() {
        let at = |m: String| SceneError::format(file, format!("frame {k}: {m}"));
        let fobj = frame
            .as_object()
            .ok_or_else(|| at("expected an object".into()))?;
        let rel = fobj
            .get("file_path")
            .and_then(|v| v.as_str())
            .ok_or_else(|| at("no `file_path`".into()))?;
        let mut path = base.join(rel);
        if path.extension().is_none() || !path.is_file() {
            // Blender-style paths omit the extension.
            if let Some(p) = ["png", "jpg", "jpeg", "PNG", "JPG"]
                .iter()
                .map(|e| base.join(format!("{rel}.{e}")))
                .find(|p| p.is_file())
            {
                path = p;
            }
        }
        if !path.is_file() {
            missing_images.push(path.clone());
            warnings.push(format!(
                "skipping frame {k}: image {} not found",
                path.display()
            ));
            continue;
        }
        let m = fobj
            .get("transform_matrix")
            .ok_or_else(|| at(format!("({rel}) no `transform_matrix`")))?;
        let c2w_gl = matrix4(m).map_err(|e| at(format!("({rel}) transform_matrix: {e}")))?;
        // OpenGL camera axes → OpenCV: flip the camera's y and z axes.
        let mut c2w = c2w_gl;
        for row in c2w.iter_mut().take(3) {
            row[1] = -row[1];
            row[2] = -row[2];
        }
        let (r, _) = linalg::rt_from_mat4(&c2w);
        let det = linalg::det3(&r);
        if (det - 1.0).abs() > 1e-3 {
            return Err(at(format!(
                "({rel}) transform_matrix rotation is not a rotation (determinant {det:.6})"
            )));
        }
        let w2c = linalg::rigid_inverse(&orthonormalize(&c2w));
        let get = |key: &str| -> Result<Option<f64>> {
            match fobj.get(key).or_else(|| root.get(key)) {
                None | Some(serde_json::Value::Null) => Ok(None),
                Some(v) => v
                    .as_f64()
                    .filter(|x| x.is_finite())
                    .map(Some)
                    .ok_or_else(|| at(format!("({rel}) `{key}` is not a finite number"))),
            }
        };
        let (iw, ih) = match (get("w")?, get("h")?) {
            (Some(w), Some(h)) => (w, h),
            _ => {
                let (w, h) = augsplat_core::image::image_size(&path)?;
                (w as f64, h as f64)
            }
        };
        let fl_x = match (get("fl_x")?, get("camera_angle_x")?) {
            (Some(f), _) => f,
            (None, Some(a)) => 0.5 * iw / (0.5 * a).tan(),
            (None, None) => match (get("fl_y")?, get("camera_angle_y")?) {
                (Some(f), _) => f,
                (None, Some(a)) => 0.5 * ih / (0.5 * a).tan(),
                _ => {
                    return Err(at(format!(
                        "({rel}) no focal length (fl_x or camera_angle_x)"
                    )))
                }
            },
        };
        let fl_y = match (get("fl_y")?, get("camera_angle_y")?) {
            (Some(f), _) => f,
            (None, Some(a)) if get("fl_x")?.is_none() => 0.5 * ih / (0.5 * a).tan(),
            _ => fl_x,
        };
        let distortion = Distortion {
            k1: get("k1")?.unwrap_or(0.0),
            k2: get("k2")?.unwrap_or(0.0),
            k3: get("k3")?.unwrap_or(0.0),
            k4: get("k4")?.unwrap_or(0.0),
            p1: get("p1")?.unwrap_or(0.0),
            p2: get("p2")?.unwrap_or(0.0),
        };
        if iw < 1.0 || ih < 1.0 || iw.fract() != 0.0 || ih.fract() != 0.0 {
            return Err(at(format!(
                "({rel}) image size {iw}×{ih} is not a positive integer size"
            )));
        }
        let intrinsics = Intrinsics {
            kind: if distortion.is_zero() {
                ModelKind::Pinhole
            } else {
                ModelKind::OpenCv
            },
            width: iw as u32,
            height: ih as u32,
            fx: fl_x,
            fy: fl_y,
            cx: get("cx")?.unwrap_or(iw / 2.0),
            cy: get("cy")?.unwrap_or(ih / 2.0),
            distortion,
        };
        intrinsics.check().map_err(|e| at(format!("({rel}) {e}")))?;
        views.push(RawView {
            name: stem(rel),
            image_path: path,
            intrinsics,
            world_to_camera: w2c,
            bounds: None,
        });
    }
    if views.is_empty() {
        return Err(SceneError::Invalid(format!(
            "no views left: none of the {} frames of {} has its image",
            frames.len(),
            file.display()
        )));
    }
    sort_views(&mut views, file)?;
    let points = match root.get("ply_file_path") {
        None | Some(serde_json::Value::Null) => RawPoints::default(),
        Some(v) => {
            let rel = v
                .as_str()
                .ok_or_else(|| SceneError::format(file, "`ply_file_path` is not a string"))?;
            let ply = base.join(rel);
            if ply.is_file() {
                let read = crate::ply_points::read_points_ply(&ply)?;
                let tracks = crate::ply_points::tracks_by_visibility(&views, &read.positions);
                warnings.push(format!(
                    "{} points from {} (`ply_file_path`); which views see each is worked out \
                     from visibility (a PLY has no observations)",
                    read.positions.len(),
                    ply.display()
                ));
                RawPoints {
                    errors: vec![0.0; read.positions.len()],
                    positions: read.positions,
                    colors: read.colors,
                    tracks,
                }
            } else {
                warnings.push(format!(
                    "`ply_file_path` names {}, which does not exist: no points from it",
                    ply.display()
                ));
                RawPoints::default()
            }
        }
    };
    Ok(RawScene {
        source: format!("transforms.json {}", file.display()),
        views,
        points,
        warnings,
        missing_images,
    })
}

/// Re-orthonormalises the rotation of a rigid transform (files store rounded matrices).
fn orthonormalize(m: &Mat4) -> Mat4 {
    let (r, t) = linalg::rt_from_mat4(m);
    let q = linalg::mat3_to_quat(&r);
    linalg::mat4_from_rt(&linalg::quat_to_mat3(q), t)
}

fn matrix4(v: &serde_json::Value) -> std::result::Result<Mat4, String> {
    let rows = v.as_array().ok_or("expected a 4×4 (or 3×4) array")?;
    if rows.len() != 4 && rows.len() != 3 {
        return Err(format!("expected 4 rows, found {}", rows.len()));
    }
    let mut m = [
        [0.0, 0.0, 0.0, 0.0],
        [0.0; 4],
        [0.0; 4],
        [0.0, 0.0, 0.0, 1.0],
    ];
    for (i, row) in rows.iter().enumerate() {
        let r = row.as_array().ok_or("rows must be arrays")?;
        if r.len() != 4 {
            return Err(format!("row {i} has {} values, expected 4", r.len()));
        }
        for (j, x) in r.iter().enumerate() {
            let x = x
                .as_f64()
                .ok_or_else(|| format!("entry [{i}][{j}] is not a number"))?;
            if !x.is_finite() {
                return Err(format!("entry [{i}][{j}] is not finite"));
            }
            m[i][j] = x;
        }
    }
    Ok(m)
}

/// The `images` and `images_N` folders of LLFF folder `dir`, by factor (1 for `images`).
pub fn llff_image_folders(dir: &Path) -> Result<Vec<(u32, PathBuf)>> {
    let mut folders: Vec<(u32, PathBuf)> = std::fs::read_dir(dir)
        .map_err(|e| SceneError::io(dir, e))?
        .filter_map(|e| e.ok().map(|e| e.path()))
        .filter(|p| p.is_dir())
        .filter_map(|p| {
            let name = p.file_name()?.to_str()?.to_string();
            let f = if name == "images" {
                1
            } else {
                name.strip_prefix("images_")?.parse().ok()?
            };
            Some((f, p))
        })
        .collect();
    folders.sort();
    Ok(folders)
}

/// The last component of `p`, for messages that must not depend on where a capture lies.
fn folder_name(p: &Path) -> String {
    p.file_name()
        .map(|n| n.to_string_lossy().to_string())
        .unwrap_or_default()
}

/// The images folder of LLFF folder `dir` to read: `images_<factor>` (`images` for factor 1)
/// when it exists, else the folder whose image count matches the poses (the most downscaled
/// one when several do), with a note saying so. An error lists the folders and their counts
/// when none matches.
pub fn choose_llff_images(dir: &Path, factor: u32) -> Result<(PathBuf, Option<String>)> {
    let wanted = match factor {
        0 | 1 => dir.join("images"),
        f => dir.join(format!("images_{f}")),
    };
    if wanted.is_dir() {
        return Ok((wanted, None));
    }
    let npy = dir.join("poses_bounds.npy");
    if !npy.is_file() {
        return Err(SceneError::missing(&npy, "LLFF poses file"));
    }
    let (shape, _) = augsplat_core::image::read_npy_array(&npy)?;
    let rows = shape.first().copied().unwrap_or(0);
    let folders = llff_image_folders(dir)?;
    let counted: Vec<(u32, PathBuf, usize)> = folders
        .into_iter()
        .map(|(f, p)| {
            let n = list_images(&p).map(|v| v.len()).unwrap_or(0);
            (f, p, n)
        })
        .collect();
    match counted.iter().rev().find(|(_, _, n)| *n == rows) {
        Some((_, p, _)) => Ok((
            p.clone(),
            Some(format!(
                "{} not found; reading {}, whose {rows} images match poses_bounds.npy \
                 (set `llff_factor` or `images` to choose another)",
                folder_name(&wanted),
                folder_name(p)
            )),
        )),
        None => {
            let seen: Vec<String> = counted
                .iter()
                .map(|(_, p, n)| format!("{} ({n} images)", p.display()))
                .collect();
            Err(SceneError::format(
                dir,
                format!(
                    "{} not found, and no images folder holds the {rows} images \
                     poses_bounds.npy describes (found: {})",
                    wanted.display(),
                    if seen.is_empty() {
                        "none".to_string()
                    } else {
                        seen.join(", ")
                    }
                ),
            ))
        }
    }
}

/// Reads an LLFF folder: `poses_bounds.npy` and the images folder `images_dir`.
pub fn load_llff(dir: &Path, images_dir: &Path) -> Result<RawScene> {
    let npy = dir.join("poses_bounds.npy");
    if !npy.is_file() {
        return Err(SceneError::missing(&npy, "LLFF poses file"));
    }
    let (shape, a) = augsplat_core::image::read_npy_array(&npy)?;
    if shape.len() != 2 || shape[1] != 17 {
        return Err(SceneError::format(
            &npy,
            format!("expected an N×17 array, found shape {shape:?}"),
        ));
    }
    if !images_dir.is_dir() {
        return Err(SceneError::missing(images_dir, "LLFF images folder"));
    }
    let files = list_images(images_dir)?;
    let n = shape[0];
    if files.len() != n {
        return Err(SceneError::format(
            images_dir,
            format!(
                "{} images but {} has {n} poses (LLFF pairs sorted images with rows)",
                files.len(),
                npy.display()
            ),
        ));
    }
    let (aw, ah) = augsplat_core::image::image_size(&files[0])?;
    let mut views = Vec::with_capacity(n);
    for (i, file) in files.iter().enumerate() {
        let row = &a[i * 17..(i + 1) * 17];
        let at = |m: String| SceneError::format(&npy, format!("row {i} ({}): {m}", file.display()));
        if row.iter().any(|v| !v.is_finite()) {
            return Err(at("contains a non-finite value".into()));
        }
        let p = |r: usize, c: usize| row[r * 5 + c];
        let (h, w, f) = (p(0, 4), p(1, 4), p(2, 4));
        if !(h > 0.0 && w > 0.0 && f > 0.0) {
            return Err(at(format!("h, w, f = {h}, {w}, {f} must be positive")));
        }
        let s = aw as f64 / w;
        if (ah as f64 - h * s).abs() > 1.0 {
            return Err(at(format!(
                "image is {aw}×{ah}, which is not the pose's {w}×{h} scaled uniformly"
            )));
        }
        // Columns: down, right, back → OpenCV x = right, y = down, z = forward = −back.
        let down = [p(0, 0), p(1, 0), p(2, 0)];
        let right = [p(0, 1), p(1, 1), p(2, 1)];
        let back = [p(0, 2), p(1, 2), p(2, 2)];
        let t = [p(0, 3), p(1, 3), p(2, 3)];
        let r = [
            [right[0], down[0], -back[0]],
            [right[1], down[1], -back[1]],
            [right[2], down[2], -back[2]],
        ];
        let det = linalg::det3(&r);
        if (det - 1.0).abs() > 1e-3 {
            return Err(at(format!("rotation has determinant {det:.6}, not 1")));
        }
        let c2w = orthonormalize(&linalg::mat4_from_rt(&r, t));
        let (near, far) = (row[15], row[16]);
        if !(near > 0.0 && far > near) {
            return Err(at(format!(
                "bounds near {near}, far {far} are not 0 < near < far"
            )));
        }
        let (iw, ih) = augsplat_core::image::image_size(file)?;
        if (iw, ih) != (aw, ah) {
            return Err(SceneError::format(
                file,
                format!(
                    "image is {iw}×{ih}, but {} is {aw}×{ah}",
                    files[0].display()
                ),
            ));
        }
        views.push(RawView {
            name: stem(&file.to_string_lossy()),
            image_path: file.clone(),
            intrinsics: Intrinsics {
                kind: ModelKind::Pinhole,
                width: aw,
                height: ah,
                fx: f * s,
                fy: f * s,
                cx: aw as f64 / 2.0,
                cy: ah as f64 / 2.0,
                distortion: Distortion::default(),
            },
            world_to_camera: linalg::rigid_inverse(&c2w),
            bounds: Some((near, far)),
        });
    }
    sort_views(&mut views, images_dir)?;
    Ok(RawScene {
        source: format!(
            "LLFF {} with images {}",
            dir.display(),
            images_dir.display()
        ),
        views,
        points: RawPoints::default(),
        warnings: Vec::new(),
        missing_images: Vec::new(),
    })
}

/// Transforms a point by a rigid 4×4 (re-exported helper).
pub fn transform(m: &Mat4, p: Vec3) -> Vec3 {
    colmap::transform(m, p)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn transforms_opengl_axes_become_opencv() {
        let dir = tempfile::tempdir().unwrap();
        let img = augsplat_core::ImageF32::new(8, 6, 3);
        augsplat_core::image::write_png(&dir.path().join("a.png"), &img).unwrap();
        // Camera at (0, 0, 5) looking down −z (OpenGL identity rotation): the world origin
        // is straight ahead at depth 5 in OpenCV terms.
        let json = r#"{"fl_x": 10, "fl_y": 11, "cx": 4, "cy": 3, "w": 8, "h": 6, "aabb_scale": 16,
            "frames": [
              {"file_path": "a", "transform_matrix": [[1,0,0,0],[0,1,0,0],[0,0,1,5],[0,0,0,1]]},
              {"file_path": "missing.png", "transform_matrix": [[1,0,0,0],[0,1,0,0],[0,0,1,5],[0,0,0,1]]}
            ]}"#;
        let f = dir.path().join("transforms.json");
        std::fs::write(&f, json).unwrap();
        let raw = load_transforms(&f).unwrap();
        assert_eq!(raw.views.len(), 1);
        assert_eq!(raw.warnings.len(), 1);
        assert!(raw.warnings[0].contains("missing.png"));
        let v = &raw.views[0];
        assert_eq!(v.name, "a");
        let pc = transform(&v.world_to_camera, [0.0, 0.0, 0.0]);
        assert!((pc[2] - 5.0).abs() < 1e-12 && pc[0].abs() < 1e-12 && pc[1].abs() < 1e-12);
        // World +y (up) appears at negative image y (OpenCV y points down).
        let up = transform(&v.world_to_camera, [0.0, 1.0, 0.0]);
        assert!(up[1] < 0.0);
        assert_eq!(
            (v.intrinsics.fx, v.intrinsics.fy, v.intrinsics.cx),
            (10.0, 11.0, 4.0)
        );
    }

    #[test]
    fn transforms_bad_matrix_names_the_frame() {
        let dir = tempfile::tempdir().unwrap();
        let img = augsplat_core::ImageF32::new(8, 6, 3);
        augsplat_core::image::write_png(&dir.path().join("a.png"), &img).unwrap();
        let f = dir.path().join("transforms.json");
        std::fs::write(&f, r#"{"camera_angle_x": 0.7, "frames": [{"file_path": "a.png", "transform_matrix": [[1,0,0],[0,1,0,0],[0,0,1,5]]}]}"#).unwrap();
        let e = load_transforms(&f).unwrap_err().to_string();
        assert!(
            e.contains("transforms.json") && e.contains("frame 0"),
            "{e}"
        );
    }
}
