//! The `EvaluateEnsemble` node: measures each radiance-field ensemble member and the
//! per-pixel median of the members (the target AugSplat distils) on the held-out views.
//!
//! Inputs are the members' renders at the test poses (`RenderField` at the poses of
//! `ScenePoses` on the test split), so the fields are rendered once and the median uses the
//! same convention as `AggregateEnsemble` (per pixel and channel; the mean of the two middle
//! values for an even M). Renders are clamped to [0, 1] before measuring, as in `Evaluate`.

use crate::evalset::{files, png_name, Metrics, ViewMetrics};
use crate::evaluate::{load_lpips, measure, LpipsNet};
use crate::ReportError;
use augsplat_augment::aggregate::median_in_place;
use augsplat_core::artifacts::{self, RenderSet};
use augsplat_core::{image, ImageF32, Scene};
use augsplat_graph::{InputDecl, Node, NodeError, RunContext, Threads};
use serde::{Deserialize, Serialize};
use std::path::{Path, PathBuf};

/// Layout version of the ensemble `metrics.json`.
pub const ENSEMBLE_FORMAT_VERSION: u32 = 1;

/// Args of [`EvaluateEnsembleNode`].
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct EvaluateEnsembleArgs {
    /// Label of the median in tables (default `Ensemble median`).
    pub label: String,
    /// LPIPS backbone (`None`: no LPIPS, hence no average error).
    pub lpips: LpipsNet,
}

impl Default for EvaluateEnsembleArgs {
    fn default() -> Self {
        EvaluateEnsembleArgs {
            label: "Ensemble median".into(),
            lpips: LpipsNet::Alex,
        }
    }
}

/// One set of per-view metrics with their mean.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct MeasuredSet {
    /// Mean over views.
    pub mean: Metrics,
    /// Per view, in test-scene order.
    pub views: Vec<ViewMetrics>,
}

/// The contents of the ensemble `metrics.json`.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct EnsembleMetrics {
    /// Layout version ([`ENSEMBLE_FORMAT_VERSION`]).
    pub format: u32,
    /// Label of the median.
    pub label: String,
    /// Number of members M.
    pub members: usize,
    /// LPIPS backbone used, `None` when LPIPS was not computed.
    pub lpips_net: Option<String>,
    /// The per-pixel median of the members' renders.
    pub median: MeasuredSet,
    /// Each member, in input order.
    pub member: Vec<MeasuredSet>,
    /// Mean over members of each member's mean metrics (LPIPS and average error only when
    /// every member has them).
    pub member_mean: Metrics,
    /// Remarks for readers (missing LPIPS weights).
    pub notes: Vec<String>,
}

/// `EvaluateEnsemble`: inputs `members` (a list of `RenderField` outputs rendered at the test
/// views, e.g. via `ScenePoses`), `test` (the held-out scene folder), optional `lpips`; output
/// `eval`: `metrics.json` ([`EnsembleMetrics`]), `metrics.csv` (one row per view and source),
/// `renders/<view>.png` (the median) and `gt/<view>.png`.
pub struct EvaluateEnsembleNode;

impl Node for EvaluateEnsembleNode {
    const KIND: &'static str = "EvaluateEnsemble";
    const VERSION: u32 = 3;
    type Args = EvaluateEnsembleArgs;

    fn inputs(_: &EvaluateEnsembleArgs) -> Vec<InputDecl> {
        vec![
            InputDecl::many("members"),
            InputDecl::one("test"),
            InputDecl::optional("lpips"),
        ]
    }
    fn outputs(_: &EvaluateEnsembleArgs) -> Vec<String> {
        vec!["eval".into()]
    }
    fn threads(_: &EvaluateEnsembleArgs) -> Threads {
        Threads::All
    }
    fn validate(_: &EvaluateEnsembleArgs) -> Result<(), String> {
        Ok(())
    }
    fn run(args: &EvaluateEnsembleArgs, ctx: &mut RunContext) -> Result<(), NodeError> {
        let members: Vec<PathBuf> = ctx.input_list("members")?.to_vec();
        let test = ctx.input("test")?.to_path_buf();
        let lpips_input = ctx.optional_input("lpips").map(Path::to_path_buf);
        let out = ctx.output("eval")?.to_path_buf();
        let (model, note) = load_lpips(args.lpips, lpips_input.as_deref())?;
        if let Some(n) = &note {
            ctx.log(n);
        }
        let lpips = model.as_ref().map(|(m, b)| (m, b.name().to_string()));
        let metrics = evaluate_ensemble(
            &args.label,
            &members,
            &test,
            lpips.as_ref().map(|(m, n)| (*m, n.as_str())),
            note,
            &out,
            &|done, total| ctx.progress(done, total, "views"),
        )?;
        ctx.log(format!(
            "{} members: median PSNR {:.3} dB, SSIM {:.4}; members' mean PSNR {:.3} dB (min {:.3}, max {:.3})",
            metrics.members,
            metrics.median.mean.psnr,
            metrics.median.mean.ssim,
            metrics.member_mean.psnr,
            metrics.member.iter().map(|m| m.mean.psnr).fold(f64::INFINITY, f64::min),
            metrics.member.iter().map(|m| m.mean.psnr).fold(f64::NEG_INFINITY, f64::max),
        ));
        Ok(())
    }
}

/// Reads the RGB render of view `name` from a member's render folder, as an interleaved image.
fn read_member_view(dir: &Path, set: &RenderSet, name: &str) -> Result<ImageF32, ReportError> {
    let json = dir.join(artifacts::files::RENDERS);
    let view = set.views.iter().find(|v| v.name == name).ok_or_else(|| {
        ReportError::invalid(&json, format!("has no render of the test view {name:?}"))
    })?;
    Ok(image::read_rgb(&dir.join(&view.file))?)
}

/// Measures every member and their per-pixel median on the views of the scene folder `test`,
/// writes the eval folder into `out` and returns its metrics. `lpips` is the model and its
/// backbone's name.
pub fn evaluate_ensemble(
    label: &str,
    members: &[PathBuf],
    test: &Path,
    lpips: Option<(&augsplat_metrics::lpips::Lpips, &str)>,
    lpips_note: Option<String>,
    out: &Path,
    progress: &dyn Fn(u64, u64),
) -> Result<EnsembleMetrics, ReportError> {
    if members.is_empty() {
        return Err(ReportError::Message(
            "input `members` lists no render sets".into(),
        ));
    }
    let scene = Scene::load(test)?;
    if scene.views.is_empty() {
        return Err(ReportError::invalid(test, "the test scene has no views"));
    }
    let sets: Vec<RenderSet> = members
        .iter()
        .map(|d| artifacts::read_json(&d.join(artifacts::files::RENDERS)))
        .collect::<Result<_, _>>()?;
    let renders_dir = out.join(files::RENDERS);
    let gt_dir = out.join(files::GT);
    for d in [&renders_dir, &gt_dir] {
        std::fs::create_dir_all(d).map_err(|e| ReportError::io(d, e))?;
    }
    let m = members.len();
    let mut member_views: Vec<Vec<ViewMetrics>> = vec![Vec::new(); m];
    let mut median_views = Vec::with_capacity(scene.views.len());
    let mut notes: Vec<String> = lpips_note.into_iter().collect();
    let mut scratch = vec![0f32; m];
    for (i, view) in scene.views.iter().enumerate() {
        let gt = scene.load_image(test, i)?;
        let mut imgs = Vec::with_capacity(m);
        for (dir, set) in members.iter().zip(&sets) {
            let mut img = read_member_view(dir, set, &view.name)?;
            if (img.width, img.height) != (gt.width, gt.height) {
                return Err(ReportError::invalid(
                    dir.join(artifacts::files::RENDERS),
                    format!(
                        "the render of view {:?} is {}×{}, its ground truth {}×{} (render the test poses at the images' resolution)",
                        view.name, img.width, img.height, gt.width, gt.height
                    ),
                ));
            }
            for v in &mut img.data {
                *v = v.clamp(0.0, 1.0);
            }
            imgs.push(img);
        }
        let mut median = ImageF32::from_vec(gt.width, gt.height, 3, vec![0.0; gt.data.len()]);
        for (k, out_v) in median.data.iter_mut().enumerate() {
            for (s, img) in scratch.iter_mut().zip(&imgs) {
                *s = img.data[k];
            }
            *out_v = median_in_place(&mut scratch);
        }
        let lp = match lpips {
            Some((model, _)) => match model
                .net()
                .check_size(gt.width as usize, gt.height as usize)
            {
                Ok(()) => Some(model),
                Err(msg) => {
                    let n = format!("LPIPS unavailable: {msg}; average error unavailable");
                    if !notes.contains(&n) {
                        notes.push(n);
                    }
                    None
                }
            },
            None => None,
        };
        let view_metrics = |metrics: Metrics| ViewMetrics {
            name: view.name.clone(),
            width: gt.width,
            height: gt.height,
            metrics,
        };
        for (j, img) in imgs.iter().enumerate() {
            let mm = measure(img, &gt, lp).map_err(|e| {
                ReportError::Message(format!("member {j}, view {:?}: {e}", view.name))
            })?;
            member_views[j].push(view_metrics(mm));
        }
        let mm = measure(&median, &gt, lp)
            .map_err(|e| ReportError::Message(format!("median, view {:?}: {e}", view.name)))?;
        median_views.push(view_metrics(mm));
        let file = png_name(&view.name);
        image::write_png(&renders_dir.join(&file), &median)?;
        image::write_png(&gt_dir.join(&file), &gt)?;
        progress(i as u64 + 1, scene.views.len() as u64);
    }
    let measured = |views: Vec<ViewMetrics>| MeasuredSet {
        mean: Metrics::mean(&views.iter().map(|v| v.metrics.clone()).collect::<Vec<_>>()),
        views,
    };
    let member: Vec<MeasuredSet> = member_views.into_iter().map(measured).collect();
    let member_mean = Metrics::mean(&member.iter().map(|s| s.mean.clone()).collect::<Vec<_>>());
    let metrics = EnsembleMetrics {
        format: ENSEMBLE_FORMAT_VERSION,
        label: if label.is_empty() {
            "Ensemble median".into()
        } else {
            label.into()
        },
        members: m,
        lpips_net: lpips.map(|(_, n)| n.to_string()),
        median: measured(median_views),
        member,
        member_mean,
        notes,
    };
    artifacts::write_json(&out.join(files::METRICS), &metrics)?;
    let csv = out.join(files::METRICS_CSV);
    std::fs::write(&csv, ensemble_csv(&metrics)).map_err(|e| ReportError::io(&csv, e))?;
    Ok(metrics)
}

/// `source,view,width,height,psnr,ssim,lpips,mse,avg_error`: the median's rows, then each
/// member's (`member0`, `member1`, …).
pub fn ensemble_csv(m: &EnsembleMetrics) -> String {
    let opt = |v: Option<f64>| v.map(|x| format!("{x}")).unwrap_or_default();
    let mut s = String::from("source,view,width,height,psnr,ssim,lpips,mse,avg_error\n");
    let sources = std::iter::once(("median".to_string(), &m.median)).chain(
        m.member
            .iter()
            .enumerate()
            .map(|(j, set)| (format!("member{j}"), set)),
    );
    for (src, set) in sources {
        for v in &set.views {
            s.push_str(&format!(
                "{src},{},{},{},{},{},{},{},{}\n",
                crate::evalset::csv_field(&v.name),
                v.width,
                v.height,
                v.metrics.psnr,
                v.metrics.ssim,
                opt(v.metrics.lpips),
                v.metrics.mse,
                opt(v.metrics.avg_error)
            ));
        }
    }
    s
}
