//! The scene artifact: the normalised multi-view scene that import writes and every later
//! stage reads.
//!
//! On disk (one folder):
//! - `scene.json` — [`Scene`] (views with cameras and relative image paths, bounds, the
//!   normalisation applied);
//! - `images/<name>.png` — 8-bit RGB images, one per view;
//! - `depth/<name>.exr` — optional per-view depth with channels `Z` (depth along the optical
//!   axis, 0 where unknown) and `W` (confidence weight in [0, 1], 0 where unknown);
//! - `points.safetensors` — optional [`PointCloud`].
//!
//! Coordinates are the *normalised* frame: `p_norm = (p_orig − center) · scale`.

use crate::{camera::Camera, image, linalg::Vec3, CoreError, ImageF32};
use serde::{Deserialize, Serialize};
use std::path::Path;

/// Depth (Z) and confidence (W) planes of one view, row-major.
pub type DepthPlanes = (Vec<f32>, Vec<f32>);

/// File name of the scene description inside a scene folder.
pub const SCENE_FILE: &str = "scene.json";
/// File name of the point cloud inside a scene folder.
pub const POINTS_FILE: &str = "points.safetensors";

/// One view: a camera and its image (and optional depth), paths relative to the scene folder.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct SceneView {
    /// Stable name (the source image's file stem).
    pub name: String,
    /// Relative path of the RGB image.
    pub image: String,
    /// Relative path of the depth EXR (channels Z, W), if any.
    #[serde(default)]
    pub depth: Option<String>,
    /// The camera, in the normalised frame.
    pub camera: Camera,
}

/// The similarity applied on import: `p_norm = (p_orig − center) · scale`.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Normalization {
    /// Subtracted first, in original units.
    pub center: Vec3,
    /// Multiplied second.
    pub scale: f64,
}

impl Default for Normalization {
    fn default() -> Self {
        Normalization {
            center: [0.0; 3],
            scale: 1.0,
        }
    }
}

impl Normalization {
    /// Original-frame point to normalised frame.
    pub fn apply(&self, p: Vec3) -> Vec3 {
        [
            (p[0] - self.center[0]) * self.scale,
            (p[1] - self.center[1]) * self.scale,
            (p[2] - self.center[2]) * self.scale,
        ]
    }
    /// Normalised-frame point back to the original frame.
    pub fn invert(&self, p: Vec3) -> Vec3 {
        [
            p[0] / self.scale + self.center[0],
            p[1] / self.scale + self.center[1],
            p[2] / self.scale + self.center[2],
        ]
    }
}

/// A scene description (`scene.json`).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Scene {
    /// Where the scene came from, in words (format and path), for reports.
    pub source: String,
    /// The views, in a stable order.
    pub views: Vec<SceneView>,
    /// Near bound of scene content along camera rays (normalised units).
    pub near: f64,
    /// Far bound of scene content along camera rays (normalised units).
    pub far: f64,
    /// The normalisation applied on import.
    #[serde(default)]
    pub normalization: Normalization,
    /// Whether `points.safetensors` is present.
    #[serde(default)]
    pub has_points: bool,
}

impl Scene {
    /// Reads `scene.json` from a scene folder.
    pub fn load(dir: &Path) -> Result<Scene, CoreError> {
        let path = dir.join(SCENE_FILE);
        let text = std::fs::read_to_string(&path).map_err(|e| CoreError::io(&path, e))?;
        serde_json::from_str(&text)
            .map_err(|e| CoreError::format(&path, format!("invalid scene description: {e}")))
    }
    /// Writes `scene.json` into a scene folder (images and points are written separately).
    pub fn save(&self, dir: &Path) -> Result<(), CoreError> {
        let path = dir.join(SCENE_FILE);
        let text = serde_json::to_string_pretty(self).expect("scene serialises");
        std::fs::write(&path, text).map_err(|e| CoreError::io(&path, e))
    }
    /// Loads the RGB image of view `index`.
    pub fn load_image(&self, dir: &Path, index: usize) -> Result<ImageF32, CoreError> {
        image::read_rgb(&dir.join(&self.views[index].image))
    }
    /// Loads the depth (Z) and weight (W) planes of view `index`, if it has depth.
    pub fn load_depth(&self, dir: &Path, index: usize) -> Result<Option<DepthPlanes>, CoreError> {
        let Some(rel) = &self.views[index].depth else {
            return Ok(None);
        };
        let path = dir.join(rel);
        let exr = image::read_exr(&path)?;
        let z = exr
            .channel("Z")
            .ok_or_else(|| CoreError::format(&path, "depth EXR has no Z channel"))?;
        let w = exr
            .channel("W")
            .ok_or_else(|| CoreError::format(&path, "depth EXR has no W channel"))?;
        Ok(Some((z.to_vec(), w.to_vec())))
    }
    /// Loads the point cloud, or an empty one when the scene has none.
    pub fn load_points(&self, dir: &Path) -> Result<PointCloud, CoreError> {
        if !self.has_points {
            return Ok(PointCloud::default());
        }
        PointCloud::load(&dir.join(POINTS_FILE))
    }
    /// Axis-aligned bounds of the camera centres.
    pub fn camera_bounds(&self) -> (Vec3, Vec3) {
        let mut lo = [f64::INFINITY; 3];
        let mut hi = [f64::NEG_INFINITY; 3];
        for v in &self.views {
            let c = v.camera.center();
            for k in 0..3 {
                lo[k] = lo[k].min(c[k]);
                hi[k] = hi[k].max(c[k]);
            }
        }
        (lo, hi)
    }
}

/// SfM points with colours, reprojection errors and tracks (which views see each point).
#[derive(Clone, Debug, Default, PartialEq)]
pub struct PointCloud {
    /// Positions, normalised frame.
    pub positions: Vec<[f32; 3]>,
    /// RGB colours in [0, 1].
    pub colors: Vec<[f32; 3]>,
    /// Mean reprojection error per point, pixels (0 when unknown).
    pub errors: Vec<f32>,
    /// `track_offsets[i]..track_offsets[i+1]` indexes `track_views` for point i (len N+1).
    pub track_offsets: Vec<u32>,
    /// View indices (into `Scene::views`) observing each point, concatenated.
    pub track_views: Vec<u32>,
}

impl PointCloud {
    /// Number of points.
    pub fn len(&self) -> usize {
        self.positions.len()
    }
    /// Whether there are no points.
    pub fn is_empty(&self) -> bool {
        self.positions.is_empty()
    }
    /// The views that observe point i.
    pub fn track(&self, i: usize) -> &[u32] {
        if self.track_offsets.len() <= i + 1 {
            return &[];
        }
        &self.track_views[self.track_offsets[i] as usize..self.track_offsets[i + 1] as usize]
    }

    /// Writes the cloud as safetensors (tensors `positions [N,3]`, `colors [N,3]`, `errors [N]`
    /// f32; `track_offsets [N+1]`, `track_views [T]` u32).
    pub fn save(&self, path: &Path) -> Result<(), CoreError> {
        use safetensors::tensor::{Dtype, TensorView};
        let n = self.len();
        let f32s = |v: &[f32]| v.iter().flat_map(|x| x.to_le_bytes()).collect::<Vec<u8>>();
        let u32s = |v: &[u32]| v.iter().flat_map(|x| x.to_le_bytes()).collect::<Vec<u8>>();
        let pos = f32s(&self.positions.concat());
        let col = f32s(&self.colors.concat());
        let err = f32s(&self.errors);
        let off = if self.track_offsets.is_empty() {
            vec![0u32; n + 1]
        } else {
            self.track_offsets.clone()
        };
        let offb = u32s(&off);
        let tv = u32s(&self.track_views);
        let bad = |e: safetensors::SafeTensorError| {
            CoreError::format(path, format!("cannot encode points: {e}"))
        };
        let tensors = vec![
            (
                "positions",
                TensorView::new(Dtype::F32, vec![n, 3], &pos).map_err(bad)?,
            ),
            (
                "colors",
                TensorView::new(Dtype::F32, vec![n, 3], &col).map_err(bad)?,
            ),
            (
                "errors",
                TensorView::new(Dtype::F32, vec![n], &err).map_err(bad)?,
            ),
            (
                "track_offsets",
                TensorView::new(Dtype::U32, vec![n + 1], &offb).map_err(bad)?,
            ),
            (
                "track_views",
                TensorView::new(Dtype::U32, vec![self.track_views.len()], &tv).map_err(bad)?,
            ),
        ];
        let bytes = safetensors::serialize(tensors, None).map_err(bad)?;
        std::fs::write(path, bytes).map_err(|e| CoreError::io(path, e))
    }

    /// Reads a cloud written by [`PointCloud::save`].
    pub fn load(path: &Path) -> Result<PointCloud, CoreError> {
        let bytes = std::fs::read(path).map_err(|e| CoreError::io(path, e))?;
        let st = safetensors::SafeTensors::deserialize(&bytes).map_err(|e| {
            CoreError::format(path, format!("not a point-cloud safetensors file: {e}"))
        })?;
        let get = |name: &str| {
            st.tensor(name)
                .map_err(|e| CoreError::format(path, format!("missing tensor {name}: {e}")))
        };
        let f32v = |name: &str| -> Result<Vec<f32>, CoreError> {
            Ok(get(name)?
                .data()
                .chunks_exact(4)
                .map(|b| f32::from_le_bytes([b[0], b[1], b[2], b[3]]))
                .collect())
        };
        let u32v = |name: &str| -> Result<Vec<u32>, CoreError> {
            Ok(get(name)?
                .data()
                .chunks_exact(4)
                .map(|b| u32::from_le_bytes([b[0], b[1], b[2], b[3]]))
                .collect())
        };
        let triples = |v: Vec<f32>| {
            v.chunks_exact(3)
                .map(|c| [c[0], c[1], c[2]])
                .collect::<Vec<_>>()
        };
        let cloud = PointCloud {
            positions: triples(f32v("positions")?),
            colors: triples(f32v("colors")?),
            errors: f32v("errors")?,
            track_offsets: u32v("track_offsets")?,
            track_views: u32v("track_views")?,
        };
        let n = cloud.positions.len();
        if cloud.colors.len() != n || cloud.errors.len() != n || cloud.track_offsets.len() != n + 1
        {
            return Err(CoreError::format(
                path,
                "point-cloud tensors disagree in length",
            ));
        }
        if cloud.track_offsets.last().copied().unwrap_or(0) as usize != cloud.track_views.len() {
            return Err(CoreError::format(
                path,
                "track offsets do not match track_views",
            ));
        }
        Ok(cloud)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn point_cloud_round_trip_including_empty() {
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("p.safetensors");
        let cloud = PointCloud {
            positions: vec![[1.0, 2.0, 3.0], [4.0, 5.0, 6.0]],
            colors: vec![[0.1, 0.2, 0.3], [0.4, 0.5, 0.6]],
            errors: vec![0.5, 0.25],
            track_offsets: vec![0, 2, 3],
            track_views: vec![0, 1, 1],
        };
        cloud.save(&p).unwrap();
        let back = PointCloud::load(&p).unwrap();
        assert_eq!(back, cloud);
        assert_eq!(back.track(0), &[0, 1]);
        let empty = PointCloud::default();
        empty.save(&p).unwrap();
        assert_eq!(PointCloud::load(&p).unwrap().len(), 0);
    }

    #[test]
    fn normalization_inverts() {
        let n = Normalization {
            center: [1.0, -2.0, 0.5],
            scale: 0.25,
        };
        let p = [3.0, 4.0, -5.0];
        let q = n.invert(n.apply(p));
        for k in 0..3 {
            assert!((p[k] - q[k]).abs() < 1e-12);
        }
    }
}
