//! The `eval` folder that the `Evaluate` node writes and `Report` / `augsplat compare` read.
//!
//! Layout:
//! - `metrics.json` — [`EvalMetrics`]: per-view and mean metrics of the evaluated checkpoint,
//!   the best step of the training curve, the evaluation at the baseline's best step;
//! - `metrics.csv` — the same per-view and mean metrics as a table ([`EvalMetrics::to_csv`]);
//! - `renders/<view>.png`, `gt/<view>.png` — the evaluated renders and their ground truth;
//! - `curve.json` — the training curve of the model (copied; absent when the model had none);
//! - `cameras.json` — the held-out cameras as rendered, `[{"name", "camera"}]` in view order;
//! - `model.ply` — the evaluated checkpoint (a copy: the store keeps one blob for both), for
//!   the report's 3-D viewer.
//!
//! Infinite PSNR (a render identical to its ground truth) is written as the string `"inf"` in
//! JSON and CSV, because JSON has no infinity.

use crate::select::{AtBaselineStep, BestStep};
use crate::ReportError;
use augsplat_core::artifacts::{self, TrainingCurve};
use serde::{Deserialize, Serialize};
use std::path::{Path, PathBuf};

/// File names inside an eval folder.
pub mod files {
    /// [`super::EvalMetrics`].
    pub const METRICS: &str = "metrics.json";
    /// The CSV table.
    pub const METRICS_CSV: &str = "metrics.csv";
    /// The copied training curve.
    pub const CURVE: &str = "curve.json";
    /// Folder of renders.
    pub const RENDERS: &str = "renders";
    /// Folder of ground-truth images.
    pub const GT: &str = "gt";
    /// The held-out cameras as rendered.
    pub const CAMERAS: &str = "cameras.json";
    /// The evaluated checkpoint.
    pub const MODEL: &str = "model.ply";
}

/// One entry of `cameras.json`.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct EvalCamera {
    /// The view's name.
    pub name: String,
    /// The camera at the evaluation resolution.
    pub camera: augsplat_core::Camera,
}

/// Version of the `metrics.json` layout.
pub const FORMAT_VERSION: u32 = 1;

/// Serde helpers writing non-finite floats as strings (`"inf"`, `"-inf"`, `"nan"`); the
/// one owner is [`augsplat_core::artifacts::nonfinite`] (the training curve uses it too).
pub use augsplat_core::artifacts::nonfinite;

/// Metrics of one image pair (or their mean over views).
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct Metrics {
    /// PSNR, dB (infinite for identical images).
    #[serde(with = "nonfinite")]
    pub psnr: f64,
    /// SSIM (torchmetrics convention).
    pub ssim: f64,
    /// Mean squared error over pixels and channels.
    pub mse: f64,
    /// LPIPS distance, when weights were available.
    #[serde(default)]
    pub lpips: Option<f64>,
    /// Average error `(MSE · sqrt(1 − SSIM) · LPIPS)^(1/3)`, when LPIPS was available.
    #[serde(default)]
    pub avg_error: Option<f64>,
}

impl From<augsplat_metrics::measure::Measurement> for Metrics {
    fn from(m: augsplat_metrics::measure::Measurement) -> Self {
        Metrics {
            psnr: m.psnr,
            ssim: m.ssim,
            mse: m.mse,
            lpips: m.lpips,
            avg_error: m.avg_error,
        }
    }
}

impl Metrics {
    /// The mean of each metric over `items` (LPIPS and average error only when every item has
    /// them). PSNR is the mean of per-view PSNRs, as gsplat and AugSplat report it.
    pub fn mean(items: &[Metrics]) -> Metrics {
        if items.is_empty() {
            return Metrics {
                psnr: f64::NAN,
                ssim: f64::NAN,
                mse: f64::NAN,
                lpips: None,
                avg_error: None,
            };
        }
        let n = items.len() as f64;
        let mean = |f: &dyn Fn(&Metrics) -> f64| items.iter().map(f).sum::<f64>() / n;
        let mean_opt = |f: &dyn Fn(&Metrics) -> Option<f64>| -> Option<f64> {
            let mut s = 0.0;
            for m in items {
                s += f(m)?;
            }
            Some(s / n)
        };
        Metrics {
            psnr: mean(&|m| m.psnr),
            ssim: mean(&|m| m.ssim),
            mse: mean(&|m| m.mse),
            lpips: mean_opt(&|m| m.lpips),
            avg_error: mean_opt(&|m| m.avg_error),
        }
    }

    /// The value of metric `key` (`psnr`, `ssim`, `lpips`, `mse`, `avg_error`).
    pub fn get(&self, key: MetricKey) -> Option<f64> {
        match key {
            MetricKey::Psnr => Some(self.psnr),
            MetricKey::Ssim => Some(self.ssim),
            MetricKey::Lpips => self.lpips,
            MetricKey::Mse => Some(self.mse),
            MetricKey::AvgError => self.avg_error,
        }
    }

    /// The metrics of a training-curve point.
    pub fn from_curve_point(p: &artifacts::CurvePoint) -> Metrics {
        Metrics {
            psnr: p.psnr,
            ssim: p.ssim,
            mse: p.mse,
            lpips: p.lpips,
            avg_error: p.avg_error,
        }
    }
}

/// One of the reported metrics.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum MetricKey {
    /// PSNR (higher is better).
    Psnr,
    /// SSIM (higher is better).
    Ssim,
    /// LPIPS (lower is better).
    Lpips,
    /// MSE (lower is better).
    Mse,
    /// Average error (lower is better).
    AvgError,
}

impl MetricKey {
    /// The four metrics of the paper's Table 1, in its order.
    pub const TABLE: [MetricKey; 4] = [
        MetricKey::Psnr,
        MetricKey::Ssim,
        MetricKey::Lpips,
        MetricKey::AvgError,
    ];
    /// Every metric.
    pub const ALL: [MetricKey; 5] = [
        MetricKey::Psnr,
        MetricKey::Ssim,
        MetricKey::Lpips,
        MetricKey::Mse,
        MetricKey::AvgError,
    ];
    /// Whether larger values are better.
    pub fn higher_is_better(self) -> bool {
        matches!(self, MetricKey::Psnr | MetricKey::Ssim)
    }
    /// Column title.
    pub fn title(self) -> &'static str {
        match self {
            MetricKey::Psnr => "PSNR",
            MetricKey::Ssim => "SSIM",
            MetricKey::Lpips => "LPIPS",
            MetricKey::Mse => "MSE",
            MetricKey::AvgError => "Avg. error",
        }
    }
    /// Machine name (JSON/CSV).
    pub fn key(self) -> &'static str {
        match self {
            MetricKey::Psnr => "psnr",
            MetricKey::Ssim => "ssim",
            MetricKey::Lpips => "lpips",
            MetricKey::Mse => "mse",
            MetricKey::AvgError => "avg_error",
        }
    }
    /// Decimals shown in tables (PSNR 2, MSE 5, others 3).
    pub fn decimals(self) -> i32 {
        match self {
            MetricKey::Psnr => 2,
            MetricKey::Mse => 5,
            _ => 3,
        }
    }
    /// The value rounded to the decimals shown (non-finite values unchanged).
    pub fn round_shown(self, v: f64) -> f64 {
        if !v.is_finite() {
            return v;
        }
        let f = 10f64.powi(self.decimals());
        (v * f).round() / f
    }
    /// Formats a value for tables (PSNR 2 decimals, others 3, MSE 5, `inf` as ∞).
    pub fn format(self, v: f64) -> String {
        if v == f64::INFINITY {
            return "∞".into();
        }
        if !v.is_finite() {
            return nonfinite::format_value(v);
        }
        match self {
            MetricKey::Psnr => format!("{v:.2}"),
            MetricKey::Mse => format!("{v:.5}"),
            _ => format!("{v:.3}"),
        }
    }
}

/// Metrics of one evaluated view.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct ViewMetrics {
    /// The view's name (from the test scene).
    pub name: String,
    /// Evaluation resolution.
    pub width: u32,
    /// Evaluation resolution.
    pub height: u32,
    /// The metrics.
    #[serde(flatten)]
    pub metrics: Metrics,
}

/// The contents of `metrics.json`.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct EvalMetrics {
    /// Layout version ([`FORMAT_VERSION`]).
    pub format: u32,
    /// The method's label.
    pub label: String,
    /// Which checkpoint was rendered: `best` or `final`.
    pub checkpoint: String,
    /// The training step of that checkpoint, when known.
    #[serde(default)]
    pub checkpoint_step: Option<u64>,
    /// The LPIPS backbone used (`alex`, `vgg`), `None` when LPIPS was not computed.
    #[serde(default)]
    pub lpips_net: Option<String>,
    /// Mean over views.
    pub mean: Metrics,
    /// Per view, in test-scene order.
    pub views: Vec<ViewMetrics>,
    /// The best step of the training curve (lowest average error; PSNR fallback).
    #[serde(default)]
    pub best: Option<BestStep>,
    /// The curve's evaluation at the baseline's best step, when a baseline was given.
    #[serde(default)]
    pub at_baseline: Option<AtBaselineStep>,
    /// Training wall time in seconds (last curve point), when the trainer recorded it
    /// (`OptimizeSplats` `record_wall_time: true`; a curve whose seconds are all 0 did not).
    #[serde(default)]
    pub train_seconds: Option<f64>,
    /// Number of Gaussians in the evaluated model.
    #[serde(default)]
    pub primitives: Option<u64>,
    /// Wall time of this evaluation (rendering + metrics), seconds, when recorded
    /// (`record_wall_time: true`; off by default so that outputs are byte-identical).
    #[serde(default)]
    pub eval_seconds: Option<f64>,
    /// The GPU adapter that rendered the views (name, driver, backend); absent for the CPU.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub device: Option<augsplat_splat::gpu::AdapterSummary>,
    /// Remarks for readers (missing LPIPS weights, fallbacks taken).
    #[serde(default)]
    pub notes: Vec<String>,
    /// Mean PSNR over the training views (dB), when `Evaluate` had the `train` input: with
    /// the held-out PSNR it shows a run that fits its photos but not the scene.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub train_psnr: Option<f64>,
}

/// Held-out PSNR below which a reconstruction is taken to have failed, dB.
pub const FAILED_PSNR_DB: f64 = 12.0;
/// Training PSNR this far above the held-out PSNR is taken as a failure to generalise, dB.
pub const OVERFIT_GAP_DB: f64 = 10.0;

/// Signs that a run has gone wrong, in words with the likely causes: held-out PSNR below
/// [`FAILED_PSNR_DB`], or training PSNR more than [`OVERFIT_GAP_DB`] above it. Empty for a
/// healthy run.
pub fn failure_signs(m: &EvalMetrics) -> Vec<String> {
    let mut signs = Vec::new();
    let psnr = m.mean.psnr;
    if psnr < FAILED_PSNR_DB {
        signs.push(format!(
            "held-out PSNR {psnr:.2} dB is below {FAILED_PSNR_DB} dB: the reconstruction has \
             failed. Likely causes: no sparse points to start from (see the import's and \
             TriangulatePoints' messages), near/far bounds that miss the scene, or wrong poses"
        ));
    }
    if let Some(t) = m.train_psnr {
        if t - psnr > OVERFIT_GAP_DB {
            signs.push(format!(
                "training PSNR {t:.2} dB is {:.1} dB above the held-out {psnr:.2} dB: the \
                 Gaussians fit the training photos but not the scene. Likely causes: wrong \
                 poses, no sparse points (Gaussians placed in front of the cameras), or bounds \
                 that miss the scene",
                t - psnr
            ));
        }
    }
    signs
}

impl EvalMetrics {
    /// The CSV table: header `view,width,height,psnr,ssim,lpips,mse,avg_error`, one row per
    /// view, then a `mean` row. Unavailable values are empty cells; infinite PSNR is `inf`.
    pub fn to_csv(&self) -> String {
        let mut out = String::from("view,width,height,psnr,ssim,lpips,mse,avg_error\n");
        let row = |out: &mut String, name: &str, w: String, h: String, m: &Metrics| {
            let opt = |v: Option<f64>| v.map(nonfinite::format_value).unwrap_or_default();
            out.push_str(&format!(
                "{},{},{},{},{},{},{},{}\n",
                csv_field(name),
                w,
                h,
                nonfinite::format_value(m.psnr),
                nonfinite::format_value(m.ssim),
                opt(m.lpips),
                nonfinite::format_value(m.mse),
                opt(m.avg_error)
            ));
        };
        for v in &self.views {
            row(
                &mut out,
                &v.name,
                v.width.to_string(),
                v.height.to_string(),
                &v.metrics,
            );
        }
        row(&mut out, "mean", String::new(), String::new(), &self.mean);
        out
    }
}

/// The PNG file name of a view: its name with every character other than ASCII letters,
/// digits, `-`, `_` and `.` replaced by `_` (and a leading `.` too), plus `.png`.
pub fn png_name(view: &str) -> String {
    let mut s: String = view
        .chars()
        .map(|c| {
            if c.is_ascii_alphanumeric() || matches!(c, '-' | '_' | '.') {
                c
            } else {
                '_'
            }
        })
        .collect();
    if s.is_empty() || s.starts_with('.') {
        s.insert(0, '_');
    }
    s.push_str(".png");
    s
}

/// Quotes a CSV field when it holds a comma, quote or line break.
pub fn csv_field(s: &str) -> String {
    if s.contains([',', '"', '\n', '\r']) {
        format!("\"{}\"", s.replace('"', "\"\""))
    } else {
        s.to_string()
    }
}

/// An eval folder read back: its metrics and (when present) its curve.
#[derive(Clone, Debug)]
pub struct EvalDir {
    /// The folder.
    pub dir: PathBuf,
    /// `metrics.json`.
    pub metrics: EvalMetrics,
    /// `curve.json`, when present.
    pub curve: Option<TrainingCurve>,
}

impl EvalDir {
    /// Reads an eval folder.
    pub fn load(dir: &Path) -> Result<EvalDir, ReportError> {
        let path = dir.join(files::METRICS);
        if !path.is_file() {
            return Err(ReportError::invalid(
                dir,
                format!("not an evaluation folder: no {}", files::METRICS),
            ));
        }
        let metrics: EvalMetrics = artifacts::read_json(&path)?;
        if metrics.format != FORMAT_VERSION {
            return Err(ReportError::invalid(
                &path,
                format!(
                    "metrics layout version {} (this build reads {FORMAT_VERSION})",
                    metrics.format
                ),
            ));
        }
        let curve_path = dir.join(files::CURVE);
        let curve = if curve_path.is_file() {
            Some(artifacts::read_json(&curve_path)?)
        } else {
            None
        };
        Ok(EvalDir {
            dir: dir.to_path_buf(),
            metrics,
            curve,
        })
    }

    /// Path of the render of view `name`.
    pub fn render_path(&self, name: &str) -> PathBuf {
        self.dir.join(files::RENDERS).join(png_name(name))
    }
    /// Path of the ground truth of view `name`.
    pub fn gt_path(&self, name: &str) -> PathBuf {
        self.dir.join(files::GT).join(png_name(name))
    }
    /// The evaluated checkpoint, when the folder has it (folders written before it was added
    /// do not).
    pub fn model_path(&self) -> Option<PathBuf> {
        Some(self.dir.join(files::MODEL)).filter(|p| p.is_file())
    }
    /// The held-out cameras as rendered (empty when the folder has no `cameras.json`).
    pub fn cameras(&self) -> Result<Vec<EvalCamera>, ReportError> {
        let p = self.dir.join(files::CAMERAS);
        if !p.is_file() {
            return Ok(Vec::new());
        }
        Ok(artifacts::read_json(&p)?)
    }
}

/// Finds eval folders: `path` itself when it holds `metrics.json`, otherwise its immediate
/// subfolders that do (sorted by name). Errors when none is found.
pub fn find_eval_dirs(path: &Path) -> Result<Vec<PathBuf>, ReportError> {
    if path.join(files::METRICS).is_file() {
        return Ok(vec![path.to_path_buf()]);
    }
    if !path.is_dir() {
        return Err(ReportError::invalid(
            path,
            "no such folder (expected an Evaluate output folder or a folder of them)",
        ));
    }
    let entries = std::fs::read_dir(path).map_err(|e| ReportError::io(path, e))?;
    let mut dirs = Vec::new();
    for entry in entries {
        let entry = entry.map_err(|e| ReportError::io(path, e))?;
        let p = entry.path();
        if p.join(files::METRICS).is_file() {
            dirs.push(p);
        }
    }
    dirs.sort();
    if dirs.is_empty() {
        return Err(ReportError::invalid(
            path,
            format!(
                "holds no {} (expected an Evaluate output folder or a folder of them)",
                files::METRICS
            ),
        ));
    }
    Ok(dirs)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn m(psnr: f64, lpips: Option<f64>) -> Metrics {
        Metrics {
            psnr,
            ssim: 0.5,
            mse: 0.01,
            lpips,
            avg_error: lpips.map(|l| (0.01 * 0.5f64.sqrt() * l).cbrt()),
        }
    }

    #[test]
    fn infinite_psnr_round_trips_through_json_and_csv() {
        let e = EvalMetrics {
            format: FORMAT_VERSION,
            label: "a,b".into(),
            checkpoint: "best".into(),
            checkpoint_step: Some(3),
            train_psnr: None,
            lpips_net: None,
            mean: m(f64::INFINITY, None),
            views: vec![ViewMetrics {
                name: "v\"1".into(),
                width: 4,
                height: 2,
                metrics: m(f64::INFINITY, None),
            }],
            best: None,
            at_baseline: None,
            train_seconds: None,
            primitives: Some(10),
            eval_seconds: Some(0.5),
            device: None,
            notes: vec![],
        };
        let text = serde_json::to_string(&e).unwrap();
        assert!(text.contains("\"psnr\":\"inf\""), "{text}");
        let back: EvalMetrics = serde_json::from_str(&text).unwrap();
        assert_eq!(back.mean.psnr, f64::INFINITY);
        assert_eq!(back, e);
        let csv = e.to_csv();
        let lines: Vec<&str> = csv.lines().collect();
        assert_eq!(lines[0], "view,width,height,psnr,ssim,lpips,mse,avg_error");
        assert_eq!(lines[1], "\"v\"\"1\",4,2,inf,0.5,,0.01,");
        assert_eq!(lines[2], "mean,,,inf,0.5,,0.01,");
    }

    #[test]
    fn view_file_names_are_safe() {
        assert_eq!(png_name("DSCF5568"), "DSCF5568.png");
        assert_eq!(png_name("a/b c"), "a_b_c.png");
        assert_eq!(png_name("../x"), "_.._x.png");
        assert_eq!(png_name(""), "_.png");
    }

    #[test]
    fn mean_needs_every_view_for_optional_metrics() {
        let all = Metrics::mean(&[m(10.0, Some(0.2)), m(20.0, Some(0.4))]);
        assert_eq!(all.psnr, 15.0);
        assert!((all.lpips.unwrap() - 0.3).abs() < 1e-12);
        let some = Metrics::mean(&[m(10.0, Some(0.2)), m(20.0, None)]);
        assert_eq!(some.lpips, None);
        assert_eq!(some.avg_error, None);
        assert!(Metrics::mean(&[]).psnr.is_nan());
    }

    #[test]
    fn bad_metrics_files_name_the_path() {
        let dir = tempfile::tempdir().unwrap();
        let err = EvalDir::load(dir.path()).unwrap_err().to_string();
        assert!(err.contains("not an evaluation folder"), "{err}");
        std::fs::write(dir.path().join(files::METRICS), "{").unwrap();
        let err = EvalDir::load(dir.path()).unwrap_err().to_string();
        assert!(err.contains("metrics.json"), "{err}");
        assert!(find_eval_dirs(&dir.path().join("nope")).is_err());
    }
}
