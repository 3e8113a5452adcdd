//! Folder layouts that pass between node families (besides the scene, see [`crate::scene`]).
//! Each is a JSON index plus per-view files, paths relative to the folder.
//!
//! | artifact | index file | per-view files | written by → read by |
//! |---|---|---|---|
//! | [`PoseSet`] | `poses.json` | — | SynthesizePoses → RenderField |
//! | [`RenderSet`] | `renders.json` | EXR with channels R, G, B (colour), D (expected depth), A (accumulated opacity) | RenderField → AggregateEnsemble |
//! | [`SyntheticSet`] | `synthetic.json` | target EXR (R, G, B), weight EXR (W), preview PNGs | AggregateEnsemble → OptimizeSplats |
//! | [`TrainingCurve`] | `curve.json` | — | OptimizeSplats, TrainField → Evaluate, Report |

use crate::{camera::Camera, CoreError};
use serde::{de::DeserializeOwned, Deserialize, Serialize};
use std::path::Path;

/// A named camera.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct PoseView {
    /// Stable name, unique within the set.
    pub name: String,
    /// The camera (intrinsics at the resolution to render).
    pub camera: Camera,
    /// Where the pose came from, e.g. `jitter:DSCF5568` or `interp:a,b@0.25`.
    #[serde(default)]
    pub origin: String,
}

/// A set of poses to render (`poses.json`).
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct PoseSet {
    /// The poses, in order.
    pub views: Vec<PoseView>,
}

/// One rendered view of a radiance field.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct RenderedView {
    /// The pose's name.
    pub name: String,
    /// The camera rendered.
    pub camera: Camera,
    /// Relative path of the EXR (channels R, G, B, D, A).
    pub file: String,
}

/// The renders of one ensemble member (`renders.json`).
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct RenderSet {
    /// The views, in the order of the pose set.
    pub views: Vec<RenderedView>,
}

/// One synthetic supervision view.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct SyntheticView {
    /// The pose's name.
    pub name: String,
    /// The camera (at the synthetic resolution).
    pub camera: Camera,
    /// Relative path of the target EXR (channels R, G, B): the per-pixel ensemble median.
    pub target: String,
    /// Relative path of the weight EXR (channel W): confidence in [0, 1].
    pub weight: String,
    /// Sum of the weight map (lets trainers skip views with no confidence).
    pub weight_sum: f64,
}

/// Synthetic supervision (`synthetic.json`).
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct SyntheticSet {
    /// The views.
    pub views: Vec<SyntheticView>,
}

/// One evaluation point of a training run.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct CurvePoint {
    /// Optimisation step (after that many steps).
    pub step: u64,
    /// Mean held-out PSNR, dB.
    pub psnr: f64,
    /// Mean held-out SSIM (torchmetrics convention).
    pub ssim: f64,
    /// Mean held-out LPIPS, when weights were available.
    #[serde(default)]
    pub lpips: Option<f64>,
    /// Mean held-out MSE.
    #[serde(default)]
    pub mse: f64,
    /// Average error (MSE·sqrt(1−SSIM)·LPIPS)^(1/3), when LPIPS was available.
    #[serde(default)]
    pub avg_error: Option<f64>,
    /// Number of primitives (Gaussians) at that step, 0 when not applicable.
    #[serde(default)]
    pub primitives: u64,
    /// Seconds of training so far.
    #[serde(default)]
    pub seconds: f64,
    /// Training loss at that step.
    #[serde(default)]
    pub loss: f64,
}

/// A training curve (`curve.json`).
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct TrainingCurve {
    /// A label for reports (method name).
    #[serde(default)]
    pub label: String,
    /// Evaluation points in step order.
    pub points: Vec<CurvePoint>,
}

/// File names of the indexes above.
pub mod files {
    /// [`super::PoseSet`] index.
    pub const POSES: &str = "poses.json";
    /// [`super::RenderSet`] index.
    pub const RENDERS: &str = "renders.json";
    /// [`super::SyntheticSet`] index.
    pub const SYNTHETIC: &str = "synthetic.json";
    /// [`super::TrainingCurve`].
    pub const CURVE: &str = "curve.json";
}

/// Reads a JSON artifact index.
pub fn read_json<T: DeserializeOwned>(path: &Path) -> Result<T, CoreError> {
    let text = std::fs::read_to_string(path).map_err(|e| CoreError::io(path, e))?;
    serde_json::from_str(&text).map_err(|e| CoreError::format(path, format!("invalid JSON: {e}")))
}

/// Writes a JSON artifact index (pretty, deterministic).
pub fn write_json<T: Serialize>(path: &Path, value: &T) -> Result<(), CoreError> {
    let text =
        serde_json::to_string_pretty(value).map_err(|e| CoreError::format(path, e.to_string()))?;
    std::fs::write(path, text).map_err(|e| CoreError::io(path, e))
}
