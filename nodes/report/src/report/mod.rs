//! The report: one self-contained HTML page (inline SVG plots, base64 PNG images, no external
//! resources; the only script is the 3-D viewer's) and a Markdown summary, built from eval
//! folders and optionally a synthetic supervision set and the training scene.
//!
//! Sections: results tables (evaluated checkpoint; best step of each training curve; every
//! method at the baseline's best step) with the best value per column marked; per-view
//! metrics; the 3-D viewer (every evaluated model side by side on one camera, the cameras as
//! frusta, the ground truth at held-out cameras; see [`crate::viewer`]); training curves (PSNR, SSIM, LPIPS, average error vs step); ground truth vs methods
//! side by side with zoomed crops where the first method errs most; synthetic views with their
//! confidence maps; wall time per stage and run time vs error across runs with the Pareto front
//! (when the evaluations carry their wall times, see [`TIMES_ELSEWHERE`]).

use crate::compare::display_labels;
use crate::evalset::{failure_signs, EvalDir, MetricKey, Metrics};
use crate::html::{self, escape, MetricRow, MetricTable};
use crate::svg::{self, Chart, Series};
use crate::ReportError;
use augsplat_core::artifacts;
use std::fmt::Write as _;
use std::path::Path;

mod images;
mod timing;

use images::{image_section, synthetic_section};
pub use timing::TIMES_ELSEWHERE;
use timing::{any_times, time_section};

/// What to put in a report.
#[derive(Clone, Debug)]
pub struct ReportOptions {
    /// Page title.
    pub title: String,
    /// Test views shown side by side (the first ones of the first run).
    pub max_views: usize,
    /// Synthetic views shown (evenly spaced over the set).
    pub max_synthetic: usize,
    /// Display width of full images, pixels (images are downscaled to fit).
    pub image_width: u32,
    /// Display size of zoomed crops, pixels (approximate: integer zoom).
    pub crop_size: u32,
    /// Embed the 3-D viewer (when the eval folders hold their models).
    pub viewer: bool,
    /// Cap on the Gaussians per viewer pane (the most opaque are kept).
    pub viewer_max_gaussians: usize,
    /// The training scene folder, whose cameras the viewer draws.
    pub train_scene: Option<std::path::PathBuf>,
    /// The scene gate's decision and evidence, when the pipeline has one.
    pub gate: Option<crate::gate::GateReport>,
    /// Why each evaluation that a gate skipped was skipped (one entry per such evaluation).
    pub gated_evals: Vec<String>,
}

impl Default for ReportOptions {
    fn default() -> Self {
        ReportOptions {
            title: "augsplat report".into(),
            max_views: 3,
            max_synthetic: 4,
            image_width: 320,
            crop_size: 160,
            viewer: true,
            viewer_max_gaussians: crate::viewer::DEFAULT_MAX_GAUSSIANS,
            train_scene: None,
            gate: None,
            gated_evals: Vec::new(),
        }
    }
}

/// The built report.
#[derive(Clone, Debug, PartialEq)]
pub struct BuiltReport {
    /// `index.html`.
    pub html: String,
    /// `summary.md`.
    pub markdown: String,
}

const CSS: &str = "body{font-family:system-ui,sans-serif;margin:24px auto;max-width:1200px;color:#222;padding:0 16px}\
h1{font-size:1.6em}h2{border-bottom:1px solid #ccc;padding-bottom:4px;margin-top:2em}\
table.metrics{border-collapse:collapse;margin:12px 0}table.metrics caption{text-align:left;font-weight:bold;margin-bottom:4px}\
table.metrics th,table.metrics td{border:1px solid #ccc;padding:4px 10px;text-align:right}\
table.metrics th[scope=row],table.metrics thead th:first-child{text-align:left}td.best{background:#e6f4e6}.detail{color:#777;font-weight:normal;font-size:.9em}\
.plots{display:flex;flex-wrap:wrap;gap:12px}.note{color:#555;font-size:.92em}.warning{border:2px solid #c60;background:#fff4e5;padding:4px 12px;margin:8px 0}\
figure{margin:0;display:inline-block;vertical-align:top;text-align:center}figcaption{font-size:.85em;color:#444}\
.row{display:flex;flex-wrap:wrap;gap:8px;align-items:flex-start;margin-bottom:8px}img.px{image-rendering:pixelated}";

/// Builds the report from eval folders (in the order given; the first is the reference for
/// crops) and an optional synthetic set folder.
pub fn build_report(
    opts: &ReportOptions,
    evals: &[EvalDir],
    synthetic: Option<&Path>,
) -> Result<BuiltReport, ReportError> {
    if evals.is_empty() {
        return Err(ReportError::Message(
            "a report needs at least one evaluation (input `evals` is empty)".into(),
        ));
    }
    // A run that shows signs of failure is marked in every table and explained at the top.
    let labels: Vec<String> = display_labels(evals)
        .into_iter()
        .zip(evals)
        .map(|(l, e)| {
            if failure_signs(&e.metrics).is_empty() {
                l
            } else {
                format!("⚠ {l}")
            }
        })
        .collect();
    let mut body = String::new();
    let mut md = format!("# {}\n\n", opts.title.replace('\n', " "));
    let mut warnings: Vec<String> = evals
        .iter()
        .zip(&labels)
        .flat_map(|(e, l)| {
            failure_signs(&e.metrics)
                .into_iter()
                .map(move |s| format!("{l}: {s}"))
        })
        .collect();
    let triangulation = opts.train_scene.as_deref().and_then(triangulation_record);
    if let Some(w) = triangulation.as_ref().and_then(|r| r.warning.clone()) {
        warnings.insert(0, w);
    }
    if !warnings.is_empty() {
        body.push_str("<div class=\"warning\" id=\"warnings\"><h2>Warnings</h2><ul>");
        md.push_str("**Warnings**\n\n");
        for w in &warnings {
            let _ = write!(body, "<li>{}</li>", escape(w));
            let _ = writeln!(md, "- ⚠ {w}");
        }
        body.push_str("</ul></div>");
        md.push('\n');
    }

    // --- notes -----------------------------------------------------------------------------
    // An evaluation without LPIPS says so in up to three notes (no weights, hence no average
    // error, hence a best step by PSNR): the report says it once, with how to get them.
    let mut per_method: Vec<(&str, &str)> = Vec::new();
    let mut without_lpips: Vec<&str> = Vec::new();
    let mut lpips_off_by_choice = true;
    // When no evaluation carries wall times, the wall-time section says so once: the
    // methods' "not recorded" notes would repeat it.
    let times_recorded = any_times(evals);
    for (e, label) in evals.iter().zip(&labels) {
        let no_lpips = e.metrics.lpips_net.is_none();
        if no_lpips {
            without_lpips.push(label);
            lpips_off_by_choice &= e.metrics.notes.iter().any(|n| n.contains("(lpips: None)"));
        }
        for n in &e.metrics.notes {
            let said_once = (no_lpips && is_lpips_note(n))
                || (!times_recorded && n.contains("wall time not recorded"));
            if !said_once {
                per_method.push((label, n));
            }
        }
        if let Some(b) = &e.metrics.best {
            if let Some(n) = &b.note {
                if !(no_lpips && is_lpips_note(n)) {
                    per_method.push((label, n));
                }
            }
        }
    }
    let mut notes = Vec::new();
    if let Some(r) = &triangulation {
        notes.push(format!(
            "Sparse points triangulated from the training photos: {}",
            r.report.summary()
        ));
    }
    if !without_lpips.is_empty() {
        notes.push(lpips_line(&without_lpips, lpips_off_by_choice));
    }
    notes.extend(group_notes(&per_method));

    // --- tables ----------------------------------------------------------------------------
    let tables = results_tables(evals, &labels);
    let _ = write!(body, "<h2 id=\"results\">Results</h2>");
    for t in &tables {
        body.push_str(&t.to_html());
        md.push_str(&t.to_markdown());
        md.push('\n');
    }
    body.push_str("<p class=\"note\">Best value per column in bold (when at least two methods have one). ↑: higher is better, ↓: lower is better. Average error = (MSE·√(1−SSIM)·LPIPS)<sup>1/3</sup>.</p>");
    if !notes.is_empty() {
        body.push_str("<ul class=\"note\">");
        md.push_str("Notes:\n\n");
        for n in &notes {
            let _ = write!(body, "<li>{}</li>", escape(n));
            let _ = writeln!(md, "- {n}");
        }
        body.push_str("</ul>");
        md.push('\n');
    }
    body.push_str(&per_view_table(evals, &labels));
    gate_section(opts, &mut body, &mut md);

    // --- viewer ----------------------------------------------------------------------------
    let viewer = if opts.viewer {
        viewer_section(opts, evals, &labels)?
    } else {
        None
    };
    let has_viewer = viewer.is_some();
    if let Some(section) = viewer {
        body.push_str(&section);
    }

    // --- curves ----------------------------------------------------------------------------
    body.push_str("<h2 id=\"curves\">Training curves</h2><div class=\"plots\">");
    for (key, title) in [
        (MetricKey::Psnr, "PSNR (dB)"),
        (MetricKey::Ssim, "SSIM"),
        (MetricKey::Lpips, "LPIPS"),
        (MetricKey::AvgError, "Average error"),
    ] {
        let series = curve_series(evals, &labels, key, |p| p.step as f64);
        body.push_str(&svg::line_chart(
            &Chart::new(&format!("{title} vs step"), "step", title),
            &series,
        ));
    }
    body.push_str("</div>");

    // --- images ----------------------------------------------------------------------------
    body.push_str(&image_section(opts, evals, &labels)?);
    if let Some(dir) = synthetic {
        body.push_str(&synthetic_section(opts, dir)?);
    }

    // --- time ------------------------------------------------------------------------------
    body.push_str(&time_section(evals, &labels, &mut md));

    let html = format!(
        "<!DOCTYPE html>\n<html lang=\"en\"><head><meta charset=\"utf-8\"><title>{t}</title><style>{CSS}</style></head><body><h1>{t}</h1><p class=\"note\">{n} run(s): {runs}. Generated by augsplat; self-contained ({what}).</p>{body}</body></html>\n",
        t = escape(&opts.title),
        what = if has_viewer {
            "no external files; the one script is the 3-D viewer"
        } else {
            "no scripts, no external files"
        },
        n = evals.len(),
        runs = escape(&labels.join(", ")),
    );
    Ok(BuiltReport { html, markdown: md })
}

/// The 3-D viewer section: one pane per eval folder that holds its model, the held-out
/// cameras of the first folder that has them (with their ground truth), and the training
/// cameras of `opts.train_scene`. `None` when no folder holds a model.
fn viewer_section(
    opts: &ReportOptions,
    evals: &[EvalDir],
    labels: &[String],
) -> Result<Option<String>, ReportError> {
    use crate::viewer::{self, ViewerCamera, ViewerModel};
    let mut models = Vec::new();
    for (e, label) in evals.iter().zip(labels) {
        if let Some(p) = e.model_path() {
            let g = augsplat_splat::read_ply(&p)?;
            models.push(ViewerModel {
                label: label.clone(),
                packed: viewer::pack(&g, opts.viewer_max_gaussians),
            });
        }
    }
    if models.is_empty() {
        return Ok(None);
    }
    let mut cameras = Vec::new();
    if let Some(dir) = &opts.train_scene {
        let scene = augsplat_core::Scene::load(dir)?;
        for v in scene.views {
            cameras.push(ViewerCamera {
                name: v.name,
                held_out: false,
                camera: v.camera,
                ground_truth: None,
            });
        }
    }
    for e in evals {
        let held = e.cameras()?;
        if held.is_empty() {
            continue;
        }
        for c in held {
            let gt = e.gt_path(&c.name);
            let ground_truth = match std::fs::read(&gt) {
                Ok(bytes) => Some(format!("data:image/png;base64,{}", html::base64(&bytes))),
                Err(_) => None,
            };
            cameras.push(ViewerCamera {
                name: c.name,
                held_out: true,
                camera: c.camera,
                ground_truth,
            });
        }
        break;
    }
    let mut out = String::from("<h2 id=\"viewer\">3-D viewer</h2>");
    out.push_str("<p class=\"note\">Each evaluated model (the checkpoint the tables measure), side by side on one camera, with degree-0 colour. Pick a camera, or drag in any pane: the panes move together.</p>");
    out.push_str(&viewer::viewer_section(&models, &cameras, [0.0; 3]));
    Ok(Some(out))
}

/// Whether an evaluation's note is about LPIPS being unavailable (or the average error and the
/// best-step choice that depend on it).
/// One series per evaluation: `key` along its training curve against `x` of each point
/// (points without the metric left out).
fn curve_series(
    evals: &[EvalDir],
    labels: &[String],
    key: MetricKey,
    x: impl Fn(&artifacts::CurvePoint) -> f64,
) -> Vec<Series> {
    evals
        .iter()
        .zip(labels)
        .map(|(e, label)| Series {
            label: label.clone(),
            points: e
                .curve
                .as_ref()
                .map(|c| {
                    c.points
                        .iter()
                        .filter_map(|p| Some((x(p), Metrics::from_curve_point(p).get(key)?)))
                        .collect()
                })
                .unwrap_or_default(),
        })
        .collect()
}

fn is_lpips_note(note: &str) -> bool {
    note.starts_with("LPIPS") || note.contains("no LPIPS weights")
}

/// The scene gate's section: which evaluations it skipped, its decision and its evidence.
fn gate_section(opts: &ReportOptions, body: &mut String, md: &mut String) {
    if opts.gate.is_none() && opts.gated_evals.is_empty() {
        return;
    }
    body.push_str("<h2 id=\"gate\">Scene gate</h2>");
    if !opts.gated_evals.is_empty() {
        let mut reasons = opts.gated_evals.clone();
        reasons.dedup();
        let line = format!(
            "{} evaluation(s) skipped by the gate: {}",
            opts.gated_evals.len(),
            reasons.join("; ")
        );
        let _ = write!(body, "<p class=\"note\">{}</p>", escape(&line));
        let _ = writeln!(md, "{line}\n");
    }
    if let Some(g) = &opts.gate {
        let gmd = g.to_markdown();
        md.push_str(&gmd);
        md.push('\n');
        let _ = write!(
            body,
            "<p><b>Decision: {}.</b> {}</p><table class=\"metrics\"><thead><tr><th>rehearsal</th><th>{}</th><th>vs baseline</th><th>PSNR</th><th>SSIM</th></tr></thead><tbody>",
            escape(&g.verdict()),
            escape(&g.reason),
            escape(&g.metric)
        );
        for e in g.rows() {
            let _ = write!(
                body,
                "<tr><th scope=\"row\">{}</th><td>{:.4}</td><td>{:+.1} %</td><td>{:.2}</td><td>{:.3}</td></tr>",
                escape(&e.label),
                e.error,
                100.0 * e.relative,
                e.metrics.psnr,
                e.metrics.ssim
            );
        }
        let _ = write!(
            body,
            "</tbody></table><p class=\"note\">Measured on training views {} left out of the rehearsals; no held-out view is read.</p>",
            escape(&g.views.join(", "))
        );
    }
}

/// The one line that replaces the LPIPS notes of the evaluations in `labels`.
fn lpips_line(labels: &[&str], by_choice: bool) -> String {
    if by_choice {
        format!(
            "{}: LPIPS and the average error not computed (lpips: None); best steps chosen by PSNR",
            labels.join(", ")
        )
    } else {
        format!(
            "{}: LPIPS and the average error need the LPIPS weights — {}; the ready pipelines then connect them (`Installed(\"lpips\")`), so rerun",
            labels.join(", "),
            crate::evaluate::LPIPS_INSTALL_HINT
        )
    }
}

/// The results tables: evaluated checkpoint; best curve step; at the baseline's best step.
pub fn results_tables(evals: &[EvalDir], labels: &[String]) -> Vec<MetricTable> {
    let cols = MetricKey::TABLE.to_vec();
    let values = |m: &Metrics| cols.iter().map(|k| m.get(*k)).collect::<Vec<_>>();
    let mut tables = Vec::new();
    tables.push(MetricTable {
        caption: "Evaluated checkpoint (full resolution, mean over test views)".into(),
        columns: cols.clone(),
        rows: evals
            .iter()
            .zip(labels)
            .map(|(e, label)| MetricRow {
                label: label.clone(),
                detail: match e.metrics.checkpoint_step {
                    Some(s) => format!("{} @ step {s}", e.metrics.checkpoint),
                    None => e.metrics.checkpoint.clone(),
                },
                values: values(&e.metrics.mean),
            })
            .collect(),
    });
    let best_rows: Vec<MetricRow> = evals
        .iter()
        .zip(labels)
        .filter_map(|(e, label)| {
            let b = e.metrics.best.as_ref()?;
            Some(MetricRow {
                label: label.clone(),
                detail: format!("step {} (by {})", b.step, b.criterion.describe()),
                values: values(&Metrics::from_curve_point(&b.point)),
            })
        })
        .collect();
    if !best_rows.is_empty() {
        tables.push(MetricTable {
            caption: "Best checkpoint of each training curve (lowest average error)".into(),
            columns: cols.clone(),
            rows: best_rows,
        });
    }
    // At the baseline's best step: methods evaluated with a baseline, plus the baseline itself
    // (recognised by its label) at its own best step.
    if let Some(first) = evals.iter().find_map(|e| e.metrics.at_baseline.as_ref()) {
        let base_label = &first.baseline_label;
        let base_step = first.baseline_best.step;
        let mut rows = Vec::new();
        for (e, label) in evals.iter().zip(labels) {
            if let Some(a) = &e.metrics.at_baseline {
                let mut detail = format!("step {}", a.step);
                if !a.exact {
                    detail.push_str(&format!(" (latest before {})", a.baseline_best.step));
                }
                rows.push(MetricRow {
                    label: label.clone(),
                    detail,
                    values: values(&Metrics::from_curve_point(&a.point)),
                });
            } else if e.metrics.label == *base_label
                || e.curve
                    .as_ref()
                    .is_some_and(|c| c.label == *base_label && !c.label.is_empty())
            {
                if let Some(b) = &e.metrics.best {
                    rows.push(MetricRow {
                        label: label.clone(),
                        detail: format!("baseline, step {}", b.step),
                        values: values(&Metrics::from_curve_point(&b.point)),
                    });
                }
            }
        }
        tables.push(MetricTable {
            caption: format!(
                "All methods at the baseline's best step ({base_label}, step {base_step})"
            ),
            columns: cols,
            rows,
        });
    }
    tables
}

fn per_view_table(evals: &[EvalDir], labels: &[String]) -> String {
    let views: Vec<&str> = evals[0]
        .metrics
        .views
        .iter()
        .map(|v| v.name.as_str())
        .collect();
    if views.is_empty() {
        return String::new();
    }
    let mut out = String::from("<details><summary>Per-view metrics (PSNR / SSIM / LPIPS)</summary><table class=\"metrics\"><thead><tr><th>View</th>");
    for l in labels {
        let _ = write!(out, "<th>{}</th>", escape(l));
    }
    out.push_str("</tr></thead><tbody>");
    for name in views {
        let _ = write!(out, "<tr><th scope=\"row\">{}</th>", escape(name));
        for e in evals {
            let cell = match e.metrics.views.iter().find(|v| v.name == name) {
                Some(v) => format!(
                    "{} / {} / {}",
                    MetricKey::Psnr.format(v.metrics.psnr),
                    MetricKey::Ssim.format(v.metrics.ssim),
                    v.metrics
                        .lpips
                        .map(|l| MetricKey::Lpips.format(l))
                        .unwrap_or_else(|| "—".into())
                ),
                None => "—".into(),
            };
            let _ = write!(out, "<td>{}</td>", escape(&cell));
        }
        out.push_str("</tr>");
    }
    out.push_str("</tbody></table></details>");
    out
}

/// The notes of the methods, one line per distinct note with the methods it concerns
/// (`3DGS, Staged, Dual: LPIPS … not computed …`), in order of first appearance: the same
/// missing-weights note is not repeated for every method.
pub fn group_notes(per_method: &[(&str, &str)]) -> Vec<String> {
    let mut groups: Vec<(&str, Vec<&str>)> = Vec::new();
    for &(label, note) in per_method {
        match groups.iter_mut().find(|(n, _)| *n == note) {
            Some((_, labels)) => {
                if !labels.contains(&label) {
                    labels.push(label);
                }
            }
            None => groups.push((note, vec![label])),
        }
    }
    groups
        .into_iter()
        .map(|(note, labels)| format!("{}: {note}", labels.join(", ")))
        .collect()
}

/// The triangulation record beside a training scene's points, when the points were
/// triangulated (`TriangulatePoints`); an unreadable record is left out.
fn triangulation_record(train: &Path) -> Option<augsplat_scene::triangulate::TriangulationRecord> {
    let path = train.join(augsplat_scene::triangulate::RECORD_FILE);
    path.is_file()
        .then(|| artifacts::read_json(&path).ok())
        .flatten()
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::evalset::{EvalMetrics, FORMAT_VERSION};

    fn eval(label: &str, psnr: f64, train_psnr: Option<f64>) -> EvalDir {
        EvalDir {
            dir: std::path::PathBuf::from(format!("/evals/{label}")),
            metrics: EvalMetrics {
                format: FORMAT_VERSION,
                label: label.into(),
                checkpoint: "best".into(),
                checkpoint_step: Some(100),
                lpips_net: None,
                mean: Metrics {
                    psnr,
                    ssim: 0.5,
                    lpips: None,
                    mse: 10f64.powf(-psnr / 10.0),
                    avg_error: None,
                },
                views: vec![],
                best: None,
                at_baseline: None,
                train_seconds: None,
                primitives: None,
                eval_seconds: None,
                device: None,
                notes: vec![],
                train_psnr,
            },
            curve: None,
        }
    }

    #[test]
    fn failed_runs_are_marked_and_explained() {
        let opts = ReportOptions {
            viewer: false,
            ..ReportOptions::default()
        };
        let healthy = [eval("3DGS", 22.0, Some(28.0)), eval("Dual", 23.0, None)];
        let built = build_report(&opts, &healthy, None).unwrap();
        assert!(!built.markdown.contains("Warnings") && !built.markdown.contains('⚠'));
        // Below 12 dB held out; 12.5 dB held out but 25 dB on the training views.
        let failed = [
            eval("3DGS", 9.7, Some(14.0)),
            eval("Dual", 12.5, Some(25.0)),
        ];
        let built = build_report(&opts, &failed, None).unwrap();
        let md = &built.markdown;
        assert!(md.contains("**Warnings**"), "{md}");
        assert!(md.contains("| ⚠ 3DGS") && md.contains("| ⚠ Dual"), "{md}");
        assert!(md.contains("held-out PSNR 9.70 dB is below 12 dB"), "{md}");
        assert!(
            md.contains("training PSNR 25.00 dB is 12.5 dB above"),
            "{md}"
        );
        assert!(md.contains("no sparse points"), "{md}");
        assert!(built.html.contains("id=\"warnings\""));
    }

    #[test]
    fn the_same_note_of_several_methods_is_one_line() {
        let lines = group_notes(&[
            ("3DGS", "no LPIPS weights"),
            ("3DGS", "wall time not recorded"),
            ("Staged", "no LPIPS weights"),
            ("Dual", "no LPIPS weights"),
            ("Dual", "best step chosen by PSNR"),
        ]);
        assert_eq!(
            lines,
            [
                "3DGS, Staged, Dual: no LPIPS weights",
                "3DGS: wall time not recorded",
                "Dual: best step chosen by PSNR",
            ]
        );
    }
}
