//! Folder layouts that pass between node families (besides the scene, see [`crate::scene`]).
//! Each is a JSON index plus per-view files, paths relative to the folder.
//!
//! | artifact | index file | per-view files | written by → read by |
//! |---|---|---|---|
//! | [`PoseSet`] | `poses.json` | — | SynthesizePoses → RenderField |
//! | [`RenderSet`] | `renders.json` | EXR with channels R, G, B (colour), D (expected depth), A (accumulated opacity) | RenderField → AggregateEnsemble |
//! | [`SyntheticSet`] | `synthetic.json` | target EXR (R, G, B), weight EXR (W), preview PNGs | AggregateEnsemble → OptimizeSplats |
//! | [`TrainingCurve`] | `curve.json` | — | OptimizeSplats, TrainField → Evaluate, Report |
//!
//! This module owns each format: [`SyntheticView::write`] and [`SyntheticView::read`] are the
//! only code that knows the synthetic view's files and channels, and
//! [`RenderSet::check_compatible`] is the one test that several render sets show the same views
//! at the same sizes (an ensemble).

use crate::{camera::Camera, image, CoreError, ImageF32};
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

impl RenderSet {
    /// Checks that every set renders the same views (same names, in the same order) at the same
    /// image sizes as the first, as the members of one ensemble must. `dirs[k]` is the folder
    /// of `sets[k]`, named in the message.
    pub fn check_compatible(sets: &[RenderSet], dirs: &[&Path]) -> Result<(), String> {
        let Some(first) = sets.first() else {
            return Ok(());
        };
        let dir = |k: usize| {
            dirs.get(k)
                .map_or(String::new(), |d| d.display().to_string())
        };
        for (k, s) in sets.iter().enumerate().skip(1) {
            if s.views.len() != first.views.len() {
                return Err(format!(
                    "member {k} ({}) has {} views, member 0 ({}) has {}",
                    dir(k),
                    s.views.len(),
                    dir(0),
                    first.views.len()
                ));
            }
            for (a, b) in first.views.iter().zip(&s.views) {
                if a.name != b.name
                    || a.camera.width != b.camera.width
                    || a.camera.height != b.camera.height
                {
                    return Err(format!(
                        "member {k} ({}) view `{}` ({}×{}) does not match member 0 view `{}` ({}×{})",
                        dir(k),
                        b.name,
                        b.camera.width,
                        b.camera.height,
                        a.name,
                        a.camera.width,
                        a.camera.height
                    ));
                }
            }
        }
        Ok(())
    }
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

/// The pixels of one synthetic view, as [`SyntheticView::read`] returns them.
#[derive(Clone, Debug, PartialEq)]
pub struct SyntheticPixels {
    /// The target colour, interleaved RGB at the camera's size.
    pub target: ImageF32,
    /// The confidence weights, `H·W`, row-major.
    pub weight: Vec<f32>,
}

/// The channel of the weight EXR of a synthetic view.
pub const WEIGHT_CHANNEL: &str = "W";

/// A file-name-safe version of a view name: ASCII letters, digits, `-`, `_` and `.` are kept,
/// every other character becomes `_`.
pub fn file_stem(name: &str) -> String {
    name.chars()
        .map(|c| {
            if c.is_ascii_alphanumeric() || c == '-' || c == '_' || c == '.' {
                c
            } else {
                '_'
            }
        })
        .collect()
}

impl SyntheticView {
    /// The sub-folders of a synthetic set's folder that [`SyntheticView::write`] writes into;
    /// create them (e.g. with [`SyntheticSet::create_folders`]) before writing views.
    pub const FOLDERS: [&'static str; 3] = ["targets", "weights", "previews"];

    /// Writes the files of view `name` into the synthetic set's folder `dir`:
    /// `targets/<stem>.exr` (channels R, G, B from the planar `target`, `3·H·W` values),
    /// `weights/<stem>.exr` (channel W from `weight`, `H·W` values) and the previews
    /// `previews/<stem>_target.png` and `previews/<stem>_weight.png`, `<stem>` being
    /// [`file_stem`] of the name. Returns the index entry, with the weight sum (in f64, in
    /// pixel order).
    pub fn write(
        dir: &Path,
        name: &str,
        camera: &Camera,
        target: &[f32],
        weight: &[f32],
    ) -> Result<SyntheticView, CoreError> {
        let (w, h) = (camera.width, camera.height);
        let n = (w * h) as usize;
        let stem = file_stem(name);
        let target_rel = format!("targets/{stem}.exr");
        let weight_rel = format!("weights/{stem}.exr");
        if target.len() != 3 * n {
            return Err(CoreError::format(
                dir.join(&target_rel),
                format!(
                    "target holds {} values, {w}×{h}×3 needs {}",
                    target.len(),
                    3 * n
                ),
            ));
        }
        let (r, g, b) = (&target[..n], &target[n..2 * n], &target[2 * n..]);
        image::write_exr(
            &dir.join(&target_rel),
            w,
            h,
            &[("R", r), ("G", g), ("B", b)],
        )?;
        image::write_exr(&dir.join(&weight_rel), w, h, &[(WEIGHT_CHANNEL, weight)])?;
        let mut rgb = Vec::with_capacity(3 * n);
        for p in 0..n {
            rgb.extend_from_slice(&[r[p], g[p], b[p]]);
        }
        image::write_png(
            &dir.join(format!("previews/{stem}_target.png")),
            &ImageF32::from_vec(w, h, 3, rgb),
        )?;
        image::write_png(
            &dir.join(format!("previews/{stem}_weight.png")),
            &ImageF32::from_vec(w, h, 1, weight.to_vec()),
        )?;
        let weight_sum: f64 = weight.iter().map(|&x| x as f64).sum();
        Ok(SyntheticView {
            name: name.to_string(),
            camera: camera.clone(),
            target: target_rel,
            weight: weight_rel,
            weight_sum,
        })
    }

    /// Reads the target colour and the weight map of this view from the synthetic set's
    /// folder `dir`, checking that the weight EXR has its W channel and that both match the
    /// camera's size.
    pub fn read(&self, dir: &Path) -> Result<SyntheticPixels, CoreError> {
        let target = image::read_rgb(&dir.join(&self.target))?;
        let wpath = dir.join(&self.weight);
        let exr = image::read_exr(&wpath)?;
        let weight = exr
            .channel(WEIGHT_CHANNEL)
            .ok_or_else(|| {
                CoreError::format(
                    &wpath,
                    format!(
                        "weight EXR has no channel {WEIGHT_CHANNEL} (has {:?})",
                        exr.names()
                    ),
                )
            })?
            .to_vec();
        let (w, h) = (self.camera.width, self.camera.height);
        if (target.width, target.height) != (w, h) || weight.len() != (w * h) as usize {
            return Err(CoreError::format(
                &wpath,
                format!(
                    "view {}: target {}×{} / weight {} values do not match the camera {}×{}",
                    self.name,
                    target.width,
                    target.height,
                    weight.len(),
                    w,
                    h
                ),
            ));
        }
        // A custom augmentation node may write anything: refuse what would poison training.
        if let Some((i, v)) = weight
            .iter()
            .enumerate()
            .find(|(_, v)| !(v.is_finite() && (0.0..=1.0).contains(*v)))
        {
            return Err(CoreError::format(
                &wpath,
                format!(
                    "view {}: weight {v} at pixel ({}, {}) is not a confidence in [0, 1]",
                    self.name,
                    i as u32 % w,
                    i as u32 / w
                ),
            ));
        }
        if let Some(i) = target.data.iter().position(|v| !v.is_finite()) {
            let p = i as u32 / 3;
            return Err(CoreError::format(
                dir.join(&self.target),
                format!(
                    "view {}: target value {} at pixel ({}, {}) is not finite",
                    self.name,
                    target.data[i],
                    p % w,
                    p / w
                ),
            ));
        }
        self.camera.validate().map_err(|e| {
            CoreError::format(
                dir.join("synthetic.json"),
                format!("view {}: invalid camera: {e}", self.name),
            )
        })?;
        Ok(SyntheticPixels { target, weight })
    }
}

/// Synthetic supervision (`synthetic.json`).
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct SyntheticSet {
    /// The views.
    pub views: Vec<SyntheticView>,
}

impl SyntheticSet {
    /// Creates the sub-folders ([`SyntheticView::FOLDERS`]) of a synthetic set's folder `dir`.
    pub fn create_folders(dir: &Path) -> Result<(), CoreError> {
        for sub in SyntheticView::FOLDERS {
            let d = dir.join(sub);
            std::fs::create_dir_all(&d).map_err(|e| CoreError::io(&d, e))?;
        }
        Ok(())
    }
}

/// One evaluation point of a training run.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct CurvePoint {
    /// Optimisation step (after that many steps).
    pub step: u64,
    /// Mean held-out PSNR, dB (infinite when every view is rendered exactly; written as the
    /// string `inf`, see [`nonfinite`]).
    #[serde(with = "nonfinite")]
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

/// Serde for an `f64` that may be non-finite (e.g. the PSNR of an exact render): finite
/// values are plain JSON numbers (the same text as without this module), `inf`, `-inf` and
/// `nan` are strings. Use with `#[serde(with = "augsplat_core::artifacts::nonfinite")]`.
pub mod nonfinite {
    use serde::{Deserialize, Deserializer, Serializer};

    /// Serialises an f64, non-finite values as strings.
    pub fn serialize<S: Serializer>(v: &f64, s: S) -> Result<S::Ok, S::Error> {
        if v.is_finite() {
            s.serialize_f64(*v)
        } else {
            s.serialize_str(&format_value(*v))
        }
    }

    /// Deserialises a number or one of the strings `inf`, `-inf`, `nan`.
    pub fn deserialize<'de, D: Deserializer<'de>>(d: D) -> Result<f64, D::Error> {
        #[derive(Deserialize)]
        #[serde(untagged)]
        enum Repr {
            Num(f64),
            Str(String),
        }
        match Repr::deserialize(d)? {
            Repr::Num(v) => Ok(v),
            Repr::Str(s) => parse(&s).ok_or_else(|| {
                serde::de::Error::custom(format!(
                    "expected a number, `inf`, `-inf` or `nan`, found `{s}`"
                ))
            }),
        }
    }

    /// The text of a value: shortest round-trip decimal, or `inf` / `-inf` / `nan`.
    pub fn format_value(v: f64) -> String {
        if v.is_nan() {
            "nan".into()
        } else if v == f64::INFINITY {
            "inf".into()
        } else if v == f64::NEG_INFINITY {
            "-inf".into()
        } else {
            format!("{v}")
        }
    }

    /// Parses a value written by [`format_value`] (or any decimal).
    pub fn parse(s: &str) -> Option<f64> {
        match s.trim() {
            "inf" | "+inf" | "Infinity" => Some(f64::INFINITY),
            "-inf" | "-Infinity" => Some(f64::NEG_INFINITY),
            "nan" | "NaN" => Some(f64::NAN),
            t => t.parse().ok(),
        }
    }
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

#[cfg(test)]
mod tests {
    use super::*;

    fn camera(w: u32, h: u32) -> Camera {
        let mut m = [[0.0; 4]; 4];
        for (i, row) in m.iter_mut().enumerate() {
            row[i] = 1.0;
        }
        Camera {
            width: w,
            height: h,
            fx: w as f64,
            fy: w as f64,
            cx: w as f64 / 2.0,
            cy: h as f64 / 2.0,
            world_to_camera: m,
        }
    }

    #[test]
    fn synthetic_view_round_trips_through_its_owner() {
        let tmp = tempfile::tempdir().unwrap();
        let dir = tmp.path();
        SyntheticSet::create_folders(dir).unwrap();
        let (w, h) = (5u32, 3u32);
        let n = (w * h) as usize;
        let target: Vec<f32> = (0..3 * n).map(|i| i as f32 / (3 * n) as f32).collect();
        let weight: Vec<f32> = (0..n).map(|i| (i % 4) as f32 / 4.0).collect();
        let v = SyntheticView::write(dir, "a view/1", &camera(w, h), &target, &weight).unwrap();
        assert_eq!(v.target, "targets/a_view_1.exr");
        assert_eq!(v.weight, "weights/a_view_1.exr");
        assert!(dir.join("previews/a_view_1_target.png").is_file());
        assert!(dir.join("previews/a_view_1_weight.png").is_file());
        let sum: f64 = weight.iter().map(|&x| x as f64).sum();
        assert_eq!(v.weight_sum, sum);
        let px = v.read(dir).unwrap();
        assert_eq!(px.weight, weight);
        // The target comes back interleaved.
        assert_eq!((px.target.width, px.target.height), (w, h));
        for p in 0..n {
            for c in 0..3 {
                assert_eq!(px.target.data[3 * p + c], target[c * n + p]);
            }
        }
        // A camera of another size is an error naming the view.
        let mut other = v.clone();
        other.camera = camera(w + 1, h);
        let e = other.read(dir).unwrap_err().to_string();
        assert!(e.contains("a view/1") && e.contains("6×3"), "{e}");
        // A weight file without its W channel is an error naming the file.
        other = v.clone();
        other.weight = v.target.clone();
        let e = other.read(dir).unwrap_err().to_string();
        assert!(e.contains("no channel W"), "{e}");
        // What a custom augmentation node might write: NaN or out-of-range weights, a
        // non-finite target, a missing file. Each is an error naming the file and the pixel.
        let mut bad_w = weight.clone();
        bad_w[7] = f32::NAN;
        let b = SyntheticView::write(dir, "nan", &camera(w, h), &target, &bad_w).unwrap();
        let e = b.read(dir).unwrap_err().to_string();
        assert!(
            e.contains("weights/nan.exr") && e.contains("pixel (2, 1)"),
            "{e}"
        );
        bad_w[7] = 1.5;
        let b = SyntheticView::write(dir, "big", &camera(w, h), &target, &bad_w).unwrap();
        assert!(b
            .read(dir)
            .unwrap_err()
            .to_string()
            .contains("not a confidence in [0, 1]"));
        let mut bad_t = target.clone();
        bad_t[n + 4] = f32::INFINITY;
        let b = SyntheticView::write(dir, "inf", &camera(w, h), &bad_t, &weight).unwrap();
        let e = b.read(dir).unwrap_err().to_string();
        assert!(
            e.contains("targets/inf.exr") && e.contains("pixel (4, 0)"),
            "{e}"
        );
        std::fs::remove_file(dir.join(&v.weight)).unwrap();
        let e = v.read(dir).unwrap_err().to_string();
        assert!(e.contains("weights/a_view_1.exr"), "{e}");
    }

    #[test]
    fn render_sets_of_one_ensemble_are_compatible() {
        let view = |name: &str, w: u32| RenderedView {
            name: name.into(),
            camera: camera(w, 4),
            file: format!("{name}.exr"),
        };
        let a = RenderSet {
            views: vec![view("x", 8), view("y", 8)],
        };
        let dirs = [Path::new("m0"), Path::new("m1")];
        assert!(RenderSet::check_compatible(&[a.clone(), a.clone()], &dirs).is_ok());
        let fewer = RenderSet {
            views: vec![view("x", 8)],
        };
        let e = RenderSet::check_compatible(&[a.clone(), fewer], &dirs).unwrap_err();
        assert!(e.contains("member 1 (m1) has 1 views"), "{e}");
        let resized = RenderSet {
            views: vec![view("x", 8), view("y", 9)],
        };
        let e = RenderSet::check_compatible(&[a, resized], &dirs).unwrap_err();
        assert!(e.contains("view `y` (9×4)"), "{e}");
    }

    #[test]
    fn curve_psnr_may_be_infinite_and_finite_values_keep_their_text() {
        let p = CurvePoint {
            step: 3,
            psnr: 31.25,
            ..Default::default()
        };
        #[derive(Serialize)]
        struct Plain {
            psnr: f64,
        }
        let text = serde_json::to_string(&p).unwrap();
        let plain = serde_json::to_string(&Plain { psnr: 31.25 }).unwrap();
        assert!(text.contains(&plain[1..plain.len() - 1]), "{text}");
        let inf = CurvePoint {
            psnr: f64::INFINITY,
            ..p
        };
        let text = serde_json::to_string(&inf).unwrap();
        assert!(text.contains("\"psnr\":\"inf\""), "{text}");
        let back: CurvePoint = serde_json::from_str(&text).unwrap();
        assert_eq!(back.psnr, f64::INFINITY);
    }
}
