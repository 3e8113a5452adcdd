//! COLMAP sparse models: reading and writing the binary (`cameras.bin`, `images.bin`,
//! `points3D.bin`, in `binary.rs`) and text (`*.txt`, in `text.rs`) forms, the checks every
//! loaded model passes, and COLMAP's mean reprojection error.
//!
//! COLMAP stores world-to-camera poses as a unit quaternion (qw, qx, qy, qz) and a translation,
//! OpenCV camera axes, pixel centres at +0.5 — the same conventions as augsplat's [`Camera`].
//!
//! [`Camera`]: augsplat_core::Camera

use crate::error::{Result, SceneError};
use crate::intrinsics::{Intrinsics, ModelKind};
use augsplat_core::linalg::{self, Mat4};
use std::collections::BTreeMap;
use std::path::Path;

mod binary;
#[cfg(test)]
mod tests;
mod text;

/// One COLMAP camera (intrinsics shared by images).
#[derive(Clone, Debug, PartialEq)]
pub struct ColmapCamera {
    /// Camera id.
    pub id: u32,
    /// Model, size and parameters.
    pub intrinsics: Intrinsics,
}

/// One registered image.
#[derive(Clone, Debug, PartialEq)]
pub struct ColmapImage {
    /// Image id.
    pub id: u32,
    /// World-to-camera rotation as (qw, qx, qy, qz).
    pub qvec: [f64; 4],
    /// World-to-camera translation.
    pub tvec: [f64; 3],
    /// The camera it uses.
    pub camera_id: u32,
    /// File name relative to the images folder.
    pub name: String,
    /// 2D keypoints (x, y in pixels) and the 3D point each belongs to (-1 for none).
    pub points2d: Vec<([f64; 2], i64)>,
}

impl ColmapImage {
    /// The world-to-camera 4×4 transform.
    pub fn world_to_camera(&self) -> Mat4 {
        linalg::mat4_from_rt(&linalg::quat_to_mat3(self.qvec), self.tvec)
    }
}

/// One 3D point with its track.
#[derive(Clone, Debug, PartialEq)]
pub struct ColmapPoint {
    /// Point id.
    pub id: u64,
    /// Position (model frame).
    pub xyz: [f64; 3],
    /// Colour.
    pub rgb: [u8; 3],
    /// Mean reprojection error COLMAP stored, pixels.
    pub error: f64,
    /// Observations: (image id, index into that image's `points2d`).
    pub track: Vec<(u32, u32)>,
}

/// A whole sparse model.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct ColmapModel {
    /// Cameras by id.
    pub cameras: BTreeMap<u32, ColmapCamera>,
    /// Registered images by id.
    pub images: BTreeMap<u32, ColmapImage>,
    /// Points, sorted by id by [`ColmapModel::load`] (file order from the format readers).
    pub points: Vec<ColmapPoint>,
}

/// Whether `dir` holds a COLMAP model (binary or text).
pub fn is_model_dir(dir: &Path) -> bool {
    dir.join("cameras.bin").is_file() || dir.join("cameras.txt").is_file()
}

impl ColmapModel {
    /// Reads a model folder: binary if `cameras.bin` exists, else text.
    pub fn load(dir: &Path) -> Result<ColmapModel> {
        if !dir.is_dir() {
            return Err(SceneError::missing(dir, "COLMAP model folder"));
        }
        let model = if dir.join("cameras.bin").is_file() {
            ColmapModel::load_binary(dir)?
        } else if dir.join("cameras.txt").is_file() {
            ColmapModel::load_text(dir)?
        } else {
            return Err(SceneError::missing(
                &dir.join("cameras.bin"),
                "COLMAP cameras file (cameras.bin or cameras.txt)",
            ));
        };
        model.check_references(dir)?;
        let mut model = model;
        model.points.sort_by_key(|p| p.id);
        Ok(model)
    }

    /// Checks that images name existing cameras and tracks name existing images/keypoints.
    fn check_references(&self, dir: &Path) -> Result<()> {
        for img in self.images.values() {
            if !self.cameras.contains_key(&img.camera_id) {
                return Err(SceneError::format(
                    dir.join("images"),
                    format!(
                        "image {} ({}) uses camera {}, which the model does not have",
                        img.id, img.name, img.camera_id
                    ),
                ));
            }
        }
        for p in &self.points {
            for &(iid, idx) in &p.track {
                let ok = self.images.get(&iid).is_some_and(|img| {
                    (idx as usize) < img.points2d.len() || img.points2d.is_empty()
                });
                if !ok {
                    return Err(SceneError::format(
                        dir.join("points3D"),
                        format!("point {}: track names image {iid} keypoint {idx}, which does not exist", p.id),
                    ));
                }
            }
        }
        Ok(())
    }

    /// COLMAP's mean reprojection error: for each point with at least one observation whose
    /// keypoint is known, the mean distance (pixels) between its projection (with distortion)
    /// and the keypoint; then the mean over those points. Returns (error, number of points,
    /// number of observations), or `None` when no observation has a keypoint.
    pub fn mean_reprojection_error(&self) -> Option<(f64, usize, usize)> {
        let mut sum = 0.0;
        let mut npts = 0usize;
        let mut nobs = 0usize;
        for p in &self.points {
            let mut s = 0.0;
            let mut n = 0usize;
            for &(iid, idx) in &p.track {
                let Some(img) = self.images.get(&iid) else {
                    continue;
                };
                let Some(&(xy, _)) = img.points2d.get(idx as usize) else {
                    continue;
                };
                let cam = &self.cameras[&img.camera_id].intrinsics;
                let w2c = img.world_to_camera();
                let pc = transform(&w2c, p.xyz);
                let Some((u, v)) = cam.project_camera_point(pc) else {
                    continue;
                };
                s += ((u - xy[0]).powi(2) + (v - xy[1]).powi(2)).sqrt();
                n += 1;
            }
            if n > 0 {
                sum += s / n as f64;
                npts += 1;
                nobs += n;
            }
        }
        (npts > 0).then(|| (sum / npts as f64, npts, nobs))
    }
}

/// Applies a rigid 4×4 transform to a point.
pub(crate) fn transform(m: &Mat4, p: [f64; 3]) -> [f64; 3] {
    let (r, t) = linalg::rt_from_mat4(m);
    linalg::add(linalg::mat3_vec(&r, p), t)
}

fn make_camera(
    path: &Path,
    id: i64,
    kind: ModelKind,
    width: u64,
    height: u64,
    params: &[f64],
) -> Result<ColmapCamera> {
    let bad = |m: String| SceneError::format(path, format!("camera {id}: {m}"));
    let id = u32::try_from(id).map_err(|_| bad("id out of range".into()))?;
    let (w, h) = (
        u32::try_from(width).map_err(|_| bad(format!("width {width} out of range")))?,
        u32::try_from(height).map_err(|_| bad(format!("height {height} out of range")))?,
    );
    let intrinsics = Intrinsics::from_colmap(kind, w, h, params).map_err(bad)?;
    Ok(ColmapCamera { id, intrinsics })
}

fn make_image(
    path: &Path,
    id: i64,
    qvec: [f64; 4],
    tvec: [f64; 3],
    camera_id: i64,
    name: String,
    points2d: Vec<([f64; 2], i64)>,
) -> Result<ColmapImage> {
    let bad = |m: String| SceneError::format(path, format!("image {id} ({name}): {m}"));
    let uid = u32::try_from(id).map_err(|_| bad("id out of range".into()))?;
    let cid =
        u32::try_from(camera_id).map_err(|_| bad(format!("camera id {camera_id} out of range")))?;
    if qvec.iter().chain(&tvec).any(|v| !v.is_finite()) {
        return Err(bad(format!(
            "pose contains a non-finite value (q {qvec:?}, t {tvec:?})"
        )));
    }
    let qn = qvec.iter().map(|v| v * v).sum::<f64>().sqrt();
    if qn.is_nan() || qn <= 1e-6 {
        return Err(bad("rotation quaternion is zero".into()));
    }
    if name.is_empty() {
        return Err(bad("empty image name".into()));
    }
    if points2d
        .iter()
        .any(|(xy, _)| !xy[0].is_finite() || !xy[1].is_finite())
    {
        return Err(bad("a keypoint position is not finite".into()));
    }
    Ok(ColmapImage {
        id: uid,
        qvec,
        tvec,
        camera_id: cid,
        name,
        points2d,
    })
}

fn check_point(path: &Path, id: u64, xyz: [f64; 3]) -> Result<()> {
    if xyz.iter().any(|v| !v.is_finite()) {
        return Err(SceneError::format(
            path,
            format!("point {id}: position {xyz:?} is not finite"),
        ));
    }
    Ok(())
}
